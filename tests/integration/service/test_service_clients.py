#!/usr/bin/python3
# ctest-timeout: 900
"""Several Python clients drive wheels against the real daemon (loopback,
CPU backend, no demo actors):

- four clients, each with a wheel (a cylinder turned to roll) driven along
  its own path with a POSE_BATCH every tick (60 Hz) for about four seconds,
  each subscribed to a region around its path (client 1's region overlaps
  client 0's). Afterwards Σh (/v1/stats volume) is unchanged, every client's
  mirror equals GET /v1/heights of its region bit for bit at the same tick,
  and each got ACKs (in tick order) and CONTACT feedback with plausible
  values (penetrating volume > 0 in the snow, area = cells x cell², unit
  normals, deepest point under the wheel);
- determinism: two clients plough the same cells in the same ticks (a
  scripted, tick-locked scenario at 10 Hz); run on two fresh daemons, the
  final heights are identical bit for bit. The same on the GL backend when
  a GL context can be made (skipped otherwise).
"""
import asyncio
import math
import os
import sys
import traceback

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (BIN, Checks, Daemon, RecordingClient, compare_with_server, skip,  # noqa: E402
                             wheel_pose)
from terrad import Pose  # noqa: E402

check = Checks()
RADIUS = 0.3
SINK = 0.05


# ---- four clients ---------------------------------------------------------------

def client_specs(world):
    """(path start cell, path end cell, region) per client."""
    W, H = world["width"], world["height"]
    s = min(W, H) / 512.0
    def c(v):
        return int(v * s)
    specs = [
        ((c(40), c(100)), (c(220), c(100))),   # 0
        ((c(220), c(130)), (c(40), c(130))),   # 1: its region overlaps 0's
        ((c(260), c(300)), (c(460), c(300))),  # 2
        ((c(440), c(200)), (c(440), c(400))),  # 3: along y
    ]
    out = []
    for (a, b) in specs:
        x0, x1 = min(a[0], b[0]) - 16, max(a[0], b[0]) + 16
        y0, y1 = min(a[1], b[1]) - 24, max(a[1], b[1]) + 24
        x0, y0 = max(x0, 0), max(y0, 0)
        x1, y1 = min(x1, W), min(y1, H)
        out.append((a, b, (x0, y0, x1 - x0, y1 - y0)))
    return out


async def four_clients(d):
    world = d.world()
    cell, units = world["cell_size_m"], world["units_per_m"]
    check(world.get("tick_hz", 0) > 0, f"/v1/world tick_hz is the tick rate ({world.get('tick_hz')})")
    specs = client_specs(world)
    check(specs[0][2][1] < specs[1][2][1] < specs[0][2][1] + specs[0][2][3],
          "client 1's region overlaps client 0's")
    vol0 = d.stats()["volume"]
    clients, wheels, sids, grounds = [], [], [], []
    for i, (a, b, region) in enumerate(specs):
        c = RecordingClient(d.ws, name=f"test-client-{i}")
        await c.connect()
        clients.append(c)
        shape = dict(radius=RADIUS, half_length=0.1) if i != 2 else dict(radius=RADIUS, width=0.2)
        wheels.append(await c.create_collider("cylinder" if i != 2 else "wheel", **shape))
        sids.append(await c.subscribe(*region))
        _, h0 = d.heights(*region)
        grounds.append(h0)
    hz = clients[0].world["tick_hz"]
    check(hz > 0, f"world message tick_hz {hz}")
    hz = hz if hz > 0 else 60
    loop = asyncio.get_running_loop()
    deadline = loop.time() + 10
    while not all(c.mirrors[s].complete for c, s in zip(clients, sids)) and loop.time() < deadline:
        await asyncio.sleep(0.02)
    check(all(c.mirrors[s].complete for c, s in zip(clients, sids)),
          "every client holds the snapshot of its region")

    steps = int(4 * hz)
    t0 = loop.time() + 0.05
    sent = [[] for _ in clients]  # (seq, x, y) per client

    def pose_at(i, k):
        (ax, ay), (bx, by), region = specs[i]
        f = k / (steps - 1)
        cx, cy = ax + (bx - ax) * f, ay + (by - ay) * f
        x, y = (cx + 0.5) * cell, (cy + 0.5) * cell
        rx, ry, rw, _ = region
        ground = grounds[i][(int(cy) - ry) * rw + (int(cx) - rx)] / units
        if i == 2:  # the "wheel" shape: axle along y already
            return Pose(wheels[i], x, y, ground + RADIUS - SINK), x, y
        if ax == bx:  # driving along y: axle along x
            q = (math.cos(math.pi / 4), 0.0, math.sin(math.pi / 4), 0.0)
            return Pose(wheels[i], x, y, ground + RADIUS - SINK, *q), x, y
        return wheel_pose(wheels[i], x, y, ground + RADIUS - SINK), x, y

    async def drive(i):
        c = clients[i]
        for k in range(steps):
            p, x, y = pose_at(i, k)
            seq = await c.send_poses([p])
            sent[i].append((seq, x, y))
            delay = t0 + (k + 1) / hz - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)

    await asyncio.gather(*(drive(i) for i in range(len(clients))))
    drive_s = loop.time() - t0

    # park every wheel 5 m up, keep acking, compare each mirror with the server
    async def parked(i):
        (ax, ay), (bx, by), _ = specs[i]
        x, y = (bx + 0.5) * cell, (by + 0.5) * cell
        return await clients[i].send_poses([wheel_pose(wheels[i], x, y, 5.0)])

    for i in range(len(clients)):
        await parked(i)
    await asyncio.sleep(0.2)
    for i, c in enumerate(clients):
        same, tick, detail = await compare_with_server(c, d, sids[i], specs[i][2],
                                                       lambda i=i: parked(i))
        check(same, f"client {i}: mirror of {specs[i][2]} equals GET /v1/heights bit for bit "
                    f"(tick {tick}) {detail}")
    vol1 = d.stats()["volume"]
    check(vol1 == vol0, f"Σh unchanged by four ploughing wheels: {vol0} -> {vol1}")

    for i, c in enumerate(clients):
        n = c.counts
        # behaviour, not speed: a loaded machine merges ticks, so no count per batch
        check(n["ACK"] > 0, f"client {i}: ACKs {n['ACK']} for {steps} batches")
        ticks = [t for t, _ in c.acks]
        seqs = [s for _, s in c.acks]
        check(all(b > a for a, b in zip(ticks, ticks[1:])), f"client {i}: ACK ticks increase")
        check(all(b >= a for a, b in zip(seqs, seqs[1:])), f"client {i}: ACK seqs never go back")
        check(seqs and seqs[-1] >= sent[i][-1][0], f"client {i}: the last batch was acknowledged "
              f"({seqs[-1] if seqs else None} >= {sent[i][-1][0]})")
        check(n["DELTA"] > 10, f"client {i}: DELTA frames {n['DELTA']}")
        check(n["CONTACT"] > 0, f"client {i}: CONTACT frames {n['CONTACT']}")  # no count: load merges ticks
        check(not c.errors, f"client {i}: no error messages: {c.errors[:3]}")
        first_used = min((t for t, _ in c.acks), default=None)
        early = [(t, ct) for t, ct in c.contact_log if ct.id == wheels[i] and
                 (first_used is None or t < first_used)]
        check(not early, f"client {i}: no CONTACT entry before the wheel's first pose was used "
                         f"(tick {first_used}); {len(early)} came, first {early[:1]}")
        mine = [ct for t, ct in c.contact_log if ct.id == wheels[i] and first_used is not None
                and t >= first_used]
        pen = [ct for ct in mine if ct.volume > 0]
        check(len(pen) > 0,  # not a fraction: how many ticks a pose spans depends on the load
              f"client {i}: penetrating volume > 0 in the snow ({len(pen)} of {len(mine)} entries)")
        (ax, ay), (bx, by), _ = specs[i]
        bad = []
        for ct in pen:
            area = ct.cells * cell * cell
            nlen = math.sqrt(sum(v * v for v in ct.normal))
            # distance of the deepest point from the path line, metres
            if ay == by:
                off = abs(ct.deepest[1] - (ay + 0.5) * cell)
            else:
                off = abs(ct.deepest[0] - (ax + 0.5) * cell)
            if not (ct.cells > 0 and abs(ct.area_m2 - area) <= 1e-3 * max(area, 1e-6) + 1e-6
                    and abs(nlen - 1) < 1e-3 and ct.normal[2] > 0.5 and off <= RADIUS + 0.1
                    and 0 < ct.support_height_m < 5
                    and ct.volume <= ct.cells * RADIUS * 2 * d_units(c)):
                bad.append(ct)
        check(not bad, f"client {i}: plausible contact values ({len(bad)} implausible, "
                       f"first {bad[:1]})")
        # support height: the terrain under the wheel's centre, near the wheel's bottom
        last = mine[-1] if mine else None
        check(last is not None and 0 < last.support_height_m < 5,
              f"client {i}: support height {last.support_height_m if last else None}")
    print(f"info: drove {steps} ticks in {drive_s:.2f} s; deltas per client "
          f"{[c.counts['DELTA'] for c in clients]}, bytes {[c.counts['delta_bytes'] for c in clients]}",
          flush=True)
    for c in clients:
        await c.close()


def d_units(c):
    return c.world.get("units_per_m", 10000)


# ---- determinism -----------------------------------------------------------------

async def scripted(d, steps=30):
    """Two clients, two wheels a few cells apart on the same row, stepped
    one tick at a time. Returns (valid, final heights, region, detail)."""
    world = d.world()
    cell, units = world["cell_size_m"], world["units_per_m"]
    W, H = world["width"], world["height"]
    row = H // 2
    xa, xb = W // 5, W // 5 + 60
    region = (xa - 16, row - 16, xb - xa + 40, 32)
    _, ground = d.heights(*region)
    a = RecordingClient(d.ws, name="plough-a", record=False)
    b = RecordingClient(d.ws, name="plough-b", record=False)
    await a.connect()
    await b.connect()
    wa = await a.create_collider("cylinder", radius=RADIUS, half_length=0.1)
    wb = await b.create_collider("cylinder", radius=RADIUS, half_length=0.1)

    def z_at(x):
        col = int(x / cell) - region[0]
        return ground[16 * region[2] + col] / units + RADIUS - SINK

    used = {"a": {}, "b": {}}  # seq -> first tick that acknowledged it
    a.on_ack = lambda t, s: used["a"].setdefault(s, t)
    b.on_ack = lambda t, s: used["b"].setdefault(s, t)
    loop = asyncio.get_running_loop()
    y = (row + 0.5) * cell
    seqs = []
    for k in range(steps + 1):
        if k < steps:
            x = (xa + (xb - xa) * k / (steps - 1)) * cell
            pa = wheel_pose(wa, x, y, z_at(x))
            pb = wheel_pose(wb, x + 0.1, y, z_at(x + 0.1))  # 2 cells ahead: the same cells
        else:
            pa = wheel_pose(wa, x, y, 5.0)
            pb = wheel_pose(wb, x + 0.1, y, 5.0)
        sa = await a.send_poses([pa])
        sb = await b.send_poses([pb])
        seqs.append((sa, sb))
        deadline = loop.time() + 120  # generous: a loaded machine may be slow, never wrong
        while (sa not in used["a"] or sb not in used["b"]) and loop.time() < deadline:
            await asyncio.sleep(0.002)
        if sa not in used["a"] or sb not in used["b"]:
            await a.close()
            await b.close()
            return False, None, region, f"step {k}: no ACK within 120 s"
    ticks = [(used["a"][sa], used["b"][sb]) for sa, sb in seqs]
    valid = all(ta == tb for ta, tb in ticks) and all(
        t2[0] == t1[0] + 1 for t1, t2 in zip(ticks, ticks[1:]))
    # let the parked wheels' windows settle, then read the heights
    prev = None
    for _ in range(40):
        await a.send_poses([])
        await asyncio.sleep(0.25)
        _, h = d.heights(*region)
        if h == prev:
            break
        prev = h
    await a.close()
    await b.close()
    detail = "" if valid else f"steps did not land one per tick: {ticks}"
    return valid, prev, region, detail


async def determinism(backend, runs=2):
    results = []
    for r in range(runs):
        for attempt in range(5):
            try:
                # Each step must land in the tick after the last one's ACK. At 4 Hz (250 ms) both
                # backends missed it 5 times running under make test-stress (a loaded GL tick left
                # no window at all), so 1 Hz. The check itself is unchanged; only the room a
                # loaded machine gets.
                d = Daemon(backend=backend, tick_hz=1, name=f"terrad-{backend}-det{r}")
            except RuntimeError as e:
                if backend == "gl":
                    return None, str(e).splitlines()[-1] if str(e) else "no GL"
                raise
            check.daemons.append(d)
            try:
                vol0 = d.stats()["volume"]
                _, start = d.heights(*scripted_region(d))
                valid, heights, region, detail = await scripted(d)
                vol1 = d.stats()["volume"]
            finally:
                st = d.stop()
            check(st == 0, f"{backend}: SIGTERM exits 0 ({st})")
            check(vol0 == vol1, f"{backend}: Σh unchanged by the scripted ploughing {vol0} -> {vol1}")
            if valid:
                check(heights is not None and heights != start,
                      f"{backend}: the scripted wheels changed the terrain")
                results.append(heights)
                break
            print(f"info: {backend} run {r} attempt {attempt}: {detail}; retrying", flush=True)
        else:
            check(False, f"{backend}: could not step the scenario one pose per tick in 5 attempts")
            return False, "timing"
    same = results[0] == results[1]
    if not same:
        diff = sum(1 for p, q in zip(results[0], results[1]) if p != q)
        print(f"info: {backend}: {diff} cells differ between runs", flush=True)
    return same, results


def scripted_region(d):
    world = d.world()
    W, H = world["width"], world["height"]
    row = H // 2
    xa, xb = W // 5, W // 5 + 60
    return (xa - 16, row - 16, xb - xa + 40, 32)


async def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    try:
        await all_cases()
    except Exception:
        check(False, "the test raised:\n" + traceback.format_exc())
    check.finish()


async def all_cases():
    d = Daemon(backend="cpu", name="terrad-cpu-4clients")
    check.daemons.append(d)
    try:
        await four_clients(d)
    finally:
        st = d.stop()
    check(st == 0, f"SIGTERM stops the daemon with status 0 ({st})")

    same, res = await determinism("cpu")
    check(same, "cpu: two clients ploughing the same cells: identical heights on two fresh daemons")
    cpu_heights = res[0] if same else None

    same, res = await determinism("gl")
    if same is None:
        print(f"skip: GL backend: {res}", flush=True)
    else:
        check(same, "gl: two clients ploughing the same cells: identical heights on two fresh daemons")
        if same and cpu_heights is not None:
            diff = sum(1 for p, q in zip(cpu_heights, res[0]) if p != q)
            print(f"info: GL vs CPU twin after the scripted scenario: {diff} of {len(cpu_heights)} "
                  f"cells differ", flush=True)


if __name__ == "__main__":
    asyncio.run(main())
