#!/usr/bin/python3
# ctest-timeout: 600
"""Many worlds on one daemon's shared pool of sim workers (issue 22, item 2),
against the real daemon, its real websocket and HTTP ports:

- 70 worlds created by POST /v1/worlds (more than the 63 the daemon held
  before the pool) all tick; the 71st is refused naming max_worlds;
- the worlds cost no thread each: the daemon's thread count stays where it
  was before them (the pool's workers are started with the daemon; a
  world's snapshot worker only once a client subscribes);
- spheres driven in three worlds at once deform each of them, and a world
  nobody drives keeps its terrain;
- deleting every world brings threads and descriptors back to their level.

Behaviour only: every wait is for a condition, with a generous deadline.
(Heights on the pool bit-identical to a world alone: tests/unit/test_ticker.c.)
"""
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon, json_call, tp  # noqa: E402
from waiting import wait_for  # noqa: E402

check = Checks()
WORLDS = 70
SIZE = 32  # cells a side, 5 cm each


def scene(name):
    return {"name": name, "world": {"width": SIZE, "height": SIZE, "cell_size_m": 0.05},
            "terrain": {"kind": "flat", "height_m": 0.5}}


def call(d, method, path, body=None):
    return json_call(d.http, method, path, body)


def ticks(d):
    status, doc = call(d, "GET", "/v1/worlds")
    return {w["name"]: w["tick"] for w in doc.get("worlds", []) if not w["default"]}


def count(pid, what):
    return len(os.listdir(f"/proc/{pid}/{what}"))


def heights(d, world):
    status, body, _ = d.get(f"/v1/heights?x=0&y=0&w={SIZE}&h={SIZE}&world={world}", timeout=60)
    return body if status == 200 else None


async def drive(d, world):
    """Hello into world, press a sphere in, a little deeper each tick, until its terrain moves."""
    c = tp.TerradClient(d.ws, name="driver", world=world)
    await asyncio.wait_for(c.connect(), 60)
    try:
        sid = await c.subscribe(0, 0, SIZE, SIZE)
        await c.wait_complete(sid, 60)
        before = c.heights(sid).copy() if tp.HAVE_NUMPY else [r[:] for r in c.heights(sid)]
        cid = await c.create_collider("sphere", radius=0.3)
        for i in range(600):
            seq = await c.send_poses([tp.Pose(cid, 0.8, 0.8, 0.5 + 0.3 - 0.002 * min(i, 100))])
            await c.wait_ack(seq, 60)
            now = c.heights(sid)
            if (now != before).any() if tp.HAVE_NUMPY else now != before:
                return True
        return False
    finally:
        await c.close()


async def drive_three(d, names):
    return await asyncio.gather(*(drive(d, n) for n in names))


def main():
    d = Daemon(backend="cpu", extra=["--no-data", "--max-worlds", str(WORLDS),
                                     "--scene", os.path.join(SOURCE, "tests/scenes/tiny.json")])
    with check.running(d):
        check(wait_for(lambda: d.get("/readyz")[0] == 200, 60), "the daemon is ready")
        threads0, fds0 = count(d.pid, "task"), count(d.pid, "fd")

        names = [f"pool-{i}" for i in range(WORLDS)]
        created = [call(d, "POST", "/v1/worlds", {"name": n, "scene": scene(n)})[0] for n in names]
        check(all(s == 201 for s in created), f"{WORLDS} worlds created "
              f"({sum(s == 201 for s in created)} answered 201)")
        status, doc = call(d, "POST", "/v1/worlds", {"name": "one-too-many", "scene": scene("x")})
        check(status == 409 and doc.get("field") == "max_worlds",
              f"world {WORLDS + 1}: 409 naming max_worlds ({status} {doc})")

        first = ticks(d)
        check(len(first) == WORLDS, f"GET /v1/worlds lists {WORLDS} created worlds ({len(first)})")
        moving = wait_for(lambda: all(t >= first.get(n, 0) + 5 for n, t in ticks(d).items()), 120)
        check(moving, "every world on the pool ticks")
        threads = count(d.pid, "task")
        check(threads <= threads0, f"{WORLDS} idle worlds cost no thread: {threads} threads, "
              f"{threads0} before them")

        still = heights(d, names[3])
        moved = asyncio.run(drive_three(d, names[:3]))
        check(all(moved), f"spheres driven in three worlds at once deform each ({moved})")
        check(still is not None and heights(d, names[3]) == still,
              "a world nobody drives keeps its terrain")

        deleted = [call(d, "DELETE", f"/v1/worlds/{n}")[0] for n in names]
        check(all(s == 200 for s in deleted), f"every world deleted "
              f"({sum(s == 200 for s in deleted)} answered 200)")
        back = wait_for(lambda: count(d.pid, "task") <= threads0 and count(d.pid, "fd") <= fds0,
                        60, step=0.2)
        check(back, f"threads {count(d.pid, 'task')} (were {threads0}) and descriptors "
              f"{count(d.pid, 'fd')} (were {fds0}) back to their level")
    check.finish()


if __name__ == "__main__":
    main()
