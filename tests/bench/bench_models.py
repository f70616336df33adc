#!/usr/bin/python3
"""Every deformation model (docs/models.md) on the same scripted colliders:
mean and p99 tick, the model's own stage, the volume drift it documents, and
the scratch memory it holds, in all and by stage. A benchmark, not a test:
it prints figures (CPU backend; the non-persson models have no GL version).

Usage: bench_models.py [--ticks N] [--scenes thesis-car,box45]
"""
import argparse
import json
import os
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import machine  # noqa: E402

SOURCE = os.environ.get("TERRAD_SOURCE_DIR", ".")
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))
MODELS = ["persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
          "diffusion", "decals", "sumner", "bekker"]
# Chrono SCM's published CPU figures (its benchmark notes, i7-13700K, 4 threads) and the ones
# measured on this machine (../shared/notes/terramechanics.md), ms per step: the anchors the
# bekker model's cost is printed beside.
SCM_ANCHORS = ("Chrono SCM anchors, ms/step: HMMWV 0.351 (i7-13700K, 4 threads); one wheel on "
               "0.02 m 2.12, on 0.01 m 8.61 (same); this machine, 1 thread: thesis-car carve "
               "0.68, with bulldozing 1.58; the Ding wheel 6.6-7.6")
STAGES = ["depth", "classify", "jump_flood", "displace", "even_slopes", "backend_other", "model",
          "gather_scatter"]


def tick_ms(scene, model, ticks, threads):
    p = subprocess.run([BIN, "simulate", "--scene", scene, "--ticks", str(ticks), "--backend",
                        "cpu", "--model", model, "--threads", str(threads)],
                       capture_output=True, text=True, timeout=1800)
    return json.loads(p.stdout)["stages"]["tick"]["mean_ms"] if p.returncode == 0 else None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--ticks", type=int, default=1000)
    ap.add_argument("--scenes", default="thesis-car,box45")
    args = ap.parse_args()
    print(f"bench_models on {machine()}, {args.ticks} ticks, CPU backend (timings noisy on a "
          f"shared machine)")
    for name in args.scenes.split(","):
        scene = os.path.join(SOURCE, "tests", "scenes", name + ".json")
        print(f"\n{name}")
        print(f"{'model':<18} {'tick ms':>8} {'p99':>8} {'model ms':>9} {'Σh drift':>12} "
              f"{'scratch B':>10}  by stage")
        for model in MODELS:
            p = subprocess.run([BIN, "simulate", "--scene", scene, "--ticks", str(args.ticks),
                                "--backend", "cpu", "--model", model],
                               capture_output=True, text=True, timeout=1800)
            if p.returncode != 0:
                print(f"{model:<18} failed: {p.stderr.strip()[-200:]}")
                continue
            r = json.loads(p.stdout)
            st = r["stages"]
            by = ", ".join(f"{s} {r['scratch_bytes_by_stage'][s]}" for s in STAGES
                           if r["scratch_bytes_by_stage"][s])
            extra = f"; {r['footprint_events']} footprint events" if "footprint_events" in r else ""
            print(f"{model:<18} {st['tick']['mean_ms']:>8.3f} {st['tick']['p99_ms']:>8.3f} "
                  f"{st['model']['mean_ms']:>9.3f} {r['volume_after'] - r['volume_before']:>+12d} "
                  f"{r['scratch_bytes_peak']:>10d}  {by}{extra}")
        # the goal: the soil model at most 1.3x persson-ssbo at one thread
        soil, ssbo = (tick_ms(scene, m, args.ticks, 1) for m in ("bekker", "persson-ssbo"))
        if soil and ssbo:
            print(f"one thread: bekker {soil:.3f} ms, persson-ssbo {ssbo:.3f} ms, "
                  f"ratio {soil / ssbo:.2f} (goal <= 1.3)")
    print(f"\n{SCM_ANCHORS}")


if __name__ == "__main__":
    main()
