#!/usr/bin/python3
"""The real daemon on a loopback port: probes answer, the demo actors deform
the terrain while Σh stays exactly the same, unknown paths and methods get
clear errors, and SIGTERM stops it cleanly. Runs on the CPU backend so it
needs no GL; the GL backend is exercised when a context can be made.

The default backend is auto: GL where the renderer is a hardware GPU, the
CPU twin where it is software (llvmpipe here) or missing; /v1/world and the
log say which and why, `--backend gl` still forces GL, and a backend name
that is none of them is refused naming --backend.

The log: every line starts with an ISO-8601 UTC timestamp with milliseconds
and the level; a disconnect names who closed, with the code and reason (a
client closing with 4000 "bye", the server's 4003 "bad protocol version"),
or "connection lost, no close frame".

The demo stays beautiful and a world can be reset: `serve --ticks N` with demo
actors and no --data keeps the world in memory and leaves no ./data; with
--data it is kept, and `--fresh` starts it over (tick 0, the base terrain);
--fresh refuses a directory holding a file that is not the store's."""
import asyncio
import contextlib
import json
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon  # noqa: E402

import websockets  # noqa: E402  (Debian's python3-websockets)

check = Checks()


def get(port, path, method="GET"):
    req = urllib.request.Request(f"http://127.0.0.1:{port}{path}", method=method)
    try:
        with urllib.request.urlopen(req, timeout=5) as r:
            return r.status, r.read().decode(), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode(), e.headers


def start(backend):
    """backend None: the default (no --backend)."""
    args = [BIN, "serve", "--http-port", "0", "--no-data"]
    if backend is not None:
        args += ["--backend", backend]
    p = subprocess.Popen(args, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    lines = []
    while time.time() < deadline:
        line = p.stderr.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"http://127\.0\.0\.1:(\d+)/", line)
        if m:
            return p, int(m.group(1)), lines
    p.kill()
    return None, None, lines


def run_daemon(backend):
    p, port, lines = start(backend)
    if p is None:
        return "".join(lines)
    try:
        status, body, _ = get(port, "/healthz")
        check(status == 200 and body.strip() == "ok", f"{backend}: /healthz ok ({status})")
        status, body, _ = get(port, "/readyz")
        check(status == 200, f"{backend}: /readyz ready ({status} {body})")
        status, body, _ = get(port, "/v1/world")
        world = json.loads(body)
        check(status == 200 and world["width"] > 0 and world["units_per_m"] == 10000,
              f"{backend}: /v1/world {body}")
        check(world["backend"] == backend and
              world["backend_reason"] == f"forced by --backend {backend}",
              f"{backend}: /v1/world says the backend was forced: {body}")
        first = json.loads(get(port, "/v1/stats")[1])
        # behaviour, not speed: wait (generously) until ticks have advanced
        deadline = time.time() + 120
        later = first
        while later["tick"] <= first["tick"] + 30 and time.time() < deadline:
            time.sleep(0.2)
            later = json.loads(get(port, "/v1/stats")[1])
        check(later["tick"] > first["tick"] + 30,
              f"{backend}: ticks advance ({first['tick']} -> {later['tick']})")
        check(isinstance(later["volume"], int) and later["volume"] == first["volume"],
              f"{backend}: demo actors keep the volume ({first['volume']} -> {later['volume']})")
        status, body, _ = get(port, "/nope")
        check(status == 404 and "not found" in body, f"{backend}: unknown path 404")
        status, body, _ = get(port, "/healthz", method="POST")
        check(status == 405, f"{backend}: POST refused with 405 ({status})")
        p.send_signal(signal.SIGTERM)
        try:
            rc = p.wait(timeout=120)  # generous: a loaded machine is slow, not wrong
        except subprocess.TimeoutExpired:
            p.kill()
            rc = None
        check(rc == 0, f"{backend}: SIGTERM stops the daemon cleanly (rc {rc})")
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    return None


STAMP_RE = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z terrad (info|warn|error): ")


def wait_log(d, needle, timeout=30):
    deadline = time.time() + timeout
    while time.time() < deadline:
        for line in list(d.lines):
            if needle in line:
                return line
        time.sleep(0.1)
    return None


async def closing_clients(d):
    """Three clients: one closes with 4000 "bye", one says hello with a
    protocol the server refuses (it closes 4003), one just drops the socket."""
    async with websockets.connect(d.ws, subprotocols=["terrad.v1"]) as ws:
        await ws.close(4000, "bye")
    async with websockets.connect(d.ws, subprotocols=["terrad.v1"]) as ws:
        await ws.send(json.dumps({"type": "hello", "protocol": 99, "name": "old"}))
        with contextlib.suppress(websockets.ConnectionClosed):
            while True:
                await asyncio.wait_for(ws.recv(), 30)
    ws = await websockets.connect(d.ws, subprotocols=["terrad.v1"])
    ws.transport.abort()


def check_log_lines():
    d = Daemon(backend="cpu", extra=["--no-data"], name="terrad-log")
    with check.running(d):
        asyncio.run(closing_clients(d))
        line = wait_log(d, 'the client closed with code 4000 ("bye")')
        check(line is not None, "a client closing with 4000 \"bye\" is logged with code and reason")
        line = wait_log(d, 'the server closed with code 4003 ("bad protocol version")')
        check(line is not None, "the server's own close is logged with code and reason")
        line = wait_log(d, "disconnected: connection lost, no close frame")
        check(line is not None, "a dropped socket is logged as lost without a close frame")
        lines = [x for x in d.lines if x.strip()]
        bad = [x for x in lines if not STAMP_RE.match(x)]
        check(len(lines) > 3 and not bad, f"every log line has a timestamp and level: {bad[:3]}")


def serve_ticks(cwd, *extra):
    return subprocess.run([BIN, "serve", "--ticks", "90", "--http-port", "0", "--ws-port", "0",
                           "--backend", "cpu", "--durability", "none", *extra], cwd=cwd,
                          capture_output=True, text=True, timeout=240)


def whole(d, base=False):
    w = d.world()
    if not base:
        return d.heights(0, 0, w["width"], w["height"])[1]
    status, body, headers = d.get(f"/v1/heights?x=0&y=0&w={w['width']}&h={w['height']}&base=1")
    check(status == 200 and headers.get("X-Terrad-Tick") == "0", f"base=1 answers ({status})")
    return list(struct.unpack(f"<{len(body) // 4}i", body))


def check_demo_and_fresh():
    tmp = tempfile.mkdtemp(prefix="terrad-fresh-")
    try:
        r = serve_ticks(tmp)
        check(r.returncode == 0 and "demo: world in memory (give --data DIR to keep it)" in r.stderr,
              f"a demo without --data says its world is in memory: {r.stderr[-400:]}")
        check(not os.path.exists(os.path.join(tmp, "data")), "a demo without --data leaves no ./data")
        data = os.path.join(tmp, "kept")
        r = serve_ticks(tmp, "--data", data)
        check(r.returncode == 0 and os.path.exists(os.path.join(data, "MANIFEST")),
              f"a demo with --data keeps its world: {r.stderr[-400:]}")
        base = Daemon(backend="cpu", extra=["--no-data"], name="terrad-base")
        with check.running(base):
            want = whole(base)
            check(whole(base, base=True) == want, "/v1/heights?base=1 is the untouched world")
        used = Daemon(backend="cpu", data_dir=data, name="terrad-used")
        with check.running(used):
            check(re.search(r"recovered tick 9\d", used.log()) is not None and whole(used) != want,
                  "without --fresh the used directory comes back dug")
            check(whole(used, base=True) == want, "... while base=1 is still the scene's base")
        fresh = Daemon(backend="cpu", data_dir=data, extra=["--fresh"], name="terrad-fresh")
        with check.running(fresh):
            log = fresh.log()
            check("started over" in log and "recovered tick 0 " in log,
                  f"--fresh recovers tick 0: {log[-600:]}")
            got = whole(fresh)
            check(got == want and sum(got) == sum(want), "--fresh gives the base terrain back")
        with open(os.path.join(data, "notes.txt"), "w") as f:
            f.write("mine\n")
        r = serve_ticks(tmp, "--data", data, "--fresh", "--no-demo")
        check(r.returncode != 0 and "notes.txt" in r.stderr and "nothing removed" in r.stderr,
              f"--fresh refuses a directory with a foreign file: {r.stderr[-400:]}")
        check(os.path.exists(os.path.join(data, "MANIFEST")) and
              os.path.exists(os.path.join(data, "notes.txt")), "... and removes nothing")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def gl_renderer():
    """GL_RENDERER of the context `simulate --backend gl` makes here, or None."""
    p = subprocess.run([BIN, "simulate", "--scene", os.path.join(SOURCE, "tests", "scenes",
                        "tiny.json"), "--ticks", "1", "--backend", "gl"],
                       capture_output=True, text=True, timeout=120)
    return json.loads(p.stdout)["renderer"] if p.returncode == 0 else None


def check_auto_backend():
    """No --backend: auto. It chooses by the renderer, and says so."""
    renderer = gl_renderer()
    software = renderer is not None and any(
        s in renderer.lower() for s in ("llvmpipe", "softpipe", "swiftshader", "lavapipe"))
    p, port, lines = start(None)
    check(p is not None, f"default-backend daemon started: {''.join(lines)[-500:]}")
    if p is None:
        return
    try:
        world = json.loads(get(port, "/v1/world")[1])
        why = world.get("backend_reason", "")
        if renderer is None:
            check(world["backend"] == "cpu" and why.startswith("auto: no GL context"),
                  f"auto without GL: the CPU twin, saying why: {world}")
        elif software:
            check(world["backend"] == "cpu" and renderer in why and "software" in why,
                  f"auto on the software renderer {renderer!r}: the CPU twin, saying why: {world}")
        else:
            check(world["backend"] == "gl" and renderer in why and "hardware GPU" in why,
                  f"auto on the hardware renderer {renderer!r}: GL, saying why: {world}")
        check(any(f"backend: {world['backend']} (auto: " in line for line in lines),
              f"the log says the choice and why: {lines}")
    finally:
        p.kill()
        p.wait()
    q = subprocess.run([BIN, "serve", "--http-port", "0", "--ws-port", "0", "--no-data",
                        "--backend", "vulkan"], capture_output=True, text=True, timeout=60)
    check(q.returncode != 0 and "--backend" in q.stderr and "auto, gl or cpu" in q.stderr,
          f"an unknown backend refused naming --backend: {q.returncode} {q.stderr[-300:]}")


def main():
    check_auto_backend()
    check_demo_and_fresh()
    check_log_lines()
    err = run_daemon("cpu")
    check(err is None, f"cpu daemon started: {err}")
    err = run_daemon("gl")
    if err is not None:
        print("GL daemon not started (no GL context?):", err.strip().splitlines()[-1:])
    # a port that is taken: a clear error, non-zero exit
    p, port, _ = start("cpu")
    if p:
        q = subprocess.run([BIN, "serve", "--http-port", str(port), "--backend", "cpu", "--no-data"],
                           capture_output=True, text=True, timeout=60)
        check(q.returncode != 0 and "port" in q.stderr, f"port in use refused: {q.stderr}")
        p.kill()
        p.wait()
    q = subprocess.run([BIN, "serve", "--http-port", "99999"], capture_output=True, text=True)
    check(q.returncode == 2 and "--http-port" in q.stderr, "bad port value refused")
    check.finish()


if __name__ == "__main__":
    main()
