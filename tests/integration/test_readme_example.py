#!/usr/bin/python3
"""The README's Python example, for real: the daemon runs as `make run`
starts it (demo actors on), and proto/python/examples/drive_wheel.py drives
a wheel, then checks that the heights it rebuilt from snapshots and deltas
equal GET /v1/heights at the same tick. On the CPU backend, and on the GL
backend where a context can be made."""
import os
import re
import subprocess
import sys
import time

SOURCE = os.environ.get("TERRAD_SOURCE_DIR", ".")
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))
EXAMPLE = os.path.join(SOURCE, "proto", "python", "examples", "drive_wheel.py")

passed = failed = 0


def check(cond, what):
    global passed, failed
    if cond:
        passed += 1
    else:
        failed += 1
        print("FAIL:", what, flush=True)


def start(backend):
    p = subprocess.Popen([BIN, "serve", "--http-port", "0", "--ws-port", "0", "--backend", backend],
                         stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    while time.time() < deadline:
        line = p.stderr.readline()
        if not line:
            break
        m = re.search(r"http://127\.0\.0\.1:(\d+)/.*ws://127\.0\.0\.1:(\d+)/", line)
        if m:
            return p, int(m.group(1)), int(m.group(2))
    p.kill()
    p.wait()
    return None, None, None


def run(backend, required):
    p, http, ws = start(backend)
    if p is None:
        check(not required, f"{backend} daemon started")
        if not required:
            print(f"{backend}: no daemon (no GL context?), skipped")
        return
    try:
        r = subprocess.run(["/usr/bin/python3", EXAMPLE, f"ws://127.0.0.1:{ws}/",
                            f"http://127.0.0.1:{http}/"], capture_output=True, text=True,
                           timeout=120)
        print(r.stdout.strip())
        check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
              f"{backend}: example's mirror equals the server: {r.stdout} {r.stderr[-2000:]}")
    finally:
        p.terminate()
        try:
            check(p.wait(timeout=10) == 0, f"{backend}: daemon stopped cleanly")
        except subprocess.TimeoutExpired:
            p.kill()
            check(False, f"{backend}: daemon did not stop on SIGTERM")


run("cpu", True)
run("gl", False)
print(f"{passed} passed, {failed} failed")
sys.exit(1 if failed else 0)
