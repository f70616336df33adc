#!/usr/bin/python3
# ctest-timeout: 90
"""The FORCES frame (0x15) against the real daemon (loopback, CPU backend, a store in a
temporary directory, so frames pass the durability gate) on a scene whose material is the
bekker soil model (docs/models.md, proto/PROTOCOL.md "FORCES"):

- a client drives a wheel pressed into the soil, rolling with slip 0.3: every FORCES entry
  is its collider's, after that tick's CONTACT and before its ACK; the soil carries it
  (Fz > 0, area and sinkage > 0, patch width within the wheel's width), and entries whose
  tick saw a new pose carry the slip commanded (slip comes from the two poses);
- `client.forces[id]` holds the latest entry;
- a collider created with "feedback": false gets no entry, another client's gets none;
- lifted off the ground: Fz 0, no contact cells.
"""
import asyncio
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, RecordingClient, flat_scene, serve_scene  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()

W, H, CELL, GROUND = 160, 64, 0.05, 0.4
RADIUS, WIDTH, PRESS, SLIP = 0.3, 0.2, 0.03, 0.3


class Watcher(RecordingClient):
    """Keeps every FORCES entry with its tick, and the order of the binary frames."""

    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.entries = []  # (tick, Force)
        self.order = []  # (type, tick) of CONTACT, FORCES, ACK

    async def _on_binary(self, data):
        t = tp.decode_header(data)
        if t == tp.MsgType.FORCES:
            tick, fs = tp.decode_forces(data)
            self.entries += [(tick, f) for f in fs]
            self.order.append((t, tick))
        elif t in (tp.MsgType.CONTACT, tp.MsgType.ACK):
            self.order.append((t, tp.decode_contact(data)[0] if t == tp.MsgType.CONTACT
                               else tp.decode_ack(data)[0]))
        await super()._on_binary(data)


def wheel_pose(cid, x, y, z, angle):
    """A wheel (axis local y) turned by angle about y: rolls along +x for angle > 0."""
    return tp.Pose(cid, x, y, z, math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


async def scenario(d):
    driver, other = Watcher(d.ws, name="driver"), Watcher(d.ws, name="other")
    await driver.connect()
    await other.connect()
    wheel = await driver.create_collider("wheel", radius=RADIUS, width=WIDTH)
    quiet = (await driver.request(tp.collider_create("sphere", "default", radius=0.2)
                                  | {"feedback": False}, "collider_created"))["id"]
    theirs = await other.create_collider("sphere", radius=0.2)
    x, y, z = 1.0, 1.6, GROUND + RADIUS - PRESS
    v, dt = 0.3, 1 / 60
    omega = v / (RADIUS * (1 - SLIP))
    angle = 0.0
    seq = 0
    for k in range(60):
        x += v * dt
        angle += omega * dt
        seq = await driver.send_poses([wheel_pose(wheel, x, y, z, angle),
                                       tp.Pose(quiet, 5.0, 1.6, GROUND + 0.15, 1, 0, 0, 0)])
        await other.send_poses([tp.Pose(theirs, 6.5, 1.6, GROUND + 0.15, 1, 0, 0, 0)])
        await asyncio.sleep(dt)
    await driver.wait_ack(seq, 10)
    await driver.wait_for(lambda: len(driver.entries) >= 10, 10)
    ids = {f.id for _, f in driver.entries}
    check(ids == {wheel}, f"FORCES entries only for the feedback wheel ({ids}, wheel {wheel})")
    check(not other.entries or {f.id for _, f in other.entries} == {theirs},
          f"the other client's FORCES hold only its own collider ({len(other.entries)} entries)")
    loaded = [f for _, f in driver.entries if f.cells > 0]
    check(len(loaded) >= 10, f"the pressed wheel is in contact ({len(loaded)} entries)")
    if loaded:
        f = loaded[-1]
        check(f.force[2] > 0 and f.area_m2 > 0 and f.sinkage_m > 0,
              f"the soil carries the wheel: F {f.force}, area {f.area_m2}, sinkage {f.sinkage_m}")
        check(0 < f.patch_width_m <= WIDTH + 2 * CELL, f"patch width {f.patch_width_m:.3f} m")
        check(f.cells == round(f.area_m2 / (CELL * CELL)), "area = cells x cell area")
        check(driver.forces[wheel] == driver.entries[-1][1], "client.forces holds the latest entry")
    slips = [f.slip for _, f in driver.entries if f.slip != 0.0]
    check(any(abs(s - SLIP) < 0.02 for s in slips),
          f"entries of ticks with a new pose carry the slip {SLIP} (seen {sorted(set(round(s, 3) for s in slips))[:8]})")
    # frame order within a tick: CONTACT, FORCES, ACK
    by_tick = {}
    for t, tick in driver.order:
        by_tick.setdefault(tick, []).append(t)
    bad = [k for k, ts in by_tick.items() if tp.MsgType.FORCES in ts and
           ts != [x for x in (tp.MsgType.CONTACT, tp.MsgType.FORCES, tp.MsgType.ACK) if x in ts]]
    check(not bad, f"CONTACT, FORCES, ACK in that order each tick (out of order: {bad[:3]})")

    # lifted off: zeros
    seq = await driver.send_poses([wheel_pose(wheel, x, y, GROUND + 2.0, angle)])
    await driver.wait_ack(seq, 5)
    lifted = driver.acked_tick
    await driver.wait_for(lambda: any(t >= lifted for t, _ in driver.entries), 5)
    after = [f for t, f in driver.entries if t >= lifted]
    check(after and all(f.cells == 0 and f.force[2] == 0.0 for f in after),
          f"lifted off: no force ({after[:1]})")
    await driver.close()
    await other.close()


def main():
    soil = {"model": "bekker", "compression": 0.5, "soil": {"preset": "ding2011"}}
    serve_scene(check, flat_scene("forces", W, H, CELL, GROUND, soil), scenario, "terrad-bekker")
    check.finish()


if __name__ == "__main__":
    main()
