#!/usr/bin/python3
# ctest-timeout: 900
"""A budgeted client's summed deltas held between snapshot pieces (net_budget.c;
PROTOCOL.md "Budgets"), on the real daemon over loopback serving its default world (dunes,
512 x 512, 64-cell tiles), a client with a 1024 bytes/s budget and absolute snapshots:
its whole-world subscription's 64 pieces (a few kB each, more than a second's budget) go
one a second, nearest its focus first (the world's centre), so the corner tile (0, 0)'s
piece P1 waits in the ledger for most of a minute. Meanwhile another client digs tile
(0, 0): its deltas fold into the ledger's sum, and the budgeted client subscribes to a
second rectangle inside that tile (0, 0, 40, 40), whose piece P2 comes at the tile's
latest version. The summed delta D must go between P1 and P2 (it takes P1's tile from
P1's version to P2's; sent before P1 the client would skip it, after P2 the first
mirror would miss the digging):

- default limits, craters: the client receives P1, D and P2 as three consecutive DELTA
  frames (the ledger entry sent at once), D from P1's version to P2's, no mirror error,
  and both mirrors end equal to GET /v1/heights;
- max_pending_bytes 4096 and a stamp of noise over the tile (a summed delta of about
  6 kB): the held delta passes max_pending_bytes, so the daemon treats the client as
  slow (its log says so) and sends it fresh snapshots once it has caught up; no mirror
  error, and both mirrors still end equal to GET /v1/heights.

Without the held delta (D sent ahead of P1, or dropped with the pieces it waited between)
the first mirror misses the digging (its tile stays at P1's heights, or a stale_base
resync is needed: a mirror error); without the held bytes counted against
max_pending_bytes the daemon never says the client is slow on their account (the log
check fails). A tile's pending state needs no cap of its own: its pieces are at most one
per subscription rectangle (a newer one replaces what it covers, an unsubscribe prunes),
its sum is one tile of int32s, and the deltas held between pieces are what
max_pending_bytes bounds, as checked here.
"""
import asyncio
import os
import random
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "..", "support"))
sys.path.insert(0, HERE)
from service_harness import Checks, Daemon  # noqa: E402
from test_budget_ledger import wait_exact  # noqa: E402

import terrad as tp  # noqa: E402
from terrad.proto import stamp_data  # noqa: E402

check = Checks()
TILE = (0, 0, 64, 64)  # the corner tile: distance 4 from the focus, among the last pieces
INNER = (0, 0, 40, 40)  # the second subscription: another rectangle of the same tile


async def held(d, dig):
    """The scenario: (the budgeted client's DELTA frames, each a list of its rectangles of
    tile (0, 0) as (encoding, (x, y, w, h), base_version, new_version), whether P1 had
    arrived before the second subscription was answered, the client)."""
    frames = []
    c = tp.TerradClient(d.ws, name="held", budget=1024)
    c.on(tp.MsgType.DELTA, lambda tick, rects: frames.append(
        [(r.encoding, (r.x, r.y, r.w, r.h), r.base_version, r.new_version) for r in rects
         if r.x < TILE[2] and r.y < TILE[3]]))
    world = await c.connect()
    whole = (0, 0, world["width"], world["height"])
    sid_whole = await c.subscribe(*whole)
    await asyncio.sleep(1.5)  # the snapshot staged: P1 waits in the ledger
    async with tp.TerradClient(d.ws, name="digger") as digger:
        await dig(digger)
    sid_inner = await c.subscribe(*INNER)
    early = any(e == tp.Encoding.SNAPSHOT and rect == TILE for f in frames for e, rect, _, _ in f)
    for sid, rect in ((sid_whole, whole), (sid_inner, INNER)):
        ok = await wait_exact(c, sid, d.heights(*rect)[1], 240)
        check(ok, f"the mirror of {rect} is complete and equals GET /v1/heights "
              f"(versions {c.mirrors[sid].versions[:4]}...)")
    check(not c.errors, f"no error: no mirror error, no resync asked by the client ({c.errors[:2]})")
    check(c.desync["tiles_differing"] == 0,
          f"no CHECKSUM found a tile differing (the mirrors never missed a delta: {c.desync})")
    await c.close()
    return frames, early


def between(frames):
    """The index of three consecutive frames P1 (the tile's piece of the whole world), D (a
    delta from P1's version) and P2 (the inner piece at D's new version), or -1."""
    for i in range(len(frames) - 2):
        p1 = [r for r in frames[i] if r[0] == tp.Encoding.SNAPSHOT and r[1] == TILE]
        dd = [r for r in frames[i + 1] if r[0] == tp.Encoding.DELTA]
        p2 = [r for r in frames[i + 2] if r[0] == tp.Encoding.SNAPSHOT and r[1] == INNER]
        if p1 and dd and p2 and dd[0][2] == p1[0][3] and dd[0][3] == p2[0][3]:
            return i
    return -1


async def craters(c):
    for i in range(8):
        await c.edit("crater", x=8 + 6 * i, y=10 + 5 * i, radius=5 + i, depth=600 + 150 * i)


async def noise(c):
    rng = random.Random(32)
    await c.edit("stamp", x=0, y=0, w=64, h=64, mode="add",
                 data=stamp_data([rng.randrange(3000) for _ in range(64 * 64)]))


def client_id(d, name):
    for line in list(d.lines):
        m = re.search(rf'net: client (\d+) \(.*\) said hello as "{name}"', line)
        if m:
            return m.group(1)
    return None


async def between_pieces(d):
    frames, early = await held(d, craters)
    check(not early, "tile (0, 0)'s piece of the whole world still waited when the second "
          "subscription was answered (the scenario's premise)")
    i = between(frames)
    check(i >= 0, "P1, the summed delta from P1's version and P2 at the delta's version came "
          f"as three consecutive frames (tile (0, 0): {[f for f in frames if f][:8]})")


async def held_too_much(d):
    frames, early = await held(d, noise)
    check(not early, "tile (0, 0)'s piece still waited when the second subscription was answered")
    cid = client_id(d, "held")
    lines = [line for line in d.lines if cid and f"client {cid} " in line]
    said = [line for line in lines if "bytes of deltas wait between snapshot pieces" in line]
    check(bool(said), f"the daemon says the deltas held between pieces passed max_pending_bytes "
          f"({said[:1] or lines[-3:]})")
    check(any("is slow" in line for line in lines), "and treats the client as slow")
    snaps = sum(1 for f in frames for e, rect, _, _ in f if e == tp.Encoding.SNAPSHOT and rect == INNER)
    print(f"held too much: {snaps} snapshot piece(s) of {INNER} received", flush=True)


def run():
    with check.running(Daemon(extra=("--no-data",))) as d:
        asyncio.run(asyncio.wait_for(between_pieces(d), 400))
    with check.running(Daemon(extra=("--no-data",), config={"limits": {"max_pending_bytes": 4096}})) as d2:
        asyncio.run(asyncio.wait_for(held_too_much(d2), 400))
    check.finish()


if __name__ == "__main__":
    run()
