#!/usr/bin/python3
# ctest-timeout: 90
"""The FOOTPRINTS frame (0x14) against the real daemon (loopback, CPU backend,
a store in a temporary directory, so frames pass the durability gate) on a
scene whose material is the decals model:

- a viewer subscribed with "footprints": true, while a client presses a sphere
  into the ground, gets events of that collider near its centre, with
  size > 0 and strength about the depth pressed; lifted off the ground, the
  events stop;
- the heights do not change (GET /v1/heights before and after are the same);
- a client subscribed to the same region without the option, and a client
  subscribed with the option to a region elsewhere, receive no FOOTPRINTS;
- /metrics counts the frames and events sent;
- "footprints": "yes" is refused with bad_value naming the field, counted in
  /metrics, and the connection goes on.
"""
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, RecordingClient, flat_scene, metric_value,  # noqa: E402
                             serve_scene)
import terrad as tp  # noqa: E402

check = Checks()

W, H, CELL, GROUND = 256, 128, 0.05, 0.4  # a 12.8 m x 6.4 m world, flat at 0.4 m
RADIUS, PRESS = 0.3, 0.05  # the sphere, and how deep it is pressed in


class Watcher(RecordingClient):
    """Keeps every FOOTPRINTS event with the tick of its frame."""

    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.events = []  # (tick, Footprint)
        self.frames = 0

    async def _on_binary(self, data):
        if tp.decode_header(data) == tp.MsgType.FOOTPRINTS:
            tick, events = tp.decode_footprints(data)
            self.frames += 1
            self.events += [(tick, e) for e in events]
        await super()._on_binary(data)


async def scenario(d):
    world = d.world()
    check(world["width"] == W and world["cell_size_m"] == CELL, f"the scene's world: {world}")
    left, right = (0, 0, W // 2, H), (W // 2, 0, W // 2, H)
    viewer, plain, elsewhere, driver = (Watcher(d.ws, name=n) for n in
                                        ("viewer", "plain", "elsewhere", "driver"))
    for c in (viewer, plain, elsewhere, driver):
        await c.connect()
    await viewer.subscribe(*left, footprints=True)
    await plain.subscribe(*left)
    await elsewhere.subscribe(*right, footprints=True)

    x, y = 3.2, 3.2  # cell (64, 64), in the left half
    around = (int(x / CELL) - 16, int(y / CELL) - 16, 32, 32)
    _, before = d.heights(*around)

    sphere = await driver.create_collider("sphere", radius=RADIUS)
    z = GROUND + RADIUS - PRESS
    seq = 0
    for k in range(20):  # pressed in, rolling 1 cm a tick along x
        seq = await driver.send_poses([tp.Pose(sphere, x + 0.01 * k, y, z, 1, 0, 0, 0)])
        await asyncio.sleep(1 / 60)
    await driver.wait_ack(seq, 5)
    await viewer.wait_for(lambda: len(viewer.events) >= 5, 5)
    mine = [e for _, e in viewer.events if e.collider == sphere]
    check(len(mine) >= 5 and len(mine) == len(viewer.events),
          f"events of the pressed sphere arrive ({len(mine)} of {len(viewer.events)})")
    if mine:
        e = mine[-1]
        check(abs(e.x - (x + 0.19)) < 2 * CELL and abs(e.y - y) < 2 * CELL,
              f"the event is at the collider ({e.x:.3f}, {e.y:.3f}) vs ({x + 0.19:.3f}, {y:.3f})")
        # depth is sampled at cell centres, so a little under the press
        check(abs(e.strength_m - PRESS) < 5e-3, f"strength {e.strength_m:.4f} m ~ the press {PRESS} m")
        # the pressed disc has radius sqrt(r^2 - (r - press)^2), size is its area's square side
        disc = (RADIUS ** 2 - (RADIUS - PRESS) ** 2) ** 0.5
        want = (3.14159265 * disc * disc) ** 0.5
        check(abs(e.size_m - want) < 0.25 * want, f"size {e.size_m:.3f} m ~ {want:.3f} m")
        check(abs(e.yaw) < 1e-6, f"yaw of an unturned sphere is 0 ({e.yaw})")
    ticks = [t for t, _ in viewer.events]
    check(ticks == sorted(ticks), "ticks in order")

    # a quarter turn about z: the yaw follows
    q = 0.5 ** 0.5
    seq = await driver.send_poses([tp.Pose(sphere, x, y, z, q, 0, 0, q)])
    await driver.wait_ack(seq, 5)
    n = len(viewer.events)
    await viewer.wait_for(lambda: any(abs(e.yaw - 1.5707964) < 1e-4 for _, e in viewer.events[n:]), 5)

    # lifted off: no more events after the lift's tick
    seq = await driver.send_poses([tp.Pose(sphere, x, y, GROUND + 2.0, 1, 0, 0, 0)])
    await driver.wait_ack(seq, 5)
    lifted = driver.acked_tick
    await asyncio.sleep(0.5)
    late = [t for t, _ in viewer.events if t >= lifted]
    check(not late, f"no events once lifted (tick {lifted}; late ticks {late[:5]})")

    _, after = d.heights(*around)
    check(after == before, "the heights are unchanged (decals deform nothing)")
    check(plain.frames == 0, f"no FOOTPRINTS without the option ({plain.frames} frames)")
    check(elsewhere.frames == 0, f"no FOOTPRINTS for a region elsewhere ({elsewhere.frames} frames)")

    text = d.metrics()[1]
    frames = metric_value(text, "terrad_footprint_frames_total") or 0
    events = metric_value(text, "terrad_footprint_events_total") or 0
    check(frames == viewer.frames and events == len(viewer.events),
          f"/metrics counts what was sent ({frames} frames, {events} events; the viewer got "
          f"{viewer.frames}, {len(viewer.events)})")

    # bad input
    m0 = metric_value(text, "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    try:
        await viewer.request(tp.subscribe(0, 0, 4, 4) | {"footprints": "yes"}, "subscribed")
        check(False, "footprints: \"yes\" is refused")
    except tp.ServerError as e:
        check(e.msg["name"] == "bad_value" and "footprints" in e.msg["message"],
              f"footprints: \"yes\" -> {e.msg['name']}: {e.msg['message']}")
    m1 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    check(m1 == m0 + 1, f"the refusal is counted ({m0} -> {m1})")
    await viewer.subscribe(0, 0, 4, 4)  # the connection goes on
    for c in (viewer, plain, elsewhere, driver):
        await c.close()


def main():
    serve_scene(check, flat_scene("footprints", W, H, CELL, GROUND, {"model": "decals"}), scenario,
                "terrad-decals")
    check.finish()


if __name__ == "__main__":
    main()
