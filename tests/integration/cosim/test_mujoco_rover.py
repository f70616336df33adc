#!/usr/bin/python3
# ctest-timeout: 900
"""clients/c/examples/mujoco_rover.c (issue 30 item 3, docs/simulators.md): a real physics engine
as terrad's client. MuJoCo (Debian's libmujoco 2.2.2) owns a four-wheeled rover's body,
suspension and motors (mujoco_rover.xml); terrad's bekker soil is its wheel-ground contact, in
lockstep with a client-clocked world: each step MuJoCo's wheel poses go out in a STEP of one
tick, that tick's FORCES come back onto the wheel bodies (xfrc_applied), then mj_step2. The
rover starts on a 20-degree ramp (its scene from `mujoco_rover --write-scene`, a real daemon per
run). Asserted, behaviour only (simulated positions and slips; never a wall-clock rate):

- soft soil (snow-us, slip-sinkage 0.4): the rover digs in and stalls on the ramp: verdict
  "bogged" (< 5 cm in its last 3 simulated seconds, mean slip > 0.5), short of the top, and its
  wheels deeper in the last second than in the second one;
- firm soil (sandy-loam): it climbs (its rear wheels pass the top);
- the same run twice (two daemons, the same scene; the second with one sim thread): the same
  output line for line (every simulated figure and the digest of every step's MuJoCo state and
  FORCES), the same heights everywhere (GET /v1/heights) and the world at the same tick:
  bit-identical end to end;
- every world's Σh + Σcompacted (/v1/stats volume + soil_compacted) is what it was before the
  rover drove, and the world ticked exactly once per step the rover made;
- on a world of the wall clock the example refuses to run, naming the clock.

Without MuJoCo (no libmujoco-dev, so no build/mujoco_rover) the test skips, except under
`make test` (TERRAD_REQUIRE_MUJOCO=1, after scripts/deps --test installed it): a failure.
"""
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, need_built  # noqa: E402

check = Checks()
ROVER = need_built(os.path.join(os.path.dirname(BIN), "mujoco_rover"),
                   "MuJoCo (libmujoco-dev, scripts/deps --test)", "TERRAD_REQUIRE_MUJOCO")
MODEL = os.path.join(SOURCE, "clients", "c", "examples", "mujoco_rover.xml")
HZ = 500  # the world's tick and MuJoCo's step: 2 ms, inside the stability bound (simulators.md)
W, H = 280, 48
VERDICT = re.compile(r"^(climbed|bogged|neither): moved (-?[0-9.]+) m \(the top is (-?[0-9.]+) m "
                     r"away\), slip (-?[0-9.]+), sinkage (-?[0-9.]+) mm \(second 2: (-?[0-9.]+) mm\)"
                     r", Fz chatter [0-9.]+ N, (\d+) steps of [0-9.]+ ms, digest ([0-9a-f]{16})$")


def scene(tmp, soil, slip_n):
    p = subprocess.run([ROVER, "--write-scene", soil, tmp, "--slip-n", str(slip_n), "--hz",
                        str(HZ)], capture_output=True, text=True, timeout=60)
    check(p.returncode == 0, f"--write-scene {soil} ({p.returncode}: {p.stderr})")
    return p.stdout.strip()


def mass(d):
    s = d.stats()
    return s["volume"] + s["soil_compacted"], s["tick"]


def drive(scene_path, name, threads=None):
    """One run on a fresh daemon: (verdict match or None, simulated lines, heights, tick)."""
    extra = ["--scene", scene_path] + (["--threads", str(threads)] if threads else [])
    with check.running(Daemon(extra=extra, name=name)) as d:
        before, tick0 = mass(d)
        p = subprocess.run([ROVER, "--port", str(d.ws_port), "--model", MODEL],
                           capture_output=True, text=True, timeout=600)
        print(p.stdout, end="")
        check(p.returncode == 0, f"{name}: the rover ran ({p.returncode}: {p.stderr})")
        lines = [line for line in p.stdout.splitlines() if not line.startswith("speed:")]
        m = VERDICT.match(lines[-1]) if lines else None
        check(m is not None, f"{name}: a verdict line ({lines[-1:]})")
        after, tick = mass(d)
        check(after == before, f"{name}: Σh + Σcompacted exact ({before} -> {after})")
        if m:
            check(tick - tick0 == int(m.group(7)),
                  f"{name}: one tick per step ({tick - tick0} ticks, {m.group(7)} steps)")
        return m, lines, d.heights(0, 0, W, H)[1], tick


with tempfile.TemporaryDirectory(prefix="terrad-rover-") as tmp:
    snow = scene(tmp, "snow-us", 0.4)
    loam = scene(tmp, "sandy-loam", 0)

    with check.running(Daemon(name="wall-clock")) as d:
        p = subprocess.run([ROVER, "--port", str(d.ws_port), "--model", MODEL],
                           capture_output=True, text=True, timeout=120)
        check(p.returncode == 1 and "clock" in p.stderr,
              f"a wall-clock world is refused naming the clock ({p.returncode}: {p.stderr})")

    m, lines, heights, tick = drive(snow, "snow-1")
    if m:
        check(m.group(1) == "bogged", f"snow: the rover bogs down ({m.group(0)})")
        check(float(m.group(3)) > 1.0, f"snow: it stalls more than a metre short of the top "
                                       f"({m.group(3)} m)")
        check(float(m.group(4)) > 0.5, f"snow: its wheels spin (slip {m.group(4)})")
        check(float(m.group(5)) > float(m.group(6)),
              f"snow: it digs in (sinkage {m.group(6)} mm in second 2, {m.group(5)} mm at the end)")
    m2, lines2, heights2, tick2 = drive(snow, "snow-2", threads=1)
    check(lines2 == lines, "the same run twice prints the same lines (every simulated figure "
                           "and the digest of every step's state and forces)")
    check(heights2 == heights and tick2 == tick,
          f"the same run twice leaves the same heights at the same tick ({tick}, {tick2}; "
          f"{sum(a != b for a, b in zip(heights, heights2))} cells differ)")

    m, _, _, _ = drive(loam, "loam")
    if m:
        check(m.group(1) == "climbed", f"sandy loam: the rover climbs the ramp ({m.group(0)})")
check.finish()
