#!/usr/bin/python3
# ctest-timeout: 120
"""GET /metrics of the real daemon (CPU backend, demo actors, a client that
drives a wheel and sends one bad frame) passes `promtool check metrics`
(Debian's prometheus package), is served as the Prometheus text format, and
has the families issue 3 asks for: tick and stage durations, active cells,
colliders, clients, bytes in and out, delta compression, coalesced and
dropped frames, refused messages by reason, Σh; terrad_build_info with the
version of CMakeLists.txt's project() (also in --version and /v1/world) and
the standard process_* metrics, checked against /proc/<pid>. Exits 77 (skip)
without promtool.
"""
import asyncio
import os
import re
import shutil
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, metric_value, skip  # noqa: E402
from waiting import wait_for  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
FAMILIES = [
    "terrad_tick_duration_seconds", "terrad_stage_duration_seconds", "terrad_active_cells",
    "terrad_colliders", "terrad_clients", "terrad_bytes_in_total", "terrad_bytes_out_total",
    "terrad_delta_raw_bytes_total", "terrad_delta_compressed_bytes_total",
    "terrad_frames_coalesced_total", "terrad_frames_dropped_total",
    "terrad_refused_messages_total", "terrad_volume_units", "terrad_tick", "terrad_build_info",
    "process_cpu_seconds_total", "process_start_time_seconds", "process_resident_memory_bytes",
    "process_virtual_memory_bytes", "process_open_fds", "process_max_fds",
]


def cmake_version():
    """The version set once, in CMakeLists.txt's project() line."""
    root = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "..")
    with open(os.path.join(root, "CMakeLists.txt")) as f:
        return re.search(r"project\(terrad VERSION (\d+\.\d+\.\d+)", f.read()).group(1)


async def traffic(d):
    c = tp.TerradClient(d.ws, name="metrics-test")
    await c.connect()
    wheel = await c.create_collider("wheel", radius=0.3, width=0.2)
    await c.subscribe(0, 0, 128, 128)
    for i in range(60):
        await c.send_poses([tp.Pose(wheel, 1.0 + i * 0.05, 3.0, 0.55, 0.7071, 0.0, 0.0, 0.7071)])
        await asyncio.sleep(1 / 60)
    await c.ws.send(b"T")  # one refused frame, so the labelled counter has a sample
    await asyncio.sleep(0.3)
    return c


async def main():
    promtool = shutil.which("promtool") or ("/usr/bin/promtool" if os.access("/usr/bin/promtool", os.X_OK) else None)
    if not promtool:
        skip("promtool not found (apt-get install prometheus)")
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    d = Daemon(backend="cpu", demo=True, name="terrad-metrics")
    with check.running(d):
        c = await traffic(d)
        # more than 10 ticks behind us however slowly a loaded machine ticks (a condition)
        wait_for(lambda: d.stats()["tick"] > 11, 60)
        status, body, headers = d.get("/metrics")
        await c.close()
        text = body.decode("utf-8", "replace")
        check(status == 200, f"GET /metrics: {status}")
        ctype = headers.get("Content-Type", "")
        check(ctype.startswith("text/plain") and "version=0.0.4" in ctype,
              f"Content-Type is the text exposition format: {ctype!r}")
        r = subprocess.run([promtool, "check", "metrics"], input=body, capture_output=True, timeout=30)
        out = (r.stdout + r.stderr).decode("utf-8", "replace").strip()
        check(r.returncode == 0, f"promtool check metrics exits 0 (got {r.returncode}): {out[:2000]}")
        for fam in FAMILIES:
            check(f"# TYPE {fam} " in text, f"/metrics has the family {fam}")
        check(metric_value(text, "terrad_refused_messages_total", {"reason": "bad_frame"}) == 1,
              "terrad_refused_messages_total{reason=\"bad_frame\"} counts the one bad frame")
        vol = d.stats()["volume"]
        check(metric_value(text, "terrad_volume_units") == float(vol),
              f"terrad_volume_units is Σh ({metric_value(text, 'terrad_volume_units')} vs {vol})")
        check((metric_value(text, "terrad_tick_duration_seconds_count") or 0) > 10,
              "the tick histogram counts ticks")
        version = cmake_version()
        check(metric_value(text, "terrad_build_info", {"version": version}) == 1,
              f"terrad_build_info{{version=\"{version}\"}} 1")
        check(d.world().get("version") == version, f"/v1/world says version {version}")
        r = subprocess.run([BIN, "--version"], capture_output=True, text=True, timeout=30)
        check(r.stdout.strip() == f"terrad {version}", f"terrad --version: {r.stdout!r}")
        # the process_* figures are this daemon's own, from /proc/<pid>
        with open(f"/proc/{d.pid}/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/stat") as f:
            btime = next(int(x.split()[1]) for x in f if x.startswith("btime "))
        started = btime + start_ticks / os.sysconf("SC_CLK_TCK")
        check(abs(metric_value(text, "process_start_time_seconds") - started) < 1,
              f"process_start_time_seconds is the daemon's start ({started})")
        check(abs(time.time() - started) < 3600, "... which is recent")
        fds = len(os.listdir(f"/proc/{d.pid}/fd"))
        check(0 < metric_value(text, "process_open_fds") <= fds + 8,
              f"process_open_fds counts the daemon's descriptors (~{fds})")
        rss = d.rss_kb() * 1024
        check(rss / 4 < metric_value(text, "process_resident_memory_bytes") < rss * 4,
              f"process_resident_memory_bytes is the daemon's RSS (~{rss})")
        check(metric_value(text, "process_virtual_memory_bytes") >=
              metric_value(text, "process_resident_memory_bytes"), "virtual >= resident")
        check(metric_value(text, "process_cpu_seconds_total") > 0, "process_cpu_seconds_total > 0")
        check(metric_value(text, "process_max_fds") >= 64, "process_max_fds is the fd limit")
    check.finish()


if __name__ == "__main__":
    asyncio.run(main())
