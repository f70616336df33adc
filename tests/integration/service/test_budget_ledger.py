#!/usr/bin/python3
# ctest-timeout: 900
"""A budgeted client's ledger of snapshot pieces (net_budget.c; PROTOCOL.md
"Budgets"), on the real daemon over loopback serving its default world (dunes,
512 × 512):

- a client with a 20,000 bytes/s budget asking for base snapshots
  (PROTOCOL.md "Base snapshots") of the whole untouched world gets a complete
  mirror equal to GET /v1/heights: its pieces of untouched tiles are 37 bytes
  each, and a snapshot frame of dozens of them must still be taken into the
  ledger;
- (a second daemon, max_pending_bytes 65,536) a client with the smallest
  budget, 1024 bytes/s, holding a 128 × 128 subscription, subscribes to the
  same window again and unsubscribes 150 times, 40 ms apart: a newer snapshot
  piece replaces the waiting one it covers and an unsubscribe drops the
  pieces no subscription takes, so what the daemon owes the client stays
  bounded: its fullest second (the daemon's line when it leaves) is within
  max_pending_bytes, and its mirror ends equal to GET /v1/heights;
- (a third daemon, checksum_interval_ticks 1) a client with a 1024 bytes/s
  budget subscribes to a 128 × 128 window whose snapshot pieces (one 64 × 64
  tile each, a few kB) are larger than a second's budget: a CHECKSUM frame
  every tick must not keep the window from ever emptying of tile data, so
  the pieces go (one a second, overruns) and the mirror ends equal to
  GET /v1/heights;
- (a fourth daemon) a client with a 1024 bytes/s budget and base snapshots
  holding the whole 512 × 512 world (64 tiles: a CHECKSUM of all of them,
  1,298 bytes, never fits its window) gets CHECKSUM frames of as many tiles
  as fit, in turn, and a height corrupted behind its back is found and
  repaired: its mirror ends equal to GET /v1/heights. Without the turns no
  CHECKSUM ever reached it and desync repair never ran.

Without the change: sizing the ledger's decode by 39 bytes a rectangle (the
old guess) fails the base-snapshot frames (TOO_LARGE), the client is resynced
again and again and its mirror never completes; without replacing waiting
pieces every subscribe adds a snapshot's worth to the ledger, sent a tile's
pile at a time: the fullest second held 1,118,670 bytes. Without droppable
frames (CHECKSUM, COLLIDERS, FOOTPRINTS) yielding to an owed ledger entry and
an entry larger than the budget going once the window holds no tile data,
the checksums kept the window busy and no piece ever went: the mirror stayed
empty (versions 0) for 120 s, while the daemon sent the client a CHECKSUM
for the tiles it thought current.
"""
import asyncio
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "support"))
sys.path.insert(0, HERE)
from service_harness import Checks, Daemon, skip  # noqa: E402
from test_budget import fullest_second  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
BUDGET = 20000
PENDING = 65536


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
    check(world.get("snapshot_base") is True,
          f"base snapshots agreed ({world.get('snapshot_base')})")
    rect = (0, 0, world["width"], world["height"])
    sid = await c.subscribe(*rect)
    ok = await wait_exact(c, sid, d.heights(*rect)[1], 90)
    check(ok, f"a budgeted base-snapshot client's mirror of the whole untouched world "
          f"{rect[2]} x {rect[3]} is complete and equals GET /v1/heights")
    await c.close()


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
    peak, _ = await fullest_second(d, "pile", 1024, 30)
    print(f"pile-up: the fullest second held {peak} bytes", flush=True)
    check(peak is not None and peak <= PENDING,
          f"what the daemon owed the client stayed bounded: its fullest second held {peak} "
          f"bytes (max_pending_bytes {PENDING})")


async def checksum_storm(d):
    c = tp.TerradClient(d.ws, name="storm", budget=1024)
    world = await c.connect()
    rect = (0, 0, min(128, world["width"]), min(128, world["height"]))
    sid = await c.subscribe(*rect)
    ok = await wait_exact(c, sid, d.heights(*rect)[1], 120)
    check(ok, "with a CHECKSUM every tick, a 1024 bytes/s client's mirror of 128 x 128 is "
          f"complete and equals GET /v1/heights (versions {c.mirrors[sid].versions})")
    await c.close()


async def checksum_turns(d):
    c = tp.TerradClient(d.ws, name="turns", budget=1024, base_snapshots=True)
    world = await c.connect()
    rect = (0, 0, world["width"], world["height"])
    sid = await c.subscribe(*rect)
    want = d.heights(*rect)[1]
    check(await wait_exact(c, sid, want, 120), "the 1024 bytes/s client's base-snapshot mirror of "
          "the whole world is complete")
    await c.wait_for(lambda: c.desync["checksum_frames"] >= 3, 120)
    check(c.desync["checksum_frames"] >= 3 and c.desync["tiles_differing"] == 0,
          f"it gets CHECKSUM frames though a whole window's does not fit its budget ({c.desync})")
    m = c.mirrors[sid]
    m.heights[300 * rect[2] + 400] -= 3  # behind the client's back: tile (6, 4)
    ok = await wait_exact(c, sid, want, 120)
    check(ok and c.desync["tiles_differing"] >= 1 and c.desync["tiles_resynced"] >= 1,
          f"a corrupted height is found and repaired within its turns ({c.desync})")
    await c.close()


def run():
    try:
        d = Daemon()
    except FileNotFoundError as e:
        skip(f"no daemon binary: {e}")
        return
    with check.running(d):
        asyncio.run(asyncio.wait_for(base_join(d), 150))
    with check.running(Daemon(config={"limits": {"max_pending_bytes": PENDING}})) as d2:
        asyncio.run(asyncio.wait_for(pile_up(d2), 240))
    with check.running(Daemon(config={"limits": {"checksum_interval_ticks": 1}})) as d3:
        asyncio.run(asyncio.wait_for(checksum_storm(d3), 150))
    with check.running(Daemon()) as d4:
        asyncio.run(asyncio.wait_for(checksum_turns(d4), 330))
    check.finish()


if __name__ == "__main__":
    run()
