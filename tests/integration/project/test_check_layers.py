#!/usr/bin/python3
# ctest-timeout: 60
"""scripts/check_layers on synthetic trees: each rule is broken once on
purpose and must be named (file, line, edge), each limit is checked on both
sides of its bound, and a clean tree passes. Each tree carries the real
docs/design.md, whose "Layers" table is then broken (a floor moved, a row
gone, a face misnamed) beside folders it does not list and a second public
header. The real tree is checked by the check_layers test itself."""
import importlib.machinery
import importlib.util
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks  # noqa: E402

SCRIPT = os.path.join(SOURCE, "scripts", "check_layers")
check = Checks()


def function_of(name, lines):
    """A C function whose signature-to-closing-brace span is `lines` lines."""
    body = ["    x++;"] * (lines - 3)
    return "\n".join([f"static void {name}(int x)", "{"] + body + ["}"]) + "\n"


def run(files, *args):
    with tempfile.TemporaryDirectory() as root:
        for rel, text in files.items():
            path = os.path.join(root, rel)
            os.makedirs(os.path.dirname(path), exist_ok=True)
            if not rel.endswith("/"):  # a name ending in / is a folder, maybe empty
                with open(path, "w") as f:
                    f.write(text)
        p = subprocess.run(["/usr/bin/python3", SCRIPT, "--root", root, *args],
                           capture_output=True, text=True, timeout=30)
        return p.returncode, p.stdout


CLEAN = {
    "server/base/base.h": "int base(void);\n",
    "server/world/world.h": '#include "base/base.h"\n',
    "server/sim/sim.h": '#include "ground/ground.h"\n#include "world/world.h"\n',
    "server/ground/ground.h": '#include "world/world.h"\n',
    "server/gl/gl_internal.h": '#include "gl.h"\n',
    "server/gl/gl.h": '#include "sim/sim.h"\n',
    "server/gl/backend.c": '#include "gl_internal.h"\n#include "terrad_proto.h"\n' + function_of("f", 120),
    "server/service/service.c": '#include "gl/gl.h"\n#include "hub/hub.h"\n',
    "server/hub/hub.h": '#include "sim/sim.h"\n',
    "server/app/app.h": '#include "service/service.h"\n',
    "server/service/service.h": "",
    "server/main.c": '#include "app/app.h"\n',
    "proto/c/terrad_proto.h": "",
    "proto/c/terrad_proto.c": '#include "terrad_proto.h"\n',
    "server/twin/terrad_twin.h": '#include "sim/sim.h"\n',
    "clients/c/terrad_client.h": '#include "terrad_proto.h"\n',
    "clients/c/terrad_client_internal.h": '#include "terrad_client.h"\n',
    "clients/c/terrad_client.c": '#include "terrad_client_internal.h"\n#include "terrad_twin.h"\n',
    "server/app/loadgen.c": '#include "terrad_client.h"\n',
    "server/sim/long.c": "int x;\n" * 800,
}


def load_script():
    loader = importlib.machinery.SourceFileLoader("check_layers", SCRIPT)
    module = importlib.util.module_from_spec(importlib.util.spec_from_loader(loader.name, loader))
    loader.exec_module(module)
    return module


LAYERS = load_script()
with open(os.path.join(SOURCE, LAYERS.DESIGN), encoding="utf-8") as design_file:
    DESIGN = design_file.read()
ROWS = LAYERS.design_rows(SOURCE, [])
# Every path the real table names, with its face in the row's first folder: the table holds here.
for _, _, _, where, face in ROWS:
    CLEAN.setdefault(where[0] + face if where[0].endswith("/") else where[0], "")
    for rel in where[1:]:
        CLEAN.setdefault(rel, "")
CLEAN[LAYERS.DESIGN] = DESIGN


def design_line(name):
    """The line number of subsystem name's row in the real table, and that row's line."""
    number = next(row[0] for row in ROWS if row[2] == name)
    return number, DESIGN.splitlines()[number - 1]


def edited(line, new):
    """CLEAN with the real table's line `line` replaced by new (None: removed)."""
    lines = DESIGN.splitlines(keepends=True)
    lines[line - 1] = "" if new is None else new + "\n"
    return dict(CLEAN, **{LAYERS.DESIGN: "".join(lines)})


def check_design():
    number, line = design_line("host")
    layer = LAYERS.LAYER_OF["host"]
    tree = edited(number, line.replace(f"| {layer} | host |", f"| {layer + 1} | host |", 1))
    rc, out = run(tree)
    check(rc == 1 and offences(out) == [
        f"docs/design.md:{number}: subsystem 'host' is on layer {layer + 1} here and on layer "
        f"{layer} in scripts/check_layers LAYERS"], f"a floor moved in design.md fails, named:\n{out}")

    tree = dict(CLEAN, **{"server/foo/": ""})
    rc, out = run(tree)
    check(rc == 1 and offences(out) == [
        "server/foo/:1: a folder that neither docs/design.md's \"Layers\" table nor "
        "scripts/check_layers LAYERS lists"], f"an empty folder in server/ fails, named:\n{out}")

    tree = dict(CLEAN, **{"clients/cpp/": ""})
    rc, out = run(tree)
    check(rc == 1 and offences(out) == [
        "clients/cpp/:1: a folder that docs/design.md's \"Layers\" table does not list"],
          f"a folder in clients/ that the table does not list fails:\n{out}")

    number, _ = design_line("world")
    rc, out = run(edited(number, None))
    check(rc == 1 and offences(out) == [
        "docs/design.md:1: subsystem 'world' of scripts/check_layers LAYERS is not in the "
        "\"Layers\" table",
        "server/world/:1: a folder that docs/design.md's \"Layers\" table does not list"],
          f"a subsystem missing from design.md fails:\n{out}")

    number, line = design_line("gl")
    rc, out = run(edited(number, line.replace("`gl.h`", "`gl_face.h`", 1)))
    check(rc == 1 and offences(out) == [
        f"docs/design.md:{number}: the face of 'gl' is gl_face.h here, but its public header is "
        "gl.h"], f"a face design.md misnames fails:\n{out}")

    number, _ = design_line("sim")
    rc, out = run(dict(CLEAN, **{"server/sim/extra.h": ""}))
    check(rc == 1 and offences(out) == [
        f"docs/design.md:{number}: 'sim' has 2 public headers (extra.h, sim.h); a subsystem has "
        "one, its face"], f"a second public header fails:\n{out}")


def offences(out):
    return [line for line in out.splitlines() if not line.startswith("check_layers:")]


def main():
    rc, out = run(CLEAN)
    check(rc == 0 and offences(out) == [], f"a clean tree passes (rc {rc}):\n{out}")

    tree = dict(CLEAN)
    tree["server/ground/ground.h"] = '#include "world/world.h"\n\n#include "sim/sim.h"\n'
    rc, out = run(tree)
    check(rc == 1 and offences(out) == [
        'server/ground/ground.h:3: forbidden edge ground -> sim ("sim/sim.h"): sim (layer 3) '
        "is a higher layer than ground (layer 2)"], f"an upward edge fails, named:\n{out}")
    rc, out = run(tree, "--report")
    check(rc == 0 and len(offences(out)) == 1, f"--report prints it and exits 0 (rc {rc}):\n{out}")

    tree = dict(CLEAN)
    tree["server/scene/scene.c"] = '#include "store/store.h"\n'
    tree["server/store/store.h"] = ""
    rc, out = run(tree)
    check(rc == 1 and len(offences(out)) == 1 and "server/scene/scene.c:1: forbidden edge scene -> store"
          in out and "the same layer" in out, f"a same-layer edge fails:\n{out}")

    tree = dict(CLEAN)
    tree["server/service/service.c"] = '#include "gl/gl.h"\n#include "gl/gl_internal.h"\n'
    rc, out = run(tree)
    check(rc == 1 and offences(out) == [
        'server/service/service.c:2: includes "gl/gl_internal.h", an internal header of gl '
        "(only server/gl/ may include it)"], f"an internal header from outside fails:\n{out}")

    tree = dict(CLEAN)
    tree["proto/c/terrad_proto.c"] = '#include "terrad_proto.h"\n#include "terrad_twin.h"\n'
    tree["server/sim/sim.c"] = '#include "terrad_client.h"\n'
    tree["server/net/net.c"] = '#include "terrad_client_internal.h"\n'
    rc, out = run(tree)
    check(rc == 1 and sorted(offences(out)) == [
        'proto/c/terrad_proto.c:2: forbidden edge proto -> twin ("terrad_twin.h"): twin (layer 4) '
        "is a higher layer than proto (layer 0)",
        'server/net/net.c:1: includes "terrad_client_internal.h", an internal header of clients '
        "(only clients/c/ may include it)",
        'server/sim/sim.c:1: forbidden edge sim -> clients ("terrad_client.h"): clients (layer 5) '
        "is a higher layer than sim (layer 3)"],
          f"proto/ and clients/ are in the layering: the wire includes no server header, the "
          f"server below clients/ includes none of it:\n{out}")

    tree = dict(CLEAN)
    tree["server/tick/tick.c"] = '#include "sim/sim.h"\n'
    rc, out = run(tree)
    check(rc == 1 and "server/tick/tick.c:1: subsystem 'tick' is not in the layer table" in out,
          f"a folder outside the layer table fails:\n{out}")

    tree = dict(CLEAN)
    tree["server/sim/long.c"] = "int x;\n" * 801
    rc, out = run(tree)
    check(rc == 1 and offences(out) == ["server/sim/long.c:1: 801 lines (more than 800)"],
          f"a file of 801 lines fails:\n{out}")

    tree = dict(CLEAN)
    tricky = ('struct s {\n    int a;\n};\nstatic const int table[] = {1, 2};\n'
              '#define BLOCK(x) { x; }\n/* { a comment brace */\n'
              'static int\nlong_one(int x)\n{\n    const char *s = "{";\n    char c = \'}\';\n'
              '    if (x) {\n        x++;\n    }\n' + "    x++;\n" * 111 + "    return x + s[0] + c;\n}\n")
    tree["server/sim/fn.c"] = tricky + function_of("short_one", 120)
    rc, out = run(tree)
    check(rc == 1 and offences(out) == ["server/sim/fn.c:7: function long_one is 121 lines (more than 120)"],
          f"a function of 121 lines fails, one of 120 passes, braces in strings, comments, macros "
          f"and initialisers are ignored:\n{out}")

    check_design()
    check.finish()


if __name__ == "__main__":
    main()
