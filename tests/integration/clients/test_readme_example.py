#!/usr/bin/python3
"""The Python example of docs/clients.md ("Driving it from Python"), for real: the
daemon runs as `make run` starts it (demo actors on), and clients/python/examples/drive_wheel.py drives
a wheel, then checks that the heights it rebuilt from snapshots and deltas
equal GET /v1/heights at the same tick. On the CPU backend, and on the GL
backend where a context can be made. The example uses only the package's
public API: every code line of that page's Python block is in the file, and
the file touches no private name of terrad (nothing like `._on_binary`)."""
import os
import re
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon  # noqa: E402

EXAMPLE = os.path.join(SOURCE, "clients", "python", "examples", "drive_wheel.py")
check = Checks()

with open(os.path.join(SOURCE, "docs", "clients.md")) as f:
    readme = f.read()
with open(EXAMPLE) as f:
    example = f.read()
section = readme[readme.index("## Driving it from Python"):]
block = re.search(r"```python\n(.*?)```", section, re.S).group(1)
example_lines = {ln.strip() for ln in example.splitlines()}
for line in block.splitlines():
    code = line.split("  #")[0].strip()
    check(any(e.startswith(code) for e in example_lines),
          f"docs/clients.md line is in the example: {code!r}")
private = re.findall(r"\b(?:client|terrad|c)\._\w+", example)
check(not private, f"the example uses only public names: {private}")
check("sys.path" not in example, "the example imports the installed package, not a source path")


def run(backend, required):
    try:
        d = Daemon(backend=backend, demo=True, name=f"terrad-{backend}")
    except RuntimeError as e:
        check(not required, f"{backend} daemon started: {e}")
        if not required:
            print(f"{backend}: no daemon (no GL context?), skipped")
        return
    with check.running(d):
        # The package from the source tree, through the harness's PYTHONPATH
        # (test_python_package.py runs it installed).
        r = subprocess.run(["/usr/bin/python3", EXAMPLE, d.ws, d.http + "/"],
                           capture_output=True, text=True, timeout=120)
        print(r.stdout.strip())
        check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
              f"{backend}: example's mirror equals the server: {r.stdout} {r.stderr[-2000:]}")


run("cpu", True)
run("gl", False)
check.finish()
