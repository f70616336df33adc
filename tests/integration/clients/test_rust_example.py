#!/usr/bin/python3
# ctest-timeout: 300
"""The Rust example over the C client library by FFI (clients/rust/drive.rs, docs/engines.md "Rust"),
built with `rustc` alone (Debian's rustc 1.63; std only, no cargo, no crates) against the build
tree's libterrad-client and run against a real daemon (--backend cpu, a flat scene of default
material): it says hello, predicts a window, drives a sphere through it (every compared ACK
exact, an unknown model refused) and writes its mirror, which must equal GET /v1/heights.
Exit 77 (skipped) without `rustc` (scripts/deps --test installs it)."""
import os
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, drive_ffi_example, require_client_library, skip  # noqa: E402

RUSTC = shutil.which("rustc")
if not RUSTC:
    skip("rustc not installed (scripts/deps --test installs it)")
LIBDIR = require_client_library()
check = Checks()


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-rust-") as tmp:
        exe = os.path.join(tmp, "drive")
        r = subprocess.run([RUSTC, "--edition", "2018", "-O", "-D", "warnings", "-o", exe,
                            os.path.join(SOURCE, "clients", "rust", "drive.rs"), "-L", "native=" + LIBDIR,
                            "-C", f"link-arg=-Wl,-rpath,{LIBDIR}"],
                           capture_output=True, text=True, timeout=240, cwd=tmp)
        check(r.returncode == 0, f"rustc ({r.stdout}{r.stderr})")
        print(subprocess.run([RUSTC, "--version"], capture_output=True, text=True).stdout.strip())
        drive_ffi_example(check, tmp, "rust", [exe], lambda out: out.rstrip().endswith("ok"),
                          "Rust example")
    check.finish()


main()
