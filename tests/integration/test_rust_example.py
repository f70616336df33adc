#!/usr/bin/python3
# ctest-timeout: 300
"""The Rust example over the C client library by FFI (proto/rust/drive.rs, docs/engines.md "Rust"),
built with `rustc` alone (Debian's rustc 1.63; std only, no cargo, no crates) against the build
tree's libterrad-client and run against a real daemon (--backend cpu, a flat scene of default
material): it says hello, predicts a window, drives a sphere through it (every compared ACK
exact, an unknown model refused) and writes its mirror, which must equal GET /v1/heights.
Exit 77 (skipped) without `rustc` (scripts/deps --test installs it)."""
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, skip, twin_config  # noqa: E402

RUSTC = shutil.which("rustc")
TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
LIBDIR = os.path.dirname(BIN)
if not RUSTC:
    skip("rustc not installed (scripts/deps --test installs it)")
if not (os.access(TRACE, os.X_OK) and os.path.exists(os.path.join(LIBDIR, "libterrad-client.so"))):
    skip("twin_trace / libterrad-client.so not built")
check = Checks()
SCENE = {"name": "rust", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
REGION = (64, 80, 128, 64)


def config_text(cfg):
    return " ".join(f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in cfg.items())


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-rust-") as tmp:
        exe = os.path.join(tmp, "drive")
        r = subprocess.run([RUSTC, "--edition", "2018", "-O", "-D", "warnings", "-o", exe,
                            os.path.join(SOURCE, "proto", "rust", "drive.rs"), "-L", "native=" + LIBDIR,
                            "-C", f"link-arg=-Wl,-rpath,{LIBDIR}"],
                           capture_output=True, text=True, timeout=240, cwd=tmp)
        check(r.returncode == 0, f"rustc ({r.stdout}{r.stderr})")
        print(subprocess.run([RUSTC, "--version"], capture_output=True, text=True).stdout.strip())
        path = os.path.join(tmp, "scene.json")
        with open(path, "w") as f:
            json.dump(SCENE, f)
        cfg = twin_config(path)
        out = os.path.join(tmp, "mirror.raw")
        with check.running(Daemon(extra=["--scene", path])) as d:
            r = subprocess.run([exe, str(d.ws_port), *map(str, REGION), config_text(cfg), out],
                               capture_output=True, text=True, timeout=180)
            print(r.stdout + r.stderr, flush=True)
            check(r.returncode == 0 and r.stdout.rstrip().endswith("ok"), "the Rust example's checks passed")
            n = REGION[2] * REGION[3]
            data = open(out, "rb").read() if os.path.exists(out) else b""
            mirror = list(struct.unpack(f"<{n}i", data)) if len(data) == 4 * n else None
            _, http = d.heights(*REGION)
            check(mirror is not None and mirror == http, "the Rust client's mirror equals GET /v1/heights")
    check.finish()


main()
