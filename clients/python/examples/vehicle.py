#!/usr/bin/env python3
"""A remote vehicle simulator on terrad's soil forces (issue 21): a four-wheeled rover climbs a
20-degree slope of firm soil and bogs down on the same slope of soft soil.

    python3 clients/python/examples/vehicle.py [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/] [TOKEN]

Two worlds are created through the lifecycle API (POST /v1/worlds: the bekker model; soft: Wong's
"snow (US)" with slip-sinkage 0.4, firm: sandy loam), a ramp is stamped into each (an `edit`),
and one client per world drives a rover. The client owns the dynamics, integrated at 60 Hz (the
worlds tick at 60 Hz): a rigid chassis in the x-z plane (mass, pitch inertia) on four
spring-damper suspension struts, and four wheels, feedback colliders, each turned by a motor
whose torque falls linearly to zero at its free speed. Every tick, in lock step: the wheels'
poses, the ACK, that tick's FORCES (force, torque about the axle, sinkage, slip per wheel), then
one semi-implicit Euler step: the soil's x force and the struts move the chassis; motor and soil
torque turn each wheel; each (massless) wheel's sinkage below the undeformed ground moves by
(strut - Fz) / K, at most 0.5 mm a tick, towards where the soil carries the strut's load. Lateral
forces and roll are left out (the rover is symmetric). Prints a line a second (position, speed,
and the wheels' slip and sinkage, means over that second) and a verdict per world; exits 0 when
the firm rover reached the top and the soft one stalled (< 5 cm in its last 3 s) spinning.
TOKEN: an admin token where the daemon has an --auth-file. Only terrad's public API."""
import asyncio
import base64
import math
import os
import struct
import sys

import terrad
from terrad import Client, MsgType, Pose

HZ, G, CELL, UPM, SECONDS = 60, 9.81, 0.025, 10000, 14.0  # SECONDS: the most each rover drives
WIDTH, HEIGHT = 280, 48                    # cells: 7 m along the slope, 1.2 m across
GROUND, RAMP_X, SLOPE_DEG, RISE = 0.5, 1.5, 20.0, 1.0  # m; the ramp's foot, angle and height
TOP_X = RAMP_X + RISE / math.tan(math.radians(SLOPE_DEG))
MASS, PITCH_I = 60.0, 6.0                  # chassis: kg, kg m^2
RADIUS, WHEEL_W, WHEEL_I = 0.2, 0.12, 0.3  # m, m, kg m^2 (wheel with its gearbox)
HALF_BASE, HALF_TRACK, REST = 0.35, 0.3, 0.15  # m: wheel positions, suspension rest length
K_SUSP, C_SUSP = 12000.0, 1200.0           # N/m, N s/m
T_MAX, OMEGA_FREE = 40.0, 5.0              # N m at stall, rad/s (1 m/s at no slip)
SEARCH_K, STEP = 150e3, 0.0005            # the wheels' sinkage search: N/m, most m a tick
SOILS = {"soft": {"preset": "snow-us", "slip_n": 0.4}, "firm": {"preset": "sandy-loam"}}
WHEELS = [(sx * HALF_BASE, sy * HALF_TRACK) for sx in (1, -1) for sy in (1, -1)]


def scene(soil):
    return {"name": "slope", "world": {"width": WIDTH, "height": HEIGHT, "cell_size_m": CELL,
                                       "units_per_m": UPM},
            "terrain": {"kind": "flat", "height_m": GROUND}, "tick_hz": HZ,
            "material": {"model": "bekker", "compression": 0.5, "soil": soil}}


def surface(x):
    """The ground as stamped: flat, a 20-degree ramp from RAMP_X, flat again RISE higher."""
    return GROUND + min(max(x - RAMP_X, 0.0) * math.tan(math.radians(SLOPE_DEG)), RISE)


def rest_z(x):
    """Where a wheel's centre would rest on the undeformed ground at x (the highest touch)."""
    return max(surface(x + RADIUS * u / 10) + RADIUS * math.sqrt(1 - (u / 10) ** 2)
               for u in range(-10, 11))


def ramp():  # the stamp's data: every row of cells is surface() at the cell's centre
    row = [round(surface((x + 0.5) * CELL) * UPM) for x in range(WIDTH)]
    return base64.b64encode(struct.pack(f"<{WIDTH * HEIGHT}i", *(row * HEIGHT))).decode()


async def drive(ws, token, world, name):
    """One rover up one slope; returns (distance m, mean slip, mean sinkage m, stalled, idle
    ticks: ticks that came before the next pose, standing the wheels still)"""
    async with Client(ws, token=token, world=world) as c:
        await c.edit("stamp", x=0, y=0, w=WIDTH, h=HEIGHT, data=ramp())
        ids = [await c.create_collider("wheel", radius=RADIUS, width=WHEEL_W) for _ in WHEELS]
        forces, dt, y0 = {}, 1.0 / HZ, HEIGHT * CELL / 2  # forces: tick -> {id: Force}
        c.on(MsgType.FORCES, lambda tick, fs: forces.__setitem__(tick, {f.id: f for f in fs}))
        x, z = 0.6, GROUND + RADIUS - 0.002 + REST - MASS * G / (4 * K_SUSP)
        vx = vz = pitch = rate = idle = last = 0
        sink = [0.002] * 4  # each wheel's centre below where it would rest on the ground
        spin, omega, comp = [0.0] * 4, [0.0] * 4, [None] * 4
        track, slips, sinks = [], [], []
        for k in range(int(SECONDS * HZ)):
            mounts = [(x + lx * math.cos(pitch), z - lx * math.sin(pitch)) for lx, _ in WHEELS]
            zw = [rest_z(mx) - sink[i] for i, (mx, _) in enumerate(mounts)]
            poses = [Pose(cid, mx, y0 + ly, zw[i], math.cos((spin[i] + pitch) / 2), 0.0,
                          math.sin((spin[i] + pitch) / 2), 0.0)
                     for i, (cid, (mx, _), (_, ly)) in enumerate(zip(ids, mounts, WHEELS))]
            await c.wait_ack(await c.send_poses(poses), timeout=60)
            idle, last = idle + (max(0, c.acked_tick - last - 1) if last else 0), c.acked_tick
            got = forces.pop(c.acked_tick, {})
            forces.clear()
            fx = fz = torque = 0.0
            for i, (mx, mz) in enumerate(mounts):
                f = got.get(ids[i])
                sx, sz, ty = (f.force[0], f.force[2], f.torque[1]) if f else (0.0, 0.0, 0.0)
                squeeze = REST - (mz - zw[i])
                rate_s = 0.0 if comp[i] is None else (squeeze - comp[i]) / dt
                comp[i] = squeeze
                push = max(0.0, K_SUSP * squeeze + C_SUSP * rate_s)
                motor = T_MAX * min(1.0, max(0.0, 1.0 - omega[i] / OMEGA_FREE))
                omega[i] += dt * (motor + ty) / WHEEL_I
                spin[i] += omega[i] * dt
                sink[i] += max(-STEP, min(STEP, (push - sz) / SEARCH_K))
                fx, fz = fx + sx, fz + push
                torque += (zw[i] - z) * sx - (mx - x) * push - motor
                if f and k >= HZ:
                    slips.append(f.slip)
                    sinks.append(f.sinkage_m)
            vx, vz = vx + dt * fx / MASS, vz + dt * (fz / MASS - G)
            rate += dt * torque / PITCH_I
            x, z, pitch = x + vx * dt, z + vz * dt, pitch + rate * dt
            track.append(x)
            if k % HZ == HZ - 1:
                n = max(len(slips[-4 * HZ:]), 1)
                print(f"{name}: t {(k + 1) / HZ:4.1f} s  x {x:5.2f} m  v {vx:5.2f} m/s  "
                      f"slip {sum(slips[-4 * HZ:]) / n:4.2f}  sinkage "
                      f"{1e3 * sum(sinks[-4 * HZ:]) / n:5.1f} mm", flush=True)
            if x - HALF_BASE > TOP_X:
                break  # the rear wheels are over the top
        end = 3 * HZ  # the last three seconds
        stalled = len(track) > end and track[-1] - track[-end] < 0.05
        n = max(len(slips[-4 * end:]), 1)
        return track[-1] - 0.6, sum(slips[-4 * end:]) / n, sum(sinks[-4 * end:]) / n, stalled, idle


async def main(ws, http, token):
    loop, runs = asyncio.get_running_loop(), {}
    for name, soil in SOILS.items():
        world = f"{name}-slope-{os.getpid()}"
        await loop.run_in_executor(None, lambda: terrad.create_world(http, world, scene=scene(soil),
                                                                     token=token))
        runs[name] = world
    try:
        results = await asyncio.gather(*(drive(ws, token, w, n) for n, w in runs.items()))
    finally:
        for world in runs.values():
            await loop.run_in_executor(None, lambda: terrad.delete_world(http, world, token=token))
    ok = True
    for name, (dist, slip, sink, stalled, idle) in zip(runs, results):
        top = dist + 0.6 - HALF_BASE > TOP_X
        verdict = "climbed" if top else ("bogged" if stalled and slip > 0.5 else "neither")
        print(f"{name}: {verdict}: moved {dist:.2f} m (the top is {TOP_X - 0.6 + HALF_BASE:.2f} m "
              f"away), slip {slip:.2f}, sinkage {sink * 1e3:.1f} mm over the last 3 s; "
              f"idle ticks {idle}")
        ok &= verdict == ("bogged" if name == "soft" else "climbed")
    return 0 if ok else 1


if __name__ == "__main__":
    args = sys.argv[1:] + ["ws://127.0.0.1:8081/", "http://127.0.0.1:8080/", ""][len(sys.argv) - 1:]
    sys.exit(asyncio.run(main(*args[:3])))
