#!/usr/bin/python3
"""Desync detection and repair (PROTOCOL.md "CHECKSUM"; issue 32 item 4), for `make bench`: a
real daemon on loopback (--backend cpu, six demo actors digging, so deltas flow meanwhile) and
the Python client. Printed:

- corruption to repair: REPEATS times, one height of the client's mirror changed on purpose in
  a 512 x 128 window; seconds until the client has found the tile differing, asked for it and
  holds it again from its snapshot (p50, max). It waits for the next CHECKSUM (every
  checksum_interval_ticks, 0.5 s at 60 Hz: 0.25 s on average), then a tick and the snapshot's
  round trip.
- CHECKSUM bytes per second per window, over MEASURE_S seconds, for a 512 x 128 window (16
  tiles) and a 256 x 256 one (16 tiles): 18 + 20 bytes per tile, twice a second at 60 Hz.

Anchor: the issue's "repaired within a second". Never fails on a figure. TERRAD_BENCH_REPEATS
(default 10), TERRAD_BENCH_SECONDS (default 10).
"""
import asyncio
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import Daemon, machine, tp  # noqa: E402

REPEATS = int(os.environ.get("TERRAD_BENCH_REPEATS", "10"))
MEASURE_S = float(os.environ.get("TERRAD_BENCH_SECONDS", "10"))
WINDOWS = {"512 x 128": (0, 192, 512, 128), "256 x 256": (128, 128, 256, 256)}


class Counting(tp.Client):
    """Counts the CHECKSUM frames' bytes per subscription."""

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        self.checksum_bytes = {}

    async def _on_binary(self, data):
        if tp.decode_header(data) == tp.MsgType.CHECKSUM:
            sid = tp.decode_checksum(data)[1]
            self.checksum_bytes[sid] = self.checksum_bytes.get(sid, 0) + len(data)
        await super()._on_binary(data)


async def bench(d):
    async with Counting(d.ws) as c:
        sids = {name: await c.subscribe(*w) for name, w in WINDOWS.items()}
        for sid in sids.values():
            await c.wait_complete(sid, timeout=120)
        base = dict(c.checksum_bytes)
        t0 = time.monotonic()
        await asyncio.sleep(MEASURE_S)
        span = time.monotonic() - t0
        rates = {n: (c.checksum_bytes.get(s, 0) - base.get(s, 0)) / span for n, s in sids.items()}
        sid = sids["512 x 128"]
        m = c.mirrors[sid]
        times = []
        for i in range(REPEATS):
            asked = c.desync["tiles_resynced"]
            k = (37 * i % 128) * 512 + (101 * i % 512)
            m.heights[k] = tp.wrap32(m.heights[k] + 5)
            t = time.monotonic()
            await c.wait_for(lambda: c.desync["tiles_resynced"] > asked and m.complete, 60)
            times.append(time.monotonic() - t)
        return rates, times


def main():
    load = os.getloadavg()[0]
    with_demo = Daemon(demo=True)
    try:
        rates, times = asyncio.run(bench(with_demo))
    finally:
        with_demo.stop()
    print(f"desync repair, Python client, six demo actors digging; {machine()}, load {load:.1f}")
    print(f"  corruption to repair ({REPEATS} times, 512 x 128 window): p50 {statistics.median(times):.3f} s, "
          f"max {max(times):.3f} s   (anchor: within 1 s)")
    for name, r in rates.items():
        print(f"  CHECKSUM bytes per second, {name} window: {r:.0f} B/s")


if __name__ == "__main__":
    main()
