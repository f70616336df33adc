#!/usr/bin/python3
# ctest-timeout: 900 (generous: make run configures and checks the build tree on a busy machine)
# ctest-lock: build-tree (make run reconfigures and may rebuild the build tree)
"""Every command the README shows runs in a test, or says why it cannot (issue 28 item 6): a
newcomer's path must not break unseen, as `make run` then `make test` once did.

- The shell blocks (```sh) of README.md and of the pages its quick starts lead to (PAGES) are
  read, continuation lines joined, comments dropped: one command a line; and the README's inline
  commands (a `code span` that starts with make, terrad, ./build/terrad or scripts/deps).
- Each command must be in COMMANDS, which says how it is exercised: run here, for real, on
  loopback (free ports; the docs' 8080/8081, make run's defaults, become the daemon's own, and
  ./build/terrad the binary under test), or the name of the test that runs it, or why it cannot
  run in a test at all (`make test` itself). A command the docs gain that COMMANDS does not know
  fails, and so does an entry of COMMANDS the docs no longer show (a stale table).
- Run here: `make run` itself (the daemon up, GET /healthz 200, GET /terrad_twin.wasm a wasm
  module, SIGTERM, make exits 0), `scripts/deps` and its sets, `terrad --help`, the game
  backend's curl calls (an edit's exact volume change, a world created, listed and deleted), an
  export of a data directory, an offline simulate, and token add / token hash.
- The docs' links: every relative link of README.md, docs/**/*.md, proto/PROTOCOL.md and the
  clients' READMEs leads to a file (and a heading, for a #fragment into a page), and
  docs/README.md names every page of docs/.
"""
import glob
import hashlib
import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, PORTS_RE, SOURCE, Checks, Daemon, children_of  # noqa: E402

check = Checks()
# README.md and the pages made from its old sections (each user's quick start).
PAGES = ["README.md", "docs/quickstart-game-backend.md", "docs/quickstart-simulator.md",
         "docs/quickstart-viewer.md", "docs/clients.md", "docs/operations.md", "docs/security.md"]


def shell_commands(text):
    """The commands of text's ```sh blocks: continuations joined, comments dropped."""
    out = []
    for block in re.findall(r"```(?:sh|bash|shell)\n(.*?)```", text, re.S):
        joined = re.sub(r"\\\n\s*", " ", block)
        for line in joined.splitlines():
            line = re.sub(r"\s+#\s.*$", "", line).strip()  # a trailing "  # ..." comment
            if line and not line.startswith("#"):
                out.append(re.sub(r"\s+", " ", line))
    return out


def inline_commands(text):
    """The commands in text's inline code spans (outside fenced blocks): those that start with
    make, terrad, ./build/terrad or scripts/deps."""
    text = re.sub(r"```.*?```", "", text, flags=re.S).replace("\n", " ")
    return [re.sub(r"\s+", " ", c.strip()) for c in re.findall(r"`([^`]+)`", text)
            if re.match(r"(make|terrad|\./build/terrad|scripts/deps)( |$)", c.strip())]


def sub(cmd, d=None):
    """A command as run here: the binary under test, and a daemon's own ports."""
    cmd = cmd.replace("./build/terrad", shlex.quote(BIN))
    if d is not None:
        cmd = cmd.replace("127.0.0.1:8080", f"127.0.0.1:{d.http_port}")
        cmd = cmd.replace("127.0.0.1:8081", f"127.0.0.1:{d.ws_port}")
    return cmd


def sh(cmd, cwd=SOURCE, env=None, timeout=600):
    return subprocess.run(["bash", "-c", cmd], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=None if env is None else {**os.environ, **env})


def http_get(url):
    with urllib.request.urlopen(url, timeout=60) as r:
        return r.status, r.read()


class Context:
    """What the commands run here share: one daemon (the default scene, no demo) started on
    first use, and a scratch directory."""

    def __init__(self):
        self.tmp = tempfile.mkdtemp(prefix="terrad-readme-")
        self.daemon = None
        self.token = None

    def d(self):
        if self.daemon is None:
            self.daemon = Daemon(name="terrad-readme")
            check.daemons.append(self.daemon)
        return self.daemon

    def close(self):
        if self.daemon is not None:
            st = self.daemon.stop()
            check(st == 0, f"SIGTERM stops the daemon with status 0 ({st})")
        shutil.rmtree(self.tmp, ignore_errors=True)


# ---- the commands run here -----------------------------------------------------------------

def run_make_run(cmd, ctx):
    """`make run` as the README says, on free ports (ARGS, as the docs show it) and on the build
    tree under test (BUILD): the daemon serves, /healthz answers, the wasm twin is served (it is
    what make run once left out), and SIGTERM stops it with make exiting 0."""
    build = os.path.relpath(os.path.dirname(BIN), SOURCE)
    if build.startswith(".."):
        check(False, f"make run: the binary under test ({BIN}) is outside the source tree")
        return
    argv = shlex.split(cmd) + [f"BUILD={build}", "ARGS=--http-port 0 --ws-port 0"]
    log = os.path.join(ctx.tmp, "make-run.log")
    with open(log, "w") as out:
        make = subprocess.Popen(argv, cwd=SOURCE, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    http = None
    deadline = time.monotonic() + 600
    try:
        while http is None and make.poll() is None and time.monotonic() < deadline:
            m = PORTS_RE.search(open(log, errors="replace").read())
            if m:
                http = f"{m.group(1)}://127.0.0.1:{m.group(2)}"
            else:
                time.sleep(0.5)
        if not check(http is not None, "make run: the daemon printed the addresses it serves"):
            return
        status, _ = http_get(http + "/healthz")
        check(status == 200, f"make run: GET /healthz answers 200 ({status})")
        status, body = http_get(http + "/terrad_twin.wasm")
        check(status == 200 and body[:4] == b"\0asm",
              f"make run: GET /terrad_twin.wasm serves the WebAssembly twin ({status}, {body[:4]!r})")
        # make's one child is the daemon (the recipe execs it): SIGTERM to it, as Ctrl-C would
        kids = children_of(make.pid)
        check(len(kids) == 1, f"make run: one child, the daemon ({kids})")
        for pid in kids:
            os.kill(pid, signal.SIGTERM)
        try:
            st = make.wait(120)
        except subprocess.TimeoutExpired:
            st = None
        check(st == 0, f"make run: SIGTERM stops the daemon and make exits 0 ({st})")
    except Exception as e:  # noqa: BLE001
        check(False, f"make run: {e!r}")
    finally:
        if make.poll() is None:
            os.killpg(make.pid, signal.SIGKILL)
            make.wait()
        if check.failed:
            print(open(log, errors="replace").read()[-4000:])


def run_deps(cmd, ctx):
    r = sh(cmd)  # make test installed --test, which includes every set: nothing to install
    check(r.returncode == 0, f"{cmd}: {r.returncode} {r.stdout[-500:]} {r.stderr[-500:]}")


def run_help(cmd, ctx):
    r = sh(sub(cmd.replace("terrad", "./build/terrad", 1)))
    out = r.stdout + r.stderr
    check(r.returncode == 0 and all(c in out for c in ("serve", "simulate", "export", "calibrate")),
          f"{cmd}: exits 0 and names the commands ({r.returncode}): {out[:300]}")


def run_curl_edit(cmd, ctx):
    d = ctx.d()
    r = sh(sub(cmd, d))
    try:
        ans = json.loads(r.stdout)
    except ValueError:
        ans = {}
    # 20 x 20 cells, 500 units each: exactly 200,000 units, as the page shows
    check(r.returncode == 0 and ans.get("op") == "add" and ans.get("volume_change") == 200000,
          f"{cmd}: {r.stdout} {r.stderr}")


def run_curl_worlds(cmd, ctx):
    d = ctx.d()
    r = sh(sub(cmd, d))
    try:
        ans = json.loads(r.stdout) if r.stdout.strip() else {}
    except ValueError:
        ans = {"raw": r.stdout}
    names = [w.get("name") for w in ans.get("worlds", [])]
    ok = r.returncode == 0
    if "-X POST" in cmd:
        ok = ok and ans.get("name") == "match-17" and ans.get("state") == "running"
    elif "-X DELETE" in cmd:
        _, body = http_get(d.http + "/v1/worlds")
        ok = ok and "match-17" not in [w["name"] for w in json.loads(body)["worlds"]]
    else:
        ok = ok and "match-17" in names and any(w.get("default") for w in ans.get("worlds", []))
    check(ok, f"{cmd}: {r.returncode} {r.stdout[-800:]} {r.stderr[-300:]}")


def run_export(cmd, ctx):
    """A data directory with a world in it (the default scene, demo actors digging), then the
    export as the page writes it, from a directory whose ./data is that world."""
    data = os.path.join(ctx.tmp, "data")
    d = Daemon(name="terrad-export", demo=True, data_dir=data)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            _, body = http_get(d.http + "/v1/stats")
            if json.loads(body)["tick"] >= 30:
                break
            time.sleep(0.2)
    finally:
        st = d.stop()
    check(st == 0, f"export: the daemon that wrote ./data stopped with 0 ({st})")
    r = sh(sub(cmd), cwd=ctx.tmp)
    png = os.path.join(ctx.tmp, "world.png")
    ok = r.returncode == 0 and os.path.exists(png) and os.path.exists(png + ".json")
    check(ok and "export: world.png 256x256 at 0,0" in r.stderr, f"{cmd}: {r.stderr[-800:]}")
    if os.path.exists(png):
        with open(png, "rb") as f:
            check(f.read(8) == b"\x89PNG\r\n\x1a\n", "export: world.png is a PNG")


def run_simulate(cmd, ctx):
    r = sh(sub(cmd))
    try:
        out = json.loads(r.stdout)
    except ValueError:
        out = {}
    check(r.returncode == 0 and out.get("backend") == "cpu" and out.get("ticks") == 5000
          and out.get("volume_before") == out.get("volume_after"),
          f"{cmd}: {r.returncode} {r.stdout[-500:]} {r.stderr[-500:]}")


def run_token_add(cmd, ctx):
    r = sh(sub(cmd), cwd=ctx.tmp)
    ctx.token = r.stdout.strip()
    check(r.returncode == 0 and ctx.token.startswith("tdk_"), f"{cmd}: {r.stdout} {r.stderr}")
    line = open(os.path.join(ctx.tmp, "tokens")).read().split()
    check(line[:2] == ["driver", "car-7"]
          and line[2] == hashlib.sha256(ctx.token.encode()).hexdigest(),
          f"{cmd}: the file holds 'driver car-7 SHA256' ({line})")


def run_token_hash(cmd, ctx):
    r = sh(sub(cmd), cwd=ctx.tmp, env={"TOKEN": ctx.token or ""})
    line = open(os.path.join(ctx.tmp, "tokens")).read().split()
    check(r.returncode == 0 and r.stdout.strip() == line[2],
          f"{cmd}: prints the hash token add wrote ({r.stdout.strip()} vs {line[2]})")


# ---- every command the pages show, and how it is exercised -------------------------------
# A callable: run here. "test_name: what": that test runs it (the name is checked to exist).
# "-: why": it cannot run in a test.
COMMANDS = {
    # README.md
    "make run": run_make_run,
    "make test": "-: the whole suite, of which this test is one; .ci/run runs it after make run",
    # README.md, inline
    "make run ARGS=--no-demo": "test_serve: --no-demo (every daemon of the tests but the demo's "
                               "runs it; make run with ARGS runs here, with its ports)",
    "terrad --help": run_help,
    "make test-stress": "-: make test, of which this test is one, beside a CPU hog",
    "make build": "-: what make test does first; every test here runs on what it built",
    "make install": "test_install: what it installs, used as a user would",
    "make screenshot": "test_screenshot: scripts/screenshot.mjs against a real daemon",
    "make chaos": "test_chaos: two of its schedules, fixed seed (make chaos runs 200, about an "
                  "hour on 2 cores)",
    "terrad calibrate": "test_calibrate: plates and the Ding 2011 wheel",
    "terrad simulate": "test_simulate: every method and metric on both backends",
    "scripts/deps": run_deps,
    "scripts/deps --build": run_deps,
    "scripts/deps --runtime": run_deps,
    # docs/clients.md
    "make web-deps": "-: npm ci replaces node_modules, which the browser tests use while this one "
                     "runs; make test runs it as its first step",
    "cd clients/js && npm pack": "test_ts_client: packs the package, installs the tarball, runs it",
    "scripts/deps --python": run_deps,
    "/usr/bin/python3 -m venv --system-site-packages venv":
        "test_python_package: a fresh venv that sees Debian's modules",
    "venv/bin/pip install --no-deps --no-build-isolation ./clients/python":
        "test_python_package: pip installs a copy of clients/python into it",
    "venv/bin/python clients/python/examples/drive_wheel.py":
        "test_python_package: runs the example from the venv (test_readme_example: from the tree)",
    "make install PREFIX=$HOME/.local": "test_install: installs into a temporary prefix",
    "export PKG_CONFIG_PATH=$HOME/.local/lib/pkgconfig":
        "test_install: pkg-config with the prefix's lib/pkgconfig",
    "cc clients/c/examples/drive_wheel.c -o drive_wheel $(pkg-config --cflags --libs terrad-client) -lm":
        "test_install: builds the installed drive_wheel.c with pkg-config, shared and static",
    "./drive_wheel 127.0.0.1 8081 8080": "test_install: runs it against a daemon, no LD_LIBRARY_PATH",
    "make install PREFIX=/tmp/terrad": "test_install: installs into a temporary prefix",
    "cc /tmp/terrad/share/doc/terrad/examples/twin_rut.c $(PKG_CONFIG_PATH=/tmp/terrad/lib/pkgconfig "
    "pkg-config --cflags --libs terrad-twin) -o twin_rut": "test_install: builds the installed twin_rut.c",
    "./twin_rut": "test_install: runs twin_rut from the installed library",
    # docs/operations.md
    "make run ARGS='--data data'": "test_store_crash: a daemon on a data directory, recovered "
                                   "(make run with ARGS runs here, with its ports)",
    "./build/terrad export --data ./data --out world.png --format png16 --region 0,0,256,256":
        run_export,
    # docs/quickstart-game-backend.md
    "curl -X POST http://127.0.0.1:8080/v1/worlds/default-dunes/edits "
    "-d '{\"op\":\"add\",\"x\":10,\"y\":10,\"w\":20,\"h\":20,\"amount\":500}'": run_curl_edit,
    "curl -X POST http://127.0.0.1:8080/v1/worlds -d '{\"name\":\"match-17\",\"scene\":{\"name\":"
    "\"arena\",\"world\":{\"width\":256,\"height\":256,\"cell_size_m\":0.05},\"terrain\":"
    "{\"kind\":\"flat\",\"height_m\":0.5}}}'": run_curl_worlds,
    "curl http://127.0.0.1:8080/v1/worlds": run_curl_worlds,
    "curl -X DELETE http://127.0.0.1:8080/v1/worlds/match-17": run_curl_worlds,
    # docs/quickstart-simulator.md
    "./build/terrad calibrate --wheel tests/validation/single-wheel-ding2011.csv --where "
    "wheel=smooth --radius 0.15735 --width 0.165 --out ding-fitted.json --residuals "
    "ding-residuals.csv": "test_calibrate: the Ding 2011 smooth wheel fit, its residuals and JSON",
    "./build/terrad simulate --scene tests/scenes/thesis-car.json --ticks 5000 --backend gl":
        "test_simulate: the GL backend where a context can be made, equal to the CPU's heights",
    "./build/terrad simulate --scene tests/scenes/thesis-car.json --ticks 5000 --backend cpu "
    "--method multi --metric manhattan": run_simulate,
    "./build/terrad bench --trade": "-: the full sweep, ~9.5 min on 2 loaded cores (make bench, "
                                    "make docs-images); test_trade runs the --quick one",
    "./build/terrad bench --trade --quick --out /tmp/trade": "test_trade: the quick sweep, into a "
                                                              "temporary directory",
    # docs/security.md
    "./build/terrad token add --auth-file tokens --role driver --name car-7": run_token_add,
    "echo -n \"$TOKEN\" | ./build/terrad token hash": run_token_hash,
    "make run ARGS='--auth-file tokens'": "test_auth_roles: a daemon with an auth file "
                                         "(make run with ARGS runs here, with its ports)",
}


def check_links():
    """Every relative link of README.md, docs/, proto/PROTOCOL.md and the clients' READMEs resolves
    (and its #fragment names a heading); docs/README.md names every page."""
    def headings(path):
        out = set()
        for line in open(path, encoding="utf-8"):
            m = re.match(r"#+\s+(.*)", line)
            if m:
                out.add(re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-"))
        return out
    pages = ["README.md", "proto/PROTOCOL.md", "clients/js/README.md", "clients/python/README.md"] + \
        sorted(os.path.relpath(p, SOURCE) for p in
               glob.glob(os.path.join(SOURCE, "docs", "**", "*.md"), recursive=True))
    bad = []
    for page in pages:
        text = re.sub(r"```.*?```", "", open(os.path.join(SOURCE, page), encoding="utf-8").read(),
                      flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            path, _, frag = target.partition("#")
            full = os.path.normpath(os.path.join(SOURCE, os.path.dirname(page), path)) if path \
                else os.path.join(SOURCE, page)
            if not os.path.exists(full):
                bad.append(f"{page}: {target}")
            elif frag and full.endswith(".md") and frag not in headings(full):
                bad.append(f"{page}: {target} (no such heading)")
    check(not bad, f"every link in README.md, docs/, PROTOCOL.md and the clients' READMEs leads somewhere: {bad}")
    index = open(os.path.join(SOURCE, "docs", "README.md"), encoding="utf-8").read()
    missing = [p for p in pages if p.startswith("docs/") and p != "docs/README.md"
               and f"]({os.path.relpath(p, 'docs')})" not in index]
    for extra in ("openapi.yaml",):
        if f"]({extra})" not in index:
            missing.append("docs/" + extra)
    check(not missing, f"docs/README.md indexes every page of docs/: {missing}")


def main():
    shown = {}
    for page in PAGES:
        with open(os.path.join(SOURCE, page), encoding="utf-8") as f:
            text = f.read()
        for cmd in shell_commands(text):
            shown.setdefault(cmd, page)
        if page == "README.md":
            for cmd in inline_commands(text):
                shown.setdefault(cmd, "README.md (inline)")
    for cmd, page in shown.items():
        check(cmd in COMMANDS, f"{page} shows a command that no test knows: {cmd!r} "
                               "(run it in a test and add it to COMMANDS here)")
    for cmd in COMMANDS:
        check(cmd in shown, f"COMMANDS lists a command no page shows any more: {cmd!r}")
    tests = {os.path.splitext(os.path.basename(p))[0] for p in
             glob.glob(os.path.join(SOURCE, "tests", "**", "test_*.*"), recursive=True)}
    ctx = Context()
    try:
        for cmd in shown:
            how = COMMANDS.get(cmd)
            if callable(how):
                print(f"run: {cmd}", flush=True)
                how(cmd, ctx)
            elif how:
                name, _, why = how.partition(": ")
                check(name == "-" or name in tests, f"{cmd!r}: the test {name} exists")
                check(bool(why.strip()), f"{cmd!r}: says how it is exercised")
                print(f"{'cannot run' if name == '-' else 'by ' + name}: {cmd} ({why})", flush=True)
    except Exception as e:  # noqa: BLE001
        check(False, f"raised: {e!r}")
    finally:
        ctx.close()
    check_links()


main()
check.finish()
