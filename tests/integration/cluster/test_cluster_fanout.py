"""test_cluster_fanout: viewers spread over the nodes of a cluster, all
subscribed to one world, hold the owner's heights (docs/cluster.md, any node
serves any world). TERRAD_FANOUT_VIEWERS read-only viewers (default 60; the
soak runs 300) are spread evenly over TERRAD_FANOUT_NODES terrad nodes
(default 3) on TERRAD_FANOUT_NATS nats-servers (default 1; the soak: 3). Node
n0 ticks "dunes"; the others relay it. A driver on a relay node drives a
sphere across the viewers' region, lifts it and lets the terrain settle;
then every viewer's mirror equals the owner's GET /v1/heights?world=dunes of
the region, and each node's /metrics counts the bytes it sent (printed, not
checked: a figure of load, not of speed). Skipped (77) without nats-server.
"""
# ctest-timeout: 300
import asyncio
import os
import re
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import Node, wait_for  # noqa: E402
from service_harness import Checks, RecordingClient, skip, tp  # noqa: E402

VIEWERS = int(os.environ.get("TERRAD_FANOUT_VIEWERS", "60"))
NODES = int(os.environ.get("TERRAD_FANOUT_NODES", "3"))
NATS = int(os.environ.get("TERRAD_FANOUT_NATS", "1"))
check = Checks()


def bytes_out(node):
    status, body = node.get("/metrics")
    m = re.search(rb"^terrad_bytes_out_total (\d+)", body, re.M)
    return int(m.group(1)) if m else 0


async def viewers_scenario(nodes, region):
    owner = nodes[0]
    viewers = [tp.TerradClient(nodes[i % len(nodes)].ws, name=f"viewer{i}", world="dunes",
                               ping_interval=None) for i in range(VIEWERS)]
    for k in range(0, VIEWERS, 20):  # connect in groups: the loopback accept queue is short
        await asyncio.gather(*(v.connect() for v in viewers[k:k + 20]))
    sids = await asyncio.gather(*(v.subscribe(*region) for v in viewers))
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not all(v.mirrors[s].complete
                                                  for v, s in zip(viewers, sids)):
        await asyncio.sleep(0.1)
    check(all(v.mirrors[s].complete for v, s in zip(viewers, sids)),
          f"all {VIEWERS} viewers hold their snapshot")
    sent0 = [bytes_out(n) for n in nodes]
    d = RecordingClient(nodes[-1].ws, name="driver", record=False, world="dunes")
    await d.connect()
    dsid = await d.subscribe(*region)
    await d.wait_for(lambda: d.mirrors[dsid].complete, 30)
    cid = await d.create_collider("sphere", radius=0.4)
    w = d.world
    cs, upm = w["cell_size_m"], w["units_per_m"]
    mirror = d.mirrors[dsid]
    x, y = 1.0, (region[1] + region[3] // 2) * cs
    t_end = time.monotonic() + 2.0
    while time.monotonic() < t_end:
        x += 3.0 / 60
        cx, cy = int(x / cs) - mirror.x, int(y / cs) - mirror.y
        ground = mirror.heights[cy * mirror.w + cx] / upm
        await d.send_poses([tp.Pose(cid, x, y, ground + 0.25, 1, 0, 0, 0)])
        await asyncio.sleep(1 / 60)
    await d.send_poses([tp.Pose(cid, x, y, 50.0, 1, 0, 0, 0)])
    # settled: the owner's heights stop changing
    last, same_since = None, time.monotonic()
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        _, server = owner.heights("dunes", *region)
        if server != last:
            last, same_since = server, time.monotonic()
        elif time.monotonic() - same_since > 1.0:
            break
        await asyncio.sleep(0.2)
    changed = sum(1 for p, q in zip(viewers[0].mirrors[sids[0]].heights, last) if p != q)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not all(v.mirrors[s].heights == last
                                                  for v, s in zip(viewers, sids)):
        await asyncio.sleep(0.2)
    holding = sum(1 for v, s in zip(viewers, sids) if v.mirrors[s].heights == last)
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and d.mirrors[dsid].heights != last:
        await asyncio.sleep(0.2)
    trail = sum(1 for a, b in zip(d.mirrors[dsid].heights, last) if a != b)
    check(holding == VIEWERS, f"{holding} of {VIEWERS} viewers over {len(nodes)} nodes hold the "
          f"owner's heights of the region at the end (the trail changed cells; {changed} "
          "differed just before the last check)")
    check(trail == 0, f"the driver's mirror holds the owner's heights too ({trail} cells differ)")
    sent = [bytes_out(n) - s0 for n, s0 in zip(nodes, sent0)]
    print("bytes out per node while driving (n0 owns dunes): " +
          ", ".join(f"{n.name} {b / 1e6:.2f} MB" for n, b in zip(nodes, sent)), flush=True)
    await d.close()
    await asyncio.gather(*(v.close() for v in viewers), return_exceptions=True)


def main():
    if ch.NATS_SERVER is None:
        skip("nats-server is not installed")
    with ch.NatsCluster(NATS) as nats, ch.running_nodes(check, [], tail=20,
                                                        stopped=ch.all_zero) as nodes:
        urls = nats.urls
        ok, said = ch.world_add(urls, "dunes", "server/scene/default.json")
        check(ok, f"world add dunes: {said}")
        nodes.append(Node("n0", urls))
        check(wait_for(lambda: nodes[0].serves("dunes"), 60), "n0 ticks dunes")
        for i in range(1, NODES):
            nodes.append(Node(f"n{i}", urls))
        for n in nodes[1:]:
            check(wait_for(lambda: any("relays world dunes" in l for l in n.lines), 30),
                  f"{n.name} relays dunes")
        asyncio.run(viewers_scenario(nodes, (0, 224, 256, 64)))
    check.finish()


if __name__ == "__main__":
    main()
