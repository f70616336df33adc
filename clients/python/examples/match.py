#!/usr/bin/env python3
"""Play a short match the way a game backend would (issue 22).

    pip install ./clients/python        # once (see clients/python/README.md)
    python3 clients/python/examples/match.py [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/] [TOKEN]

1. creates a world for the match (POST /v1/worlds: a small flat arena);
2. two players say hello into it and each drives a wheel across the arena;
3. game logic fires a crater between them (an `edit`; its rim keeps the
   arena's sum of heights exactly);
4. the arena is reset between rounds (`reset`: back to the scene's terrain);
5. the world is deleted (DELETE /v1/worlds/{name}); the players are told
   (close 4020, "world deleted").

It checks what it can see from the outside: the wheels leave ruts, the
crater's reply declares no volume change and /v1/stats agrees, the reset
gives the base terrain back, and the world is gone from GET /v1/worlds.
TOKEN: an admin token where the daemon has an --auth-file. Only terrad's
public API. Exit status 0 when every step went as described.
"""
import asyncio
import json
import math
import os
import sys
import urllib.request

import terrad
from terrad import Client, Pose

GROUND_M = 0.5  # the arena's flat terrain
ARENA: dict = {"name": "arena", "world": {"width": 160, "height": 96, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": GROUND_M}, "material": {"repose_deg": 32}}


def stats(http: str, world: str, token: str) -> dict:
    req = urllib.request.Request(f"{http.rstrip('/')}/v1/stats?world={world}")
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


async def player(ws: str, token: str, world: str, name: str, lane_y: float) -> tuple[Client, int, int]:
    """A player in the match's world, with a wheel and a subscription to its lane."""
    c = Client(ws, token=token, name=name, world=world)
    await c.connect()
    cells = c.world["cell_size_m"]
    sid = await c.subscribe(0, int(lane_y / cells) - 8, c.world["width"], 16)
    await c.wait_complete(sid, 60)
    wheel = await c.create_collider("wheel", radius=0.25, width=0.15)
    return c, wheel, sid


async def drive(c: Client, wheel: int, lane_y: float, ground: float, ticks: int) -> None:
    """Across the arena, a pose a tick, each batch acknowledged."""
    x0, x1 = 1.0, c.world["width"] * c.world["cell_size_m"] - 1.0
    for i in range(ticks):
        x = x0 + (x1 - x0) * i / (ticks - 1)
        q = (math.cos(x / 0.25 / 2), 0.0, math.sin(x / 0.25 / 2), 0.0)  # rolling
        seq = await c.send_poses([Pose(wheel, x, lane_y, ground + 0.25 - 0.04, *q)])
        await c.wait_ack(seq, 60)


def changed(before, after) -> int:
    return sum(1 for a, b in zip(before, after) for u, v in zip(a, b) if u != v)


async def match(ws: str, http: str, token: str) -> bool:
    ok = True
    loop = asyncio.get_running_loop()
    name = f"match-{os.getpid()}"
    made = await loop.run_in_executor(None, lambda: terrad.create_world(http, name, scene=ARENA,
                                                                        token=token))
    print(f"created world {made['name']}: {made['width']}x{made['height']} cells, {made['state']}")
    ground = GROUND_M
    a, wa, sa = await player(ws, token, name, "red", 1.5)
    b, wb, sb = await player(ws, token, name, "blue", 3.3)
    before = (a.heights(sa).tolist() if terrad.HAVE_NUMPY else a.heights(sa),
              b.heights(sb).tolist() if terrad.HAVE_NUMPY else b.heights(sb))
    await asyncio.gather(drive(a, wa, 1.5, ground, 90), drive(b, wb, 3.3, ground, 90))
    ruts = [changed(before[0], a.heights(sa).tolist() if terrad.HAVE_NUMPY else a.heights(sa)),
            changed(before[1], b.heights(sb).tolist() if terrad.HAVE_NUMPY else b.heights(sb))]
    print(f"two wheels drove across: {ruts[0]} and {ruts[1]} cells of their lanes changed")
    ok &= min(ruts) > 0
    await a.delete_collider(wa)  # the round is over: the wheels leave the arena
    await b.delete_collider(wb)
    volume = await loop.run_in_executor(None, stats, http, name, token)
    r = await a.edit("crater", x=80, y=48, radius=10, depth=2000)
    after = await loop.run_in_executor(None, stats, http, name, token)
    while after["tick"] < r["tick"]:
        await asyncio.sleep(0.02)
        after = await loop.run_in_executor(None, stats, http, name, token)
    print(f"crater at tick {r['tick']}: volume change {r['volume_change']} (Σh {volume['volume']} → "
          f"{after['volume']}: its rim kept it)")
    ok &= r["volume_change"] == 0 and after["volume"] == volume["volume"]
    r = await b.edit("reset")
    print(f"arena reset at tick {r['tick']} (volume change {r['volume_change']})")
    flat = int(ground * a.world["units_per_m"])

    def lane_flat() -> bool:
        lane = a.heights(sa).tolist() if terrad.HAVE_NUMPY else a.heights(sa)
        return all(v == flat for row in lane for v in row)
    try:
        await a.wait_for(lane_flat, 60)  # the reset's deltas follow its tick
    except asyncio.TimeoutError:
        pass
    print(f"red's lane is the flat arena again: {lane_flat()}")
    ok &= lane_flat()
    gone = await loop.run_in_executor(None, lambda: terrad.delete_world(http, name, token=token))
    try:
        await a.wait_for(lambda: a.ws is None or a.ws.close_code is not None, 30)
    except asyncio.TimeoutError:
        pass
    code = a.ws.close_code if a.ws is not None else None
    print(f"world {gone['name']} deleted; red's connection closed with {code}")
    ok &= gone["deleted"] and code == 4020
    names = [w["name"] for w in await loop.run_in_executor(
        None, lambda: terrad.list_worlds(http, token=token))]
    ok &= name not in names
    print(f"worlds now: {names}")
    for c in (a, b):
        await c.close()
    return bool(ok)


if __name__ == "__main__":
    ws = sys.argv[1] if len(sys.argv) > 1 else "ws://127.0.0.1:8081/"
    http = sys.argv[2] if len(sys.argv) > 2 else "http://127.0.0.1:8080/"
    token = sys.argv[3] if len(sys.argv) > 3 else ""
    sys.exit(0 if asyncio.run(match(ws, http, token)) else 1)
