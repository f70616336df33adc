#!/usr/bin/python3
# ctest-timeout: 600
"""test_cluster_spectate: spectators on cluster nodes (issue 32 item 3; PROTOCOL.md "Spectate",
docs/cluster.md "Replays"): the world's past is read back from JetStream (its tile snapshots
and log: server/cluster/cluster_history.c) by the same store cursor a single daemon's
spectators use on its data directory, on one real nats-server and three terrad nodes:

- node a ticks "match" (the compaction drive's 96 x 40 scene, two tiles); node b ticks
  "spare" and relays match; a live viewer on a subscribes to the whole world and keeps its
  mirror after every DELTA frame, while a driver presses a sphere along a track and makes two
  craters by edit (tests/support/spectate_check.py, shared with test_spectate).
- A spectator on a from tick 0 at 8x, one from a middle tick, and one through the relay b
  (hello naming match: its spectate goes to a, its frames come back through b): at every ACK
  each spectator's mirror equals the viewer's at that tick, and GET /v1/heights?tick=N on a
  (the same reader) at sampled ticks; each ends with spectate_end "live".
- Refusals through the relay and on a, each an error naming the field, counted in
  terrad_spectate_refused_total{field}: a from_tick in the future; then, once the owner has
  compacted the log into tile snapshots (it purges the log below them), a from_tick before
  them ("no longer held", on a and through b) and GET /v1/heights?tick=1 (410, on a and
  through b: a relay asks the owner).
- After that compaction a spectator from a tick the snapshots cover (its rebuild loads the
  tile snapshots, then the log after them) equals the viewer while the world changes again.
- kill -9 of the owner during two stepping spectates (one on a, one through b): the one on a
  sees its connection closed, the one on b gets shutting_down (the world moved) and is closed;
  nothing hangs. Node c takes match from JetStream, and a spectator through b (now relaying
  c) from a tick before the kill equals what the viewer on a was served live; c's
  terrad_spectators is back to 0 afterwards, and b and c go on.
- The world is deleted (DELETE /v1/worlds/match on b) under two stepping spectators replaying
  on c (one on c, one through b): the one on c is told the world was deleted (close 4020), the
  relayed one is closed by b (which stops relaying a world gone from the registry), c's replay
  threads are cancelled with it (terrad_spectators 0), and b and c go on.

Without the JetStream reader every spectate on a cluster node is refused ("keeps no log to
replay") and no mirror is compared: the first check fails. Skipped (77) when nats-server is
not installed. No figure of speed is checked; every wait is a condition with a generous
deadline.
"""
import asyncio
import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import Checks, RecordingClient, json_call, metric_value, skip, tp  # noqa: E402
import compaction_drive as cd  # noqa: E402
import spectate_check as sc  # noqa: E402

check = Checks()
WORLD = "match"
WAIT = sc.WAIT
# records (one a tick) between compactions: 60 s at 60 Hz, so that the spectators from tick 0
# (a few seconds here at load 20) replay before the first compaction purges the log below its
# snapshots, even on a busy machine
COMPACT = ["--compact-records", "3600"]


async def until(predicate, timeout):
    """Waits for predicate() while the event loop runs (the live viewer keeps reading: a
    blocking wait would make it fall behind and miss deltas)."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout
    while not predicate() and loop.time() < end:
        await asyncio.sleep(0.2)
    return predicate()


def read_past(node, tick):
    """The whole world as of tick, from node's GET /v1/heights?tick=N (None: refused)."""
    status, body = node.get(f"/v1/heights?world={WORLD}&x=0&y=0&w={cd.W}&h={cd.H}&tick={tick}")
    return list(struct.unpack(f"<{cd.W * cd.H}i", body)) if status == 200 else None


def tick_of(node):
    return (node.stats(WORLD) or {}).get("tick", 0)


def metric(node, name, labels=None):
    status, body = node.get("/metrics")
    return (metric_value(body.decode(), name, labels) or 0) if status == 200 else None


def refused(node, field):
    return metric(node, "terrad_spectate_refused_total", {"field": field})


async def watch(node, what, from_tick, viewer, via=None):
    """A spectator on via (default node) from from_tick at 8x, compared with the viewer and
    node's ?tick=N."""
    at = via or node
    sid, s, started = await sc.spectate(at.ws, what, from_tick, lambda: tick_of(node), world=WORLD)
    sc.compare(check, viewer, s, sid, what, from_tick, started, lambda t: read_past(node, t))
    await s.close()


async def expect_refusal(node, from_tick, field, words, what):
    c = RecordingClient(node.ws, name="refused-spectator", world=WORLD)
    await c.connect()
    try:
        await c.request(tp.spectate(*sc.REGION, from_tick), "spectating", timeout=WAIT)
        check(False, f"{what}: refused")
    except tp.ServerError as e:
        said = e.msg.get("message", "")
        check(said.startswith(f"{field}:") and all(w in said for w in words),
              f"{what}: an error naming {field}, saying {words} ({e.msg})")
    await c.close()


async def live_spectators(a, b, viewer):
    ticks = sorted(viewer.by_tick)
    check(len(ticks) >= 30, f"the viewer saw the window change in {len(ticks)} ticks")
    await watch(a, "from tick 0 on the owner", 0, viewer)
    await watch(a, "from a middle tick on the owner", ticks[len(ticks) // 2], viewer)
    await watch(a, "through the relay b", ticks[len(ticks) // 3], viewer, via=b)
    before = refused(a, "from_tick")
    await expect_refusal(b, tick_of(a) + 100000, "from_tick", ["in the future"],
                         "a future from_tick through the relay")
    check(refused(a, "from_tick") == before + 1,
          "counted by the owner in terrad_spectate_refused_total{field=\"from_tick\"}")


async def after_compaction(a, b, viewer):
    """The log below the snapshots is purged: older ticks refused, newer ones replayed from
    the snapshots and the log after them."""
    before = refused(a, "from_tick")
    await expect_refusal(a, 0, "from_tick", ["no longer held", "compacted"],
                         "from_tick 0 once the log was compacted (on the owner)")
    await expect_refusal(b, 1, "from_tick", ["no longer held", "compacted"],
                         "from_tick 1 once the log was compacted (through the relay)")
    check(refused(a, "from_tick") == before + 2,
          "both counted in terrad_spectate_refused_total{field=\"from_tick\"}")
    status, body = a.get(f"/v1/heights?world={WORLD}&x=0&y=0&w=8&h=8&tick=1")
    check(status == 410 and b"no longer held" in body,
          f"GET /v1/heights?tick=1 once compacted: 410 ({status}, {body[:200]!r})")
    status, body = b.get(f"/v1/heights?world={WORLD}&x=0&y=0&w=8&h=8&tick=1")
    check(status == 410 and b"no longer held" in body,
          f"and through the relay b, which asks the owner: 410 ({status}, {body[:200]!r})")
    start = tick_of(a)
    await sc.drive(a.ws, cd.SECOND[:12], craters=(4,), world=WORLD)
    await watch(a, "from a tick the snapshots cover", start, viewer)
    return start


async def killed_owner(a, b, c, viewer, from_tick):
    """kill -9 of the owner under two stepping spectators; then c serves the world's past."""
    direct = RecordingClient(a.ws, name="stepper-a", world=WORLD, keep=10 ** 6)
    relayed = RecordingClient(b.ws, name="stepper-b", world=WORLD, keep=10 ** 6)
    for s in (direct, relayed):
        await s.connect()
        await s.spectate(*sc.REGION, from_tick, step=True, timeout=WAIT)
        await s.wait_for(lambda s=s: s.acked_tick == from_tick, WAIT)
    check(metric(a, "terrad_spectators") == 2,
          f"two spectators replay on the owner ({metric(a, 'terrad_spectators')})")
    a.kill9()
    try:
        await direct.wait_for(lambda: direct.ws.closed, WAIT)
    except asyncio.TimeoutError:
        pass
    check(direct.ws.closed, "kill -9 of the owner: the spectator on it sees its connection closed")
    try:
        await relayed.wait_for(
            lambda: any(e.get("name") == "shutting_down" for e in relayed.errors)
            or relayed.ws.closed, WAIT)
    except asyncio.TimeoutError:
        pass
    moved = [e for e in relayed.errors if e.get("name") == "shutting_down"]
    check(moved and "new owner" in moved[0].get("message", ""),
          f"the spectator through b is told the world has a new owner ({relayed.errors[-3:]})")
    for s in (direct, relayed):
        try:
            await s.close()
        except Exception:  # noqa: BLE001
            pass
    check(await until(lambda: c.serves(WORLD), WAIT), "node c takes match from JetStream")
    again = None
    for _ in range(30):  # b relays c once its node loop has seen the new owner
        try:
            await watch(c, "through b from before the kill, replayed by c", from_tick, viewer, via=b)
            again = True
            break
        except Exception as e:  # noqa: BLE001 (refused, or closed while b still relays a)
            again = e
            await asyncio.sleep(1)
    check(again is True, f"a spectate through b is served by c ({again})")
    check(await until(lambda: metric(c, "terrad_spectators") == 0, WAIT),
          "c's replay threads end (terrad_spectators 0)")
    check(b.stats("spare") is not None and (c.stats(WORLD) or {}).get("ready"),
          "b and c go on")


async def deleted(b, c, from_tick):
    """The world is deleted (DELETE on b) under two stepping spectators replaying on its owner c,
    one on c and one through b: the DELETE answers, the one on c is told the world was deleted,
    the relayed one is closed by b, c's replay threads are cancelled (terrad_spectators 0) and
    the nodes go on."""
    watchers = [RecordingClient(n.ws, name=f"doomed-{n.name}", world=WORLD) for n in (c, b)]
    for s in watchers:
        await s.connect()
        await s.spectate(*sc.REGION, from_tick, step=True, timeout=WAIT)
    check(metric(c, "terrad_spectators") == 2,
          f"two spectators replay on c ({metric(c, 'terrad_spectators')})")
    loop = asyncio.get_running_loop()
    status, answer = await loop.run_in_executor(None, json_call, b.http, "DELETE",
                                                f"/v1/worlds/{WORLD}")
    check(status == 200 and answer.get("deleted") is True, f"DELETE {WORLD} on b: {status} {answer}")
    on_c, via_b = watchers
    told = await until(lambda: on_c.ws.closed, WAIT)
    said = [e.get("message", "") for e in on_c.errors]
    check(told and any("deleted" in m for m in said) and on_c.ws.close_code == 4020,
          f"the spectator on c is told the world was deleted and closed 4020 ({said[-2:]}, "
          f"{on_c.ws.close_code} {on_c.ws.close_reason!r})")
    # b stops relaying a world gone from the registry and closes its clients ("world moved"),
    # whether or not the owner's error came first: a clear end either way
    check(await until(lambda: via_b.ws.closed, WAIT),
          f"the spectator through b is closed ({via_b.ws.close_code} {via_b.ws.close_reason!r}, "
          f"{[e.get('message', '') for e in via_b.errors][-2:]})")
    for s in watchers:
        try:
            await s.close()
        except Exception:  # noqa: BLE001
            pass
    check(await until(lambda: metric(c, "terrad_spectators") == 0, WAIT),
          "c's replay threads are cancelled with the world (terrad_spectators 0)")
    check(b.stats("spare") is not None and metric(c, "terrad_spectators") == 0, "b and c go on")


async def run(a, b, c):
    viewer = sc.Viewer(a.ws, name="viewer", world=WORLD)
    await viewer.connect()
    await viewer.subscribe(*sc.REGION)
    await viewer.wait_for(lambda: viewer.by_tick, WAIT)
    await sc.drive(a.ws, cd.FIRST[:36], craters=(10, 25), world=WORLD)
    await live_spectators(a, b, viewer)
    # the owner compacts its log (a record a tick) into tile snapshots every COMPACT records
    check(ch.compactions(a, WORLD) == 0, "no compaction yet while the spectators replayed from 0")
    check(await until(lambda: ch.compactions(a, WORLD) > 0, 5 * WAIT),
          "the owner compacted the log into tile snapshots")
    start = await after_compaction(a, b, viewer)
    await killed_owner(a, b, c, viewer, start)
    await viewer.close()
    await deleted(b, c, start)


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    scene = cd.scene_file()
    left = "SIGTERM stops every node left with status 0"
    try:
        with ch.NatsCluster(1) as nats, ch.running_nodes(
                check, [], stopped=lambda codes: all(c in (0, -9) for c in codes),
                said=left) as nodes:
            urls = nats.urls
            for name, path in ((WORLD, scene), ("spare", "tests/scenes/tiny.json")):
                ok, said = ch.world_add(urls, name, path)
                check(ok, f"world add {name}: {said}")
            a = Node("a", urls, extra=["--worlds", WORLD] + COMPACT)
            nodes.append(a)
            check(wait_for(lambda: a.serves(WORLD), 60), "node a ticks match")
            b = Node("b", urls, extra=["--worlds", "spare"])
            nodes.append(b)
            check(wait_for(lambda: any(f"relays world {WORLD}" in line for line in b.lines), 30),
                  "node b relays match")
            c = Node("c", urls, extra=["--worlds", WORLD] + COMPACT)
            nodes.append(c)
            check(wait_for(lambda: any("is a standby" in line for line in c.lines), 30),
                  "node c waits for match")
            asyncio.run(run(a, b, c))
    finally:
        os.unlink(scene)
    check.finish()


if __name__ == "__main__":
    main()
