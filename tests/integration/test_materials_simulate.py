#!/usr/bin/python3
# ctest-timeout: 300
"""Per-cell materials and compaction memory through the real `terrad simulate`.

- tests/scenes/materials-mixed.json (sand, pebbles, mud, snow) on the CPU
  backend: volume_after + compacted == volume_before exactly, snow compacted.
- The same scene without snow (nothing compacts): Σh exact, no "compacted".
- The GL backend refuses a scene with per-cell materials with a message
  naming them (it has no per-cell path, so it must not compute a different
  result); where GL is unavailable the refusal is still an error.
- Bad material tables are refused with the field named.
"""
import json
import os
import subprocess
import tempfile

SOURCE = os.environ.get("TERRAD_SOURCE_DIR", ".")
BIN = os.environ.get("TERRAD_BIN", os.path.join(SOURCE, "build", "terrad"))
SCENE = os.path.join(SOURCE, "tests", "scenes", "materials-mixed.json")

passed = 0
failed = 0


def check(cond, what):
    global passed, failed
    if cond:
        passed += 1
    else:
        failed += 1
        print("FAIL:", what, flush=True)


def simulate(scene_path, ticks, backend):
    p = subprocess.run([BIN, "simulate", "--scene", scene_path, "--ticks", str(ticks),
                        "--backend", backend], capture_output=True, text=True, timeout=240)
    return p.returncode, (json.loads(p.stdout) if p.returncode == 0 else None), p.stderr


def with_scene(doc, fn):
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
        json.dump(doc, f)
        path = f.name
    try:
        return fn(path)
    finally:
        os.unlink(path)


rc, rep, err = simulate(SCENE, 400, "cpu")
check(rc == 0, "mixed scene runs on cpu: " + err)
if rep:
    compacted = rep.get("compacted", 0)
    check(compacted > 0, "snow compacted something (%s)" % compacted)
    check(rep["volume_after"] + compacted == rep["volume_before"],
          "volume_after %d + compacted %d == volume_before %d"
          % (rep["volume_after"], compacted, rep["volume_before"]))
    check(rep["refused_windows"] == 0, "no window refused")

with open(SCENE) as f:
    doc = json.load(f)
doc["materials"]["snow"] = {"preset": "sand", "repose_deg": 20}
rc, rep, err = with_scene(doc, lambda p: simulate(p, 400, "cpu"))
check(rc == 0, "no-compaction scene runs: " + err)
if rep:
    check(rep["volume_after"] == rep["volume_before"], "Σh exact without compaction")
    check("compacted" not in rep, "no compaction layer reported")

rc, rep, err = simulate(SCENE, 5, "gl")
check(rc != 0, "gl backend refuses per-cell materials")
if "gl backend" not in err and "EGL" not in err and "OpenGL" not in err:
    check("cpu backend" in err and "materials" in err, "refusal names the cause: " + err.strip())

bad = dict(doc)
bad["materials"] = {"sand": {"preset": "sand", "roughness": -1}}
bad["material_map"] = {"default": "sand"}
rc, rep, err = with_scene(bad, lambda p: simulate(p, 1, "cpu"))
check(rc != 0 and "materials.sand.roughness" in err, "bad roughness named: " + err.strip())
bad["materials"] = {"sand": {"preset": "sand"}}
bad["material_map"] = {"default": "sand", "paint": [{"material": "clay", "rect": [0, 0, 1, 1]}]}
rc, rep, err = with_scene(bad, lambda p: simulate(p, 1, "cpu"))
check(rc != 0 and "material_map.paint[0].material" in err, "unknown paint material named: " + err.strip())

print("%d passed, %d failed" % (passed, failed))
raise SystemExit(1 if failed else 0)
