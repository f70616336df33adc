#!/usr/bin/python3
"""The real daemon on a loopback port: probes answer, the demo actors deform
the terrain while Σh stays exactly the same, unknown paths and methods get
clear errors, and SIGTERM stops it cleanly. Runs on the CPU backend so it
needs no GL; the GL backend is exercised when a context can be made."""
import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, Checks  # noqa: E402

check = Checks()


def get(port, path, method="GET"):
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method)
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, r.read().decode(), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode(), e.headers


def start(backend):
    p = subprocess.Popen([BIN, "serve", "--http-port", "0", "--backend", backend, "--no-data"],
                         stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    lines = []
    while time.time() < deadline:
        line = p.stderr.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        if m:
            return p, int(m.group(1)), lines
    p.kill()
    return None, None, lines


def run_daemon(backend):
    p, port, lines = start(backend)
    if p is None:
        return "".join(lines)
    try:
        status, body, _ = get(port, "/healthz")
        check(status == 200 and body.strip() == "ok", f"{backend}: /healthz ok ({status})")
        status, body, _ = get(port, "/readyz")
        check(status == 200, f"{backend}: /readyz ready ({status} {body})")
        status, body, _ = get(port, "/v1/world")
        world = json.loads(body)
        check(status == 200 and world["width"] > 0 and world["units_per_m"] == 10000,
              f"{backend}: /v1/world {body}")
        first = json.loads(get(port, "/v1/stats")[1])
        time.sleep(2.0)
        later = json.loads(get(port, "/v1/stats")[1])
        check(later["tick"] > first["tick"] + 30,
              f"{backend}: ticks advance ({first['tick']} -> {later['tick']})")
        check(isinstance(later["volume"], int) and later["volume"] == first["volume"],
              f"{backend}: demo actors keep the volume ({first['volume']} -> {later['volume']})")
        status, body, _ = get(port, "/nope")
        check(status == 404 and "not found" in body, f"{backend}: unknown path 404")
        status, body, _ = get(port, "/healthz", method="POST")
        check(status == 405, f"{backend}: POST refused with 405 ({status})")
        p.send_signal(signal.SIGTERM)
        try:
            rc = p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()
            rc = None
        check(rc == 0, f"{backend}: SIGTERM stops the daemon cleanly (rc {rc})")
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    return None


def main():
    err = run_daemon("cpu")
    check(err is None, f"cpu daemon started: {err}")
    err = run_daemon("gl")
    if err is not None:
        print("GL daemon not started (no GL context?):", err.strip().splitlines()[-1:])
    # a port that is taken: a clear error, non-zero exit
    p, port, _ = start("cpu")
    if p:
        q = subprocess.run([BIN, "serve", "--http-port", str(port), "--backend", "cpu", "--no-data"],
                           capture_output=True, text=True, timeout=60)
        check(q.returncode != 0 and "port" in q.stderr, f"port in use refused: {q.stderr}")
        p.kill()
        p.wait()
    q = subprocess.run([BIN, "serve", "--http-port", "99999"], capture_output=True, text=True)
    check(q.returncode == 2 and "--http-port" in q.stderr, "bad port value refused")
    check.finish()


if __name__ == "__main__":
    main()
