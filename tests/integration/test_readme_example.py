#!/usr/bin/python3
"""The README's Python example, for real: the daemon runs as `make run`
starts it (demo actors on), and proto/python/examples/drive_wheel.py drives
a wheel, then checks that the heights it rebuilt from snapshots and deltas
equal GET /v1/heights at the same tick. On the CPU backend, and on the GL
backend where a context can be made."""
import os
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import SOURCE, Checks, Daemon  # noqa: E402

EXAMPLE = os.path.join(SOURCE, "proto", "python", "examples", "drive_wheel.py")
check = Checks()


def run(backend, required):
    try:
        d = Daemon(backend=backend, demo=True, name=f"terrad-{backend}")
    except RuntimeError as e:
        check(not required, f"{backend} daemon started: {e}")
        if not required:
            print(f"{backend}: no daemon (no GL context?), skipped")
        return
    with check.running(d):
        r = subprocess.run(["/usr/bin/python3", EXAMPLE, d.ws, d.http + "/"],
                           capture_output=True, text=True, timeout=120)
        print(r.stdout.strip())
        check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
              f"{backend}: example's mirror equals the server: {r.stdout} {r.stderr[-2000:]}")


run("cpu", True)
run("gl", False)
check.finish()
