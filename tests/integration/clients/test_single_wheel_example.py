#!/usr/bin/python3
# ctest-timeout: 240
"""clients/python/examples/single_wheel.py (the single-wheel testbed over the wire) against the
real daemon on its scene (clients/python/examples/single_wheel_scene.json: the bekker model on
Ding et al. 2011's soil; CPU backend, a store in a temporary directory):

- it exits 0 and prints one row per slip of Ding's smooth wheel (0, 0.1, 0.2, 0.3, 0.4, 0.6),
  each with drawbar pull, sinkage, torque and load beside Ding's values;
- the server-side load search (a load-driven wheel, load_n 80) holds its mean vertical force
  near 80 N (within 20 %), and the sinkage is that of a wheel in soil (between 2 and 30 mm;
  Ding measured 5-17.5 mm, the server-side test 8-15 mm);
- the physics that must hold whatever the calibration and the machine's load: the towed wheel
  (slip 0) is resisted, the wheel at slip 0.6 pulls (more than the towed one by 10 N) and needs
  more driving torque than the towed one.
Bounds are loose on purpose: a tick that comes before the client's next pose (a loaded machine)
stands the wheel still for a tick and moves the figures; the example prints how many.
"""
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon  # noqa: E402

EXAMPLES = os.path.join(SOURCE, "clients", "python", "examples")
check = Checks()
ROW = re.compile(r"^\s*([0-9.]+)\s+(-?[0-9.]+) \(\s*(-?[0-9.]+)\)\s+(-?[0-9.]+) \(\s*([0-9.]+)\)"
                 r"\s+(-?[0-9.]+) \(\s*([0-9.]+)\)\s+(-?[0-9.]+)\s+idle ticks (\d+)$")

with check.running(Daemon(extra=["--scene", os.path.join(EXAMPLES, "single_wheel_scene.json")],
                          name="terrad-single-wheel")) as d:
    r = subprocess.run([sys.executable, os.path.join(EXAMPLES, "single_wheel.py"), d.ws, d.http],
                       capture_output=True, text=True, timeout=200)
    print(r.stdout, end="")
    check(r.returncode == 0, f"the example exits 0 ({r.returncode}): {r.stderr[-600:]}")
    rows = {}
    for line in r.stdout.splitlines():
        m = ROW.match(line)
        if m:
            slip, dp, _, z, _, t, _, load, idle = m.groups()
            rows[float(slip)] = (float(dp), float(z), float(t), float(load), int(idle))
    check(sorted(rows) == [0.0, 0.1, 0.2, 0.3, 0.4, 0.6], f"one row per slip: {sorted(rows)}")
    if len(rows) == 6:
        for slip, (dp, z, t, load, idle) in rows.items():
            check(64.0 <= load <= 96.0,
                  f"slip {slip}: the server's load search holds 80 N ({load} N)")
            check(2.0 <= z <= 30.0, f"slip {slip}: sinkage of a wheel in soil ({z} mm)")
        check(rows[0.0][0] < 0.0, f"the towed wheel is resisted (DP {rows[0.0][0]} N)")
        check(rows[0.6][0] > rows[0.0][0] + 10.0,
              f"slip 0.6 pulls: DP {rows[0.6][0]} N vs {rows[0.0][0]} N towed")
        check(rows[0.6][2] > rows[0.0][2], f"slip 0.6 needs more torque ({rows[0.6][2]} N m vs "
              f"{rows[0.0][2]} N m)")
check.finish()
