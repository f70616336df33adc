#!/usr/bin/python3
"""HTTP against careless and hostile clients (issue 15, items 6 and 7):

- unread /v1/heights answers: each is one allocation of the whole rectangle,
  held until the client reads it; 62 connections of one address once took
  RSS to 1.3 GB. Now an address may hold at most 64 MiB of answers in flight
  (256 MiB in all): 40 connections ask for 4 Mi cells (16 MiB) each and never
  read; the daemon refuses the rest with 429 and a JSON error, counts them in
  terrad_http_heights_refused_total, its RSS stays bounded, /healthz answers,
  and once the idle timeout has ended the unread answers the same address is
  served again.
- slowloris: a connection sending one byte of its headers every 2 s is never
  idle, so MHD's idle timeout never cut it. Now a request's headers must be
  whole within the timeout (10 s) of the connection opening: the daemon
  closes such connections (terrad_http_connections_cut_total) while a
  normal client on the same port is served.
"""
# ctest-timeout: 240
import os
import socket
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value  # noqa: E402

UNREAD = 40
RSS_BOUND_MB = 300
SLOW = 20


def unread_heights(d, w, h):
    """A connection that asks for a w x h rectangle and never reads the answer."""
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    s.settimeout(5)
    s.connect(("127.0.0.1", d.http_port))
    s.sendall(f"GET /v1/heights?x=0&y=0&w={w}&h={h} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    return s


def status_of(s):
    """The status of an answer and its first bytes: a 200's head only (its body
    stays unread), anything else until its JSON body has come."""
    head = b""
    try:
        s.settimeout(10)
        head = s.recv(512)
        line = head.split(b"\r\n", 1)[0].decode("latin-1")
        status = int(line.split()[1])
        while status != 200 and not head.rstrip().endswith(b"}") and len(head) < 4096:
            more = s.recv(512)
            if not more:
                break
            head += more
        return status, head
    except (OSError, ValueError, IndexError):
        return None, head


def main():
    check = Checks()
    # a 2048-cell-wide world: a read of 2048 x 2048 cells is 16 MiB
    d = Daemon(extra=("--scene", "tests/scenes/large-dunes.json"))
    with check.running(d):
        world = d.world()
        W, H = world["width"], world["height"]
        w, h = W, min(H, (4 * 1024 * 1024) // W)
        bytes_each = 4 * w * h
        rss0 = (d.rss_kb() or 0) / 1024
        conns = [unread_heights(d, w, h) for _ in range(UNREAD)]
        time.sleep(3)
        peak = rss0
        statuses = []
        for s in conns:
            st, head = status_of(s)
            statuses.append((st, head))
            peak = max(peak, (d.rss_kb() or 0) / 1024)
        print("info: statuses " + str(sorted({str(st): sum(1 for x, _ in statuses if x == st)
                                              for st, _ in statuses}.items())), flush=True)
        refused = [head for st, head in statuses if st == 429]
        served = [st for st, _ in statuses if st == 200]
        print(f"info: {UNREAD} unread requests of {bytes_each >> 20} MiB: {len(served)} answered, "
              f"{len(refused)} refused; RSS {rss0:.0f} -> peak {peak:.0f} MB", flush=True)
        budget = 64 << 20
        check(len(served) <= budget // bytes_each + 1 and len(refused) > 0,
              f"past 64 MiB in flight the address is refused ({len(served)} answered, "
              f"{len(refused)} refused)")
        check(any(b"application/json" in r and b"in flight" in r for r in refused),
              "a refusal is JSON and says why")
        check(peak < RSS_BOUND_MB, f"RSS stays under {RSS_BOUND_MB} MB ({peak:.0f})")
        st, _, _ = d.get("/healthz")
        check(st == 200, f"/healthz answers while the answers sit unread ({st})")
        _, m = d.metrics()
        n = metric_value(m, "terrad_http_heights_refused_total") or 0
        check(n >= len(refused), f"terrad_http_heights_refused_total counts them ({n})")
        # the unread answers end by MHD's idle timeout (10 s): then the address is served again
        deadline = time.monotonic() + 90
        st = None
        while time.monotonic() < deadline and st != 200:
            try:
                st = d.get(f"/v1/heights?x=0&y=0&w={w}&h={h}", timeout=30)[0]
            except Exception:  # noqa: BLE001
                st = None
            if st != 200:
                time.sleep(1)
        check(st == 200, f"once the unread answers time out the address is served again ({st})")
        for s in conns:
            s.close()

        # slowloris: headers one byte every 2 s
        slow = []
        for _ in range(SLOW):
            s = socket.socket()
            s.settimeout(5)
            s.connect(("127.0.0.1", d.http_port))
            slow.append(s)
        request = b"GET /v1/stats HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 200
        closed = set()
        t0 = time.monotonic()
        i = 0
        while time.monotonic() - t0 < 60 and len(closed) < SLOW:
            for k, s in enumerate(slow):
                if k in closed:
                    continue
                try:
                    s.send(request[i:i + 1])
                    s.settimeout(0.01)
                    if s.recv(1) == b"":
                        closed.add(k)
                except socket.timeout:
                    pass
                except OSError:
                    closed.add(k)
            i += 1
            try:
                ok = d.get("/v1/stats", timeout=30)[0] == 200
            except Exception as e:  # noqa: BLE001
                print(f"info: /v1/stats beside the slow ones: {e!r}", flush=True)
                ok = False
            if not ok:
                break
            time.sleep(2)
        took = time.monotonic() - t0
        print(f"info: {len(closed)} of {SLOW} slowloris connections closed after {took:.0f} s",
              flush=True)
        check(ok, "a normal client is served beside the slow ones")
        check(len(closed) == SLOW, f"every slowloris connection is closed ({len(closed)} of {SLOW})")
        _, m = d.metrics()
        cut = metric_value(m, "terrad_http_connections_cut_total") or 0
        check(cut >= SLOW, f"terrad_http_connections_cut_total counts them ({cut})")
        for s in slow:
            s.close()
    check.finish()


if __name__ == "__main__":
    main()
