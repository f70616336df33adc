#!/usr/bin/python3
"""Tick time and memory against the size of the world (issue 6, tiling).

The same colliders — the thesis car (four wheels 8 cm deep, driving east at
1.5 m/s) and three spheres pressed into flat 0.4 m snow — at the same places
in worlds of 1,024², 16,384² and 65,536² cells of 5 cm, on both backends.
With the sparse tiled world the tick time should stay nearly flat and the
resident memory follow the tiles the colliders touched, not the world (a
dense 65,536² world would be 16 GiB of heights). A benchmark, not a test: it
prints a table.

Usage: bench_scale.py [--ticks N] [--sizes 1024,16384,65536] [--backends cpu,gl]
                      [--tile-cells 256]
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


def scene(size, tile_cells):
    wheel_r, sink, speed = 0.33, 0.08, 1.5
    z = 0.4 - sink + wheel_r
    colliders = []
    # the car starts astride the corner of tiles at (12.8 m, 12.8 m) for 256-cell tiles
    for dx in (0.0, 2.6):
        for dy in (-0.75, 0.75):
            colliders.append({
                "shape": "cylinder", "radius": wheel_r, "half_length": 0.1,
                "position": [11.5 + dx, 12.8 + dy, z],
                "motion": {"velocity": [speed, 0.0, 0.0], "spin_axis": [0.0, 1.0, 0.0],
                           "spin_deg_per_s": speed / wheel_r * 57.29577951308232},
            })
    for i, (x, y) in enumerate(((20.0, 30.0), (35.0, 8.0), (44.0, 44.0))):
        colliders.append({"shape": "sphere", "radius": 0.4 + 0.1 * i,
                          "position": [x, y, 0.4 + 0.4 + 0.1 * i - 0.1],
                          "motion": {"velocity": [0.0, 0.8, 0.0]}})
    return {
        "name": f"scale-{size}",
        "world": {"width": size, "height": size, "cell_size_m": 0.05, "tile_cells": tile_cells},
        "terrain": {"kind": "flat", "height_m": 0.4},
        "material": {"roughness": 0.3, "repose_deg": 35},
        "colliders": colliders,
    }


def run(path, ticks, backend):
    p = subprocess.run([BIN, "simulate", "--scene", path, "--ticks", str(ticks),
                        "--backend", backend], capture_output=True, text=True)
    if p.returncode != 0:
        lines = p.stderr.strip().splitlines()
        return None, lines[-1] if lines else "failed"
    return json.loads(p.stdout), None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=300)
    ap.add_argument("--sizes", default="1024,16384,65536")
    ap.add_argument("--backends", default="cpu,gl")
    ap.add_argument("--tile-cells", type=int, default=256)
    args = ap.parse_args()
    print(f"# terrad scale benchmark — machine: {machine()}, {platform.system()} "
          f"{platform.release()}")
    print(f"# {args.ticks} ticks per run, 4 wheels + 3 spheres, flat base, tiles of "
          f"{args.tile_cells}² cells; memory in MiB")
    header = (f"{'world':>13} {'backend':>7} {'tick ms':>8} {'p99 ms':>7} {'peak RSS':>9} "
              f"{'world MiB':>9} {'tiles':>6} {'GPU cache':>9} {'GPU tiles':>9} {'uploads':>7} "
              f"{'cached/direct':>13} {'dense would be':>14}")
    print(header)
    print("-" * len(header))
    bad = 0
    with tempfile.TemporaryDirectory() as tmp:
        for size in [int(s) for s in args.sizes.split(",")]:
            path = os.path.join(tmp, f"scale-{size}.json")
            with open(path, "w") as f:
                json.dump(scene(size, args.tile_cells), f)
            for backend in args.backends.split(","):
                rep, err = run(path, args.ticks, backend)
                if rep is None:
                    print(f"{size:>6}x{size:<6} {backend:>7} not run: {err}")
                    continue
                if rep["volume_before"] != rep["volume_after"]:
                    bad += 1
                    print(f"# VOLUME CHANGED: {rep['volume_before']} -> {rep['volume_after']}")
                mib = 1 << 20
                gpu = rep.get("gpu_tile_cache_bytes", 0)
                gpu_text = f"{gpu / mib:.1f}" if gpu else "-"
                windows = f"{rep.get('gpu_windows_cached', 0)}/{rep.get('gpu_windows_direct', 0)}"
                print(f"{size:>6}x{size:<6} {backend:>7} {rep['stages']['tick']['mean_ms']:>8.2f} "
                      f"{rep['stages']['tick']['p99_ms']:>7.2f} "
                      f"{rep['peak_rss_bytes'] / mib:>9.1f} "
                      f"{rep['world_resident_bytes'] / mib:>9.2f} "
                      f"{rep['world_stored_tiles']:>6} {gpu_text:>9} "
                      f"{rep.get('gpu_tiles_resident', 0):>9} {rep.get('gpu_tile_uploads', 0):>7} "
                      f"{windows if backend == 'gl' else '-':>13} "
                      f"{size * size * 4 / mib:>10.0f} MiB")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
