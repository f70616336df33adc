"""test_cluster_node_worlds: one `terrad serve --cluster` node ticks several
worlds (docs/cluster.md), on one real nats-server with JetStream:

  - node a (--max-worlds 3) takes the three registered worlds, each ticking
    on its own sim thread, all on one HTTP and one websocket port;
  - /v1/world, /v1/stats and /v1/heights take ?world=NAME (each world's own
    extent and tick); an unknown world is a 404 JSON error naming the worlds
    served; /metrics has the per-world series labelled world="NAME" and
    passes `promtool check metrics` (when installed);
  - hello picks the world: the world message names it and has its extent; a
    hello naming a world the node does not serve is refused (bad_value,
    close 4005) naming the ones it serves;
  - a client drives a sphere in "dunes": its mirror equals GET
    /v1/heights?world=dunes, and Σh of the other worlds is untouched;
  - one world lost while the others go on: `terrad world remove tiny`; the
    node sees it gone from the registry (or is fenced off at its next commit),
    stops ticking tiny, its client is told and closed, /v1/stats?world=tiny is 404, dunes ticks on;
  - failover of a node with several worlds: node b (standby, --max-worlds 2)
    takes both worlds after a kill -9 of node a; Σh and the heights equal the
    client's mirror of its last acknowledged tick (the terrain had settled).
No figure of speed is checked. Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 300
import asyncio
import json
import os
import shutil
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import BIN, SOURCE, Checks, RecordingClient, raw_hello, skip, tp  # noqa: E402

check = Checks()
WORLDS = {"dunes": "server/scene/default.json", "spheres": "tests/scenes/spheres.json",
          "tiny": "tests/scenes/tiny.json"}


def world_cmd(urls, *args):
    return subprocess.run([BIN, "world", *args, "--cluster", urls], capture_output=True,
                          text=True, timeout=60)


def http_views(a):
    sizes = {}
    for w in WORLDS:
        status, body = a.get(f"/v1/world?world={w}")
        info = json.loads(body) if status == 200 else {}
        check(status == 200 and info.get("world") == w, f"/v1/world?world={w} names it ({status})")
        sizes[w] = (info.get("width"), info.get("height"))
    check(sizes["dunes"] != sizes["tiny"] and sizes["tiny"] == (1, 1),
          f"each world has its own extent ({sizes})")
    t0 = {w: a.stats(w)["tick"] for w in WORLDS}
    ok = wait_for(lambda: all(a.stats(w)["tick"] > t0[w] for w in WORLDS), 20)
    check(ok, f"all three worlds tick on node a ({t0} -> {[a.stats(w)['tick'] for w in WORLDS]})")
    status, body = a.get("/v1/stats?world=nope")
    err = json.loads(body).get("error", "") if body.startswith(b"{") else ""
    check(status == 404 and '"nope"' in err and '"dunes"' in err and '"tiny"' in err,
          f"an unknown world is a 404 naming the worlds served ({status}: {body[:300]!r})")
    status, body = a.get("/v1/heights?world=nope&x=0&y=0&w=1&h=1")
    check(status == 404, f"/v1/heights of an unknown world is 404 ({status})")
    status, body = a.get("/metrics")
    text = body.decode()
    for w in WORLDS:
        check(f'terrad_world_tick{{world="{w}"}}' in text and
              f'terrad_world_volume{{world="{w}"}}' in text, f"/metrics has world=\"{w}\" series")
    promtool = shutil.which("promtool")
    if promtool:
        r = subprocess.run([promtool, "check", "metrics"], input=body, capture_output=True,
                           timeout=30)
        check(r.returncode == 0, f"promtool check metrics passes: {(r.stdout + r.stderr)[:800]!r}")


def hellos(a):
    answer, code = asyncio.run(raw_hello(a, "spheres"))
    check(answer.get("type") == "world" and answer.get("world") == "spheres" and
          answer.get("width") == 256 and code is None,
          f"a hello naming spheres gets spheres' world message ({str(answer)[:200]}, {code})")
    answer, code = asyncio.run(raw_hello(a, "nope"))
    msg = answer.get("message", "")
    check(answer.get("name") == "bad_value" and code == 4005 and '"nope"' in msg and
          all(f'world "{w}"' in msg for w in WORLDS),
          f"a hello naming a world not served is refused naming those served ({answer}, {code})")


async def drive(node, world, run_s=1.5):
    """Drives a sphere through world, lifts it, waits until the terrain settled; returns
    the client (still connected), its lane and its collider."""
    c = RecordingClient(node.ws, name="driver", keep=600, world=world)
    await c.connect()
    w = c.world
    lane = (0, w["height"] // 2 - 32, w["width"], 64)
    sid = await c.subscribe(*lane)
    await c.wait_for(lambda: all(m.complete for m in c.mirrors.values()), 30)
    cid = await c.create_collider("sphere", radius=0.4)
    cs, upm = w["cell_size_m"], w["units_per_m"]
    mirror = c.mirrors[sid]
    x, y, vx = 1.0, (lane[1] + 32) * cs, 4.0
    t_end = time.monotonic() + run_s
    while time.monotonic() < t_end:
        x += vx / 60
        cx, cy = int(x / cs), int(y / cs) - mirror.y
        ground = mirror.heights[cy * mirror.w + cx] / upm
        await c.send_poses([tp.Pose(cid, x, y, ground + 0.25, 1, 0, 0, 0)])
        await asyncio.sleep(1 / 60)
    park = tp.Pose(cid, x, y, 50.0, 1, 0, 0, 0)
    await ch.settled(c, sid, park)  # quiescent by condition, not after a fixed sleep
    return c, lane, sid, park


async def mirror_equals(c, node, world, lane, sid, park):
    """GET /v1/heights?world= of the lane equals the client's copy at that tick."""
    loop = asyncio.get_running_loop()
    for _ in range(6):
        await c.send_poses([park])
        tick, server = await loop.run_in_executor(None, node.heights, world, *lane)
        deadline = loop.time() + 10
        while c.acked_tick < tick and loop.time() < deadline:
            await c.send_poses([park])
            await asyncio.sleep(0.01)
        mine = c.history.get(tick, {}).get(sid)
        if mine and mine[1]:
            return mine[0] == server, tick
    return False, None


async def drive_and_compare(a, volumes):
    c, lane, sid, park = await drive(a, "dunes")
    same, tick = await mirror_equals(c, a, "dunes", lane, sid, park)
    check(same, f"the client's mirror of dunes equals GET /v1/heights?world=dunes (tick {tick})")
    check(a.stats("dunes")["volume"] == volumes["dunes"], "Σh of dunes is conserved")
    for w in ("spheres", "tiny"):
        check(a.stats(w)["volume"] == volumes[w], f"Σh of {w} is untouched by the drive in dunes")
    return c, lane, sid, park


async def lose_one_world(a, urls):
    t = RecordingClient(a.ws, name="tiny-viewer", world="tiny")
    await t.connect()
    await t.subscribe(0, 0, 1, 1)
    r = world_cmd(urls, "remove", "tiny")
    check(r.returncode == 0, f"world remove tiny: {r.stderr.strip()}")
    # the node sees tiny gone from the registry (its next listing), or is
    # fenced off at its next commit: either way it stops ticking tiny
    lost = wait_for(lambda: not a.serves("tiny") and
                    any("world tiny was deleted from the registry" in l or
                        "no longer owns world tiny" in l for l in a.lines), 60)
    check(lost, "node a says tiny was deleted (or that it no longer owns it)")
    await asyncio.sleep(1)
    check(any(e.get("name") == "shutting_down" for e in t.errors) or t.ws.closed,
          f"tiny's client was told and closed ({t.errors})")
    status, _ = a.get("/v1/stats?world=tiny")
    check(status == 404, f"/v1/stats?world=tiny is 404 once tiny is gone ({status})")
    t0 = a.stats("dunes")["tick"]
    check(wait_for(lambda: a.stats("dunes")["tick"] > t0, 10), "dunes ticks on")
    try:
        await t.close()
    except Exception:  # noqa: BLE001
        pass


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    last = "SIGTERM stops the last node with status 0"
    with ch.NatsCluster(1) as nats, ch.running_nodes(
            check, [], nats, stopped=lambda codes: codes and codes[-1] == 0, said=last) as nodes:
        urls = nats.urls
        for name, scene in WORLDS.items():
            r = world_cmd(urls, "add", name, "--scene", os.path.join(SOURCE, scene))
            check(r.returncode == 0, f"world add {name}: {r.stderr.strip()}")
        a = Node("a", urls, max_worlds=3)
        nodes.append(a)
        check(wait_for(lambda: a.worlds >= set(WORLDS), 60), f"node a serves {sorted(WORLDS)}")
        http_views(a)
        hellos(a)
        volumes = {w: a.stats(w)["volume"] for w in WORLDS}
        b = None

        async def scenario():
            nonlocal b
            c, lane, sid, park = await drive_and_compare(a, volumes)
            await lose_one_world(a, urls)
            b = Node("b", urls, max_worlds=2)
            nodes.append(b)
            check(wait_for(lambda: b.listening.is_set() and
                           any("is a standby" in l for l in b.lines), 30),
                  "node b waits as a standby")
            acked = c.acked_tick
            mine = c.history.get(acked, {}).get(sid)
            a.kill9()
            took = wait_for(lambda: b.serves("dunes") and b.serves("spheres"), 60)
            check(took, "node b serves dunes and spheres after kill -9 of node a")
            if took:
                st = b.stats("dunes")
                check(st["tick"] >= acked and st["volume"] == volumes["dunes"],
                      f"dunes on b: tick {st['tick']} >= acked {acked}, Σh unchanged")
                check(b.stats("spheres")["volume"] == volumes["spheres"],
                      "spheres on b: Σh unchanged")
                _, heights = b.heights("dunes", *lane)
                check(mine is not None and heights == mine[0],
                      "GET /v1/heights?world=dunes on b equals the client's mirror of its "
                      f"last acknowledged tick {acked}")
            try:
                await c.close()
            except Exception:  # noqa: BLE001
                pass

        asyncio.run(scenario())
    check.finish()


if __name__ == "__main__":
    main()
