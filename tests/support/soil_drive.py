"""The bekker soil-state recovery drive, shared by test_soil_recovery (a single daemon killed
-9 on its data directory) and test_cluster_soil_failover (a cluster node killed -9, the world
taken over from JetStream): a bekker scene, a real client driving a slipping wheel along a rut
and back over it, and the figures both tests compare with a twin run that never failed.

The drive is deterministic though the daemon ticks on its clock: each pose is sent only once
the previous one's tick and HOLD more have gone by (waits by condition), and a wheel held still
changes nothing after a couple of ticks (checked: the last HOLD ticks' FORCES of the first and
last steps agree), so how many idle ticks a loaded machine adds does not matter.

Not a test itself (ctest registers only test_*.py). Run with /usr/bin/python3.
"""
import math

from service_harness import RecordingClient, json_file
import terrad as tp

W, H, CELL, GROUND = 96, 48, 0.05, 0.4
RADIUS, WIDTH, SLIP = 0.25, 0.15, 0.3
STEP = 0.02  # metres per pose: under half a cell
HOLD = 4  # ticks after a pose's tick before the next pose
WAIT = 120  # seconds: generous, a loaded 2-core machine

FIRST = [1.0 + STEP * i for i in range(60)]  # along the rut
SECOND = [FIRST[-1] - STEP * i for i in range(45)]  # back over it: a second pass


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


def scene():
    """The bekker scene (Ding 2011 soil) as a dict."""
    return {
        "name": "soil-recovery",
        "world": {"width": W, "height": H, "cell_size_m": CELL},
        "terrain": {"kind": "flat", "height_m": GROUND},
        "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "ding2011"}},
        "colliders": [],
    }


def scene_file():
    """The scene in a temporary file (the caller removes it)."""
    return json_file(scene(), "terrad-soil-recovery")


def wheel_pose(cid, x, angle, press):
    z = GROUND + RADIUS - press
    return tp.Pose(cid, x, H * CELL / 2, z, math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)


def strip(f):
    """A FORCES entry without the collider id (each run numbers its colliders)."""
    return (f.force, f.torque, f.sinkage_m, f.area_m2, f.patch_width_m, f.slip, f.cells)


async def drive(check, ws, xs, press, world=None):
    """One pass on the daemon or node at websocket url ws (world: hello's): a new client and
    wheel, one pose per step (angle from the slip), each held HOLD ticks. Returns the FORCES
    entry of each step's tick and of its last held tick, then closes (the wheel goes with
    the client)."""
    c = Watcher(ws, name="driver", world=world)
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


def compare(check, ref, got, what):
    """The checks both tests make. ref, got: (middle, recovered, second, end) of the run
    that never failed and of the one that did, each state a (heights, Σ compacted)."""
    (ref_mid, _, ref_second, ref_end), (mid, rec, second, end) = ref, got
    check(ref_mid[1] > 0, f"the first pass compacted the soil (Σ compacted {ref_mid[1]})")
    check(mid == ref_mid, "before the failure: the same heights and Σ compacted as the reference")
    check(rec[0] == mid[0], f"after {what}: every height as it was")
    check(rec[1] == mid[1], f"after {what}: Σ compacted {rec[1]} as it was ({mid[1]})")
    pressed = [f for f, _ in ref_second if f[6] > 0]
    check(len(pressed) > len(SECOND) // 2, f"the second pass is in contact ({len(pressed)})")
    same = sum(a == b for a, b in zip(second, ref_second))
    check(same == len(SECOND) and len(second) == len(ref_second),
          f"second pass after {what}: {same} of {len(SECOND)} steps' FORCES bit-identical "
          f"to the uninterrupted run")
    check(end[0] == ref_end[0], "after the second pass: every height as the uninterrupted run's")
    check(end[1] == ref_end[1],
          f"after the second pass: Σ compacted {end[1]} as the uninterrupted run's ({ref_end[1]})")
