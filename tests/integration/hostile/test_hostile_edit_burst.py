#!/usr/bin/python3
"""A burst of edits over the per-address HTTP connection limit (issue 28, item
5): 200 concurrent crater edits from one address (POST
/v1/worlds/{name}/edits, as a game backend's explosion burst would send) had
77 connections closed without any answer: the per-address limit (64) closed
them at accept, so the sender could not tell whether its edit happened.

A real daemon (CPU backend, in memory); 200 threads wait at a barrier, then
each opens its own connection and sends one crater without a rim (so Σh falls
by exactly the volume the answer declares) at its own spot, the spots far
enough apart that no two craters meet, and reads until the server closes.
Checked:
  - every connection got an HTTP answer (a status line), none was closed or
    reset without one;
  - every answer is 200 or a 503 with Retry-After (the burst over the limit
    is refused, saying so, or waits its turn);
  - the applied edits are exactly those answered 200: Σh moved by exactly the
    sum of their declared volume changes, each of their spots is dug, and
    every other spot still has the base terrain's heights;
  - the refusals are counted in terrad_http_refused_total, and a second,
    polite round (the refused ones again, after their Retry-After) is applied.
Without the change the first check fails (connections closed without an
answer).
"""
# ctest-timeout: 600
import json
import os
import socket
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value  # noqa: E402

BURST = 200
RADIUS, DEPTH, STEP = 3, 4000, 12  # a crater without rim changes cells within RADIUS of its spot


def spot(i):
    return 20 + STEP * (i % 20), 20 + STEP * (i // 20)


def post_raw(port, path, body, timeout=120):
    """One POST on its own connection: (status or None, headers, body, error)."""
    data = json.dumps(body).encode()
    req = (f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
           f"Content-Length: {len(data)}\r\nConnection: close\r\n\r\n").encode() + data
    got, err = b"", None
    s = socket.socket()
    s.settimeout(timeout)
    try:
        s.connect(("127.0.0.1", port))
        try:
            s.sendall(req)
        except OSError as e:  # an early answer may be waiting all the same
            err = f"send: {e!r}"
        while True:
            chunk = s.recv(65536)
            if not chunk:
                break
            got += chunk
    except OSError as e:
        err = (err + "; " if err else "") + repr(e)
    finally:
        s.close()
    head, _, rest = got.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    if not lines[0].startswith("HTTP/1."):
        return None, {}, got, err
    headers = dict((k.strip().lower(), v.strip()) for k, _, v in (ln.partition(":") for ln in lines[1:]))
    return int(lines[0].split()[1]), headers, rest, err


def burst(port, path, indices):
    results = {}
    barrier = threading.Barrier(len(indices))

    def one(i):
        x, y = spot(i)
        barrier.wait()
        results[i] = post_raw(port, path, {"op": "crater", "x": x, "y": y, "radius": RADIUS,
                                           "depth": DEPTH, "rim": False})
    threads = [threading.Thread(target=one, args=(i,)) for i in indices]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return results


def main():
    check = Checks()
    d = Daemon(extra=("--no-data",))
    with check.running(d):
        name = d.world().get("scene_name") or "default-dunes"
        path = f"/v1/worlds/{name}/edits"
        volume0 = d.stats()["volume"]
        side = 20 + STEP * 20
        _, base = d.heights(0, 0, side, side)
        results = burst(d.http_port, path, list(range(BURST)))
        silent = {i: r[3] or f"{len(r[2])} bytes, no status line" for i, r in results.items() if r[0] is None}
        check(not silent, f"every one of {BURST} connections got an HTTP answer "
                          f"({len(silent)} did not: {list(silent.items())[:4]})")
        applied = {i for i, r in results.items() if r[0] == 200}
        refused = {i for i, r in results.items() if r[0] == 503}
        other = {i: r[:3] for i, r in results.items() if r[0] not in (200, 503, None)}
        check(not other, f"every answer is 200 or 503 ({list(other.items())[:3]})")
        no_retry = [i for i in refused if "retry-after" not in results[i][1]]
        check(not no_retry, f"every 503 says when to retry (Retry-After; {len(no_retry)} without)")
        print(f"{len(applied)} applied, {len(refused)} refused with 503 (of {BURST})")
        declared = sum(json.loads(results[i][2])["volume_change"] for i in applied)
        _, after = d.heights(0, 0, side, side)
        volume1 = d.stats()["volume"]
        check(volume1 - volume0 == declared,
              f"Σh moved by exactly the applied edits' declared changes ({volume1 - volume0} vs {declared})")

        def dug(i, heights):
            x, y = spot(i)
            return heights[y * side + x] < base[y * side + x]

        def untouched(i, heights):
            x, y = spot(i)
            return all(heights[(y + dy) * side + x + dx] == base[(y + dy) * side + x + dx]
                       for dy in range(-RADIUS, RADIUS + 1) for dx in range(-RADIUS, RADIUS + 1))
        wrong = [i for i in range(BURST) if not (dug(i, after) if i in applied else untouched(i, after))]
        check(not wrong, f"the applied edits are exactly those answered 200 ({len(wrong)} spots disagree: {wrong[:8]})")
        status, text = d.metrics()
        # refused once read (terrad_http_refused_total), or closed to make room with a 503
        # written first (terrad_http_connections_cut_total)
        counted = ((metric_value(text, "terrad_http_refused_total") or 0) +
                   (metric_value(text, "terrad_http_connections_cut_total") or 0))
        check(counted >= len(refused), f"the metrics count the refusals ({counted} >= {len(refused)})")

        # the refused ones, asked again after their Retry-After, a few at a time
        time.sleep(max([float(results[i][1].get("retry-after", "1")) for i in refused] or [0]))
        again = {}
        todo = sorted(refused)
        for k in range(0, len(todo), 16):
            again.update(burst(d.http_port, path, todo[k:k + 16]))
        check(all(r[0] == 200 for r in again.values()),
              f"asked again politely, the refused edits are applied ({sorted({r[0] for r in again.values()}, key=str)})")
        _, final = d.heights(0, 0, side, side)
        check(all(dug(i, final) for i in range(BURST)), "and then every spot is dug")
    check.finish()


if __name__ == "__main__":
    main()
