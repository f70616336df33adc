#!/usr/bin/python3
"""What client-side prediction (docs/engines.md, "Prediction") costs a client per tick, for
`make bench`: the twin library natively (libterrad-twin through terrad.twin, ctypes) and as
WebAssembly under Node (web/twin.mjs; tests/bench/bench_predict_wasm.mjs). A sphere of 0.3 m
rolls through flat snow of the default material in a window of the world, one pose per
tick. Printed per window size, mean ms:

- predict: one own batch ticked at once (set_pose, tick, read the window) — what send_poses
  adds, the cost a player pays each tick;
- reconcile: one ACK with one tick of replay and two batches pending (write the server's
  heights, place, tick, read, write again, place, two ticks, each read) — what an ACK adds.

Anchor: predict within one frame's budget at 60 frames/s (16.7 ms) for a 128 x 128 window.
Never fails on a figure. TERRAD_BENCH_TICKS (default 300).
"""
import json
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import BIN, SOURCE, machine  # noqa: E402

import terrad  # noqa: E402

TICKS = int(os.environ.get("TERRAD_BENCH_TICKS", "300"))
WINDOWS = [(64, 64), (128, 128), (256, 256)]
CONFIG = {"width": 1024, "height": 1024, "terrain.height_m": 0.4}
ANCHOR_MS = 1000 / 60
LIB = os.path.join(os.path.dirname(BIN), "libterrad-twin.so")
WASM = os.path.join(os.path.dirname(BIN), "terrad_twin.wasm")


def native(w, h):
    x0, y0 = 100, 100
    twin = terrad.Twin(CONFIG, x0, y0, w, h, library=LIB if os.path.exists(LIB) else None)
    twin.add_collider(1, "sphere", radius=0.3)
    cell, ys = 0.05, (y0 + h / 2) * 0.05

    def pose(i):
        return ((x0 + 8 + (w - 16) * (i % TICKS) / TICKS) * cell, ys, 0.64)

    t = time.perf_counter()
    for i in range(TICKS):
        twin.set_pose(1, pose(i))
        twin.tick()
        server = twin.read()
    predict = (time.perf_counter() - t) / TICKS * 1e3
    t = time.perf_counter()
    for i in range(TICKS):
        twin.write(server)
        twin.place(1, pose(i))
        twin.set_pose(1, pose(i + 1))
        twin.tick()
        twin.read()
        twin.write(server)
        twin.place(1, pose(i + 1))
        for k in (2, 3):
            twin.set_pose(1, pose(i + k))
            twin.tick()
            twin.read()
    reconcile = (time.perf_counter() - t) / TICKS * 1e3
    twin.close()
    return predict, reconcile


def wasm(w, h):
    if not (shutil.which("node") and os.path.exists(WASM)):
        return None
    p = subprocess.run(["node", os.path.join(HERE, "bench_predict_wasm.mjs"), WASM, str(w), str(h),
                        str(TICKS)], capture_output=True, text=True, timeout=600, cwd=SOURCE)
    if p.returncode != 0:
        print(f"  wasm: failed: {p.stderr[-500:]}")
        return None
    r = json.loads(p.stdout)
    return r["predict"], r["reconcile"]


def main():
    print(f"prediction cost per tick, {TICKS} ticks of a 0.3 m sphere in flat snow; {machine()}")
    print(f"{'window':>10} {'native predict':>15} {'reconcile':>10} {'wasm predict':>13} {'reconcile':>10}")
    for w, h in WINDOWS:
        n = native(w, h)
        m = wasm(w, h)
        ws = f"{m[0]:13.3f} {m[1]:10.3f}" if m else f"{'-':>13} {'-':>10}"
        print(f"{w:>4} x {h:<4} {n[0]:15.3f} {n[1]:10.3f} {ws}   ms")
        if (w, h) == (128, 128):
            worst = max(n[0], m[0] if m else 0)
            print(f"  anchor: predict <= {ANCHOR_MS:.1f} ms (one frame at 60/s) for 128 x 128: "
                  f"{'met' if worst <= ANCHOR_MS else 'NOT met'} ({worst:.3f} ms)")


main()
