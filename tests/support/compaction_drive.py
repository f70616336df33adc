"""The compaction-memory recovery drive, shared by test_compaction_recovery (a single daemon
killed -9 on its data directory) and test_cluster_compaction_failover (a cluster node killed
-9, the world taken over from JetStream): a persson scene of fresh snow (the snow preset) and
a crust (snow with max_compaction_m 5 mm, as issue 28 measured it), a real client pressing a
sphere along one track across both and back over it, and the figures both tests compare with
a twin run that never failed.

The memory is read where a client can read it: GET /v1/heights?layer=compaction (the memory
of every cell, int32) and /v1/stats `compacted` (its sum).

The drive is deterministic though the daemon ticks on its clock: each pose is sent only once
the world has come to rest under the previous one (wait_steady: a tick that changed nothing
is a fixed point), so how many idle ticks a loaded machine adds does not matter. (A fixed
number of ticks held was not enough: under load some steps were still settling, and two
runs that never crashed differed in 42 cells.)

Not a test itself (ctest registers only test_*.py). Run with /usr/bin/python3.
"""
import time

from service_harness import RecordingClient, json_file
import terrad as tp

W, H, CELL, GROUND = 96, 40, 0.05, 0.4
RADIUS = 0.2
CRUST_X = 2.4  # metres: snow west of it, the crust east
SNOW_M, CRUST_M = 0.30, 0.005  # max_compaction_m: the snow preset's, the crust's
UNITS = 10000
STEP = 0.04  # metres per pose: under a cell
WAIT = 120  # seconds: generous, a loaded 2-core machine

FIRST = [1.2 + STEP * i for i in range(61)]  # 1.2 .. 3.6 m, across both materials
SECOND = [FIRST[-1] - STEP * i for i in range(61)]  # back over it: a second pass
Y = H * CELL / 2


def scene(model=None):
    """The scene (snow, and a crust that remembers 5 mm at most) as a dict: the persson
    model (the default), or `model` (sumner keeps the same memory)."""
    doc = {
        "name": "compaction-recovery",
        "world": {"width": W, "height": H, "cell_size_m": CELL, "units_per_m": UNITS},
        "terrain": {"kind": "flat", "height_m": GROUND},
        "material": {"displace_iterations": 10, "slope_iterations": 10},
        "materials": {
            "snow": {"preset": "snow"},
            "crust": {"preset": "snow", "max_compaction_m": CRUST_M},
        },
        "material_map": {"default": "snow",
                         "paint": [{"material": "crust", "rect": [CRUST_X, 0.0, W * CELL, H * CELL]}]},
        "colliders": [],
    }
    if model:
        doc["material"]["model"] = model
    return doc


def scene_file(model=None):
    """The scene in a temporary file (the caller removes it)."""
    return json_file(scene(model), "terrad-compaction-recovery")


def limit_of(i):
    """Cell i's maximum memory in units (its material's max_compaction_m)."""
    x = (i % W + 0.5) * CELL
    return int(round((CRUST_M if x >= CRUST_X else SNOW_M) * UNITS))


def wait_steady(read, after):
    """Waits until a tick after tick `after` changed nothing: the heights read at one tick
    equal those read at a later one. The sphere then holds still (its previous pose is its
    pose) and each tick is a function of the world alone, so a tick that changed nothing is
    a fixed point: every later tick changes nothing either, and how many of them a loaded
    machine runs does not matter. Heights suffice: compaction always lowers Σh, so a tick
    that left every height as it was compacted nothing. Returns the tick it was seen at, or
    None past WAIT seconds."""
    end = time.monotonic() + WAIT
    last, seen = None, None
    while time.monotonic() < end:
        t, hs = read(0, 0, W, H)
        if t > after:
            if seen is not None and t > last and hs == seen:
                return t
            last, seen = t, hs
        time.sleep(0.01)
    return None


async def drive(check, ws, read, xs, press, world=None):
    """One pass on the daemon or node at websocket url ws (world: hello's): a new client and
    sphere, pressed `press` metres below the ground, one pose per step, each held until the
    world is at rest. read(x, y, w, h, layer=None) gives (tick, values) of a region (a
    daemon's or node's GET /v1/heights). Closes at the end (the sphere goes with the
    client)."""
    c = RecordingClient(ws, name="driver", world=world, record=False)
    await c.connect()
    sphere = await c.create_collider("sphere", radius=RADIUS)
    z = GROUND + RADIUS - press
    for i, x in enumerate(xs):
        seq = await c.send_poses([tp.Pose(sphere, x, Y, z, 1.0, 0.0, 0.0, 0.0)])
        await c.wait_ack(seq, WAIT)
        steady = wait_steady(read, c.acked_tick)
        if not check(steady is not None,
                     f"step {i}: the world comes to rest under the held sphere"):
            break
    await c.close()


def state(heights, memory, stats):
    """What the tests compare: every height, every cell's memory, /v1/stats volume and
    compacted."""
    return {"heights": heights, "memory": memory, "volume": stats["volume"],
            "compacted": stats["compacted"]}


def compare(check, ref, got, what):
    """The checks both tests make. ref, got: dicts start, middle, recovered, end (states)
    of the run that never failed and of the one that did."""
    for name, run in (("reference", ref), ("crashed", got)):
        for k in ("start", "middle", "recovered", "end"):
            s = run[k]
            check(s["compacted"] == sum(s["memory"]),
                  f"{name} {k}: /v1/stats compacted {s['compacted']} is Σ of every cell's "
                  f"memory ({sum(s['memory'])})")
            over = [i for i, m in enumerate(s["memory"]) if not 0 <= m <= limit_of(i)]
            check(not over, f"{name} {k}: the memory never passes M ({len(over)} cells do)")
            total = s["volume"] + s["compacted"]
            start = run["start"]["volume"] + run["start"]["compacted"]
            check(total == start, f"{name} {k}: Σh + Σmemory = {total}, as at the start ({start})")
    mid, rmid = got["middle"], ref["middle"]
    crust = [i for i in range(W * H) if limit_of(i) == int(CRUST_M * UNITS)]
    check(any(rmid["memory"][i] == int(CRUST_M * UNITS) for i in crust),
          "the first pass filled the crust's memory to its 5 mm somewhere")
    check(any(m > int(CRUST_M * UNITS) for m in rmid["memory"]),
          "the first pass compacted the snow past the crust's limit somewhere")
    check(mid["heights"] == rmid["heights"] and mid["memory"] == rmid["memory"],
          "before the failure: the same heights and memory as the reference")
    rec = got["recovered"]
    check(rec["heights"] == mid["heights"], f"after {what}: every height as it was")
    diff = sum(a != b for a, b in zip(rec["memory"], mid["memory"]))
    check(diff == 0, f"after {what}: every cell's memory as it was ({diff} cells differ)")
    check(rec["compacted"] == mid["compacted"],
          f"after {what}: compacted {rec['compacted']} as it was ({mid['compacted']})")
    second_ref = ref["end"]["compacted"] - rmid["compacted"]
    second = got["end"]["compacted"] - mid["compacted"]
    check(second_ref > 0, f"the second pass compacts more ({second_ref} units)")
    check(second == second_ref,
          f"the second pass after {what} compacts {second} units, as the uninterrupted "
          f"run's ({second_ref})")
    end, rend = got["end"], ref["end"]
    hd = sum(a != b for a, b in zip(end["heights"], rend["heights"]))
    md = sum(a != b for a, b in zip(end["memory"], rend["memory"]))
    check(hd == 0, f"after the second pass: every height as the uninterrupted run's "
                   f"({hd} cells differ)")
    check(md == 0, f"after the second pass: every cell's memory as the uninterrupted run's "
                   f"({md} cells differ)")
