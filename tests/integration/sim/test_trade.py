#!/usr/bin/python3
# ctest-timeout: 600
"""`terrad bench --trade --quick`, the real binary, into a temporary directory.

- trade.csv parses, holds every requested model × scene (and only those, plus
  the persson-iterative reference and its convergence check), one row per
  model × scene × cell size × iterations × backend, every value finite;
- the reference measured again against itself has error 0, every model that
  promises volume (Persson, integer diffusion, Sumner at compression 0, decals)
  has drift exactly 0, subtract loses exactly what it displaces (drift 1),
  deferred's cuts and rims do not balance (drift > 0); decals leave the trail
  untouched, so their error is the same in every run of a scene and they show
  no anisotropy; coarse runs have a non-zero error and anisotropy (the measure
  is not blind);
- the physical axis: with bekker in the sweep, trade-physical.csv holds a row per bekker
  configuration and wheel on Ding 2011's single-wheel testbed (quick: 0.02 and 0.01 m cells; the
  smooth wheel and the lugged one, the same configurations for both), each with its cost
  and its median errors against the measurements (finite, and the same on every run: the
  testbed is deterministic, so the rows equal test_single_wheel_ding2011's kind of figures at
  their own cell size), each wheel's finest at 0 against itself, the lugged wheel's figures its
  own (not the smooth wheel's); trade.txt has both wheels and says the geometric models
  have no forces; a sweep without bekker writes no such file;
- no trade.svg (scripts/trade-plot draws the plot from the CSV: test_trade_plot);
  trade.txt carries the summary;
- a subset (--models/--scenes) gives just that subset; GL rows when a GL
  context can be made (skipped otherwise);
- bad arguments (unknown model or scene, --out unwritable, bad --backend,
  no --trade) give a clear message and a nonzero exit.
"""
import csv
import math
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks  # noqa: E402

MODELS = ["persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
          "diffusion", "sumner", "decals", "bekker"]
# Σh exact by construction (docs/models.md, docs/materials.md; the scenes' snow has
# compression 0, so bekker compacts nothing, and diffusion runs its integer flux form by default).
VOLUME_EXACT = {"persson-iterative", "persson-ssbo", "persson-multi", "diffusion", "sumner",
                "decals", "bekker"}
SCENES = ["car", "spheres", "footsteps"]
QUICK_CELLS = {0.2, 0.1}
QUICK_ITERATIONS = {1, 10}
NUMERIC = ["cell_m", "iterations", "world_cells", "ticks", "tick_ms_mean", "tick_ms_p95",
           "scratch_bytes_peak", "bytes_per_world_cell", "volume_drift", "cross_section_rms_m",
           "max_slope_excess_m", "anisotropy_rms_m", "refused_windows"]

check = Checks()


def bench(*args, timeout=300):
    return subprocess.run([BIN, "bench", *args], capture_output=True, text=True, timeout=timeout)


def read_rows(out):
    with open(os.path.join(out, "trade.csv"), newline="") as f:
        return list(csv.DictReader(f))


def check_rows(rows, models, scenes, backends, label):
    check(len(rows) > 0, f"{label}: rows")
    for r in rows:
        for k in NUMERIC:
            try:
                ok = math.isfinite(float(r[k])) and float(r[k]) >= 0
            except ValueError:
                ok = False
            check(ok, f"{label}: {k} = {r[k]!r} finite and >= 0 ({r['model']} {r['scene']})")
        check(r["renderer"] != "", f"{label}: renderer named")
        what = (f"{label}: {r['model']} {r['scene']} {r['backend']} cell {r['cell_m']} "
                f"it {r['iterations']}")
        if r["model"] in VOLUME_EXACT:
            check(r["volume_drift"] == "0", f"{what}: drift exactly 0 ({r['volume_drift']})")
        elif r["model"] == "subtract":
            # 0 only where it cut nothing (a 12 cm foot can miss every 0.2 m cell centre)
            check(float(r["volume_drift"]) in (0.0, 1.0),
                  f"{what}: subtract loses all it displaces, drift 1 ({r['volume_drift']})")
        elif r["model"] == "deferred":
            check(float(r["volume_drift"]) > 0, f"{what}: deferred drifts ({r['volume_drift']})")
    sweep = [r for r in rows if r["role"] == "sweep"]
    want = {(m, s, b, c, i) for m in models for s in scenes for b, cells in backends.items()
            for c in cells for i in QUICK_ITERATIONS}
    got = [(r["model"], r["scene"], r["backend"], float(r["cell_m"]), int(r["iterations"]))
           for r in sweep]
    check(len(got) == len(set(got)), f"{label}: one row per configuration")
    check(set(got) == want, f"{label}: rows are exactly model x scene x backend x cell x "
          f"iterations (missing {sorted(want - set(got))[:4]}, extra {sorted(set(got) - want)[:4]})")
    if "subtract" in models:
        check(any(float(r["volume_drift"]) == 1.0 for r in sweep if r["model"] == "subtract"),
              f"{label}: subtract cuts somewhere and loses it all (drift 1)")
    for s in scenes:
        ref = [r for r in rows if r["scene"] == s and r["role"] == "reference"]
        conv = [r for r in rows if r["scene"] == s and r["role"] == "convergence"]
        check(len(ref) == 1 and len(conv) == 1, f"{label}: {s}: one reference, one convergence row")
        if ref:
            check(ref[0]["model"] == "persson-iterative" and float(ref[0]["cell_m"]) == 0.1,
                  f"{label}: {s}: reference is persson-iterative at the finest cell")
            check(float(ref[0]["cross_section_rms_m"]) < 1e-9,
                  f"{label}: {s}: the reference's own error is 0 ({ref[0]['cross_section_rms_m']})")
        if conv:
            check(float(conv[0]["cross_section_rms_m"]) < 0.005,
                  f"{label}: {s}: 20/20 vs 40/40 differ by < 5 mm ({conv[0]['cross_section_rms_m']})")
        decals = [r for r in sweep if r["scene"] == s and r["model"] == "decals"]
        if decals:
            check(len({r["cross_section_rms_m"] for r in decals}) == 1 and
                  float(decals[0]["cross_section_rms_m"]) > 1e-3,
                  f"{label}: {s}: decals leave the snow untouched: one error, the trail's own "
                  f"({sorted({r['cross_section_rms_m'] for r in decals})})")
            check(all(float(r["anisotropy_rms_m"]) == 0 for r in decals),
                  f"{label}: {s}: decals show no anisotropy")
        coarse = [r for r in sweep if r["scene"] == s and float(r["cell_m"]) == 0.2]
        check(any(float(r["cross_section_rms_m"]) > 1e-4 for r in coarse),
              f"{label}: {s}: 0.2 m cells differ from the reference")
        check(any(float(r["anisotropy_rms_m"]) > 1e-4 for r in coarse),
              f"{label}: {s}: 0.2 m cells show some anisotropy")


def check_physical(out, txt):
    path = os.path.join(out, "trade-physical.csv")
    check(os.path.exists(path), "bekker in the sweep: trade-physical.csv written")
    if not os.path.exists(path):
        return
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    wheels = {w: [r for r in rows if r.get("wheel") == w] for w in ("smooth", "lugged")}
    check(len(wheels["smooth"]) + len(wheels["lugged"]) == len(rows),
          f"physical: every row names its wheel, smooth or lugged ({[r.get('wheel') for r in rows]})")
    for w, mine in wheels.items():
        check([float(r["cell_m"]) for r in mine] == [0.02, 0.01],
              f"physical: {w} wheel: one row per quick cell size ({[r['cell_m'] for r in mine]})")
        check(mine and float(mine[-1]["pull_rms_vs_finest_n"]) == 0.0,
              f"physical: {w} wheel: its finest configuration is 0 against itself")
    config = ("cell_m", "tick_mm", "ticks")
    check([[r[k] for k in config] for r in wheels["smooth"]] ==
          [[r[k] for k in config] for r in wheels["lugged"]],
          "physical: the same configurations for both wheels")
    figures = ("pull_median_error", "sinkage_median_error", "torque_median_error")
    check(all([s[k] for k in figures] != [g[k] for k in figures]
              for s, g in zip(wheels["smooth"], wheels["lugged"])),
          "physical: the lugged rows are the lugged wheel's own run, not the smooth one's")
    for r in rows:
        errs = [float(r[k]) for k in figures]
        check(r["model"] == "bekker" and all(math.isfinite(e) and 0 <= e < 10 for e in errs)
              and float(r["tick_ms_mean"]) > 0,
              f"physical: {r.get('wheel')} {r['cell_m']} m: errors against Ding finite ({errs}), "
              f"cost > 0")
    check("against measured data" in txt and "compute no forces" in txt and "lugged" in txt,
          "trade.txt has the physical table, both wheels, and says the geometric models have no "
          "forces")


def check_no_svg(out, p, label):
    """The bench writes data only; the picture is scripts/trade-plot's (matplotlib)."""
    check(not os.path.exists(os.path.join(out, "trade.svg")), f"{label}: the bench writes no SVG")
    check("scripts/trade-plot" in p.stdout, f"{label}: the bench says how to plot the CSV")


with tempfile.TemporaryDirectory() as tmp:
    # the whole quick sweep on the CPU twin
    out = os.path.join(tmp, "all", "nested")
    p = bench("--trade", "--quick", "--backend", "cpu", "--out", out)
    check(p.returncode == 0, f"quick sweep exits 0 ({p.returncode}): {p.stderr[-600:]}")
    if p.returncode == 0:
        rows = read_rows(out)
        check_rows(rows, MODELS, SCENES, {"cpu": QUICK_CELLS}, "all")
        check_no_svg(out, p, "all")
        with open(os.path.join(out, "trade.txt")) as f:
            txt = f.read()
        check("summary" in txt and "converged" in txt, "trade.txt has the summary")
        check("summary" in p.stdout and "wrote" in p.stdout, "the table is printed")
        check_physical(out, txt)

    # a subset, and GL where it exists
    out = os.path.join(tmp, "subset")
    p = bench("--trade", "--quick", "--backend", "cpu", "--models", "persson-ssbo",
              "--scenes", "footsteps,car", "--out", out)
    check(p.returncode == 0, f"subset exits 0: {p.stderr[-600:]}")
    if p.returncode == 0:
        rows = read_rows(out)
        check_rows(rows, ["persson-ssbo"], ["footsteps", "car"], {"cpu": QUICK_CELLS}, "subset")
        check({r["model"] for r in rows if r["role"] == "sweep"} == {"persson-ssbo"},
              "subset: only the model asked for")
        check_no_svg(out, p, "subset")
        check(not os.path.exists(os.path.join(out, "trade-physical.csv")),
              "subset without bekker: no trade-physical.csv")

    # GL where a context can be made (the same probe as test_simulate)
    probe = subprocess.run([BIN, "simulate", "--scene", os.path.join(SOURCE, "tests", "scenes",
                            "tiny.json"), "--ticks", "1", "--backend", "gl"],
                           capture_output=True, text=True, timeout=120)
    if probe.returncode != 0:
        print("GL backend unavailable, GL case skipped:", probe.stderr.strip().splitlines()[-1:])
    else:
        out = os.path.join(tmp, "gl")
        p = bench("--trade", "--quick", "--backend", "gl", "--models", "persson-multi",
                  "--scenes", "footsteps", "--out", out)
        check(p.returncode == 0, f"gl exits 0: {p.stderr[-600:]}")
        if p.returncode == 0:
            rows = read_rows(out)
            check_rows(rows, ["persson-multi"], ["footsteps"], {"gl": QUICK_CELLS}, "gl")
            gl_rows = [r for r in rows if r["backend"] == "gl"]
            check(gl_rows and all(r["renderer"] for r in gl_rows), "gl: renderer recorded")

    # bad arguments
    def refused(args, needle, what, code=None):
        p = bench(*args)
        check(p.returncode != 0 and (code is None or p.returncode == code),
              f"{what}: nonzero exit ({p.returncode})")
        check(needle in p.stderr, f"{what}: message names {needle!r}: {p.stderr.strip()!r}")
        check(p.stdout.strip() == "", f"{what}: nothing on stdout")

    refused(["--trade", "--quick", "--models", "persson-ssbo,warp-drive", "--out", tmp],
            "warp-drive", "unknown model", 2)
    refused(["--trade", "--quick", "--scenes", "moon", "--out", tmp], "moon", "unknown scene", 2)
    refused(["--trade", "--backend", "vulkan"], "--backend", "bad backend", 2)
    refused(["--quick"], "--trade", "no --trade", 2)
    refused(["--trade", "--frobnicate", "1"], "--frobnicate", "unknown option", 2)
    refused(["--trade", "--out"], "--out", "--out without a value", 2)
    blocker = os.path.join(tmp, "a-file")
    with open(blocker, "w") as f:
        f.write("not a directory\n")
    refused(["--trade", "--quick", "--out", os.path.join(blocker, "sub")], blocker,
            "--out under a file")
    if os.geteuid() != 0:
        ro = os.path.join(tmp, "read-only")
        os.mkdir(ro, 0o555)
        refused(["--trade", "--quick", "--out", ro], ro, "--out read-only")

    h = subprocess.run([BIN, "--help"], capture_output=True, text=True)
    check("bench --trade" in h.stdout, "terrad --help lists bench --trade")
    h = bench("--help")
    check(h.returncode == 0 and all(m in h.stdout for m in MODELS + SCENES),
          "terrad bench --help lists the models and scenes")

check.finish()
