#!/usr/bin/python3
# ctest-timeout: 420
"""The C client's prediction and its hello into a created world (terrad_client.h:
terrad_client_predict, terrad_client_connect_world; docs/engines.md) against a real daemon
(--backend cpu, no demo actors, a flat scene of default material), through
tests/support/c_predict_drive.c linked to the shared libterrad-client:

- prediction (the Python client's test, in C): a sphere, a rolling wheel, a capsule (a
  quaternion of norm 1.04) and a rolling wheel with grousers (terrad_client_create_lugged_collider:
  before the twin library took grousers the client left it out of the prediction, and the
  replays differed from the server) driven for 600 ticks, one pose batch per tick; bad grousers
  are refused by the server naming the field; its lugs dent deeper than the smooth rim; the rut is in the
  prediction before the server's ACK of its batch; every compared ACK's replay of the
  server's ticks has 0 cells differing; a second client's rut makes replays differ and every
  reconciliation with nothing pending equals the mirror; bad input to terrad_client_predict
  (an unknown subscription, an unknown model, NaN, an unknown key, a pair without '=', a NULL
  out, a second prediction of one subscription) is refused naming the field and the client
  goes on; at the end the mirror equals GET /v1/heights;
- a load-driven wheel (terrad_client_create_loaded_collider, on a second daemon's bekker world)
  rolled with slip through a predicted window for 300 ticks: every compared ACK exact, its
  height the server's (FORCES heights below the posed one). Without its load in the twin (the
  client's height, as before terrad_twin_prediction_set_load) 0 of 301 compared ACKs were exact;
- a world: POST /v1/worlds creates one; the C client says hello into it (the world message
  names it), an unknown and an over-long name are refused naming "world"; its sphere presses
  that world (the mirror equals GET /v1/heights?world=NAME) and not the default one.
"""
import json
import os
import struct
import subprocess
import sys
import tempfile
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, SOIL_PREDICT_REGION, read_mirror, skip,  # noqa: E402
                             soil_predict_config, twin_config, twin_config_text)

DRIVE = os.environ.get("TERRAD_C_PREDICT_DRIVE", "")
TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
if not (os.access(DRIVE, os.X_OK) and os.access(TRACE, os.X_OK)):
    skip("c_predict_drive / twin_trace not built")
check = Checks()
SCENE = {"name": "predict-c", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.4}, "colliders": []}
REGION = (64, 80, 128, 96)  # x, y, w, h cells: the predicted window
WORLD = {"name": "c-world", "world": {"width": 96, "height": 80, "cell_size_m": 0.05},
         "terrain": {"kind": "flat", "height_m": 0.5}}


def drive(args):
    r = subprocess.run([DRIVE, *map(str, args)], capture_output=True, text=True, timeout=240)
    print(r.stdout + r.stderr, flush=True)
    return r.returncode == 0 and " 0 failed" in r.stdout


def post_world(d, body):
    req = urllib.request.Request(d.http + "/v1/worlds", data=json.dumps(body).encode(),
                                 method="POST")
    try:
        with urllib.request.urlopen(req, timeout=120) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-predict-c-") as tmp:
        path = os.path.join(tmp, "scene.json")
        with open(path, "w") as f:
            json.dump(SCENE, f)
        cfg = twin_config(path)
        check(cfg.get("model") and cfg.get("width") == 256, f"the scene's twin config ({cfg})")
        out = os.path.join(tmp, "mirror.raw")
        with check.running(Daemon(extra=["--scene", path])) as d:
            ok = drive(["predict", d.ws_port, *REGION, twin_config_text(cfg), out])
            check(ok, "c_predict_drive predict: every check passed")
            mirror = read_mirror(out, REGION[2] * REGION[3]) if ok else None
            _, http = d.heights(*REGION)
            check(mirror is not None and mirror == http,
                  "the C client's mirror (its prediction's at the end) equals GET /v1/heights")

            status, answer = post_world(d, {"name": WORLD["name"], "scene": WORLD})
            check(status in (200, 201), f"POST /v1/worlds created {WORLD['name']} ({status} {answer})")
            w, h = WORLD["world"]["width"], WORLD["world"]["height"]
            _, default_before = d.heights(0, 0, w, h)
            out_w = os.path.join(tmp, "world.raw")
            ok = drive(["world", d.ws_port, WORLD["name"], w, h, out_w])
            check(ok, "c_predict_drive world: every check passed")
            mirror = read_mirror(out_w, w * h) if ok else None
            status, body, _ = d.get(f"/v1/heights?x=0&y=0&w={w}&h={h}&world={WORLD['name']}")
            http = list(struct.unpack(f"<{w * h}i", body)) if status == 200 and len(body) == 4 * w * h else None
            check(mirror is not None and mirror == http,
                  f"the mirror of world {WORLD['name']} equals GET /v1/heights?world= ({status})")
            check(d.heights(0, 0, w, h)[1] == default_before, "the default world was not pressed")
        soil, soil_cfg = soil_predict_config(tmp)
        check(soil_cfg.get("model") == "bekker", f"the bekker scene's twin config ({soil_cfg})")
        with check.running(Daemon(extra=["--scene", soil, "--no-data"])) as d:
            check(drive(["loaded", d.ws_port, *SOIL_PREDICT_REGION, twin_config_text(soil_cfg)]),
                  "c_predict_drive loaded: every check passed")
    check.finish()


main()
