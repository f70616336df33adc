#!/usr/bin/python3
# ctest-timeout: 300
"""`terrad loadgen` against a real daemon on loopback.

A few C clients (the C client library, one process, non-blocking sockets) each drive two wheels
for a few seconds, subscribed to their own blocks; at the end every client's mirror must equal
the daemon's GET /v1/heights of its block, and the JSON report must carry every figure; with
--worlds the clients join worlds created by POST /v1/worlds, each mirror compared with its own. The
figures themselves are printed, never judged (speed belongs to `make bench`). Usage errors exit 2.
"""
import json
import os
import subprocess
import sys
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon  # noqa: E402

check = Checks()

KEYS = ["clients", "wheels_per_client", "wheels", "tick_hz", "seconds", "ticks", "ticks_per_s",
        "overruns", "tick_mean_ms", "poses_sent", "latency_ms", "delta_frames", "delta_bytes",
        "delta_bytes_per_tick", "changed_cells", "delta_bytes_per_changed_cell",
        "frames_dropped", "resyncs", "failed_clients", "mirrors_checked", "mirrors_equal_count",
        "mirrors_equal"]


def loadgen(d, *extra, timeout=180):
    args = [BIN, "loadgen", "--url", d.ws, "--http", d.http] + list(extra)
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout)


with check.running(Daemon(name="loadgen", durability="every-tick")) as d:
    p = loadgen(d, "--clients", "3", "--wheels-per-client", "2", "--seconds", "3", "--json")
    print(p.stdout, p.stderr, sep="", end="")
    check(p.returncode == 0, f"loadgen exits 0 (got {p.returncode})")
    r = json.loads(p.stdout) if p.stdout.strip().startswith("{") else {}
    check(all(k in r for k in KEYS), f"the JSON has every figure (missing {[k for k in KEYS if k not in r]})")
    lat = r.get("latency_ms", {})
    check(all(k in lat for k in ("n", "p50", "p99", "max")), f"latency has n, p50, p99, max: {lat}")
    check(r.get("clients") == 3 and r.get("wheels") == 6, "3 clients with 2 wheels each")
    check(r.get("mirrors_equal") is True and r.get("mirrors_checked") == 3
          and r.get("mirrors_equal_count") == 3, "every mirror equals GET /v1/heights at the end")
    check(r.get("failed_clients") == 0, "no client failed")
    check(r.get("ticks", 0) > 0 and lat.get("n", 0) > 0, "ticks passed and ACKs were timed")
    check(lat.get("p50", -1) <= lat.get("p99", -1) <= lat.get("max", -1), "p50 <= p99 <= max")
    # the server's mean tick while driving: a duration, read from /metrics before and after
    check(0 < r.get("tick_mean_ms", -1) < 1000 * r.get("seconds", 0),
          f"tick_mean_ms is a plausible mean tick: {r.get('tick_mean_ms')}")
    check(r.get("changed_cells", 0) > 0 and r.get("delta_bytes", 0) > 0,
          "the wheels deformed the blocks and deltas arrived")

    p = loadgen(d, "--clients", "1", "--seconds", "1")
    check(p.returncode == 0 and "mirrors equal          true" in p.stdout,
          f"the table form says the mirror is equal:\n{p.stdout}{p.stderr}")

    # --worlds: the clients join created worlds (the C client's terrad_client_connect_world),
    # and each mirror is compared with GET /v1/heights?world= of its own world
    for name in ("lg0", "lg1"):
        scene = {"name": name, "world": {"width": 128, "height": 128, "cell_size_m": 0.05},
                 "terrain": {"kind": "flat", "height_m": 0.5}}
        req = urllib.request.Request(d.http + "/v1/worlds", method="POST",
                                     data=json.dumps({"name": name, "scene": scene}).encode())
        with urllib.request.urlopen(req, timeout=120) as a:
            check(a.status == 201, f"world {name} created")
    p = loadgen(d, "--clients", "2", "--worlds", "2", "--world-prefix", "lg", "--seconds", "2",
                "--json")
    r = json.loads(p.stdout) if p.stdout.strip().startswith("{") else {}
    check(p.returncode == 0 and r.get("mirrors_equal") is True and r.get("mirrors_checked") == 2
          and r.get("failed_clients") == 0 and r.get("changed_cells", 0) > 0,
          f"--worlds 2: clients in created worlds deform them, mirrors equal:\n{p.stdout}{p.stderr}")

    for bad in (["--clients", "0"], ["--frobnicate"], ["--url", "http://x"]):
        p = subprocess.run([BIN, "loadgen"] + bad, capture_output=True, text=True, timeout=30)
        check(p.returncode == 2 and "loadgen" in p.stderr, f"{bad} is a usage error: {p.stderr!r}")

    # nobody listening on the HTTP port given: a clear message and exit 1, not a hang
    p = subprocess.run([BIN, "loadgen", "--url", d.ws, "--http", "http://127.0.0.1:1",
                        "--seconds", "1"], capture_output=True, text=True, timeout=60)
    check(p.returncode == 1 and "no answer" in p.stderr, f"unreachable HTTP: {p.returncode} {p.stderr!r}")

check.finish()
