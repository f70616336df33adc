#!/usr/bin/python3
"""Signals (issue 15, item 10): SIGHUP must not kill the daemon (it killed it
before: clients saw 1006); it is logged (it reads an --auth-file again, which
test_auth_roles covers; without one nothing else happens), and a connected client
carries on. SIGTERM with subscribed clients and demo actors deforming the
world stops the daemon with status 0 (the harness gives it a generous 30 s).
"""
# ctest-timeout: 240
import asyncio
import os
import signal
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, tp  # noqa: E402


async def hup_while_connected(check, d):
    c = tp.TerradClient(d.ws, name="hup-watcher")
    await c.connect()
    try:
        sid = await c.subscribe(0, 0, 128, 128)
        await c.wait_complete(sid, timeout=30)
        for _ in range(3):
            os.kill(d.pid, signal.SIGHUP)
            await asyncio.sleep(0.3)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any("SIGHUP" in l for l in d.lines):
            await asyncio.sleep(0.1)
        check(d.alive(), "the daemon survives SIGHUP")
        check(any("SIGHUP received" in l for l in d.lines), "SIGHUP is logged")
        # the same connection still works: a request gets its answer
        sid2 = await c.subscribe(128, 0, 64, 64)
        await c.wait_complete(sid2, timeout=30)
        check(True, "the client's connection outlives SIGHUP")
        status, _, _ = d.get("/healthz")
        check(status == 200, f"/healthz after SIGHUP ({status})")
    finally:
        await c.close()


async def load(d, n):
    clients = []
    for i in range(n):
        c = tp.TerradClient(d.ws, name=f"load-{i}")
        await c.connect()
        await c.subscribe(0, 0, 512, 512)
        clients.append(c)
    return clients


def main():
    check = Checks()
    d = Daemon(demo=True)
    with check.running(d):
        asyncio.run(hup_while_connected(check, d))

    # SIGTERM under load: 8 whole-world subscribers (some never read) and 6 demo actors
    d = Daemon(demo=True)
    check.daemons.append(d)
    loop = asyncio.new_event_loop()
    clients = loop.run_until_complete(load(d, 8))
    loop.run_until_complete(asyncio.sleep(2))
    t0 = time.monotonic()
    st = d.stop(timeout=30)
    check(st == 0, f"SIGTERM under load exits 0 within 30 s ({st}, {time.monotonic() - t0:.1f} s)")
    for c in clients:
        try:
            loop.run_until_complete(asyncio.wait_for(c.close(), 10))
        except Exception:  # noqa: BLE001
            pass
    loop.close()
    check.finish()


if __name__ == "__main__":
    main()
