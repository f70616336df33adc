#!/usr/bin/python3
# ctest-timeout: 240
"""clients/python/examples/vehicle.py (issue 21's remote simulator: a four-wheeled rover whose
dynamics the client integrates at 60 Hz from terrad's per-wheel forces and torques) against a
real daemon with tokens. The example creates two worlds of the bekker model through the
lifecycle API, stamps a 20-degree ramp into each and drives a rover up it. Asserted, behaviour
only (positions and slips are the simulation's own, never wall-clock rates):

- bad soil parameters in a world's scene are refused first, each naming its field (422,
  `material.soil.<field>`), counted in terrad_world_requests_total{op="create",result="refused"},
  nothing created, and the daemon goes on to serve the example;
- it exits 0 and prints one verdict per world;
- soft soil (snow): the rover bogs down: it stalls (< 5 cm in its last 3 simulated seconds, the
  example's own test) more than a metre short of the top, its wheels spinning (mean slip > 0.5
  over those seconds), and its wheels sink deeper as it digs in (the last second's sinkage above
  the second second's);
- firm soil (sandy loam): the rover reaches the top;
- both worlds are deleted afterwards (none left in the data directory).

A tick that comes before the client's next pose (a loaded machine) stands the wheels still for a
tick; the example prints how many there were. The margins above hold with them.
"""
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon, metric_value  # noqa: E402

sys.path.insert(0, os.path.join(SOURCE, "clients", "python"))
sys.path.insert(0, os.path.join(SOURCE, "clients", "python", "examples"))
import terrad  # noqa: E402
import vehicle  # noqa: E402

EXAMPLE = os.path.join(SOURCE, "clients", "python", "examples", "vehicle.py")
TOKEN = "vehicle-example-admin"
VERDICT = re.compile(r"^(soft|firm): (climbed|bogged|neither): moved (-?[0-9.]+) m \(the top is "
                     r"([0-9.]+) m away\), slip (-?[0-9.]+), sinkage (-?[0-9.]+) mm .*idle ticks (\d+)$")
SECOND = re.compile(r"^(soft|firm): t\s+([0-9.]+) s .* sinkage\s+(-?[0-9.]+) mm$")

check = Checks()
with check.running(Daemon(token=TOKEN, name="terrad-vehicle")) as d:
    REFUSED = {"op": "create", "result": "refused"}
    before = metric_value(d.metrics()[1], "terrad_world_requests_total", REFUSED) or 0
    bad = {"n": 0, "shear_k_m": 0, "friction_deg": 90}
    for field, value in bad.items():
        try:
            terrad.create_world(d.http, f"bad-{field}", scene=vehicle.scene({field: value}),
                                token=TOKEN)
            check(False, f"soil {field} {value} refused (it was accepted)")
        except terrad.WorldError as e:
            check(e.status in (400, 422) and f"material.soil.{field}" in e.message,
                  f"soil {field} {value} refused naming material.soil.{field} ({e})")
    after = metric_value(d.metrics()[1], "terrad_world_requests_total", REFUSED) or 0
    check(after - before == 3, f"the three refusals are counted ({before} -> {after})")
    env = {**os.environ, "PYTHONPATH": os.path.join(SOURCE, "clients", "python")}
    r = subprocess.run([sys.executable, EXAMPLE, d.ws, d.http + "/", TOKEN], capture_output=True,
                       text=True, timeout=200, env=env)
    print(r.stdout, end="")
    check(r.returncode == 0, f"vehicle.py exits 0 ({r.returncode}): {r.stderr[-600:]}")
    verdicts, seconds = {}, {"soft": {}, "firm": {}}
    for line in r.stdout.splitlines():
        m, s = VERDICT.match(line), SECOND.match(line)
        if m:
            verdicts[m.group(1)] = (m.group(2), *map(float, m.group(3, 4, 5, 6)), int(m.group(7)))
        if s:
            seconds[s.group(1)][float(s.group(2))] = float(s.group(3))
    check(sorted(verdicts) == ["firm", "soft"], f"one verdict per world: {sorted(verdicts)}")
    if "soft" in verdicts:
        verdict, moved, top, slip, _, idle = verdicts["soft"]
        check(verdict == "bogged", f"soft soil bogs the rover down ({verdict}, {idle} idle ticks)")
        check(moved < top - 1.0, f"it stalls more than 1 m short of the top ({moved} of {top} m)")
        check(slip > 0.5, f"its wheels spin as it stalls (slip {slip})")
        soft = seconds["soft"]
        check(2.0 in soft and len(soft) >= 5 and soft[max(soft)] > soft[2.0],
              f"its wheels sink deeper as it digs in (mm per second: {soft})")
    if "firm" in verdicts:
        verdict, moved, top, _, _, idle = verdicts["firm"]
        check(verdict == "climbed" and moved >= top,
              f"firm soil: the rover climbs to the top ({verdict}, {moved} of {top} m, "
              f"{idle} idle ticks)")
    worlds = os.path.join(d.data_dir, "worlds")
    check(not os.path.isdir(worlds) or not os.listdir(worlds),
          f"both worlds are deleted ({os.listdir(worlds) if os.path.isdir(worlds) else []})")
check.finish()
