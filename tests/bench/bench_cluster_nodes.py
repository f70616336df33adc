#!/usr/bin/python3
"""bench_cluster_nodes: cluster mode, daemon level (docs/cluster.md "Measured").
Real nats-server processes and real terrad nodes on loopback:

  1. failover time: 3 NATS servers, node a ticks "dunes", node b waits; kill -9
     of the owner → the first tick of the new owner (its /v1/stats?world=dunes
     answers with a tick past the one recovered), FAILOVERS times (default 6);
     p50 and max (anchor: within 5 s, issue 11);
  2. commit latency at 60 Hz: the owner's terrad_world_commit_p50/p99_seconds
     (publish → JetStream acknowledged, 3 replicas) while 6 demo actors deform
     the world (anchor: p99 under one tick, 16.7 ms);
  3. per-world tick rate for 1, 2 and 6 worlds on 1 and 3 nodes (3 NATS
     servers, each world with 6 demo actors deforming it; a node ticks
     ceil(worlds / nodes) worlds, each on its own sim thread): ticks per second
     per world over MEASURE_S (anchor: the scene's 60 Hz);
  4. fan-out: bytes out per node with 300 viewers of one world spread over 3
     nodes (tests/soak/cluster_fanout.sh's scenario; anchor: the relays send
     as much as the owner — viewers scale with nodes, not with the owner).

Every node, NATS server and this script share the machine's cores: on a
2-core machine the figures of 3 and 6 worlds measure contention first. The
figures are printed beside their anchors; nothing here ever fails on them.
Skipped (exit 0, a note) without nats-server.
"""
import math
import os
import re
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, owner_of, wait_for  # noqa: E402
from service_harness import BIN, SOURCE, machine  # noqa: E402

FAILOVERS = int(os.environ.get("TERRAD_BENCH_FAILOVERS", "6"))
MEASURE_S = float(os.environ.get("TERRAD_BENCH_MEASURE_S", "4"))
SCENE = os.path.join(SOURCE, "tests/scenes/spheres.json")  # 256 x 256 cells, 60 Hz


def add_worlds(urls, names):
    for name in names:
        ok, said = ch.world_add(urls, name, SCENE)
        if not ok:
            raise RuntimeError(f"world add {name}: {said}")


def tick_of(node, world):
    try:
        st = node.stats(world)
        return st["tick"] if st else None
    except Exception:  # noqa: BLE001
        return None


def failover():
    print("## failover: kill -9 of the owner -> first tick on the new owner (3 NATS, R3)")
    times = []
    with ch.NatsCluster(3) as nats:
        add_worlds(nats.urls, ["dunes"])
        nodes = [Node("a", nats.urls), Node("b", nats.urls)]
        try:
            for k in range(FAILOVERS):
                owner = owner_of(nodes, "dunes", 60)
                if not owner:
                    print("  no owner: stopped")
                    break
                other = next(n for n in nodes if n is not owner)
                wait_for(lambda: any("is a standby" in l for l in other.lines), 30)
                time.sleep(1.0 + (k % 3) * 0.4)
                before = tick_of(owner, "dunes")
                t0 = time.monotonic()
                owner.kill9()
                served = wait_for(lambda: other.serves("dunes"), 60, step=0.01)
                first = served and wait_for(
                    lambda: (tick_of(other, "dunes") or 0) > (before or 0), 60, step=0.01)
                if not first:
                    print(f"  round {k}: no takeover within 60 s")
                    break
                times.append(time.monotonic() - t0)
                print(f"  round {k}: {times[-1]:.2f} s", flush=True)
                owner.start()
        finally:
            for n in nodes:
                n.stop()
    if times:
        p50, worst = statistics.median(times), max(times)
        print(f"failover p50 {p50:.2f} s, max {worst:.2f} s over {len(times)} kills "
              f"(anchor <= 5 s: {'met' if worst <= 5 else 'NOT met'})")


def metric(text, name, world):
    m = re.search(rf'^{name}{{world="{world}"}} ([0-9.e+-]+)', text, re.M)
    return float(m.group(1)) if m else None


def tick_rates(nats, worlds, nnodes):
    """Ticks per second of each world, with ceil(worlds / nodes) worlds per node."""
    names = [f"w{worlds}n{nnodes}x{i}" for i in range(worlds)]
    add_worlds(nats.urls, names)
    per = math.ceil(worlds / nnodes)
    nodes = [Node(f"n{i}", nats.urls, max_worlds=per,
                        extra=["--worlds", ",".join(names), "--demo-actors", "6"])
             for i in range(nnodes)]
    try:
        ok = wait_for(lambda: all(any(n.serves(w) for n in nodes) for w in names), 120)
        if not ok:
            return None, None
        time.sleep(1.5)
        owner = {w: next(n for n in nodes if n.serves(w)) for w in names}
        t0 = {w: (tick_of(owner[w], w), time.monotonic()) for w in names}
        time.sleep(MEASURE_S)
        rates = []
        for w in names:
            t1 = tick_of(owner[w], w)
            rates.append((t1 - t0[w][0]) / (time.monotonic() - t0[w][1]))
        commit = None
        if worlds == 1:
            text = owner[names[0]].get("/metrics")[1].decode()
            commit = (metric(text, "terrad_world_commit_p50_seconds", names[0]),
                      metric(text, "terrad_world_commit_p99_seconds", names[0]))
        return rates, commit
    finally:
        for n in nodes:
            n.stop()
        for w in names:
            subprocess.run([BIN, "world", "remove", w, "--cluster", nats.urls],
                           capture_output=True, timeout=60)


def tick_rate_table():
    print("## per-world tick rate, each world 256x256 cells with 6 demo actors (3 NATS, R3)")
    print(f"{'worlds':>6} {'nodes':>5} {'mean Hz':>8} {'min Hz':>7}  anchor")
    commit = None
    with ch.NatsCluster(3) as nats:
        for worlds in (1, 2, 6):
            for nnodes in (1, 3):
                rates, c = tick_rates(nats, worlds, nnodes)
                if c and nnodes == 1:
                    commit = c
                if not rates:
                    print(f"{worlds:>6} {nnodes:>5}  (not all worlds started within 120 s)")
                    continue
                mean, low = statistics.mean(rates), min(rates)
                print(f"{worlds:>6} {nnodes:>5} {mean:>8.1f} {low:>7.1f}  (anchor 60 Hz: "
                      f"{'met' if low >= 59 else 'NOT met'})", flush=True)
    if commit and commit[0] is not None:
        p50, p99 = commit[0] * 1000, commit[1] * 1000
        print(f"commit latency at 60 Hz (1 world, 1 node, 3 replicas): p50 {p50:.2f} ms, "
              f"p99 {p99:.2f} ms (anchor p99 < 16.7 ms: {'met' if p99 < 16.7 else 'NOT met'})")


def fanout():
    print("## fan-out: 300 viewers of one world over 3 nodes (3 NATS, R3)")
    env = dict(os.environ, TERRAD_FANOUT_VIEWERS="300", TERRAD_FANOUT_NATS="3",
               TERRAD_FANOUT_NODES="3")
    p = subprocess.run(["/usr/bin/python3", os.path.join(HERE, "..", "integration",
                                                         "test_cluster_fanout.py")],
                       env=env, capture_output=True, text=True, timeout=600)
    line = next((l for l in p.stdout.splitlines() if l.startswith("bytes out per node")), None)
    print(f"  {line or 'no figure (the run failed: ' + p.stdout[-300:] + ')'}")
    sizes = [float(x) for x in re.findall(r"([0-9.]+) MB", line or "")]
    if len(sizes) == 3:
        print(f"relays / owner bytes out: {sizes[1] / sizes[0]:.2f}, {sizes[2] / sizes[0]:.2f} "
              "(anchor ~1: each node sends its own viewers' share)")


def main():
    if ch.NATS_SERVER is None:
        print("bench_cluster_nodes: nats-server is not installed, skipped")
        return
    print(f"# bench_cluster_nodes on {machine()}, load average {os.getloadavg()[0]:.1f} "
          "(every process shares these cores)")
    only = sys.argv[1:] or ["failover", "ticks", "fanout"]
    if "failover" in only:
        failover()
    if "ticks" in only:
        tick_rate_table()
    if "fanout" in only:
        fanout()


if __name__ == "__main__":
    main()
