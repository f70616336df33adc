"""test_cluster_relay_budget: a budgeted client and a client that stops reading, both
through a relay (docs/cluster.md "Any node serves any world"), on one real nats-server with
JetStream and two real terrad nodes: a ticks "dunes" (a flat 512 x 256 world, so its
snapshots are small), b ticks "spare" and relays dunes. The relay holds the client's socket,
so it is the relay that must keep the client's budget (PROTOCOL.md "Budgets") and judge its
lag (PROTOCOL.md "seen", max_client_lag_ticks):

- budget: a client on b states a 20,000 bytes/s budget and subscribes to the world, another
  on b states none (given max_budget_bytes_per_s, 64 KiB/s); a driver on a digs a burst of
  200 large craters (60-85 KB of deltas, more than the budget in a tick or two, however
  fast the machine). By b's own accounting (its line for the client when it leaves, as
  test_budget reads the daemon's) the budgeted client's fullest second held at most its
  budget, deltas were coalesced for it, b counts no overrun, and the wider client's fullest
  second held more than the budget (so the budget did bind); once the craters stop, the
  budgeted mirror equals a's GET /v1/heights.
- lag: a client on b subscribed to the world stops reading (its frames wait in its own
  buffers and the sockets': it says no "seen") while the driver keeps cratering. b judges it
  behind by what it said or by its queue's oldest frame (a "has handled tick ... behind" or
  "is stale" line naming it; terrad_clients_behind_total or terrad_clients_stale_total of b
  counts it); once the craters stop and it reads again, it is sent snapshots (SNAPSHOT
  rectangles arrive after it drains) and its mirror equals a's GET /v1/heights, its
  connection open.
No figure of speed is checked: every wait is a condition with a generous deadline.
Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 300
import asyncio
import json
import os
import random
import re
import sys
import time
import urllib.error

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import (Checks, CountingClient, RecordingClient, json_file,  # noqa: E402
                             metric_value, skip, tp)

check = Checks()
BUDGET = 20000
LIMIT = 65536
LAG = 30  # max_client_lag_ticks: half a second at 60 Hz
REGION = (0, 0, 512, 256)
SCENE = {"name": "relay-budget", "world": {"width": 512, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
CONFIG = {"limits": {"max_budget_bytes_per_s": LIMIT, "max_client_lag_ticks": LAG}}


def crater(rng, big=True):
    x0, y0, w, h = REGION
    if big:
        return tp.edit("crater", x=rng.randrange(x0, x0 + w), y=rng.randrange(y0, y0 + h),
                       radius=rng.randrange(20, 50), depth=rng.randrange(1000, 6000))
    return tp.edit("crater", x=rng.randrange(x0, x0 + w), y=rng.randrange(y0, y0 + h),
                   radius=rng.randrange(4, 10), depth=rng.randrange(100, 800))


def metrics(node):
    return node.get("/metrics")[1].decode()


def relay_ids(b, start):
    """The ids b gave the clients that said hello for dunes after line start, in order."""
    return [m.group(1) for m in (re.search(r"net: client (\d+) \(.*\) said hello for world dunes",
                                           line) for line in b.lines[start:]) if m]


async def wait_ids(b, start, n, timeout=30):
    end = time.monotonic() + timeout  # the node's log is read by a thread
    while len(relay_ids(b, start)) < n and time.monotonic() < end:
        await asyncio.sleep(0.1)
    return relay_ids(b, start)


async def fullest_second(b, cid, deadline_s=60):
    """b's line for its client cid, written when it leaves (net_budget_free): (budget, the
    bytes its fullest second held, the deltas coalesced for it), or None."""
    end = time.monotonic() + deadline_s
    while time.monotonic() < end:
        for line in list(b.lines):
            m = re.search(rf"net: client {cid} .*: budget (\d+) bytes/s, \d+ bytes sent, the "
                          r"fullest second held (\d+), (\d+) deltas coalesced", line)
            if m:
                return tuple(int(v) for v in m.groups())
        await asyncio.sleep(0.2)
    return None


async def wait_mirror(a, client, sid, deadline_s):
    """Until client's mirror of REGION is complete and equals a's heights (settled terrain)."""
    end = time.monotonic() + deadline_s
    loop = asyncio.get_running_loop()
    while time.monotonic() < end:
        try:
            _, server = await loop.run_in_executor(None, a.heights, "dunes", *REGION)
        except urllib.error.HTTPError as e:  # 503: the sim thread busy past heights_timeout_ms
            if e.code != 503:
                raise
            await asyncio.sleep(0.25)
            continue
        m = client.mirrors.get(sid)
        if m is not None and m.complete and list(m.heights) == server:
            return True
        await asyncio.sleep(0.25)
    return False


async def budget_through_relay(a, b, driver):
    start = len(b.lines)
    budgeted = CountingClient(b.ws, name="budgeted", budget=BUDGET, world="dunes")
    await budgeted.connect()
    wide = CountingClient(b.ws, name="wide", world="dunes")  # states none: given LIMIT
    await wide.connect()
    ids = await wait_ids(b, start, 2)
    check(len(ids) == 2, f"b's log names the two relayed clients ({ids})")
    check(budgeted.world.get("budget") == BUDGET and wide.world.get("budget") == LIMIT,
          f"through the relay the world message says the budgets in force "
          f"({budgeted.world.get('budget')}, {wide.world.get('budget')})")
    sid_b = await budgeted.subscribe(*REGION)
    sid_w = await wide.subscribe(*REGION)
    await wide.wait_complete(sid_w, 60)
    rng = random.Random(28)
    for _ in range(199):  # one burst, its last crater's answer awaited: the burst is applied
        await driver.ws.send(json.dumps(crater(rng)))
    await driver.request(crater(rng), "edited", timeout=120)
    check(await wait_mirror(a, budgeted, sid_b, 180),
          "the budgeted client's mirror on b equals a's GET /v1/heights once the craters stop")
    check(await wait_mirror(a, wide, sid_w, 60), "the wider client's mirror on b is exact too")
    text = metrics(b)
    check(metric_value(text, "terrad_budget_overruns_total") == 0,
          "b counts no overrun: no second of the budgeted client held more than its budget")
    check((metric_value(text, "terrad_budget_deltas_coalesced_total") or 0) > 0,
          "b coalesced deltas for the budgeted client (a burst's deltas exceed its budget)")
    print(f"budgeted client received {budgeted.bytes} bytes, wide {wide.bytes}", flush=True)
    await budgeted.close()
    await wide.close()
    mine, theirs = await fullest_second(b, ids[0]), await fullest_second(b, ids[1])
    print(f"b's accounting: budgeted {mine}, wide {theirs}", flush=True)
    check(mine is not None and mine[0] == BUDGET and 0 < mine[1] <= BUDGET and mine[2] > 0,
          f"b's accounting: the budgeted client's fullest second held at most {BUDGET} bytes, "
          f"deltas coalesced (budget, fullest, coalesced: {mine})")
    check(theirs is not None and theirs[0] == LIMIT and BUDGET < theirs[1] <= LIMIT,
          f"the wider client's fullest second held more than {BUDGET} bytes, within {LIMIT}: "
          f"the budget did bind ({theirs})")


async def lag_through_relay(a, b, driver):
    m0 = metrics(b)
    judged0 = sum(metric_value(m0, n) or 0 for n in ("terrad_clients_behind_total",
                                                     "terrad_clients_stale_total"))
    start = len(b.lines)
    c = RecordingClient(b.ws, name="stops-reading", world="dunes", record=False,
                        ping_interval=None)
    snapshots = []  # (time, rect) of the SNAPSHOT rectangles it handled
    c.on(tp.MsgType.DELTA, lambda tick, rects: snapshots.extend(
        (time.monotonic(), (r.x, r.y, r.w, r.h)) for r in rects
        if r.encoding == tp.Encoding.SNAPSHOT))
    await c.connect()
    ids = await wait_ids(b, start, 1)
    cid = ids[0] if ids else None
    sid = await c.subscribe(*REGION)
    await c.wait_complete(sid, 60)
    reading = asyncio.Event()
    orig = c._on_binary

    async def stalled(data):
        await reading.wait()
        await orig(data)
    c._on_binary = stalled  # it stops reading: frames wait in its buffers and the sockets'
    rng = random.Random(29)
    judged_re = re.compile(rf"net: client {cid} \(.*\) (has handled tick \d+, \d+ behind|is stale)")

    def judged():
        return [line for line in b.lines[start:] if judged_re.search(line)]
    end = time.monotonic() + 90
    n = 0
    while cid and not judged() and time.monotonic() < end:
        await driver.request(crater(rng, big=False), "edited", timeout=60)
        n += 1
        await asyncio.sleep(0.05)
    said = judged()
    print(f"{n} craters while it did not read; b said: {said[:1]}", flush=True)
    check(bool(said), f"b judged the client that stopped reading (client {cid}) behind: "
          f"{said[:1] or b.lines[-3:]}")
    m1 = metrics(b)
    judged1 = sum(metric_value(m1, n) or 0 for n in ("terrad_clients_behind_total",
                                                     "terrad_clients_stale_total"))
    check(judged1 > judged0, f"b's metrics count it ({judged0} -> {judged1})")
    await driver.request(crater(rng, big=False), "edited", timeout=60)  # the last crater
    drained = time.monotonic()
    c._on_binary = orig
    reading.set()  # it reads again: what waited, then fresh snapshots
    check(await wait_mirror(a, c, sid, 120),
          "read again, its mirror on b equals a's GET /v1/heights")
    later = [r for t, r in snapshots if t >= drained]
    check(len(later) > 0, f"it was sent snapshots after it drained ({len(later)} SNAPSHOT "
          "rectangles)")
    check(not c.ws.closed, "its connection stayed open")
    await c.close()


async def scenario(a, b):
    driver = tp.TerradClient(a.ws, name="driver", world="dunes")
    await driver.connect()
    await budget_through_relay(a, b, driver)
    await lag_through_relay(a, b, driver)
    await driver.close()


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    config = json_file(CONFIG, "terrad-relay-budget-config")
    scene = json_file(SCENE, "terrad-relay-budget-scene")
    left = "SIGTERM stops every node with status 0"
    try:
        with ch.NatsCluster(1) as nats, ch.running_nodes(check, [], stopped=ch.all_zero, said=left) as nodes:
            urls = nats.urls
            for name, path in (("dunes", scene), ("spare", "tests/scenes/tiny.json")):
                ok, said = ch.world_add(urls, name, path)
                check(ok, f"world add {name}: {said}")
            a = Node("a", urls, extra=["--worlds", "dunes", "--config", config])
            nodes.append(a)
            check(wait_for(lambda: a.serves("dunes"), 60), "node a ticks dunes")
            b = Node("b", urls, extra=["--worlds", "spare", "--config", config])
            nodes.append(b)
            check(wait_for(lambda: any("relays world dunes" in l for l in b.lines), 60),
                  "node b relays dunes")
            asyncio.run(asyncio.wait_for(scenario(a, b), 240))
    finally:
        os.unlink(config)
        os.unlink(scene)
    check.finish()


if __name__ == "__main__":
    main()
