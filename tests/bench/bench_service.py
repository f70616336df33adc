#!/usr/bin/python3
"""Service figures for `make bench`: the real daemon on loopback (CPU backend,
`--durability every-tick`, 60 Hz) driven by `terrad loadgen` (C, one process,
non-blocking sockets, on the same machine) with 1, 8, 64 and 256 wheels: one
wheel per client up to 64 clients, then 64 clients with 4 wheels each. Each
client drives its wheels in circles inside its own 64 x 64 cell block with a
POSE_BATCH every tick, subscribed to that block, keeping a mirror.

For each run, from loadgen's JSON: ticks/s reached (the server's tick
counter), pose->ACK latency p50/p99/max (a POSE_BATCH sent -> the ACK of the
tick that used it, which comes after every DELTA of that tick), delta bytes
per tick and per changed cell, frames dropped and resyncs, and whether every
mirror equals GET /v1/heights at the end, and the server's mean tick time
while driving (terrad_tick_duration_seconds). Anchors (issue 10): 64 wheels >= 59 ticks/s and
p99 <= 33 ms (2 ticks at 60 Hz); 256 wheels: printed. Never fails on a
figure. TERRAD_BENCH_SECONDS (default 5), TERRAD_BENCH_WHEELS ("1,8,64,256"),
TERRAD_BENCH_BACKENDS ("cpu"; "cpu,gl" adds the GL backend where a context can
be made).
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import BIN, Daemon, machine  # noqa: E402

DRIVE_S = float(os.environ.get("TERRAD_BENCH_SECONDS", "5"))
WHEELS = [int(x) for x in os.environ.get("TERRAD_BENCH_WHEELS", "1,8,64,256").split(",")]
BACKENDS = os.environ.get("TERRAD_BENCH_BACKENDS", "cpu").split(",")
ANCHORS = {64: (59.0, 33.0)}  # wheels: (ticks/s at least, p99 ms at most)


def layout(wheels):
    """(clients, wheels per client): a client per wheel up to 64 blocks of the 512^2 world."""
    clients = min(wheels, 64)
    return clients, max(1, wheels // clients)


def daemon_cpu_s(pid):
    """User + system CPU seconds of a process so far (/proc/PID/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_case(backend, wheels):
    clients, per = layout(wheels)
    d = Daemon(backend=backend, name=f"bench-{backend}-{wheels}", durability="every-tick")
    try:
        cpu0, t0 = daemon_cpu_s(d.pid), time.monotonic()
        p = subprocess.run([BIN, "loadgen", "--url", d.ws, "--http", d.http, "--clients",
                            str(clients), "--wheels-per-client", str(per), "--seconds",
                            str(DRIVE_S), "--json"], capture_output=True, text=True,
                           timeout=DRIVE_S * 4 + 180)
        if not p.stdout.strip().startswith("{"):
            raise RuntimeError(f"loadgen failed ({p.returncode}): {p.stderr}")
        r = json.loads(p.stdout)
        # the daemon's own CPU time per second of the run (user + system, all its threads):
        # what the load of other jobs changes least
        r["daemon_cpu_share"] = (daemon_cpu_s(d.pid) - cpu0) / (time.monotonic() - t0)
        r["load"] = os.getloadavg()[0]

        r["tick_ms"] = r["tick_mean_ms"]
        r["backend"] = backend
        r["renderer"] = d.world().get("renderer", backend)
        r["stderr"] = p.stderr.strip()
        return r
    finally:
        d.stop()


def main():
    rows = []
    t_start = time.monotonic()
    for backend in BACKENDS:
        for w in WHEELS:
            try:
                rows.append(run_case(backend, w))
            except RuntimeError as e:
                if backend == "gl":
                    print(f"bench_service: GL backend not available here, skipped "
                          f"({str(e).strip().splitlines()[-1] if str(e).strip() else ''})")
                    break
                raise
            print(f"  {backend} {w:3d} wheels: done ({time.monotonic() - t_start:.0f} s)",
                  flush=True)
    print()
    print(f"terrad service bench: {machine()}; `terrad loadgen` on the same machine; "
          f"{DRIVE_S:g} s of driving per run, loopback, --durability every-tick, 60 Hz")
    for rn in sorted({r["renderer"] for r in rows}):
        print(f"  renderer: {rn}")
    hdr = (f"{'backend':7} {'wheels':>6} {'clients':>7} {'ticks/s':>8} {'p50 ms':>7} "
           f"{'p99 ms':>7} {'max ms':>7} {'tick ms':>8} {'overruns':>8} {'B/tick':>8} "
           f"{'B/cell':>7} {'dropped':>7} {'resyncs':>7} {'mirrors':>7} {'CPU/s':>6} {'load':>5}  anchor")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        lat = r["latency_ms"]
        a = ANCHORS.get(r["wheels"])
        if a:
            ok = r["ticks_per_s"] >= a[0] and lat["p99"] <= a[1]
            anchor = f">= {a[0]:g} ticks/s, p99 <= {a[1]:g} ms: {'met' if ok else 'NOT met'}"
        else:
            anchor = "(printed)"
        print(f"{r['backend']:7} {r['wheels']:6d} {r['clients']:7d} {r['ticks_per_s']:8.1f} "
              f"{lat['p50']:7.1f} {lat['p99']:7.1f} {lat['max']:7.1f} {r['tick_ms']:8.2f} "
              f"{r['overruns']:8d} {r['delta_bytes_per_tick']:8.0f} "
              f"{r['delta_bytes_per_changed_cell']:7.2f} {r['frames_dropped']:7d} "
              f"{r['resyncs']:7d} {'equal' if r['mirrors_equal'] else 'DIFFER':>7} "
              f"{r['daemon_cpu_share']:6.2f} {r['load']:5.1f}  {anchor}")
    print("(latency: POSE_BATCH sent -> the ACK of the tick that used it, after that tick's "
          "DELTAs; B/cell: delta bytes per mirror cell a DELTA changed; tick ms: the server's mean "
          "tick while driving, from terrad_tick_duration_seconds; CPU/s: the daemon's CPU seconds (all "
          "threads) per second of the run; load: the 1-minute load average at its end, on "
          f"{os.cpu_count()} cores shared with whatever else runs)")
    for r in rows:
        if not r["mirrors_equal"] or r["failed_clients"]:
            print(f"bench_service: {r['backend']}/{r['wheels']}: mirrors "
                  f"{r['mirrors_equal_count']} of {r['mirrors_checked']} equal, "
                  f"{r['failed_clients']} clients failed: {r['stderr'][-500:]}")


if __name__ == "__main__":
    main()
