#!/usr/bin/python3
"""Key-to-visible latency of the viewer's own rut with and without prediction, for `make bench`
(docs/engines.md, "In the viewer"): tests/bench/bench_viewer_predict.mjs drives the viewer in
headless Chromium against the real daemon through a loopback relay that delays each direction
by 50 ms (a 100 ms round trip), and times each 0.4 m move of the page's sphere until a drawn
frame shows the cell under its new centre dug: median ms and frames drawn, with prediction on
and with the toggle off (server only); then, per mode, a few seconds of steady driving: the
prediction's ms per drawn frame in Chromium and the bytes per second and per pose batch each
way (equal per batch: prediction sends nothing).

Anchor: with prediction, within one frame (the key's frame); without, at least the round trip.
Software GL (llvmpipe) on a loaded machine draws slowly, so the frames matter more than the ms.
Never fails on a figure. TERRAD_BENCH_TRIALS (default 8).
"""
import json
import os
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import SOURCE, machine  # noqa: E402

TRIALS = os.environ.get("TERRAD_BENCH_TRIALS", "8")
DELAY_MS = 50


def main():
    if not shutil.which("node"):
        print("viewer prediction latency: skipped (node missing)")
        return
    p = subprocess.run(["node", os.path.join(HERE, "bench_viewer_predict.mjs"), str(DELAY_MS), TRIALS],
                       capture_output=True, text=True, timeout=900, cwd=SOURCE)
    lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
    if p.returncode != 0 or not lines:
        print(f"viewer prediction latency: failed: {p.stderr[-800:]}")
        return
    r = json.loads(lines[-1])
    if "skipped" in r:
        print(f"viewer prediction latency: skipped ({r['skipped']})")
        return
    print(f"viewer key-to-visible, RTT {2 * DELAY_MS} ms on loopback (relay), headless Chromium "
          f"(software GL); {machine()}, load average {os.getloadavg()[0]:.1f}")
    for mode in ("prediction", "server only"):
        m = r[mode]
        print(f"  {mode:>12}: median {m['median_ms']:.0f} ms, {m['median_frames']} frame(s) drawn "
              f"({m['seen']} of {r['trials']} moves seen; ms each: {m['runs']})")
    print(f"  steady driving, {r['prediction']['steady']['seconds']:.0f} s a mode, a 0.01 m pose batch per frame:")
    for mode in ("prediction", "server only"):
        s = r[mode]["steady"]
        cost = (f"prediction {s['ms_per_frame']:.2f} ms per frame (tick per batch {s['ms_per_send']:.2f}, "
                f"reconcile per ACK {s['ms_per_ack']:.2f}, paste per frame {s['ms_per_paste']:.2f})"
                if s["ms_per_frame"] and s["ms_per_send"] is not None else "prediction 0 ms (off)")
        print(f"  {mode:>12}: {s['frames']} frames, {s['batches']} batches; {cost}; bytes up "
              f"{s['up_bytes_per_s']:.0f}/s ({s['up_bytes_per_batch']:.1f} per batch), down {s['down_bytes_per_s']:.0f}/s "
              f"({s['down_bytes_per_batch']:.0f} per batch)")
    frames = r["prediction"]["median_frames"]
    print(f"  anchor: with prediction within one frame: {'met' if frames is not None and frames <= 1 else 'NOT met'}")


main()
