#!/usr/bin/python3
# ctest-timeout: 180
"""Load-driven colliders (proto/PROTOCOL.md "Load-driven colliders") against the real daemon:

- three rigid plates (10 x 50 cells of 5 mm, as tests/validation's plate test) created with
  `load_n` on a bekker scene (dry sand), each far from the others, each given the load of
  Bekker's pressure at 10, 25 and 50 mm: the server sets their heights; once they stand
  still (FORCES unchanged from one tick to the next, waited for by condition) each one's
  sinkage is Bekker's z = (p / (kc/b + kphi))^(1/n), p = load / area, within 1 % or one
  height unit (the validation tests' tolerance), its patch width is the plate's 2A/L, and its
  normal force is the load within the search's resolution: 0.1 % of the load or 1/1024 of a
  height unit of elastic reloading under the plate (K_e x 0.1 mm x area / 1024), whichever is
  larger (before the sub-unit search, one whole unit: up to 46 N over the load here);
- the pose height a client sends is ignored: a later pose far above the soil changes nothing;
  CONTACT describes each plate where the server put it (its cells, volume and deepest point
  at the found height; before issue 31 it was measured at the pose 0.2 m up: 0 cells), and
  a COLLIDERS subscription's entry for it has the found height (ground less FORCES' sinkage);
- the found height in FORCES every tick (PROTOCOL.md "FORCES", the height extension): the
  plates are created with forces_height, so every FORCES frame to their client has the header
  flag 0x01 and 56-byte entries whose height is the plate's (its bottom is the ground less the
  sinkage, within 1e-6 m) and COLLIDERS' found height; a second client whose plate did not ask
  gets the frames it always did (flag 0, 48-byte entries, no height) — without the server's
  extension the first check fails, with it sent to everyone the second;
- bad values are refused naming `load_n` (`bad_value`: 0, negative, a string "NaN", above
  1e9; `unsupported_collider` on a world of another model), each counted in
  terrad_refused_messages_total, and the daemon goes on.
"""
import asyncio
import json
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, RecordingClient, metric_value  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()

CELL, GROUND, UPM = 0.005, 0.5, 10000
PW, PL = 10, 50  # plate, cells
W, H = 4 * (PW + 20), PL + 20  # three plates, and a fourth of a client that asks no heights
SOIL = {"n": 1.1, "kc": 0.99e3, "kphi": 1528.43e3, "elastic": 2e8}  # dry-sand (sim_soil.c)
DEPTHS = (0.010, 0.025, 0.050)
WAIT = 120


class Watcher(RecordingClient):
    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.log = {}  # id -> [(tick, Force)]
        self.found_contacts = {}  # id -> [(tick, Contact)]
        self.found_states = {}  # id -> {tick: ColliderState}
        self.forces_forms = set()  # (header flags, bytes per entry) of every FORCES frame

    async def _on_binary(self, data):
        if tp.decode_header(data) == tp.MsgType.FORCES:
            tick, fs = tp.decode_forces(data)
            if fs:
                self.forces_forms.add((data[3], (len(data) - 14) // len(fs)))
            for f in fs:
                self.log.setdefault(f.id, []).append((tick, f))
        elif tp.decode_header(data) == tp.MsgType.COLLIDERS:
            tick, states = tp.decode_colliders(data)
            for st in states:
                self.found_states.setdefault(st.id, {})[tick] = st
        elif tp.decode_header(data) == tp.MsgType.CONTACT:
            tick, cs = tp.decode_contact(data)
            for ct in cs:
                self.found_contacts.setdefault(ct.id, []).append((tick, ct))
        await super()._on_binary(data)

    def settled(self, cid):
        """The last two entries of cid are of consecutive ticks and equal."""
        e = self.log.get(cid, [])
        return len(e) >= 3 and e[-1][0] == e[-2][0] + 1 and e[-1][1] == e[-2][1]


def scene_file():
    scene = {
        "name": "load-driven",
        "world": {"width": W, "height": H, "cell_size_m": CELL},
        "terrain": {"kind": "flat", "height_m": GROUND},
        "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "dry-sand"}},
        "colliders": [],
    }
    fd, path = tempfile.mkstemp(prefix="terrad-load-driven-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(scene, f)
    return path


def plate_pose(i, z):
    return {"p": [(PW + 20) * CELL * (i + 0.5), H * CELL / 2, z], "q": [1, 0, 0, 0]}


async def plates(d):
    c = Watcher(d.ws, name="bevameter")
    await c.connect()
    area = PW * PL * CELL * CELL
    b = 2 * area / (2 * (PW + PL) * CELL)
    k = SOIL["kc"] / b + SOIL["kphi"]
    # a viewer's subscription with colliders: COLLIDERS frames carry each plate's pose as
    # the tick used it, its height the one the server found
    await c.request(tp.subscribe(0, 0, W, H, colliders=True), "subscribed")
    ids, loads = [], []
    for i, z in enumerate(DEPTHS):
        load = k * z ** SOIL["n"] * area
        msg = tp.collider_create("box", half_extents=[PW * CELL / 2, PL * CELL / 2, 0.05],
                                 load_n=load, forces_height=True)
        msg["pose"] = plate_pose(i, GROUND + 0.2)
        ids.append((await c.request(msg, "collider_created"))["id"])
        loads.append(load)
    await c.wait_for(lambda: all(c.settled(cid) for cid in ids), WAIT)
    step_n = SOIL["elastic"] / UPM * area  # one height unit of elastic reloading
    for cid, load, z in zip(ids, loads, DEPTHS):
        f = c.log[cid][-1][1]
        err = abs(f.sinkage_m - z)
        check(err <= 0.01 * z or err <= 1 / UPM + 1e-9,
              f"load {load:.1f} N: sinkage {f.sinkage_m:.5f} m against Bekker's {z:.5f} m "
              f"(p = {load / area / 1e3:.2f} kPa)")
        check(abs(f.patch_width_m - b) < 1e-6, f"patch width {f.patch_width_m:.5f} m = 2A/L {b:.5f}")
        check(abs(f.force[2] - load) <= max(1e-3 * load, step_n / 1024) + 1e-5 * load,
              f"normal force {f.force[2]:.3f} N is the load {load:.3f} N (within 0.1 % or 1/1024 "
              f"unit's {step_n / 1024:.3f} N of elastic reloading)")
        check(f.cells == PW * PL, f"the whole plate is in contact ({f.cells} cells)")
        # its CONTACT is where the server put it, not 0.2 m up where the poses say
        tick = c.log[cid][-1][0]
        ct = [x for tk, x in c.found_contacts.get(cid, []) if tk == tick]
        check(len(ct) == 1 and ct[0].cells == PW * PL and ct[0].volume > 0
              and ct[0].deepest[2] < GROUND and abs(ct[0].area_m2 - area) < 1e-6,
              f"its CONTACT at the found height: {ct[0] if ct else None}")
        check(bool(ct) and abs(GROUND - ct[0].deepest[2] - f.sinkage_m) <= 1 / UPM + 1e-6,
              "CONTACT's deepest point is at the FORCES sinkage below the surface")
        seen = c.found_states.get(cid, {})  # frames come when something in view moved
        st = seen[max(tk for tk in seen if tk <= tick)] if any(tk <= tick for tk in seen) else None
        check(st is not None and abs(st.p[2] - 0.05 - (GROUND - f.sinkage_m)) <= 1 / UPM + 1e-6,
              f"COLLIDERS carries the found height: plate bottom {st.p[2] - 0.05 if st else None} "
              f"m = ground less the sinkage {GROUND - f.sinkage_m:.5f} m")
        check(f.height_m is not None and abs(f.height_m - 0.05 - (GROUND - f.sinkage_m)) <= 1e-6
              and st is not None and abs(f.height_m - st.p[2]) <= 1e-6,
              f"FORCES carries the found height {f.height_m} m: its bottom is the ground less the "
              f"sinkage {GROUND - f.sinkage_m:.7f} m, COLLIDERS' {st.p[2] if st else None}")
    check(c.forces_forms == {(tp.FORCES_FLAG_HEIGHT, tp.FORCE_SIZE + 8)},
          f"every FORCES frame to the client that asked has the flag and heights: "
          f"{c.forces_forms}")
    # a client that never asks (an old one) gets the frames it always did
    old = Watcher(d.ws, name="old-client")
    await old.connect()
    msg = tp.collider_create("box", half_extents=[PW * CELL / 2, PL * CELL / 2, 0.05],
                             load_n=loads[0]) | {"pose": plate_pose(3, GROUND + 0.2)}
    oid = (await old.request(msg, "collider_created"))["id"]
    await old.wait_for(lambda: old.settled(oid), WAIT)
    check(old.forces_forms == {(0, tp.FORCE_SIZE)} and old.log[oid][-1][1].height_m is None,
          f"a client that did not ask gets plain FORCES frames: {old.forces_forms}")
    await old.close()
    # a pose far above the soil: the height stays the server's
    seq = await c.send_poses([tp.Pose(ids[0], *plate_pose(0, GROUND + 1.0)["p"], 1, 0, 0, 0)])
    await c.wait_ack(seq, WAIT)
    t = c.acked_tick
    await c.wait_for(lambda: c.log[ids[0]][-1][0] > t + 1, WAIT)
    before = [f for tk, f in c.log[ids[0]] if tk < t][-1]
    after = c.log[ids[0]][-1][1]
    check(after.cells == PW * PL and abs(after.sinkage_m - before.sinkage_m) <= 1 / UPM + 1e-9,
          f"a pose 1 m up is ignored: sinkage {after.sinkage_m:.5f} m ({before.sinkage_m:.5f})")
    # a pose 2 cm above the soil (a sweep the server takes: 1 m is refused as too
    # long a sweep): CONTACT is the plate where the server put it, not where posed
    seq = await c.send_poses([tp.Pose(ids[0], *plate_pose(0, GROUND + 0.07)["p"], 1, 0, 0, 0)])
    await c.wait_ack(seq, WAIT)
    t = c.acked_tick
    await c.wait_for(lambda: c.found_contacts[ids[0]][-1][0] > t, WAIT)
    ct = [x for tk, x in c.found_contacts.get(ids[0], []) if tk == t]
    check(len(ct) == 1 and ct[0].cells == PW * PL and ct[0].deepest[2] < GROUND,
          f"the CONTACT of the tick that posed it 2 cm above the soil has the plate's cells: "
          f"{ct}")
    await c.close()


async def refusals(d, bad, name):
    c = Watcher(d.ws, name="bad")
    await c.connect()
    _, m0 = d.metrics()
    for value in bad:
        c.errors.clear()
        msg = tp.collider_create("box", half_extents=[0.1, 0.1, 0.1]) | {"load_n": value}
        await c.ws.send(json.dumps(msg))
        await c.wait_for(lambda: c.errors, WAIT)
        e = c.errors[-1]
        check(e.get("name") == name and "load_n" in e.get("message", ""),
              f"load_n {value!r}: refused with {name} naming load_n ({e})")
    _, m1 = d.metrics()
    before = metric_value(m0, "terrad_refused_messages_total", {"reason": name}) or 0
    after = metric_value(m1, "terrad_refused_messages_total", {"reason": name}) or 0
    check(after - before == len(bad), f"each refusal counted ({after - before} of {len(bad)})")
    cid = await c.create_collider("sphere", radius=0.05)
    check(cid > 0, "the daemon goes on: a good collider is created after the refusals")
    await c.close()


def main():
    path = scene_file()
    try:
        with check.running(Daemon(extra=["--scene", path, "--no-data"], name="terrad-bekker",
                                 config={"limits": {"max_active_cells": 65536}})) as d:
            asyncio.run(plates(d))
            asyncio.run(refusals(d, [0, -5.0, "NaN", 2e9], "bad_value"))
        with check.running(Daemon(extra=["--no-data"], name="terrad-persson")) as d:
            asyncio.run(refusals(d, [100.0], "unsupported_collider"))
    finally:
        os.unlink(path)
    check.finish()


if __name__ == "__main__":
    main()
