#!/usr/bin/python3
# ctest-timeout: 900
"""Issue 24's heavy scenes (tests/scenes/heavy: a box pressed 1 m into 5 m of
snow at 12 m/s, a blade and tracks in steep dunes on 2048², 48 deep feet, a
4096² steep world with six deep colliders) give the same heights whatever
the thread count and on both backends: `terrad simulate --out` is byte for
byte identical at --threads 1 and 2 on the CPU twin (three method × metric
pairs on the 1024² scenes, SSBO on the larger ones: a 4096² world's start-up
and heights file cost seconds per run on a busy machine), and on the GL
backend against the CPU for a short run.

These scenes drive the paths the fast stages take on deep and steep
windows: jump flooding by runs of 8 cells along a row with ties redone one
by one (sim_jump_flood.c), slope evening by 16-cell blocks on a one-material
window (sim_stages.c), both banded across threads. tests/unit/test_sparse_stages.c
compares the same stages with their dense references on random windows.
Each run must also move material (tiles change) and keep Σh (no compression
in these scenes).
"""
import json
import os
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, simulate  # noqa: E402

HEAVY = os.path.join(SOURCE, "tests", "scenes", "heavy")
PAIRS = [("ssbo", "euclidean"), ("iterative", "chebyshev"), ("multi", "manhattan")]
TICKS = 8
GL_TICKS = 3


def heights(scene, ticks, out, *extra, backend="cpu"):
    rc, report, err = simulate(scene, ticks, "--out", out, *extra, backend=backend)
    data = b""
    if rc == 0:
        with open(out, "rb") as f:
            data = f.read()
    return rc, report, err, data


def main():
    check = Checks()
    scenes = sorted(f for f in os.listdir(HEAVY) if f.endswith(".json"))
    check(len(scenes) >= 4, f"heavy scenes found: {scenes}")
    with tempfile.TemporaryDirectory() as tmp:
        gl_ok = simulate(os.path.join(HEAVY, "deep-box.json"), 1, backend="gl")[0] == 0
        if not gl_ok:
            print("GL backend unavailable here: the GL cases are skipped", flush=True)
        for name in scenes:
            scene = os.path.join(HEAVY, name)
            with open(scene) as f:
                small = json.load(f)["world"]["width"] <= 1024
            for method, metric in PAIRS if small else PAIRS[:1]:
                runs = {}
                for threads in (1, 2):
                    out = os.path.join(tmp, f"{name}-{method}-{threads}.bin")
                    rc, rep, err, data = heights(scene, TICKS, out, "--method", method,
                                                 "--metric", metric, "--threads", str(threads))
                    check(rc == 0, f"{name} {method}/{metric} --threads {threads} runs "
                                   f"({err.strip()[-300:]})")
                    runs[threads] = data
                    if rc == 0 and threads == 1:
                        check(rep["active_cells_mean"] > 1000,
                              f"{name}: heavy ({rep['active_cells_mean']:.0f} active cells)")
                        check(rep["world_stored_tiles"] > 0,
                              f"{name} {method}: the colliders moved material")
                        check(rep["volume_before"] == rep["volume_after"],
                              f"{name} {method}: Σh kept ({rep['volume_before']} -> "
                              f"{rep['volume_after']})")
                check(runs[1] and runs[2] == runs[1],
                      f"{name} {method}/{metric}: 2 threads give the heights of 1")
            if gl_ok:
                outs = {}
                for backend in ("cpu", "gl"):
                    out = os.path.join(tmp, f"{name}-{backend}.bin")
                    rc, _, err, outs[backend] = heights(scene, GL_TICKS, out, "--method", "ssbo",
                                                        backend=backend)
                    check(rc == 0, f"{name} {backend} runs ({err.strip()[-300:]})")
                check(outs["gl"] and outs["gl"] == outs["cpu"],
                      f"{name}: GL heights == CPU heights bit for bit ({GL_TICKS} ticks)")
            print(f"done: {name}", flush=True)
    return check.finish()


if __name__ == "__main__":
    sys.exit(main())
