#!/usr/bin/python3
# ctest-timeout: 600
"""Base snapshots (issue 32 item 2, PROTOCOL.md "Base snapshots"): a late joiner whose
hello asks for `snapshot_base` gets its snapshots as the heights less the scene's base
terrain, which it rebuilds with the twin library, and ends with exactly the server's
heights. Against the real daemon, a dunes world (a base that is not a constant) dug by
craters and by a rolling wheel:

- the C client (terrad_client_connect_base, through tests/support/c_join_probe) and the
  Python client (Client(base_snapshots=True)) join a window that cuts tiles and the whole
  world: each mirror equals GET /v1/heights bit for bit; the world message says
  `snapshot_base: true` and carries the base's twin config;
- the snapshot rectangles a base client gets are encoding 2 (and fewer bytes than an
  absolute snapshot of the same window); a client that does not ask (an old client) gets
  encoding 1 only, and its mirror is exact too;
- after joining, deltas go on from the snapshot's versions: more craters and rolling, and
  the base client's mirror still equals /v1/heights;
- a world whose base the twin cannot make (a raw file base) answers `snapshot_base: false`
  and sends absolute snapshots to the client that asked; its mirror is exact;
- slope snapshots (PROTOCOL.md "Slope snapshots"): with a sand pile at its slope limits
  stamped into one tile (64..127 squared), a client whose hello also offers
  `snapshot_slope` (the C client's terrad_client_connect_slope, Python's
  slope_snapshots=True) is told `snapshot_slope: true`, gets encoding 3 for that tile
  (and 2 or 3 elsewhere, the shorter), fewer bytes than encoding 2 alone, and ends exact,
  before and after more craters; a client offering it without `snapshot_base` is told
  false and gets encoding 1; a file base is told false;
- bad input: `snapshot_base` or `snapshot_slope` not a boolean is refused with bad_value
  naming the field, counted in terrad_refused_messages_total{reason="bad_value"}; the daemon
  goes on.

Without the change the base client's snapshots are absolute (no encoding 2: fails), and
with the base left in the server's differences the mirrors differ from /v1/heights. With
the server never sending encoding 3 the slope checks fail (no encoding 3, bytes equal);
with a decoder's bound off by one the mirrors differ."""
import asyncio
import json
import os
import struct
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (JOIN_PROBE, Checks, Daemon, built, join_probe, json_file,  # noqa: E402
                             metric_value, tp)

check = Checks()
SIDE = 256
WINDOW = (37, 50, 150, 120)  # cuts tiles on every side
SCENE = {"name": "joinbase", "world": {"width": SIDE, "height": SIDE, "cell_size_m": 0.05},
         "terrain": {"kind": "dunes", "min_height_m": 0.2, "max_height_m": 0.6,
                     "wavelength_m": 4, "octaves": 4, "seed": 32},
         "colliders": []}


def craters(d, seed, n, side=SIDE):
    """n craters by the websocket edit message, each acknowledged (applied and logged)."""
    async def go():
        async with tp.Client(d.ws) as c:
            for i in range(n):
                k = seed * 1000 + i
                await c.edit("crater", x=(k * 37) % side, y=(k * 91) % side, radius=4 + k % 12,
                             depth=400 + (k * 53) % 2000)
    asyncio.run(go())


def roll(d):
    """A sphere rolled across the world, pressing a rut, until its last pose is acknowledged."""
    async def go():
        async with tp.Client(d.ws) as c:
            cid = await c.create_collider("sphere", radius=0.4)
            for i in range(120):
                seq = await c.send_poses([tp.Pose(cid, 1.0 + i * 0.08, 6.4 + (i % 7) * 0.01,
                                                  0.5, 1, 0, 0, 0)])
                await asyncio.sleep(0.005)
            await c.wait_ack(seq, timeout=60)
            await c.delete_collider(cid)
    asyncio.run(go())


async def python_join(d, rect, base, slope=False):
    """A Python client joins rect (offering slope snapshots when slope): (its world message,
    the client for more, the subscription, the encodings of every snapshot rectangle it was
    sent)."""
    c = tp.Client(d.ws, base_snapshots=base, slope_snapshots=slope)
    encodings = []
    c.on(tp.MsgType.DELTA, lambda tick, rects: encodings.extend(
        r.encoding for r in rects if r.encoding != tp.Encoding.DELTA))
    world = await c.connect()
    sid = await c.subscribe(*rect)
    for _ in range(2400):
        if c.mirrors[sid].complete:
            break
        await asyncio.sleep(0.05)
    return world, c, sid, encodings


def heights(d, rect):
    return d.heights(*rect)[1]


PILE = (64, 64, 64, 64)  # tile (1, 1), inside WINDOW


def stamp_pile(d):
    """Tile (1, 1) set to its base plus a sand pile: the lowest of cones 300 units a cell
    steep axially, 420 diagonally (under the slope stage's thresholds, so it stays), from
    seeded apexes: almost every cell sits at a bound of its neighbours (encoding 3's case)."""
    x0, y0, w, h = PILE
    status, body, _ = d.get_busy(f"/v1/heights?x={x0}&y={y0}&w={w}&h={h}&base=1")
    check(status == 200, f"the pile's base ({status})")
    base = struct.unpack(f"<{w * h}i", body)
    apexes = [((k * 29) % w, (k * 47) % h, -600 + (k * 173) % 500) for k in range(9)]
    values = []
    for y in range(h):
        for x in range(w):
            z = min(c + 300 * (max(abs(x - ax), abs(y - ay)) - min(abs(x - ax), abs(y - ay)))
                    + 420 * min(abs(x - ax), abs(y - ay)) for ax, ay, c in apexes)
            values.append(base[y * w + x] + z)

    async def go():
        async with tp.Client(d.ws) as c:
            await c.edit("stamp", x=x0, y=y0, w=w, h=h, data=tp.stamp_data(values))
    asyncio.run(go())


def test_joins(d):
    craters(d, 1, 60)
    roll(d)
    stamp_pile(d)
    for rect in (WINDOW, (0, 0, SIDE, SIDE)):
        want = heights(d, rect)
        for mode in ("slope", "base", "plain"):
            line, got = join_probe(d, rect, mode)
            check(line is not None and line["base_on"] == (mode != "plain") and
                  line["slope_on"] == (mode == "slope"),
                  f"C {mode} join of {rect}: the server agreed to base (and slope) snapshots "
                  f"({line})")
            check(got == want, f"C {mode} join of {rect}: the mirror equals /v1/heights")
        if rect == WINDOW:
            s, b, p = (join_probe(d, rect, m)[0] for m in ("slope", "base", "plain"))
            check(b and p and b["bytes"] < p["bytes"],
                  f"a base join of a dug window takes fewer bytes ({b}, {p})")
            check(s and b and s["bytes"] < b["bytes"],
                  f"a slope join of a window with a sand pile takes fewer bytes ({s}, {b})")

    async def python():
        for base, slope in ((True, True), (True, False), (False, False), (False, True)):
            world, c, sid, encodings = await python_join(d, WINDOW, base, slope)
            try:
                check(world.get("snapshot_base") is (True if base else None),
                      f"Python base={base}: the world message's snapshot_base "
                      f"({world.get('snapshot_base')})")
                check(world.get("snapshot_slope") is (base if slope else None),
                      f"Python base={base} slope={slope}: the world message's snapshot_slope "
                      f"({world.get('snapshot_slope')})")
                check(not base or (isinstance(world.get("base"), dict) and
                                   world["base"].get("terrain.kind") == "dunes"),
                      "the world message carries the base's twin config")
                check(c.mirrors[sid].complete, f"Python base={base}: the mirror completes")
                check(c.mirrors[sid].heights == heights(d, WINDOW),
                      f"Python base={base}: the mirror equals /v1/heights")
                if base and slope:  # the pile's tile in encoding 3, the others the shorter
                    want = {int(tp.Encoding.BASE), int(tp.Encoding.BASE_SLOPE)}
                    check(set(encodings) <= want and int(tp.Encoding.BASE_SLOPE) in encodings,
                          f"Python slope: its snapshot rectangles are encodings 2 and 3, 3 "
                          f"among them (got {sorted(set(encodings))})")
                else:
                    want = {int(tp.Encoding.BASE)} if base else {int(tp.Encoding.SNAPSHOT)}
                    check(set(encodings) == want,
                          f"Python base={base} slope={slope}: its snapshot rectangles are "
                          f"encoding {want} (got {sorted(set(encodings))})")
                if base:  # deltas after the join go on from the snapshot's versions
                    await c.edit("crater", x=WINDOW[0] + 40, y=WINDOW[1] + 30, radius=9,
                                 depth=1500)
                    await c.edit("crater", x=WINDOW[0] + 100, y=WINDOW[1] + 70, radius=6,
                                 depth=900)
                    want_after = heights(d, WINDOW)
                    for _ in range(2400):  # 120 s: generous, a loaded machine reads late
                        if c.mirrors[sid].heights == want_after:
                            break
                        await asyncio.sleep(0.05)
                    check(c.mirrors[sid].heights == want_after,
                          f"after two more craters the base client's mirror (slope={slope}) "
                          "equals /v1/heights")
            finally:
                await c.close()
    asyncio.run(python())


def test_bad_input(d):
    async def go(field):
        ws = await tp.client._websockets().connect(d.ws, subprotocols=[tp.SUBPROTOCOL])
        try:
            await ws.send(json.dumps({"type": "hello", "protocol": 1, "token": "",
                                      "client": "bad", "snapshot_base": True, field: "yes"}))
            msg = json.loads(await ws.recv())
        finally:
            await ws.close()
        return msg
    for field in ("snapshot_base", "snapshot_slope"):
        _, before = d.metrics()
        msg = asyncio.run(go(field))
        check(msg.get("type") == "error" and msg.get("name") == "bad_value" and
              field in msg.get("message", ""),
              f"a hello with {field} \"yes\" is refused naming the field ({msg})")
        _, after = d.metrics()
        check(metric_value(after, "terrad_refused_messages_total", {"reason": "bad_value"}) >
              metric_value(before, "terrad_refused_messages_total", {"reason": "bad_value"}),
              f"the refusal of {field} is counted in "
              "terrad_refused_messages_total{reason=\"bad_value\"}")
    for mode in ("base", "slope"):
        line, got = join_probe(d, WINDOW, mode)
        check(got == heights(d, WINDOW), f"the daemon goes on: a {mode} join after it is exact")


def test_file_base():
    """A raw file base: the twin cannot rebuild it, so the client is told no and gets
    absolute snapshots."""
    side = 128
    with tempfile.NamedTemporaryFile(prefix="terrad-base-", suffix=".raw", delete=False) as f:
        f.write(struct.pack(f"<{side * side}h", *[(i * 13) % 3000 for i in range(side * side)]))
        raw = f.name
    scene = {"name": "filebase", "world": {"width": side, "height": side, "cell_size_m": 0.05},
             "terrain": {"kind": "raw_int16", "path": raw}, "colliders": []}
    path = json_file(scene, "terrad-filebase")
    try:
        with check.running(Daemon(extra=["--scene", path])) as d:
            craters(d, 2, 10, side)

            async def go():
                world, c, sid, encodings = await python_join(d, (0, 0, side, side), True, True)
                try:
                    check(world.get("snapshot_base") is False and "base" not in world,
                          f"a file base: snapshot_base false, no base ({world.get('snapshot_base')})")
                    check(world.get("snapshot_slope") is False,
                          f"a file base: snapshot_slope false ({world.get('snapshot_slope')})")
                    check(set(encodings) == {int(tp.Encoding.SNAPSHOT)},
                          f"a file base: absolute snapshots ({sorted(set(encodings))})")
                    check(c.mirrors[sid].heights == heights(d, (0, 0, side, side)),
                          "a file base: the mirror equals /v1/heights")
                finally:
                    await c.close()
            asyncio.run(go())
            line, got = join_probe(d, (0, 0, side, side), "base")
            check(line is not None and line["base_on"] == 0 and
                  got == heights(d, (0, 0, side, side)),
                  f"a file base: the C client is told no and its mirror is exact ({line})")
    finally:
        os.unlink(path)
        os.unlink(raw)


def main():
    built(JOIN_PROBE)
    path = json_file(SCENE, "terrad-joinbase")
    try:
        with check.running(Daemon(extra=["--scene", path])) as d:
            test_joins(d)
            test_bad_input(d)
    finally:
        os.unlink(path)
    test_file_base()
    return check.finish()


if __name__ == "__main__":
    sys.exit(main())
