#!/usr/bin/python3
"""The tick's budget charges what a collider really costs this tick (issue 20,
item 3; collider_cost_cells, calibrated in collider.c): its depth work once
per sweep sub-step and the lane of window its travel adds (a fast collider
does its depth work once per sub-step), and its depth once more with contact
feedback (measured again against the terrain before the tick). A daemon at
10 Hz with a small max_tick_cells, two clients each with one collider:

  - sweep: a 0.3 m sphere (window 441 cells, 6 per pose's depth, a lane of 21)
    moved 20 cells per pose (40 sub-steps: 1,080 cells) beside a light 0.3 m
    sphere moved one cell per pose, under max_tick_cells 1,200: by one pose
    each (about 900) nothing would wait; the fast one waits a tick now and
    then (terrad_tick_shed_total counts; the log's "cells asked for" counts
    the sub-steps), the light one is served: every one of its pose batches
    is acknowledged;
  - feedback: a 0.5 m UV-sphere mesh of 32,760 triangles at rest (window 841,
    5,119 per pose's depth) beside the light sphere under max_tick_cells
    8,000: without feedback (about 6,400 in all) nothing ever waits; the same
    mesh created with feedback (its depth twice: 11,079) waits now and then
    while the light one is still served.
"""
# ctest-timeout: 240
import asyncio
import os
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, metric_value, tp,  # noqa: E402
                             uv_sphere_mesh)

# a 0.3 m sphere at 0.05 m cells: window (13 + 8)^2, depth ceil(13^2 / 32), lane 21
WINDOW, DEPTH, LANE = 441, 6, 21
FAST = WINDOW + 40 * DEPTH + 19 * LANE  # 40 sub-steps


def shed(d):
    return metric_value(d.metrics()[1], "terrad_tick_shed_total", {"reason": "max_tick_cells"}) or 0


async def pair(d, shape, heavy_dims, heavy_feedback, heavy_step_cells, poses=30):
    """A heavy and a light client pose together for `poses` rounds at 10 Hz;
    returns the light client's sequence numbers (all acknowledged)."""
    cell = d.world()["cell_size_m"]
    heavy = RecordingClient(d.ws, name="heavy", record=False)
    light = RecordingClient(d.ws, name="light", record=False)
    await heavy.connect()
    await light.connect()
    hid = await heavy.request(tp.collider_create(shape, feedback=heavy_feedback, **heavy_dims),
                              "collider_created")
    lid = await light.request(tp.collider_create("sphere", feedback=False, radius=0.3),
                              "collider_created")
    seqs = []
    for k in range(poses):
        await heavy.send_poses([tp.Pose(hid["id"], (60 + heavy_step_cells * k) * cell,
                                        128 * cell, 5.0)])
        seqs.append(await light.send_poses([tp.Pose(lid["id"], (60 + k) * cell, 384 * cell, 5.0)]))
        await asyncio.sleep(0.1)
    for seq in seqs:
        await light.wait_ack(seq, 60)
    await heavy.close()
    await light.close()
    return seqs


async def sweep(check, d):
    seqs = await pair(d, "sphere", {"radius": 0.3}, False, 20)
    check(True, f"every one of the light client's {len(seqs)} pose batches was acknowledged")
    n = shed(d)
    check(n > 0, f"the fast sphere waited a tick now and then: terrad_tick_shed_total {n}")
    asked = [int(m.group(1)) for line in d.lines
             for m in [re.search(r"\((\d+) cells asked for", line)] if m]
    least = FAST + WINDOW + DEPTH  # the light one at rest, at least
    check(asked and max(asked) >= least,
          f"the log charges the 40 sub-steps (>= {least} cells asked for): {asked[:5]}")


async def feedback(check, d):
    verts, tris = uv_sphere_mesh(0.5)
    mesh = {"vertices": verts, "indices": tris}
    await pair(d, "mesh", mesh, False, 0)
    check(shed(d) == 0, f"without feedback nothing waits: terrad_tick_shed_total {shed(d)}")
    seqs = await pair(d, "mesh", mesh, True, 0)
    check(True, f"with feedback: every one of the light client's {len(seqs)} pose batches "
          "was acknowledged")
    check(shed(d) > 0, f"the mesh with feedback waited a tick now and then: "
          f"terrad_tick_shed_total {shed(d)}")


def main():
    check = Checks()
    d = Daemon(tick_hz=10, config={"limits": {"max_tick_cells": 1200}}, name="terrad-sweep-cost")
    with check.running(d):
        asyncio.run(sweep(check, d))
    d = Daemon(tick_hz=10, config={"limits": {"max_tick_cells": 8000,
                                                            "max_active_cells": 65536}}, name="terrad-fb-cost")
    with check.running(d):
        asyncio.run(feedback(check, d))
    check.finish()


if __name__ == "__main__":
    main()
