#!/usr/bin/python3
"""Per-stage milliseconds of the deformation core for the thesis's
configurations, side by side with Persson's Tables 5.4 (iterative) and 5.5
(SSBO), on both backends. A benchmark, not a test: it prints figures.

The scene mirrors the thesis's section 5.3: a 200 m terrain at heightmap
sizes 512 to 4096, a car driving over snow, one active area around the car
sized like the thesis's (3,774 / 15,100 / 60,398 / 241,591 pixels), and
Table 5.3's parameters (10 displacement and 10 slope iterations).

Usage: bench_core.py [--ticks N] [--sizes 512,1024,...] [--backends gl,cpu]
"""
import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import machine  # noqa: E402

SOURCE = os.environ.get("TERRAD_SOURCE_DIR", ".")
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))

# Thesis Tables 5.4 and 5.5 (GTX 660), ms, by heightmap size.
THESIS = {
    "iterative": {
        "depth": [0.203, 0.202, 0.201, 0.373],
        "classify": [0.116, 0.112, 0.118, 0.671],
        "jump_flood": [0.403, 0.529, 0.909, 10.692],
        "displace": [0.513, 0.579, 0.847, 11.864],
        "even_slopes": [0.826, 0.988, 1.531, 14.480],
    },
    "ssbo": {
        "depth": [0.204, 0.207, 0.201, 0.210],
        "classify": [0.111, 0.116, 0.120, 0.670],
        "jump_flood": [0.408, 0.549, 0.905, 9.045],
        "displace": [0.107, 0.127, 0.177, 1.659],
        "even_slopes": [0.544, 0.773, 1.617, 5.486],
    },
}
THESIS_SIZES = [512, 1024, 2048, 4096]
THESIS_ACTIVE = [3774, 15100, 60398, 241591]
STAGE_NAMES = {
    "depth": "Render depth texture",
    "classify": "Create penetration texture",
    "jump_flood": "Jump flooding",
    "displace": "Displace material",
    "even_slopes": "Even out steep slopes",
    "transfer": "(terrad) upload + read back",
    "gather_scatter": "(terrad) plan, gather, scatter",
    "tick": "(terrad) whole tick",
}


def car_scene(size):
    cell = 200.0 / size
    wheel_r, sink = 0.33, 0.08
    z = 0.4 - sink + wheel_r
    speed = 5.0
    wheels = []
    for dx in (0.0, 2.6):
        for dy in (-0.75, 0.75):
            wheels.append({
                "shape": "cylinder", "radius": wheel_r, "half_length": 0.1,
                "position": [60.0 + dx, 100.0 + dy, z],
                "motion": {"velocity": [speed, 0.0, 0.0], "spin_axis": [0.0, 1.0, 0.0],
                           "spin_deg_per_s": speed / wheel_r * 57.29577951308232},
            })
    # margin so the merged window matches the thesis's active area (~24 m square)
    margin = max(1, round(10.3 / cell))
    return {
        "name": f"bench-car-{size}",
        "world": {"width": size, "height": size, "cell_size_m": cell, "units_per_m": 10000,
                  "floor_m": 0.0},
        "terrain": {"kind": "flat", "height_m": 0.4},
        "material": {"compression": 0, "roughness": 0.3, "repose_deg": 35,
                     "displace_iterations": 10, "slope_iterations": 10},
        "tick_hz": 60,
        "active_margin_cells": margin,
        "colliders": wheels,
    }


def run(scene_path, ticks, backend, method):
    p = subprocess.run([BIN, "simulate", "--scene", scene_path, "--ticks", str(ticks),
                        "--backend", backend, "--method", method],
                       capture_output=True, text=True)
    if p.returncode != 0:
        return None, p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "failed"
    return json.loads(p.stdout), None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=120)
    ap.add_argument("--sizes", default="512,1024,2048,4096")
    ap.add_argument("--backends", default="gl,cpu")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")]
    print(f"# terrad core benchmark — machine: {machine()}, {platform.system()} {platform.release()}")
    print(f"# {args.ticks} ticks per run; thesis figures: GTX 660 (Persson 2019, Tables 5.4/5.5)")
    results = {}
    renderers = {}
    with tempfile.TemporaryDirectory() as tmp:
        for size in sizes:
            path = os.path.join(tmp, f"car-{size}.json")
            with open(path, "w") as f:
                json.dump(car_scene(size), f)
            for backend in args.backends.split(","):
                for method in ("iterative", "ssbo"):
                    rep, err = run(path, args.ticks, backend, method)
                    if rep is None:
                        print(f"# {backend} {method} {size}: not run: {err}")
                        continue
                    renderers[backend] = rep["renderer"]
                    results[(backend, method, size)] = rep
                    if rep["volume_before"] != rep["volume_after"]:
                        print(f"# WARNING: volume changed in {backend} {method} {size}")
    for backend, renderer in renderers.items():
        print(f"# backend {backend}: {renderer}")
    for method in ("iterative", "ssbo"):
        table = "5.4" if method == "iterative" else "5.5"
        print()
        print(f"## {method} — mean ms per tick (thesis Table {table} in brackets)")
        header = f"{'step':34}"
        for size in sizes:
            header += f" | {size:>6} thesis"
            for backend in renderers:
                header += f" {backend:>7}"
        print(header)
        for stage in STAGE_NAMES:
            line = f"{STAGE_NAMES[stage]:34}"
            for size in sizes:
                idx = THESIS_SIZES.index(size) if size in THESIS_SIZES else -1
                ref = THESIS[method].get(stage)
                line += f" | {('%.3f' % ref[idx]) if ref and idx >= 0 else '-':>13}"
                for backend in renderers:
                    rep = results.get((backend, method, size))
                    v = rep["stages"][stage]["mean_ms"] if rep else None
                    line += f" {('%.3f' % v) if v is not None else '-':>7}"
            print(line)
        line = f"{'active cells (thesis: pixels)':34}"
        for size in sizes:
            idx = THESIS_SIZES.index(size) if size in THESIS_SIZES else -1
            line += f" | {THESIS_ACTIVE[idx] if idx >= 0 else '-':>13}"
            for backend in renderers:
                rep = results.get((backend, method, size))
                line += f" {int(rep['active_cells_mean']) if rep else '-':>7}"
        print(line)
        line = f"{'bytes per world cell (thesis 78/126)':34}"
        for size in sizes:
            line += f" | {78 if method == 'ssbo' else 126:>13}"
            for backend in renderers:
                rep = results.get((backend, method, size))
                line += f" {rep['bytes_per_world_cell'] if rep else '-':>7}"
        print(line)
        line = f"{'bytes per active cell':34}"
        for size in sizes:
            line += f" | {'-':>13}"
            for backend in renderers:
                rep = results.get((backend, method, size))
                line += f" {rep['bytes_per_active_cell'] if rep else '-':>7}"
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
