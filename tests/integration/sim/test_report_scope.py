#!/usr/bin/python3
# ctest-timeout: 300
"""Issue 12, "Also": the simulate report walks stored tiles, and the model
lists name every model.

- A 65,536 x 65,536 world with two colliders at opposite corners: the report
  finishes, says max_slope_excess_scope "stored_tiles", and counts the cells
  it scanned: the stored tiles and a one-cell ring, far under the 2.7e9 of
  their bounding box (what it scanned before). No time is asserted.
- `terrad simulate --help` and the --model refusal name every model (sumner
  was missing), and a scene's material.model refusal does too.
"""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, simulate  # noqa: E402

MODELS = ["persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
          "diffusion", "sumner", "decals"]
check = Checks()


def scene_file(scene):
    fd, path = tempfile.mkstemp(prefix="terrad-scope-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(scene, f)
    return path


big = scene_file({
    "name": "far-apart", "world": {"width": 65536, "height": 65536, "cell_size_m": 0.05},
    "terrain": {"kind": "flat", "height_m": 0.4},
    "colliders": [
        {"name": "a", "shape": "sphere", "radius": 0.3, "position": [2, 2, 0.62],
         "motion": {"velocity": [0.5, 0, 0]}},
        {"name": "b", "shape": "sphere", "radius": 0.3, "position": [3274, 3274, 0.62],
         "motion": {"velocity": [-0.5, 0, 0]}}]})
rc, r, err = simulate(big, 3)
check(rc == 0, f"65,536^2 world with two far-apart colliders: simulate ran: {err[-300:]}")
if r:
    check(r["max_slope_excess_scope"] == "stored_tiles", f"scope {r['max_slope_excess_scope']}")
    tiles = r["world_stored_tiles"]
    cells = r["max_slope_excess_cells"]
    check(tiles >= 2, f"{tiles} tiles stored (one per corner at least)")
    # each stored tile at most 256^2 cells plus its ring; the corners' box is 2.7e9 cells
    check(0 < cells <= tiles * 258 * 258,
          f"scanned {cells} cells for {tiles} stored tiles (their bounding box: 2.7e9)")
    check(r["volume_before"] == r["volume_after"], "sum(h) exact")
os.unlink(big)

p = subprocess.run([BIN, "simulate", "--help"], capture_output=True, text=True, timeout=60)
for m in MODELS:
    check(m in p.stdout + p.stderr, f"--help names {m}")
small = scene_file({"world": {"width": 16, "height": 16, "cell_size_m": 0.05}})
rc, r, err = simulate(small, 1, "--model", "nonesuch")
for m in MODELS:
    check(rc != 0 and m in err, f"--model refusal names {m}: {err.strip()[-200:]}")
os.unlink(small)
bad = scene_file({"world": {"width": 16, "height": 16, "cell_size_m": 0.05},
                  "material": {"model": "nonesuch"}})
rc, r, err = simulate(bad, 1)
for m in MODELS:
    check(rc != 0 and "material.model" in err and m in err, f"material.model refusal names {m}")
os.unlink(bad)
check.finish()
