#!/usr/bin/python3
# ctest-timeout: 600
"""Tiled ≡ untiled, bit for bit, through the real `terrad simulate`.

Every core scene (tests/scenes/*.json) is run twice per backend: once in
tiles of 16 or 64 cells and once with one tile as large as the world (the
dense layout the tiles replace). The final heights (--out), Σh before and
after, and the slope excess must be identical. Two generated scenes put
colliders exactly over tile corners — a sphere pressed onto the corner of
four 64-cell tiles and a box driven diagonally through several corners — so
the gather/scatter seams are crossed every tick.

On GL the tiled runs go through the GPU tile cache (windows gathered from
and scattered into an array texture of resident tiles); a third tiling runs
it with a tiny cache (12 layers, 4 KiB of uploads a tick) so tiles are
evicted, windows fall back to the CPU upload and stale tiles are re-uploaded
— still bit for bit. The GL backend needs an OpenGL 4.3 context; where none
can be made its cases are skipped.
"""
import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, SOURCE, Checks  # noqa: E402

SCENES = os.path.abspath(os.path.join(SOURCE, "tests", "scenes"))
WHOLE = 65536  # one tile covers any world

check = Checks()


TINY_CACHE = "tiny"  # tiles of 16 with a GPU tile cache of 12 layers, 4 KiB a tick


def simulate(scene, ticks, backend, out, env_cache=None, extra=()):
    args = [BIN, "simulate", "--scene", scene, "--ticks", str(ticks), "--backend", backend,
            "--out", out] + list(extra)
    env = dict(os.environ)
    if env_cache:
        env["TERRAD_GL_TILE_CACHE"] = env_cache
    p = subprocess.run(args, capture_output=True, text=True, timeout=240, env=env)
    return p.returncode, (json.loads(p.stdout) if p.returncode == 0 else None), p.stderr


def with_tiles(doc, tile_cells, scene_dir):
    """A copy of a scene doc in tiles of tile_cells, file paths made absolute."""
    d = json.loads(json.dumps(doc))
    d["world"]["tile_cells"] = tile_cells
    for c in d.get("colliders", []):
        if "obj" in c:
            c["obj"] = os.path.join(scene_dir, c["obj"])
    if "path" in d.get("terrain", {}):
        d["terrain"]["path"] = os.path.join(scene_dir, d["terrain"]["path"])
    return d


def corner_scenes():
    corner = 64 * 0.05  # metres to the corner of tiles (0,0),(1,0),(0,1),(1,1)
    press = {
        "name": "tile-corner-press",
        "world": {"width": 200, "height": 180, "cell_size_m": 0.05},
        "terrain": {"kind": "dunes", "min_height_m": 0.3, "max_height_m": 0.5,
                    "wavelength_m": 2, "octaves": 3, "seed": 5},
        "colliders": [
            {"name": "ball", "shape": "sphere", "radius": 0.6,
             "motion": {"keyframes": [
                 {"time_s": 0.0, "position": [corner, corner, 1.2]},
                 {"time_s": 1.0, "position": [corner, corner, 0.75]},
                 {"time_s": 2.0, "position": [corner + 0.02, corner - 0.03, 1.2]}]}}],
    }
    drive = {
        "name": "tile-corner-drive",
        "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
        "terrain": {"kind": "flat", "height_m": 0.4},
        "material": {"roughness": 0.4},
        "colliders": [
            {"name": "crate", "shape": "box", "half_extents": [0.4, 0.3, 0.25],
             "position": [1.5, 1.6, 0.55], "orientation": [0.9238795, 0, 0, 0.3826834],
             "motion": {"velocity": [1.2, 1.2, 0]}},
            {"name": "wheel", "shape": "wheel", "radius": 0.33, "half_length": 0.1,
             "position": [corner * 2, 1.0, 0.65],
             "motion": {"velocity": [0, 1.5, 0], "spin_axis": [1, 0, 0],
                        "spin_deg_per_s": 260}}],
    }
    return [press, drive]


def main():
    if not os.path.exists(BIN):
        print("no terrad binary at", BIN)
        return 1
    gl_ok = subprocess.run([BIN, "simulate", "--scene", os.path.join(SCENES, "tiny.json"),
                            "--ticks", "1", "--backend", "gl"],
                           capture_output=True).returncode == 0
    if not gl_ok:
        print("GL backend unavailable: GL cases skipped")
    backends = ["cpu"] + (["gl"] if gl_ok else [])
    ticks = {"thesis-car": 600, "spheres": 300, "box45": 400, "boot": 600, "odd": 400,
             "tiny": 50, "tile-corner-press": 120, "tile-corner-drive": 200}
    with tempfile.TemporaryDirectory() as tmp:
        docs = []
        for name in sorted(os.listdir(SCENES)):
            if name.endswith(".json"):
                with open(os.path.join(SCENES, name)) as f:
                    docs.append((json.load(f), SCENES, [16, 64]))
        docs += [(d, SCENES, [16, 64]) for d in corner_scenes()]
        jobs = []
        for doc, scene_dir, tilings in docs:
            name = doc["name"]
            for tc in tilings + [WHOLE]:
                path = os.path.join(tmp, f"{name}-{tc}.json")
                with open(path, "w") as f:
                    json.dump(with_tiles(doc, tc, scene_dir), f)
                for b in backends:
                    jobs.append((name, tc, b, path, os.path.join(tmp, f"{name}-{tc}-{b}.i32")))
                    if b == "gl" and tc == 16:
                        jobs.append((name, TINY_CACHE, b, path,
                                     os.path.join(tmp, f"{name}-tiny-{b}.i32")))

        def run(job):
            name, tc, b, path, out = job
            env_cache = "12,4096" if tc == TINY_CACHE else None
            return job, simulate(path, ticks.get(name, 300), b, out, env_cache)

        with ThreadPoolExecutor(max_workers=2) as pool:
            results = {(j[0], j[1], j[2]): (j, r) for j, r in pool.map(run, jobs)}

        evictions = tiny_cached = tiny_direct = 0
        for (name, tc, b), (job, (rc, rep, err)) in sorted(results.items(), key=str):
            check(rc == 0, f"{name} tiles {tc} {b}: exit {rc} {err.strip()[-300:]}")
            if tc == WHOLE or rc != 0:
                continue
            wjob, (wrc, wrep, _) = results[(name, WHOLE, b)]
            if wrc != 0:
                continue
            with open(job[4], "rb") as f:
                tiled = f.read()
            with open(wjob[4], "rb") as f:
                whole = f.read()
            check(len(tiled) > 0 and tiled == whole,
                  f"{name} {b}: heights in tiles of {tc} == one tile, bit for bit")
            for key in ("volume_before", "volume_after", "max_slope_excess", "peak_active_cells",
                        "refused_windows"):
                check(rep[key] == wrep[key],
                      f"{name} {b} tiles {tc}: {key} {rep[key]} == {wrep[key]}")
            check(rep["world_tile_cells"] == (16 if tc == TINY_CACHE else tc),
                  f"{name}: tile_cells {tc} reported")
            if b == "gl" and rep["active_cells_mean"] > 0 and tc != TINY_CACHE:
                check(rep["gpu_windows_cached"] > 0,
                      f"{name} gl tiles {tc}: windows gathered from the GPU tile cache "
                      f"({rep['gpu_windows_cached']} cached, {rep['gpu_windows_direct']} direct)")
            if tc == TINY_CACHE:
                evictions += rep["gpu_tile_evictions"]
                tiny_cached += rep["gpu_windows_cached"]
                tiny_direct += rep["gpu_windows_direct"]
                # (a scene with nothing touching the ground never makes the cache's texture)
                check(rep["gpu_tile_cache_bytes"] == 12 * 16 * 16 * 4 or
                      rep["active_cells_mean"] == 0,
                      f"{name}: the tiny cache is 12 layers ({rep['gpu_tile_cache_bytes']} bytes)")
            if name.startswith("tile-corner"):
                check(rep["world_stored_tiles"] >= 4,
                      f"{name} {b} tiles {tc}: the corner's tiles were written "
                      f"({rep['world_stored_tiles']})")

        # GL through the tiny cache ≡ the CPU twin, each with its own depth
        if gl_ok:
            for name in ("thesis-car", "tile-corner-drive"):
                path = os.path.join(tmp, f"{name}-16.json")
                outs = []
                for b, cache in (("gl", "12,4096"), ("cpu", None)):
                    out = os.path.join(tmp, f"{name}-depth-{b}.i32")
                    rc, rep, err = simulate(path, ticks[name], b, out, cache, [])
                    check(rc == 0, f"{name} {b}: {err.strip()[-300:]}")
                    with open(out, "rb") as f:
                        outs.append(f.read())
                check(len(outs[0]) > 0 and outs[0] == outs[1],
                      f"{name}: GL through a tiny tile cache == CPU twin, bit for bit")
            check(evictions > 0 and tiny_cached > 0 and tiny_direct > 0,
                  f"the tiny GPU tile cache evicted tiles ({evictions}), served windows "
                  f"({tiny_cached}) and sent others the direct way ({tiny_direct})")
    check.finish()


if __name__ == "__main__":
    sys.exit(main())  # check.finish() exits on its own; main returns 1 without a binary
