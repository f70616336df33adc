#!/usr/bin/python3
# ctest-timeout: 600
"""scripts/screenshot.mjs (make screenshot), the documented way to get a picture of a running
daemon's viewer, against a real daemon with its demo actors on:

- it exits 0 and writes a PNG of the size asked for;
- the picture is the terrain, not the "connecting" screen: most pixels are not the page's
  background colour, there are many colours (lit terrain, not a flat fill), and some are the
  viewer's "dug" blue (the demo's trench, so the deltas after the snapshot are drawn);
- a daemon that is not there, and a bad option, get exit 1 / 2 with the reason on stderr
  naming it, and no PNG.
Skips without /usr/bin/chromium, node or node_modules/playwright-core (make web-deps)."""
import os
import shutil
import socket
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from png_read import read_png  # noqa: E402
from service_harness import SOURCE, Checks, Daemon, skip  # noqa: E402

SCRIPT = os.path.join(SOURCE, "scripts", "screenshot.mjs")
BACKGROUND = (29, 33, 41)  # the page's clear colour (web/viewer.mjs app.background, 0..1 * 255)
for need in ("/usr/bin/chromium", os.path.join(SOURCE, "node_modules", "playwright-core")):
    if not os.path.exists(need):
        skip(f"{need} missing (scripts/deps --test; make web-deps)")
if not shutil.which("node"):
    skip("node missing")
check = Checks()


def screenshot(*args, timeout=400):
    return subprocess.run(["node", SCRIPT, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=SOURCE)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


with tempfile.TemporaryDirectory(prefix="terrad-screenshot-") as tmp:
    out = os.path.join(tmp, "viewer.png")
    d = Daemon(backend="cpu", demo=True, extra=("--no-data",), name="terrad-screenshot")
    with check.running(d):
        # A generous wait: software WebGL on a busy CI machine draws a frame in seconds.
        r = screenshot("--url", f"{d.http}/", "--out", out, "--size", "640x400",
                       "--timeout", "300")
        print(r.stdout.strip(), r.stderr.strip()[-2000:])
        check(r.returncode == 0 and os.path.exists(out), f"screenshot exits 0 with a PNG: {r.returncode}")
    if os.path.exists(out):
        width, height, depth, channels, px = read_png(out)
        check((width, height, depth) == (640, 400, 8), f"a 640x400 8-bit PNG: {width}x{height}, {depth} bits")
        pixels = [tuple(px[i:i + 3]) for i in range(0, len(px), channels)]
        n = len(pixels)
        background = sum(1 for p in pixels if max(abs(p[k] - BACKGROUND[k]) for k in range(3)) <= 6)
        colours = len(set(pixels))
        dug = sum(1 for r_, g, b in pixels if b > r_ + 60 and b > g + 20)
        print(f"{n} pixels: {100.0 * background / n:.1f}% background, {colours} colours, {dug} dug-blue")
        check(background < n // 2, f"the terrain fills the picture, not the background "
                                   f"({100.0 * background / n:.1f}% background)")
        check(colours > 1000, f"a lit terrain has many colours ({colours})")
        check(dug > 0, "the demo's trench shows in the viewer's dug blue")

    # Nobody on the port: a clear failure naming the address, no picture.
    missing = os.path.join(tmp, "missing.png")
    url = f"http://127.0.0.1:{free_port()}/"
    r = screenshot("--url", url, "--out", missing, "--timeout", "20")
    check(r.returncode == 1 and "screenshot:" in r.stderr and url.rstrip("/") in r.stderr
          and not os.path.exists(missing),
          f"no daemon: exit 1 naming {url}, no PNG: {r.returncode} {r.stderr[-500:]}")
    r = screenshot("--size", "10x", "--out", missing, timeout=60)
    check(r.returncode == 2 and "--size" in r.stderr and not os.path.exists(missing),
          f"a bad --size: exit 2 naming the option: {r.returncode} {r.stderr[-300:]}")
check.finish()
