#!/usr/bin/python3
"""A cluster node's drain (issue 32, item 5; docs/fleet.md) on a real
nats-server (JetStream) with two real terrad nodes and one registered world:
a client drives a sphere through the world's owner, lifts it and waits until
the terrain has settled; the owner gets SIGTERM. Then:

  - the connected client is told (the owner logs the "draining" notice sent
    to its client) and the owner exits 0;
  - the other node (a standby) takes the world over and serves it: a hello
    there gets the world message naming it, its tick is at least the last
    tick the client saw acknowledged, and GET /v1/heights of the client's lane
    equals the client's mirror cell for cell (nothing acknowledged lost).

Then a third node starts as the standby and POST /v1/drain on the new owner
hands the world over the same way (202, the owner exits 0, the third node
serves it).

The hand-over time (SIGTERM → the standby serves the world) is printed, a
figure for docs/fleet.md, never a threshold. Without the node's drain the
notice check fails (the client is only closed). Skipped (77) when
nats-server is not installed.
"""
# ctest-timeout: 300
import asyncio
import os
import signal
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, owner_of  # noqa: E402
from service_harness import Checks, json_call, machine, raw_hello, skip  # noqa: E402

check = Checks()


def exit_code(node, timeout=60):
    """node's exit status once it has exited by itself (None: still running)."""
    try:
        return node.proc.wait(timeout)
    except Exception:  # noqa: BLE001  (subprocess.TimeoutExpired)
        return None


def handover(nats, nodes):
    """The owner of dunes drained by SIGTERM while a client drives; the checks above."""
    urls = nats.urls
    ok, said = ch.world_add(urls, "dunes", "server/scene/default.json")
    check(ok, f"world add dunes: {said}")
    nodes.extend(Node(f"n{i}", urls) for i in range(2))
    owner = owner_of(nodes, "dunes", 60)
    check(owner is not None, "a node owns dunes")
    if owner is None:
        return
    standby = next(n for n in nodes if n is not owner)
    check(ch.wait_for(lambda: standby.up(), 60), "the other node waits as a standby")
    sent = []

    def sigterm():
        sent.append(time.monotonic())
        owner.proc.send_signal(signal.SIGTERM)

    acked, lane, heights = asyncio.run(ch.drive_and_kill(
        owner, 1.5, True, world="dunes", half_lane=32, radius=0.4, speed=4.0, dip=0.25,
        end=sigterm))
    check(heights is not None, "the client had an acknowledged mirror")
    served = owner_of([standby], "dunes", 120, step=0.01)
    took = time.monotonic() - sent[0] if sent else None
    check(served is standby, "the standby serves dunes after the owner's SIGTERM")
    rc = exit_code(owner)
    check(rc == 0, f"the drained owner exits 0 ({rc})")
    check(any("draining" in line and "1 clients told" in line for line in owner.lines),
          "the owner told its connected client it drains")
    world, _ = asyncio.run(raw_hello(standby, "dunes"))
    check(world.get("type") == "world" and world.get("world") == "dunes",
          f"a hello naming dunes on the standby gets its world message ({world})")
    stats = standby.stats("dunes")
    check(stats is not None and stats["tick"] >= acked,
          f"the standby's tick {stats and stats['tick']} >= the last ACK {acked}")
    if heights is not None:
        _, now = standby.heights("dunes", *lane)
        diff = sum(1 for a, b in zip(now, heights) if a != b)
        check(diff == 0, f"the standby's heights equal the client's mirror ({diff} differ)")
    if took is not None and served is standby:
        print(f"hand-over: {took:.2f} s from SIGTERM to the standby serving dunes "
              f"({machine()})", flush=True)
    admin_drain(urls, nodes, standby)


def admin_drain(urls, nodes, owner):
    """The same hand-over asked by POST /v1/drain on the owner (no tokens: any
    caller is an admin), to a third node started as the new standby."""
    third = Node("n2", urls)
    nodes.append(third)
    check(ch.wait_for(lambda: third.up(), 60), "a third node waits as a standby")
    t0 = time.monotonic()
    st, body = json_call(owner.http, "POST", "/v1/drain", raw=b"")
    check(st == 202 and body.get("draining") is True and body.get("grace_ms") == 0,
          f"POST /v1/drain on the owner answers 202, grace 0 ({st} {body})")
    served = owner_of([third], "dunes", 120, step=0.01)
    took = time.monotonic() - t0
    check(served is third, "after POST /v1/drain the third node serves dunes")
    rc = exit_code(owner)
    check(rc == 0, f"the owner drained by POST /v1/drain exits 0 ({rc})")
    check(any("POST /v1/drain" in line and "draining" in line for line in owner.lines),
          "the owner says it drains for POST /v1/drain")
    if served is third:
        print(f"hand-over: {took:.2f} s from POST /v1/drain to the next node serving dunes",
              flush=True)


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    nodes = []
    nats = ch.NatsCluster(1).start()
    try:
        handover(nats, nodes)
    except Exception as e:  # noqa: BLE001
        check(False, f"the test raised: {e!r}")
    finally:
        if check.failed:
            for n in nodes:
                n.print_log()
        for n in nodes:
            n.stop()
        nats.stop()
    check.finish()


if __name__ == "__main__":
    main()
