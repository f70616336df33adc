#!/usr/bin/python3
# ctest-timeout: 300
"""A client-clocked world on a cluster (issue 30, item 1; docs/cluster.md): registered with
"clock": "client" (terrad world add), ticked by one node, stepped by a real C client
(tests/support/c_cosim_drive.c) through that node. The owner is killed with SIGKILL while the
driver waits after its last STEPPED; the standby takes the world over from JetStream, and the
world it serves is at least at the last acknowledged tick with the driver's mirror's heights
(failover keeps every acknowledged step); then it waits for a driver (no tick by the clock), and
a new driver steps it on from the new owner.

Behaviour only: every wait is for a condition, with a generous deadline. Skipped (77) when
nats-server is missing.
"""
import os
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, owner_of, wait_for  # noqa: E402
from service_harness import (COSIM_DRIVE, COSIM_H, COSIM_W, Checks, cosim_acked,  # noqa: E402
                             cosim_mirror, cosim_paused, cosim_scene, json_file, skip)

check = Checks()


def port(node):
    return node.ws.rstrip("/").rsplit(":", 1)[1]


def main():
    if not shutil.which("nats-server"):
        skip("nats-server is not installed")
    tmp = tempfile.mkdtemp(prefix="terrad-cosim-cluster-")
    scene = json_file(cosim_scene(clock="client"), "terrad-cosim-cluster-scene")
    with ch.NatsCluster(3) as nats, ch.running_nodes(check, [], tail=40) as nodes:
        ok, said = ch.world_add(nats.urls, "cw", scene)
        check(ok, f"terrad world add cw (clock client): {said}")
        nodes += [Node(f"n{i}", nats.urls) for i in range(2)]
        owner = owner_of(nodes, "cw", 60)
        check(owner is not None, "a node ticks the world")
        standby = next(n for n in nodes if n is not owner)
        check(wait_for(standby.up, 60), "the other node waits as a standby")
        p, lines = cosim_paused(port(owner), "cw", 200, os.path.join(tmp, "d"))
        last = cosim_acked(lines)
        check(lines and lines[-1].startswith("PAUSED") and last > 0,
              f"driver paused after its steps (last acknowledged tick {last})")
        before = owner.stats("cw")["tick"]
        time.sleep(0.5)
        check(owner.stats("cw")["tick"] == before, f"a client-clocked world waits: tick {before}")
        owner.kill9()
        p.kill()
        p.wait()
        new = owner_of([standby], "cw", 90)
        check(new is standby, "the standby took the world over")
        if new is not None:
            tick = wait_for(lambda: (new.stats("cw") or {}).get("tick"), 60)
            check(tick is not None and tick >= last, f"recovered tick {tick} >= the last STEPPED tick {last}")
            _, hs = new.heights("cw", 0, 0, COSIM_W, COSIM_H)
            with open(os.path.join(tmp, "d.cw")) as f:
                check(hs == cosim_mirror(f.read()), "heights after the failover == the driver's mirror")
            r = subprocess.run([COSIM_DRIVE, port(new), "cw", "20", os.path.join(tmp, "e")],
                               capture_output=True, text=True, timeout=120)
            check(r.returncode == 0, f"a new driver steps it on the new owner: {r.stderr[-500:]}")
    os.unlink(scene)
    shutil.rmtree(tmp, ignore_errors=True)


main()
check.finish()
