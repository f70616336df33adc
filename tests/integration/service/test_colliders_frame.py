#!/usr/bin/python3
# ctest-timeout: 120
"""The COLLIDERS frame (0x13) against the real daemon (loopback, CPU backend):

- a viewer subscribed with "colliders": true gets the colliders meeting its
  region: another client's sphere (owner 1, kind sphere, its radius and pose),
  its own box (owner 0), the daemon's demo actors (owner 2, ids >= 2^31);
- a collider moved out of the region leaves the list, moved back it returns;
- rate: a collider moved every tick gives at most one frame per 3 ticks; an
  unchanged list is repeated about once a second only;
- a client subscribed without the option gets no COLLIDERS frame;
- "colliders": 1 is refused with bad_value naming the field, counted in
  /metrics, and the connection goes on.
"""
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, RecordingClient, metric_value  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()


class Viewer(RecordingClient):
    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.frames = []  # (tick, {id: ColliderState})

    async def _on_binary(self, data):
        await super()._on_binary(data)
        if tp.decode_header(data) == tp.MsgType.COLLIDERS:
            self.frames.append((self.colliders_tick, dict(self.colliders)))


async def scenario(d):
    world = d.world()
    cell, W, H = world["cell_size_m"], world["width"], world["height"]
    region = (0, 0, W // 2, H // 2)
    viewer, other, plain = Viewer(d.ws, name="viewer"), RecordingClient(d.ws, name="other"), \
        Viewer(d.ws, name="plain")
    for c in (viewer, other, plain):
        await c.connect()
    await viewer.subscribe(*region, colliders=True)
    await plain.subscribe(*region)
    hz = viewer.world["tick_hz"]

    # another client's sphere inside the region, above the snow (no deformation needed)
    sphere = await other.create_collider("sphere", radius=0.4)
    x, y = W * cell / 4, H * cell / 4
    await other.send_poses([tp.Pose(sphere, x, y, 5.0, 1, 0, 0, 0)])
    await viewer.wait_for(lambda: sphere in viewer.colliders, 5)
    s = viewer.colliders[sphere]
    check(s.owner == 1 and s.kind == 0, f"another client's sphere: owner {s.owner}, kind {s.kind}")
    check(abs(s.dims[0] - 0.4) < 1e-6 and abs(s.p[0] - x) < 1e-3 and abs(s.p[1] - y) < 1e-3 and
          abs(s.p[2] - 5.0) < 1e-3, f"its radius and pose {s.dims} {s.p}")
    demo = [c for c in viewer.colliders.values() if c.owner == 2]
    check(all(c.id >= 0x80000000 for c in demo), "demo actors have ids >= 2^31")

    # the viewer's own box
    box = await viewer.request(tp.collider_create("box", half_extents=[0.5, 0.25, 0.2],
                                                  pose={"p": [x + 2, y, 5.0], "q": [1, 0, 0, 0]}),
                               "collider_created")
    box = box["id"]
    await viewer.wait_for(lambda: box in viewer.colliders, 5)
    b = viewer.colliders[box]
    check(b.owner == 0 and b.kind == 1 and [round(v, 4) for v in b.dims] == [0.5, 0.25, 0.2],
          f"own box: owner {b.owner}, kind {b.kind}, dims {b.dims}")

    # out of the region and back
    far = (W * 3 / 4 * cell, H * 3 / 4 * cell)
    await other.send_poses([tp.Pose(sphere, far[0], far[1], 5.0, 1, 0, 0, 0)])
    await viewer.wait_for(lambda: sphere not in viewer.colliders, 5)
    check(box in viewer.colliders, "the box stays while the sphere leaves")
    await other.send_poses([tp.Pose(sphere, x, y, 5.0, 1, 0, 0, 0)])
    await viewer.wait_for(lambda: sphere in viewer.colliders, 5)

    # rate: moving every tick until 6 frames came (a count of frames, not of seconds: a loaded
    # machine ticks and sends more slowly, the rule per tick is the same)
    n0, t0 = len(viewer.frames), viewer.frames[-1][0]
    deadline = asyncio.get_running_loop().time() + 60
    k = 0
    while len(viewer.frames) - n0 < 6 and asyncio.get_running_loop().time() < deadline:
        await other.send_poses([tp.Pose(sphere, x + 0.01 * (k % 100), y, 5.0, 1, 0, 0, 0)])
        k += 1
        await asyncio.sleep(1 / hz)
    moved = viewer.frames[n0:]
    ticks = [t for t, _ in moved]
    gaps = [b - a for a, b in zip([t0] + ticks, ticks)]
    check(len(moved) >= 6, f"a moving collider is reported ({len(moved)} frames in {k} ticks' poses)")
    check(min(gaps) >= 3, f"at most one frame every 3 ticks (gaps {gaps})")
    # unchanged lists: only repeated after about a second (the demo actors move, so
    # check the rule frame by frame over the whole run)
    await asyncio.sleep(1.5)
    repeats = [(a[0], b[0]) for a, b in zip(viewer.frames, viewer.frames[1:]) if a[1] == b[1]]
    check(all(tb - ta >= 60 for ta, tb in repeats),
          f"an unchanged list is repeated only after 60 ticks ({[tb - ta for ta, tb in repeats]})")
    check(not plain.frames, f"no COLLIDERS without the option ({len(plain.frames)} frames)")

    # bad input
    m0 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    try:
        await viewer.request(tp.subscribe(0, 0, 4, 4) | {"colliders": 1}, "subscribed")
        check(False, "colliders: 1 is refused")
    except tp.ServerError as e:
        check(e.msg["name"] == "bad_value" and "colliders" in e.msg["message"],
              f"colliders: 1 -> {e.msg['name']}: {e.msg['message']}")
    m1 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    check(m1 == m0 + 1, f"the refusal is counted ({m0} -> {m1})")
    await viewer.subscribe(0, 0, 4, 4)  # the connection goes on
    for c in (viewer, other, plain):
        await c.close()


def main():
    with check.running(Daemon(demo=True)) as d:
        asyncio.run(scenario(d))
    check.finish()


if __name__ == "__main__":
    main()
