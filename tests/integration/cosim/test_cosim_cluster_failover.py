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
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, owner_of, wait_for  # noqa: E402
from service_harness import BIN, Checks, skip  # noqa: E402

check = Checks()
DRIVE = os.environ.get("TERRAD_C_COSIM_DRIVE", os.path.join(os.path.dirname(BIN), "c_cosim_drive"))
W, H = 96, 64
SCENE = {"name": "cosim", "clock": "client", "world": {"width": W, "height": H, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4},
         "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "ding2011"}}}


def port(node):
    return node.ws.rstrip("/").rsplit(":", 1)[1]


def mirror_of(path):
    with open(path) as f:
        lines = f.read().split("MIRROR", 1)[1].splitlines()[1:]
    return [int(v) for line in lines for v in line.split()]


def main():
    if not shutil.which("nats-server"):
        skip("nats-server is not installed")
    tmp = tempfile.mkdtemp(prefix="terrad-cosim-cluster-")
    scene = os.path.join(tmp, "cosim.json")
    with open(scene, "w") as f:
        json.dump(SCENE, f)
    with ch.NatsCluster(3) as nats:
        ok, said = ch.world_add(nats.urls, "cw", scene)
        check(ok, f"terrad world add cw (clock client): {said}")
        nodes = [Node(f"n{i}", nats.urls) for i in range(2)]
        try:
            owner = owner_of(nodes, "cw", 60)
            check(owner is not None, "a node ticks the world")
            standby = next(n for n in nodes if n is not owner)
            check(wait_for(standby.up, 60), "the other node waits as a standby")
            p = subprocess.Popen([DRIVE, port(owner), "cw", "200", os.path.join(tmp, "d"), "pause"],
                                 stdout=subprocess.PIPE, text=True)
            lines = []
            for line in p.stdout:
                lines.append(line)
                if line.startswith("PAUSED"):
                    break
            acked = [int(x.split()[2]) for x in lines if x.startswith("ACKED ")]
            check(lines and lines[-1].startswith("PAUSED") and acked, f"driver paused after {len(acked)} steps")
            last = acked[-1] if acked else 0
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
                _, hs = new.heights("cw", 0, 0, W, H)
                check(hs == mirror_of(os.path.join(tmp, "d.cw")), "heights after the failover == the driver's mirror")
                r = subprocess.run([DRIVE, port(new), "cw", "20", os.path.join(tmp, "e")],
                                   capture_output=True, text=True, timeout=120)
                check(r.returncode == 0, f"a new driver steps it on the new owner: {r.stderr[-500:]}")
        finally:
            for n in nodes:
                n.stop()
            if check.failed:
                for n in nodes:
                    n.print_log()
    shutil.rmtree(tmp, ignore_errors=True)


main()
check.finish()
