#!/usr/bin/python3
# ctest-timeout: 240
"""The C# client (proto/csharp/Terrad.cs, P/Invoke to libterrad-client) built with Debian's
mono-mcs and run under mono against a real daemon (--backend cpu, a flat scene of default
material), through tests/support/CsharpDrive.cs: hello (a world name over 64 bytes refused
naming "world"), a subscription, a sphere driven through it whose rut arrives as DELTA
frames, CONTACT feedback, prediction on (the rut at once, every compared ACK exact), bad input
(a NaN radius, an unknown model) refused naming the field; at the end the heights the C#
client decoded equal GET /v1/heights. Exit 77 (skipped) without mcs and mono
(scripts/deps --test installs them)."""
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, skip, twin_config  # noqa: E402

MCS, MONO = shutil.which("mcs"), shutil.which("mono")
TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
LIBDIR = os.path.dirname(BIN)
if not (MCS and MONO):
    skip("mcs / mono not installed (scripts/deps --test)")
if not (os.access(TRACE, os.X_OK) and os.path.exists(os.path.join(LIBDIR, "libterrad-client.so"))):
    skip("twin_trace / libterrad-client.so not built")
check = Checks()
SCENE = {"name": "csharp", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
REGION = (64, 80, 128, 64)


def config_text(cfg):
    """The twin keys as terrad_client_predict's "key=value" pairs."""
    return " ".join(f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in cfg.items())


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-csharp-") as tmp:
        exe = os.path.join(tmp, "drive.exe")
        r = subprocess.run([MCS, "-warnaserror", "-out:" + exe,
                            os.path.join(SOURCE, "proto", "csharp", "Terrad.cs"),
                            os.path.join(SOURCE, "tests", "support", "CsharpDrive.cs")],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode == 0, f"mcs builds Terrad.cs and the drive ({r.stdout}{r.stderr})")
        path = os.path.join(tmp, "scene.json")
        with open(path, "w") as f:
            json.dump(SCENE, f)
        cfg = twin_config(path)
        out = os.path.join(tmp, "mirror.raw")
        with check.running(Daemon(extra=["--scene", path])) as d:
            env = {**os.environ, "LD_LIBRARY_PATH": LIBDIR}  # where Mono finds libterrad-client.so
            r = subprocess.run([MONO, exe, str(d.ws_port), *map(str, REGION), config_text(cfg), out],
                               capture_output=True, text=True, timeout=180, env=env)
            print(r.stdout + r.stderr, flush=True)
            check(r.returncode == 0 and " 0 failed" in r.stdout, "the C# drive: every check passed")
            n = REGION[2] * REGION[3]
            data = open(out, "rb").read() if os.path.exists(out) else b""
            mirror = list(struct.unpack(f"<{n}i", data)) if len(data) == 4 * n else None
            _, http = d.heights(*REGION)
            check(mirror is not None and mirror == http,
                  "the heights the C# client decoded equal GET /v1/heights")
    check.finish()


main()
