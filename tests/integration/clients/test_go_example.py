#!/usr/bin/python3
# ctest-timeout: 300
"""The Go example over the C client library by cgo (clients/go/drive.go, docs/engines.md "Go"),
built with Debian's golang-go (offline: no modules to fetch) against the build tree's
libterrad-client and run against a real daemon (--backend cpu, a flat scene of default
material): it says hello, predicts a window, drives a sphere through it (every compared ACK
exact, an unknown model refused) and writes its mirror, which must equal GET /v1/heights.
Exit 77 (skipped) without `go` (scripts/deps --test installs golang-go)."""
import os
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, drive_ffi_example, require_client_library, skip  # noqa: E402

GO = shutil.which("go")
if not GO:
    skip("go not installed (scripts/deps --test installs golang-go)")
LIBDIR = require_client_library()
check = Checks()


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-go-") as tmp:
        # <terrad/terrad_client.h> and the <terrad/terrad_proto.h> it includes, as an installed
        # prefix has them
        os.makedirs(os.path.join(tmp, "include", "terrad"))
        for header in (("clients", "c", "terrad_client.h"), ("proto", "c", "terrad_proto.h")):
            os.symlink(os.path.join(SOURCE, *header),
                       os.path.join(tmp, "include", "terrad", header[-1]))
        exe = os.path.join(tmp, "drive")
        env = {**os.environ, "GOCACHE": os.path.join(LIBDIR, "go-cache"),  # std compiled once
               "GOPATH": os.path.join(tmp, "gopath"),
               "GOFLAGS": "-mod=mod", "GOPROXY": "off", "CGO_ENABLED": "1",
               "CGO_CFLAGS": "-I" + os.path.join(tmp, "include"),
               "CGO_LDFLAGS": f"-L{LIBDIR} -Wl,-rpath,{LIBDIR}"}
        r = subprocess.run([GO, "build", "-o", exe, "."], cwd=os.path.join(SOURCE, "clients", "go"),
                           capture_output=True, text=True, timeout=240, env=env)
        check(r.returncode == 0, f"go build ({r.stdout}{r.stderr})")
        drive_ffi_example(check, tmp, "go", [exe], lambda out: out.rstrip().endswith("ok"),
                          "Go example")
    check.finish()


main()
