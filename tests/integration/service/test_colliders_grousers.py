#!/usr/bin/python3
# ctest-timeout: 120
"""COLLIDERS' grousers extension (PROTOCOL.md "COLLIDERS") against the real daemon
(loopback, CPU backend):

- a viewer subscribed with "colliders": true, "grousers": true sees another client's
  lugged wheel with its grousers exactly (count, and height and thickness as the f32 of
  what the driver created) and its phase (the entry's orientation is the wheel's pose, lug
  0 along its -z); the frame has the header flag 0x01 and 60-byte entries; a smooth wheel
  in the same frame has none; while no lugged wheel is in view its frames are the plain
  ones (flag 0, 48-byte entries);
- a viewer subscribed with "colliders": true only (every client before the extension)
  gets the plain frames: flag 0, 48-byte entries, which the rule of the decoders before
  the extension (flags 0, 14 + 48·count bytes) reads, the wheel there without grousers;
- "grousers" without "colliders", and "grousers": 1, are refused with bad_value naming
  the field, counted in /metrics, and the connection goes on;
- a wheel whose lug height or thickness rounds to f32 0 (which no frame could carry) is
  refused at collider_create naming the field, counted, and the viewers' frames go on.
"""
import asyncio
import math
import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, RecordingClient, metric_value  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()

LUGS = {"count": 30, "height": 0.01, "thickness": 0.004}


def f32(v):
    return struct.unpack("<f", struct.pack("<f", v))[0]


def old_decoder_reads(data):
    """The rule every COLLIDERS decoder before the extension applied: flags 0 and exactly
    14 + 48 bytes per entry."""
    count = struct.unpack_from("<H", data, 12)[0]
    return data[3] == 0 and len(data) == 14 + 48 * count


class Viewer(RecordingClient):
    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.raw = []  # (flags, length, entries) of every COLLIDERS frame

    async def _on_binary(self, data):
        await super()._on_binary(data)
        if tp.decode_header(data) == tp.MsgType.COLLIDERS:
            self.raw.append((data[3], len(data), struct.unpack_from("<H", data, 12)[0], data))


async def scenario(d):
    world = d.world()
    cell, W, H = world["cell_size_m"], world["width"], world["height"]
    region = (0, 0, W // 2, H // 2)
    viewer, plain, driver = Viewer(d.ws, name="viewer"), Viewer(d.ws, name="plain"), \
        RecordingClient(d.ws, name="driver")
    for c in (viewer, plain, driver):
        await c.connect()
    await viewer.subscribe(*region, colliders=True, grousers=True)
    await plain.subscribe(*region, colliders=True)
    x, y = W * cell / 4, H * cell / 4

    # a smooth wheel first: no lugs in view, so the asking viewer's frames are the plain ones
    smooth = await driver.create_collider("wheel", radius=0.3, width=0.2)
    await driver.send_poses([tp.Pose(smooth, x + 2, y, 5.0, 1, 0, 0, 0)])
    await viewer.wait_for(lambda: smooth in viewer.colliders, 60)
    check(all(fl == 0 and n == 14 + 48 * k for fl, n, k, _ in viewer.raw),
          f"no lugged wheel in view: plain frames ({[(fl, n, k) for fl, n, k, _ in viewer.raw]})")
    check(viewer.colliders[smooth].grousers is None, "the smooth wheel has no grousers")

    # the lugged wheel, turned 30 degrees about its axle (y): that turn is its lugs' phase
    lugged = await driver.create_collider("wheel", radius=0.3, width=0.2, grousers=LUGS)
    half = math.radians(30) / 2
    q = (math.cos(half), 0.0, math.sin(half), 0.0)
    await driver.send_poses([tp.Pose(lugged, x, y, 5.0, *q)])
    await viewer.wait_for(lambda: lugged in viewer.colliders, 60)
    n0 = len(viewer.raw)
    await viewer.wait_for(lambda: len(viewer.raw) > n0, 60)  # a whole frame after it came
    w = viewer.colliders[lugged]
    want = {"count": 30, "height": f32(0.01), "thickness": f32(0.004)}
    check(w.grousers == want, f"the lugged wheel's grousers, exactly: {w.grousers} (want {want})")
    check(w.owner == 1 and w.kind == 3 and abs(w.dims[0] - 0.3) < 1e-6,
          f"another client's wheel: owner {w.owner}, kind {w.kind}, dims {w.dims}")
    check(all(abs(a - b) < 1e-6 for a, b in zip(w.q, q)),
          f"its orientation, the lugs' phase (lug 0 along its -z): {w.q} (want {q})")
    check(viewer.colliders[smooth].grousers is None, "the smooth wheel beside it has none")
    fl, n, k, data = viewer.raw[-1]
    check(fl == tp.COLLIDERS_FLAG_GROUSERS and n == 14 + 60 * k and k >= 2,
          f"with a lugged wheel in view: flag 0x01, 60-byte entries ({fl}, {n} bytes, {k} entries)")
    check(not old_decoder_reads(data), "(an old decoder would refuse it: only asked for)")

    # the client that did not ask: plain frames an old decoder reads, the wheel without lugs
    await plain.wait_for(lambda: lugged in plain.colliders, 60)
    p = plain.colliders[lugged]
    check(p.grousers is None and p.kind == 3 and abs(p.dims[0] - 0.3) < 1e-6,
          f"not asked: the rim only ({p})")
    check(all(abs(a - b) < 1e-6 for a, b in zip(p.q, q)), "and its pose as the asking viewer's")
    check(plain.raw and all(fl == 0 and old_decoder_reads(data) for fl, _, _, data in plain.raw),
          f"every frame to it is one an old decoder reads ({[(fl, n, k) for fl, n, k, _ in plain.raw]})")

    # bad input: a clear error naming the field, counted, and the connection goes on
    m0 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    for extra, what in (({"grousers": True}, "grousers without colliders"),
                        ({"colliders": True, "grousers": 1}, "grousers: 1")):
        try:
            await plain.request(tp.subscribe(0, 0, 4, 4) | extra, "subscribed")
            check(False, f"{what} is refused")
        except tp.ServerError as e:
            check(e.msg["name"] == "bad_value" and "grousers" in e.msg["message"],
                  f"{what} -> {e.msg['name']}: {e.msg['message']}")
    m1 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    check(m1 == m0 + 2, f"the refusals are counted ({m0} -> {m1})")
    await plain.subscribe(0, 0, 4, 4, colliders=True, grousers=True)  # the connection goes on
    await plain.wait_for(lambda: plain.colliders.get(lugged) is not None and
                         plain.colliders[lugged].grousers == want, 60)
    check(plain.colliders[lugged].grousers == want, "asked later, it gets the grousers too")

    # a lug size whose f32 is 0 (the frames carry f32 > 0; one reported as 0 would have the
    # whole frame refused, for every viewer that asked): refused naming the field, counted,
    # and the asking viewer's frames go on
    m0 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    for field, lugs in (("grousers.height", {"count": 30, "height": 1e-46, "thickness": 0.004}),
                        ("grousers.thickness", {"count": 30, "height": 0.01, "thickness": 1e-300})):
        try:
            tiny = await driver.create_collider("wheel", radius=0.3, width=0.2, grousers=lugs)
            await driver.send_poses([tp.Pose(tiny, x - 2, y, 5.0, 1, 0, 0, 0)])
            check(False, f"a {field} f32 cannot carry is refused (collider {tiny} created)")
        except tp.ServerError as e:
            check(e.msg["name"] == "bad_value" and e.msg["message"].startswith(field),
                  f"{field} {lugs} -> {e.msg['name']}: {e.msg['message']}")
    m1 = metric_value(d.metrics()[1], "terrad_refused_messages_total", {"reason": "bad_value"}) or 0
    check(m1 == m0 + 2, f"the refusals are counted ({m0} -> {m1})")
    n0 = len(viewer.raw)
    await driver.send_poses([tp.Pose(lugged, x + 1, y, 5.0, *q)])
    await viewer.wait_for(lambda: len(viewer.raw) > n0 and viewer.colliders[lugged].p[0] > x + 0.5,
                          60)
    check(viewer.colliders[lugged].grousers == want, "the asking viewer's frames go on")
    for c in (viewer, plain, driver):
        await c.close()


def main():
    with check.running(Daemon()) as d:
        asyncio.run(scenario(d))
    check.finish()


if __name__ == "__main__":
    main()
