#!/usr/bin/python3
"""bench_mujoco_rover: the MuJoCo rover on terrad's soil (clients/c/examples/mujoco_rover.c,
docs/simulators.md). A real daemon per run on the example's ramp scene (a client-clocked world;
the harness's daemon, durability "none", as a co-simulation without a data directory runs).

1. speed: the example driving up the ramp on sandy loam at 500 Hz, RUNS runs: each step one
   mj_step1/mj_step2 pair, one STEP of one tick (four wheels) and its round trip over loopback.
   Printed: steps, wall time, steps per second and the multiple of real time (anchor: 1x, real
   time), with the machine and its load;
2. the stability of explicit coupling (docs/simulators.md's table; 15 runs, under a minute):
   4 simulated seconds on sandy-loam, snow-us
   (slip_n 0.4) and lete-sand at 60, 120, 250, 500 and 1000 Hz, each run's distance moved,
   sinkage and Fz chatter (the RMS change of a wheel's Fz from one step to the next). These are
   simulated figures, the same on every machine: past the bound the chatter is hundreds of
   newtons and the rover is bounced back; within it the figures agree across rates.

Nothing here fails on a figure; skipped (exit 0, a note) where build/mujoco_rover was not built
(no MuJoCo).
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
VERDICT = re.compile(r"^\w+: moved (-?[0-9.]+) m .* sinkage (-?[0-9.]+) mm .* Fz chatter "
                     r"([0-9.]+) N")


def run(tmp, soil, slip_n, hz, *extra):
    """The example on a fresh daemon: its stdout lines."""
    out = os.path.join(tmp, f"{soil}-{hz}")
    os.makedirs(out, exist_ok=True)
    scene = subprocess.run([ROVER, "--write-scene", soil, out, "--slip-n", str(slip_n), "--hz",
                            str(hz)], capture_output=True, text=True, check=True).stdout.strip()
    d = Daemon(extra=["--scene", scene], name="terrad-rover-bench")
    try:
        p = subprocess.run([ROVER, "--port", str(d.ws_port), "--model", MODEL, *extra],
                           capture_output=True, text=True, timeout=600)
    finally:
        d.stop()
    if p.returncode != 0:
        print(f"  {soil} at {hz} Hz: the example failed ({p.returncode}: {p.stderr.strip()})")
    return p.stdout.splitlines()


if not os.path.exists(ROVER):
    print(f"bench_mujoco_rover: skipped: {ROVER} not built (it needs MuJoCo: libmujoco-dev)")
    sys.exit(0)
with tempfile.TemporaryDirectory(prefix="terrad-rover-bench-") as tmp:
    print(f"mujoco_rover on sandy loam at 500 Hz ({machine()}, load {os.getloadavg()[0]:.1f})")
    for k in range(RUNS):
        lines = run(tmp, "sandy-loam", 0, 500)
        m = next((SPEED.match(line) for line in lines if SPEED.match(line)), None)
        if m:
            steps, wall = int(m.group(1)), float(m.group(2))
            print(f"  run {k + 1}: {steps} steps in {wall:.2f} s: {steps / wall:,.0f} steps/s, "
                  f"{steps * 0.002 / wall:.1f}x real time (anchor: 1x)")
    print("stability of explicit coupling, 4 simulated seconds from the start on the ramp "
          "(moved m / sinkage mm / Fz chatter N):")
    rates = (60, 120, 250, 500, 1000)
    print("  soil        " + "".join(f"{hz:>24} Hz" for hz in rates))
    for soil, slip_n in (("sandy-loam", 0), ("snow-us", 0.4), ("lete-sand", 0)):
        cells = []
        for hz in rates:
            m = next((VERDICT.match(line) for line in run(tmp, soil, slip_n, hz, "--seconds", "4")
                      if VERDICT.match(line)), None)
            cells.append(f"{float(m.group(1)):+.3f} / {float(m.group(2)):5.1f} / "
                         f"{float(m.group(3)):6.1f}" if m else "failed")
        print(f"  {soil:<12}" + "".join(f"{c:>27}" for c in cells))
