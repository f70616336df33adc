#!/usr/bin/python3
"""test_soil_materials_scene: a bad soil in a scene's `materials` entry is
refused naming the field, by `terrad serve --scene` and by POST /v1/worlds
(docs/scene-format.md, issue 21: soil per material).

- `terrad serve --scene` on a scene whose entry "firm" has soil.n 0 exits
  non-zero and says `materials.firm.soil.n`;
- a running daemon: POST /v1/worlds with each bad soil (n 0, kphi and kc 0,
  an unknown preset, an unknown key, a string) answers 422 naming
  `materials.firm.soil.<field>`, counted as refused, with nothing created;
  the same scene with a good soil per entry is created (201), its stats say
  it is a bekker world, and the default world goes on ticking.
"""
import json
import os
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, json_call, metric_value  # noqa: E402

check = Checks()
ADMIN = "admin-token-for-soil-materials"


def scene(firm_soil):
    return {"name": "two-soils", "world": {"width": 64, "height": 32, "cell_size_m": 0.05},
            "terrain": {"kind": "flat", "height_m": 0.4},
            "material": {"model": "bekker", "compression": 0.5, "soil": {"preset": "snow-us"}},
            "materials": {"soft": {}, "firm": {"compression": 0.2, "soil": firm_soil}},
            "material_map": {"default": "soft",
                             "paint": [{"material": "firm", "rect": [1.6, 0, 3.2, 1.6]}]}}


def call(d, method, path, body=None):
    return json_call(d.http, method, path, body, token=ADMIN)


def refused(d):
    return metric_value(d.metrics()[1], "terrad_world_requests_total", {"result": "refused"}) or 0


def serve_refuses():
    fd, path = tempfile.mkstemp(prefix="soil-materials-", suffix=".json")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(scene({"preset": "lete-sand", "n": 0}), f)
        r = subprocess.run([BIN, "serve", "--scene", path, "--no-demo", "--no-data",
                            "--http-port", "0", "--ws-port", "0", "--backend", "cpu"],
                           stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)
        check(r.returncode != 0 and "materials.firm.soil.n" in r.stderr,
              f"terrad serve --scene with soil.n 0 in an entry: refused naming "
              f"materials.firm.soil.n (rc {r.returncode}, {r.stderr.strip()[-300:]!r})")
    finally:
        os.unlink(path)


def stats_tick(d):
    status, doc = call(d, "GET", "/v1/stats")
    return doc.get("tick", -1) if status == 200 else -1


def wait_until(predicate, timeout=120):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.1)
    return False


def api_refuses():
    with check.running(Daemon(token=ADMIN)) as d:
        cases = [({"n": 0}, "n"), ({"kc": 0, "kphi": 0}, "kphi"), ({"preset": "mars"}, "preset"),
                 ({"kx": 1}, "kx"), ({"n": "one"}, "n")]
        for soil, field in cases:
            before = refused(d)
            status, doc = call(d, "POST", "/v1/worlds", {"name": "two-soils", "scene": scene(soil)})
            want = f"materials.firm.soil.{field}"
            check(status == 422 and doc.get("field") == "scene" and want in doc.get("error", ""),
                  f"POST /v1/worlds with soil {soil} in an entry: 422 naming {want} "
                  f"({status} {doc})")
            check(refused(d) == before + 1, f"soil {soil}: counted as refused")
        status, doc = call(d, "GET", "/v1/worlds")
        listed = [w.get("name") for w in doc.get("worlds", [])] if status == 200 else None
        check(listed is not None and "two-soils" not in listed,
              f"nothing created by the refusals ({status} {listed})")
        status, doc = call(d, "POST", "/v1/worlds",
                           {"name": "two-soils", "scene": scene({"preset": "lete-sand"})})
        check(status == 201, f"the same scene with a good soil per entry is created ({status} {doc})")
        status, doc = call(d, "GET", "/v1/stats?world=two-soils")
        check(status == 200 and "soil_compacted" in doc,
              f"the created world is a bekker world ({status} {doc})")
        first = stats_tick(d)
        check(first >= 0 and wait_until(lambda: stats_tick(d) > first),
              "the default world goes on ticking")


serve_refuses()
api_refuses()
check.finish()
