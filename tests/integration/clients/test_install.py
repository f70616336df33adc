#!/usr/bin/python3
# ctest-timeout: 300
# ctest-lock: build-tree (cmake --install reads the build tree that make run may rebuild)
"""`cmake --install` into a temporary prefix, then use what it installed as a user would:

- the twin library (libterrad-twin.so.1, .a, terrad_twin.h, terrad-twin.pc, terrad_twin.wasm):
  the installed twin_rut.c example builds with pkg-config and runs with no LD_LIBRARY_PATH
- the daemon, the client library (shared with SONAME libterrad-client.so.1, and static), its
  headers and terrad-client.pc, the systemd unit, the example configuration and the man page
  land where GNUInstallDirs says;
- `terrad --version` prints the version of CMakeLists.txt's project() line;
- the installed terrad.json is accepted by `terrad serve --config` (a short run on free ports);
- the man page renders without groff warnings; the unit passes `systemd-analyze verify` where
  systemd-analyze exists (skipped otherwise);
- every range `--help` prints from an option's row ("N in [0, 65535]") is in the man page as
  --help prints it: serve's and simulate's in the option's own paragraph, wheel's, calibrate's
  and loadgen's in the command's (calibrate's wheel options in wheel's);
- the installed share/doc/terrad/examples/drive_wheel.c builds with `pkg-config --cflags --libs
  terrad-client` against the installed library, shared and then static (`--static`), and both
  binaries start and pass against a real daemon with the demo actors on (the mirror equals
  GET /v1/heights at the same tick) with no LD_LIBRARY_PATH: the pkg-config flags carry a run
  path to the prefix's lib/, so a program built against a non-system prefix starts as it is.
"""
import glob
import os
import re
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, Daemon, skip  # noqa: E402

check = Checks()
BUILD = os.path.dirname(BIN)
if not os.path.exists(os.path.join(BUILD, "cmake_install.cmake")):
    skip(f"{BUILD} is not a CMake build tree")
for tool in ("pkg-config", "cc", "cmake", "readelf"):
    if not shutil.which(tool):
        skip(f"{tool} missing")


def run(args, env=None, **kw):
    return subprocess.run(args, capture_output=True, text=True, timeout=240,
                          env=None if env is None else {**os.environ, **env}, **kw)


def help_ranges(terrad, command):
    """{option: "V in [lo, hi]"} from `terrad COMMAND --help`: the range cli_print_help ends a
    numeric option's help with."""
    out = run([terrad, command, "--help"]).stdout
    ranges, opt = {}, None
    for line in out.splitlines():
        if line.startswith("  --"):
            opt = line.split()[0]
        m = re.search(r"(\S+ in \[[^]]+\])$", line)
        if opt and m:
            ranges[opt] = m.group(1)
    return ranges


def man_paragraphs(man_source):
    """{(section, first line): text} of the man page source, escapes and .I undone, so
    "\\-\\-ticks" reads --ticks and ".I N\\nin [0,\\ 1e8]" reads "N in [0, 1e8]"."""
    paragraphs, section = {}, ""
    for chunk in re.split(r"^\.(?=SH |TP$)", man_source, flags=re.M):
        lines = chunk.replace("\\-", "-").replace("\\ ", " ").splitlines()
        if chunk.startswith("SH "):
            section = lines[0][3:].strip('"')
            continue
        body = [re.sub(r"^\.(I|B|BI|BR|RB) ", "", ln) for ln in lines[1:]]
        if body:
            paragraphs[(section, body[0].split()[0])] = " ".join(" ".join(body).split())
    return paragraphs


def one(pattern):
    found = glob.glob(os.path.join(prefix, pattern))
    check(len(found) == 1, f"installed: {pattern} ({found})")
    return found[0] if found else ""


with open(os.path.join(SOURCE, "CMakeLists.txt")) as f:
    version = re.search(r"project\(terrad VERSION (\d+\.\d+\.\d+)", f.read()).group(1)

prefix = tempfile.mkdtemp(prefix="terrad-install-")
try:
    r = run(["cmake", "--install", BUILD, "--prefix", prefix])
    check(r.returncode == 0, f"cmake --install: {r.stdout[-2000:]} {r.stderr[-2000:]}")

    terrad = one("bin/terrad")
    r = run([terrad, "--version"])
    check(r.stdout.strip() == f"terrad {version}", f"terrad --version says {version}: {r.stdout!r}")

    so = next((os.path.join(d, "libterrad-client.so.1") for d, _, files in os.walk(prefix)
               if "libterrad-client.so.1" in files), "")
    check(so != "", "installed: libterrad-client.so.1")
    if so:
        dyn = run(["readelf", "-d", so]).stdout
        check("Library soname: [libterrad-client.so.1]" in dyn, f"SONAME libterrad-client.so.1: {dyn}")
        real = os.path.realpath(so)
        check(real.endswith(f"libterrad-client.so.{version}"), f"the real file is .so.{version}: {real}")
    libdir = os.path.dirname(so)
    check(os.path.exists(os.path.join(libdir, "libterrad-client.so")), "the libterrad-client.so link")
    check(os.path.exists(os.path.join(libdir, "libterrad-client.a")), "libterrad-client.a")
    pc = os.path.join(libdir, "pkgconfig", "terrad-client.pc")
    check(os.path.exists(pc), "pkgconfig/terrad-client.pc")
    for h in ("terrad_client.h", "terrad_proto.h"):
        check(os.path.exists(os.path.join(prefix, "include", "terrad", h)), f"include/terrad/{h}")

    # The example configuration: every key is one `terrad serve --config` accepts.
    conf = one("etc/terrad/terrad.json")
    data = tempfile.mkdtemp(prefix="terrad-install-data-")
    r = run([terrad, "serve", "--config", conf, "--backend", "cpu", "--http-port", "0",
             "--ws-port", "0", "--data", data, "--ticks", "3"])
    shutil.rmtree(data, ignore_errors=True)
    check(r.returncode == 0 and "stopping after tick" in r.stderr,
          f"terrad serve --config <installed terrad.json> runs: {r.returncode} {r.stderr[-2000:]}")

    man = one("share/man/man1/terrad.1")
    if shutil.which("groff"):
        r = run(["groff", "-man", "-Tutf8", "-ww", "-z", man])
        check(r.returncode == 0 and r.stderr == "", f"the man page renders without warnings: {r.stderr}")
        text = run(["groff", "-man", "-Tascii", "-P", "-cbou", man]).stdout
        check(f"terrad {version}" in text and "--config FILE" in text,
              "the man page names the version and the options")

    # The ranges: --help prints them from the rows, the man page is written by hand.
    with open(man) as f:
        paragraphs = man_paragraphs(f.read())
    serve_ranges = help_ranges(terrad, "serve")
    check(len(serve_ranges) >= 10, f"serve --help prints its options' ranges: {serve_ranges}")
    for command, section in (("serve", "SERVE OPTIONS"), ("simulate", "SIMULATE OPTIONS")):
        for opt, want in help_ranges(terrad, command).items():
            said = paragraphs.get((section, opt), "")
            check(want in said, f"man {section} {opt}: {want!r} as --help says (man: {said!r})")
    for command, where in (("wheel", ["wheel"]), ("loadgen", ["loadgen"]),
                           ("calibrate", ["calibrate", "wheel"])):
        said = " ".join(paragraphs.get(("COMMANDS", w), "") for w in where)
        for opt, want in help_ranges(terrad, command).items():
            check(want.split(" in ", 1)[1] in said,
                  f"man COMMANDS {command}: {opt}'s {want!r} as --help says (man: {said!r})")

    unit = one("lib/systemd/system/terrad.service")
    with open(unit) as f:
        unit_text = f.read()
    for opt in ("DynamicUser=yes", "StateDirectory=terrad", "ProtectSystem=strict",
                "NoNewPrivileges=yes", "PrivateTmp=yes"):
        check(opt in unit_text, f"the unit sets {opt}")
    if shutil.which("systemd-analyze"):
        # verify wants ExecStart's binary to exist: point it at the installed one.
        local = os.path.join(prefix, "terrad.service")
        with open(local, "w") as f:
            f.write(re.sub(r"ExecStart=\S+", f"ExecStart={terrad}", unit_text))
        r = run(["systemd-analyze", "verify", local])
        problems = [ln for ln in (r.stdout + r.stderr).splitlines()
                    if "terrad.service" in ln and "man terrad(1)" not in ln]
        check(not problems, f"systemd-analyze verify: {r.stdout} {r.stderr}")

    # The C example, built only from what was installed.
    env = {"PKG_CONFIG_PATH": os.path.dirname(pc)}
    flags = run(["pkg-config", "--cflags", "--libs", "terrad-client"], env=env)
    check(flags.returncode == 0 and "-lterrad-client" in flags.stdout, f"pkg-config: {flags.stdout} {flags.stderr}")
    static = run(["pkg-config", "--static", "--cflags", "--libs", "terrad-client"], env=env)
    example = one("share/doc/terrad/examples/drive_wheel.c")
    shared_bin, static_bin = os.path.join(prefix, "drive_wheel"), os.path.join(prefix, "drive_wheel_static")
    r = run(["cc", "-std=c11", "-Wall", "-Wextra", "-Werror", "-o", shared_bin, example]
            + flags.stdout.split() + ["-lm"])
    check(r.returncode == 0, f"cc drive_wheel.c $(pkg-config --cflags --libs terrad-client): {r.stderr}")
    if os.path.exists(shared_bin):
        dyn = run(["readelf", "-d", shared_bin]).stdout
        paths = re.findall(r"\((?:RUNPATH|RPATH)\)\s+Library r(?:un)?path: \[([^\]]*)\]", dyn)
        check(any(os.path.realpath(p) == os.path.realpath(libdir) for p in paths),
              f"the shared build's run path leads to {libdir}: {paths}")
    r = run(["cc", "-std=c11", "-Wall", "-Wextra", "-Werror", "-static-libgcc", "-o", static_bin, example]
            + [a.replace("-lterrad-client", os.path.join(libdir, "libterrad-client.a"))
               for a in static.stdout.split()] + ["-lm"])
    check(r.returncode == 0, f"cc drive_wheel.c with libterrad-client.a (pkg-config --static): {r.stderr}")
    if os.path.exists(static_bin):
        needed = run(["readelf", "-d", static_bin]).stdout
        check("libterrad-client" not in needed, "the static build does not load libterrad-client.so")

    # The twin library (docs/engines.md): SONAME, static archive, header, .pc, the wasm module,
    # and the installed example built with pkg-config and run with no LD_LIBRARY_PATH.
    twin_so = os.path.join(libdir, "libterrad-twin.so.1")
    check(os.path.exists(twin_so), "installed: libterrad-twin.so.1")
    if os.path.exists(twin_so):
        dyn = run(["readelf", "-d", twin_so]).stdout
        check("Library soname: [libterrad-twin.so.1]" in dyn, f"SONAME libterrad-twin.so.1: {dyn}")
    check(os.path.exists(os.path.join(libdir, "libterrad-twin.a")), "libterrad-twin.a")
    check(os.path.exists(os.path.join(prefix, "include", "terrad", "terrad_twin.h")),
          "include/terrad/terrad_twin.h")
    # the wasm module whenever its toolchain is here, and always under make test (which
    # installed it): a cached configure once left it out (issue 28)
    if os.path.exists("/usr/lib/wasm32-wasi/libc.a") or os.environ.get("TERRAD_REQUIRE_WASM") == "1":
        check(os.path.exists(os.path.join(prefix, "share", "terrad", "terrad_twin.wasm")),
              "share/terrad/terrad_twin.wasm")
    twin_flags = run(["pkg-config", "--cflags", "--libs", "terrad-twin"], env=env)
    check(twin_flags.returncode == 0 and "-lterrad-twin" in twin_flags.stdout,
          f"pkg-config terrad-twin: {twin_flags.stdout} {twin_flags.stderr}")
    twin_bin = os.path.join(prefix, "twin_rut")
    r = run(["cc", "-std=c11", "-Wall", "-Wextra", "-Werror", "-o", twin_bin,
             one("share/doc/terrad/examples/twin_rut.c")] + twin_flags.stdout.split())
    check(r.returncode == 0, f"cc twin_rut.c $(pkg-config --cflags --libs terrad-twin): {r.stderr}")
    if os.path.exists(twin_bin):
        env_run = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
        r = subprocess.run([twin_bin], capture_output=True, text=True, timeout=60, env=env_run,
                           cwd="/")
        check(r.returncode == 0 and "rut: lowest cell" in r.stdout,
              f"twin_rut runs from the installed library: {r.stdout} {r.stderr}")

    d = Daemon(backend="cpu", demo=True, name="terrad-install")
    with check.running(d):
        for exe in (shared_bin, static_bin):
            if not os.path.exists(exe):
                continue
            # As a user starts it: no LD_LIBRARY_PATH, from another directory.
            env = {k: v for k, v in os.environ.items() if k != "LD_LIBRARY_PATH"}
            r = subprocess.run([exe, "127.0.0.1", str(d.ws_port), str(d.http_port)],
                               capture_output=True, text=True, timeout=240, env=env, cwd="/")
            print(f"{os.path.basename(exe)}: {r.stdout.strip()}")
            check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
                  f"{os.path.basename(exe)} against the daemon: {r.stdout} {r.stderr[-2000:]}")
            check("lws" not in r.stderr and "libwebsockets" not in r.stderr.lower(),
                  f"libwebsockets printed nothing into the host's stderr: {r.stderr[-1000:]}")
finally:
    shutil.rmtree(prefix, ignore_errors=True)
check.finish()
