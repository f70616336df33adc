#!/usr/bin/python3
"""A mesh's real cost in the budgets (issue 20, item 3: one client's mesh at
the default limits, 16,384 vertices and 32,768 triangles, posed in the dunes
took the tick from 60 to 26 ticks/s, charged only its bounding square). A
collider is charged collider_cost_cells (collider.c has the calibration): its
window, and per pose the depth work, for a mesh 1/8 cell per triangle (and
1/32 per cell its triangles may visit), once more with contact feedback; by
the per-client max_active_cells and the per-tick max_tick_cells alike.
Checked, with UV-sphere meshes of 16,382 vertices and 32,760 triangles:

  - default limits (max_active_cells 8,192, max_tick_cells 32,768): a 0.5 m
    sphere mesh with feedback is refused naming max_active_cells, its cost
    past it, although a primitive 0.5 m sphere with feedback is accepted;
  - the same mesh without feedback is accepted, and charged at least its
    window (841 cells) plus 32,760 / 8: a second one is refused, its message
    counting both;
  - the tick's budget (max_tick_cells 12,000, 10 Hz): the 0.5 m mesh with
    feedback ploughing beside a light sphere waits a tick now and then
    (terrad_tick_shed_total counts, the log says so) while every pose batch of
    the light client is acknowledged; by windows alone (1,282 cells) nothing
    would ever wait.
"""
# ctest-timeout: 240
import asyncio
import math
import os
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, metric_value, tp,  # noqa: E402
                             uv_sphere_mesh)

TRIANGLES = 32760
BUDGET = 12000


async def create(client, shape, **dims):
    try:
        return await client.create_collider(shape, **dims), None
    except tp.ServerError as e:
        return None, e


def square(r, cell):
    """the window: the bounding square and the active margin (4 cells) each side"""
    return (math.ceil(2 * r / cell) + 1 + 8) ** 2


async def client_budget(check, d):
    c = RecordingClient(d.ws, name="mesh-budget", record=False)
    await c.connect()
    limit = c.world["limits"]["max_active_cells"]
    check(limit == 8192 and c.world["limits"].get("max_tick_cells") == 32768,
          f"the default budgets: {c.world['limits']}")
    verts, tris = uv_sphere_mesh(0.5)
    cid, err = await create(c, "mesh", vertices=verts, indices=tris)
    m = re.search(r"cost of (\d+) cells", err.message) if err else None
    check(cid is None and err.code == 8 and "max_active_cells" in err.message and m and
          int(m.group(1)) > limit,
          f"the mesh with feedback is refused by its triangles' cost: {err and err.message}")
    sphere, err = await create(c, "sphere", radius=0.5)
    check(sphere is not None, f"a primitive 0.5 m sphere with feedback fits: {err and err.message}")
    await c.delete_collider(sphere)

    plain = {"feedback": False, "vertices": verts, "indices": tris}
    mesh = await c.request(tp.collider_create("mesh", **plain), "collider_created")
    check(mesh is not None, "the mesh without feedback fits the budget")
    try:
        await c.request(tp.collider_create("mesh", **plain), "collider_created")
        err = None
    except tp.ServerError as e:
        err = e
    m = re.search(r"cost of (\d+) cells.* to (\d+) active cells", err.message) if err else None
    least = square(0.5, 0.05) + TRIANGLES // 8
    check(m and int(m.group(1)) >= least and int(m.group(2)) == 2 * int(m.group(1)),
          f"a second one is refused, each charged at least {least} cells: "
          f"{err and err.message}")
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
    d = Daemon(tick_hz=10, config={"limits": {"max_tick_cells": BUDGET,
                                                      "max_active_cells": 65536}}, name="terrad-mesh-tick")
    with check.running(d):
        asyncio.run(tick_budget(check, d))
    check.finish()


if __name__ == "__main__":
    main()
