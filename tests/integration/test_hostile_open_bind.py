#!/usr/bin/python3
"""Authentication defaults (issue 15, item 11): `--bind-any` without any token
used to start silently, letting anyone who can reach the ports deform the
world. Now it refuses to start (status 2, a line saying why) unless
--insecure-open says so; a token on the command line still works but logs a
deprecation warning (every local user can read /proc/PID/cmdline); the config
key "token" is the way.
"""
# ctest-timeout: 120
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, Checks  # noqa: E402

BASE = [BIN, "serve", "--no-data", "--http-port", "0", "--ws-port", "0", "--backend", "cpu",
        "--no-demo", "--ticks", "2"]


def run(*extra):
    p = subprocess.run(BASE + list(extra), capture_output=True, text=True, timeout=60)
    return p.returncode, p.stderr


def main():
    check = Checks()
    rc, err = run("--bind-any")
    check(rc == 2, f"--bind-any without a token refuses to start (status {rc})")
    check("--insecure-open" in err, "the refusal names --insecure-open")
    rc, err = run("--bind-any", "--insecure-open")
    check(rc == 0, f"--bind-any --insecure-open starts ({rc}): {err[-300:]}")
    rc, err = run("--token", "sekrit")
    check(rc == 0 and "deprecated" in err, f"--token works and logs a deprecation ({rc})")
    fd, path = tempfile.mkstemp(suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump({"token": "sekrit", "bind_any": True}, f)
    try:
        rc, err = run("--config", path)
        check(rc == 0 and "deprecated" not in err,
              f"a token from the config file allows --bind-any without a warning ({rc})")
    finally:
        os.unlink(path)
    check.finish()


if __name__ == "__main__":
    main()
