#!/usr/bin/python3
"""The attack cases of issue 20, item 3 for `make bench`: what one client at
the default limits can make a tick cost (before the budgets: one mesh of
16,384 vertices and 32,768 triangles posed in the dunes took the tick from 60
to 26 ticks/s). The real daemon on loopback with its default limits, one
client, one collider ploughing a line through the dunes one pose per tick at
60 Hz. Cases: a closed UV-sphere mesh of 16,382 vertices and 32,760 triangles
(0.5 m) without and with contact feedback (with it, the default
max_active_cells refuses it); the largest primitive sphere the default budget
accepts (2 m without feedback); an 8 m sphere (refused); a 0.3 m sphere swept
20 cells a tick (40 sub-steps). Printed per case: accepted or the budget's
refusal, ticks/s reached (the server's tick counter over the drive) and the
server's mean tick (terrad_tick_duration_seconds). Anchor: a case the budgets
accept keeps >= 30 ticks/s (does not halve the tick rate). Never fails on a
figure. TERRAD_BENCH_SECONDS (default 5), TERRAD_BENCH_BACKENDS ("cpu";
"cpu,gl" adds the GL backend where a context can be made).
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
# (label, shape, radius m, feedback, cells moved per tick)
CASES = [("mesh 0.5 m", "mesh", 0.5, False, 0.25), ("mesh 0.5 m +fb", "mesh", 0.5, True, 0.25),
         ("sphere 2 m", "sphere", 2.0, False, 0.25), ("sphere 8 m", "sphere", 8.0, False, 0.25),
         ("sweep 0.3 m", "sphere", 0.3, False, 20.0)]
ANCHOR = 30.0


def tick_sums(d):
    text = d.metrics()[1]
    return (metric_value(text, "terrad_tick_duration_seconds_sum") or 0.0,
            metric_value(text, "terrad_tick_duration_seconds_count") or 0.0)


async def drive(d, shape, r, feedback, speed):
    w = d.world()
    cell, upm = w["cell_size_m"], w["units_per_m"]
    c = RecordingClient(d.ws, name="bench-mesh", record=False)
    await c.connect()
    try:
        if shape == "mesh":
            verts, tris = uv_sphere_mesh(r)
            dims = {"vertices": verts, "indices": tris}
        else:
            dims = {"radius": r}
        cid = (await c.request(tp.collider_create(shape, feedback=feedback, **dims),
                               "collider_created"))["id"]
    except Exception as e:  # noqa: BLE001  (a budget's refusal is a figure too)
        await c.close()
        return {"accepted": False, "why": repr(e)[:160]}
    y = w["height"] // 2
    _, row = d.heights(0, y, w["width"], 1)
    z = min(row) / upm - 0.1 + r
    x0 = 40 + r / cell
    span = w["width"] - 2 * x0  # a fast one comes back along the line: there and back
    s0, n0 = tick_sums(d)
    t0, tick0 = time.monotonic(), d.stats()["tick"]
    k = 0
    while time.monotonic() - t0 < DRIVE_S:
        u = (speed * k) % (2 * span)
        await c.send_poses([tp.Pose(cid, (x0 + min(u, 2 * span - u)) * cell, y * cell, z)])
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
        for label, shape, r, feedback, speed in CASES:
            if True:
                try:
                    d = Daemon(backend=backend, name=f"bench-mesh-{backend}")
                except RuntimeError as e:
                    print(f"bench_mesh: {backend} backend not available here "
                          f"({str(e).strip().splitlines()[-1] if str(e).strip() else ''})")
                    break
                try:
                    res = asyncio.run(drive(d, shape, r, feedback, speed))
                    res.update(backend=backend, shape=label, r=r,
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
    hdr = (f"{'backend':7} {'case':15} {'ticks/s':>8} {'tick ms':>8} "
           f"{'load':>5}  anchor")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        if not r["accepted"]:
            print(f"{r['backend']:7} {r['shape']:15} {'refused':>8} {'':>8} "
                  f"{r['load']:5.1f}  ({r['why']})")
            continue
        anchor = f">= {ANCHOR:g} ticks/s: {'met' if r['ticks_per_s'] >= ANCHOR else 'NOT met'}"
        print(f"{r['backend']:7} {r['shape']:15} {r['ticks_per_s']:8.1f} "
              f"{r['tick_ms']:8.2f} {r['load']:5.1f}  {anchor}")
    print(f"(mesh: a UV sphere of 16,382 vertices and 32,760 triangles; +fb: with contact "
          f"feedback; sweep: 20 cells a tick; tick ms: the server's mean tick while driving; load: the "
          f"1-minute load average at the run's end, on {os.cpu_count()} cores shared with "
          "whatever else runs)")


if __name__ == "__main__":
    main()
