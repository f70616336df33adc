#!/usr/bin/python3
"""The watchdog behind /healthz (issue 15, "the net thread cannot be wedged"):
/healthz must fail (503, naming the thread) when the tick loop or the net
thread makes no progress, and answer 200 again once it moves. A real daemon
on loopback; one thread at a time is stopped by the fault hook
TERRAD_FAULT_STALL=FILE (base/fault.c: while FILE names "tick" or "net", that
thread sleeps where it would go on; SIGSTOP would stop every thread, the
probes' too). The watchdog's limit is 10 s, so each stall lasts until the
503 is seen (waited for with a generous deadline).

First a daemon whose tick loop is stuck before its first tick (the file names
"tick" from the start): the watchdog's clock starts when the world is ready, so
that is caught too (it was not: with no tick published, /healthz said 200).

Also checked: the other threads go on meanwhile (a stalled net thread does
not stop the ticks; a stalled tick does not stop /healthz from answering),
the probe port (--probe-port) reports the same, and afterwards a new client
is served and SIGTERM stops the daemon with status 0.
"""
# ctest-timeout: 240
import asyncio
import os
import re
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, hello_ok  # noqa: E402

DEADLINE_S = 90  # the watchdog's limit is 10 s; generous for a loaded machine


def probe(port, path="/healthz"):
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
            return r.status, r.read().decode("utf-8", "replace")
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode("utf-8", "replace")
    except Exception as e:  # noqa: BLE001
        return repr(e)[:60], ""


def wait_health(port, want, deadline_s=DEADLINE_S, naming=None):
    """Poll /healthz until it answers want (and, with naming, a body naming that
    thread): on a loaded machine the other thread may also lag past the limit
    for a while, and the answer names the first stalled thread it finds."""
    end = time.monotonic() + deadline_s
    st, body = None, ""
    while time.monotonic() < end:
        st, body = probe(port)
        if st == want and (naming is None or naming in body):
            break
        time.sleep(0.5)
    return st, body


def main():
    check = Checks()
    fd, stall = tempfile.mkstemp(prefix="terrad-stall-")
    os.close(fd)
    # stuck before the first tick
    with open(stall, "w") as f:
        f.write("tick\n")
    d0 = Daemon(demo=True, env={"TERRAD_FAULT_STALL": stall})
    try:
        with check.running(d0):
            st, body = wait_health(d0.http_port, 503)
            check(st == 503 and "tick" in body,
                  f"/healthz fails naming the tick when it is stuck before its first ({st} {body!r})")
            os.unlink(stall)  # the hook acts while the file exists: let it stop
    finally:
        if os.path.exists(stall):
            os.unlink(stall)
    d = Daemon(demo=True, extra=("--probe-port", "0"), env={"TERRAD_FAULT_STALL": stall})
    try:
        with check.running(d):
            m = None
            for line in d.lines:
                m = re.search(r"probes: http://127\.0\.0\.1:(\d+)/", line) or m
            probe_port = int(m.group(1)) if m else d.http_port
            check(wait_health(d.http_port, 200)[0] == 200, "/healthz is 200 before any stall")

            # the sim thread stops ticking
            with open(stall, "w") as f:
                f.write("tick\n")
            st, body = wait_health(d.http_port, 503)
            check(st == 503 and "tick" in body,
                  f"/healthz fails naming the tick when the sim thread is stuck ({st} {body!r})")
            pst, pbody = probe(probe_port)
            check(pst == 503 and "tick" in pbody, f"the probe port says the same ({pst} {pbody!r})")
            t0 = d.stats()["tick"]
            time.sleep(0.5)
            check(d.stats()["tick"] == t0, f"no tick while the hook holds the sim thread ({t0})")
            os.unlink(stall)
            st, _ = wait_health(d.http_port, 200)
            check(st == 200, f"/healthz is 200 again once the ticks go on ({st})")

            # the net thread stops; the ticks go on
            with open(stall, "w") as f:
                f.write("net\n")
            st, body = wait_health(d.http_port, 503, naming="net")
            check(st == 503 and "net" in body,
                  f"/healthz fails naming the net thread when it is stuck ({st} {body!r})")
            t0 = d.stats()["tick"]
            end = time.monotonic() + 30
            while time.monotonic() < end and d.stats()["tick"] <= t0:
                time.sleep(0.2)
            check(d.stats()["tick"] > t0, "ticks go on while the net thread is stuck")
            os.unlink(stall)
            st, _ = wait_health(d.http_port, 200)
            check(st == 200, f"/healthz is 200 again once the net thread goes on ({st})")
            check(asyncio.run(hello_ok(d, "after-the-stall")), "a new client gets its world message afterwards")
            check(any("fault hook: the net thread goes on" in l for l in d.lines),
                  "the hook logs what it did")
    finally:
        if os.path.exists(stall):
            os.unlink(stall)
    check.finish()


if __name__ == "__main__":
    main()
