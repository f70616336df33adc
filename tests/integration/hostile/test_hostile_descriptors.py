#!/usr/bin/python3
"""Descriptors (issue 15, item 4): 300 idle websocket clients against a daemon
whose RLIMIT_NOFILE is 256. Before the fix they exhausted its descriptors:
/healthz stopped answering, the store failed and "accept: errno 24" lines were
logged by the hundred thousand. Now websocket sockets are refused while fewer
than the reserve are free, so the probes answer, the store keeps writing
(/readyz stays 200, no store error), refusals are logged at a bounded rate,
and once the crowd leaves a new client gets its world message.
"""
# ctest-timeout: 300
import asyncio
import base64
import json
import os
import resource
import socket
import stat
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import service_harness  # noqa: E402
from service_harness import Checks, Daemon, hello_ok  # noqa: E402

CROWD = 300


def open_crowd(port, n):
    """n websockets that say hello and then only sit there; the list holds the
    admitted ones (handshake answered), the rest are closed. Bounded: a socket
    gets 2 s to connect and the crowd 30 s in all for its handshakes."""
    pending = []
    for _ in range(n):
        s = socket.socket()
        s.settimeout(2)
        try:
            s.connect(("127.0.0.1", port))
            key = base64.b64encode(os.urandom(16)).decode()
            s.sendall(("GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\n"
                       "Connection: Upgrade\r\nSec-WebSocket-Key: %s\r\n"
                       "Sec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: terrad.v1\r\n\r\n"
                       % key).encode())
            pending.append(s)
        except OSError:
            s.close()
    admitted = []
    deadline = time.monotonic() + 30
    data = json.dumps({"type": "hello", "protocol": 1, "token": "", "client": "idle"}).encode()
    for s in pending:
        buf = b""
        try:
            while b"\r\n\r\n" not in buf:
                left = deadline - time.monotonic()
                if left <= 0:
                    raise OSError("crowd deadline")
                s.settimeout(min(left, 2))
                chunk = s.recv(4096)
                if not chunk:
                    raise OSError("closed")
                buf += chunk
            mask = os.urandom(4)
            s.sendall(bytes([0x81, 0x80 | len(data)]) + mask +
                      bytes(b ^ mask[i % 4] for i, b in enumerate(data)))
            admitted.append(s)
        except OSError:
            s.close()
    return admitted


def main():
    check = Checks()
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if hard != resource.RLIM_INFINITY and hard < CROWD + 200:
        service_harness.skip(f"this test needs {CROWD + 200} descriptors (hard limit {hard})")
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 65536) if hard != resource.RLIM_INFINITY
                                                 else 65536, hard))
    # the daemon alone runs under nofile 256 (prlimit execs it: same pid)
    fd, wrapper = tempfile.mkstemp(prefix="terrad-nofile-", suffix=".sh")
    with os.fdopen(fd, "w") as f:
        f.write(f'#!/bin/sh\nexec prlimit --nofile=256:256 "{service_harness.BIN}" "$@"\n')
    os.chmod(wrapper, stat.S_IRWXU)
    real_bin, service_harness.BIN = service_harness.BIN, wrapper
    t_start = time.monotonic()
    try:
        d = Daemon(demo=True, durability="every-tick")
    finally:
        service_harness.BIN = real_bin
        os.unlink(wrapper)
    with check.running(d):
        crowd = open_crowd(d.ws_port, CROWD)
        print(f"{len(crowd)} of {CROWD} idle clients got their handshake")
        time.sleep(2)
        probes = []
        for p in ("/healthz", "/readyz"):
            for _ in range(5):
                try:
                    probes.append(d.get(p, timeout=10)[0])
                except Exception as e:  # noqa: BLE001
                    probes.append(repr(e)[:60])
        check(all(p == 200 for p in probes), f"probes answer 200 under the crowd ({probes})")
        try:
            t0 = d.stats()["tick"]
            time.sleep(2)
            check(d.stats()["tick"] > t0, "ticks go on (and are logged) under the crowd")
        except Exception as e:  # noqa: BLE001
            check(False, f"/v1/stats under the crowd: {e!r}")
        check(not any("store" in l and ("error" in l or "fail" in l) for l in d.lines),
              "no store error under the crowd")
        refusal_lines = sum(1 for l in d.lines if "refused a connection" in l or "accept" in l)
        # bounded: the old fixed allowance plus one line a second (NET_REFUSAL_LOG_MS) for however
        # long a loaded machine stretched the run
        secs = int(time.monotonic() - t_start)
        check(refusal_lines < 40 + secs, f"refusals are logged at a bounded rate ({refusal_lines} "
              f"lines in {secs} s)")
        for s in crowd:
            s.close()
        deadline = time.monotonic() + 60
        ok = False
        while not ok and time.monotonic() < deadline:
            try:
                ok = asyncio.run(hello_ok(d, "after-the-crowd"))
            except Exception:  # noqa: BLE001
                time.sleep(1)
        check(ok, "after the crowd leaves, a new client gets its world message")
    check.finish()


if __name__ == "__main__":
    main()
