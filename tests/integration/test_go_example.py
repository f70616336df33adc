#!/usr/bin/python3
# ctest-timeout: 300
"""The Go example over the C client library by cgo (proto/go/drive.go, docs/engines.md "Go"),
built with Debian's golang-go (offline: no modules to fetch) against the build tree's
libterrad-client and run against a real daemon (--backend cpu, a flat scene of default
material): it says hello, predicts a window, drives a sphere through it (every compared ACK
exact, an unknown model refused) and writes its mirror, which must equal GET /v1/heights.
Exit 77 (skipped) without `go` (scripts/deps --test installs golang-go)."""
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, skip, twin_config  # noqa: E402

GO = shutil.which("go")
TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
LIBDIR = os.path.dirname(BIN)
if not GO:
    skip("go not installed (scripts/deps --test installs golang-go)")
if not (os.access(TRACE, os.X_OK) and os.path.exists(os.path.join(LIBDIR, "libterrad-client.so"))):
    skip("twin_trace / libterrad-client.so not built")
check = Checks()
SCENE = {"name": "go", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
REGION = (64, 80, 128, 64)


def config_text(cfg):
    return " ".join(f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in cfg.items())


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-go-") as tmp:
        # <terrad/terrad_client.h> as an installed prefix has it
        os.makedirs(os.path.join(tmp, "include"))
        os.symlink(os.path.join(SOURCE, "proto", "c"), os.path.join(tmp, "include", "terrad"))
        exe = os.path.join(tmp, "drive")
        env = {**os.environ, "GOCACHE": os.path.join(LIBDIR, "go-cache"),  # the build tree's: std compiled once "GOPATH": os.path.join(tmp, "gopath"),
               "GOFLAGS": "-mod=mod", "GOPROXY": "off", "CGO_ENABLED": "1",
               "CGO_CFLAGS": "-I" + os.path.join(tmp, "include"),
               "CGO_LDFLAGS": f"-L{LIBDIR} -Wl,-rpath,{LIBDIR}"}
        r = subprocess.run([GO, "build", "-o", exe, "."], cwd=os.path.join(SOURCE, "proto", "go"),
                           capture_output=True, text=True, timeout=240, env=env)
        check(r.returncode == 0, f"go build ({r.stdout}{r.stderr})")
        path = os.path.join(tmp, "scene.json")
        with open(path, "w") as f:
            json.dump(SCENE, f)
        cfg = twin_config(path)
        out = os.path.join(tmp, "mirror.raw")
        with check.running(Daemon(extra=["--scene", path])) as d:
            r = subprocess.run([exe, str(d.ws_port), *map(str, REGION), config_text(cfg), out],
                               capture_output=True, text=True, timeout=180)
            print(r.stdout + r.stderr, flush=True)
            check(r.returncode == 0 and r.stdout.rstrip().endswith("ok"), "the Go example's checks passed")
            n = REGION[2] * REGION[3]
            data = open(out, "rb").read() if os.path.exists(out) else b""
            mirror = list(struct.unpack(f"<{n}i", data)) if len(data) == 4 * n else None
            _, http = d.heights(*REGION)
            check(mirror is not None and mirror == http, "the Go client's mirror equals GET /v1/heights")
    check.finish()


main()
