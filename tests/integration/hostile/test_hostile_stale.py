#!/usr/bin/python3
"""Staleness (issue 15, item 5): a client that reads steadily but too slowly
(one frame per 20 ms) used to fall behind by time, bounded only by bytes
(max_pending_bytes, 8 MiB): 54 s behind after 60 s. Now a client whose oldest
queued delta is more than limits.max_client_lag_ticks old is switched to
snapshots like one over max_pending_bytes, so what it reads stays within a
bound counted in ticks.

A real daemon (CPU backend, demo actors deforming the world, lag limit 30
ticks); the reader subscribes to the whole world with small socket buffers
and reads one frame per 20 ms for 16 s. Each frame that carries a tick
(DELTA, ACK, CONTACT, COLLIDERS) is compared with the daemon's tick
(/v1/stats, polled beside it). Over the last 4 s the lag, in ticks, must stay
under the limit plus what the reader needs to drain what is already past the
daemon's queue when it is switched: the kernel's socket buffers (the daemon
fixes its send buffer at 64 KiB, doubled by the kernel; the reader's are 8
KiB) and a snapshot frame, at the frame rate, delta frame size and tick rate
this run measured, plus two seconds. So the bound follows this machine's
speed; before the change the lag only grew (616 ticks after 12 s here, and
54 s after 60 s in the issue).
"""
# ctest-timeout: 600
import asyncio
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, TickWatch,  # noqa: E402
                             compare_with_server, metric_value, tp)

LAG_LIMIT = 30        # ticks (half a second at 60 Hz)
READ_S = 16.0         # seconds of slow reading
LAST_S = 4.0          # the lag is judged over the last seconds of it
BUFFERED = 2 * 64 * 1024 + 2 * 8192 + 2 * 4096  # kernel send + receive buffers, client's
TICKED = {tp.MsgType.DELTA, tp.MsgType.ACK, tp.MsgType.CONTACT, tp.MsgType.COLLIDERS}


def small_socket(port, rcvbuf=8192):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    s.connect(("127.0.0.1", port))
    s.setblocking(False)
    return s


async def slow_reader(check, d):
    w = d.world()
    W, H = w["width"], w["height"]
    # say_seen=False: this is the bound for a client that never says which tick it has handled
    # (PROTOCOL.md "seen"; test_hostile_lag has the one that does)
    c = RecordingClient(d.ws, name="slow-reader", keep=600, sock=small_socket(d.ws_port), say_seen=False,
                        max_queue=1, ping_interval=None, read_limit=4096, write_limit=4096)
    # the reader's pace: one frame per 20 ms, recording each ticked frame's lag
    lags = []
    read = {"frames": 0, "small": 0, "small_bytes": 0}
    watch = TickWatch(d)
    t0 = [None]
    orig = c._on_binary

    async def paced(data):
        await asyncio.sleep(0.02)
        if t0[0] is not None:
            read["frames"] += 1
            if len(data) < 65536:  # deltas and status frames, not snapshots
                read["small"] += 1
                read["small_bytes"] += len(data)
        if t0[0] is not None and len(data) >= 12 and data[2] in TICKED:
            (tick,) = struct.unpack_from("<Q", data, 4)
            lags.append((time.monotonic() - t0[0], watch.tick - tick))
        await orig(data)

    c._on_binary = paced
    await c.connect()
    got = c.world.get("limits", {}).get("max_client_lag_ticks")
    check(got == LAG_LIMIT, f"the world message's limits carry max_client_lag_ticks ({got})")
    sid = await c.subscribe(0, 0, W, H)
    wheel = await c.create_collider("sphere", radius=0.2)  # parked above the terrain: ACKs

    async def park():
        await c.send_poses([tp.Pose(wheel, 1.0, 1.0, 40.0)])

    t0[0] = time.monotonic()
    tick0 = watch.tick
    await asyncio.sleep(READ_S)
    watch.stop.set()
    tick_rate = (watch.tick - tick0) / READ_S
    frame_s = READ_S / max(read["frames"], 1)  # what one frame costs this reader
    mean = read["small_bytes"] / max(read["small"], 1)
    drain_s = (BUFFERED / max(mean, 1.0) + 2) * frame_s + 2.0  # buffers, a snapshot, slack
    bound = LAG_LIMIT + int(tick_rate * drain_s)
    last = [lag for t, lag in lags if t >= READ_S - LAST_S]
    worst = max(last) if last else None
    first = [lag for t, lag in lags if t < 2]
    print(f"info: {len(lags)} ticked frames read in {READ_S:.0f} s; lag in ticks: first 2 s max "
          f"{max(first) if first else None}, last {LAST_S:.0f} s max {worst} "
          f"(limit {LAG_LIMIT}, bound {bound}: {tick_rate:.1f} ticks/s, {frame_s * 1000:.1f} ms a "
          f"frame, {mean:.0f} bytes a delta frame)", flush=True)
    check(len(last) >= 1, f"the reader read ticked frames to the end ({len(last)})")
    check(worst is not None and worst <= bound,
          f"a steady slow reader stays within {bound} ticks of the daemon (worst {worst})")
    _, m = d.metrics()
    stale = metric_value(m, "terrad_clients_stale_total") or 0
    check(stale >= 1, f"terrad_clients_stale_total counts the switch ({stale})")
    check(any(" is stale (" in l and f"limit {LAG_LIMIT})" in l for l in d.lines),
          "the log names the stale client, its lag and the limit")

    # read at full speed again: the mirror is right. Under load (make test-stress) a Python
    # reader applying whole-world snapshots can take a while to come back within the lag
    # limit of half a second, so the catch-up waits by condition (ACKs flowing again), and
    # the comparison has a deadline of its own that ends well inside the ctest timeout with
    # a failure that says why.
    c._on_binary = orig
    loop = asyncio.get_running_loop()
    acks0, deadline = c.counts["ACK"], loop.time() + 120
    while c.counts["ACK"] < acks0 + 3 and loop.time() < deadline:
        await park()
        await asyncio.sleep(0.05)
    same, tick, detail = await compare_with_server(c, d, sid, (0, 0, W, H),
                                                   park, attempts=20, deadline_s=300)
    check(same, f"the reader's mirror equals GET /v1/heights afterwards (tick {tick}) {detail}")
    check(not c.ws.closed, "the reader's connection stayed open")
    await c.close()


def main():
    check = Checks()
    d = Daemon(demo=True, config={"limits": {"max_client_lag_ticks": LAG_LIMIT}})
    with check.running(d):
        asyncio.run(slow_reader(check, d))
    check.finish()


if __name__ == "__main__":
    main()
