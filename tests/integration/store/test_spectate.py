#!/usr/bin/python3
# ctest-timeout: 600
"""Spectators (issue 32 item 3; PROTOCOL.md "Spectate"): a client watches a window from a past
tick, played forward from the data directory's log, and its mirror at every tick it saw is the
mirror a live subscriber held at that tick, bit for bit.

- A live viewer subscribes to the whole world (96 x 40 cells, two tiles) and keeps a copy of its
  mirror after every DELTA frame (by tick), while a driver presses a sphere along a track and
  makes two craters by `edit`, on a daemon with 4 KiB log segments (compacted into tile snapshots
  and keyframe generations many times) and --replay-retain-bytes keeping the whole log.
- Then a spectator from tick 0 at 8x, and one from a middle tick at 8x: at every ACK (its tick
  mark) the spectator's mirror equals the viewer's mirror at that tick (before the viewer's
  snapshot: GET /v1/heights?tick=N), and at sampled ticks GET /v1/heights?tick=N; each ends with spectate_end "live" at or after the tick
  the world was at when it started, and none of them ever got a CHECKSUM frame (the viewer did).
- A stepping spectator: two spectate_step messages play exactly those ticks; spectate_stop ends
  it with spectate_end "stopped". One whose connection goes while its thread waits for a step:
  the thread ends (terrad_spectators back to 0) and the daemon goes on.
- A 1024 B/s spectator that sends a PING every 50 ms (its window always holds a PONG) gets frames
  larger than its window has room for (the snapshot's), and its mirror equals the viewer's.
- Refusals, each an error naming the field, counted in terrad_spectate_refused_total{field},
  while the viewer keeps getting its deltas and the daemon goes on: speed 9 and 0, a from_tick
  in the future, a subscribe while spectating and a spectate while subscribed, spectate_step
  without a stepping spectate, a daemon without retention whose early log was compacted away
  (from_tick no longer held), and a memory-only daemon (no log at all).
- max_spectators (a limit of the table, told in the world message): on a daemon configured
  with `max_spectators: 1`, while a stepping spectator waits a second spectate is refused
  (too_large naming type, the message naming max_spectators, counted under
  terrad_spectate_refused_total{field="busy"}); the first goes on (a step of 3 plays 3 ticks)
  and, once it stopped and its thread ended, a spectate is accepted again. Without the limit
  (the fixed 16) the second spectator is accepted and that check fails.
- No spectator's frame was dropped: terrad_spectate_frames_dropped_total is there, at 0 (a drop
  happens only out of memory; test_net_spectate covers its branch).

- A small window on a larger world (a created 1024 x 1024 world, whose world tiles are 256 cells
  a side): craters inside the window (one crossing the edge of the window's 64-cell tile, so
  the cursor keeps only part of its rectangle) and in three other world tiles; a spectator of
  the window from before the first crater equals a live viewer's mirror of the window and GET
  /v1/heights?tick=N at every tick it saw; a second spectator from the tick of the last crater
  (its rebuild replays them all) starts from the same heights; and neither store cursor held
  more than the one world tile under the window (terrad_spectate_cursor_cells_max <= 256 * 256;
  each held the four tiles the craters touched, 262,144 cells, while records were applied
  whole: the first through store_cursor_apply, the second through its rebuild).
- The world is deleted (DELETE /v1/worlds/NAME) under a live spectator and one whose spectate
  was just sent (its rebuild replays the world's log from the base as the DELETE comes): the
  DELETE answers, each spectator gets an error saying the world was deleted, their replay
  threads end (terrad_spectators 0), and the daemon and a client of another world go on
  (test_store's test_cursor_cancel shows the rebuild stops at its next record once cancelled).

Without the spectator (net_spectate.c, store_cursor_*) every spectate is refused as an unknown
type, and no mirror is compared: the first check fails.
"""
import asyncio
import json
import os
import shutil
import struct
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, json_call, metric_value,  # noqa: E402
                             wait_until)
import compaction_drive as cd  # noqa: E402
import spectate_check as sc  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()
SEGMENT = ["--wal-segment-bytes", "4096"]
RETAIN = ["--replay-retain-bytes", str(64 << 20)]
WAIT = sc.WAIT
REGION = sc.REGION
Viewer = sc.Viewer


def read_past(d, tick):
    status, body, headers = d.get_busy(f"/v1/heights?x=0&y=0&w={cd.W}&h={cd.H}&tick={tick}",
                                       timeout=60)
    if status != 200:
        return None
    return list(struct.unpack(f"<{cd.W * cd.H}i", body))


def refused(d, field):
    return metric_value(d.metrics()[1], "terrad_spectate_refused_total", {"field": field}) or 0


async def spectate(d, what, from_tick):
    return await sc.spectate(d.ws, what, from_tick, lambda: d.stats()["tick"])


def compare(d, viewer, s, sid, what, from_tick, started_at):
    sc.compare(check, viewer, s, sid, what, from_tick, started_at, lambda t: read_past(d, t))


async def stepping(d, viewer, from_tick):
    s = RecordingClient(d.ws, name="spectator-step", keep=10 ** 6)
    await s.connect()
    sid = await s.spectate(*REGION, from_tick, step=True, timeout=WAIT)
    await s.wait_for(lambda: s.acked_tick == from_tick, WAIT)
    await asyncio.sleep(0.5)
    check(s.acked_tick == from_tick, f"stepping: it waits at tick {from_tick} ({s.acked_tick})")
    await s.spectate_step(7)
    await s.spectate_step(5)
    await s.wait_for(lambda: s.acked_tick >= from_tick + 12, WAIT)
    await asyncio.sleep(0.5)
    ticks = sorted(s.history)
    check(ticks == list(range(from_tick, from_tick + 13)),
          f"stepping: two steps of 7 and 5 played exactly 12 ticks ({ticks[0]}..{ticks[-1]}, "
          f"{len(ticks)})")
    check(all(s.history[t][sid][0] == viewer.at(t) for t in ticks),
          "stepping: its mirror equals the viewer's at each of them")
    end = await s.spectate_stop()
    check(end["reason"] == "stopped" and end["tick"] == from_tick + 12,
          f"spectate_stop: spectate_end \"stopped\" at its tick ({end})")
    await s.close()
    # a spectator whose connection goes while its thread waits for a step: the thread is
    # stopped and joined (terrad_spectators back to 0), the daemon goes on
    gone = RecordingClient(d.ws, name="spectator-gone")
    await gone.connect()
    await gone.spectate(*REGION, from_tick, step=True, timeout=WAIT)
    alive = metric_value(d.metrics()[1], "terrad_spectators")
    await gone.close()
    loop = asyncio.get_running_loop()
    end_at = loop.time() + WAIT
    while metric_value(d.metrics()[1], "terrad_spectators") and loop.time() < end_at:
        await asyncio.sleep(0.1)
    left = metric_value(d.metrics()[1], "terrad_spectators")
    check(alive == 1 and left == 0 and d.stats()["ready"],
          f"a spectator that disconnects mid-replay: its thread ends ({alive} -> {left} alive), "
          f"the daemon goes on")


class Budgeted(RecordingClient):
    """A spectator with the smallest budget a hello may state, that notes its largest frame."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, budget=1024, keep=10 ** 6, **kwargs)
        self.largest = 0

    async def _on_binary(self, data):
        self.largest = max(self.largest, len(data))
        await super()._on_binary(data)


async def chatter(c):
    """A PING every 50 ms: the PONGs keep the client's budget window from ever being empty."""
    nonce = 0
    while True:
        nonce += 1
        await c.ws.send(tp.encode_ping(nonce))
        await asyncio.sleep(0.05)


async def budgeted(d, viewer, from_tick):
    """A 1024 B/s spectator that sends a PING every 50 ms: a snapshot frame larger than its window
    will ever have room for goes once the window holds no replay frames, whatever PONGs it holds
    (the ledger's rule; without it the frame waited forever: for the window to be empty before
    80fb550, and for the window to hold no PONG while the client keeps pinging after it)."""
    s = Budgeted(d.ws, name="spectator-budget")
    await s.connect()
    pinging = asyncio.ensure_future(chatter(s))
    sid = await s.spectate(*REGION, from_tick, step=True, timeout=WAIT)
    await s.spectate_step(3)
    try:
        await s.wait_for(lambda: s.acked_tick >= from_tick + 3, WAIT)
    except asyncio.TimeoutError:
        pass  # the checks below say what did not come
    pinging.cancel()
    ticks = sorted(s.history)
    check(ticks == list(range(from_tick, from_tick + 4))
          and all(s.history[t][sid][1] and s.history[t][sid][0] == viewer.at(t) for t in ticks),
          f"budget 1024 B/s: its mirror equals the viewer's at ticks {ticks}")
    check(s.largest > 1024 - 256, f"(a frame of {s.largest} bytes: more than the window has room for)")
    await s.spectate_stop()
    await s.close()


async def expect_error(c, msg, field, what):
    try:
        await c.request(msg, "spectating")
        check(False, f"{what}: refused")
    except tp.ServerError as e:
        check(e.msg.get("message", "").startswith(f"{field}:"),
              f"{what}: an error naming {field} ({e.msg})")


async def refusals(d, viewer):
    before = {f: refused(d, f) for f in ("speed", "from_tick", "state", "step")}
    c = RecordingClient(d.ws, name="bad-spectator")
    await c.connect()
    now = d.stats()["tick"]
    await expect_error(c, tp.spectate(*REGION, 1, speed=9), "speed", "speed 9")
    await expect_error(c, tp.spectate(*REGION, 1, speed=0), "speed", "speed 0")
    await expect_error(c, tp.spectate(*REGION, now + 100000), "from_tick", "a future from_tick")
    await expect_error(c, {**tp.spectate(*REGION, 1), "step": "yes"}, "step", "a step that is not a boolean")
    await expect_error(c, tp.spectate_step(3), "type", "spectate_step without a stepping spectate")
    sid = await c.subscribe(*REGION)
    await expect_error(c, tp.spectate(*REGION, 1), "type", "a spectate while subscribed")
    await c.unsubscribe(sid)
    await c.spectate(*REGION, now - 20, step=True)  # it waits there: no step asked for
    try:
        await c.subscribe(*REGION)
        check(False, "a subscribe while spectating: refused")
    except tp.ServerError as e:
        check("spectating" in e.msg.get("message", ""), f"a subscribe while spectating: refused ({e.msg})")
    await c.close()
    after = {f: refused(d, f) for f in before}
    check(after["speed"] == before["speed"] + 2 and after["from_tick"] == before["from_tick"] + 1
          and after["step"] == before["step"] + 1 and after["state"] >= before["state"] + 3,
          f"each counted in terrad_spectate_refused_total{{field}} ({before} -> {after})")
    check(d.stats()["ready"], "and the daemon goes on")


async def watched_drive(d):
    """A live viewer of REGION, then the drive: (the viewer, its first tick)."""
    viewer = Viewer(d.ws, name="viewer")
    await viewer.connect()
    await viewer.subscribe(*REGION)
    await viewer.wait_for(lambda: viewer.by_tick, WAIT)
    first = min(viewer.by_tick)
    await sc.drive(d.ws, cd.FIRST[:36], craters=(10, 25))
    return viewer, first


async def retained_run(d):
    viewer, first = await watched_drive(d)
    ticks = sorted(viewer.by_tick)
    check(len(ticks) >= 30, f"the viewer saw the window change in {len(ticks)} ticks")
    check(viewer.desync["checksum_frames"] > 0,
          f"the live viewer got CHECKSUM frames ({viewer.desync['checksum_frames']})")
    sid, s, started = await spectate(d, "from tick 0", 0)
    compare(d, viewer, s, sid, "from tick 0", 0, started)
    check(first in s.history, f"from tick 0: it passed the viewer's first tick {first}")
    await s.close()
    middle = ticks[len(ticks) // 2]
    sid, s, started = await spectate(d, "from a middle tick", middle)
    compare(d, viewer, s, sid, f"from tick {middle}", middle, started)
    await s.close()
    await stepping(d, viewer, ticks[len(ticks) // 3])
    await budgeted(d, viewer, ticks[len(ticks) // 2])
    await refusals(d, viewer)
    await viewer.close()
    # a frame dropped would end its spectate "failed" (only when out of memory: test_net_spectate
    # covers that branch); here every frame was made and kept, and the series is there to say so
    dropped = metric_value(d.metrics()[1], "terrad_spectate_frames_dropped_total")
    check(dropped == 0, f"no spectator's frame dropped (terrad_spectate_frames_dropped_total {dropped})")


async def gone_run(d):
    viewer, first = await watched_drive(d)
    c = RecordingClient(d.ws, name="late-spectator")
    await c.connect()
    before = refused(d, "from_tick")
    # the compaction thread drops the early log beside the ticks: on a busy machine it may still
    # be behind the drive's end, so wait (a condition) until tick `first` is no longer held
    gone = f"/v1/heights?x=0&y=0&w={cd.W}&h={cd.H}&tick={first}"
    check(await asyncio.to_thread(wait_until, lambda: d.get_busy(gone, timeout=60)[0] == 410),
          f"without retention, tick {first} is compacted away (GET ?tick= is 410)")
    try:
        await c.spectate(*REGION, first, timeout=WAIT)
        check(False, "without retention, an early from_tick: refused")
    except tp.ServerError as e:
        why = e.msg.get("message", "")
        check(why.startswith("from_tick:") and "no longer held" in why,
              f"without retention, tick {first} (compacted away): an error naming from_tick ({e.msg})")
    check(refused(d, "from_tick") == before + 1, "counted")
    now = d.stats()["tick"]
    sid = await c.spectate(*REGION, now, timeout=WAIT)
    await c.wait_for(lambda: c.spectate_ended is not None, WAIT)
    check(c.spectate_ended["reason"] == "live" and c.mirrors[sid].complete,
          f"a recent tick is still spectated ({c.spectate_ended})")
    await c.close()
    await viewer.close()


def spectators(d):
    return metric_value(d.metrics()[1], "terrad_spectators") or 0


async def one_spectator(d):
    """max_spectators 1 (an idle world whose whole log is kept): a second spectator is refused
    while a stepping one waits at tick 0, which goes on."""
    check(await asyncio.to_thread(wait_until, lambda: d.stats()["tick"] >= 10),
          "max_spectators 1: the world ticks")
    first = RecordingClient(d.ws, name="spectator-first", keep=10 ** 6)
    await first.connect()
    told = first.world.get("limits", {}).get("max_spectators")
    check(told == 1, f"max_spectators 1: the world message tells it ({told})")
    start = 0
    await first.spectate(*REGION, start, step=True, timeout=WAIT)  # it waits there for steps
    busy = refused(d, "busy")
    second = RecordingClient(d.ws, name="spectator-second")
    await second.connect()
    try:
        await second.spectate(*REGION, start, step=True, timeout=WAIT)
        check(False, "max_spectators 1: a second spectator is refused")
    except tp.ServerError as e:
        why = e.msg.get("message", "")
        check(e.name == "too_large" and why.startswith("type:")
              and "max_spectators (1)" in why,
              f"max_spectators 1: a second spectator is refused, too_large naming max_spectators "
              f"({e.msg})")
    check(refused(d, "busy") == busy + 1,
          f"and counted in terrad_spectate_refused_total{{field=\"busy\"}} ({busy} -> "
          f"{refused(d, 'busy')})")
    await first.spectate_step(3)
    await first.wait_for(lambda: first.acked_tick >= start + 3, WAIT)
    ticks = sorted(first.history)
    check(ticks == list(range(start, start + 4)),
          f"max_spectators 1: the first spectator goes on (a step of 3 played ticks {ticks})")
    end = await first.spectate_stop()
    check(end["reason"] == "stopped", f"the first spectator stops ({end})")
    check(await asyncio.to_thread(wait_until, lambda: spectators(d) == 0),
          "its thread ends (terrad_spectators 0)")
    sid = await second.spectate(*REGION, d.stats()["tick"], timeout=WAIT)
    await second.wait_for(lambda: second.spectate_ended is not None, WAIT)
    check(second.spectate_ended["reason"] == "live" and second.mirrors[sid].complete,
          f"max_spectators 1: once the first stopped, a spectate is accepted again "
          f"({second.spectate_ended})")
    await second.close()
    await first.close()
    check(d.stats()["ready"], "and the daemon goes on")


async def memory_only(d):
    c = RecordingClient(d.ws, name="spectator")
    await c.connect()
    await expect_error(c, tp.spectate(*REGION, 0), "from_tick", "a memory-only daemon")
    await c.close()


BIG, BIG_WORLD = 1024, "spectate-big"
# inside world tile (0, 0), 256 x 256 cells, and reaching the right edge of its 64-cell tile:
# the crater at (62, 20) crosses that edge, so the cursor applies only part of its rectangle
WINDOW = (8, 8, 56, 24)
CRATERS = [(20, 20), (600, 100), (62, 20), (300, 800), (900, 900), (30, 14)]


def big_heights(d, tick):
    x, y, w, h = WINDOW
    status, body, _ = d.get_busy(f"/v1/heights?x={x}&y={y}&w={w}&h={h}&tick={tick}"
                                 f"&world={BIG_WORLD}", timeout=60)
    return list(struct.unpack(f"<{w * h}i", body)) if status == 200 else None


async def larger_world(d):
    big = cd.scene()
    big["world"] = {**big["world"], "width": BIG, "height": BIG}
    status, doc = json_call(d.http, "POST", "/v1/worlds", {"name": BIG_WORLD, "scene": big})
    check(status in (200, 201), f"POST /v1/worlds {BIG_WORLD} ({status} {doc})")
    viewer = Viewer(d.ws, name="big-viewer", world=BIG_WORLD)  # the live mirror to compare
    await viewer.connect()
    await viewer.subscribe(*WINDOW)
    await viewer.wait_for(lambda: next(iter(viewer.mirrors.values())).complete, WAIT)
    c = RecordingClient(d.ws, name="big-editor", world=BIG_WORLD, record=False)
    await c.connect()
    ticks = []
    for x, y in CRATERS:  # three inside the window, three in other world tiles
        ticks.append((await c.edit("crater", x=x, y=y, radius=6, depth=500))["tick"])
    await c.close()
    await viewer.wait_for(lambda: viewer.by_tick and max(viewer.by_tick) >= ticks[-1], WAIT)
    from_tick = ticks[0] - 1
    s = RecordingClient(d.ws, name="big-spectator", world=BIG_WORLD, keep=10 ** 6)
    await s.connect()
    sid = await s.spectate(*WINDOW, from_tick, speed=8, timeout=WAIT)
    await s.wait_for(lambda: s.spectate_ended is not None, WAIT * 2)
    seen = sorted(t for t in s.history if t >= from_tick)
    # the live viewer's mirror (what was served live; before its first DELTA, its snapshot's
    # tick: GET ?tick=N), and GET ?tick=N itself (the same rebuild code as the cursor's)
    live = [viewer.at(t) or big_heights(d, t) for t in seen]
    bad = [t for t, v in zip(seen, live) if not s.history[t][sid][1]
           or s.history[t][sid][0] != v or v != big_heights(d, t)]
    check(seen and seen[0] == from_tick and seen[-1] >= ticks[-1] and not bad,
          f"a {WINDOW[2]} x {WINDOW[3]} window of a {BIG}^2 world: the spectator's mirror equals "
          f"the live viewer's and GET /v1/heights?tick=N at all {len(seen)} ticks it saw "
          f"(differing: {bad[:5]})")
    check(s.history[seen[0]][sid][0] != s.history[seen[-1]][sid][0],
          "(the window changed while it watched)")
    await s.close()
    # and one that starts after the craters: its rebuild replays them (the log from the base)
    late = RecordingClient(d.ws, name="big-late-spectator", world=BIG_WORLD, keep=10 ** 6)
    await late.connect()
    lid = await late.spectate(*WINDOW, ticks[-1], speed=8, timeout=WAIT)
    await late.wait_for(lambda: late.spectate_ended is not None, WAIT)
    check(late.history[ticks[-1]][lid][0] == big_heights(d, ticks[-1]) == viewer.at(ticks[-1]),
          f"a spectator from tick {ticks[-1]}, after the craters: its snapshot is the window then")
    await late.close()
    held = metric_value(d.metrics()[1], "terrad_spectate_cursor_cells_max")
    check(held and held <= 256 * 256,
          f"their store cursors held only the window's world tile ({held} cells; <= {256 * 256}, "
          f"while craters touched {len(CRATERS) - 3} other tiles)")
    await viewer.close()


async def deleted_under_spectator(d):
    other = RecordingClient(d.ws, name="other-world")
    await other.connect()
    await other.subscribe(*REGION)
    s = RecordingClient(d.ws, name="deleted-spectator", world=BIG_WORLD)
    await s.connect()
    await s.spectate(*WINDOW, 1, step=True, timeout=WAIT)  # waits for a step: alive
    # its snapshot and ACK first: no frame of it is then in flight when the close comes (the
    # client's reply to a frame that arrives after the close would end its reader early)
    await s.wait_for(lambda: s.acked_tick == 1, WAIT)
    # and one whose rebuild (the world's whole log, from the base) runs as the DELETE comes: its
    # spectate goes without waiting for "spectating", so the DELETE finds it rebuilding or
    # (should the rebuild win) playing; either way its thread stops (store_cancel between the
    # rebuild's records, or wait_turn) and its client gets the world's error
    status, stats = await asyncio.to_thread(json_call, d.http, "GET",
                                            f"/v1/stats?world={BIG_WORLD}")
    rebuilding = RecordingClient(d.ws, name="rebuilding-spectator", world=BIG_WORLD)
    await rebuilding.connect()
    await rebuilding.ws.send(json.dumps(tp.spectate(*WINDOW, stats["tick"], speed=1)))
    alive = metric_value(d.metrics()[1], "terrad_spectators")
    status, doc = await asyncio.to_thread(json_call, d.http, "DELETE",
                                          f"/v1/worlds/{BIG_WORLD}")
    check(status in (200, 204), f"DELETE /v1/worlds/{BIG_WORLD} under a live spectator and one "
                                f"rebuilding ({status} {doc})")
    for c, what in ((s, "the stepping spectator"), (rebuilding, "the rebuilding spectator")):
        await c.wait_for(lambda: c.errors, WAIT)
        why = c.errors[0].get("message", "") if c.errors else ""
        check(c.errors and c.errors[0].get("name") == "shutting_down" and "deleted" in why,
              f"{what} is told its world was deleted ({c.errors[:1]})")
    check(await asyncio.to_thread(wait_until, lambda: not metric_value(
        d.metrics()[1], "terrad_spectators")),
        f"its replay thread ended ({alive} alive before)")
    await other.unsubscribe(next(iter(other.mirrors)))
    again = await other.subscribe(*REGION)
    check(again and d.stats()["ready"], "a client of another world and the daemon go on")
    await other.close()
    for c in (s, rebuilding):
        try:
            await c.close()
        except Exception:  # noqa: BLE001 - closed by the server after the error
            pass


async def worlds_run(d):
    await larger_world(d)
    await deleted_under_spectator(d)


def main():
    scene = cd.scene_file()
    data = tempfile.mkdtemp(prefix="terrad-spectate-")
    big_data = tempfile.mkdtemp(prefix="terrad-spectate-big-")
    try:
        with check.running(Daemon(data_dir=data, extra=["--scene", scene] + SEGMENT + RETAIN,
                                  durability="every-tick")) as d:
            asyncio.run(retained_run(d))
        with check.running(Daemon(extra=["--scene", scene] + SEGMENT)) as d:
            asyncio.run(gone_run(d))
        with check.running(Daemon(extra=["--scene", scene] + RETAIN,
                                  config={"limits": {"max_spectators": 1}})) as d:
            asyncio.run(one_spectator(d))
        with check.running(Daemon(data_dir=big_data, extra=["--scene", scene] + RETAIN)) as d:
            asyncio.run(worlds_run(d))
        with check.running(Daemon(extra=["--scene", scene, "--no-data"])) as d:
            asyncio.run(memory_only(d))
    finally:
        os.unlink(scene)
        shutil.rmtree(data, ignore_errors=True)
        shutil.rmtree(big_data, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
