#!/usr/bin/python3
"""HTTP slowloris (issue 15, item 6): 300 connections to the HTTP port, each
sending one byte of a request every 4 s, used to starve the probes (0 of 120
answered in 40 s). The probes now have their own listener (--probe-port,
127.0.0.1, its own connection budget): every probe there is answered while
the slow crowd holds the main port, and the main port serves again once the
crowd leaves.
"""
# ctest-timeout: 200
import os
import re
import socket
import sys
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import Checks, Daemon  # noqa: E402

CROWD = 300
REQUEST = b"GET /v1/stats HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 200


def probe(port, path):
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
            return r.status
    except urllib.error.HTTPError as e:
        return e.code
    except Exception as e:  # noqa: BLE001
        return repr(e)[:40]


def main():
    check = Checks()
    d = Daemon(extra=("--probe-port", "0"))
    with check.running(d):
        m = None
        for line in d.lines:
            m = re.search(r"probes: http://127\.0\.0\.1:(\d+)/", line) or m
        check(m is not None, "the daemon names its probe port")
        probe_port = int(m.group(1)) if m else d.http_port
        crowd = []
        for _ in range(CROWD):
            s = socket.socket()
            s.settimeout(2)
            try:
                s.connect(("127.0.0.1", d.http_port))
                crowd.append(s)
            except OSError:
                s.close()
        print(f"{len(crowd)} of {CROWD} slow connections opened")
        answers = []
        offset = 0
        end = time.monotonic() + 24
        next_byte = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_byte:  # one more byte on each slow connection
                for s in list(crowd):
                    try:
                        s.send(REQUEST[offset:offset + 1])
                    except OSError:
                        crowd.remove(s)
                offset += 1
                next_byte = time.monotonic() + 4
            for path in ("/healthz", "/readyz"):
                answers.append(probe(probe_port, path))
            time.sleep(0.5)
        ok = sum(1 for a in answers if a == 200)
        check(ok == len(answers), f"every probe on the probe port answered 200 under slowloris "
                                  f"({ok} of {len(answers)}: {[a for a in answers if a != 200][:5]})")
        check(probe(probe_port, "/v1/heights?x=0&y=0&w=1&h=1") == 404,
              "the probe port serves probes only")
        for s in crowd:
            s.close()
        deadline = time.monotonic() + 60
        st = None
        while time.monotonic() < deadline and st != 200:
            st = probe(d.http_port, "/healthz")
            time.sleep(0.5)
        check(st == 200, f"the main port answers once the crowd leaves ({st})")
    check.finish()


if __name__ == "__main__":
    main()
