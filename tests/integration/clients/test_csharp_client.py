#!/usr/bin/python3
# ctest-timeout: 240
"""The C# client (clients/csharp/Terrad.cs, P/Invoke to libterrad-client) built with Debian's
mono-mcs and run under mono against a real daemon (--backend cpu, a flat scene of default
material), through tests/support/CsharpDrive.cs: hello (a world name over 64 bytes refused
naming "world"), a subscription, a sphere driven through it whose rut arrives as DELTA
frames, CONTACT feedback, prediction on (the rut at once, every compared ACK exact), bad input
(a NaN radius, an unknown model) refused naming the field; at the end the heights the C#
client decoded equal GET /v1/heights. Exit 77 (skipped) without mcs and mono
(scripts/deps --test installs them)."""
import os
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, drive_ffi_example, require_client_library, skip  # noqa: E402

MCS, MONO = shutil.which("mcs"), shutil.which("mono")
if not (MCS and MONO):
    skip("mcs / mono not installed (scripts/deps --test)")
LIBDIR = require_client_library()
check = Checks()


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-csharp-") as tmp:
        exe = os.path.join(tmp, "drive.exe")
        r = subprocess.run([MCS, "-warnaserror", "-out:" + exe,
                            os.path.join(SOURCE, "clients", "csharp", "Terrad.cs"),
                            os.path.join(SOURCE, "tests", "support", "CsharpDrive.cs")],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode == 0, f"mcs builds Terrad.cs and the drive ({r.stdout}{r.stderr})")
        env = {**os.environ, "LD_LIBRARY_PATH": LIBDIR}  # where Mono finds libterrad-client.so
        drive_ffi_example(check, tmp, "csharp", [MONO, exe], lambda out: " 0 failed" in out,
                          "C# drive", env=env)
    check.finish()


main()
