#!/usr/bin/python3
# ctest-timeout: 300
"""clients/python as a package, installed the way docs/clients.md says, into a fresh virtual
environment that sees Debian's websockets, zstandard and numpy:

    /usr/bin/python3 -m venv --system-site-packages VENV
    VENV/bin/pip install --no-deps --no-build-isolation --no-index COPY-OF-clients/python

(from a copy, so that the build leaves nothing in the source tree). Then, with VENV's python:
- `import terrad` comes from VENV's site-packages, its version is CMakeLists.txt's, py.typed is
  installed, and the codec is the package's one module (terrad.proto);
- the example (clients/python/examples/drive_wheel.py) passes against a real daemon with the demo
  actors on, from outside the source tree: the mirror equals GET /v1/heights at the same tick;
- SyncClient drives a wheel without asyncio; every kind of frame reaches its public callback;
  heights are a NumPy int32 array (h, w) equal to GET /v1/heights, and lists of rows when NumPy
  cannot be imported;
- mypy type-checks the example against the installed package (its py.typed and hints);
- without zstandard, `import terrad` fails with an ImportError that names the module and says
  how to get it beyond Debian (pip install zstandard).
Skips (77) without python3-venv or python3-setuptools.
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon, skip  # noqa: E402

check = Checks()
PYTHON = "/usr/bin/python3"
if subprocess.run([PYTHON, "-c", "import ensurepip, setuptools, wheel"], capture_output=True).returncode:
    skip("python3-venv, python3-setuptools or python3-wheel missing (scripts/deps --test)")

with open(os.path.join(SOURCE, "CMakeLists.txt")) as f:
    version = re.search(r"project\(terrad VERSION (\d+\.\d+\.\d+)", f.read()).group(1)

# Run by VENV's python from a directory outside the source tree.
PROBE = r'''
import asyncio, json, os, sys
want_numpy = sys.argv[3] == "numpy"
if not want_numpy:
    sys.modules["numpy"] = None  # as if NumPy were not installed
import terrad
from terrad import MsgType, Pose, SyncClient
ws, http = sys.argv[1], sys.argv[2]
out = {"file": terrad.__file__, "version": terrad.__version__, "numpy": terrad.HAVE_NUMPY,
       "codec": terrad.proto.__file__, "typed": os.path.exists(os.path.join(os.path.dirname(terrad.__file__), "py.typed"))}
seen = {}
def count(kind):
    def cb(*args):
        seen[kind] = seen.get(kind, 0) + 1
    return cb
with SyncClient(ws) as c:
    for kind in (MsgType.DELTA, MsgType.CONTACT, MsgType.ACK, MsgType.COLLIDERS, "message"):
        c.on(kind, count(getattr(kind, "name", kind)))
    w = c.world
    x0, y0 = 40, w["height"] // 2 - 16
    sid = c.subscribe(x0, y0, 64, 32, colliders=True)
    c.wait_complete(sid)
    wheel = c.create_collider("wheel", radius=0.3, width=0.2)
    cell, hz = w["cell_size_m"], w["tick_hz"]
    import time
    for i in range(60):
        seq = c.send_poses([Pose(wheel, (x0 + 10 + i * 0.5) * cell, (y0 + 16) * cell, 0.3, 1, 0, 0, 0)])
        time.sleep(1 / hz)
    c.wait_ack(seq)
    c.send_poses([Pose(wheel, (x0 + 40) * cell, (y0 + 16) * cell, 30.0, 1, 0, 0, 0)])
    same = False
    for attempt in range(20):  # the demo actors may pass between the two reads: read again
        seq = c.send_poses([Pose(wheel, (x0 + 40) * cell, (y0 + 16) * cell, 30.0, 1, 0, 0, 0)])
        c.wait_ack(seq)
        mine = c.heights(sid)
        tick, server = terrad.get_heights(http, x0, y0, 64, 32)
        same = [list(map(int, r)) for r in mine] == [list(map(int, r)) for r in server]
        if same:
            break
        time.sleep(0.05)
    out["type"] = type(mine).__module__ + "." + type(mine).__name__
    out["shape"] = [len(mine), len(mine[0])]
    out["dtype"] = str(getattr(mine, "dtype", ""))
    out["same"] = same
    out["contact"] = c.contact(wheel) is not None
out["seen"] = seen
print(json.dumps(out))
'''


def venv_python(venv, *args, env=None, cwd=None):
    return subprocess.run([os.path.join(venv, "bin", "python"), *args], capture_output=True,
                          text=True, timeout=180, env=env, cwd=cwd)


tmp = tempfile.mkdtemp(prefix="terrad-venv-")
try:
    venv = os.path.join(tmp, "venv")
    r = subprocess.run([PYTHON, "-m", "venv", "--system-site-packages", venv], capture_output=True, text=True)
    check(r.returncode == 0, f"python3 -m venv --system-site-packages: {r.stderr}")
    src = os.path.join(tmp, "python")
    shutil.copytree(os.path.join(SOURCE, "clients", "python"), src,
                    ignore=shutil.ignore_patterns("__pycache__", "build", "*.egg-info"))
    r = subprocess.run([os.path.join(venv, "bin", "pip"), "install", "--no-deps", "--no-build-isolation",
                        "--no-index", src], capture_output=True, text=True, timeout=240)
    check(r.returncode == 0, f"pip install --no-deps --no-build-isolation: {r.stdout[-2000:]} {r.stderr[-2000:]}")
    work = os.path.join(tmp, "elsewhere")
    os.mkdir(work)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}

    r = venv_python(venv, "-c", "import terrad, sys; print(terrad.__file__)", env=env, cwd=work)
    check(r.returncode == 0 and r.stdout.startswith(venv), f"import terrad from the venv: {r.stdout} {r.stderr}")
    r = venv_python(venv, "-m", "pip", "show", "terrad", env=env, cwd=work)
    check(f"Version: {version}" in r.stdout, f"pip show terrad: version {version}: {r.stdout}")

    # The installed package is typed (py.typed): mypy type-checks the example against it.
    if shutil.which("mypy"):
        r = subprocess.run(["mypy", "--python-executable", os.path.join(venv, "bin", "python"),
                            "--no-incremental", "--cache-dir", os.path.join(tmp, "mypy-cache"),
                            os.path.join(SOURCE, "clients", "python", "examples", "drive_wheel.py")],
                           capture_output=True, text=True, timeout=240, env=env, cwd=work)
        check(r.returncode == 0 and "Success" in r.stdout, f"mypy on the example with the installed package: {r.stdout} {r.stderr}")
    else:
        print("mypy missing: type check skipped (scripts/deps --test installs it)")

    r = venv_python(venv, "-c", "import sys; sys.modules['zstandard'] = None; import terrad", env=env, cwd=work)
    msg = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else ""
    check(r.returncode != 0 and "ImportError" in msg and "'zstandard'" in msg and "pip install zstandard" in msg,
          f"a clear ImportError without zstandard: {msg}")

    d = Daemon(backend="cpu", demo=True, name="terrad-venv")
    with check.running(d):
        r = venv_python(venv, os.path.join(SOURCE, "clients", "python", "examples", "drive_wheel.py"),
                        d.ws, d.http + "/", env=env, cwd=work)
        print(r.stdout.strip())
        check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
              f"the example from the venv: {r.stdout} {r.stderr[-2000:]}")
        for flavour in ("numpy", "lists"):
            r = venv_python(venv, "-c", PROBE, d.ws, d.http, flavour, env=env, cwd=work)
            try:
                out = json.loads(r.stdout.strip().splitlines()[-1])
            except (ValueError, IndexError):
                check(False, f"{flavour}: the SyncClient probe ran: {r.stdout} {r.stderr[-3000:]}")
                continue
            print(flavour, {k: out[k] for k in ("type", "shape", "dtype", "same", "seen")})
            check(out["file"].startswith(venv) and out["codec"].startswith(venv), f"{flavour}: from the venv: {out}")
            check(out["version"] == version and out["typed"], f"{flavour}: version and py.typed: {out}")
            check(out["same"], f"{flavour}: SyncClient's heights equal GET /v1/heights")
            check(out["shape"] == [32, 64], f"{flavour}: heights are 32 rows of 64: {out['shape']}")
            if flavour == "numpy":
                check(out["numpy"] and out["type"] == "numpy.ndarray" and out["dtype"] == "int32",
                      f"with NumPy: an int32 ndarray: {out}")
            else:
                check(not out["numpy"] and out["type"] == "builtins.list", f"without NumPy: lists: {out}")
            check(out["contact"], f"{flavour}: contact feedback for the wheel")
            for kind in ("DELTA", "CONTACT", "ACK", "COLLIDERS", "message"):
                check(out["seen"].get(kind, 0) > 0, f"{flavour}: the {kind} callback was called: {out['seen']}")
finally:
    shutil.rmtree(tmp, ignore_errors=True)
check.finish()
