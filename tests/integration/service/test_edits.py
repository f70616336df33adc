#!/usr/bin/python3
# ctest-timeout: 600
"""Terrain edits from game logic (issue 22, item 3) against the real daemon:
the websocket `edit` message and POST /v1/worlds/{name}/edits.

- crater with its rim keeps Σh exactly; without it, Σh falls by exactly the
  volume the reply declares; add / remove change it by amount x cells;
- stamp (int32 and PNG16; set / add / min / max; a mask) gives exactly the
  heights computed here from the heights before; reset gives the base terrain
  back (GET /v1/heights?base=1), a rectangle or the whole world;
- every reply names the tick and the volume change, and Σh (/v1/stats) moves
  by exactly that; a subscriber's mirror (ordinary deltas) equals
  /v1/heights bit for bit afterwards;
- bad input (unknown op, outside the world, over max_edit_cells, stamp bytes
  not matching w x h, a mask of the wrong size, a non-integer, NaN, a change
  past the height range) is refused naming the field, nothing changes, and
  the next edit works; /metrics counts edits and their volume;
- kill -9 after an acknowledged edit: the restarted daemon has its heights;
- the same edits on the CPU twin with 1 and 2 threads, and on GL where a
  context can be made, give the same heights."""
import asyncio
import base64
import json
import os
import shutil
import struct
import sys
import tempfile
import zlib

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value, post_edit, tp  # noqa: E402

check = Checks()
REGION = (0, 0, 256, 256)


def png16(w, h, values):
    """A 16-bit greyscale PNG of w x h values (row-major)."""
    raw = b"".join(b"\0" + struct.pack(f">{w}H", *values[y * w:(y + 1) * w]) for y in range(h))

    def chunk(kind, data):
        return (struct.pack(">I", len(data)) + kind + data +
                struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)) +
            chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def rect(d, x, y, w, h, base=False):
    status, body, _ = d.get(f"/v1/heights?x={x}&y={y}&w={w}&h={h}" + ("&base=1" if base else ""))
    if status != 200:
        raise RuntimeError(f"/v1/heights: {status} {body[:200]!r}")
    return list(struct.unpack(f"<{w * h}i", body))


async def edit_and_volume(c, d, op, **fields):
    """The edit's reply, and Σh's change across it (nothing else moves)."""
    before = d.stats()["volume"]
    r = await c.edit(op, **fields)
    # /v1/stats is published at the end of the tick the reply names, or later
    for _ in range(200):
        s = d.stats()
        if s["tick"] >= r["tick"]:
            break
        await asyncio.sleep(0.02)
    return r, s["volume"] - before


async def refused(c, d, msg, name, field, what):
    """msg (sent raw) is refused with error `name` whose message names field;
    Σh does not move."""
    before = d.stats()["volume"]
    c.errors.clear()
    await c.ws.send(msg if isinstance(msg, str) else json.dumps(msg))
    try:
        await c.wait_for(lambda: c.errors, 10)
    except asyncio.TimeoutError:
        check(False, f"{what}: no error came")
        return
    e = c.errors[-1]
    check(e.get("name") == name and field in e.get("message", ""),
          f"{what}: refused with {name} naming {field}: {e}")
    await asyncio.sleep(0.1)
    check(d.stats()["volume"] == before, f"{what}: Σh unchanged")


async def shapes(c, d):
    r, dv = await edit_and_volume(c, d, "crater", x=60, y=60, radius=12, depth=30000)
    check(r["volume_change"] == 0 and dv == 0 and r["tick"] > 0,
          f"crater with rim: Σh kept exactly ({r}, Σh moved {dv})")
    centre = rect(d, 60, 60, 1, 1)[0]
    r, dv = await edit_and_volume(c, d, "crater", x=120, y=60, radius=10, depth=20000, rim=False)
    check(r["volume_change"] < 0 and dv == r["volume_change"],
          f"crater without rim: Σh moved by the declared {r['volume_change']} ({dv})")
    removed_crater = -r["volume_change"]
    r, dv = await edit_and_volume(c, d, "add", x=10, y=150, w=20, h=10, amount=500)
    check(r["volume_change"] == 500 * 200 and dv == r["volume_change"],
          f"add: +amount x cells declared and kept ({r}, {dv})")
    r, dv = await edit_and_volume(c, d, "remove", x=10, y=150, w=10, h=10, amount=200)
    check(r["volume_change"] == -200 * 100 and dv == r["volume_change"],
          f"remove: -amount x cells declared and kept ({r}, {dv})")
    check(centre < rect(d, 60, 60, 1, 1)[0] + 1, "the crater's centre stays dug")
    return removed_crater


async def stamps(c, d):
    x, y, w, h = 150, 150, 8, 6
    for mode, fn in (("set", lambda old, v: v), ("add", lambda old, v: old + v),
                     ("min", min), ("max", max)):
        old = rect(d, x, y, w, h)
        vals = [(-1) ** i * (i * 997 % 40000) for i in range(w * h)]
        mask = bytes(1 if (i % 3) else 0 for i in range(w * h))
        r, dv = await edit_and_volume(c, d, "stamp", x=x, y=y, w=w, h=h, mode=mode,
                                      data=tp.stamp_data(vals),
                                      mask=base64.b64encode(mask).decode())
        want = [fn(o, v) if m else o for o, v, m in zip(old, vals, mask)]
        got = rect(d, x, y, w, h)
        check(got == want, f"stamp {mode} with a mask: the heights computed here")
        check(r["volume_change"] == sum(want) - sum(old) == dv,
              f"stamp {mode}: declared {r['volume_change']} = Σ(new - old) = Σh's change {dv}")
    pix = [i * 300 for i in range(w * h)]
    r, dv = await edit_and_volume(c, d, "stamp", x=x, y=y, w=w, h=h, format="png16",
                                  data=base64.b64encode(png16(w, h, pix)).decode(),
                                  scale=2, offset=-1000)
    check(rect(d, x, y, w, h) == [-1000 + 2 * p for p in pix] and dv == r["volume_change"],
          f"stamp png16: offset + value x scale, Σh by the declared change ({r})")


async def resets(c, d, volume0):
    base = rect(d, 100, 40, 60, 40, base=True)
    r, dv = await edit_and_volume(c, d, "reset", x=100, y=40, w=60, h=40)
    check(rect(d, 100, 40, 60, 40) == base and dv == r["volume_change"],
          f"reset of a rectangle: the base terrain back, Σh by the declared change ({r})")
    r, dv = await edit_and_volume(c, d, "reset")
    check(d.stats()["volume"] == volume0 and dv == r["volume_change"] and r["w"] == 512,
          f"reset of the whole world: Σh back to the start ({r})")
    check(rect(d, *REGION) == rect(d, *REGION, base=True), "reset: every height is the base's")


async def bad_input(c, d):
    await refused(c, d, {"type": "edit", "op": "explode"}, "bad_value", "op", "unknown op")
    await refused(c, d, {"type": "edit", "op": "crater", "x": -1, "y": 5, "radius": 3,
                         "depth": 10}, "outside_world", "x, y", "crater outside the world")
    await refused(c, d, {"type": "edit", "op": "add", "x": 500, "y": 0, "w": 20, "h": 5,
                         "amount": 1}, "outside_world", "x, y, w, h", "add outside the world")
    await refused(c, d, {"type": "edit", "op": "stamp", "x": 0, "y": 0, "w": 4, "h": 4,
                         "data": tp.stamp_data([1] * 15)}, "bad_value", "data",
                  "stamp bytes not matching w x h")
    await refused(c, d, {"type": "edit", "op": "stamp", "x": 0, "y": 0, "w": 2, "h": 2,
                         "data": tp.stamp_data([1] * 4), "mask": "AAA="}, "bad_value", "mask",
                  "mask of the wrong size")
    await refused(c, d, {"type": "edit", "op": "crater", "x": 5, "y": 5, "radius": 3,
                         "depth": 1.5}, "bad_value", "depth", "a depth that is not an integer")
    await refused(c, d, {"type": "edit", "op": "add", "x": 0, "y": 0, "w": 2, "h": 2,
                         "amount": "NaN"}, "bad_value", "amount", "a string where a number is")
    await refused(c, d, '{"type":"edit","op":"add","x":0,"y":0,"w":2,"h":2,"amount":NaN}',
                  "bad_json", "JSON", "a NaN in the JSON")
    await refused(c, d, '{"type":"edit","op":"add","x":0,"y":0,"w":2,"h":2,"amount":1e400}',
                  "bad_value", "amount", "an infinite amount")
    before = rect(d, 0, 0, 4, 4)
    await refused(c, d, {"type": "edit", "op": "add", "x": 0, "y": 0, "w": 4, "h": 4,
                         "amount": (1 << 29)}, "refused_height_limit", "height range",
                  "an add past the height range")
    check(rect(d, 0, 0, 4, 4) == before, "a refused edit changed no height")
    r, dv = await edit_and_volume(c, d, "add", x=0, y=0, w=1, h=1, amount=1)
    check(r["volume_change"] == 1 and dv == 1, "after every refusal the next edit works")


async def http_edits(d, name):
    before = d.stats()["volume"]
    st, a = post_edit(d, name, {"op": "add", "x": 30, "y": 30, "w": 5, "h": 4, "amount": 70})
    check(st == 200 and a.get("volume_change") == 1400 and a.get("tick", 0) > 0,
          f"POST edits: applied, with the tick and the volume change ({st} {a})")
    for _ in range(100):
        if d.stats()["tick"] >= a.get("tick", 0):
            break
        await asyncio.sleep(0.02)
    check(d.stats()["volume"] - before == 1400, "POST edits: Σh moved by the declared change")
    st, a = post_edit(d, "no-such-world", {"op": "reset"})
    check(st == 404 and name in a.get("error", ""), f"POST edits of another name: 404 ({a})")
    st, a = post_edit(d, name, {"op": "crater", "x": 3, "y": 3, "radius": 0, "depth": 5})
    check(st == 400 and "radius" in a.get("error", "") and a.get("name") == "bad_value",
          f"POST edits, a bad field: 400 naming it ({st} {a})")
    st, a = post_edit(d, name, b"{not json")
    check(st == 400 and a.get("name") == "bad_json", f"POST edits, not JSON: 400 ({st} {a})")
    return a


async def mirror_matches(c, d, sid):
    """The subscriber's mirror, made only of deltas, equals /v1/heights."""
    for _ in range(100):
        tick, server = d.heights(*REGION)
        await c.wait_for(lambda: c.mirrors[sid].complete, 10)
        await asyncio.sleep(0.1)
        if list(c.mirrors[sid].heights) == server:
            return True
    return False


async def main_daemon(d):
    name = d.world().get("world") or "default-dunes"
    volume0 = d.stats()["volume"]
    async with tp.Client(d.ws, name="edits") as c:
        sid = await c.subscribe(*REGION)
        await c.wait_complete(sid)
        removed = await shapes(c, d)
        await stamps(c, d)
        check(await mirror_matches(c, d, sid), "a subscriber's mirror equals /v1/heights")
        await bad_input(c, d)
        await resets(c, d, volume0)
        check(await mirror_matches(c, d, sid), "the mirror follows the resets too")
        await http_edits(d, name)
        # a last acknowledged edit, then a crash
        await c.edit("crater", x=200, y=200, radius=6, depth=9000)
        status, text = d.metrics()
        check(metric_value(text, "terrad_edits_total",
                           {"op": "crater", "result": "applied"}) == 3 and
              metric_value(text, "terrad_edit_volume_removed_units_total",
                           {"op": "crater"}) == removed,
              "/metrics: edits by op and result, and the volume they removed")
        return rect(d, *REGION)


def crash_and_recover(data):
    d = Daemon(data_dir=data, durability="every-tick", name="terrad-edits")
    check.daemons.append(d)
    try:
        before = asyncio.run(main_daemon(d))
    finally:
        d.kill9()
    d2 = Daemon(data_dir=data, durability="every-tick", name="terrad-edits-recovered")
    with check.running(d2):
        check(rect(d2, *REGION) == before, "kill -9: the restarted daemon has every edited height")


async def script(d):
    async with tp.Client(d.ws, name="script") as c:
        await c.edit("crater", x=100, y=100, radius=20, depth=40000)
        await c.edit("crater", x=110, y=95, radius=9, depth=15000, rim=False)
        await c.edit("stamp", x=90, y=90, w=4, h=4, mode="add",
                     data=tp.stamp_data(list(range(16))))
        try:
            await c.edit("add", x=0, y=0, w=100, h=100, amount=5)
            check(False, "over max_edit_cells: refused")
        except tp.ServerError as e:
            check(e.msg.get("name") == "too_large" and "max_edit_cells" in str(e),
                  f"over max_edit_cells: too_large naming the limit ({e.msg})")
        await c.edit("remove", x=95, y=120, w=30, h=30, amount=700)
    return rect(d, 60, 60, 100, 100)


def backends():
    """The same edits on the CPU twin (1 and 2 threads) and GL: the same heights."""
    results = {}
    for label, backend, extra in (("cpu/1", "cpu", ["--threads", "1"]),
                                  ("cpu/2", "cpu", ["--threads", "2"]),
                                  ("gl", "gl", [])):
        d = None
        try:
            d = Daemon(backend=backend, extra=["--no-data", *extra], name=f"terrad-{label}",
                       config={"limits": {"max_edit_cells": 8000}})
            results[label] = asyncio.run(script(d))
        except (RuntimeError, OSError) as e:
            if backend != "gl":
                check(False, f"{label}: {e}")
            print(f"{label}: not run ({e})")
        finally:
            if d:
                d.stop()
    ref = results.get("cpu/1")
    for label, heights in results.items():
        check(heights == ref, f"{label} gives the heights of cpu/1")


def main():
    data = tempfile.mkdtemp(prefix="terrad-edits-")
    try:
        crash_and_recover(data)
    finally:
        shutil.rmtree(data, ignore_errors=True)
    backends()
    check.finish()


if __name__ == "__main__":
    main()
