#!/usr/bin/python3
"""HTTP slowloris (issue 15, item 6; issue 20, item 3): 300 connections to
the main HTTP port, each sending one byte of a request every 4 s, used to
starve the probes (0 of 120 answered in 40 s), and then, with the probes on
their own listener, the main port's API (99 of 120 answered: the crowd and
the API callers share one address, and its 64 slots were the crowd's).

Here the crowd is topped up to 300 before every byte round (a closed one is
opened again at once), and every 0.5 s the main port is asked for /healthz,
/readyz, /v1/stats and a /v1/heights rectangle, and the probe port for its
probes, each with a generous 10 s timeout. Checked: every one of them
answered 200 (the guard closes the oldest connection still sending its
headers to make room, and says so in terrad_http_connections_cut_total and
the log); the probe port serves probes only; the main port serves once the
crowd leaves.
"""
# ctest-timeout: 200
import os
import re
import socket
import sys
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value  # noqa: E402

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

        def top_up():
            while len(crowd) < CROWD:
                s = socket.socket()
                s.settimeout(2)
                try:
                    s.connect(("127.0.0.1", d.http_port))
                    s.send(REQUEST[:offset])
                    crowd.append(s)
                except OSError:
                    s.close()
                    return

        answers = {"main": [], "probe": []}
        offset = 0
        top_up()
        print(f"{len(crowd)} of {CROWD} slow connections opened")
        end = time.monotonic() + 24
        next_byte = 0.0
        while time.monotonic() < end:
            if time.monotonic() >= next_byte:  # one more byte on each slow connection
                for s in list(crowd):
                    try:
                        s.send(REQUEST[offset:offset + 1])
                    except OSError:
                        crowd.remove(s)
                        s.close()
                offset += 1
                top_up()
                next_byte = time.monotonic() + 4
            for path in ("/healthz", "/readyz", "/v1/stats", "/v1/heights?x=0&y=0&w=8&h=8"):
                answers["main"].append((path, probe(d.http_port, path)))
            for path in ("/healthz", "/readyz"):
                answers["probe"].append((path, probe(probe_port, path)))
            time.sleep(0.5)
        for port, got in answers.items():
            ok = sum(1 for _, a in got if a == 200)
            check(got and ok == len(got),
                  f"every call on the {port} port answered 200 under slowloris "
                  f"({ok} of {len(got)}: {[a for a in got if a[1] != 200][:5]})")
        cut = metric_value(d.metrics()[1], "terrad_http_connections_cut_total") or 0
        check(cut >= CROWD - 64, f"the guard closed slow connections to make room ({cut})")
        check(any("to make room" in line for line in d.lines), "and the log says so")
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
