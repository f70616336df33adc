#!/usr/bin/python3
# ctest-timeout: 900
"""`terrad wheel` (docs/calibrate.md, "Running the testbed"): the single-wheel testbed from the
command line, the very run `terrad calibrate` and the Ding 2011 validation test make.

- Ding's wheel on the ding2011 preset at Ding's six slips gives the validation test's own table
  (build/test_single_wheel_ding2011, which calls sim_wheel_testbed itself): pull, sinkage and
  torque identical at the two decimals it prints;
- fed back to `terrad calibrate --wheel` as if measured (its CSV is calibrate's columns), the same
  soil and testbed give calibrate's own runs exactly: the base soil's objective is 0 and every
  residual's relative error is 0 — equal doubles, which only the same run gives (a figure off by
  one unit in the last place is a residual of ~1e-16, not 0);
- the material JSON calibrate writes (--out) as --soil FILE gives the same bytes as the preset;
  --format json carries the same doubles; two runs are byte-identical;
- bad arguments exit 2, print nothing on stdout and name the option or the material's field:
  a missing --soil/--load/--slips, an unknown preset and missing file, a material file with a
  field out of range (material.soil.kc), a material of another model (material.model), not
  JSON, slips out of range or not numbers, a radius of 0 or NaN, an unknown format, malformed
  --grousers;
- Ding's lugged wheel (--grousers 30,0.01,0.004) gives the validation test's lugged table.
"""
import csv
import io
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks  # noqa: E402

check = Checks()
DING_WHEEL = ["--radius", "0.15735", "--width", "0.165", "--load", "80"]
DING_SLIPS = "0,0.1,0.2,0.3,0.4,0.6"
# a small bed for the round trips (the Ding comparison keeps the default 5 mm, 0.5 m)
SMALL = ["--cell", "0.01", "--distance", "0.2"]
LOAM = ["--soil", "sandy-loam", "--radius", "0.2", "--width", "0.12", "--load", "150",
        "--slips", "0.1,0.3,0.5", *SMALL]


def terrad(*args):
    p = subprocess.run([BIN, *args], capture_output=True, text=True, timeout=240)
    return p.returncode, p.stdout, p.stderr


def rows(text):
    return list(csv.DictReader(io.StringIO(text)))


def write(path, text):
    with open(path, "w") as f:
        f.write(text)
    return path


def test_ding():
    rc, out, err = terrad("wheel", "--soil", "ding2011", *DING_WHEEL, "--slips", DING_SLIPS)
    check(rc == 0, f"the Ding run exits 0 ({rc}: {err})")
    got = rows(out)
    check([float(r["slip"]) for r in got] == [0, 0.1, 0.2, 0.3, 0.4, 0.6], f"one row a slip: {out}")
    validation = os.path.join(os.path.dirname(BIN), "test_single_wheel_ding2011")
    v = subprocess.run([validation], capture_output=True, text=True, timeout=800)
    # its first table (the smooth wheel's six slips); tables of later passes follow it
    first = v.stdout.split("median relative error")[0]
    table = [line.split("|")[1:-1] for line in first.splitlines() if line.startswith("| 0.")]
    check(len(table) == 6, f"the validation test prints its six rows ({v.stdout})")
    for r, cells in zip(got, table):
        cells = [c.strip() for c in cells]
        mine = [f"{float(r['drawbar_pull_n']):.2f}", f"{1e3 * float(r['sinkage_m']):.2f}",
                f"{float(r['torque_nm']):.2f}"]
        theirs = [cells[1], cells[4], cells[7]]
        check(mine == theirs, f"slip {r['slip']}: pull, sinkage mm, torque {mine} are the "
                              f"validation test's {theirs}")
    # Ding's lugged wheel (--grousers): the validation test's lugged table
    rc, out, err = terrad("wheel", "--soil", "ding2011", *DING_WHEEL, "--slips", DING_SLIPS,
                          "--grousers", "30,0.01,0.004")
    got = rows(out) if rc == 0 else []
    check(rc == 0 and all(r["grouser_count"] == "30" for r in got),
          f"the lugged Ding run exits 0 with its lugs in the CSV ({rc}: {err} {out[:200]})")
    part = v.stdout.split("lugged wheel")[-1].split("lugged median")[0]
    table = [line.split("|")[1:-1] for line in part.splitlines() if line.startswith("| 0.")]
    check(len(table) == 6 and len(got) == 6, f"the lugged table has six rows ({part})")
    for r, cells in zip(got, table):
        cells = [c.strip() for c in cells]
        mine = [f"{float(r['drawbar_pull_n']):.2f}", f"{1e3 * float(r['sinkage_m']):.2f}",
                f"{float(r['torque_nm']):.2f}"]
        check(mine == [cells[1], cells[3], cells[5]],
              f"lugged, slip {r['slip']}: {mine} are the validation test's {cells}")


def test_calibrate_round_trip(tmp):
    rc, out, err = terrad("wheel", *LOAM)
    check(rc == 0 and len(rows(out)) == 3, f"sandy loam at three slips ({rc}: {err}{out})")
    rc2, out2, _ = terrad("wheel", *LOAM)
    check(rc2 == 0 and out2 == out, "two runs print the same bytes")
    measured = write(os.path.join(tmp, "loam.csv"), out)
    residuals, material = os.path.join(tmp, "res.csv"), os.path.join(tmp, "loam.json")
    rc, report, err = terrad("calibrate", "--wheel", measured, "--base", "sandy-loam", "--fit",
                             "slip_n", "--rounds", "0", *SMALL, "--residuals", residuals,
                             "--out", material)
    check(rc == 0, f"calibrate takes terrad wheel's CSV ({rc}: {err})")
    check("base soil: objective 0\n" in report,
          f"calibrate's runs of the same soil are the wheel's exactly: objective 0 ({report})")
    with open(residuals) as f:
        res = rows(f.read())
    check(len(res) == 9 and all(float(r["relative_error"]) == 0 for r in res),
          f"every one of the 9 residuals is exactly 0 ({res})")
    # the material file calibrate wrote (the preset, every field written) as --soil FILE
    args = list(LOAM)
    args[args.index("sandy-loam")] = material
    rc, from_file, err = terrad("wheel", *args)
    check(rc == 0 and from_file == out,
          f"--soil {os.path.basename(material)} gives the preset's bytes ({rc}: {err})")
    rc, text, err = terrad("wheel", *LOAM, "--format", "json")
    doc = json.loads(text) if rc == 0 else {}
    runs = doc.get("runs", [])
    same = len(runs) == 3 and all(
        float(c[k]) == j[k] for c, j in zip(rows(out), runs)
        for k in ("slip", "drawbar_pull_n", "sinkage_m", "torque_nm"))
    check(same, f"--format json carries the CSV's doubles ({rc}: {err}{text})")
    check(doc.get("soil", {}).get("kphi") == 1515.04e3 and doc.get("compression") == 0.5
          and doc.get("wheel") == {"radius_m": 0.2, "width_m": 0.12, "load_n": 150}
          and doc.get("testbed", {}).get("cell_m") == 0.01,
          f"the JSON names the soil, the wheel and the bed ({doc})")


def test_refusals(tmp):
    bad_soil = write(os.path.join(tmp, "bad-soil.json"),
                     '{"model": "bekker", "soil": {"preset": "sandy-loam", "kc": -1}}')
    persson = write(os.path.join(tmp, "persson.json"), '{"model": "persson"}')
    broken = write(os.path.join(tmp, "broken.json"), '{"model": "bekker",')
    wheel = ["--radius", "0.2", "--width", "0.12", "--load", "150", "--slips", "0.2"]
    cases = [
        (["--radius", "0.2", "--width", "0.1", "--load", "10", "--slips", "0.1"], "--soil"),
        (["--soil", "loam", *wheel], "--soil"),
        (["--soil", os.path.join(tmp, "missing.json"), *wheel], "missing.json"),
        (["--soil", bad_soil, *wheel], "material.soil.kc"),
        (["--soil", persson, *wheel], "material.model"),
        (["--soil", broken, *wheel], "broken.json"),
        (["--soil", "snow-us", "--radius", "0.2", "--width", "0.1", "--slips", "0.1"], "--load"),
        (["--soil", "snow-us", "--radius", "0.2", "--width", "0.1", "--load", "9"], "--slips"),
        (["--soil", "snow-us", *wheel[:-2], "--slips", "0.1,abc"], "--slips"),
        (["--soil", "snow-us", *wheel[:-2], "--slips", "0.1,0.99"], "--slips"),
        (["--soil", "snow-us", *wheel[:-2], "--slips", "0.1,"], "--slips"),
        (["--soil", "snow-us", "--radius", "0", *wheel[2:]], "--radius"),
        (["--soil", "snow-us", "--radius", "nan", *wheel[2:]], "--radius"),
        (["--soil", "snow-us", *wheel, "--format", "xml"], "--format"),
        (["--soil", "snow-us", *wheel, "--cell", "1"], "--cell"),
        (["--soil", "snow-us", *wheel, "--grousers", "30,0.01"], "--grousers"),
        (["--soil", "snow-us", *wheel, "--grousers", "2.5,0.01,0.004"], "--grousers"),
    ]
    for args, names in cases:
        rc, out, err = terrad("wheel", *args)
        check(rc == 2 and out == "" and names in err and err.startswith("terrad wheel: "),
              f"{' '.join(args)}: exit 2 naming {names} ({rc}: {err.strip()}{out})")


with tempfile.TemporaryDirectory(prefix="terrad-wheel-") as tmp:
    test_refusals(tmp)
    test_calibrate_round_trip(tmp)
    test_ding()
check.finish()
