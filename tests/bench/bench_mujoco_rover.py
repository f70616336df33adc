#!/usr/bin/python3
"""bench_mujoco_rover: the MuJoCo rover on terrad's soil (clients/c/examples/mujoco_rover.c,
docs/simulators.md), lockstep steps per second. A real daemon on the example's ramp scene (a
client-clocked world at 500 Hz, sandy loam; the harness's daemon, durability "none", as a
co-simulation without a data directory runs), the example driving it up the ramp: each step one
mj_step1/mj_step2 pair, one STEP of one tick (four wheels) and its round trip over loopback.
Printed: steps, wall time, steps per second and the multiple of real time (anchor: 1x, real
time; the issue's goal for the lockstep alone is 3,000 steps/s, docs/simulators.md), RUNS runs,
with the machine and its load. Nothing here fails on a figure; skipped (exit 0, a note) where
build/mujoco_rover was not built (no MuJoCo).
"""
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import BIN, SOURCE, Daemon, machine  # noqa: E402

ROVER = os.path.join(os.path.dirname(BIN), "mujoco_rover")
MODEL = os.path.join(SOURCE, "clients", "c", "examples", "mujoco_rover.xml")
RUNS = int(os.environ.get("TERRAD_BENCH_ROVER_RUNS", "3"))
SPEED = re.compile(r"^speed: (\d+) steps in ([0-9.]+) s of wall time")

if not os.path.exists(ROVER):
    print(f"bench_mujoco_rover: skipped: {ROVER} not built (it needs MuJoCo: libmujoco-dev)")
    sys.exit(0)
with tempfile.TemporaryDirectory(prefix="terrad-rover-bench-") as tmp:
    scene = subprocess.run([ROVER, "--write-scene", "sandy-loam", tmp, "--hz", "500"],
                           capture_output=True, text=True, check=True).stdout.strip()
    print(f"mujoco_rover on sandy loam at 500 Hz ({machine()}, load {os.getloadavg()[0]:.1f})")
    for run in range(RUNS):
        d = Daemon(extra=["--scene", scene], name="terrad-rover-bench")
        try:
            p = subprocess.run([ROVER, "--port", str(d.ws_port), "--model", MODEL],
                               capture_output=True, text=True, timeout=600)
        finally:
            d.stop()
        m = next((SPEED.match(line) for line in p.stdout.splitlines() if SPEED.match(line)), None)
        if not m:
            print(f"  run {run + 1}: no speed line ({p.returncode}: {p.stderr.strip()})")
            continue
        steps, wall = int(m.group(1)), float(m.group(2))
        print(f"  run {run + 1}: {steps} steps in {wall:.2f} s: {steps / wall:,.0f} steps/s, "
              f"{steps * 0.002 / wall:.1f}x real time (anchor: 1x)")
