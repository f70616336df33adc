#!/usr/bin/python3
# ctest-timeout: 300
"""The bekker model's per-cell soil state (plastic sinkage, shear displacement, compacted
volume; docs/storage.md "Soil state") survives kill -9 of the real daemon exactly:

- a real client drives a wheel (with slip) along a rut on a bekker scene, then back over
  it, against a daemon with a data directory (durability every-tick);
- run A (the reference) is never killed; run B is killed with SIGKILL between the two
  passes and restarted on its data directory. Both clients do the same thing at the same
  point (close, reconnect, create the wheel again), so the two runs differ only by the crash;
- after the restart run B's heights and Σ compacted (/v1/stats `soil_compacted`) are A's
  at the same point, and after the second pass — which sinks less where the first pressed,
  so it reads the recovered plastic state — its heights, Σ compacted and every FORCES
  entry of the pass are bit-identical to A's.

The runs are deterministic though the daemon ticks on its clock: each pose is sent only
once the previous one's tick and HOLD more have gone by (waits by condition), and a wheel
held still changes nothing after a couple of ticks (checked: the last HOLD ticks' FORCES of
each step agree), so how many idle ticks a loaded machine adds does not matter.
"""
import asyncio
import json
import math
import os
import shutil
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import Checks, Daemon, RecordingClient  # noqa: E402
import terrad as tp  # noqa: E402

check = Checks()

W, H, CELL, GROUND = 96, 48, 0.05, 0.4
RADIUS, WIDTH, SLIP = 0.25, 0.15, 0.3
STEP = 0.02  # metres per pose: under half a cell
HOLD = 4  # ticks after a pose's tick before the next pose
WAIT = 120  # seconds: generous, a loaded 2-core machine


class Watcher(RecordingClient):
    """Keeps every FORCES entry of its colliders by tick."""

    def __init__(self, *a, **k):
        super().__init__(*a, record=False, **k)
        self.by_tick = {}
        self.last_forces_tick = 0

    async def _on_binary(self, data):
        if tp.decode_header(data) == tp.MsgType.FORCES:
            tick, fs = tp.decode_forces(data)
            for f in fs:
                self.by_tick[tick] = f
            self.last_forces_tick = max(self.last_forces_tick, tick)
        await super()._on_binary(data)


def scene_file():
    scene = {
        "name": "soil-recovery",
        "world": {"width": W, "height": H, "cell_size_m": CELL},
        "terrain": {"kind": "flat", "height_m": GROUND},
        "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "ding2011"}},
        "colliders": [],
    }
    fd, path = tempfile.mkstemp(prefix="terrad-soil-recovery-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(scene, f)
    return path


def wheel_pose(cid, x, angle, press):
    z = GROUND + RADIUS - press
    return tp.Pose(cid, x, H * CELL / 2, z, math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


def strip(f):
    """A FORCES entry without the collider id (each run numbers its colliders)."""
    return (f.force, f.torque, f.sinkage_m, f.area_m2, f.patch_width_m, f.slip, f.cells)


async def drive(d, xs, press):
    """One pass: a new client and wheel, one pose per step (angle from the slip), each
    held HOLD ticks. Returns the FORCES entry of each step's tick and of its last held
    tick, then closes (the wheel goes with the client)."""
    c = Watcher(d.ws, name="driver")
    await c.connect()
    wheel = await c.create_collider("wheel", radius=RADIUS, width=WIDTH)
    out = []
    angle = 0.0
    for i, x in enumerate(xs):
        if i:
            angle += (x - xs[i - 1]) / (RADIUS * (1 - SLIP))
        seq = await c.send_poses([wheel_pose(wheel, x, angle, press)])
        await c.wait_ack(seq, WAIT)
        t = c.acked_tick
        await c.wait_for(lambda: c.last_forces_tick >= t + HOLD, WAIT)
        held = [c.by_tick.get(k) for k in range(t + HOLD - 1, t + HOLD + 1)]
        if i in (0, len(xs) - 1):
            check(None not in held and strip(held[0]) == strip(held[1]),
                  f"step {i}: the held wheel changes nothing after {HOLD - 1} ticks")
        out.append((strip(c.by_tick[t]), strip(held[-1]) if held[-1] else None))
    await c.close()
    return out


def state(d):
    _, hs = d.heights(0, 0, W, H)
    return hs, d.stats()["soil_compacted"]


FIRST = [1.0 + STEP * i for i in range(60)]  # along the rut
SECOND = [FIRST[-1] - STEP * i for i in range(45)]  # back over it: a second pass


def run(data, crash):
    """One run on data directory `data`; crash: kill -9 and restart between the passes."""
    label = "crashed" if crash else "reference"
    args = dict(extra=["--scene", SCENE], durability="every-tick")
    d = Daemon(data_dir=data, name=f"terrad-{label}", **args)
    check.daemons.append(d)
    try:
        asyncio.run(drive(d, FIRST, 0.02))
        middle = state(d)
        if crash:
            d.kill9()
            d = Daemon(data_dir=data, name=f"terrad-{label}-restarted", **args)
            check.daemons.append(d)
            recovered = state(d)
        else:
            recovered = middle
        second = asyncio.run(drive(d, SECOND, 0.03))  # deeper: in contact
        end = state(d)
    finally:
        d.stop()
    return middle, recovered, second, end


def main():
    global SCENE
    SCENE = scene_file()
    dirs = [tempfile.mkdtemp(prefix="terrad-soil-recovery-") for _ in range(2)]
    try:
        ref = run(dirs[0], crash=False)
        got = run(dirs[1], crash=True)
        (ref_mid, _, ref_second, ref_end), (mid, rec, second, end) = ref, got
        check(ref_mid[1] > 0, f"the first pass compacted the soil (Σ compacted {ref_mid[1]})")
        check(mid == ref_mid, "before the crash: the same heights and Σ compacted as the reference")
        check(rec[0] == mid[0], "after kill -9 and restart: every height as it was")
        check(rec[1] == mid[1],
              f"after kill -9 and restart: Σ compacted {rec[1]} as it was ({mid[1]})")
        pressed = [f for f, _ in ref_second if f[6] > 0]
        check(len(pressed) > len(SECOND) // 2, f"the second pass is in contact ({len(pressed)})")
        same = sum(a == b for a, b in zip(second, ref_second))
        check(same == len(SECOND) and len(second) == len(ref_second),
              f"second pass after recovery: {same} of {len(SECOND)} steps' FORCES bit-identical "
              f"to the uninterrupted run")
        check(end[0] == ref_end[0], "after the second pass: every height as the uninterrupted run's")
        check(end[1] == ref_end[1],
              f"after the second pass: Σ compacted {end[1]} as the uninterrupted run's "
              f"({ref_end[1]})")
    finally:
        os.unlink(SCENE)
        for p in dirs:
            shutil.rmtree(p, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
