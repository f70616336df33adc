#!/usr/bin/python3
"""bench_join: late join at any age (issue 32 item 2; docs/performance.md "Late join").

One real daemon (--backend cpu, memory only, a tiny default world) and two worlds of
thesis-car's terrain (tests/scenes/thesis-car.json without its car: 1024 x 1024 cells of
4.88 cm, 0.4 m of flat snow), created with POST /v1/worlds:

  - craters: 2,000 random craters by edit (POST /v1/worlds/craters/edits, seeded: centre
    anywhere, radius 4..24 cells, depth 500..3000 units = 5..30 cm, with their rims);
  - vehicles: a client-clocked world ("clock": "client", PROTOCOL.md "STEP") driven by one
    client as fast as the daemon steps: 8 vehicles of 4 wheels (r 0.33 m, 8 cm into the
    snow, 2.6 m x 1.5 m apart) each lapping its own circle at 2 m/s while the circle's
    centre wanders, for BENCH_JOIN_TICKS ticks (default 36,000: 10 minutes of match at
    60 Hz, so make bench stays short; 216000 is the hour of the goal). Steps of 600 ticks,
    one pose set a tick.

Then, for each world, late joiners (tests/support/c_join_probe: the C client library, a
fresh connection each) subscribe to a 256² window and to the whole world, with absolute
snapshots (hello without snapshot_base: what every client got before), with base
snapshots (PROTOCOL.md "Base snapshots": encoding 2) and with slope snapshots offered too
(PROTOCOL.md "Slope snapshots": each piece in the shorter of encodings 2 and 3): DELTA
bytes and milliseconds from the subscribe request until the mirror is complete (the base
rebuilt by the twin library included), and whether the mirror equals GET /v1/heights.
Beside them, the codings measured on the same heights, per 64² tile as the protocol sends
them (25 bytes of rectangle header each): absolute heights + zstd 3 (encoding 1), h - base
+ zstd 3 and 19, h - base predicted + varints + zstd 3 and 19 (these need numpy and
zstandard; skipped without), and the range coders of encodings 2 and 2-or-3 (the probe's
bytes). Goal (goal_KiB beside each figure): <= 48 KiB and <= 100 ms for the window, <= 1 MiB
for the whole world, exact. Prints the machine and its load; never fails on a figure (an
inexact mirror is printed as such: the test is test_join_base.py).
"""
import concurrent.futures as cf
import json
import math
import os
import random
import struct
import sys
import tempfile
import time
import urllib.request

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import (JOIN_PROBE, SOURCE, Daemon, join_probe, json_call,  # noqa: E402
                             machine, tp)

TICKS = int(os.environ.get("BENCH_JOIN_TICKS", "36000"))
# BENCH_JOIN_DUMP=dir: write the heights and base heights each join measured (and, for the
# vehicles, the window every 36,000 ticks on the way) to dir, to try codings on offline
DUMP = os.environ.get("BENCH_JOIN_DUMP")
SIDE, WIN, TILE = 1024, 256, 64
WINDOW = (384, 384, WIN, WIN)
STEP = 600


def car_scene(name):
    with open(os.path.join(SOURCE, "tests", "scenes", "thesis-car.json")) as f:
        scene = json.load(f)
    scene["name"] = name
    scene["colliders"] = []
    return scene


def dig_craters(d, world, n=2000, seed=32):
    rnd = random.Random(seed)
    jobs = [{"op": "crater", "x": rnd.randrange(SIDE), "y": rnd.randrange(SIDE),
             "radius": rnd.randint(4, 24), "depth": rnd.randint(500, 3000)} for _ in range(n)]

    def post(body):
        req = urllib.request.Request(f"{d.http}/v1/worlds/{world}/edits",
                                     data=json.dumps(body).encode(), method="POST",
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=120) as r:
            return r.status
    t0 = time.monotonic()
    with cf.ThreadPoolExecutor(16) as ex:
        ok = sum(s == 200 for s in ex.map(post, jobs))
    print(json.dumps({"phase": "craters", "edits": n, "ok": ok,
                      "s": round(time.monotonic() - t0, 1)}), flush=True)


def wheel_poses(ids, t, hz=60.0):
    """The 32 wheel poses of tick t: vehicle v laps a circle of radius 6 + v m at 2 m/s
    around a centre that wanders around the world's middle once per 20 minutes."""
    poses = []
    s = t / hz
    for v in range(8):
        r = 6.0 + v
        phase = 2 * math.pi * v / 8
        wander = 2 * math.pi * s / 1200 + phase
        cx = 25 + 9 * math.cos(wander) + (v % 4 - 1.5) * 2.5
        cy = 25 + 9 * math.sin(wander) + (v // 4 - 0.5) * 4
        a = 2.0 * s / r + phase
        x, y, heading = cx + r * math.cos(a), cy + r * math.sin(a), a + math.pi / 2
        ch, sh = math.cos(heading), math.sin(heading)
        q = (math.cos(heading / 2), 0.0, 0.0, math.sin(heading / 2))
        for k, (fx, fy) in enumerate(((1.3, 0.75), (1.3, -0.75), (-1.3, 0.75), (-1.3, -0.75))):
            wx = min(max(x + fx * ch - fy * sh, 0.5), 49.5)
            wy = min(max(y + fx * sh + fy * ch, 0.5), 49.5)
            poses.append(tp.Pose(ids[v * 4 + k], wx, wy, 0.65, *q))
    return poses


def drive(d, world):
    import asyncio

    async def go():
        async with tp.Client(d.ws, world=world, max_size=1 << 26) as c:
            ids = [await c.create_collider("wheel", radius=0.33, width=0.2, feedback=False)
                   for _ in range(32)]
            t0, tick, last = time.monotonic(), 0, time.monotonic()
            loop = asyncio.get_running_loop()
            while tick < TICKS:
                n = min(STEP, TICKS - tick)
                dump = None
                if DUMP and tick and tick % 36000 == 0:  # read while the step ticks the world
                    dump = loop.run_in_executor(None, dump_region, d, world, WINDOW, f"{tick}-")
                await c.step(n, [wheel_poses(ids, tick + i) for i in range(n)], timeout=600)
                if dump:
                    await dump
                tick += n
                if time.monotonic() - last > 30:
                    last = time.monotonic()
                    print(json.dumps({"phase": "vehicles", "ticks": tick,
                                      "ticks_per_s": round(tick / (last - t0), 1)}), flush=True)
            print(json.dumps({"phase": "vehicles", "ticks": tick,
                              "s": round(time.monotonic() - t0, 1),
                              "ticks_per_s": round(tick / (time.monotonic() - t0), 1)}),
                  flush=True)
            for cid in ids:  # the match's cars leave: the terrain stays as they left it
                await c.delete_collider(cid)
    asyncio.run(go())


class Ticking:
    """A client-clocked world ticks only when its driver steps it, and a joiner's snapshot
    goes out at the end of a tick: while the joins run, a driver steps it (one tick every
    10 ms, nothing posed), as a match in progress would."""

    def __init__(self, d, world):
        import threading
        self.d, self.world, self.stop = d, world, threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)

    def run(self):
        import asyncio

        async def go():
            async with tp.Client(self.d.ws, world=self.world) as c:
                while not self.stop.is_set():
                    await c.step(1, timeout=120)
                    await asyncio.sleep(0.01)
        asyncio.run(go())

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join(120)


def region(d, world, rect, base=False):
    x, y, w, h = rect
    q = f"/v1/heights?world={world}&x={x}&y={y}&w={w}&h={h}" + ("&base=1" if base else "")
    status, body, _ = d.get_busy(q, timeout=120)
    if status != 200:
        raise RuntimeError(f"{q}: {status}")
    return body


def dump_region(d, world, rect, tag="", heights=None, base=None):
    """Write rect's heights (and base heights) of world to DUMP as little-endian int32s."""
    name = os.path.join(DUMP, f"{world}-{tag}{'_'.join(map(str, rect))}")
    for suffix, body in (("heights", heights), ("base", base)):
        with open(f"{name}.{suffix}", "wb") as f:
            f.write(body if body is not None else region(d, world, rect, base=suffix == "base"))


def codings(heights, base, rect):
    """Bytes of each alternative coding of rect's tiles (payload + 25 per rectangle)."""
    try:
        import numpy as np
        import zstandard as zstd
    except ImportError:
        return {"skipped": "numpy and zstandard not importable"}
    x0, y0, w, h = rect
    hh = np.frombuffer(heights, dtype="<i4").reshape(h, w).astype(np.int64)
    bb = np.frombuffer(base, dtype="<i4").reshape(h, w).astype(np.int64)

    def zz(v):
        v = ((v + 2**31) & 0xFFFFFFFF) - 2**31
        return (((v << 1) ^ (v >> 63)) & 0xFFFFFFFF).astype(np.uint32)

    def predicted(d):
        p = np.zeros_like(d)
        p[1:, 1:] = d[1:, :-1] + d[:-1, 1:] - d[:-1, :-1]
        p[0, 1:] = d[0, :-1]
        p[1:, 0] = d[:-1, 0]
        return d - p

    def varint(u):
        out = bytearray()
        for v in u.ravel().tolist():
            while v >= 0x80:
                out.append((v & 0x7F) | 0x80)
                v >>= 7
            out.append(v)
        return bytes(out)

    ways = {"absolute zstd3 (encoding 1)": (lambda t, b: zz(t).tobytes(), 3),
            "h-base zstd3": (lambda t, b: zz(t - b).tobytes(), 3),
            "h-base zstd19": (lambda t, b: zz(t - b).tobytes(), 19),
            "h-base predicted varint zstd3": (lambda t, b: varint(zz(predicted(t - b))), 3),
            "h-base predicted varint zstd19": (lambda t, b: varint(zz(predicted(t - b))), 19)}
    out = {}
    for name, (f, level) in ways.items():
        c = zstd.ZstdCompressor(level=level, write_content_size=True)
        total = 0
        for ty in range(0, h, TILE):
            for tx in range(0, w, TILE):
                total += 25 + len(c.compress(f(hh[ty:ty + TILE, tx:tx + TILE],
                                               bb[ty:ty + TILE, tx:tx + TILE])))
        out[name] = total
    out["changed cells"] = round(float(np.count_nonzero(hh != bb)) / hh.size, 3)
    return out


def joins(d, world):
    for label, rect, goal in (("window 256²", WINDOW, 48), ("whole world", (0, 0, SIDE, SIDE), 1024)):
        want = region(d, world, rect)
        want_heights = list(struct.unpack(f"<{len(want) // 4}i", want))
        base = region(d, world, rect, base=True)
        if DUMP:
            dump_region(d, world, rect, heights=want, base=base)
        alt = codings(want, base, rect)
        for mode in ("plain", "base", "slope"):
            line, got = join_probe(d, rect, mode, world)
            line = line or {"error": "c_join_probe failed (its output above)"}
            line.update({"world": world, "join": label, "snapshots": mode,
                         "KiB": round(line.get("bytes", 0) / 1024, 1), "goal_KiB": goal,
                         "exact": got == want_heights})
            print(json.dumps(line), flush=True)
        print(json.dumps({"world": world, "join": label, "codings_bytes": alt}), flush=True)


def main():
    if not os.access(JOIN_PROBE, os.X_OK):
        print(f"bench_join: no {JOIN_PROBE} (make build)")
        return 0
    print(json.dumps({"machine": machine(), "ticks": TICKS, "load": os.getloadavg()[0]}), flush=True)
    tiny = {"name": "tiny", "world": {"width": 64, "height": 64, "cell_size_m": 0.05},
            "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
    fd, tiny_path = tempfile.mkstemp(prefix="bench-join-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(tiny, f)
    # one driver poses all 32 wheels (a client-clocked world has one): its cost budget
    # raised to hold them (4 x 584 cells a vehicle)
    limits = {"max_active_cells": 65536, "max_tick_cells": 131072, "max_sweep_cells": 131072}
    d = Daemon(extra=["--scene", tiny_path, "--no-data"], config={"limits": limits})
    try:
        json_call(d.http, "POST", "/v1/worlds", {"name": "craters", "scene": car_scene("craters")})
        json_call(d.http, "POST", "/v1/worlds",
                  {"name": "vehicles", "clock": "client", "scene": car_scene("vehicles")})
        dig_craters(d, "craters")
        joins(d, "craters")
        drive(d, "vehicles")
        with Ticking(d, "vehicles"):
            joins(d, "vehicles")
        print(json.dumps({"load_after": os.getloadavg()[0]}), flush=True)
    finally:
        d.stop()
        os.unlink(tiny_path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
