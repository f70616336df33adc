#!/usr/bin/python3
"""Service figures for `make bench`: the real daemon on loopback with 1, 8
and 64 clients, each driving a wheel with a pose every tick (60 Hz) and
subscribed to its own 64 x 64 cell block, on the CPU backend and, when a GL
context can be made, the GL backend. For each run:

- delta bytes per tick and per client (DELTA frames as received);
- delta compression ratio (/metrics terrad_delta_raw_bytes_total over
  terrad_delta_compressed_bytes_total);
- pose-to-delta latency p50/p99: from sending a POSE_BATCH to receiving the
  first DELTA frame of the tick that used it (the ACK names that tick and
  the batch's sequence; when that tick changed nothing the client holds, the
  ACK's arrival is used and counted);
- tick time: mean and p99 (from the terrad_tick_duration_seconds histogram)
  and the tick rate reached.

Clients run in a few worker processes (asyncio each) so that Python is not
the bottleneck where avoidable; the achieved pose rate per client is printed
too. About two minutes in all. Prints a table naming the machine and the
renderer. Debian's /usr/bin/python3 with python3-websockets.
"""
import asyncio
import json
import math
import multiprocessing as mp
import os
import struct
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "support"))
from service_harness import Daemon, machine, metric_value  # noqa: E402

import terrad as tp  # noqa: E402

DRIVE_S = float(os.environ.get("TERRAD_BENCH_SECONDS", "5"))
CLIENTS = [int(x) for x in os.environ.get("TERRAD_BENCH_CLIENTS", "1,8,64").split(",")]
RADIUS = 0.3
BLOCK = 64


def blocks(n, world):
    W, H = world["width"], world["height"]
    per_row = W // BLOCK
    out = []
    for i in range(n):
        bx, by = (i % per_row) * BLOCK, ((i // per_row) % (H // BLOCK)) * BLOCK
        out.append((bx, by, BLOCK, BLOCK))
    return out


async def worker_main(ws_uri, specs, ground, world, start_at, hz):
    import websockets
    cell, units = world["cell_size_m"], world["units_per_m"]
    W = world["width"]
    results = []

    async def one(idx, region):
        ws = await websockets.connect(ws_uri, subprotocols=[tp.SUBPROTOCOL], max_size=1 << 24,
                                      ping_interval=None)
        await ws.send(json.dumps(tp.hello("", f"bench-{idx}")))
        await ws.recv()
        await ws.send(json.dumps(tp.collider_create("wheel", radius=RADIUS, width=0.2, ref="w")))
        wid = None
        while wid is None:
            m = json.loads(await ws.recv())
            if m.get("type") == "collider_created":
                wid = m["id"]
        await ws.send(json.dumps(tp.subscribe(*region, ref="s")))
        r = {"sent": 0, "delta_bytes": 0, "delta_frames": 0, "acks": 0, "lat": [], "lat_ack": 0,
             "errors": 0, "bytes_after_start": 0}
        sent_at = {}
        first_delta = {}
        driving = {"on": False}

        async def reader():
            try:
                async for data in ws:
                    now = time.monotonic()
                    if isinstance(data, str):
                        if json.loads(data).get("type") == "error":
                            r["errors"] += 1
                        continue
                    t = data[2]
                    if t == tp.MsgType.DELTA:
                        tick = struct.unpack_from("<Q", data, 4)[0]
                        first_delta.setdefault(tick, now)
                        if driving["on"]:
                            r["delta_bytes"] += len(data)
                            r["delta_frames"] += 1
                    elif t == tp.MsgType.ACK:
                        tick, seq = struct.unpack_from("<QI", data, 4)
                        r["acks"] += 1
                        s = sent_at.pop(seq, None)
                        if s is not None and driving["on"]:
                            got = first_delta.get(tick)
                            if got is None:
                                got = now
                                r["lat_ack"] += 1
                            r["lat"].append(got - s)
                        for old in [k for k in first_delta if k < tick - 120]:
                            del first_delta[old]
            except websockets.ConnectionClosed:
                pass

        rt = asyncio.get_running_loop().create_task(reader())
        x0, y0 = region[0], region[1]
        cxm, cym = (x0 + BLOCK / 2) * cell, (y0 + BLOCK / 2) * cell
        rad = BLOCK * cell * 0.3
        delay = start_at - time.time()
        if delay > 0:
            await asyncio.sleep(delay)
        driving["on"] = True
        t0 = time.monotonic()
        seq = 0
        k = 0
        while time.monotonic() - t0 < DRIVE_S:
            a = k / hz * 0.9 + idx
            x, y = cxm + rad * math.cos(a), cym + rad * math.sin(a)
            ci, cj = int(x / cell), int(y / cell)
            z = ground[cj * W + ci] / units + RADIUS - 0.05 if ground else 0.5
            yaw = a + math.pi / 2  # rolling along the circle: axle turned with the heading
            q = (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))
            seq += 1
            sent_at[seq] = time.monotonic()
            await ws.send(tp.encode_pose_batch(seq, [tp.Pose(wid, x, y, z, *q)]))
            r["sent"] += 1
            k += 1
            nxt = t0 + k / hz
            d = nxt - time.monotonic()
            if d > 0:
                await asyncio.sleep(d)
        r["drive_s"] = time.monotonic() - t0
        driving["on"] = False
        await asyncio.sleep(0.2)
        await ws.close()
        rt.cancel()
        results.append(r)

    await asyncio.gather(*(one(i, reg) for i, reg in specs))
    return results


def worker(args):
    return asyncio.run(worker_main(*args))


def percentile(v, p):
    if not v:
        return float("nan")
    v = sorted(v)
    return v[min(len(v) - 1, int(p / 100 * len(v)))]


def hist_p99(text, name):
    buckets = []
    for line in text.splitlines():
        if line.startswith(name + "_bucket{"):
            le = line.split('le="')[1].split('"')[0]
            buckets.append((float("inf") if le == "+Inf" else float(le), float(line.split()[-1])))
    return buckets


def run_case(backend, n):
    d = Daemon(backend=backend, name=f"bench-{backend}-{n}")
    try:
        world = d.world()
        # the world message's tick rate (the HTTP one may be 0 for "the scene's")
        hz = world.get("tick_hz") or 60
        W, H = world["width"], world["height"]
        _, ground = d.heights(0, 0, W, H)
        specs = list(enumerate(blocks(n, world)))
        nproc = max(1, min(len(specs), (os.cpu_count() or 2), 4))
        chunks = [specs[i::nproc] for i in range(nproc)]
        _, m0 = d.metrics()
        s0 = None
        start_at = time.time() + 2.0 + n * 0.02
        with mp.get_context("fork").Pool(nproc) as pool:
            async_res = pool.map_async(worker, [(d.ws, c, ground, world, start_at, hz) for c in chunks])
            time.sleep(max(0, start_at - time.time()))
            s0 = d.stats()
            _, m0 = d.metrics()
            t0 = time.monotonic()
            time.sleep(DRIVE_S)
            s1 = d.stats()
            _, m1 = d.metrics()
            t1 = time.monotonic()
            results = [r for chunk in async_res.get(120) for r in chunk]

        def dm(name):
            return (metric_value(m1, name) or 0) - (metric_value(m0, name) or 0)

        ticks = s1["tick"] - s0["tick"]
        raw, comp = dm("terrad_delta_raw_bytes_total"), dm("terrad_delta_compressed_bytes_total")
        tcount, tsum = dm("terrad_tick_duration_seconds_count"), dm("terrad_tick_duration_seconds_sum")
        b0 = {le: c for le, c in hist_p99(m0, "terrad_tick_duration_seconds")}
        b1 = hist_p99(m1, "terrad_tick_duration_seconds")
        tick_p99, prev = float("nan"), 0.0
        for le, c in b1:
            if tcount > 0 and c - b0.get(le, 0) >= 0.99 * tcount:
                tick_p99 = le if le != float("inf") else -prev  # negative: above the last bound
                break
            prev = le
        lat = [x for r in results for x in r["lat"]]
        lat_ack = sum(r["lat_ack"] for r in results)
        sent = sum(r["sent"] for r in results)
        drive_s = max(r.get("drive_s", DRIVE_S) for r in results) if results else DRIVE_S
        row = {
            "backend": backend, "renderer": world.get("renderer", backend), "clients": n,
            "tick_hz": ticks / (t1 - t0), "hz": hz,
            "pose_hz": sent / max(len(results), 1) / drive_s,
            "delta_b": sum(r["delta_bytes"] for r in results) / max(ticks, 1) / max(len(results), 1),
            "ratio": raw / comp if comp else float("nan"),
            "p50": percentile(lat, 50) * 1000, "p99": percentile(lat, 99) * 1000,
            "lat_n": len(lat), "lat_ack": lat_ack,
            "tick_ms": tsum / tcount * 1000 if tcount else float("nan"),
            "tick_p99": tick_p99 * 1000, "errors": sum(r["errors"] for r in results),
            "overruns": s1.get("overruns", 0) - s0.get("overruns", 0),
        }
        return row
    finally:
        d.stop()


def tick_bound(ms):
    if ms != ms:
        return "n/a"
    return f">{-ms:.0f}" if ms < 0 else f"<={ms:.0f}"


def main():
    rows = []
    t_start = time.monotonic()
    for backend in ("cpu", "gl"):
        for n in CLIENTS:
            try:
                rows.append(run_case(backend, n))
            except RuntimeError as e:
                if backend == "gl":
                    print(f"bench_service: GL backend not available here, skipped "
                          f"({str(e).strip().splitlines()[-1] if str(e).strip() else ''})")
                    break
                raise
            r = rows[-1]
            print(f"  {backend} {n:3d} clients: done ({time.monotonic() - t_start:.0f} s)", flush=True)
    print()
    print(f"terrad service bench: {machine()}; {DRIVE_S:g} s of driving per run, loopback")
    renderers = sorted({r["renderer"] for r in rows})
    for rn in renderers:
        print(f"  renderer: {rn}")
    hdr = (f"{'backend':7} {'clients':>7} {'ticks/s':>8} {'poses/s':>8} {'delta B/tick/client':>20} "
           f"{'compress':>9} {'p50 ms':>7} {'p99 ms':>7} {'tick ms':>8} {'tick p99':>9} {'overruns':>8}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(f"{r['backend']:7} {r['clients']:7d} {r['tick_hz']:8.1f} {r['pose_hz']:8.1f} "
              f"{r['delta_b']:20.0f} {r['ratio']:8.1f}x {r['p50']:7.1f} {r['p99']:7.1f} "
              f"{r['tick_ms']:8.2f} {tick_bound(r['tick_p99']):>9} {r['overruns']:8d}")
    print("(poses/s: per client, sent; latency: pose sent -> first DELTA of the tick that used it, "
          "or its ACK when that tick changed nothing the client holds: "
          + ", ".join(f"{r['backend']}/{r['clients']}: {r['lat_ack']} of {r['lat_n']}" for r in rows)
          + "; tick p99: histogram bucket bound)")
    errors = sum(r["errors"] for r in rows)
    if errors:
        print(f"bench_service: {errors} error messages from the server during the runs")


if __name__ == "__main__":
    main()
