#!/usr/bin/python3
# ctest-timeout: 600
"""A bandwidth budget per player (issue 32 item 1; PROTOCOL.md "Budgets"), on
the real daemon over loopback serving a flat 512 × 256 world (its snapshots
small), with a driver client cratering it in two bursts of 200 large craters
(each burst's deltas, 60-85 KB measured, more than the budget however fast the
machine; edits: deterministic, and the terrain is settled the moment they stop):

- a hello stating a budget over the daemon's max_budget_bytes_per_s, under the
  smallest budget, or not an integer is refused with bad_value naming
  `budget` (terrad_refused_messages_total counts it), the connection stays
  open for a better hello, and the driver's edits go on being answered;
- a watcher with a 20,000 bytes/s budget subscribed to the world: the
  server's own accounting never puts more than the budget into one second
  (terrad_budget_overruns_total stays 0, and the daemon's line for the
  client, when it leaves, names its fullest second, at most the budget);
  what it received over the run is within the budget's bound too; deltas were
  coalesced for it (metric and its line); a watcher stating none (given the
  limit, 64 KiB/s, so budgeted too) of the same window had a second fuller than
  the budget by the daemon's line for it: the budget did bind;
- far regions arrive later, but once the edits stop the budgeted mirror
  becomes equal to GET /v1/heights (generous deadline);
- a `focus` outside the world is refused naming `x`; a valid one is taken.

Without the budget (the change undone) the over-limit hello is accepted and
the budgeted watcher receives what the wider one does (120-175 KB measured),
past its bound and its budget in one second, with nothing coalesced.
"""
import asyncio
import json
import os
import random
import re
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, CountingClient, Daemon, json_file, metric_value, skip  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
BUDGET = 20000
LIMIT = 65536
REGION = (0, 0, 512, 256)
# 400 craters and the driver's hello and last edit: under the rate limit's burst (480
# messages), however fast they are sent
BURSTS = 2
PER_BURST = 200
# flat: the subscribe's snapshots are small, so the data over the budget is the craters'
SCENE = {"name": "budget", "world": {"width": 512, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}


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


def crater(rng):
    x0, y0, w, h = REGION
    return tp.edit("crater", x=rng.randrange(x0, x0 + w), y=rng.randrange(y0, y0 + h),
                   radius=rng.randrange(20, 50), depth=rng.randrange(1000, 6000))


async def dig(driver, rng):
    """BURSTS bursts of PER_BURST craters, each burst sent at once and its last crater's
    answer awaited (edits are applied in order: the whole burst is), so the amount of data
    is the same however fast the machine is, and one burst's deltas, arriving within a tick
    or two, are more than BUDGET bytes (the wider client's fullest second tells)."""
    for i in range(BURSTS):
        if i:  # a second apart, as a slow machine would send them: each burst alone must do
            await asyncio.sleep(1.5)
        for _ in range(PER_BURST - 1):
            await driver.ws.send(json.dumps(crater(rng)))
        await driver.request(crater(rng), "edited", timeout=120)
    return BURSTS * PER_BURST


async def fullest_second(d, name, budget, deadline_s=120):
    """The daemon's line for the client that said hello as name (its id read from its hello
    line), written when it leaves (net_budget_free): (the bytes its fullest second held, the
    deltas coalesced for it), or (None, None) when no such line came within deadline_s."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        lines = list(d.lines)
        ids = [m.group(1) for m in (re.search(rf'net: client (\d+) \(.*\) said hello as "{name}"', line)
                                    for line in lines) if m]
        for line in lines:
            m = re.search(r"net: client (\d+) .*: budget (\d+) bytes/s, \d+ bytes sent, the fullest "
                          r"second held (\d+), (\d+) deltas coalesced", line)
            if m and m.group(1) in ids and int(m.group(2)) == budget:
                return int(m.group(3)), int(m.group(4))
        await asyncio.sleep(0.2)
    return None, None


async def main(d):
    await refusals(d)
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
    snap_f = free.bytes - f0
    sent = await dig(driver, rng)
    # every edit applied: the driver's last one is answered, so the terrain has settled
    last = await driver.request(tp.edit("add", x=1, y=1, w=2, h=2, amount=1), "edited",
                                timeout=120)
    dig_end = time.monotonic()
    elapsed = dig_end - start
    bound = BUDGET * (elapsed + 1.0)
    got_b, got_f = budgeted.bytes - b0, free.bytes - f0
    print(f"{sent} craters in {elapsed:.1f} s: budgeted watcher {got_b} bytes "
          f"(bound {bound:.0f}), wide {got_f} ({snap_f} of them its snapshot)", flush=True)
    check(got_b <= bound, f"the budgeted watcher got {got_b} bytes in {elapsed:.1f} s, within "
          f"its budget's bound {bound:.0f}")
    text = d.metrics()[1]
    check(metric_value(text, "terrad_budget_overruns_total") == 0,
          "no second of the budgeted watcher held more than its budget (server's accounting)")
    check(metric_value(text, "terrad_budget_deltas_coalesced_total") > 0,
          "deltas were coalesced for the budgeted watcher (a burst's deltas exceed its budget)")

    # settled: the budgeted mirror converges to the server's heights
    _, server = d.heights(*REGION)
    check(d.heights(*REGION)[1] == server, "the terrain is settled after the last edit")
    deadline = time.monotonic() + 180
    same = False
    while time.monotonic() < deadline:
        m = budgeted.mirrors.get(sid_b)
        if m is not None and m.complete and list(m.heights) == server:
            same = True
            break
        await asyncio.sleep(0.25)
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
    # the daemon's own lines (net_budget_free, as each client leaves): the budgeted client's
    # fullest second is within its budget, while the wider one (budgeted too, at LIMIT) had
    # a second fuller than BUDGET: the same data, unbudgeted, would not have fitted, so the
    # budget did bind
    peak, coalesced = await fullest_second(d, "budgeted", BUDGET)
    check(peak is not None and 0 < peak <= BUDGET,
          f"the daemon's accounting: the budgeted client's fullest second held {peak} bytes "
          f"(budget {BUDGET})")
    check(coalesced is not None and coalesced > 0,
          f"the daemon's accounting: deltas were coalesced for the budgeted client ({coalesced})")
    wide_peak, _ = await fullest_second(d, "wide", LIMIT)
    print(f"fullest second: budgeted {peak}, wide {wide_peak}; coalesced {coalesced}", flush=True)
    check(wide_peak is not None and BUDGET < wide_peak <= LIMIT,
          f"the wider client's fullest second held {wide_peak} bytes, more than {BUDGET} "
          f"(within its limit {LIMIT}): the budget did bind")


def run():
    config = {"limits": {"max_budget_bytes_per_s": LIMIT}}
    path = json_file(SCENE, "terrad-budget")
    try:
        try:
            d = Daemon(config=config, extra=["--scene", path])
        except FileNotFoundError as e:
            skip(f"no daemon binary: {e}")
            return
        with check.running(d):
            asyncio.run(asyncio.wait_for(main(d), 540))
    finally:
        os.unlink(path)
    check.finish()


if __name__ == "__main__":
    run()
