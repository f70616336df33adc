#!/usr/bin/python3
# ctest-timeout: 900
"""Heights do not depend on the thread count: `terrad simulate --threads N`
for N = 1, 2 and 7 writes identical heights (--out, byte for byte) on every
scene of tests/scenes (and the lugged wheel of tests/scenes/lugged) × method ×
metric on the CPU twin, and reports the
count it ran with as "threads". Bad counts are refused with the option named.
`terrad serve --threads N` reports N in the gauge terrad_sim_threads.

The windows of a tick run in parallel and large work lists split into bands
(server/sim/sim_threads.c); the banding itself on windows large enough to
split is compared with the dense stages in tests/unit/test_sparse_stages.c.
"""
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, metric_value, simulate  # noqa: E402
import time  # noqa: E402

SCENES = os.path.join(SOURCE, "tests", "scenes")
METHODS = ["iterative", "ssbo", "multi"]
METRICS = ["euclidean", "manhattan", "chebyshev"]
THREADS = [1, 2, 7]
TICKS = 30


def run_one(scene, method, metric, threads, out):
    st, report, err = simulate(scene, TICKS, "--method", method, "--metric", metric,
                               "--threads", str(threads), "--out", out)
    with open(out, "rb") as f:
        heights = f.read() if st == 0 else b""
    return st, report, err, heights


def main():
    check = Checks()
    scenes = sorted(f for f in os.listdir(SCENES) if f.endswith(".json"))
    check(len(scenes) >= 5, f"scenes found in tests/scenes: {scenes}")
    scenes.append(os.path.join("lugged", "lugged-wheel.json"))
    with tempfile.TemporaryDirectory() as tmp:
        cases = [(s, m, k) for s in scenes for m in METHODS for k in METRICS]

        def case(c):
            s, m, k = c
            results = []
            for t in THREADS:
                out = os.path.join(tmp, f"{os.path.basename(s)}-{m}-{k}-{t}.bin")
                results.append((t,) + run_one(os.path.join(SCENES, s), m, k, t, out))
            return c, results

        with ThreadPoolExecutor(max_workers=2) as pool:
            for (s, m, k), results in pool.map(case, cases):
                ok = all(r[1] == 0 for r in results)
                check(ok, f"{s} {m}/{k}: every thread count runs "
                          f"({[(r[0], r[1], r[3][-200:]) for r in results if r[1] != 0]})")
                if not ok:
                    continue
                for t, _, report, _, _ in results:
                    check(report.get("threads") == t, f"{s} {m}/{k}: reports threads {t}: "
                                                      f"{report.get('threads')}")
                ref = results[0][4]
                check(len(ref) > 0, f"{s} {m}/{k}: heights written")
                for t, _, _, _, heights in results[1:]:
                    check(heights == ref, f"{s} {m}/{k}: {t} threads give the heights of 1")

    for bad in ["0", "65", "two", "-3"]:
        p = subprocess.run([BIN, "simulate", "--scene", os.path.join(SCENES, "tiny.json"),
                            "--ticks", "1", "--backend", "cpu", "--threads", bad],
                           capture_output=True, text=True, timeout=60)
        check(p.returncode != 0 and "threads" in p.stderr,
              f"--threads {bad} refused with the option named ({p.returncode}: {p.stderr!r})")
    # serve --threads N: the gauge terrad_sim_threads says N once ticks run
    for n in (1, 3):
        with check.running(Daemon(backend="cpu", demo=True, extra=["--threads", str(n)])) as d:
            seen, deadline = None, time.time() + 60
            while time.time() < deadline and seen != n:
                status, text = d.metrics()
                seen = metric_value(text, "terrad_sim_threads") if status == 200 else None
                time.sleep(0.2)
            check(seen == n, f"serve --threads {n}: terrad_sim_threads {seen}")
    check.finish()


if __name__ == "__main__":
    main()
