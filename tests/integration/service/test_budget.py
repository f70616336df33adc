#!/usr/bin/python3
# ctest-timeout: 600
"""A bandwidth budget per player (issue 32 item 1; PROTOCOL.md "Budgets"), on
the real daemon over loopback with a driver client cratering a 512 × 256
window of its default world (edits: deterministic, and the terrain is settled
the moment they stop):

- a hello stating a budget over the daemon's max_budget_bytes_per_s, under the
  smallest budget, or not an integer is refused with bad_value naming
  `budget` (terrad_refused_messages_total counts it), the connection stays
  open for a better hello, and the driver's edits go on being answered;
- a watcher with a 20,000 bytes/s budget subscribed to the window: the
  server's own accounting never puts more than the budget into one second
  (terrad_budget_overruns_total stays 0, and the daemon's line for the
  client, when it leaves, names its fullest second, at most the budget);
  what it received over the run is within the budget's bound too, while a
  watcher stating none (given the limit, 64 KiB/s) of the same window
  receives more than that bound (so the budget did bind) and deltas were
  coalesced;
- far regions arrive later, but once the edits stop the budgeted mirror
  becomes equal to GET /v1/heights (generous deadline);
- a `focus` outside the world is refused naming `x`; a valid one is taken;
- a budgeted client asking for base snapshots (PROTOCOL.md "Base snapshots")
  of the whole untouched world gets a complete mirror equal to
  GET /v1/heights: its pieces of untouched tiles are a few dozen bytes each,
  and a snapshot frame of many of them must still be taken into the ledger;
- (a second daemon, max_pending_bytes 65,536) a client with the smallest
  budget, 1024 bytes/s, holding a 128 × 128 subscription, subscribes to the
  same window again and unsubscribes 150 times, 40 ms apart: a newer snapshot
  piece replaces the waiting one and an unsubscribe drops its pieces, so
  what the daemon holds for it stays bounded: its fullest second (the
  daemon's line when it leaves) is within max_pending_bytes, and its mirror
  ends equal to GET /v1/heights.

Without the budget (the change undone) the over-limit hello is accepted and
the budgeted watcher receives what the unbudgeted one does, past its bound.
Sizing the ledger's decode by 39 bytes a rectangle (the old guess) fails the
base-snapshot client's frames (TOO_LARGE): it is resynced again and again and
its mirror never completes. Without replacing waiting pieces every subscribe
adds a snapshot's worth to the ledger, sent a tile's pile at a time: the
fullest second held megabytes.
"""
import asyncio
import json
import os
import random
import re
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value, skip  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
BUDGET = 20000
LIMIT = 65536
REGION = (0, 0, 512, 256)
DIG_S = 8.0


class CountingClient(tp.TerradClient):
    """Counts the bytes of every frame it reads (binary and text)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.bytes = 0

    async def _on_binary(self, data):
        self.bytes += len(data) + (2 if len(data) < 126 else 4 if len(data) < 65536 else 10)
        await super()._on_binary(data)

    async def _on_json(self, text):
        self.bytes += len(text) + (2 if len(text) < 126 else 4)
        await super()._on_json(text)


async def raw_hello(d, extra):
    """A hello with extra fields: (the answer, a second hello's answer on the same socket)."""
    import websockets
    ws = await websockets.connect(d.ws, subprotocols=[tp.SUBPROTOCOL], close_timeout=2)
    try:
        await ws.send(json.dumps({**tp.hello("", "budget-check"), **extra}))
        first = json.loads(await asyncio.wait_for(ws.recv(), 30))
        await ws.send(json.dumps(tp.hello("", "budget-check", budget=BUDGET)))
        second = json.loads(await asyncio.wait_for(ws.recv(), 30))
        return first, second
    finally:
        await ws.close()


async def refusals(d):
    before = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"})
    for extra, what in (({"budget": LIMIT + 1}, "over max_budget_bytes_per_s"),
                        ({"budget": 100}, "under the smallest budget"),
                        ({"budget": "lots"}, "not an integer")):
        first, second = await raw_hello(d, extra)
        check(first.get("type") == "error" and first.get("code") == 5 and
              "budget" in first.get("message", ""),
              f"a hello with a budget {what} is refused with bad_value naming budget: {first}")
        check(second.get("type") == "world" and second.get("budget") == BUDGET,
              f"the same connection's next hello, within the limit, is taken: {second}")
    after = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"})
    check(after - before >= 3, f"the refusals are counted ({before} -> {after})")


async def dig(driver, stop_at, rng):
    x0, y0, w, h = REGION
    sent = 0
    while time.monotonic() < stop_at:
        await driver.ws.send(json.dumps(tp.edit("crater", x=rng.randrange(x0 + 8, x0 + w - 8),
                                                y=rng.randrange(y0 + 8, y0 + h - 8),
                                                radius=rng.randrange(3, 8),
                                                depth=rng.randrange(200, 2000))))
        sent += 1
        await asyncio.sleep(0.05)
    return sent


async def wait_exact(c, sid, want, seconds):
    """Whether c's mirror sid becomes complete and equal to want within seconds."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        m = c.mirrors.get(sid)
        if m is not None and m.complete and list(m.heights) == want:
            return True
        await asyncio.sleep(0.25)
    return False


async def base_join(d):
    c = tp.TerradClient(d.ws, name="base-budgeted", budget=BUDGET, base_snapshots=True)
    world = await c.connect()
    check(world.get("snapshot_base") is True, f"base snapshots agreed ({world.get('snapshot_base')})")
    rect = (0, 0, world["width"], world["height"])
    sid = await c.subscribe(*rect)
    ok = await wait_exact(c, sid, d.heights(*rect)[1], 90)
    check(ok, f"a budgeted base-snapshot client's mirror of the whole untouched world "
          f"{rect[2]} x {rect[3]} is complete and equals GET /v1/heights")
    await c.close()


async def fullest_second(d, budget):
    """The daemon's line for a budgeted client that left: its fullest second, bytes."""
    end = time.monotonic() + 30
    while time.monotonic() < end:
        for line in d.lines:
            m = re.search(rf"budget {budget} bytes/s, \d+ bytes sent, the fullest second held "
                          rf"(\d+)", line)
            if m:
                return int(m.group(1))
        await asyncio.sleep(0.2)
    return None


PENDING = 65536


async def pile_up(d):
    c = tp.TerradClient(d.ws, name="pile", budget=1024)
    world = await c.connect()
    rect = (0, 0, min(128, world["width"]), min(128, world["height"]))
    keep = await c.subscribe(*rect)
    for _ in range(150):
        sid = await c.subscribe(*rect)
        await asyncio.sleep(0.04)
        await c.unsubscribe(sid)
    ok = await wait_exact(c, keep, d.heights(*rect)[1], 120)
    check(ok, "after 150 subscribe/unsubscribe rounds under a 1024 bytes/s budget the kept "
          "subscription's mirror equals GET /v1/heights")
    await c.close()
    peak = await fullest_second(d, 1024)
    print(f"pile-up: the fullest second held {peak} bytes", flush=True)
    check(peak is not None and peak <= PENDING,
          f"the daemon held what it owed the client within max_pending_bytes: its fullest "
          f"second {peak} bytes (max_pending_bytes {PENDING})")


async def main(d):
    await refusals(d)
    await base_join(d)
    rng = random.Random(32)
    driver = tp.TerradClient(d.ws, name="driver")
    await driver.connect()
    free = CountingClient(d.ws, name="wide")  # states none: gets max_budget_bytes_per_s
    await free.connect()
    budgeted = CountingClient(d.ws, name="budgeted", budget=BUDGET)
    await budgeted.connect()
    check(budgeted.world.get("budget") == BUDGET,
          f"the world message says the budget in force ({budgeted.world.get('budget')})")
    check(free.world.get("budget") == LIMIT,
          f"a client stating none gets the limit, the default being none "
          f"({free.world.get('budget')})")
    check(budgeted.world.get("limits", {}).get("max_budget_bytes_per_s") == LIMIT,
          "the world message's limits tell max_budget_bytes_per_s")

    # focus: a point outside the world is refused naming x, the client goes on
    await budgeted.ws.send(json.dumps({"type": "focus", "x": -5, "y": 10}))
    await budgeted.wait_for(lambda: budgeted.errors, 30)
    err = budgeted.errors[-1]
    check(err.get("code") == 5 and err.get("message", "").startswith("x:"),
          f"a focus outside the world is refused naming x: {err}")
    await budgeted.focus(32, 32)

    start = time.monotonic()
    b0, f0 = budgeted.bytes, free.bytes
    sid_b = await budgeted.subscribe(*REGION)
    sid_f = await free.subscribe(*REGION)
    await free.wait_complete(sid_f, 60)
    sent = await dig(driver, time.monotonic() + DIG_S, rng)
    # every edit applied: the driver's last one is answered, so the terrain has settled
    last = await driver.edit("add", x=1, y=1, w=2, h=2, amount=1)
    dig_end = time.monotonic()
    elapsed = dig_end - start
    bound = BUDGET * (elapsed + 1.0)
    got_b, got_f = budgeted.bytes - b0, free.bytes - f0
    print(f"{sent} craters in {elapsed:.1f} s: budgeted watcher {got_b} bytes "
          f"(bound {bound:.0f}), wide {got_f}", flush=True)
    check(got_b <= bound, f"the budgeted watcher got {got_b} bytes in {elapsed:.1f} s, within "
          f"its budget's bound {bound:.0f}")
    check(got_f > bound, f"the wider watcher got more ({got_f}): the budget did bind")
    text = d.metrics()[1]
    check(metric_value(text, "terrad_budget_overruns_total") == 0,
          "no second of the budgeted watcher held more than its budget (server's accounting)")
    check(metric_value(text, "terrad_budget_deltas_coalesced_total") > 0,
          "deltas were coalesced for the budgeted watcher")

    # settled: the budgeted mirror converges to the server's heights
    _, server = d.heights(*REGION)
    check(d.heights(*REGION)[1] == server, "the terrain is settled after the last edit")
    same = await wait_exact(budgeted, sid_b, server, 180)
    print(f"budgeted mirror exact {time.monotonic() - dig_end:.1f} s after the last edit "
          f"(tick {last['tick']})", flush=True)
    check(same, "the budgeted watcher's mirror equals GET /v1/heights once the edits stop")
    await free.wait_for(lambda: list(free.mirrors[sid_f].heights) == server, 60)
    check(list(free.mirrors[sid_f].heights) == server, "the wider watcher's mirror is exact too")
    # desync detection (PROTOCOL.md "CHECKSUM") compares only the tiles current for a client: a
    # budgeted watcher's held-back far tiles are left out, so no tile ever differed (were they
    # compared, their older versions would)
    await budgeted.wait_for(lambda: budgeted.desync["checksum_frames"] >= 2, 60)
    check(budgeted.desync["checksum_frames"] >= 2 and budgeted.desync["tiles_differing"] == 0,
          f"the budgeted watcher's CHECKSUM frames found no tile differing ({budgeted.desync})")
    for c in (budgeted, free, driver):
        await c.close()
    # the daemon's own line for the budgeted client: its fullest second
    peak = await fullest_second(d, BUDGET)
    check(peak is not None and 0 < peak <= BUDGET,
          f"the daemon's accounting: the budgeted client's fullest second held {peak} bytes "
          f"(budget {BUDGET})")


def run():
    config = {"limits": {"max_budget_bytes_per_s": LIMIT}}
    try:
        d = Daemon(config=config)
    except FileNotFoundError as e:
        skip(f"no daemon binary: {e}")
        return
    with check.running(d):
        asyncio.run(asyncio.wait_for(main(d), 360))
    config["limits"]["max_pending_bytes"] = PENDING
    with check.running(Daemon(config=config)) as d2:
        asyncio.run(asyncio.wait_for(pile_up(d2), 300))
    check.finish()


if __name__ == "__main__":
    run()
