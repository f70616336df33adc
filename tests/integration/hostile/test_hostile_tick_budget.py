#!/usr/bin/python3
"""The tick's cost budget (issue 15, item 3: one client within its own limits
took the tick from 60 to 1.5 ticks/s and stalled everyone). With
limits.max_tick_cells set, while the posed colliders' footprint cells pass
it, the most expensive client's colliders wait a tick; only a client over its
fair share ever waits, never two ticks running, and the last one never.
Deterministic: counted in cells, not milliseconds.

Two clients plough a straight line each, one pose batch per tick (10 Hz):
a heavy sphere (2 m, 6,561 cells) and a light one (0.3 m, 169 cells), budget
6,000 cells. Checked: terrad_tick_shed_total counts the waits and the log says
so; the heavy client's ACKs all fall on ticks of one parity (it waits every
other tick, and its ACK waits with it) while the light client's fall on both
(it never waits); and both trails have no gap: every cell of both centre lines
is below the base terrain (a collider that waited sweeps from where it was).
"""
# ctest-timeout: 180
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, RecordingClient, metric_value, tp  # noqa: E402

BUDGET = 6000
STEPS = 40
X0, STEP = 100, 5  # cells: start, cells per tick


def base_row(d, x, y, w):
    status, body, _ = d.get(f"/v1/heights?x={x}&y={y}&w={w}&h=1&base=1")
    assert status == 200, (status, body[:200])
    import struct
    return list(struct.unpack(f"<{w}i", body))


async def plough(check, d):
    world = d.world()
    cell, upm = world["cell_size_m"], world["units_per_m"]
    light = RecordingClient(d.ws, name="light", record=False)
    heavy = RecordingClient(d.ws, name="heavy", record=False)
    await light.connect()
    await heavy.connect()
    got = light.world.get("limits", {}).get("max_tick_cells")
    check(got == BUDGET, f"the world message's limits carry max_tick_cells ({got})")
    rows = {"light": (128, 0.3, light), "heavy": (384, 2.0, heavy)}
    x1 = X0 + STEP * STEPS
    plan = {}
    for name, (y, r, c) in rows.items():
        _, hs = d.heights(X0, y, x1 - X0 + 1, 1)
        bottom = min(hs) / upm - 0.05  # below the lowest cell of the line: it ploughs all of it
        cid = await c.create_collider("sphere", radius=r)
        plan[name] = (c, cid, y, bottom + r)
    for k in range(STEPS + 1):
        for name, (c, cid, y, z) in plan.items():
            await c.send_poses([tp.Pose(cid, (X0 + STEP * k) * cell, y * cell, z)])
        await asyncio.sleep(0.1)
    for _ in range(6):  # the last pose reaches both, whoever waited
        for name, (c, cid, y, z) in plan.items():
            await c.send_poses([tp.Pose(cid, x1 * cell, y * cell, z)])
        await asyncio.sleep(0.1)

    _, m = d.metrics()
    shed = metric_value(m, "terrad_tick_shed_total", {"reason": "max_tick_cells"}) or 0
    check(shed > 0, f"terrad_tick_shed_total counts the waits ({shed})")
    check(any("wait a tick" in l for l in d.lines), "the log says colliders waited")
    h_ticks = sorted({t for t, _ in heavy.acks})
    l_ticks = sorted({t for t, _ in light.acks})
    print(f"info: {len(h_ticks)} heavy ACK ticks, {len(l_ticks)} light; {shed} collider-ticks "
          f"waited", flush=True)
    check(len(h_ticks) > 5 and len({t % 2 for t in h_ticks}) == 1,
          f"the heavy client moves every other tick: its ACKs on one parity ({h_ticks[:12]})")
    check(len({t % 2 for t in l_ticks}) == 2,
          f"the light client moves every tick: its ACKs on both parities ({l_ticks[:12]})")
    for name, (c, cid, y, z) in plan.items():
        _, now = d.heights(X0, y, x1 - X0 + 1, 1)
        base = base_row(d, X0, y, x1 - X0 + 1)
        gaps = [X0 + i for i in range(len(now)) if now[i] >= base[i]]
        check(not gaps, f"the {name} trail has no gap along row {y} (cells not ploughed: "
                        f"{gaps[:10]})")
    await light.close()
    await heavy.close()


def main():
    check = Checks()
    d = Daemon(tick_hz=10, config={"limits": {"max_tick_cells": BUDGET,
                                                      "max_active_cells": 65536}})
    with check.running(d):
        asyncio.run(plough(check, d))
    check.finish()


if __name__ == "__main__":
    main()
