#!/usr/bin/python3
# ctest-timeout: 300
"""clients/python/examples/match.py — the "match" a game backend plays (issue
22) — run as a user would against a real daemon with tokens: it creates a
world, drives two wheels in it, fires a crater, resets the arena and deletes
the world, and exits 0 only when each step did what it says. Afterwards the
daemon lists its default world only and its data directory holds no world."""
import os
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon  # noqa: E402

SOURCE = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", ".."))
EXAMPLE = os.path.join(SOURCE, "clients", "python", "examples", "match.py")
TOKEN = "match-example-admin"

check = Checks()
with check.running(Daemon(token=TOKEN)) as d:
    env = {**os.environ, "PYTHONPATH": os.path.join(SOURCE, "clients", "python")}
    r = subprocess.run([sys.executable, EXAMPLE, d.ws, d.http + "/", TOKEN], capture_output=True,
                       text=True, timeout=240, env=env)
    print(r.stdout, end="")
    check(r.returncode == 0, f"match.py exits 0 ({r.returncode}):\n{r.stdout}{r.stderr}")
    worlds = os.path.join(d.data_dir, "worlds")
    check(not os.path.isdir(worlds) or not os.listdir(worlds),
          f"no world is left in the data directory ({os.listdir(worlds) if os.path.isdir(worlds) else []})")
check.finish()
