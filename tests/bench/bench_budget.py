#!/usr/bin/python3
"""bench_budget: bandwidth budgets per player (issue 32 item 1; PROTOCOL.md "Budgets").

One real daemon (--backend cpu, memory only) on the match-sized scene
tests/scenes/thesis-car.json (1024 x 1024 cells of 4.88 cm, flat snow, 60 Hz);
`terrad loadgen --clients 8 --wheels-per-client 1` (C) drives 8 wheels on
circles, each in its own 64 x 64 block of the first block row, a POSE_BATCH
every tick, for DRIVE_S seconds (60 unless TERRAD_BENCH_BUDGET_S says). Four
watchers (the Python client, one websocket each) subscribe to the same
512 x 128-cell window (65,536 cells, every vehicle in view), each with its own
budget: 10,000, 32,000 and 64,000 bytes/s and none, their focus at the
window's centre. For each:

  - bytes/s received, per whole second of the drive: p50 and p99 (client
    side: payload plus websocket header, as the server counts them);
  - the visual error, twice a second while driving: its mirror against
    GET /v1/heights of the window read at that moment (cells differing, and
    the largest height difference in mm; the unbudgeted watcher's figure is
    what reading the server and the mirror at slightly different ticks costs);
  - once loadgen has stopped and the terrain has settled (two /v1/heights
    reads 0.25 s apart equal): seconds until its mirror equals it.

Goal (the issue): <= 10 kB/s p99 with 8 vehicles in view, and the mirror exact
within 1 s of the terrain settling. Anchor: 61.6 KiB/s mean, 74.8 KiB/s p99
for one such watcher without a budget (2026-11-29). Prints, never fails.
"""
import asyncio
import os
import re
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import BIN, SOURCE, CountingClient, Daemon, machine, metric_value  # noqa: E402

DRIVE_S = float(os.environ.get("TERRAD_BENCH_BUDGET_S", "60"))
SCENE = os.path.join(SOURCE, "tests/scenes/thesis-car.json")
WINDOW = (0, 0, 512, 128)
BUDGETS = [10000, 32000, 64000, None]


class Watcher(CountingClient):
    """Counts the bytes of every frame (as the server does: wire_bytes) into one-second bins."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.bins = {}
        self.t0 = None

    def counted(self, n):
        if self.t0 is not None:
            k = int(time.monotonic() - self.t0)
            self.bins[k] = self.bins.get(k, 0) + n


def error_of(mirror, server, units_per_m):
    diff = [abs(a - b) for a, b in zip(mirror, server) if a != b]
    return len(diff), (max(diff) / units_per_m * 1000 if diff else 0.0)


def pct(values, p):
    s = sorted(values)
    return s[min(len(s) - 1, int(p * (len(s) - 1) + 0.5))] if s else 0


async def run(d):
    loop = asyncio.get_running_loop()
    watchers = []
    for b in BUDGETS:
        w = Watcher(d.ws, name=f"watch-{b or 'none'}", budget=b)
        await w.connect()
        await w.focus(WINDOW[0] + WINDOW[2] / 2, WINDOW[1] + WINDOW[3] / 2)
        w.sid = await w.subscribe(*WINDOW)
        watchers.append(w)
    for w in watchers:
        await w.wait_complete(w.sid, 120)
    units = watchers[0].world.get("units_per_m", 10000)
    loadgen = subprocess.Popen(
        [BIN, "loadgen", "--url", d.ws, "--http", d.http, "--clients", "8",
         "--wheels-per-client", "1", "--seconds", str(DRIVE_S)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    start = time.monotonic()
    for w in watchers:
        w.t0 = start
    errors = {id(w): [] for w in watchers}
    while loadgen.poll() is None:
        await asyncio.sleep(0.5)
        _, server = await loop.run_in_executor(None, d.heights, *WINDOW)
        for w in watchers:
            errors[id(w)].append(error_of(list(w.mirrors[w.sid].heights), server, units))
    drive = time.monotonic() - start
    _, err = loadgen.communicate()
    # settled: two reads a quarter second apart agree
    _, prev = d.heights(*WINDOW)
    while True:
        await asyncio.sleep(0.25)
        _, now = await loop.run_in_executor(None, d.heights, *WINDOW)
        if now == prev:
            break
        prev = now
    settled = time.monotonic()
    exact = {}
    while len(exact) < len(watchers) and time.monotonic() - settled < 120:
        for w in watchers:
            if id(w) not in exact and list(w.mirrors[w.sid].heights) == now:
                exact[id(w)] = time.monotonic() - settled
        await asyncio.sleep(0.05)
    for w in watchers:
        await w.close()
    # the server's own accounting: each budgeted client's fullest second, logged as it leaves
    fullest = {}
    end = time.monotonic() + 20
    while len(fullest) < sum(1 for b in BUDGETS if b) and time.monotonic() < end:
        for line in d.lines:
            m = re.search(r"client (\d+) \([^)]*\): budget \d+ bytes/s, \d+ bytes sent, the fullest "
                          r"second held (\d+)", line)
            if m:
                fullest[int(m.group(1))] = int(m.group(2))
        await asyncio.sleep(0.2)
    overruns = metric_value(d.metrics()[1], "terrad_budget_overruns_total")
    print(f"bench_budget: {machine()}, load {os.getloadavg()[0]:.1f}; thesis-car 1024^2, "
          f"8 wheels driven by terrad loadgen for {drive:.0f} s at 60 Hz in a "
          f"{WINDOW[2]} x {WINDOW[3]} window ({WINDOW[2] * WINDOW[3]} cells)", flush=True)
    if loadgen.returncode:
        print(f"  loadgen exited {loadgen.returncode}: {err.strip()[-300:]}", flush=True)
    print("  bytes/s as the watcher received them (per whole second, client side: a loaded "
          "machine's reader bunches them) and the server's fullest second (its own accounting)",
          flush=True)
    print(f"  {'budget B/s':>10} {'p50 B/s':>9} {'p99 B/s':>9} {'mean B/s':>9} {'server max':>10} "
          f"{'cells off p50/max':>17} {'max err mm':>10} {'exact after settling':>21}",
          flush=True)
    for b, w in zip(BUDGETS, watchers):
        secs = [w.bins.get(k, 0) for k in range(int(drive))]
        cells = [c for c, _ in errors[id(w)]]
        mm = max((m for _, m in errors[id(w)]), default=0.0)
        ex = exact.get(id(w))
        server_max = fullest.get(w.world.get("client_id"), "-") if b else "-"
        print(f"  {b or 'none':>10} {pct(secs, 0.5):>9} {pct(secs, 0.99):>9} "
              f"{statistics.mean(secs) if secs else 0:>9.0f} {server_max:>10} "
              f"{pct(cells, 0.5):>8}/{max(cells, default=0):<8} {mm:>10.1f} "
              f"{(f'{ex:.2f} s' if ex is not None else 'not in 120 s'):>21}", flush=True)
    print(f"  terrad_budget_overruns_total {overruns:.0f}", flush=True)
    print("  goal: <= 10 kB/s p99 with 8 vehicles in view, exact within 1 s of settling; "
          "anchor: 61.6 KiB/s mean, 74.8 KiB/s p99 without a budget (2026-11-29)", flush=True)


def main():
    d = Daemon(backend="cpu", extra=["--no-data", "--scene", SCENE])
    try:
        asyncio.run(run(d))
    except Exception as e:  # noqa: BLE001 - a bench prints, never fails
        print(f"bench_budget: {e!r}", flush=True)
    finally:
        d.stop()


if __name__ == "__main__":
    main()
