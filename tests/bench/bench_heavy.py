#!/usr/bin/python3
"""Issue 24's heavy scenes on the CPU twin: deep, wide, fast and steep work
(tests/scenes/heavy/*.json: a vehicle-body box pressed 1 m into 5 m of snow at
12 m/s, a blade and two tracks ploughing steep dunes on 2048^2, 48 feet deep in
snow, a 4096^2 steep world with six deep colliders). A benchmark, not a test:
it prints figures beside anchors and never fails on them.

For each scene: simulate's mean ms per tick by stage and in nanoseconds per
active cell, beside the memory-bandwidth roof (build/bench_stream, a STREAM
copy: what one int32 read + write costs), and the CPU time per tick.

Side by side with an older build (issue 24 item 3, e.g. the 2026-11-23 build
cfe670f in its own worktree): --old PATH/terrad or TERRAD_OLD_BIN runs both
binaries alternately on the same scenes, --rounds times each, and prints the
ratio of their median wall-clock ticks (this build at --threads, 2 by default;
a build without --threads runs as it is, on one thread).

Usage: bench_heavy.py [--ticks N] [--threads T] [--rounds R] [--old BIN]
                      [--scenes deep-box,feet-deep,...]
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import machine  # noqa: E402

SOURCE = os.environ.get("TERRAD_SOURCE_DIR", ".")
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))
HEAVY = os.path.join(SOURCE, "tests", "scenes", "heavy")
STAGES = ["depth", "classify", "jump_flood", "displace", "even_slopes", "gather_scatter", "tick"]
DEEP_BOX_ANCHOR_MS = 1.0  # issue 24: the deep box at <= 1 ms per tick
RATIO_ANCHOR = 5.0  # issue 24: every heavy scene >= 5x the 2026-11-23 build


def takes_threads(binary):
    """Does this build's simulate know --threads (cfe670f's does not)?"""
    p = subprocess.run([binary, "--help"], capture_output=True, text=True)
    return "--threads" in p.stdout + p.stderr


def run(binary, scene, ticks, threads):
    """simulate's JSON report with "_cpu_s" (the child's user + system seconds), or None."""
    extra = ["--threads", str(threads)] if threads else []
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([binary, "simulate", "--scene", scene, "--ticks", str(ticks),
                        "--backend", "cpu"] + extra, capture_output=True, text=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        print(f"# {binary} {os.path.basename(scene)}: failed: {p.stderr.strip()[-300:]}")
        return None
    rep = json.loads(p.stdout)
    rep["_cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return rep


def stream_roof():
    exe = os.path.join(os.path.dirname(BIN), "bench_stream")
    try:
        p = subprocess.run([exe], capture_output=True, text=True, timeout=120)
        return json.loads(p.stdout.strip().splitlines()[-1])
    except (OSError, ValueError, IndexError, subprocess.TimeoutExpired):
        return None


def print_stages(name, reps, roof):
    """Median ms and ns per active cell of each stage over the rounds."""
    active = statistics.median(r["active_cells_mean"] for r in reps)
    print(f"{name}: {int(active)} active cells per tick (mean), {len(reps)} run(s)")
    for stage in STAGES:
        ms = statistics.median(r["stages"][stage]["mean_ms"] for r in reps)
        ns = ms * 1e6 / active if active > 0 else float("nan")
        line = f"  {stage:15} {ms:8.3f} ms  {ns:8.1f} ns per active cell"
        if roof:
            line += f"  ({ns / roof['ns_per_int32_read_write']:6.0f} x the int32 read+write roof)"
        print(line)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=120)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--old", default=os.environ.get("TERRAD_OLD_BIN"))
    ap.add_argument("--scenes", default="")
    args = ap.parse_args()
    names = sorted(f[:-5] for f in os.listdir(HEAVY) if f.endswith(".json"))
    if args.scenes:
        names = [n for n in names if n in args.scenes.split(",")]
    print(f"# issue 24 heavy scenes, CPU twin — machine: {machine()}, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"# {args.ticks} ticks per run, this build at --threads {args.threads}; wall: "
          f"simulate's mean tick; CPU: user + system per tick of all threads (a 0-tick run "
          f"subtracted); medians over {args.rounds} round(s)")
    roof = stream_roof()
    if roof:
        print(f"memory roof (STREAM copy, one thread): {roof['gb_per_s']:.2f} GB/s = "
              f"{roof['ns_per_int32_read_write']:.3f} ns to read and write one int32")
    builds = [("this build", BIN, args.threads)]
    if args.old:
        builds.append(("old build", args.old, args.threads if takes_threads(args.old) else None))
    for name in names:
        scene = os.path.join(HEAVY, name + ".json")
        reps = {b[0]: [] for b in builds}
        for _ in range(args.rounds):
            for label, binary, threads in builds:  # alternately, in the same minutes
                rep = run(binary, scene, args.ticks, threads)
                if rep:
                    reps[label].append(rep)
        tick = {}
        for label, binary, threads in builds:
            if not reps[label]:
                continue
            print_stages(f"{name} [{label}]", reps[label], roof)
            zero = run(binary, scene, 0, threads)
            tick[label] = statistics.median(r["stages"]["tick"]["mean_ms"] for r in reps[label])
            if zero:
                cpu = statistics.median((r["_cpu_s"] - zero["_cpu_s"]) * 1000.0 / args.ticks
                                        for r in reps[label])
                print(f"  CPU per tick   {cpu:8.3f} ms (all threads)")
        if name == "deep-box" and "this build" in tick:
            v = tick["this build"]
            print(f"deep-box: {v:.3f} ms per tick wall (anchor <= {DEEP_BOX_ANCHOR_MS} ms: "
                  f"{'met' if v <= DEEP_BOX_ANCHOR_MS else 'NOT met'})")
        if len(tick) == 2:
            x = tick["old build"] / tick["this build"]
            print(f"{name}: old {tick['old build']:.3f} ms / this {tick['this build']:.3f} ms = "
                  f"{x:.2f}x (anchor >= {RATIO_ANCHOR}x: {'met' if x >= RATIO_ANCHOR else 'NOT met'}"
                  f"; load average {os.getloadavg()[0]:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
