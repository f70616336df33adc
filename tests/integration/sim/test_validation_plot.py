#!/usr/bin/python3
# ctest-timeout: 120
"""scripts/validation-plot (matplotlib) on the real single-wheel validation test
(build/test_single_wheel_ding2011), into temporary files:

- it writes a PNG and replaces exactly the marked block of a copy of docs/validation.md with the
  test's table (six slips, ten columns) and its median line; the text outside the block is kept;
- run twice on the same model, it writes the same PNG and the same page (the test is integer and
  deterministic; the page cannot drift between runs);
- output that is not the single-wheel table, and a page without the markers, are refused with a
  message naming what is missing.
Skips (77) without Debian's python3-matplotlib. make docs-images runs the script on docs/.
"""
import os
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, skip  # noqa: E402

try:
    import matplotlib  # noqa: F401
except ImportError:
    skip("python3-matplotlib missing (scripts/deps --test)")

SCRIPT = os.path.join(SOURCE, "scripts", "validation-plot")
TEST = os.path.join(os.path.dirname(BIN), "test_single_wheel_ding2011")
PAGE = os.path.join(SOURCE, "docs", "validation.md")
check = Checks()


def plot(*args):
    return subprocess.run([sys.executable, SCRIPT, *args], capture_output=True, text=True,
                          timeout=300)


def block(text):
    a, b = text.index("<!-- ding2011-table -->"), text.index("<!-- /ding2011-table -->")
    return text[:a], text[a:b], text[b:]


with tempfile.TemporaryDirectory(prefix="terrad-valplot-") as tmp:
    md, png = os.path.join(tmp, "validation.md"), os.path.join(tmp, "ding.png")
    shutil.copy(PAGE, md)
    out = os.path.join(tmp, "out.txt")
    run = subprocess.run([TEST], capture_output=True, text=True, timeout=300)
    check(run.returncode == 0, f"the validation test runs ({run.returncode}): {run.stdout[-300:]}")
    with open(out, "w") as f:
        f.write(run.stdout)
    r = plot("--input", out, "--png", png, "--md", md)
    check(r.returncode == 0, f"the script succeeds: {r.stdout}{r.stderr}")
    with open(png, "rb") as f:
        first_png = f.read()
    check(first_png.startswith(b"\x89PNG\r\n\x1a\n") and len(first_png) > 10000,
          f"a PNG is written ({len(first_png)} bytes)")
    with open(md) as f:
        page = f.read()
    with open(PAGE) as f:
        before = f.read()
    head, table, tail = block(page)
    rows = [line for line in table.splitlines() if line.startswith("| 0.")]
    check(len(rows) == 6 and all(line.count("|") == 11 for line in rows),
          f"six slips of ten columns in the block: {rows}")
    # the validation table is what the test prints before its median line (a second-pass table follows)
    printed = run.stdout.split("median relative error")[0]
    check(rows == [line for line in printed.splitlines() if line.startswith("| 0.")],
          "the block holds exactly the rows the test printed")
    check("median relative error: drawbar pull" in table, "the block names the median errors")
    check((head, tail) == block(before)[::2], "the page outside the block is unchanged")
    r = plot("--test", TEST, "--png", png, "--md", md)
    with open(png, "rb") as f, open(md) as g:
        check(r.returncode == 0 and f.read() == first_png and g.read() == page,
              f"running the test again writes the same PNG and page: {r.stderr}")
    with open(out, "w") as f:
        f.write("8 passed, 0 failed\n")
    r = plot("--input", out, "--png", png, "--md", md)
    check(r.returncode != 0 and "no single-wheel table" in r.stderr, f"no table refused: {r.stderr}")
    with open(out, "w") as f:
        f.write(run.stdout)
    with open(md, "w") as f:
        f.write("# a page without the markers\n")
    r = plot("--input", out, "--png", png, "--md", md)
    check(r.returncode != 0 and "ding2011-table" in r.stderr, f"no markers refused: {r.stderr}")
check.finish()
