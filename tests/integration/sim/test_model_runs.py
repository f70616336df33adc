#!/usr/bin/python3
# ctest-timeout: 300
"""Every deformation model (docs/models.md) through the real binary.

- `terrad simulate --model M` for every model on tests/scenes/thesis-car.json:
  each keeps the volume promise it documents (persson-*, diffusion and decals
  exactly; subtract never gains; deferred's drift is printed), decals counts footprint events, and the
  output names the model and its memory by stage.
- A subtract scene holds under a quarter of a persson-ssbo scene's scratch on
  the same colliders, and none of the persson stages' buffers.
- Diffusion at Δt far past Gilardi's limit (sand preset, dt 1e6) keeps Σh exact;
  their float scheme runs too.
- On the GL backend a model without a GL version runs on the CPU and says so.
- Bad model names and parameters are refused naming the field.
- Through the service: a daemon whose scene uses subtract, deferred, diffusion
  or decals; docs/clients.md's Python client drives a wheel and its mirror, rebuilt from
  the deltas, equals GET /v1/heights; /metrics shows the scratch per stage.
"""
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks, Daemon, metric_value, simulate  # noqa: E402

SCENES = os.path.join(SOURCE, "tests", "scenes")
EXAMPLE = os.path.join(SOURCE, "clients", "python", "examples", "drive_wheel.py")
MODELS = ["persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
          "diffusion", "sumner", "decals"]
EXACT = {"persson-iterative", "persson-ssbo", "persson-multi", "diffusion", "sumner", "decals"}
check = Checks()


def scene_file(material, name="models"):
    scene = {
        "name": name,
        "world": {"width": 256, "height": 128, "cell_size_m": 0.05},
        "terrain": {"kind": "flat", "height_m": 0.4},
        "material": material,
        "colliders": [{
            "name": "ball", "shape": "sphere", "radius": 0.3, "position": [1.0, 3.2, 0.62],
            "motion": {"velocity": [1.5, 0, 0]}}],
    }
    fd, path = tempfile.mkstemp(prefix="terrad-models-", suffix=".json")
    with os.fdopen(fd, "w") as f:
        json.dump(scene, f)
    return path


car = os.path.join(SCENES, "thesis-car.json")
for model in MODELS:
    rc, r, err = simulate(car, 300, "--model", model)
    check(rc == 0, f"{model}: simulate ran: {err[-300:]}")
    if not r:
        continue
    check(r["model"] == model and r["refused_windows"] == 0, f"{model}: model named, no refusals")
    before, after = r["volume_before"], r["volume_after"]
    if model in EXACT:
        check(before == after, f"{model}: Σh exact ({before} -> {after})")
    elif model == "subtract":
        check(after <= before, f"{model}: Σh never grows ({before} -> {after})")
    if model == "decals":
        check(r.get("footprint_events", 0) > 0, f"decals: footprint events ({r.get('footprint_events')})")
    stages = r["scratch_bytes_by_stage"]
    check(sum(stages.values()) == r["scratch_bytes_peak"] or model not in ("subtract",),
          f"{model}: stages add up to the peak")
    print(f"{model}: volume {after - before:+d}, tick {r['stages']['tick']['mean_ms']} ms, "
          f"scratch {r['scratch_bytes_peak']} B")

# memory: subtract against persson-ssbo on the same collider
box = os.path.join(SCENES, "box45.json")
_, ssbo, _ = simulate(box, 60, "--model", "persson-ssbo")
_, sub, _ = simulate(box, 60, "--model", "subtract")
if ssbo and sub:
    check(sub["scratch_bytes_peak"] * 4 < ssbo["scratch_bytes_peak"],
          f"subtract scratch {sub['scratch_bytes_peak']} < 25% of persson-ssbo's "
          f"{ssbo['scratch_bytes_peak']}")
    s = sub["scratch_bytes_by_stage"]
    check(s["jump_flood"] == 0 and s["displace"] == 0 and s["classify"] == 0,
          f"subtract holds no persson stage buffers: {s}")

# diffusion far past the explicit limit
path = scene_file({"model": "diffusion", "preset": "sand", "dt": 1e6, "conservative": True})
rc, r, err = simulate(path, 200)
check(rc == 0 and r["volume_before"] == r["volume_after"] and r["refused_windows"] == 0,
      f"diffusion sand dt=1e6: Σh exact: {r and (r['volume_before'], r['volume_after'])} {err[-200:]}")
os.unlink(path)
path = scene_file({"model": "diffusion", "preset": "sand", "dt": 0.2, "conservative": False})
rc, r, err = simulate(path, 200)
check(rc == 0, f"diffusion, Gilardi's float scheme runs: {err[-200:]}")
if r:
    print(f"diffusion (Gilardi's scheme, sand, dt 0.2): volume "
          f"{r['volume_after'] - r['volume_before']:+d} units over 200 ticks")
os.unlink(path)

# GL: the model runs on the CPU and says so
rc, r, err = simulate(os.path.join(SCENES, "tiny.json"), 5, "--model", "subtract", backend="gl")
if rc != 0:
    print("GL backend unavailable, GL case skipped:", err.strip().splitlines()[-1:])
else:
    check(r["backend"] == "gl" and r["model_on_cpu"] is True, "gl: subtract says it ran on the CPU")

# bad input names the field
rc, _, err = simulate(car, 1, "--model", "sumnr")
check(rc == 2 and "--model" in err, f"--model with an unknown name refused: {err}")
for material, field in [({"model": "nope"}, "material.model"),
                        ({"model": "diffusion", "D": -1}, "material.D"),
                        ({"model": "diffusion", "substeps": "sometimes"}, "material.substeps"),
                        ({"model": "diffusion", "conservative": 1}, "material.conservative"),
                        ({"model": "diffusion", "preset": "gravel"}, "material.preset"),
                        ({"model": "subtract", "refill_m_per_s": 1e9}, "refill_m_per_s"),
                        ({"model": "deferred", "edge_width": 0}, "material.edge_width"),
                        ({"model": "persson-multi", "method": "ssbo"}, "material.method")]:
    path = scene_file(material)
    rc, _, err = simulate(path, 1)
    check(rc == 1 and field in err, f"{material}: refused naming {field}: {err.strip()}")
    os.unlink(path)
path = scene_file({"method": "multi"})
rc, r, err = simulate(path, 1)
check(rc == 0 and r["model"] == "persson-multi", f"method multi is persson-multi: {err}")
os.unlink(path)

# through the service
for material in [{"model": "subtract", "refill_m_per_s": 0.05}, {"model": "deferred"},
                 {"model": "diffusion", "preset": "sand"}, {"model": "decals"}]:
    model = material["model"]
    path = scene_file(material, name=f"service-{model}")
    try:
        d = Daemon(backend="cpu", extra=["--scene", path], name=f"terrad-{model}")
    except RuntimeError as e:
        check(False, f"{model}: daemon started: {e}")
        os.unlink(path)
        continue
    with check.running(d):
        world = d.world()
        check(model in world.get("models", []), f"{model}: /v1/world names the model: {world}")
        r = subprocess.run(["/usr/bin/python3", EXAMPLE, d.ws, d.http + "/"],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode == 0 and "mirror == GET /v1/heights" in r.stdout,
              f"{model}: a driven wheel's deltas rebuild the server's heights: "
              f"{r.stdout[-500:]} {r.stderr[-1000:]}")
        print(f"{model} through the service: {r.stdout.strip()}")
        _, text = d.metrics()
        held = metric_value(text, "terrad_sim_scratch_bytes", {"stage": "jump_flood"})
        check(held == 0, f"{model}: no jump-flooding buffers in the daemon ({held})")
        if model != "subtract":
            model_bytes = metric_value(text, "terrad_sim_scratch_bytes", {"stage": "model"})
            check(model_bytes is not None and model_bytes > 0,
                  f"{model}: model scratch in /metrics ({model_bytes})")
    os.unlink(path)

check.finish()
