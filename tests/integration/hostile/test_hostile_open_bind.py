#!/usr/bin/python3
"""Authentication defaults (issue 15, item 11): `--bind-any` without any token
used to start silently, letting anyone who can reach the ports deform the
world. Now it refuses to start (status 2, a line saying why) unless
--insecure-open says so. The single token of old is removed: `--token` (every
local user can read /proc/PID/cmdline) and the config key "token" both stop the
start with an error naming --auth-file, the way to give a token now.
"""
# ctest-timeout: 120
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
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
    check(rc == 2 and "--token" in err and "--auth-file" in err,
          f"--token is refused at start, naming --auth-file ({rc}): {err[-300:]}")
    fd, path = tempfile.mkstemp(suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump({"token": "sekrit", "bind_any": True}, f)
    try:
        rc, err = run("--config", path)
        check(rc == 2 and "token" in err and "--auth-file" in err,
              f"a config's \"token\" is refused at start, naming --auth-file ({rc}): {err[-300:]}")
    finally:
        os.unlink(path)
    fd, path = tempfile.mkstemp(prefix="terrad-auth-")
    os.close(fd)
    os.unlink(path)
    try:
        p = subprocess.run([BIN, "token", "add", "--auth-file", path, "--role", "admin",
                            "--name", "ops"], capture_output=True, text=True, timeout=60)
        check(p.returncode == 0, f"terrad token add makes the replacement ({p.returncode})")
        rc, err = run("--bind-any", "--auth-file", path)
        check(rc == 0, f"--bind-any with --auth-file starts ({rc}): {err[-300:]}")
    finally:
        if os.path.exists(path):
            os.unlink(path)
    check.finish()


if __name__ == "__main__":
    main()
