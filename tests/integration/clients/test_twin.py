#!/usr/bin/python3
# ctest-timeout: 600
"""The twin library (server/twin/terrad_twin.h, docs/engines.md) against the daemon's twin.

- Every scene under tests/scenes/ and the lugged wheel's (tests/scenes/lugged/: grousers,
  terrad_twin_add_wheel), and one small scene per deformation model (a sphere, a smooth
  and a lugged wheel rolling: on bekker its lug thrust too, on a soil with its own density) is
  run by `terrad simulate --backend cpu` and replayed through the twin library
  twice: natively (tests/support/twin_replay.c, linked to libterrad-twin.so
  alone) and as WebAssembly under Node (tests/support/twin_replay.mjs over
  build/terrad_twin.wasm with web/twin.mjs). The final heights differ in 0
  cells, and the scene did deform (so equality is not trivial). A scene the
  library does not take (per-cell materials) is named and counted as skipped.
- Bad input to the C API (ctypes over libterrad-twin.so): an unknown key, a
  non-finite value, an unknown model or shape, a window outside the world, a
  pose with NaN, an unknown collider, a read outside the window, grousers with a
  negative, fractional or oversized count, a negative, NaN or oversized (> the
  radius) height or thickness, a bekker soil of negative density: each refused with a
  sentence naming the field, and
  the twin goes on working (a lugged wheel it then takes presses its lugs).
"""
import ctypes
import glob
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks, need_twin_wasm, skip  # noqa: E402

TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
REPLAY = os.environ.get("TERRAD_TWIN_REPLAY", "")
REPLAY_MJS = os.path.join(SOURCE, "tests", "support", "twin_replay.mjs")
MODELS = ["persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
          "diffusion", "sumner", "decals", "bekker"]
check = Checks()
if not (os.path.exists(TRACE) and os.path.exists(REPLAY)):
    skip("twin_trace / twin_replay not built")
# Without the wasm module (a failure under make test) or node, only the native replays run.
WASM = need_twin_wasm(check)
have_wasm = WASM is not None and subprocess.run(["node", "--version"],
                                                capture_output=True).returncode == 0
tmp = tempfile.mkdtemp(prefix="terrad-twin-")


def read_file(path):
    with open(path, "rb") as f:
        return f.read()


def differing(a, b):
    """Cells (int32) that differ between two raw height files of one size."""
    if len(a) != len(b):
        return -1
    va, vb = memoryview(a).cast("i"), memoryview(b).cast("i")
    return sum(1 for i in range(len(va)) if va[i] != vb[i])


# Scenes that leave the heights as they were, by design: no colliders (large-dunes is the
# viewer's level-of-detail scene), one cell with nowhere to push material (tiny), and the
# decals model, which sends footprint events only.
UNCHANGED = {"large-dunes", "tiny", "model decals"}


def compare(scene, ticks, label):
    base = os.path.join(tmp, label)
    with open(base + ".trace", "w") as f:
        t = subprocess.run([TRACE, scene, str(ticks)], stdout=f, stderr=subprocess.PIPE,
                           text=True, timeout=120)
    if t.returncode == 77:
        print(f"{label}: not replayed: {read_file(base + '.trace').decode().strip()}", flush=True)
        check.skipped += 1
        return
    if not check(t.returncode == 0, f"{label}: twin_trace ran: {t.stderr[-300:]}"):
        return
    outs = {}
    for name, ticks_run in (("start", 0), ("sim", ticks)):
        p = subprocess.run([BIN, "simulate", "--scene", scene, "--ticks", str(ticks_run),
                            "--backend", "cpu", "--out", f"{base}.{name}"],
                           capture_output=True, text=True, timeout=300)
        if not check(p.returncode == 0, f"{label}: simulate --ticks {ticks_run}: {p.stderr[-300:]}"):
            return
        outs[name] = read_file(f"{base}.{name}")
    changed = differing(outs["start"], outs["sim"])
    check(changed == 0 if label in UNCHANGED else changed > 0,
          f"{label}: {changed} cells changed in simulate")
    with open(base + ".trace") as f:
        r = subprocess.run([REPLAY, base + ".native"], stdin=f, capture_output=True, text=True,
                           timeout=300)
    if check(r.returncode == 0, f"{label}: native replay: {r.stderr[-300:]}"):
        n = differing(outs["sim"], read_file(base + ".native"))
        check(n == 0, f"{label}: native twin library vs simulate: {n} cells differ")
    if not have_wasm:
        print(f"info: {label}: no WebAssembly twin or no node: the wasm replay is skipped",
              flush=True)
        return
    r = subprocess.run(["node", "--no-warnings", REPLAY_MJS, WASM, base + ".trace",
                        base + ".wasm"], capture_output=True, text=True, timeout=300)
    if check(r.returncode == 0, f"{label}: wasm replay: {r.stderr[-500:]}"):
        n = differing(outs["sim"], read_file(base + ".wasm"))
        check(n == 0, f"{label}: WebAssembly twin library vs simulate: {n} cells differ")


for scene in sorted(glob.glob(os.path.join(SOURCE, "tests", "scenes", "*.json"))) + [
        os.path.join(SOURCE, "tests", "scenes", "lugged", "lugged-wheel.json")]:
    name = os.path.splitext(os.path.basename(scene))[0]
    big = name in ("large-dunes", "thesis-car")
    compare(scene, 60 if big else 150, name)

for model in MODELS:
    scene = {
        "name": "twin-" + model,
        "world": {"width": 160, "height": 96, "cell_size_m": 0.05},
        "terrain": {"kind": "dunes", "min_height_m": 0.3, "max_height_m": 0.5,
                    "wavelength_m": 2.0, "seed": 7},
        # bekker: a soil of its own density (the lugs' bulldozing), a key the twin must take
        "material": {"model": model, "refill_m_per_s": 0.05,
                     **({"soil": {"preset": "ding2011", "density_kg_m3": 1850}}
                        if model == "bekker" else {})},
        "colliders": [
            {"name": "ball", "shape": "sphere", "radius": 0.3, "position": [1.0, 2.4, 0.7],
             "motion": {"velocity": [1.2, 0.3, 0]}},
            {"name": "wheel", "shape": "cylinder", "radius": 0.3, "half_length": 0.1,
             "position": [6.0, 1.5, 0.65], "motion": {"velocity": [-1.0, 0, 0]}},
            # lugs of a cell and more, rolling: each stamps its own dent
            {"name": "lugged", "shape": "wheel", "radius": 0.25, "half_length": 0.1,
             "grousers": {"count": 10, "height": 0.06, "thickness": 0.04},
             "position": [1.5, 3.6, 0.7],
             "motion": {"velocity": [1.0, 0, 0], "spin_axis": [0, 1, 0],
                        "spin_deg_per_s": 229.18}}],
    }
    path = os.path.join(tmp, f"model-{model}.json")
    with open(path, "w") as f:
        json.dump(scene, f)
    compare(path, 120, "model " + model)

# ---- bad input to the C API ----
lib = ctypes.CDLL(os.path.join(os.path.dirname(REPLAY), "libterrad-twin.so"))
lib.terrad_twin_config_new.restype = ctypes.c_void_p
lib.terrad_twin_config_set.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_double,
                                       ctypes.c_char_p]
lib.terrad_twin_config_set_name.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p,
                                            ctypes.c_char_p]
lib.terrad_twin_create.restype = ctypes.c_void_p
lib.terrad_twin_create.argtypes = [ctypes.c_void_p] + [ctypes.c_int] * 4 + [
    ctypes.c_void_p, ctypes.c_char_p]
lib.terrad_twin_add_collider.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p] + [
    ctypes.c_double] * 5 + [ctypes.c_char_p]
lib.terrad_twin_add_wheel.argtypes = [ctypes.c_void_p, ctypes.c_int] + [ctypes.c_double] * 5 + [
    ctypes.c_char_p]
lib.terrad_twin_set_pose.argtypes = [ctypes.c_void_p, ctypes.c_int] + [ctypes.c_double] * 7 + [
    ctypes.c_char_p]
lib.terrad_twin_remove_collider.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_char_p]
lib.terrad_twin_write.argtypes = [ctypes.c_void_p] + [ctypes.c_int] * 4 + [ctypes.c_void_p,
                                                                           ctypes.c_char_p]
lib.terrad_twin_tick.argtypes = [ctypes.c_void_p, ctypes.c_char_p]
lib.terrad_twin_read.argtypes = [ctypes.c_void_p] + [ctypes.c_int] * 4 + [ctypes.c_void_p,
                                                                          ctypes.c_char_p]
lib.terrad_twin_destroy.argtypes = [ctypes.c_void_p]
lib.terrad_twin_config_free.argtypes = [ctypes.c_void_p]
err = ctypes.create_string_buffer(256)


def refused(rc, field):
    text = err.value.decode()
    check(rc == -1 and field in text, f"refused naming {field!r}: rc {rc}, {text!r}")


cfg = lib.terrad_twin_config_new()
refused(lib.terrad_twin_config_set(cfg, b"widht", 10, err), "widht")
refused(lib.terrad_twin_config_set(cfg, b"roughness", float("nan"), err), "roughness")
refused(lib.terrad_twin_config_set(cfg, b"width", 12.5, err), "width")
refused(lib.terrad_twin_config_set_name(cfg, b"model", b"clay", err), "model")
for key, value in ((b"width", 64), (b"height", 64), (b"terrain.height_m", 0.4)):
    check(lib.terrad_twin_config_set(cfg, key, value, err) == 0, f"set {key}")
check(lib.terrad_twin_create(cfg, 40, 40, 40, 40, None, err) is None
      and "window" in err.value.decode(), f"a window outside the world: {err.value!r}")
lib.terrad_twin_config_set(cfg, b"roughness", 2.0, err)
check(lib.terrad_twin_create(cfg, 0, 0, 64, 64, None, err) is None
      and "roughness" in err.value.decode(), f"roughness out of range at create: {err.value!r}")
lib.terrad_twin_config_set(cfg, b"roughness", 0.3, err)
lib.terrad_twin_config_set_name(cfg, b"model", b"bekker", err)
lib.terrad_twin_config_set(cfg, b"soil.density_kg_m3", -5, err)
check(lib.terrad_twin_create(cfg, 0, 0, 64, 64, None, err) is None
      and "density_kg_m3" in err.value.decode(), f"a negative soil density at create: {err.value!r}")
lib.terrad_twin_config_set(cfg, b"soil.density_kg_m3", 1600, err)
lib.terrad_twin_config_set_name(cfg, b"model", b"persson-ssbo", err)
twin = lib.terrad_twin_create(cfg, 8, 8, 48, 48, None, err)
check(twin is not None, f"a 48 x 48 window of the base: {err.value!r}")
refused(lib.terrad_twin_add_collider(twin, 1, b"cone", 0.3, 0, 0, 0, 0, err), "shape")
refused(lib.terrad_twin_add_collider(twin, 1, b"sphere", -1, 0, 0, 0, 0, err), "radius")
check(lib.terrad_twin_add_collider(twin, 1, b"sphere", 0.3, 0, 0, 0, 0, err) == 0, "a sphere")
refused(lib.terrad_twin_add_collider(twin, 1, b"sphere", 0.3, 0, 0, 0, 0, err), "id")
nan, inf = float("nan"), float("inf")
for lugs, field in (((-1, 0.02, 0.01), "grousers.count"), ((2.5, 0.02, 0.01), "grousers.count"),
                    ((361, 0.02, 0.01), "grousers.count"), ((1e12, 0.02, 0.01), "grousers.count"),
                    ((nan, 0.02, 0.01), "grousers.count"), ((0, 0.02, 0.01), "grousers.count"),
                    ((12, -0.02, 0.01), "grousers.height"), ((12, nan, 0.01), "grousers.height"),
                    ((12, 0.31, 0.01), "grousers.height"), ((12, 0.02, 0), "grousers.thickness"),
                    ((12, 0.02, inf), "grousers.thickness"), ((12, 0.02, 0.5), "grousers.thickness")):
    refused(lib.terrad_twin_add_wheel(twin, 2, 0.3, 0.1, *lugs, err), field)
refused(lib.terrad_twin_add_wheel(twin, 2, -0.3, 0.1, 12, 0.02, 0.01, err), "radius")
refused(lib.terrad_twin_set_pose(twin, 1, float("nan"), 1, 0.5, 1, 0, 0, 0, err), "position")
refused(lib.terrad_twin_set_pose(twin, 2, 1, 1, 0.5, 1, 0, 0, 0, err), "id")
cells = (ctypes.c_int32 * (48 * 48))()
refused(lib.terrad_twin_read(twin, 0, 0, 48, 48, cells, err), "read")
check(lib.terrad_twin_set_pose(twin, 1, 1.6, 1.6, 0.6, 1, 0, 0, 0, err) == 0, "a good pose")
check(lib.terrad_twin_tick(twin, err) == 0, f"it ticks after the refusals: {err.value!r}")
check(lib.terrad_twin_read(twin, 8, 8, 48, 48, cells, err) == 0
      and min(cells) < 4000 and max(cells) > 4000, "the sphere pressed into the 0.4 m base")
# After the refusals it takes a lugged wheel: its lug 0 (local -z) reaches below the rim.
flat = (ctypes.c_int32 * (48 * 48))(*[4000] * (48 * 48))
check(lib.terrad_twin_remove_collider(twin, 1, err) == 0, "the sphere removed")
lowest = {}
for lugs in ((0, 0, 0), (12, 0.05, 0.03)):
    check(lib.terrad_twin_write(twin, 8, 8, 48, 48, flat, err) == 0, "the window flat again")
    check(lib.terrad_twin_add_wheel(twin, 2, 0.3, 0.1, *lugs, err) == 0,
          f"a wheel with grousers {lugs}: {err.value!r}")
    check(lib.terrad_twin_set_pose(twin, 2, 1.625, 0.8, 0.71, 1, 0, 0, 0, err) == 0,
          "its pose: the axle over cell centres, so that the 3 cm lug meets them")
    check(lib.terrad_twin_tick(twin, err) == 0, f"it ticks: {err.value!r}")
    lib.terrad_twin_read(twin, 8, 8, 48, 48, cells, err)
    lowest[lugs[0]] = min(cells)
    check(lib.terrad_twin_remove_collider(twin, 2, err) == 0, "the wheel removed")
check(lowest[0] == 4000 and 3600 <= lowest[12] < 4000,
      f"the smooth rim 1 cm above the 0.4 m base leaves it, its lug 0 presses up to 4 cm into it "
      f"({lowest})")
lib.terrad_twin_destroy(twin)
lib.terrad_twin_config_free(cfg)
check.finish()
