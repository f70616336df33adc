"""test_cluster_worlds_failover: failover of nodes that tick several worlds
(docs/cluster.md). 3 nats-servers (JetStream, 3 replicas), 3 terrad nodes
(--max-worlds 3), 6 registered worlds: two nodes tick three worlds each, the
third waits. Each round, a client drives a sphere in a random world on its
owner for a random time, sometimes lifting it and letting the terrain settle
first, and the owner is killed with SIGKILL at that moment; once in the run
(the middle round) a NATS server is killed first: every world goes on
ticking and committing on its node; it comes back before the owner's kill.
Each round starts once every node is up (the one killed the round before was
started again and waits as a standby: with two nodes full, it is the one that
can take over). After each kill every world of the killed node ticks on
another node; its recovered tick is at least the last tick the client saw
acknowledged, Σh of every world equals its value before the kill
(deformation moves material, never makes or loses it), and after a settled
kill GET /v1/heights of the driven world equals the client's mirror of its
last acknowledged tick.

TERRAD_CLUSTER_KILLS rounds (default 2; `make soak`: 12, see
tests/soak/cluster_failover.sh). TERRAD_TAKEOVER_S: when set (the soak sets
5, issue 11), each takeover must also come within that many seconds; make
test checks no figure of speed. Skipped (77) when nats-server is missing.
"""
# ctest-timeout: 400
import asyncio
import os
import random
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, owner_of, wait_for  # noqa: E402
from service_harness import Checks, skip  # noqa: E402

KILLS = int(os.environ.get("TERRAD_CLUSTER_KILLS", "2"))
TAKEOVER_S = float(os.environ["TERRAD_TAKEOVER_S"]) if os.environ.get("TERRAD_TAKEOVER_S") else None
rand = random.Random(int(os.environ.get("TERRAD_CLUSTER_SEED", "20261124")))
WORLDS = [f"w{i}" for i in range(6)]
SCENE = "tests/scenes/spheres.json"
check = Checks()


def volume(node, world):
    try:
        st = node.stats(world)
        return st["volume"] if st else None
    except Exception:  # noqa: BLE001
        return None


def committing(node, world, since):
    """1 when world ticks on node past tick since with its store writable."""
    st = node.stats(world) if node.serves(world) else None
    return st is not None and st["tick"] > since and st.get("ready", True)


def nats_kill(nodes, nats, volumes):
    """kill -9 of one NATS server: every world goes on ticking and committing on its node."""
    victim = nats.servers[rand.randrange(len(nats.servers))]
    ticks = {w: owner_of(nodes, w).stats(w)["tick"] for w in WORLDS}
    t0 = time.monotonic()
    victim.kill()
    for w in WORLDS:
        ok = wait_for(lambda: any(committing(n, w, ticks[w] + 60) for n in nodes), 60)
        check(ok, f"after kill -9 of NATS server {victim.name}, {w} ticks and commits on")
        n = owner_of(nodes, w)
        check(n is not None and volume(n, w) == volumes[w], f"Σh of {w} is unchanged")
    print(f"NATS server {victim.name} killed: every world committing again "
          f"{time.monotonic() - t0:.1f} s later", flush=True)
    victim.start()  # back (same store): it catches up before the next owner is killed
    victim.wait_listening()
    ticks = {w: owner_of(nodes, w).stats(w)["tick"] for w in WORLDS}
    for w in WORLDS:
        check(wait_for(lambda: any(committing(n, w, ticks[w] + 60) for n in nodes), 60),
              f"after NATS server {victim.name} is back, {w} ticks and commits on")
    return victim


def kill_round(k, nodes, volumes, nats, takeovers):
    # the node killed last round was started again: it must be up before the next kill, or
    # (two nodes full with 3 worlds each) no node could take the killed node's worlds
    check(wait_for(lambda: all(n.up() for n in nodes), 90),
          f"round {k}: every node is up (ticking worlds or a standby) before the kill")
    world = rand.choice(WORLDS)
    owner = owner_of(nodes, world)
    if not check(owner is not None, f"round {k}: {world} has an owner"):
        return
    moved = sorted(owner.worlds)
    settle = rand.random() < 0.5
    nats_killed = None
    if k == KILLS // 2:  # once in the run: a NATS server goes, and comes back
        nats_killed = nats_kill(nodes, nats, volumes)
        owner = owner_of(nodes, world)  # the NATS kill moves no world, but be sure
        if not check(owner is not None, f"round {k}: {world} has an owner"):
            return
        moved = sorted(owner.worlds)
    acked, lane, heights = asyncio.run(ch.drive_and_kill(owner, rand.uniform(0.5, 2.0), settle,
                                                             world=world))
    t_kill = time.monotonic()
    others = [n for n in nodes if n is not owner]
    for w in moved:
        new = owner_of(others, w, 60, step=0.02)
        took = time.monotonic() - t_kill
        if not check(new is not None, f"round {k}: {w} ticks on another node after the kill"):
            continue
        takeovers.append(took)
        if TAKEOVER_S is not None:
            check(took <= TAKEOVER_S, f"round {k}: {w} ticks on {new.name} {took:.1f} s after "
                  f"the kill (within {TAKEOVER_S} s)")
        st = wait_for(lambda: new.stats(w), 10)
        check(st is not None and st["volume"] == volumes[w],
              f"round {k}: Σh of {w} on {new.name} equals its value before the kill")
        if w == world:
            rec = new.recovered.get(w, -1)  # the tick recovered at, not the tick now
            check(rec >= acked, f"round {k}: {w} recovered at tick {rec} >= the last tick the "
                  f"client saw acknowledged ({acked})")
            if settle and heights is not None:
                _, now = new.heights(w, *lane)
                check(now == heights, f"round {k}: GET /v1/heights of {w} on {new.name} equals "
                      f"the client's mirror of its last acknowledged tick {acked}")
    print(f"round {k}: killed {owner.name} (worlds {moved}; drove {world}, "
          f"{'settled' if settle else 'moving'}, acked {acked})"
          f"{'; after NATS ' + nats_killed.name + ' was killed and back' if nats_killed else ''}; "
          f"takeovers {', '.join(f'{t:.1f} s' for t in takeovers[-len(moved):])}", flush=True)
    owner.start()  # back, waiting


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    takeovers = []
    with ch.NatsCluster(3) as nats, ch.running_nodes(check, [], nats, tail=30,
                                                     stopped=ch.all_zero) as nodes:
        for w in WORLDS:
            ok, said = ch.world_add(nats.urls, w, SCENE)
            check(ok, f"world add {w}: {said}")
        nodes += [Node(f"n{i}", nats.urls, max_worlds=3) for i in range(3)]
        check(wait_for(lambda: all(any(n.serves(w) for n in nodes) for w in WORLDS), 120),
              "the 6 worlds tick on the nodes")
        volumes = {w: volume(owner_of(nodes, w), w) for w in WORLDS}
        for k in range(KILLS):
            kill_round(k, nodes, volumes, nats, takeovers)
        for s in nats.servers:
            if not s.alive():
                s.start()
        check(wait_for(lambda: all(any(n.serves(w) for n in nodes) for w in WORLDS), 60),
              "at the end, every world ticks")
        if takeovers:
            takeovers.sort()
            print(f"takeovers: {len(takeovers)}, p50 {takeovers[len(takeovers) // 2]:.1f} s, "
                  f"max {takeovers[-1]:.1f} s", flush=True)
    check.finish()


if __name__ == "__main__":
    main()
