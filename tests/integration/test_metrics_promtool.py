#!/usr/bin/python3
# ctest-timeout: 120
"""GET /metrics of the real daemon (CPU backend, demo actors, a client that
drives a wheel and sends one bad frame) passes `promtool check metrics`
(Debian's prometheus package), is served as the Prometheus text format, and
has the families issue 3 asks for: tick and stage durations, active cells,
colliders, clients, bytes in and out, delta compression, coalesced and
dropped frames, refused messages by reason, Σh. Exits 77 (skip) without
promtool.
"""
import asyncio
import os
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, Checks, Daemon, metric_value, skip  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
FAMILIES = [
    "terrad_tick_duration_seconds", "terrad_stage_duration_seconds", "terrad_active_cells",
    "terrad_colliders", "terrad_clients", "terrad_bytes_in_total", "terrad_bytes_out_total",
    "terrad_delta_raw_bytes_total", "terrad_delta_compressed_bytes_total",
    "terrad_frames_coalesced_total", "terrad_frames_dropped_total",
    "terrad_refused_messages_total", "terrad_volume_units", "terrad_tick",
]


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
    check.finish()


if __name__ == "__main__":
    asyncio.run(main())
