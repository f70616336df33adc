#!/usr/bin/python3
"""Mesh depth figures for `make bench` (issue 20, item 3: one client's mesh at
the default limits, 16,384 vertices and 32,768 triangles, posed in the dunes
took the tick from 60 to 26 ticks/s). The real daemon on loopback with its
default limits, one client, one closed UV-sphere mesh of 16,382 vertices and
32,760 triangles (the most a sphere this way fits under the limits) of radius
R, ploughing a line through the dunes one pose per tick (0.25 cells a tick, so
one sweep sub-step) at 60 Hz; and the same drive with a primitive sphere of
the same radius beside it. Printed per run: whether the create was accepted
(or the budget's refusal), ticks/s reached (the server's tick counter over the
drive) and the server's mean tick (terrad_tick_duration_seconds). Anchor: a
mesh the budgets accept keeps >= 30 ticks/s (does not halve the tick rate).
Never fails on a figure. TERRAD_BENCH_SECONDS (default 5), TERRAD_BENCH_BACKENDS
("cpu"; "cpu,gl" adds the GL backend where a context can be made),
TERRAD_BENCH_RADII ("0.5,2,8": metres).
"""
import asyncio
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import (Daemon, RecordingClient, machine, metric_value, tp,  # noqa: E402
                             uv_sphere_mesh)

DRIVE_S = float(os.environ.get("TERRAD_BENCH_SECONDS", "5"))
BACKENDS = os.environ.get("TERRAD_BENCH_BACKENDS", "cpu").split(",")
RADII = [float(x) for x in os.environ.get("TERRAD_BENCH_RADII", "0.5,2,8").split(",")]
ANCHOR = 30.0


def tick_sums(d):
    text = d.metrics()[1]
    return (metric_value(text, "terrad_tick_duration_seconds_sum") or 0.0,
            metric_value(text, "terrad_tick_duration_seconds_count") or 0.0)


async def drive(d, shape, r):
    w = d.world()
    cell, upm = w["cell_size_m"], w["units_per_m"]
    c = RecordingClient(d.ws, name="bench-mesh", record=False)
    await c.connect()
    try:
        if shape == "mesh":
            verts, tris = uv_sphere_mesh(r)
            cid = await c.create_collider("mesh", vertices=verts, indices=tris)
        else:
            cid = await c.create_collider("sphere", radius=r)
    except Exception as e:  # noqa: BLE001  (a budget's refusal is a figure too)
        await c.close()
        return {"accepted": False, "why": repr(e)[:160]}
    y = w["height"] // 2
    _, row = d.heights(0, y, w["width"], 1)
    z = min(row) / upm - 0.1 + r
    x0 = 40 + r / cell
    s0, n0 = tick_sums(d)
    t0, tick0 = time.monotonic(), d.stats()["tick"]
    k = 0
    while time.monotonic() - t0 < DRIVE_S:
        await c.send_poses([tp.Pose(cid, (x0 + 0.25 * k) * cell, y * cell, z)])
        k += 1
        await asyncio.sleep(1 / 60)
    tick1, t1 = d.stats()["tick"], time.monotonic()
    s1, n1 = tick_sums(d)
    await c.close()
    return {"accepted": True, "ticks_per_s": (tick1 - tick0) / (t1 - t0),
            "tick_ms": 1000 * (s1 - s0) / max(1.0, n1 - n0)}


def main():
    rows = []
    for backend in BACKENDS:
        for r in RADII:
            for shape in ("sphere", "mesh"):
                try:
                    d = Daemon(backend=backend, name=f"bench-mesh-{backend}")
                except RuntimeError as e:
                    print(f"bench_mesh: {backend} backend not available here "
                          f"({str(e).strip().splitlines()[-1] if str(e).strip() else ''})")
                    break
                try:
                    res = asyncio.run(drive(d, shape, r))
                    res.update(backend=backend, shape=shape, r=r,
                               renderer=d.world().get("renderer", backend),
                               load=os.getloadavg()[0])
                    rows.append(res)
                finally:
                    d.stop()
    print()
    print(f"terrad mesh depth bench: {machine()}; one client, default limits, {DRIVE_S:g} s "
          "of ploughing per run, loopback, 60 Hz")
    for rn in sorted({r["renderer"] for r in rows}):
        print(f"  renderer: {rn}")
    hdr = (f"{'backend':7} {'shape':6} {'radius':>6} {'ticks/s':>8} {'tick ms':>8} "
           f"{'load':>5}  anchor")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if not r["accepted"]:
            print(f"{r['backend']:7} {r['shape']:6} {r['r']:6g} {'refused':>8} {'':>8} "
                  f"{r['load']:5.1f}  ({r['why']})")
            continue
        anchor = "(printed)"
        if r["shape"] == "mesh":
            anchor = f">= {ANCHOR:g} ticks/s: {'met' if r['ticks_per_s'] >= ANCHOR else 'NOT met'}"
        print(f"{r['backend']:7} {r['shape']:6} {r['r']:6g} {r['ticks_per_s']:8.1f} "
              f"{r['tick_ms']:8.2f} {r['load']:5.1f}  {anchor}")
    print(f"(mesh: a UV sphere of 16,382 vertices and 32,760 triangles; sphere: the primitive "
          f"of the same radius; tick ms: the server's mean tick while driving; load: the "
          f"1-minute load average at the run's end, on {os.cpu_count()} cores shared with "
          "whatever else runs)")


if __name__ == "__main__":
    main()
