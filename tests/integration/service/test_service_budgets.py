#!/usr/bin/python3
"""Cost budgets per client (issue 15, item 3): a collider is charged its
footprint (the cells it can cover at once) against max_active_cells and its
triangles against max_mesh_triangles, so one client within its message and
collider limits cannot make every tick do unbounded work.

  - one huge box collider is refused with limit_colliders (8), the message
    naming max_active_cells;
  - 512 small colliders from one client: the first ones fit, then the rest
    are refused naming the budget; deleting one frees its cells again;
  - two meshes whose triangles together pass max_mesh_triangles: the second
    is refused naming it;
  - meanwhile another client's wheel keeps being ACKed for advancing ticks;
  - terrad_colliders_refused_budget_total counts the refusals.
"""
# ctest-timeout: 300
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, RecordingClient, metric_value, skip, tp, wheel_pose  # noqa: E402

check = Checks()
CELLS = 20000


async def create(client, shape, **dims):
    try:
        return await client.create_collider(shape, **dims), None
    except tp.ServerError as e:
        return None, e


async def scenario(d):
    good = RecordingClient(d.ws, name="good", record=False)
    await good.connect()
    wheel = await good.create_collider("cylinder", radius=0.3, half_length=0.1)
    acked = []
    good.on_ack = lambda t, s: acked.append(t)
    stop = asyncio.Event()

    async def drive():
        while not stop.is_set():
            await good.send_poses([wheel_pose(wheel, 3.0, 3.0, 50.0)])
            await asyncio.sleep(1 / 60)

    task = asyncio.create_task(drive())
    big = RecordingClient(d.ws, name="big", record=False)
    await big.connect()
    check(big.world["limits"].get("max_active_cells") == CELLS,
          f"world.limits reports max_active_cells: {big.world['limits']}")

    cid, err = await create(big, "box", half_extents=[40.0, 40.0, 1.0])
    check(cid is None and err is not None and err.code == 8 and "max_active_cells" in err.message,
          f"one huge box is refused naming max_active_cells: {err and (err.code, err.message)}")

    made, refused = [], []
    for i in range(512):
        cid, err = await create(big, "sphere", radius=0.4)
        (made if cid is not None else refused).append(cid if cid is not None else err)
    before = list(acked)
    check(0 < len(made) < 512 and len(refused) == 512 - len(made),
          f"512 small colliders: {len(made)} fit, {len(refused)} refused")
    check(all(e.code == 8 and "max_active_cells" in e.message for e in refused),
          f"each refusal names the budget: {refused[0].message if refused else None}")
    await big.delete_collider(made[0])
    cid, err = await create(big, "sphere", radius=0.4)
    check(cid is not None, f"deleting a collider frees its cells: {err and err.message}")

    # meshes: two of 300 triangles against a budget of 500
    mesh = RecordingClient(d.ws, name="mesh", record=False)
    await mesh.connect()
    verts, tris = [], []
    for i in range(302):  # 2 cm apart: the triangles' own cells stay far inside max_active_cells
        verts += [0.02 * (i % 20), 0.02 * (i // 20), 0.0]
    for i in range(300):
        tris += [i, i + 1, i + 2]
    m1, err1 = await create(mesh, "mesh", vertices=verts, indices=tris)
    m2, err2 = await create(mesh, "mesh", vertices=verts, indices=tris)
    check(m1 is not None, f"the first mesh fits: {err1 and err1.message}")
    check(m2 is None and err2 is not None and "max_mesh_triangles" in err2.message,
          f"the second mesh passes the client's max_mesh_triangles: {err2 and err2.message}")

    await asyncio.sleep(0.5)
    after = acked[len(before):]
    deadline = asyncio.get_running_loop().time() + 120
    while not after and asyncio.get_running_loop().time() < deadline:
        await asyncio.sleep(0.1)
        after = acked[len(before):]
    stop.set()
    await task
    check(len(acked) > 0 and after and max(after) > (max(before) if before else 0),
          f"the other client's wheel keeps being ACKed for advancing ticks ({len(acked)} ACKs)")
    metrics = d.metrics()[1]
    n = metric_value(metrics, "terrad_colliders_refused_budget_total")
    check(n is not None and n >= len(refused) + 2, f"terrad_colliders_refused_budget_total {n}")
    for c in (good, big, mesh):
        await c.close()


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    d = Daemon(backend="cpu", name="terrad-budgets",
               config={"limits": {"max_colliders": 1024, "max_active_cells": CELLS,
                                  "max_mesh_triangles": 500, "max_messages_per_s": 100000,
                                  "messages_burst": 100000}})
    with check.running(d):
        asyncio.run(scenario(d))
    check.finish()


if __name__ == "__main__":
    main()
