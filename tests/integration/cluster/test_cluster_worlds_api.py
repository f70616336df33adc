"""test_cluster_worlds_api: the world lifecycle API on a cluster node (issue
22; docs/cluster.md "Worlds by HTTP"), against a real 3-server nats-server
JetStream cluster and two real `terrad serve --cluster` nodes:

  - POST /v1/worlds on node a registers a world; the answer names the node
    whose lease it took (a or b) once it has one;
  - a client says hello into the world on that node, subscribes, and sees an
    edit (POST /v1/worlds/{name}/edits on the owner) arrive as a delta;
  - GET /v1/worlds on node b lists every world of the cluster and its node;
  - bad input on a node is refused as on a single daemon, naming the field:
    an unsafe name, a taken name, a scene the parser refuses, a NaN (named by
    its key), both scene forms, scene_name without --scene-dir, DELETE of no
    such world, ?keep=1 (a cluster keeps no storage), a wrong method;
  - DELETE /v1/worlds/{name} on node b: the owner stops the world and its
    client is told and closed with 4020 "world deleted"; the list no longer
    has it; the same name can be created again;
  - `terrad world add|list|remove --http URL` (the same command line, a
    client of this API): add on node b, list on node a naming each world's
    node, a refused scene and an unknown world named by the server's words;
  - an admin connection on node b (in another world, "keeper") that sent
    subscribe_events hears world_created and world_deleted of the world
    made and ended through node a's and node b's HTTP.
Waits are by condition with generous deadlines (clusters are slow under
load); no figure of speed is checked. Skipped (77) without nats-server.
"""
# ctest-timeout: 300
import asyncio
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import (BIN, SOURCE, Checks, EventWatcher, json_call, metric_value, skip,  # noqa: E402
                             tp)

check = Checks()


def scene(name, w=64, h=48):
    return {"name": name, "world": {"width": w, "height": h, "cell_size_m": 0.05},
            "terrain": {"kind": "flat", "height_m": 0.5}}


def call(node, method, path, body=None, raw=None):
    """(status, JSON answer) of one request to node's HTTP port."""
    return json_call(node.http, method, path, body, raw=raw)


def listed(node):
    """{name: node} of GET /v1/worlds on node (None when it fails)."""
    status, doc = call(node, "GET", "/v1/worlds")
    return {w["name"]: w.get("node") for w in doc["worlds"]} if status == 200 else None


async def edit_seen(owner, world):
    """hello into world on owner, subscribe, POST an edit: the delta arrives."""
    c = tp.TerradClient(owner.ws, name="api-viewer", world=world)
    await asyncio.wait_for(c.connect(), 60)
    try:
        check(c.world.get("world") == world, f"hello into {world} on node {owner.name}")
        sid = await c.subscribe(0, 0, 16, 16)
        await c.wait_complete(sid, 60)
        before = c.heights(sid)
        before = before.copy() if tp.HAVE_NUMPY else [row[:] for row in before]
        loop = asyncio.get_running_loop()
        status, doc = await loop.run_in_executor(
            None, call, owner, "POST", f"/v1/worlds/{world}/edits",
            {"op": "add", "x": 2, "y": 2, "w": 4, "h": 4, "amount": 700})
        check(status == 200 and doc.get("volume_change") == 700 * 16,
              f"an edit through the owner's HTTP: {status} {doc}")
        deadline = loop.time() + 60
        moved = False
        while loop.time() < deadline and not moved:
            now = c.heights(sid)
            moved = bool((now != before).any()) if tp.HAVE_NUMPY else now != before
            await asyncio.sleep(0.05)
        check(moved, "the edit reached the subscriber as a delta")
        check(wait_for(lambda: metric_value(owner.get("/metrics")[1].decode(),
                                            "terrad_world_clients", {"world": world}) == 1, 60),
              f"the owner's /metrics counts the client in terrad_world_clients{{world={world}}}")
    finally:
        await c.close()


async def deleted_while_connected(owner, other, world):
    """A client in world on its owner; DELETE on the other node: told, closed 4020."""
    import websockets
    ws = await websockets.connect(owner.ws, subprotocols=[tp.SUBPROTOCOL], close_timeout=2)
    await ws.send(json.dumps(tp.hello("", "doomed", world)))
    hello = json.loads(await asyncio.wait_for(ws.recv(), 60))
    check(hello.get("type") == "world" and hello.get("world") == world, f"hello into {world}")
    loop = asyncio.get_running_loop()
    status, answer = await loop.run_in_executor(None, call, other, "DELETE", f"/v1/worlds/{world}")
    check(status == 200 and answer.get("deleted") is True and answer.get("name") == world,
          f"DELETE {world} on node {other.name}: {status} {answer}")
    error, code, reason = None, None, ""
    try:
        while True:
            msg = await asyncio.wait_for(ws.recv(), 90)
            if isinstance(msg, str) and json.loads(msg).get("type") == "error":
                error = json.loads(msg)
    except websockets.ConnectionClosed as e:
        code, reason = e.code, e.reason
    except asyncio.TimeoutError:
        pass
    check(error is not None and "deleted" in error.get("message", ""),
          f"its client was told the world was deleted: {error}")
    check(code == 4020 and reason == "world deleted",
          f"and closed 4020 'world deleted' ({code} {reason!r})")
    await ws.close()


def bad_inputs(a):
    cases = [
        ("unsafe name", {"name": "../etc", "scene": scene("s")}, 400, "name"),
        ("taken name", {"name": "arena", "scene": scene("dup")}, 409, "name"),
        ("scene refused", {"name": "w-bad", "scene": {"world": {"width": -1}}}, 422, "scene"),
        ("both scene forms", {"name": "w-two", "scene": scene("s"), "scene_name": "x"}, 400,
         "scene"),
        ("scene_name without --scene-dir", {"name": "w-sn", "scene_name": "flat"}, 400,
         "scene_name"),
        ("not an object", ["arena"], 400, "body"),
    ]
    for what, body, want, field in cases:
        status, doc = call(a, "POST", "/v1/worlds", body)
        check(status == want and doc.get("field") == field and
              doc.get("error", "").startswith(field),
              f"{what}: {want} naming {field} ({status} {doc})")
    raw = b'{"name": "w-nan", "scene": {"name": "s", "world": {"width": 8, "cell_size_m": NaN}}}'
    status, doc = call(a, "POST", "/v1/worlds", raw=raw)
    check(status == 400 and doc.get("field") == "cell_size_m" and
          doc.get("error", "").startswith("cell_size_m"),
          f"NaN in a scene: 400 naming cell_size_m ({status} {doc})")
    status, doc = call(a, "DELETE", "/v1/worlds/no-such-world")
    check(status == 404 and doc.get("field") == "name", f"DELETE of no such world: 404 ({doc})")
    status, doc = call(a, "DELETE", "/v1/worlds/arena?keep=1")
    check(status == 400 and doc.get("field") == "keep", f"?keep=1 on a cluster: 400 ({doc})")
    status, doc = call(a, "PUT", "/v1/worlds")
    check(status == 405, f"PUT /v1/worlds: 405 ({status})")
    names = listed(a) or {}
    check(not any(n.startswith("w-") for n in names), f"nothing refused was registered: {names}")


async def watch_events(b):
    """An admin on node b, in world keeper, subscribed to both events."""
    loop = asyncio.get_running_loop()
    end = loop.time() + 90
    while True:  # b relays keeper once its next listing (each second) has it
        watcher = await EventWatcher(b, world="keeper").connect()
        if watcher.hello.get("type") == "world" or loop.time() > end:
            break
        await watcher.close()
        await asyncio.sleep(0.2)
    check(watcher.hello.get("type") == "world", f"hello into keeper on b: {watcher.hello}")
    answer = await watcher.subscribe()
    check(answer and answer.get("type") == "events_subscribed",
          f"subscribe_events on a cluster node: {answer}")
    return watcher


async def heard(watcher, event, world):
    got = await watcher.next_event(90, event, world)
    check(got is not None, f"the admin on node b heard {event} {world}")


def scenario(a, b):
    status, doc = call(a, "POST", "/v1/worlds", {"name": "keeper", "scene": scene("keeper")})
    check(status == 201, f"POST keeper: {status} {doc}")
    check(wait_for(lambda: a.serves("keeper") or b.serves("keeper"), 90), "keeper is served")
    loop = asyncio.new_event_loop()
    watcher = loop.run_until_complete(watch_events(b))
    try:
        arena(a, b, loop, watcher)
    finally:
        loop.run_until_complete(watcher.close())
        loop.close()


def arena(a, b, loop, watcher):
    status, doc = call(a, "POST", "/v1/worlds", {"name": "arena", "scene": scene("arena")})
    check(status == 201 and doc.get("name") == "arena" and doc.get("node") in ("a", "b", None),
          f"POST /v1/worlds on node a: 201 naming the owner when it has one ({status} {doc})")
    # the answer names the owner once a node took the lease within 30 s; a
    # loaded machine may take longer, so the owner is whichever serves it
    owner = wait_for(lambda: next((n for n in (a, b) if n.serves("arena")), None), 90)
    check(owner is not None, "a node serves arena")
    owner = owner or a
    loop.run_until_complete(heard(watcher, "world_created", "arena"))
    loop.run_until_complete(edit_seen(owner, "arena"))
    check(wait_for(lambda: (listed(b) or {}).get("arena") == owner.name, 60),
          f"GET /v1/worlds on node b lists arena on node {owner.name}: {listed(b)}")
    bad_inputs(a)
    other = b if owner is a else a
    loop.run_until_complete(deleted_while_connected(owner, other, "arena"))
    check(wait_for(lambda: not owner.serves("arena"), 60), "the owner stopped ticking arena")
    loop.run_until_complete(heard(watcher, "world_deleted", "arena"))
    check(wait_for(lambda: listed(a) is not None and "arena" not in listed(a), 60),
          "GET /v1/worlds no longer lists arena")
    status, doc = call(b, "POST", "/v1/worlds", {"name": "arena", "scene": scene("arena2")})
    check(status == 201 and doc.get("name") == "arena", f"a deleted name is reused: {doc}")
    check(wait_for(lambda: a.serves("arena") or b.serves("arena"), 90), "and served again")


def world_cmd(node, *args):
    """`terrad world ... --http` against node: (exit status, stdout, stderr)."""
    p = subprocess.run([BIN, "world", *args, "--http", node.http], capture_output=True, text=True,
                       timeout=120)
    return p.returncode, p.stdout, p.stderr


def command_line(a, b):
    rc, out, err = world_cmd(b, "add", "cli-w", "--scene",
                             os.path.join(SOURCE, "tests", "scenes", "tiny.json"))
    check(rc == 0 and out.startswith("world cli-w added"), f"world add --http on b ({rc} {out!r} "
          f"{err!r})")
    check(wait_for(lambda: a.serves("cli-w") or b.serves("cli-w"), 90), "cli-w is served")
    owner = "a" if a.serves("cli-w") else "b"
    check(wait_for(lambda: f"cli-w {owner}\n" in world_cmd(a, "list")[1], 60),
          f"world list --http on a names cli-w on node {owner}: {world_cmd(a, 'list')}")
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        f.write('{"world": {"width": -1}}')
        bad = f.name
    rc, out, err = world_cmd(a, "add", "cli-bad", "--scene", bad)
    os.unlink(bad)
    check(rc == 1 and "422: scene: world.width" in err, f"a refused scene: the server's words "
          f"({rc} {err!r})")
    rc, out, err = world_cmd(a, "remove", "cli-w")
    check(rc == 0 and out == "world cli-w removed\n", f"world remove --http ({rc} {err!r})")
    rc, out, err = world_cmd(a, "remove", "cli-w")
    check(rc == 1 and "404: name: no such world" in err, f"remove an unknown world ({rc} {err!r})")


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    both = "SIGTERM stops both nodes with status 0"
    with ch.NatsCluster(3) as nats, ch.running_nodes(
            check, [], nats, stopped=lambda codes: codes == [0, 0], said=both) as nodes:
        a = Node("a", nats.urls, max_worlds=2)
        b = Node("b", nats.urls, max_worlds=2)
        nodes += [a, b]
        check(wait_for(lambda: a.up() and b.up(), 90), "both nodes are up (standbys)")
        scenario(a, b)
        command_line(a, b)
    check.finish()


if __name__ == "__main__":
    main()
