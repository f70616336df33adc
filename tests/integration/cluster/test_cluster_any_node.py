"""test_cluster_any_node: any node serves any world (docs/cluster.md), on one
real nats-server with JetStream and two terrad nodes:

  - node a ticks "dunes"; node b ticks nothing and relays it;
  - a client connected to b (hello "world": "dunes") gets the world message
    from a (through b), drives a wheel: its pose batches go to a over NATS,
    its ACKs come back, and each tick's deltas, published once by a, are
    fanned out by b: the client sees its trail in its mirror, and the mirror
    equals a's GET /v1/heights?world=dunes cell for cell at the same tick;
  - a client on a sees the same trail (the deltas of b's client's wheel);
  - bad input through the relay is refused by the owner, to the client on b
    (a collider with a NaN radius: bad_value), and a hello naming a world
    nobody registered is refused by b (bad_value, close 4005);
  - b's client disconnecting removes its collider on a (colliders go to 0);
  - HTTP through the relay: b answers /v1/world, /v1/stats and /v1/heights
    for dunes by asking a over NATS: the same bytes as a's own port (base
    terrain, live heights once they stand still, PNG, errors), a rectangle
    too large for one NATS message is refused with 413 naming max_payload,
    a registered world no node ticks ("orphan") is a 503 saying so, an owner
    that does not answer (SIGSTOP) a 504 saying so, and
    terrad_http_forwarded_total counts each result;
  - the owner dies: node c (--worlds dunes, waiting) takes dunes; a viewer on
    b is told at once (shutting_down: the new owner does not know it) and
    closed; connecting to b again, it is served by c, and its mirror equals
    c's GET /v1/heights?world=dunes; b's HTTP answers for dunes now come
    from c. (b ticks a second world, "spare", so that only c can take dunes.)
No figure of speed is checked. Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 240
import asyncio
import json
import os
import sys
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import Checks, RecordingClient, metric_value, raw_hello, skip, tp  # noqa: E402

check = Checks()


async def eventually(client, predicate, timeout):
    try:
        await client.wait_for(predicate, timeout)
        return True
    except asyncio.TimeoutError:
        return predicate()


async def relayed_failover(a, b, c_node, lane):
    v = RecordingClient(b.ws, name="relayed-viewer", world="dunes")
    await v.connect()
    sid = await v.subscribe(*lane)
    await v.wait_for(lambda: v.mirrors[sid].complete, 30)
    a.kill9()
    told = await eventually(v, lambda: any(e.get("name") == "shutting_down" for e in v.errors)
                            or v.ws.closed, 60)
    check(told and wait_for(lambda: c_node.serves("dunes"), 30),
          f"after kill -9 of the owner, c ticks dunes and the viewer on b is told ({v.errors})")
    try:
        await v.close()
    except Exception:  # noqa: BLE001
        pass
    v = RecordingClient(b.ws, name="relayed-viewer-again", world="dunes")
    await v.connect()
    sid = await v.subscribe(*lane)
    await v.wait_for(lambda: v.mirrors[sid].complete, 30)
    _, server = c_node.heights("dunes", *lane)
    check(v.mirrors[sid].heights == server,
          "connected to b again, the viewer is served by c: its mirror equals c's heights")
    await v.close()


async def scenario(a, b):
    c = RecordingClient(b.ws, name="remote-driver", keep=900, world="dunes")
    await c.connect()
    check(c.world.get("world") == "dunes" and c.world.get("width", 0) > 0,
          f"the client on b gets dunes' world message ({str(c.world)[:160]})")
    w = c.world
    lane = (0, w["height"] // 2 - 32, w["width"], 64)
    sid = await c.subscribe(*lane)
    check(await eventually(c, lambda: c.mirrors[sid].complete, 30),
          "the subscription's snapshot arrives on b")
    v = RecordingClient(a.ws, name="local-viewer", keep=900, world="dunes")
    await v.connect()
    vsid = await v.subscribe(*lane)
    await v.wait_for(lambda: all(m.complete for m in v.mirrors.values()), 30)
    before = list(c.mirrors[sid].heights)
    try:
        await c.create_collider("sphere", radius=-1.0)
        check(False, "a negative radius through the relay is refused")
    except Exception as e:  # noqa: BLE001
        check("bad_value" in str(e) or "radius" in str(e),
              f"a negative radius through the relay is refused by the owner ({e})")
    cid = await c.create_collider("wheel", radius=0.4, width=0.3)
    cs, upm = w["cell_size_m"], w["units_per_m"]
    mirror = c.mirrors[sid]
    y = (lane[1] + 32) * cs
    x = 1.0
    t_end = time.monotonic() + 2.0
    while time.monotonic() < t_end:
        x += 3.0 / 60
        cx, cy = int(x / cs), int(y / cs) - mirror.y
        ground = mirror.heights[cy * mirror.w + cx] / upm
        await c.send_poses([tp.Pose(cid, x, y, ground + 0.25, 1, 0, 0, 0)])  # a wheel: axle along y
        await asyncio.sleep(1 / 60)
    park = tp.Pose(cid, x, y, 50.0, 1, 0, 0, 0)
    await c.send_poses([park])

    def changed_cells():
        return sum(1 for p, q in zip(before, c.mirrors[sid].heights) if p != q)
    deadline = time.monotonic() + 60  # the trail's deltas arrive, however loaded the machine
    while not (changed_cells() and c.counts["DELTA"] and c.counts["ACK"]) and time.monotonic() < deadline:
        await c.send_poses([park])
        await asyncio.sleep(0.05)
    changed = changed_cells()
    check(changed > 0 and c.counts["DELTA"] > 0 and c.counts["ACK"] > 0,
          f"the client on b sees its trail ({changed} cells changed, {c.counts})")
    same = False
    tick = None
    for _ in range(6):
        await c.send_poses([park])
        tick, server = a.heights("dunes", *lane)
        deadline = time.monotonic() + 10
        while c.acked_tick < tick and time.monotonic() < deadline:
            await c.send_poses([park])
            await asyncio.sleep(0.01)
        mine = c.history.get(tick, {}).get(sid)
        if mine and mine[1]:
            same = mine[0] == server
            break
    check(same, f"the mirror on b equals a's GET /v1/heights?world=dunes at tick {tick}")
    check(await eventually(v, lambda: v.mirrors[vsid].heights == c.mirrors[sid].heights, 10),
          "a client on a holds the same heights as the client on b")
    st = a.stats("dunes")
    check(st["colliders"] >= 1, f"a counts the relayed client's collider ({st['colliders']})")
    await c.close()
    check(wait_for(lambda: a.stats("dunes")["colliders"] == 0, 15),
          "after the client on b leaves, its collider is gone on a")
    await v.close()


def get(node, path):
    """(status, headers, body) of GET path on node, errors included."""
    try:
        with urllib.request.urlopen(node.http + path, timeout=30) as r:
            return r.status, dict(r.headers), r.read()
    except urllib.error.HTTPError as e:
        return e.code, dict(e.headers), e.read()


def http_through_relay(a, b):
    """b answers HTTP for dunes (ticked by a) with a's answers."""
    for path in ("/v1/world?world=dunes", "/v1/stats?world=dunes"):
        status, headers, body = get(b, path)
        check(status == 200 and headers.get("Content-Type") == "application/json",
              f"GET {path} on b answers 200 JSON ({status}, {body[:200]!r})")
    mine, theirs = json.loads(get(a, "/v1/world?world=dunes")[2]), json.loads(
        get(b, "/v1/world?world=dunes")[2])
    for key in ("tick", "ready"):
        mine.pop(key, None)
        theirs.pop(key, None)
    check(mine == theirs and theirs.get("world") == "dunes",
          f"/v1/world of dunes on b is a's ({theirs})")
    rect = "x=100&y=200&w=64&h=48"
    for query in (f"{rect}&base=1", f"{rect}&base=1&format=png16",
                  "x=0&y=0&w=3", "x=0&y=0&w=3&h=3&format=jpeg", "x=600&y=0&w=3&h=3"):
        sa, ha, ba = get(a, f"/v1/heights?world=dunes&{query}")
        sb, hb, bb = get(b, f"/v1/heights?world=dunes&{query}")
        same = sa == sb and ba == bb and all(ha.get(h) == hb.get(h) for h in (
            "Content-Type", "X-Terrad-Tick", "X-Terrad-Rect", "X-Terrad-Offset",
            "X-Terrad-Units-Per-Metre"))
        check(same, f"GET /v1/heights?{query} on b equals a's ({sa} {len(ba)} B, {sb} {len(bb)} "
              f"B: {bb[:160]!r})")
    live = False
    for _ in range(40):  # the live heights once they stand still between two reads of a
        a1 = get(a, f"/v1/heights?world=dunes&{rect}")[2]
        sb, hb, bb = get(b, f"/v1/heights?world=dunes&{rect}")
        if a1 == get(a, f"/v1/heights?world=dunes&{rect}")[2]:
            live = sb == 200 and bb == a1 and int(hb.get("X-Terrad-Tick", "0")) > 0
            break
        time.sleep(0.25)
    check(live, "live /v1/heights of dunes on b equals a's")
    status, _, body = get(b, "/v1/heights?world=dunes&x=0&y=0&w=512&h=512")
    check(status == 413 and b"max_payload" in body,
          f"a rectangle too large for one NATS message is refused with 413 ({status}, {body!r})")
    check(wait_for(lambda: any("relays world orphan" in l for l in b.lines), 30),
          "b relays orphan too")
    status, _, body = get(b, "/v1/stats?world=orphan")
    check(status == 503 and b"no node ticks world" in body,
          f"a registered world no node ticks: 503 saying so ({status}, {body!r})")
    status, _, body = get(b, "/v1/stats?world=nowhere")
    check(status == 404 and b"does not serve world" in body,
          f"a world nobody registered: 404 as before ({status}, {body!r})")
    metrics = get(b, "/metrics")[2].decode()
    counts = {r: metric_value(metrics, "terrad_http_forwarded_total", {"result": r}) or 0
              for r in ("answered", "no_owner", "not_relayed")}
    check(counts["answered"] >= 10 and counts["no_owner"] >= 1 and counts["not_relayed"] >= 1,
          f"terrad_http_forwarded_total on b counts each result ({counts})")
    # an owner that does not answer: asked once all its threads have stopped (a
    # process stops a while after kill() returns, and meanwhile it still answers)
    try:
        paused = a.pause()
        status, _, body = get(b, "/v1/stats?world=dunes")
    finally:
        a.resume()
    check(paused, "every thread of a stops on SIGSTOP")
    check(status == 504 and b"did not answer" in body,
          f"an owner that does not answer in time: 504 saying so ({status}, {body!r})")
    tick = (a.stats("dunes") or {}).get("tick", 0)
    check(wait_for(lambda: (a.stats("dunes") or {}).get("tick", 0) > tick + 30, 30),
          "a ticks dunes on after SIGCONT (its lapsed lease taken back)")


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    left = "SIGTERM stops every node left with status 0"
    with ch.NatsCluster(1) as nats, ch.running_nodes(
            check, [], stopped=lambda codes: all(c in (0, -9) for c in codes), said=left) as nodes:
        urls = nats.urls
        for name, scene in (("dunes", "server/scene/default.json"),
                            ("spare", "tests/scenes/tiny.json"),
                            ("orphan", "tests/scenes/tiny.json")):
            ok, said = ch.world_add(urls, name, scene)
            check(ok, f"world add {name}: {said}")
        a = Node("a", urls, extra=["--worlds", "dunes"])
        nodes.append(a)
        check(wait_for(lambda: a.serves("dunes"), 60), "node a ticks dunes")
        b = Node("b", urls, extra=["--worlds", "spare"])
        nodes.append(b)
        check(wait_for(lambda: any("relays world dunes" in l for l in b.lines), 30),
              "node b relays dunes")
        answer, code = asyncio.run(raw_hello(b, "nowhere"))
        check(answer.get("name") == "bad_value" and code == 4005,
              f"a hello naming an unregistered world is refused by b ({answer}, {code})")
        http_through_relay(a, b)
        asyncio.run(scenario(a, b))
        c = Node("c", urls, extra=["--worlds", "dunes"])
        nodes.append(c)
        check(wait_for(lambda: any("is a standby" in l for l in c.lines), 30),
              "node c waits for dunes")
        asyncio.run(relayed_failover(a, b, c, (0, 224, 256, 64)))
        base = "/v1/heights?world=dunes&x=0&y=0&w=128&h=128&base=1"
        check(wait_for(lambda: get(b, "/v1/stats?world=dunes")[0] == 200, 30) and
              get(b, base)[2] == get(c, base)[2] and get(b, base)[0] == 200,
              "after the failover, b answers HTTP for dunes again (now from c)")
    check.finish()


if __name__ == "__main__":
    main()
