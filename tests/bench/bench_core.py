#!/usr/bin/python3
"""Per-stage milliseconds of the deformation core for the thesis's
configurations, side by side with Persson's Tables 5.4 (iterative) and 5.5
(SSBO), on both backends. A benchmark, not a test: it prints figures.

The scene mirrors the thesis's section 5.3: a 200 m terrain at heightmap
sizes 512 to 4096, a car driving over snow, one active area around the car
sized like the thesis's (3,774 / 15,100 / 60,398 / 241,591 pixels), and
Table 5.3's parameters (10 displacement and 10 slope iterations).

Then issue 10's anchors for the CPU twin (printed beside them, never
failed on): the Table 5.5 configuration at 1024^2 <= 2.0 ms per tick and at
4096^2 <= 25 ms, tests/scenes/thesis-car.json <= 0.35 ms per tick,
nanoseconds per active cell per tick for each stage beside this machine's
memory bandwidth (build/bench_stream, a STREAM copy), and thread scaling on
a 64-wheel scene (2 threads >= 1.7x one thread).

Usage: bench_core.py [--ticks N] [--sizes 512,1024,...] [--backends gl,cpu]
"""
import argparse
import json
import os
import platform
import resource
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


def wheels_scene(count=64):
    """count wheels in a square grid on a 1024^2 world of 5 cm cells, each
    rolling east in its own active window: the windows of one tick."""
    side = int(count ** 0.5 + 0.999)
    wheel_r, sink = 0.33, 0.08
    wheels = []
    for k in range(count):
        gx, gy = k % side, k // side
        wheels.append({
            "shape": "cylinder", "radius": wheel_r, "half_length": 0.1,
            "position": [3.0 + gx * 45.0 / side, 3.0 + gy * 45.0 / side, 0.4 - sink + wheel_r],
            "motion": {"velocity": [0.5, 0.0, 0.0], "spin_axis": [0.0, 1.0, 0.0],
                       "spin_deg_per_s": 0.5 / wheel_r * 57.29577951308232},
        })
    return {
        "name": f"bench-wheels-{count}",
        "world": {"width": 1024, "height": 1024, "cell_size_m": 0.05, "units_per_m": 10000,
                  "floor_m": 0.0},
        "terrain": {"kind": "flat", "height_m": 0.4},
        "material": {"compression": 0, "roughness": 0.3, "repose_deg": 35,
                     "displace_iterations": 10, "slope_iterations": 10, "method": "ssbo"},
        "tick_hz": 60,
        "colliders": wheels,
    }


def stream_bandwidth():
    """GB/s of a STREAM copy (build/bench_stream), or None."""
    exe = os.path.join(os.path.dirname(BIN), "bench_stream")
    try:
        p = subprocess.run([exe], capture_output=True, text=True, timeout=120)
        return json.loads(p.stdout.strip().splitlines()[-1])
    except (OSError, ValueError, IndexError, subprocess.TimeoutExpired):
        return None


def anchors(results, ticks):
    """Issue 10's CPU-twin figures beside their anchors."""
    print()
    print("## issue 10 anchors, CPU twin (figures beside anchors; never a failure)")
    print(f"# load average now: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("# wall: simulate's mean tick; CPU: the process's user + system time per tick (all "
          "threads; a 0-tick run's start-up subtracted), which the load of other jobs changes least")
    with tempfile.TemporaryDirectory() as tmp:
        for size, anchor in ((1024, 2.0), (4096, 25.0)):
            rep = results.get(("cpu", "ssbo", size))
            if rep:
                path = os.path.join(tmp, f"car-{size}.json")
                with open(path, "w") as f:
                    json.dump(car_scene(size), f)
                v = rep["stages"]["tick"]["mean_ms"]
                cpu = cpu_ms_per_tick(path, rep, ticks)
                print(f"Table 5.5 config {size}^2, SSBO 10+10: {v:.3f} ms per tick wall, "
                      f"{cpu:.3f} ms CPU (anchor <= {anchor} ms: "
                      f"{'met' if v <= anchor else 'NOT met'})")
    car = os.path.join(SOURCE, "tests", "scenes", "thesis-car.json")
    rep, err = run(car, max(ticks, 300), "cpu", "ssbo")
    if rep:
        v = rep["stages"]["tick"]["mean_ms"]
        cpu = cpu_ms_per_tick(car, rep, max(ticks, 300))
        print(f"tests/scenes/thesis-car.json: {v:.3f} ms per tick wall, {cpu:.3f} ms CPU "
              f"(anchor <= 0.35 ms, Chrono SCM: {'met' if v <= 0.35 else 'NOT met'})")
    else:
        print(f"thesis-car: not run: {err}")
    bw = stream_bandwidth()
    if bw:
        print(f"memory bandwidth (STREAM copy, one thread): {bw['gb_per_s']:.2f} GB/s = "
              f"{bw['ns_per_int32_read_write']:.3f} ns to read and write one int32")
    print(f"{'ns per active cell per tick':34}" + "".join(
        f" | {size:>7}" for size in (1024, 4096)))
    for stage in ("depth", "classify", "jump_flood", "displace", "even_slopes", "tick"):
        line = f"{STAGE_NAMES[stage]:34}"
        for size in (1024, 4096):
            rep = results.get(("cpu", "ssbo", size))
            if rep and rep["active_cells_mean"] > 0:
                ns = rep["stages"][stage]["mean_ms"] * 1e6 / rep["active_cells_mean"]
                line += f" | {ns:7.1f}"
            else:
                line += f" | {'-':>7}"
        print(line)
    if bw:
        print(f"{'(memory: one int32 read + write)':34} | "
              f"{bw['ns_per_int32_read_write']:7.3f} | {bw['ns_per_int32_read_write']:7.3f}")
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "wheels-64.json")
        with open(path, "w") as f:
            json.dump(wheels_scene(64), f)
        ms = {}
        n = max(ticks, 120)
        for threads in (1, 2):
            rep, err = run(path, n, "cpu", "ssbo", threads=threads)
            ms[threads] = rep["stages"]["tick"]["mean_ms"] if rep else None
            if rep:
                # CPU time of the process (all threads) per tick: the 0-tick run's start-up
                # and end-of-run scan subtracted
                cpu = cpu_ms_per_tick(path, rep, n, threads)
                print(f"64 wheels, {threads} thread(s): {ms[threads]:.3f} ms per tick wall, "
                      f"{cpu:.3f} ms CPU (all threads), {int(rep['active_cells_mean'])} active "
                      f"cells, load average {os.getloadavg()[0]:.1f}")
        if ms.get(1) and ms.get(2):
            x = ms[1] / ms[2]
            print(f"thread scaling 2 vs 1 on 64 wheels: {x:.2f}x "
                  f"(anchor >= 1.7x: {'met' if x >= 1.7 else 'NOT met'}; wall clock: on "
                  f"{os.cpu_count()} cores shared with other jobs the second thread runs only "
                  f"when a core is free)")


def cpu_ms_per_tick(path, rep, ticks, threads=None):
    """CPU ms per tick of a CPU-backend SSBO run: its CPU time less a 0-tick run's."""
    _, _, cpu0 = run(path, 0, "cpu", "ssbo", threads=threads, cpu=True)
    return (rep["_cpu_s"] - cpu0) * 1000.0 / ticks


def run(scene_path, ticks, backend, method, threads=None, cpu=False):
    """simulate's JSON report (with "_cpu_s": the child's user + system CPU seconds), or
    None and the error; with cpu=True also the CPU seconds as a third value."""
    extra = ["--threads", str(threads)] if threads else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([BIN, "simulate", "--scene", scene_path, "--ticks", str(ticks),
                        "--backend", backend, "--method", method] + extra,
                       capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if p.returncode != 0:
        err = p.stderr.strip().splitlines()[-1] if p.stderr.strip() else "failed"
        return (None, err, cpu_s) if cpu else (None, err)
    rep = json.loads(p.stdout)
    rep["_cpu_s"] = cpu_s
    return (rep, None, cpu_s) if cpu else (rep, None)


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
    if "cpu" in args.backends.split(","):
        anchors(results, args.ticks)
    return 0


if __name__ == "__main__":
    sys.exit(main())
