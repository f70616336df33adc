#!/usr/bin/python3
"""scripts/trade-plot (matplotlib) on the committed sweep docs/trade/trade.csv:

- each scene's front is a Pareto front: no configuration of the sweep is both cheaper and more
  accurate than a point on it, and every configuration off it is beaten by one on it; it holds
  the most accurate and the cheapest configuration of the scene;
- the SVG it writes names every scene and labels every point of every front with its model,
  cell size and iterations (text kept as text);
- the physical axis: docs/trade/trade-physical.csv beside it adds a panel of bekker's cost
  against its error against measured data (Ding 2011, the smooth and the lugged wheel), each
  configuration labelled with its wheel; a CSV
  with no such file beside it (a copy in a temporary directory) gets no such panel;
- a CSV without sweep rows is refused with a message.
Skips (77) without Debian's python3-matplotlib.
"""
import importlib.machinery
import importlib.util
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, skip  # noqa: E402

try:
    import matplotlib  # noqa: F401
except ImportError:
    skip("python3-matplotlib missing (scripts/deps --test)")

SCRIPT = os.path.join(SOURCE, "scripts", "trade-plot")
CSV = os.path.join(SOURCE, "docs", "trade", "trade.csv")
check = Checks()

loader = importlib.machinery.SourceFileLoader("trade_plot", SCRIPT)
spec = importlib.util.spec_from_loader("trade_plot", loader)
tp = importlib.util.module_from_spec(spec)
loader.exec_module(tp)

rows = tp.read_rows(CSV, "cpu")
scenes = sorted({r["scene"] for r in rows})
check(len(scenes) >= 3 and len(rows) > 100, f"the sweep has scenes and rows: {scenes}, {len(rows)}")
for scene in scenes:
    pts = [r for r in rows if r["scene"] == scene]
    front = tp.pareto_front(pts)
    dominated = [(f, p) for f in front for p in pts
                 if p["ms"] < f["ms"] and p["error_mm"] < f["error_mm"]]
    check(not dominated, f"{scene}: nothing beats a front point on both axes: {dominated[:2]}")
    off = [p for p in pts if p not in front]
    unbeaten = [p for p in off if not any(f["ms"] <= p["ms"] and f["error_mm"] <= p["error_mm"]
                                          for f in front)]
    check(not unbeaten, f"{scene}: every point off the front is beaten by one on it: {unbeaten[:2]}")
    check(min(p["error_mm"] for p in pts) == front[0]["error_mm"], f"{scene}: the most accurate is on it")
    check(min(p["ms"] for p in pts) == front[-1]["ms"], f"{scene}: the cheapest is on it")

with tempfile.TemporaryDirectory() as tmp:
    out = os.path.join(tmp, "trade.svg")
    r = subprocess.run(["/usr/bin/python3", SCRIPT, CSV, out], capture_output=True, text=True, timeout=120)
    check(r.returncode == 0 and os.path.exists(out), f"trade-plot ran: {r.stdout} {r.stderr}")
    svg = open(out).read() if os.path.exists(out) else ""
    for scene in scenes:
        check(f"{scene}:" in svg, f"the SVG has a panel for {scene}")
        for p in tp.pareto_front([x for x in rows if x["scene"] == scene]):
            check(tp.label(p) in svg, f"{scene}: the front point {tp.label(p)} is labelled")
    physical = tp.read_physical(os.path.join(os.path.dirname(CSV), "trade-physical.csv"))
    check(len(physical) >= 3, f"docs/trade has the physical axis ({len(physical)} rows)")
    check({p["wheel"] for p in physical} == {"smooth", "lugged"},
          f"docs/trade's physical axis has Ding's smooth and lugged wheels "
          f"({sorted({p['wheel'] for p in physical})})")
    check("against measured data" in svg and
          all(tp.physical_label(p) in svg for p in physical),
          "the SVG has the physical panel, every bekker configuration labelled")
    empty = os.path.join(tmp, "empty.csv")
    with open(CSV) as f, open(empty, "w") as g:
        g.write(f.readline())
    alone = os.path.join(tmp, "alone.csv")
    with open(CSV) as f, open(alone, "w") as g:
        g.write(f.read())
    r = subprocess.run(["/usr/bin/python3", SCRIPT, alone, out], capture_output=True, text=True,
                       timeout=120)
    check(r.returncode == 0 and "against measured data" not in open(out).read(),
          f"no trade-physical.csv beside the CSV: no physical panel ({r.stderr[-200:]})")
    r = subprocess.run(["/usr/bin/python3", SCRIPT, empty, out], capture_output=True, text=True, timeout=60)
    check(r.returncode != 0 and "no sweep rows" in r.stderr, f"an empty sweep is refused: {r.stderr}")
check.finish()
