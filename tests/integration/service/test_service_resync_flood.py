#!/usr/bin/python3
"""A resync flood from one client does not stall the others (issue 15, item 2).

One client subscribes 16 times to the whole world and sends two `resync`s at
once 10 times a second (well within its message limit); each resync asks for 16
whole-world snapshots. Meanwhile another client drives a wheel. Asserted
(behaviour, never a rate): the other client's ACKs keep coming for
advancing ticks while the flood goes on; the daemon's ticks advance; the
flooder's identical pending requests are coalesced or deferred (counted in
/metrics) instead of each being built inside the tick; the flooder is still
served (its mirrors complete once it stops); and a client that leaves with
requests pending has them dropped, not built.
"""
# ctest-timeout: 300
import asyncio
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, RecordingClient, metric_value, skip, tp, wheel_pose  # noqa: E402

check = Checks()
FLOOD_S = 6.0


FLOODER = r"""
import asyncio, json, sys, time
import websockets
uri, W, H, seconds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4])
async def main():
    async with websockets.connect(uri, subprotocols=["terrad.v1"], max_size=1 << 26) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol": 1, "token": "", "client": "flooder"}))
        await ws.recv()
        for _ in range(16):
            await ws.send(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": W, "h": H}))
        async def drain():  # read everything, decode nothing: the flooder costs the daemon, not us
            try:
                async for _ in ws:
                    pass
            except websockets.ConnectionClosed:
                pass
        reader = asyncio.get_running_loop().create_task(drain())
        sent, end = 0, time.time() + seconds
        while time.time() < end:
            # two at once: the second always finds the first's requests pending (whatever the
            # machine's speed), which a lone resync every 0.1 s did not on a loaded machine
            for _ in range(2):
                await ws.send(json.dumps({"type": "resync"}))
                sent += 1
            await asyncio.sleep(0.1)
        print(sent, flush=True)
        await ws.close()
        await reader
asyncio.run(main())
"""


async def scenario(d):
    w = d.world()
    W, H = w["width"], w["height"]
    proto_version = w.get("protocol", 1)
    flooder = await asyncio.create_subprocess_exec(
        sys.executable, "-c", FLOODER.replace('"protocol": 1', f'"protocol": {proto_version}'),
        d.ws, str(W), str(H), str(FLOOD_S), stdout=asyncio.subprocess.PIPE)

    good = RecordingClient(d.ws, name="good", record=False)
    await good.connect()
    await good.subscribe(0, 0, 64, 64)
    wheel = await good.create_collider("cylinder", radius=0.3, half_length=0.1)
    acked = []
    good.on_ack = lambda t, s: acked.append(t)

    stop = asyncio.Event()

    async def drive():
        x = 2.0
        while not stop.is_set():
            x = 2.0 + (x - 1.9) % 3.0
            await good.send_poses([wheel_pose(wheel, x, 2.0, 50.0)])
            await asyncio.sleep(1 / 60)

    tick0 = d.stats()["tick"]
    drive_task = asyncio.create_task(drive())
    await asyncio.sleep(FLOOD_S / 2)
    half = list(acked)
    await asyncio.sleep(FLOOD_S / 2)
    during = list(acked)
    tick1 = d.stats()["tick"]
    metrics = d.metrics()[1]
    out, _ = await flooder.communicate()
    stop.set()
    await drive_task
    sent = int(out.decode().strip() or 0)

    check(tick1 > tick0, f"ticks advance during the flood ({tick0} -> {tick1})")
    late = during[len(half):]
    check(len(half) > 0 and len(late) > 0 and max(late) > max(half),
          f"the other client's ACKs keep coming for advancing ticks during the flood "
          f"({len(half)} then {len(late)} ACKs)")
    check(all(b >= a for a, b in zip(during, during[1:])), "its ACK ticks never go backwards")
    coalesced = metric_value(metrics, "terrad_snapshot_requests_coalesced_total")
    deferred = metric_value(metrics, "terrad_snapshot_requests_deferred_total")
    print(f"info: {sent} resyncs sent in {FLOOD_S} s; coalesced {coalesced}, deferred {deferred}; "
          f"ticks {tick0} -> {tick1}; {len(during)} ACKs for the other client", flush=True)
    check(coalesced is not None and deferred is not None,
          "terrad_snapshot_requests_coalesced_total and _deferred_total are in /metrics")
    check((coalesced or 0) + (deferred or 0) > 0,
          f"the flood's requests are coalesced or deferred ({coalesced}, {deferred})")

    # a client subscribed to the whole world is served after the flood
    after = RecordingClient(d.ws, name="after", record=False)
    await after.connect()
    sid = await after.subscribe(0, 0, W, H)
    await after.wait_for(lambda: after.mirrors[sid].complete, 120)
    check(True, "a new whole-world subscription completes after the flood")
    await after.close()

    # a client that leaves with requests pending: they are dropped, not built
    leaver = RecordingClient(d.ws, name="leaver", record=False)
    await leaver.connect()
    for _ in range(8):
        await leaver.subscribe(0, 0, W, H)
    for _ in range(20):
        await leaver.resync()
    await leaver.close()
    await good.close()


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    d = Daemon(backend="cpu", name="terrad-resync-flood")
    with check.running(d):
        asyncio.run(scenario(d))
        deadline = time.time() + 120
        dropped = None
        while time.time() < deadline:
            dropped = metric_value(d.metrics()[1], "terrad_snapshot_requests_dropped_total")
            if dropped:
                break
            time.sleep(0.2)
        print(f"info: requests dropped for a client that left: {dropped}", flush=True)
        check(dropped is not None, "terrad_snapshot_requests_dropped_total is in /metrics")
    check.finish()


if __name__ == "__main__":
    main()
