"""The one Python harness of the tests (tests/integration/*/test_*.py,
tests/bench/bench_*.py): pass/fail bookkeeping (Checks), start and stop the
real daemon on loopback ports (serve_scene: on a scene given as a dict),
`terrad simulate` runs, HTTP helpers
(/v1/stats, /v1/heights, /metrics), the c_cosim_drive client's world and
output (cosim_*), the c_join_probe run (join_probe), a TerradClient that keeps a copy of its
mirrors at every ACK (to compare with GET /v1/heights at the same tick), one that counts the
bytes it reads as the server's budget does (CountingClient, wire_bytes), and
wheel poses. A test puts tests/support on sys.path and imports what it needs.

Not a test itself (ctest registers only tests/integration/**/test_*.py). Debian's /usr/bin/python3
with python3-websockets and python3-zstandard.
"""
import asyncio
import contextlib
import glob
import hashlib
import json
import math
import os
import re
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import urllib.error
import urllib.request

SOURCE = os.environ.get("TERRAD_SOURCE_DIR",
                        os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")))
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))
# The Python client package (clients/python/terrad) from the source tree, for the tests and for
# the Python programs they start (the examples).
sys.path.insert(0, os.path.join(SOURCE, "clients", "python"))
os.environ["PYTHONPATH"] = os.pathsep.join(
    p for p in (os.path.join(SOURCE, "clients", "python"), os.environ.get("PYTHONPATH")) if p)

import terrad as tp  # noqa: E402

JOIN_PROBE = os.path.join(os.path.dirname(BIN), "c_join_probe")
PORTS_RE = re.compile(r"(https?)://127\.0\.0\.1:(\d+)/.*wss?://127\.0\.0\.1:(\d+)/")


# ---- pass/fail ---------------------------------------------------------------

class Checks:
    """check(cond, what) counts a pass or prints "FAIL: what"; finish() prints
    the closing "N passed, N failed" line (", N skipped" when a test counted
    parts it could not run here) and exits 1 on any failure."""

    def __init__(self):
        self.passed = 0
        self.failed = 0
        self.skipped = 0
        self.daemons = []  # whose logs to print on failure

    def __call__(self, cond, what):
        if cond:
            self.passed += 1
        else:
            self.failed += 1
            print("FAIL:", what, flush=True)
        return cond

    @contextlib.contextmanager
    def running(self, daemon):
        """Run a test body against daemon: an exception is a failed check,
        and the daemon must then stop with status 0 on SIGTERM."""
        self.daemons.append(daemon)
        try:
            yield daemon
        except Exception:  # noqa: BLE001
            self(False, "the test raised:\n" + traceback.format_exc())
        finally:
            st = daemon.stop()
        self(st == 0, f"SIGTERM stops the daemon with status 0 ({st})")

    def finish(self):
        if self.failed:
            for d in self.daemons:
                d.print_log()
        skipped = f", {self.skipped} skipped" if self.skipped else ""
        print(f"{self.passed} passed, {self.failed} failed{skipped}", flush=True)
        sys.exit(1 if self.failed else 0)


def simulate(scene, ticks, *extra, backend="cpu"):
    """`terrad simulate` on a scene file: (exit status, its JSON report or None, stderr)."""
    args = [BIN, "simulate", "--scene", scene, "--ticks", str(ticks), "--backend", backend]
    p = subprocess.run(args + list(extra), capture_output=True, text=True, timeout=240)
    return p.returncode, (json.loads(p.stdout) if p.returncode == 0 else None), p.stderr


def flat_scene(name, width, height, cell_size_m, ground_m, material):
    """A scene (as a dict) of a flat world at ground_m metres, with no colliders."""
    return {"name": name, "world": {"width": width, "height": height, "cell_size_m": cell_size_m},
            "terrain": {"kind": "flat", "height_m": ground_m}, "material": material,
            "colliders": []}


def json_file(doc, prefix):
    """doc written to a new temporary .json file; its path (the caller removes it)."""
    fd, path = tempfile.mkstemp(prefix=f"{prefix}-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(doc, f)
    return path


def serve_scene(check, scene, scenario, name="terrad"):
    """Run the coroutine scenario(d) against a daemon serving scene (a dict,
    written to a temporary scene file that is removed afterwards)."""
    path = json_file(scene, name)
    try:
        with check.running(Daemon(extra=["--scene", path], name=name)) as d:
            asyncio.run(scenario(d))
    finally:
        os.unlink(path)


def twin_config(scene_path):
    """A scene's parameters as the twin library's config keys (terrad_twin.h), read by
    twin_trace ($TERRAD_TWIN_TRACE): what a predicting client is given (test_predict_*)."""
    trace = os.environ.get("TERRAD_TWIN_TRACE", "")
    out = subprocess.run([trace, scene_path, "0"], capture_output=True, text=True, timeout=60,
                         check=True).stdout
    cfg = {}
    for line in out.splitlines():
        kind, *rest = line.split()
        if kind == "set":
            cfg[rest[0]] = float(rest[1])
        elif kind == "name":
            cfg[rest[0]] = rest[1]
    return cfg


def children_of(pid):
    """The pids whose parent is pid, read from /proc (a bare machine may have no procps)."""
    kids = []
    for status in glob.glob("/proc/[0-9]*/status"):
        try:
            with open(status) as f:
                ppid = next((line.split()[1] for line in f if line.startswith("PPid:")), None)
        except OSError:
            continue
        if ppid == str(pid):
            kids.append(int(status.split("/")[2]))
    return sorted(kids)


def skip(why):
    print(f"skip: {why}", flush=True)
    sys.exit(77)


def need_built(path, needs, require_env, check=None):
    """path when it is built (a file the build makes only when an optional dependency is there).
    When it is not, the test cannot run that part: under `make test` (which exports require_env=1
    after scripts/deps installed the dependency) that is a failure, since a skip there hid a
    build that had lost it (issue 28: make run had configured build/ before the WebAssembly
    toolchain came); elsewhere (ctest by hand on a machine without it) a skip. needs says what
    builds it. With check (a Checks), the failure or skip is counted there and None is returned,
    so the rest of the test runs; without, the test ends here (exit 1, or 77)."""
    if os.path.exists(path):
        return path
    why = f"{path} not built (it needs {needs})"
    if os.environ.get(require_env) == "1":
        why += f"; {require_env}=1 (make test) requires it"
        if check is not None:
            check(False, why)
            return None
        print("FAIL:", why, flush=True)
        print("0 passed, 1 failed", flush=True)
        sys.exit(1)
    if check is not None:
        print(f"skip: {why}", flush=True)
        check.skipped += 1
        return None
    skip(why)


def need_twin_wasm(check=None):
    """The WebAssembly twin's path ($TERRAD_TWIN_WASM, else build/terrad_twin.wasm) when it is
    built, else need_built's failure (make test: TERRAD_REQUIRE_WASM=1) or skip."""
    path = os.environ.get("TERRAD_TWIN_WASM") or os.path.join(SOURCE, "build", "terrad_twin.wasm")
    return need_built(path, "its toolchain: clang, wasm-ld, wasi-libc and "
                      "libclang-rt-14-dev-wasm32, from scripts/deps --build",
                      "TERRAD_REQUIRE_WASM", check)


def built(path, what="make build"):
    """path when it is built; else the test fails here (exit 1, saying so): for a helper
    program the build always makes (no optional dependency, unlike need_built's), whose
    absence is a broken build, never a reason to skip."""
    if os.access(path, os.X_OK):
        return path
    print(f"FAIL: {path} is not built (it always is: {what})", flush=True)
    print("0 passed, 1 failed", flush=True)
    sys.exit(1)


def join_probe(d, rect, mode, world=None, timeout=600):
    """tests/support/c_join_probe (the C client library's late join, a fresh connection):
    joins rect (x, y, w, h) of world (None: the default) on d (anything with ws_port), with
    base snapshots (mode "base"), base snapshots with slope snapshots offered too ("slope") or
    absolute ones ("plain"). (Its JSON line, the mirror's
    w * h heights), or (None, None) when it failed (its output printed)."""
    with tempfile.NamedTemporaryFile(prefix="terrad-join-", suffix=".bin") as out:
        p = subprocess.run([JOIN_PROBE, str(d.ws_port), *map(str, rect), mode, out.name,
                            *([world] if world else [])],
                           capture_output=True, text=True, timeout=timeout)
        if p.returncode != 0:
            print(f"c_join_probe failed ({p.returncode}): {(p.stdout + p.stderr).strip()[-600:]}",
                  flush=True)
            return None, None
        data = out.read()
    return json.loads(p.stdout), list(struct.unpack(f"<{rect[2] * rect[3]}i", data))


def wire_bytes(payload_len):
    """What a websocket frame of payload_len bytes takes, as the server's budget counts it
    (server/net/net_budget.c wire_bytes): the payload plus its header, 2, 4 or 10 bytes (the
    server's frames are unmasked)."""
    return payload_len + (2 if payload_len < 126 else 4 if payload_len < 65536 else 10)


class CountingClient(tp.TerradClient):
    """A client that counts the bytes of every frame it reads, binary and text (its UTF-8
    bytes), as wire_bytes does: .bytes in all, and counted(n) per frame for a subclass (a
    bench's bins per second)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.bytes = 0

    def counted(self, n):
        pass

    def _count(self, payload_len):
        n = wire_bytes(payload_len)
        self.bytes += n
        self.counted(n)

    async def _on_binary(self, data):
        self._count(len(data))
        await super()._on_binary(data)

    async def _on_json(self, text):
        self._count(len(text.encode()))
        await super()._on_json(text)


def json_call(base, method, path, body=None, token=None, raw=None, timeout=120):
    """(status, JSON answer) of one HTTP request to base (a daemon's or node's http URL): body
    as JSON, or raw bytes as they are; token as "Authorization: Bearer". An error answer that
    is not JSON comes back as {"raw": its text}."""
    data = raw if raw is not None else (None if body is None else json.dumps(body).encode())
    req = urllib.request.Request(base + path, data=data, method=method)
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=timeout) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        text = e.read()
        try:
            return e.code, json.loads(text or b"{}")
        except ValueError:
            return e.code, {"raw": text.decode(errors="replace")}


# A bekker world for the load-driven wheel of test_predict_c / _python / _js: 2 cm cells, the
# ding2011 soil preset; the predicted window leaves a 16-cell halo about the wheel's path.
SOIL_PREDICT_SCENE = {"name": "predict-load",
                      "world": {"width": 160, "height": 96, "cell_size_m": 0.02},
                      "terrain": {"kind": "flat", "height_m": 0.4},
                      "material": {"model": "bekker", "compression": 0.5,
                                   "soil": {"preset": "ding2011"}},
                      "colliders": []}
SOIL_PREDICT_REGION = (16, 16, 128, 64)


def soil_predict_config(tmp):
    """SOIL_PREDICT_SCENE written into the folder tmp: its path and its twin config."""
    path = os.path.join(tmp, "soil.json")
    with open(path, "w") as f:
        json.dump(SOIL_PREDICT_SCENE, f)
    return path, twin_config(path)


def twin_config_text(cfg):
    """The twin keys as terrad_client_predict's "key=value" pairs (what the C library's
    prediction takes, so also the C#, Go and Rust examples built on it)."""
    return " ".join(f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}" for k, v in cfg.items())


def read_mirror(path, n):
    """n little-endian int32 heights a client wrote to path, or None (missing or short)."""
    data = open(path, "rb").read() if os.path.exists(path) else b""
    return list(struct.unpack(f"<{n}i", data)) if len(data) == 4 * n else None


# c_cosim_drive (tests/support/c_cosim_drive.c): the C client that steps client-clocked worlds
# (test_cosim_lockstep, test_cosim_cluster_failover), its world and its output.
COSIM_DRIVE = os.environ.get("TERRAD_C_COSIM_DRIVE", os.path.join(os.path.dirname(BIN), "c_cosim_drive"))
COSIM_W, COSIM_H = 96, 64


def cosim_scene(**extra):
    """c_cosim_drive's world, a flat bekker scene of COSIM_W x COSIM_H cells, with extra keys
    (clock="client") as a dict."""
    return {"name": "cosim", "world": {"width": COSIM_W, "height": COSIM_H, "cell_size_m": 0.05},
            "terrain": {"kind": "flat", "height_m": 0.4},
            "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "ding2011"}},
            **extra}


def cosim_paused(port, world, steps, prefix):
    """c_cosim_drive stepping world steps times through websocket port, then waiting ("pause")
    until it is killed: (the process, its output lines up to PAUSED). prefix: its output files."""
    p = subprocess.Popen([COSIM_DRIVE, str(port), world, str(steps), prefix, "pause"],
                         stdout=subprocess.PIPE, text=True)
    lines = []
    for line in p.stdout:
        lines.append(line)
        if line.startswith("PAUSED"):
            break
    return p, lines


def cosim_acked(lines):
    """The last tick c_cosim_drive's lines say was acknowledged (ACKED), or 0."""
    ticks = [int(line.split()[2]) for line in lines if line.startswith("ACKED ")]
    return ticks[-1] if ticks else 0


def cosim_mirror(text):
    """The MIRROR block of a c_cosim_drive output: its COSIM_W * COSIM_H heights."""
    lines = text.split("MIRROR", 1)[1].splitlines()[1:]
    return [int(v) for line in lines for v in line.split()]


FFI_REGION = (64, 80, 128, 64)  # x, y, w, h cells: the window the language examples predict


def require_client_library():
    """Skips (77) unless twin_trace and libterrad-client.so are built; returns the library's
    directory (the build tree)."""
    libdir = os.path.dirname(BIN)
    if not (os.access(os.environ.get("TERRAD_TWIN_TRACE", ""), os.X_OK)
            and os.path.exists(os.path.join(libdir, "libterrad-client.so"))):
        skip("twin_trace / libterrad-client.so not built")
    return libdir


def drive_ffi_example(check, tmp, name, command, passed, what, env=None):
    """The one run of a language's example over libterrad-client (test_csharp_client,
    test_go_example, test_rust_example): serves a flat 256² scene of default material, runs
    command + [ws port, x, y, w, h, twin config, mirror file] (it says hello, predicts
    FFI_REGION, drives through it and writes its mirror), checks passed(stdout) and that the
    mirror equals GET /v1/heights."""
    path = os.path.join(tmp, "scene.json")
    with open(path, "w") as f:
        json.dump({"name": name, "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
                   "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}, f)
    cfg = twin_config(path)
    out = os.path.join(tmp, "mirror.raw")
    with check.running(Daemon(extra=["--scene", path])) as d:
        r = subprocess.run([*command, str(d.ws_port), *map(str, FFI_REGION), twin_config_text(cfg),
                            out], capture_output=True, text=True, timeout=180, env=env)
        print(r.stdout + r.stderr, flush=True)
        check(r.returncode == 0 and passed(r.stdout), f"the {what}: every check passed")
        mirror = read_mirror(out, FFI_REGION[2] * FFI_REGION[3])
        _, http = d.heights(*FFI_REGION)
        check(mirror is not None and mirror == http, f"the {what}'s mirror equals GET /v1/heights")


def export_heights(data, tick, out, region=None):
    """(heights, stderr) of `terrad export --format raw32` of data as of tick
    (0: the last), or (None, stderr) when it fails; out is the file it writes."""
    args = [BIN, "export", "--data", data, "--out", out, "--format", "raw32"]
    if region:
        args += ["--region", ",".join(map(str, region))]
    if tick:
        args += ["--tick", str(tick)]
    r = subprocess.run(args, capture_output=True, text=True, timeout=60)
    if r.returncode != 0:
        return None, r.stderr
    with open(out, "rb") as f:
        body = f.read()
    return list(struct.unpack(f"<{len(body) // 4}i", body)), r.stderr


def uv_sphere_mesh(r, rings=126, segments=130):
    """(vertices, indices) of a closed UV sphere of radius r: 2 + rings * segments
    vertices and 2 * rings * segments triangles (the defaults: 16,382 and
    32,760, the most this way fits under the default mesh limits), millimetre
    vertices so that the collider_create stays under max_message_bytes."""
    verts = [0.0, 0.0, r]
    for i in range(1, rings + 1):
        th = math.pi * i / (rings + 1)
        for j in range(segments):
            ph = 2 * math.pi * j / segments
            verts += [round(r * math.sin(th) * math.cos(ph), 3),
                      round(r * math.sin(th) * math.sin(ph), 3), round(r * math.cos(th), 3)]
    verts += [0.0, 0.0, -r]
    south = 1 + rings * segments
    tris = []
    for j in range(segments):
        tris += [0, 1 + j, 1 + (j + 1) % segments]
    for i in range(rings - 1):
        a, b = 1 + i * segments, 1 + (i + 1) * segments
        for j in range(segments):
            k = (j + 1) % segments
            tris += [a + j, b + j, b + k, a + j, b + k, a + k]
    last = 1 + (rings - 1) * segments
    for j in range(segments):
        tris += [last + j, south, last + (j + 1) % segments]
    return verts, tris


# ---- the daemon ----------------------------------------------------------------

class Daemon:
    """terrad serve on ports 0 (both), stderr collected by a thread.

    data_dir: the daemon's --data directory, kept (tests that restart a daemon
    on the same directory). Without it each daemon gets a fresh temporary
    directory, removed by stop(), so no test ever shares ./data; "--no-data"
    in extra runs it memory-only.

    durability: "none" unless a test asks for a policy: every tick is still
    logged before it is published, but the tests of the service's timing
    (one pose per tick, ACK counts) do not wait for this machine's disk;
    the storage tests (test_store_*) choose their policies."""

    def __init__(self, backend="cpu", demo=False, token=None, tick_hz=None, config=None,
                 extra=(), name="terrad", data_dir=None, env=None, durability="none"):
        if not os.access(BIN, os.X_OK):
            raise FileNotFoundError(BIN)
        self.name = name
        self.lines = []
        self.config_path = None
        self.temp_data = None
        args = [BIN, "serve", "--http-port", "0", "--ws-port", "0", "--backend", backend]
        if "--no-data" not in extra and "--data" not in extra:
            if data_dir is None:
                data_dir = self.temp_data = tempfile.mkdtemp(prefix="terrad-data-")
            args += ["--data", data_dir]
            if "--durability" not in extra:
                args += ["--durability", durability]
        self.data_dir = data_dir
        if not demo:
            args.append("--no-demo")
        self.auth_path = None
        if token is not None:
            # the token as one admin entry of an auth file (docs/security.md):
            # the daemon takes no token in clear
            fd, self.auth_path = tempfile.mkstemp(prefix="terrad-auth-")
            with os.fdopen(fd, "w") as f:
                f.write(f"admin token {hashlib.sha256(token.encode()).hexdigest()}\n")
            args += ["--auth-file", self.auth_path]
        if tick_hz is not None:
            args += ["--tick-hz", str(tick_hz)]
        if config is not None:
            fd, self.config_path = tempfile.mkstemp(prefix="terrad-test-", suffix=".json")
            with os.fdopen(fd, "w") as f:
                json.dump(config, f)
            args += ["--config", self.config_path]
        args += list(extra)
        self.args = args
        self.proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE, text=True, errors="replace",
                                     env=None if env is None else {**os.environ, **env})
        self.pid = self.proc.pid
        self.http_port = self.ws_port = None
        self.tls = False
        # HTTP reads: the token sent as "Authorization: Bearer" (the data endpoints need
        # one when auth is on) and, for a daemon with --tls-cert, an ssl.SSLContext
        self.http_token = token
        self.ssl_context = None
        got = threading.Event()

        def reader():
            for line in self.proc.stderr:
                self.lines.append(line)
                if self.http_port is None:
                    m = PORTS_RE.search(line)
                    if m:
                        self.tls = m.group(1) == "https"
                        self.http_port, self.ws_port = int(m.group(2)), int(m.group(3))
                        got.set()
            got.set()

        self.thread = threading.Thread(target=reader, daemon=True)
        self.thread.start()
        got.wait(60)
        if self.http_port is None:
            self.stop()
            raise RuntimeError(f"{name}: the daemon did not print its ports:\n" + self.log())
        self.http = f"{'https' if self.tls else 'http'}://127.0.0.1:{self.http_port}"
        self.ws = f"{'wss' if self.tls else 'ws'}://127.0.0.1:{self.ws_port}/"

    def log(self, tail=80):
        return "".join(self.lines[-tail:])

    def print_log(self, tail=60):
        print(f"---- {self.name} stderr ({' '.join(self.args[1:])}), last {tail} lines ----")
        print(self.log(tail), end="")
        print("---- end ----", flush=True)

    def alive(self):
        return self.proc.poll() is None

    def stop(self, timeout=120):
        """SIGTERM; returns the exit status (None if it had to be killed)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                self.thread.join(2)
                return None
        self.thread.join(5)
        for attr in ("config_path", "auth_path"):
            path = getattr(self, attr)
            if path:
                with contextlib.suppress(OSError):
                    os.unlink(path)
                setattr(self, attr, None)
        if self.temp_data:
            shutil.rmtree(self.temp_data, ignore_errors=True)
            self.temp_data = None
        return self.proc.returncode

    def kill9(self):
        """SIGKILL: a crash, for the storage tests; returns the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()
        self.thread.join(5)
        return self.proc.returncode

    def rss_kb(self):
        try:
            with open(f"/proc/{self.pid}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        return int(line.split()[1])
        except OSError:
            pass
        return None

    # HTTP ------------------------------------------------------------------
    def get(self, path, timeout=10, token=None):
        """(status, body, headers); token: "Authorization: Bearer" (default self.http_token)."""
        req = urllib.request.Request(self.http + path)
        token = self.http_token if token is None else token
        if token:
            req.add_header("Authorization", f"Bearer {token}")
        try:
            with urllib.request.urlopen(req, timeout=timeout, context=self.ssl_context) as r:
                return r.status, r.read(), r.headers
        except urllib.error.HTTPError as e:
            return e.code, e.read(), e.headers

    def stats(self):
        status, body, _ = self.get("/v1/stats")
        if status != 200:
            raise RuntimeError(f"/v1/stats: {status} {body!r}")
        return json.loads(body)

    def world(self):
        return json.loads(self.get("/v1/world")[1])

    def get_busy(self, path, busy_s=60, timeout=10):
        """get(), but a 503 "retry" (the sim thread, which serves reads between
        ticks, was too busy to answer within its read timeout: a loaded machine)
        is asked again for up to busy_s; any other answer is returned as is."""
        end = time.monotonic() + busy_s
        while True:
            status, body, headers = self.get(path, timeout=timeout)
            if status != 503 or b"retry" not in body or time.monotonic() > end:
                return status, body, headers
            time.sleep(0.2)

    def heights(self, x, y, w, h, busy_s=60, layer=None):
        """(tick, list of w*h int32) from GET /v1/heights (layer="compaction": the
        compaction memory instead), through get_busy."""
        extra = f"&layer={layer}" if layer else ""
        status, body, headers = self.get_busy(f"/v1/heights?x={x}&y={y}&w={w}&h={h}{extra}", busy_s)
        if status != 200 or len(body) != 4 * w * h:
            raise RuntimeError(f"/v1/heights {x},{y},{w},{h}: {status}, {len(body)} bytes: {body[:200]!r}")
        tick = headers.get("X-Terrad-Tick")
        return (int(tick) if tick is not None else None), list(struct.unpack(f"<{w * h}i", body))

    def metrics(self):
        status, body, _ = self.get("/metrics")
        return status, body.decode("utf-8", "replace")


def post_edit(d, name, body, token=None):
    """(status, JSON answer) of POST /v1/worlds/{name}/edits."""
    data = body if isinstance(body, bytes) else json.dumps(body).encode()
    req = urllib.request.Request(f"{d.http}/v1/worlds/{name}/edits", data=data, method="POST",
                                 headers={"Content-Type": "application/json"})
    if token:
        req.add_header("Authorization", f"Bearer {token}")
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


def wait_until(cond, seconds=120, poll=0.2):
    """Whether cond() becomes true within seconds (polled): a condition, never a moment, for
    what a daemon's threads do beside its ticks (compaction, retention) on a busy machine."""
    end = time.time() + seconds
    while not cond():
        if time.time() >= end:
            return False
        time.sleep(poll)
    return True


def metric_value(text, name, labels=None):
    """Sum of the samples of a metric (optionally those whose labels include
    the given ones); None when there is none."""
    total = None
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        m = re.match(r"([a-zA-Z_:][a-zA-Z0-9_:]*)(\{([^}]*)\})?\s+(\S+)", line)
        if not m or m.group(1) != name:
            continue
        got = dict(re.findall(r'([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)"', m.group(3) or ""))
        if labels and any(got.get(k) != v for k, v in labels.items()):
            continue
        try:
            v = float(m.group(4))
        except ValueError:
            continue
        total = v if total is None else total + v
    return total


def machine():
    """'CPU model, N cores' of this machine."""
    model = "unknown CPU"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cores"


# ---- clients -------------------------------------------------------------------

class TickWatch:
    """The daemon's tick, polled in a thread (HTTP never blocks the reader's loop)."""

    def __init__(self, d):
        self.d, self.tick, self.stop = d, d.stats()["tick"], threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self):
        while not self.stop.is_set():
            try:
                self.tick = self.d.stats()["tick"]
            except Exception:  # noqa: BLE001
                pass
            time.sleep(0.05)


class RecordingClient(tp.TerradClient):
    """Keeps a copy of its mirrors at each ACK (every DELTA of tick t arrives
    before the ACK of tick t), counts frames, and remembers the contact
    feedback of its colliders."""

    def __init__(self, *args, keep=240, record=True, **kwargs):
        super().__init__(*args, **kwargs)
        self.history = {}
        self.keep = keep
        self.record = record
        self.counts = {"DELTA": 0, "CONTACT": 0, "ACK": 0, "delta_bytes": 0}
        self.acks = []         # (tick, seq)
        self.contact_log = []  # (tick, Contact) for our colliders
        self.on_ack = None     # optional callable(tick, seq)
        self.on_delta = None   # optional callable(tick, nbytes)

    async def _on_binary(self, data):
        await super()._on_binary(data)
        t = tp.decode_header(data)
        if t == tp.MsgType.DELTA:
            self.counts["DELTA"] += 1
            self.counts["delta_bytes"] += len(data)
            if self.on_delta:
                self.on_delta(self.tick, len(data))
        elif t == tp.MsgType.CONTACT:
            self.counts["CONTACT"] += 1
            for c in self.contacts.values():
                self.contact_log.append((self.contact_tick, c))
            del self.contact_log[:-4000]
        elif t == tp.MsgType.ACK:
            self.counts["ACK"] += 1
            self.acks.append((self.acked_tick, self.acked_seq))
            del self.acks[:-4000]
            if self.record:
                self.history[self.acked_tick] = {
                    s: (list(m.heights), m.complete) for s, m in self.mirrors.items()}
                for old in [k for k in self.history if k < self.acked_tick - self.keep]:
                    del self.history[old]
            if self.on_ack:
                self.on_ack(self.acked_tick, self.acked_seq)


async def compare_with_server(client, daemon, sid, region, keep_acking, attempts=6,
                              deadline_s=None):
    """GET /v1/heights of region, wait for the client's ACK of that tick, and
    compare the mirror copy at that tick. keep_acking is an async callable
    that sends one (parked) pose batch, so that every tick gets an ACK.
    deadline_s bounds all the attempts together (a test's ctest timeout must
    end in a failure that says why, not in a kill). Returns (same, tick, detail)."""
    loop = asyncio.get_running_loop()
    end = None if deadline_s is None else loop.time() + deadline_s
    detail = "no attempt"
    tick = None
    for _ in range(attempts):
        if end is not None and loop.time() >= end:
            detail += f" (gave up after {deadline_s} s)"
            break
        await keep_acking()
        tick, server = await loop.run_in_executor(None, daemon.heights, *region)
        if tick is None:
            return False, None, "GET /v1/heights has no X-Terrad-Tick header"
        deadline = loop.time() + 30  # generous: a loaded machine's client reads late
        if end is not None:
            deadline = min(deadline, end)
        while client.acked_tick < tick and loop.time() < deadline:
            await keep_acking()
            await asyncio.sleep(0.008)
        mine = client.history.get(tick, {}).get(sid)
        if mine is None:
            detail = f"no mirror copy at tick {tick} (acked up to {client.acked_tick})"
            continue
        heights, complete = mine
        if not complete:
            detail = f"mirror incomplete at tick {tick}"
            continue
        if heights == server:
            return True, tick, ""
        diff = [i for i in range(len(server)) if heights[i] != server[i]]
        x, y, w, h = region
        i = diff[0]
        return False, tick, (f"{len(diff)} of {len(server)} cells differ at tick {tick}; first at "
                             f"({x + i % w},{y + i // w}): mirror {heights[i]}, server {server[i]}")
    return False, tick, detail


WHEEL_Q = (math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0)  # cylinder axis z -> world -y


async def hello_ok(d, name, timeout=30):
    """A new client of d (anything with .ws) gets its world message."""
    c = tp.TerradClient(d.ws, name=name)
    try:
        await asyncio.wait_for(c.connect(), timeout)
        return bool(c.world)
    finally:
        await c.close()


async def raw_hello(node, world, token="", answer_s=10, close_s=3):
    """A raw hello naming a world on node (anything with .ws): (the first
    answer, the close code or None; None when no close came within close_s)."""
    import websockets
    ws = await websockets.connect(node.ws, subprotocols=[tp.SUBPROTOCOL], close_timeout=2)
    await ws.send(json.dumps(tp.hello(token, "world-check", world)))
    answer = json.loads(await asyncio.wait_for(ws.recv(), answer_s))
    code = None
    try:
        await asyncio.wait_for(ws.recv(), close_s)
    except websockets.ConnectionClosed as e:
        code = e.code
    except asyncio.TimeoutError:
        pass
    await ws.close()
    return answer, code


class EventWatcher:
    """A raw websocket connection to node (anything with .ws) that says hello
    (into world, if given) and asks for events with subscribe_events
    (PROTOCOL.md "Events"): answer() is the reply to that, next_event() the
    next {"type": "event"} message (None when none came within timeout)."""

    def __init__(self, node, token="", world="", events=("world_created", "world_deleted")):
        self.node, self.token, self.world, self.events = node, token, world, list(events)
        self.ws = None
        self.hello = None

    async def connect(self, timeout=60):
        import websockets
        self.ws = await websockets.connect(self.node.ws, subprotocols=[tp.SUBPROTOCOL],
                                           close_timeout=2)
        await self.ws.send(json.dumps(tp.hello(self.token, "event-watcher", self.world)))
        self.hello = json.loads(await asyncio.wait_for(self.ws.recv(), timeout))
        return self

    async def subscribe(self, events=None, timeout=60):
        """subscribe_events; returns its answer (events_subscribed or an error)."""
        await self.ws.send(json.dumps(tp.subscribe_events(self.events if events is None
                                                          else events, ref="ev")))
        return await self._next(lambda m: m.get("ref") == "ev", timeout)

    async def next_event(self, timeout=90, event=None, world=None):
        """The next event (of that name, about that world, when given)."""
        return await self._next(lambda m: m.get("type") == "event" and
                                event in (None, m.get("event")) and
                                world in (None, m.get("world")), timeout)

    async def _next(self, wanted, timeout):
        loop = asyncio.get_running_loop()
        end = loop.time() + timeout
        while loop.time() < end:
            try:
                msg = await asyncio.wait_for(self.ws.recv(), max(0.01, end - loop.time()))
            except asyncio.TimeoutError:
                return None
            if isinstance(msg, str) and wanted(json.loads(msg)):
                return json.loads(msg)
        return None

    async def close(self):
        if self.ws:
            await self.ws.close()


def wheel_pose(cid, x, y, z):
    """A cylinder (axis z in its frame) turned so that it rolls along x."""
    return tp.Pose(cid, x, y, z, *WHEEL_Q)


def run(coro):
    return asyncio.run(coro)
