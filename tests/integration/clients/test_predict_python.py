#!/usr/bin/python3
# ctest-timeout: 480
"""Client-side prediction in the Python client (terrad.predict, docs/engines.md "Prediction")
against a real daemon (--backend cpu, no demo actors, a flat scene of default material):

- one client predicts a subscription and drives a sphere, a rolling wheel, a capsule
  (its quaternion not of norm 1) and a rolling wheel with grousers (lugs deeper than its rim:
  the twin library's terrad_twin_prediction_add_wheel; before it the client refused to
  predict one) through it for 600 ticks, one pose batch per tick. The prediction shows the rut before the server could have it: at the first
  pressing batch, before its bytes are sent, the predicted heights are below the mirror's
  under the sphere. At every ACK the replay of the server's ticks on the client's twin
  (from the previous ACK's heights, with the poses the ACKs say the server used) equals the
  server's heights at that tick in every cell: 0 cells differ at every compared ACK;
- a second client ploughs through the same window while the first drives: the first one's
  replay then differs from the server (it cannot know the other's rut), and after every
  reconciliation with nothing pending the prediction equals the mirror, the rut of the
  other included; at the end prediction, mirror and GET /v1/heights are equal at one tick;
- bad input to the new API gets a clear error naming the field (an unknown subscription, a
  subscription without its snapshot, an unknown model, a non-finite number, an unknown key;
  terrad_twin_place with an unknown id or a NaN position), and the client goes on driving and
  predicting;
- a load-driven wheel (load_n, on a second daemon's bekker world: the server finds its height
  where the soil carries the load each tick, PROTOCOL.md "Load-driven colliders") rolls with
  slip through a predicted window for 300 ticks: the prediction runs the server's own search
  (terrad_twin_prediction_set_load) from the soil state and height its replay of the previous
  ACK reached, so every compared ACK is exact; the server did move it (its FORCES heights are
  below the posed one). Without load_n in the twin (pose-driven at the client's height) 0 of
  301 compared ACKs were exact; with it but the soil state not kept across restarts, 0 of 301
  too. A NaN, negative or infinite load_n, and any load on a non-bekker twin, are refused
  naming load_n. Then it rolls back with the next soil-state restore failing (the twin
  library's test hook, terrad_twin_fault_restores): Prediction.errors counts it and last_error
  keeps the twin's sentence, nothing is raised, and the later ACKs are taken, compared and
  reset to the mirror (before, the TwinError went to client.errors and nothing counted it);
- terrad_twin_place, offline: a twin restarted from another's heights after one tick, its
  sphere placed where that tick left it, gives the next tick the same heights as the twin
  that ran both ticks.
"""
import asyncio
import json
import math
import os
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (BIN, SOIL_PREDICT_REGION as SOIL_REGION, Checks,  # noqa: E402
                             Daemon, skip, soil_predict_config, twin_config)

import terrad  # noqa: E402
from terrad import Client, MsgType, Pose, TwinError  # noqa: E402

TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
LIB = os.path.join(os.path.dirname(BIN), "libterrad-twin.so")
if not (os.path.exists(TRACE) and os.path.exists(LIB)):
    skip("twin_trace / libterrad-twin.so not built")
os.environ["TERRAD_TWIN_LIBRARY"] = LIB
check = Checks()
WAIT = 120  # generous: the machine may be loaded
SCENE = {"name": "predict", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
REGION = (64, 80, 128, 96)  # x, y, w, h cells: the predicted window
LUGS = {"count": 12, "height": 0.05, "thickness": 0.04}  # a cell tall: each lug its own dent


def pose_at(cid, i, n, y_cell, z, cell):
    """Along x through the window, leaving a 24-cell halo at both ends."""
    x0, x1 = (REGION[0] + 24) * cell, (REGION[0] + REGION[2] - 24) * cell
    return Pose(cid, x0 + (x1 - x0) * i / (n - 1), (y_cell + 0.5) * cell, z)


def check_exact(pred, mirror, what):
    """Every compared ACK's replay had 0 cells differing; nothing pending: the mirror's state."""
    check(pred.replayed >= 10 and pred.exact == pred.replayed,
          f"{what}every compared ACK: the client's replay equals the server's heights in every "
          f"cell ({pred.exact} of {pred.replayed} exact; {pred.skipped} not compared, "
          f"{pred.reconciled} reconciliations, last differing {pred.last_differing})")
    check(list(pred.twin.read()) == list(mirror.heights),
          f"{what}with nothing pending, the prediction is the server's state")


async def bad_input(client, sid, cfg):
    try:
        client.predict(9999, cfg)
        check(False, "predict on an unknown subscription is refused")
    except ValueError as e:
        check("sid" in str(e), f"an unknown subscription is refused naming sid ({e})")
    late = await client.subscribe(0, 0, 8, 8)
    client.mirrors[late].versions[0] = 0  # as if its snapshot had not come yet
    try:
        client.predict(late, cfg)
        check(False, "predict before the snapshot is refused")
    except ValueError as e:
        check("snapshot" in str(e), f"predict before the snapshot is refused ({e})")
    await client.unsubscribe(late)
    for key, value in (("model", "nope"), ("compression", math.nan), ("shape_of_things", 1.0)):
        try:
            client.predict(sid, {**cfg, key: value})
            check(False, f"predict with {key}={value} is refused")
        except TwinError as e:
            check(key in str(e), f"a bad {key} is refused naming it ({e})")
    check(sid not in client.predictions, "a refused predict leaves no prediction behind")


async def drive(d, cfg):
    async with Client(d.ws) as a, Client(d.ws) as b:
        world = a.world
        cell, hz, units = world["cell_size_m"], world["tick_hz"], world["units_per_m"]
        sid = await a.subscribe(*REGION)
        await a.wait_complete(sid, WAIT)
        await bad_input(a, sid, cfg)
        pred = a.predict(sid, cfg)
        early = {}

        def seen(seq):  # called before batch seq's bytes are sent
            if "cells" in early:
                return
            mine, server = pred.twin.read(), a.mirrors[sid].heights
            lower = sum(1 for p, s in zip(mine, server) if p < s)
            if lower:
                early.update(cells=lower, seq=seq, acked=a.acked_seq)

        pred.on_predict(seen)
        radius = 0.3
        # Bad lugs while predicting: the server refuses them naming the field, and the
        # prediction is as it was (nothing added, nothing ticked).
        for bad, field in (({**LUGS, "count": -2}, "grousers.count"),
                           ({**LUGS, "height": 0.5}, "grousers.height"),
                           ({**LUGS, "thickness": -0.01}, "grousers.thickness")):
            try:
                await a.create_collider("wheel", radius=radius, width=0.2, grousers=bad)
                check(False, f"a lugged wheel with {bad} is refused")
            except terrad.ServerError as e:
                check(field in str(e), f"a bad {field} is refused naming it ({e})")
        check(pred.predicted == 0 and not a.own_colliders, "the refused wheels left no trace")
        z = 0.4 + radius - 0.06
        ball = await a.create_collider("sphere", radius=radius)
        # A rolling wheel (the axle's quaternion turning) and a capsule lying along x (a
        # quaternion of norm 1.04, turned from the wire's z axis): the server's pose
        # arithmetic, float32 and normalisation, is the prediction's too.
        wheel = await a.create_collider("wheel", radius=radius, width=0.2)
        capsule = await a.create_collider("capsule", radius=0.12, half_length=0.25)
        lugged = await a.create_collider("wheel", radius=radius, width=0.2, grousers=LUGS)
        y_a, y_w, y_c, y_l = REGION[1] + 20, REGION[1] + 40, REGION[1] + 60, REGION[1] + 50
        n = 600

        def own_poses(i):
            wp, lp = pose_at(wheel, i, n, y_w, z, cell), pose_at(lugged, i, n, y_l, z, cell)
            for p in (wp, lp):  # both roll
                angle = p.x / radius
                p.qw, p.qy = math.cos(angle / 2), math.sin(angle / 2)
            cp = pose_at(capsule, i, n, y_c, 0.4 + 0.12 - 0.04, cell)
            cp.qw = cp.qy = 1.04 * math.sqrt(0.5)
            return [pose_at(ball, i, n, y_a, z, cell), wp, cp, lp]

        for i in range(n):
            await a.send_poses(own_poses(i))
            await asyncio.sleep(1 / hz)
        last = own_poses(n - 1)
        for p in last:
            p.z += 5.0
        await a.send_poses(last)
        seq = await a.send_poses([pose_at(ball, n - 1, n, y_a, z + 5.0, cell)])  # lifted
        await a.wait_ack(seq, WAIT)
        print(f"drove {n} ticks: {pred.predicted} batches predicted, {pred.reconciled} ACKs "
              f"reconciled, {pred.replayed} replays compared ({pred.exact} exact), {pred.on_time} "
              f"predictions already the server's heights at their ACK, "
              f"{pred.skipped} not compared; first rut seen early: {early}", flush=True)
        check(early.get("cells", 0) > 0 and early["acked"] < early["seq"],
              f"the prediction shows the rut before the server's ACK of its batch ({early})")
        check_exact(pred, a.mirrors[sid], "")
        rows = [list(pred.twin.read(REGION[0], y, REGION[2], 1)) for y in (y_a, y_w, y_c, y_l)]
        check(all(min(r) < int(0.4 * units) - int(0.02 * units) for r in rows),
              f"sphere, wheel, capsule and lugged wheel left ruts ({[min(r) for r in rows]} "
              "units at the deepest)")
        check(min(rows[3]) < min(rows[1]) - int(0.02 * units),
              f"the lugs dent deeper than the smooth wheel's rim ({min(rows[3])} < {min(rows[1])})")

        # A second client ploughs the same window: only the server knows its rut.
        ball_b = await b.create_collider("sphere", radius=radius)
        y_b = REGION[1] + 80
        resets = []

        def after_ack(tick, seq):  # runs after the prediction reconciled this ACK
            if not pred.pending:
                resets.append(list(pred.twin.read()) == list(a.mirrors[sid].heights))

        a.on(MsgType.ACK, after_ack)
        replayed0, exact0 = pred.replayed, pred.exact
        n2 = 240
        for i in range(n2):
            await b.send_poses([pose_at(ball_b, i, n2, y_b, z, cell)])
            if i % 2 == 0:  # a still sphere of its own, so that ACKs come to the first client
                await a.send_poses([pose_at(ball, n - 1, n, y_a, z + 5.0, cell)])
            await asyncio.sleep(1 / hz)
        seq_b = await b.send_poses([pose_at(ball_b, n2 - 1, n2, y_b, z + 5.0, cell)])
        await b.wait_ack(seq_b, WAIT)
        seq = await a.send_poses([pose_at(ball, n - 1, n, y_a, z + 5.0, cell)])
        await a.wait_ack(seq, WAIT)  # an ACK with nothing pending, after all of B's rut
        check(pred.replayed - replayed0 > pred.exact - exact0,
              "another client's rut makes the replay differ from the server "
              f"({pred.exact - exact0} of {pred.replayed - replayed0} exact)")
        check(len(resets) > 0 and all(resets),
              f"after every reconciliation the prediction is the server's ({resets.count(False)} "
              f"of {len(resets)} not)")

        # The end: prediction, mirror and GET /v1/heights at one tick.
        loop = asyncio.get_running_loop()
        same = False
        for _ in range(10):
            tick, grid = await loop.run_in_executor(None, lambda: d.heights(*REGION))
            seq = await a.send_poses([pose_at(ball, n - 1, n, y_a, z + 5.0, cell)])
            await a.wait_ack(seq, WAIT)
            if a.acked_tick >= tick:
                http = [int(v) for v in grid]
                same = http == list(a.mirrors[sid].heights) == list(pred.twin.read())
                break
        check(same, "prediction, mirror and GET /v1/heights are equal once all is acknowledged")
        check(any(v < int(0.4 * units) for v in a.mirrors[sid].heights[80 * REGION[2]:81 * REGION[2]]),
              "the second client's rut is in the first client's prediction")
        check(not a.errors, f"no errors reached the client ({a.errors[:3]})")
        check(terrad.Prediction is type(pred), "the package exports Prediction")


def twin_lugs(cfg):
    """terrad.Twin.add_wheel: grousers of a bad form or value are refused naming the field (the
    twin goes on), and good ones press below the smooth rim."""
    with terrad.Twin(cfg, *REGION) as t:
        for bad, field in (({**LUGS, "count": 400}, "grousers.count"),
                           ({**LUGS, "count": 2.5}, "grousers.count"),
                           ({**LUGS, "height": -0.05}, "grousers.height"),
                           ({**LUGS, "thickness": 1.0}, "grousers.thickness"),
                           ({**LUGS, "height": "tall"}, "grousers.height"),
                           ({"count": 12, "height": 0.05}, "grousers"), ([12, 0.05, 0.04], "grousers")):
            try:
                t.add_wheel(3, 0.3, 0.1, bad)
                check(False, f"add_wheel refuses {bad}")
            except TwinError as e:
                check(field in str(e), f"add_wheel refuses {bad} naming {field} ({e})")
        lowest = []
        for cid, lugs in ((3, None), (4, LUGS)):
            t.write([int(0.4 * 10000)] * (REGION[2] * REGION[3]))
            t.add_wheel(cid, 0.3, 0.1, lugs)
            t.set_pose(cid, (5.0 + 0.025, 6.0, 0.71))  # the axle over cell centres
            t.tick()
            lowest.append(min(t.read()))
            t.remove_collider(cid)
        check(lowest[0] == 4000 and lowest[1] < 4000,
              f"the smooth rim 1 cm above the soil leaves it, its lugs press ({lowest})")
        t.add_wheel(5, 0.3, 0.1)
        try:  # this world's model is not bekker: no soil to carry a load
            t.set_load(5, 20.0)
            check(False, "set_load on a non-bekker twin is refused")
        except TwinError as e:
            check("load_n" in str(e) and "bekker" in str(e),
                  f"a load on a non-bekker twin is refused naming load_n ({e})")


def place_resumes(cfg):
    """terrad_twin_place: a twin restarted from another's heights after tick 1, its sphere
    placed where tick 1 left it, gives tick 2 the same heights as the twin that ran both (the
    sweep from the placed pose, not a fresh first press); bad places are refused."""
    window = (REGION[0], REGION[1], REGION[2], REGION[3])
    p, q = (4.6, 5.9, 0.64), (0.95, 0.0, 0.31, 0.0)
    p2 = (4.75, 5.9, 0.64)
    with terrad.Twin(cfg, *window) as a:
        a.add_collider(7, "sphere", radius=0.3)
        a.set_pose(7, p, q)
        a.tick()
        after1 = a.read()
        a.set_pose(7, p2, q)
        a.tick()
        after2 = a.read()
    with terrad.Twin(cfg, *window, heights=after1) as b:
        b.add_collider(7, "sphere", radius=0.3)
        b.place(7, p, q)
        b.set_pose(7, p2, q)
        b.tick()
        check(b.read() == after2 and after2 != after1,
              "a placed collider resumes exactly: tick 2 from tick 1's heights equals the run")
        for args, field in (((8, p, q), "id"), ((7, (math.nan, 1.0, 1.0), q), "position")):
            try:
                b.place(*args)
                check(False, f"place refuses a bad {field}")
            except TwinError as e:
                check(field in str(e), f"place refuses a bad {field} naming it ({e})")
        b.tick()  # and goes on


async def drive_loaded(d, cfg):
    """A load-driven wheel rolling with slip 0.2 on bekker, predicted: every ACK exact."""
    async with Client(d.ws) as a:
        world = a.world
        cell, hz = world["cell_size_m"], world["tick_hz"]
        sid = await a.subscribe(*SOIL_REGION)
        await a.wait_complete(sid, WAIT)
        pred = a.predict(sid, cfg)
        radius, load = 0.1, 40.0
        wheel = await a.create_collider("wheel", radius=radius, width=0.08, load_n=load,
                                        forces_height=True)
        for bad in (math.nan, -3.0, math.inf):  # the twin library's own check
            try:
                pred.twin.set_load(wheel, bad)
                check(False, f"set_load refuses {bad}")
            except TwinError as e:
                check("load_n" in str(e), f"set_load refuses {bad} naming load_n ({e})")
        n, z = 300, 0.4 + radius  # the posed height: the server's search starts there once
        x0, x1 = (SOIL_REGION[0] + 16) * cell, (SOIL_REGION[0] + SOIL_REGION[2] - 16) * cell
        y = (SOIL_REGION[1] + SOIL_REGION[3] / 2) * cell
        heights = set()

        async def roll(start, end, n):
            """The wheel from x start to end in n batches, one a tick, until all are acked."""
            for i in range(n):
                x = start + (end - start) * i / (n - 1)
                angle = (x - start) / (radius * (1 - 0.2))  # turning faster than it travels: slip 0.2
                await a.send_poses([Pose(wheel, x, y, z, math.cos(angle / 2), 0.0,
                                         math.sin(angle / 2), 0.0)])
                f = a.forces.get(wheel)
                if f is not None and f.height_m is not None:
                    heights.add(round(f.height_m, 6))
                await asyncio.sleep(1 / hz)
            seq = await a.send_poses([Pose(wheel, end, y, z, 1.0, 0.0, 0.0, 0.0)])
            await a.wait_ack(seq, WAIT)

        await roll(x0, x1, n)
        print(f"load-driven: {pred.predicted} batches predicted, {pred.replayed} replays "
              f"compared ({pred.exact} exact), {pred.on_time} on time, {pred.skipped} not "
              f"compared; {len(heights)} found heights, {min(heights, default=0)}.."
              f"{max(heights, default=0)} m", flush=True)
        check(len(heights) > 10 and max(heights) < z - 0.005,
              f"the server found the wheel's heights, below the posed {z} m ({len(heights)} of "
              f"them, highest {max(heights, default=None)})")
        check_exact(pred, a.mirrors[sid], "load-driven wheel: ")
        check(pred.errors == 0 and pred.last_error == "",
              f"no prediction errors ({pred.errors}: {pred.last_error!r})")

        # Back over the last third with the next soil-state restore failing (the twin
        # library's test hook: out of memory for it cannot be provoked): the ACK is taken, the
        # error counted with the twin's sentence, and the client goes on.
        resets = []

        def after_ack(tick, seq):  # runs after the prediction reconciled this ACK
            if not pred.pending:
                resets.append(list(pred.twin.read()) == list(a.mirrors[sid].heights))

        a.on(MsgType.ACK, after_ack)
        reconciled0, replayed0, exact0 = pred.reconciled, pred.replayed, pred.exact
        terrad.twin.load_library().terrad_twin_fault_restores(1)  # the process's next restore
        await roll(x1, x1 - (x1 - x0) / 3, 100)
        terrad.twin.load_library().terrad_twin_fault_restores(0)
        print(f"restore failed: {pred.errors} errors ({pred.last_error}); then "
              f"{pred.reconciled - reconciled0} reconciled, {pred.replayed - replayed0} compared "
              f"({pred.exact - exact0} exact)", flush=True)
        check(pred.errors == 1 and "soil state" in pred.last_error,
              f"the failed restore is counted with the twin's sentence ({pred.errors}: "
              f"{pred.last_error!r})")
        check(pred.reconciled - reconciled0 >= 10 and pred.replayed - replayed0 >= 10,
              f"the ACKs after it are taken and compared ({pred.reconciled - reconciled0}, "
              f"{pred.replayed - replayed0})")
        check(len(resets) > 10 and all(resets),
              f"with nothing pending, the prediction is the server's state at every ACK after it "
              f"({resets.count(False)} of {len(resets)} not)")
        check(not a.errors, f"no errors reached the client ({a.errors[:3]})")


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-predict-") as tmp:
        path = os.path.join(tmp, "scene.json")
        with open(path, "w") as f:
            json.dump(SCENE, f)
        cfg = twin_config(path)
        check(cfg.get("model") and cfg.get("width") == 256, f"the scene's twin config ({cfg})")
        place_resumes(cfg)
        twin_lugs(cfg)
        with check.running(Daemon(extra=["--scene", path, "--no-data"])) as d:
            asyncio.run(asyncio.wait_for(drive(d, cfg), 240))
        soil, soil_cfg = soil_predict_config(tmp)
        check(soil_cfg.get("model") == "bekker", f"the bekker scene's twin config ({soil_cfg})")
        with check.running(Daemon(extra=["--scene", soil, "--no-data"])) as d:
            asyncio.run(asyncio.wait_for(drive_loaded(d, soil_cfg), 240))
    check.finish()


main()
