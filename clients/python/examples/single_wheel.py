#!/usr/bin/env python3
"""A single-wheel testbed over the wire: drawbar pull, sinkage and torque against slip,
beside Ding et al. 2011's measurements.

    terrad --scene clients/python/examples/single_wheel_scene.json --no-demo --no-data
    python3 clients/python/examples/single_wheel.py [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/]

The scene is a flat bed of Ding et al. 2011's soil (J. Terramechanics 48(1):27-45; terrad's
`bekker` model, preset "ding2011", 5 mm cells, 50 ticks per second). A wheel of their testbed's
size (R 0.15735 m, width 0.165 m) rolls 0.4 m at 0.125 m/s, turning at v / (R (1 - s)), once for
each slip 0, 0.1, 0.2, 0.3, 0.4, 0.6, each run in its own lane of fresh soil. The wheel is
load-driven (PROTOCOL.md "Load-driven colliders": created with load_n = 80 N): its poses set x
and the turn, the server finds each tick the height at which the soil carries the load (the
validation test's search, sim_bekker_carry) and the height the client sends is ignored. Poses
go in lock step: one batch, wait for its ACK, read that tick's FORCES, send the next, so the
server's velocity (pose minus previous pose over one tick) is the commanded one. A tick that
comes before the next pose does stands the wheel still for a tick; the example counts those
"idle ticks" per run: with none, its figures are those of a testbed driven tick by tick.

Printed per slip, as means over the second half of the run: drawbar pull (Fx, along travel),
sinkage (FORCES' sinkage: below the undisturbed surface at the wheel's lowest point), driving
torque (minus the
soil's torque about the axle) and the load the wheel carried, each beside Ding's smooth-wheel
values (their Fig. 9, read off the plot: about +-1 N, +-0.5 mm). docs/validation.md has the
same wheel run server-side by the validation test, its errors and the Wong-Reece prediction.
Only terrad's public API.
"""
import asyncio
import functools
import math
import sys

import terrad
from terrad import Client, MsgType, Pose

RADIUS, WIDTH, LOAD = 0.15735, 0.165, 80.0
# Ding et al. 2011, smooth wheel, 80 N (Fig. 9): slip, drawbar pull (N), sinkage (m), torque (N m)
DING = [(0.0, -6.5, 0.005, 0.0), (0.1, 11.0, 0.0055, 3.0), (0.2, 14.5, 0.0075, 4.2),
        (0.3, 15.0, 0.010, 4.8), (0.4, 15.0, 0.0125, 5.0), (0.6, 15.0, 0.0175, 5.3)]
SPEED = 0.125       # m/s along +x: 2.5 mm a tick at 50 Hz, as the validation test's ticks
DISTANCE = 0.4      # m rolled; means over the second half


def wheel_pose(cid, x, y, z, angle):
    """A wheel (axis local y) turned by angle about y: rolls along +x for angle > 0."""
    return Pose(cid, x, y, z, math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


async def roll(wheel, client, x0, dt, steps):
    """One wheel in lock step with the server: a pose, its ACK, that tick's FORCES. Its height
    is the server's (load-driven). Sums the second half's figures into wheel["sum"]."""
    x, last_tick = x0, None
    for k in range(steps):
        x += SPEED * dt
        wheel["angle"] += wheel["omega"] * dt
        seq = await client.send_poses([wheel_pose(wheel["id"], x, wheel["y"], wheel["z"],
                                                  wheel["angle"])])
        await client.wait_ack(seq, timeout=60)
        tick = client.acked_tick
        if last_tick is not None and tick > last_tick + 1:
            wheel["idle"] += tick - last_tick - 1  # ticks that saw no new pose of this wheel
        last_tick = tick
        f = wheel["forces"].pop(tick, {}).get(wheel["id"])
        wheel["forces"].clear()
        fz = f.force[2] if f else 0.0
        if k >= steps // 2 and f:
            s = wheel["sum"]
            s[0] += f.force[0]
            s[1] += f.sinkage_m
            s[2] += -f.torque[1]
            s[3] += fz
            wheel["n"] += 1


async def testbed(ws_uri, http_uri):
    """Runs the six wheels; returns one row per slip: (slip, dp, sinkage, torque, load, idle)."""
    loop = asyncio.get_running_loop()
    async with Client(ws_uri) as client:
        world = client.world
        cell, units, hz = world["cell_size_m"], world["units_per_m"], world["tick_hz"]
        lane = world["height"] * cell / len(DING)
        dt = 1.0 / hz
        x0 = 1.2 * RADIUS
        steps = int(DISTANCE / (SPEED * dt))
        read = functools.partial(terrad.get_heights, http_uri)  # GET /v1/heights
        forces = {}  # tick -> {collider id: Force}; FORCES of a tick come before its ACK
        client.on(MsgType.FORCES, lambda tick, fs: forces.__setitem__(tick, {f.id: f for f in fs}))
        rows = []
        # One wheel at a time, each in its own lane of fresh soil: a client's colliders share
        # one budget of active cells (max_active_cells), most of which this wheel takes.
        for i, (slip, *_) in enumerate(DING):
            y = (i + 0.5) * lane
            _, h = await loop.run_in_executor(None, read, int(x0 / cell), int(y / cell), 1, 1)
            ground = int(h[0][0]) / units
            cid = await client.create_collider("wheel", radius=RADIUS, width=WIDTH, load_n=LOAD)
            wheel = {"id": cid, "slip": slip, "y": y, "ground": ground,
                     "z": ground + RADIUS, "angle": 0.0, "sum": [0.0] * 4,
                     "n": 0, "idle": 0, "forces": forces,
                     "omega": SPEED / (RADIUS * (1.0 - slip))}
            await roll(wheel, client, x0, dt, steps)
            await client.delete_collider(cid)
            rows.append((slip, *(v / max(wheel["n"], 1) for v in wheel["sum"]), wheel["idle"]))
        return rows


def main():
    ws = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8081/"
    http = sys.argv[2] if len(sys.argv) > 2 else "http://127.0.0.1:8080/"
    rows = asyncio.run(testbed(ws, http))
    print("slip  drawbar pull N (Ding)  sinkage mm (Ding)  torque N m (Ding)  load N")
    for (slip, dp, z, t, load, idle), (_, d_dp, d_z, d_t) in zip(rows, DING):
        print(f"{slip:4.1f}  {dp:7.2f} ({d_dp:5.1f})      {z * 1e3:6.2f} ({d_z * 1e3:4.1f})"
              f"      {t:5.2f} ({d_t:3.1f})       {load:5.1f}  idle ticks {idle}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
