#!/usr/bin/python3
"""Drive a wheel across the terrain and check the deltas against the server.

    /usr/bin/python3 proto/python/examples/drive_wheel.py [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/]

Connects, creates a wheel, subscribes to the strip it drives along and sends
a pose every tick for three seconds. Then it parks the wheel above the snow
(still sending a pose each tick, so an ACK closes every tick), asks the
server for the heights of the strip (GET /v1/heights, which names its tick)
and compares them with what it rebuilt from snapshots and deltas at that
very tick: they must be equal, cell for cell, even while other colliders
(the demo actors) keep deforming the world.
Runs under Debian's python3 (python3-websockets, python3-zstandard).
"""
import asyncio
import math
import os
import struct
import sys
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
from terrad_proto import MsgType, Pose, TerradClient, decode_header  # noqa: E402


class RecordingClient(TerradClient):
    """Keeps the mirror's heights as they were when each tick's ACK came:
    every DELTA of tick t arrives before the ACK of tick t."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.history = {}

    async def _on_binary(self, data: bytes) -> None:
        await super()._on_binary(data)
        if decode_header(data) == MsgType.ACK:
            self.history[self.acked_tick] = {s: list(m.heights) for s, m in self.mirrors.items()}
            for old in [t for t in self.history if t < self.acked_tick - 600]:
                del self.history[old]


def get_heights(http_uri, x, y, w, h):
    with urllib.request.urlopen(f"{http_uri}v1/heights?x={x}&y={y}&w={w}&h={h}") as r:
        return int(r.headers["X-Terrad-Tick"]), list(struct.unpack(f"<{w * h}i", r.read()))


async def drive(ws_uri: str, http_uri: str) -> bool:
    loop = asyncio.get_running_loop()
    async with RecordingClient(ws_uri) as client:
        world = client.world
        cell, units, hz = world["cell_size_m"], world["units_per_m"], world["tick_hz"]
        y_cell = world["height"] // 2
        region = (8, y_cell - 24, min(world["width"] - 16, 160), 48)
        sid = await client.subscribe(*region)
        _, start = await loop.run_in_executor(None, get_heights, http_uri, region[0] + 12,
                                              y_cell, 1, 1)
        ground = start[0] / units
        radius = 0.3
        wheel = await client.create_collider("wheel", radius=radius, width=0.2)
        x0, x1 = (region[0] + 12) * cell, (region[0] + region[2] - 12) * cell
        y = (y_cell + 0.5) * cell
        ticks = int(3 * hz)
        for i in range(ticks):
            x = x0 + (x1 - x0) * i / (ticks - 1)
            angle = (x - x0) / radius  # rolling about the axle (local y)
            q = (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)
            await client.send_poses([Pose(wheel, x, y, ground + radius - 0.06, *q)])
            await asyncio.sleep(1 / hz)

        parked = True

        async def keep_acking():
            while parked:
                await client.send_poses([Pose(wheel, x1, y, ground + 5.0, 1.0, 0.0, 0.0, 0.0)])
                await asyncio.sleep(0.5 / hz)  # twice per tick: every tick gets its ACK

        acker = loop.create_task(keep_acking())
        try:
            for _ in range(5):  # a tick that happened to get no batch has no ACK: read again
                tick, server = await loop.run_in_executor(None, get_heights, http_uri, *region)
                await client.wait_for(lambda: client.acked_tick >= tick, timeout=10)
                mine = client.history.get(tick, {}).get(sid)
                if mine is not None:
                    break
        finally:
            parked = False
            await acker
        same = mine == server
        contact = client.contacts.get(wheel)
        print(f"drove {ticks} ticks; at tick {tick} the mirror {'==' if same else '!='} "
              f"GET /v1/heights over {region[2]}x{region[3]} cells")
        if contact is not None:
            print(f"last contact: volume {contact.volume} units*cells, support "
                  f"{contact.support_height_m:.3f} m")
        return same


if __name__ == "__main__":
    ws = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8081/"
    http = sys.argv[2] if len(sys.argv) > 2 else "http://127.0.0.1:8080/"
    sys.exit(0 if asyncio.run(drive(ws, http)) else 1)
