#!/usr/bin/python3
# ctest-timeout: 1200
"""Offline runs of the real `terrad simulate` binary.

- Σh is unchanged over 5,000 ticks of tests/scenes/thesis-car.json for every
  method × metric, on both backends (exact int64 equality).
- GL ≡ CPU bit for bit on several scenes (a lugged wheel among them), each
  backend with its own depth, for every method and metric; two runs identical.
- The lugged wheel (tests/scenes/lugged) keeps Σh exact on both backends.
- Scene-level extremes with a defined outcome: a collider covering the whole
  world, colliders crossing world edges, 1×1 and non-power-of-two worlds,
  penetration below the floor, heights near the limit (refused with a message),
  roughness/compression/repose at their bounds, NaN/Inf and absurd values
  refused with the field named.

The GL backend needs an OpenGL 4.3 context; where none can be made the GL
cases are reported as skipped and the CPU cases still run.
"""
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks  # noqa: E402

SCENES = os.path.join(SOURCE, "tests", "scenes")
METHODS = ["iterative", "ssbo", "multi"]
METRICS = ["euclidean", "manhattan", "chebyshev"]

check = Checks()


def simulate(scene, ticks, backend, *extra, out=None):
    args = [BIN, "simulate", "--scene", scene, "--ticks", str(ticks), "--backend", backend]
    args += list(extra)
    if out:
        args += ["--out", out]
    p = subprocess.run(args, capture_output=True, text=True, timeout=900)
    report = None
    if p.returncode == 0:
        report = json.loads(p.stdout)
    return p.returncode, report, p.stderr


def gl_available():
    rc, _, err = simulate(os.path.join(SCENES, "tiny.json"), 1, "gl")
    if rc != 0:
        print("GL backend unavailable, GL cases skipped:", err.strip().splitlines()[-1:])
    return rc == 0


def write_scene(directory, name, doc):
    path = os.path.join(directory, name + ".json")
    with open(path, "w") as f:
        json.dump(doc, f)
    return path


def scene_doc(width, height, colliders, terrain=None, material=None, floor_m=0.0):
    return {
        "name": "generated",
        "world": {"width": width, "height": height, "cell_size_m": 0.05,
                  "units_per_m": 10000, "floor_m": floor_m},
        "terrain": terrain or {"kind": "flat", "height_m": 0.5},
        "material": material or {},
        "colliders": colliders,
    }


def sphere(x, y, z, r, vx=0.0, vy=0.0):
    return {"shape": "sphere", "radius": r, "position": [x, y, z],
            "motion": {"velocity": [vx, vy, 0.0]}}


def test_volume_5000(backends):
    scene = os.path.join(SCENES, "thesis-car.json")
    jobs = [(b, m, k) for b in backends for m in METHODS for k in METRICS]

    def run(job):
        b, m, k = job
        return job, simulate(scene, 5000, b, "--method", m, "--metric", k)

    with ThreadPoolExecutor(max_workers=2) as pool:
        for (b, m, k), (rc, rep, err) in pool.map(run, jobs):
            check(rc == 0, f"thesis-car {b} {m} {k} ran: {err.strip()[-300:]}")
            if rc != 0:
                continue
            check(rep["volume_before"] == rep["volume_after"],
                  f"thesis-car 5000 ticks {b} {m} {k}: {rep['volume_before']} -> "
                  f"{rep['volume_after']}")
            check(rep["active_cells_mean"] > 0, f"{b} {m} {k} simulated something")
            check(rep["refused_windows"] == 0, f"{b} {m} {k} refused no window")
            print(f"volume {b:3} {m:9} {k:9} {rep['volume_before']} == {rep['volume_after']}"
                  f"  tick mean {rep['stages']['tick']['mean_ms']} ms", flush=True)


def read(path):
    with open(path, "rb") as f:
        return f.read()


def test_gl_equals_cpu(tmp):
    scenes = ["thesis-car.json", "spheres.json", "box45.json", "odd.json", "tiny.json",
              "boot.json", os.path.join("lugged", "lugged-wheel.json")]
    for name in scenes:
        scene = os.path.join(SCENES, name)
        for m in METHODS:
            for k in METRICS:
                outs = {}
                for b in ("gl", "cpu"):
                    out = os.path.join(tmp, f"{os.path.basename(name)}-{m}-{k}-{b}.raw")
                    rc, rep, err = simulate(scene, 120, b, "--method", m, "--metric", k, out=out)
                    check(rc == 0, f"{name} {b} {m} {k} ran: {err.strip()[-300:]}")
                    outs[b] = read(out) if rc == 0 else b""
                check(outs["gl"] == outs["cpu"] and outs["gl"],
                      f"{name} {m} {k}: GL heights == CPU heights bit for bit")
        print(f"gl == cpu: {name}", flush=True)


def test_repeatable(tmp, backends):
    scene = os.path.join(SCENES, "spheres.json")
    for b in backends:
        a = os.path.join(tmp, f"rep-{b}-a.raw")
        c = os.path.join(tmp, f"rep-{b}-b.raw")
        simulate(scene, 200, b, "--method", "multi", out=a)
        simulate(scene, 200, b, "--method", "multi", out=c)
        check(read(a) == read(c) and len(read(a)) > 0, f"{b}: two runs identical")


def test_extremes(tmp, backends):
    cases = {
        # a box larger than the world pressing 0.1 m into it: no free column,
        # material stays in its columns (defined outcome: nothing moves)
        "whole-world": scene_doc(40, 30, [{"shape": "box", "half_extents": [5, 5, 1],
                                           "position": [1.0, 0.75, 1.4]}]),
        "edges": scene_doc(64, 64, [sphere(0.05, 1.6, 0.8, 0.4, vx=-0.3),
                                    sphere(3.1, 3.1, 0.8, 0.5, vx=0.4, vy=0.4),
                                    sphere(1.6, 0.0, 0.7, 0.3, vy=-0.2)]),
        "one-cell": scene_doc(1, 1, [sphere(0.025, 0.025, 0.6, 0.2)]),
        "odd": scene_doc(37, 53, [sphere(0.9, 1.3, 0.7, 0.35, vx=0.5, vy=0.2)]),
        # the collider reaches 2 m below the floor: the column stops at the floor
        "below-floor": scene_doc(32, 32, [sphere(0.8, 0.8, -0.1, 0.4)], floor_m=0.2),
        "rough0-comp0-rep0": scene_doc(48, 48, [sphere(1.2, 1.2, 0.7, 0.3, vx=0.4)],
                                       material={"roughness": 0, "compression": 0,
                                                 "repose_deg": 0}),
        "rough1-rep89": scene_doc(48, 48, [sphere(1.2, 1.2, 0.7, 0.3, vx=0.4)],
                                  material={"roughness": 1, "repose_deg": 89}),
        "high-terrain": scene_doc(32, 32, [sphere(0.8, 0.8, 50000.15, 0.3)],
                                  terrain={"kind": "flat", "height_m": 50000.0}),
    }
    with open(os.path.join(SCENES, "lugged", "lugged-wheel.json")) as f:
        cases["lugged-wheel"] = json.load(f)  # its lugs' dents keep Σh exact too
    for name, doc in cases.items():
        path = write_scene(tmp, name, doc)
        for b in backends:
            for m in METHODS:
                rc, rep, err = simulate(path, 60, b, "--method", m)
                check(rc == 0, f"{name} {b} {m} ran: {err.strip()[-300:]}")
                if rc == 0:
                    check(rep["volume_before"] == rep["volume_after"],
                          f"{name} {b} {m}: volume {rep['volume_before']} -> "
                          f"{rep['volume_after']}")
    # compression 1: every unit pressed out is compacted, none displaced —
    # the volume falls, and the other columns are untouched
    doc = scene_doc(48, 48, [sphere(1.2, 1.2, 0.7, 0.3)], material={"compression": 1})
    path = write_scene(tmp, "comp1", doc)
    for b in backends:
        out = os.path.join(tmp, f"comp1-{b}.raw")
        rc, rep, err = simulate(path, 10, b, out=out)
        check(rc == 0 and rep["volume_after"] < rep["volume_before"],
              f"compression 1 on {b} loses volume: {err.strip()[-200:]}")
        if rc == 0:
            import struct
            h = struct.unpack(f"<{48 * 48}i", read(out))
            check(max(h) == 5000, f"compression 1 on {b}: nothing piles up (max {max(h)})")
    # refusals, each naming what is wrong
    refusals = {
        "too-high": (scene_doc(8, 8, [], terrain={"kind": "flat", "height_m": 60000.0}),
                     "terrain"),
        "nan-radius": (scene_doc(8, 8, [{"shape": "sphere", "radius": "nan",
                                         "position": [0, 0, 0]}]), "colliders[0].radius"),
        "inf-position": (scene_doc(8, 8, [{"shape": "sphere", "radius": 0.2,
                                           "position": [1e999, 0, 0]}]),
                         "colliders[0].position"),
        "negative-radius": (scene_doc(8, 8, [{"shape": "sphere", "radius": -1,
                                              "position": [0, 0, 0]}]),
                            "colliders[0].radius"),
        "absurd-size": (scene_doc(8, 8, [{"shape": "box", "half_extents": [1e9, 1, 1],
                                          "position": [0, 0, 0]}]),
                        "colliders[0].half_extents"),
        "huge-world": (scene_doc(1 << 20, 8, []), "world.width"),
        "zero-world": (scene_doc(0, 8, []), "world.width"),
        "bad-repose": (scene_doc(8, 8, [], material={"repose_deg": 90}), "repose_deg"),
        "typo": (scene_doc(8, 8, [], material={"rougness": 0.2}), "rougness"),
    }
    for name, (doc, field) in refusals.items():
        path = os.path.join(tmp, name + ".json")
        with open(path, "w") as f:
            # json.dump writes Infinity for 1e999; write the literal ourselves
            f.write(json.dumps(doc).replace("Infinity", "1e999"))
        rc, _, err = simulate(path, 1, "cpu")
        check(rc != 0 and field in err, f"{name}: refused naming {field!r}: {err.strip()}")
    with open(os.path.join(tmp, "broken.json"), "w") as f:
        f.write('{"world": {"width": 8,, }')
    rc, _, err = simulate(os.path.join(tmp, "broken.json"), 1, "cpu")
    check(rc != 0 and "JSON" in err, f"broken JSON refused: {err.strip()}")


def main():
    backends = ["cpu"]
    if gl_available():
        backends.append("gl")
    else:
        check.skipped += 1
    with tempfile.TemporaryDirectory() as tmp:
        test_extremes(tmp, backends)
        test_repeatable(tmp, backends)
        if "gl" in backends:
            test_gl_equals_cpu(tmp)
        test_volume_5000(backends)
    check.finish()


if __name__ == "__main__":
    main()
