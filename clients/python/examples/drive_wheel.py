#!/usr/bin/env python3
"""Drive a wheel across the terrain and check the deltas against the server.

    pip install ./clients/python        # once (see clients/python/README.md)
    python3 clients/python/examples/drive_wheel.py [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/]

Connects, creates a wheel, subscribes to the strip it drives along and sends
a pose every tick for three seconds. Then it parks the wheel above the snow
(still sending a pose each tick, so an ACK closes every tick), asks the
server for the heights of the strip (GET /v1/heights, which names its tick)
and compares them with what it rebuilt from snapshots and deltas at that
very tick: they must be equal, cell for cell, even while other colliders
(the demo actors) keep deforming the world. Only terrad's public API.
"""
import asyncio
import functools
import math
import sys

import terrad
from terrad import Client, MsgType, Pose


async def drive(ws_uri: str, http_uri: str) -> bool:
    loop = asyncio.get_running_loop()
    async with Client(ws_uri) as client:
        world = client.world
        cell, units, hz = world["cell_size_m"], world["units_per_m"], world["tick_hz"]
        y_cell = world["height"] // 2
        region = (8, y_cell - 24, min(world["width"] - 16, 160), 48)
        sid = await client.subscribe(*region)
        # Every DELTA of tick t arrives before the ACK of tick t: keep the mirror at each ACK.
        history = {}

        def at_ack(tick, seq):
            if client.mirrors[sid].complete:
                history[tick] = client.heights(sid)
                history.pop(tick - 600, None)

        client.on(MsgType.ACK, at_ack)
        read = functools.partial(terrad.get_heights, http_uri)  # GET /v1/heights
        _, start = await loop.run_in_executor(None, read, region[0] + 12, y_cell, 1, 1)
        ground = int(start[0][0]) / units
        radius = 0.3
        wheel = await client.create_collider("wheel", radius=radius, width=0.2)
        x0, x1 = (region[0] + 12) * cell, (region[0] + region[2] - 12) * cell
        y = (y_cell + 0.5) * cell
        ticks = int(3 * hz)
        deepest = 0
        for i in range(ticks):
            x = x0 + (x1 - x0) * i / (ticks - 1)
            angle = (x - x0) / radius  # rolling about the axle (local y)
            q = (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)
            await client.send_poses([Pose(wheel, x, y, ground + radius - 0.06, *q)])
            await asyncio.sleep(1 / hz)
            if wheel in client.contacts:
                deepest = max(deepest, client.contacts[wheel].volume)

        parked = True

        async def keep_acking():
            while parked:
                await client.send_poses([Pose(wheel, x1, y, ground + 5.0, 1.0, 0.0, 0.0, 0.0)])
                await asyncio.sleep(0.5 / hz)  # twice per tick: every tick gets its ACK

        acker = loop.create_task(keep_acking())
        mine = None
        try:
            for _ in range(5):  # a tick that happened to get no batch has no ACK: read again
                tick, server = await loop.run_in_executor(None, read, *region)
                await client.wait_for(lambda: client.acked_tick >= tick, timeout=10)
                mine = history.get(tick)
                if mine is not None:
                    break
        finally:
            parked = False
            await acker
        same = mine is not None and len(mine) == len(server) and all(list(a) == list(b) for a, b in zip(mine, server))
        print(f"drove {ticks} ticks; at tick {tick} the mirror {'==' if same else '!='} "
              f"GET /v1/heights over {region[2]}x{region[3]} cells")
        print(f"deepest contact while driving: {deepest} height units x cells "
              f"({'NumPy' if terrad.HAVE_NUMPY else 'lists'})")
        return same


if __name__ == "__main__":
    ws = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8081/"
    http = sys.argv[2] if len(sys.argv) > 2 else "http://127.0.0.1:8080/"
    sys.exit(0 if asyncio.run(drive(ws, http)) else 1)
