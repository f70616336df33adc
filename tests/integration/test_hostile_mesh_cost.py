#!/usr/bin/python3
"""A mesh's real cost in the budgets (issue 20, item 3: one client's mesh at
the default limits, 16,384 vertices and 32,768 triangles, posed in the dunes
took the tick from 60 to 26 ticks/s, charged only its bounding square). Each
triangle is now charged the square around its own bounding sphere plus one
(collider_cost_cells), by the per-client max_active_cells and the per-tick
max_tick_cells alike. Checked, with UV-sphere meshes of 16,382 vertices and
32,760 triangles:

  - default limits: a 4 m sphere mesh, whose bounding square alone fits
    max_active_cells, is refused naming max_active_cells with a cost past it;
  - default limits: a 0.5 m sphere mesh is accepted, and is charged at least
    two cells per triangle: a primitive sphere that would fit beside the
    mesh's bounding square is refused, its message counting the mesh's cost;
  - the tick's budget (max_tick_cells 20,000, 10 Hz): the 0.5 m mesh (a
    441-cell square) ploughing beside a light sphere waits a tick now and then
    (terrad_tick_shed_total counts, the log says so) while every pose batch of
    the light client is acknowledged; by bounding squares alone (610 cells)
    nothing would ever wait.
"""
# ctest-timeout: 240
import asyncio
import math
import os
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, metric_value, tp,  # noqa: E402
                             uv_sphere_mesh)

TRIANGLES = 32760
BUDGET = 20000


async def create(client, shape, **dims):
    try:
        return await client.create_collider(shape, **dims), None
    except tp.ServerError as e:
        return None, e


def square(r, cell):
    return (math.ceil(2 * r / cell) + 1) ** 2


async def client_budget(check, d):
    w = d.world()
    cell = w["cell_size_m"]
    c = RecordingClient(d.ws, name="mesh-budget", record=False)
    await c.connect()
    limit = c.world["limits"]["max_active_cells"]
    check(limit == 262144 and c.world["limits"].get("max_tick_cells") == 1048576,
          f"the default budgets: {c.world['limits']}")
    verts, tris = uv_sphere_mesh(4.0)
    cid, err = await create(c, "mesh", vertices=verts, indices=tris)
    m = re.search(r"cost of (\d+) cells", err.message) if err else None
    check(square(4.0, cell) < limit, f"a 4 m sphere's bounding square fits ({square(4.0, cell)})")
    check(cid is None and err.code == 8 and "max_active_cells" in err.message and m and
          int(m.group(1)) > limit,
          f"the 4 m mesh is refused by its triangles' cost: {err and err.message}")

    verts, tris = uv_sphere_mesh(0.5)
    mesh, err = await create(c, "mesh", vertices=verts, indices=tris)
    check(mesh is not None, f"the 0.5 m mesh fits the budget: {err and err.message}")
    r = 0.5 * cell * (math.isqrt(limit - square(0.5, cell)) - 2)  # fits beside the square alone
    f = square(r, cell)
    check(f + square(0.5, cell) <= limit, f"a {r:.2f} m sphere ({f} cells) fits beside the "
          f"mesh's bounding square ({square(0.5, cell)} cells) in {limit}")
    big, err = await create(c, "sphere", radius=r)
    m = re.search(r"to (\d+) active cells", err.message) if err else None
    check(big is None and m and int(m.group(1)) - f >= 2 * TRIANGLES,
          f"refused: the mesh is charged at least two cells per triangle "
          f"({err and err.message})")
    await c.close()


async def tick_budget(check, d):
    w = d.world()
    cell, upm = w["cell_size_m"], w["units_per_m"]
    heavy = RecordingClient(d.ws, name="mesh", record=False)
    light = RecordingClient(d.ws, name="light", record=False)
    await heavy.connect()
    await light.connect()
    verts, tris = uv_sphere_mesh(0.5)
    mid, err = await create(heavy, "mesh", vertices=verts, indices=tris)
    check(mid is not None, f"the mesh is created: {err and err.message}")
    lid = await light.create_collider("sphere", radius=0.3)
    seqs = []
    for k in range(30):
        for c, cid, y, r in ((heavy, mid, 128, 0.5), (light, lid, 384, 0.3)):
            _, row = d.heights(100 + k, y, 1, 1)
            z = row[0] / upm - 0.05 + r
            seq = await c.send_poses([tp.Pose(cid, (100 + k) * cell, y * cell, z)])
            if c is light:
                seqs.append(seq)
        await asyncio.sleep(0.1)
    for seq in seqs:
        await light.wait_ack(seq, 60)
    check(True, f"every one of the light client's {len(seqs)} pose batches was acknowledged")
    shed = metric_value(d.metrics()[1], "terrad_tick_shed_total",
                        {"reason": "max_tick_cells"}) or 0
    check(shed > 0, f"the mesh waited a tick now and then: terrad_tick_shed_total {shed}")
    check(any("wait a tick" in line for line in d.lines), "the log says colliders waited")
    await heavy.close()
    await light.close()


def main():
    check = Checks()
    d = Daemon(name="terrad-mesh-defaults")
    with check.running(d):
        asyncio.run(client_budget(check, d))
    d = Daemon(tick_hz=10, config={"limits": {"max_tick_cells": BUDGET}}, name="terrad-mesh-tick")
    with check.running(d):
        asyncio.run(tick_budget(check, d))
    check.finish()


if __name__ == "__main__":
    main()
