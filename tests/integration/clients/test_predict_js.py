#!/usr/bin/python3
# ctest-timeout: 420
"""Client-side prediction in JavaScript (web/predict.mjs over the WebAssembly twin,
docs/engines.md "Prediction") against a real daemon (--backend cpu, no demo actors, a scene
of dunes with its own material): tests/support/predict_drive.mjs, under Node 20 with its
WebSocket, drives through two connections with the viewer's codec and reports; here:

- the prediction shows the rut before the server could have it (at the first pressing
  batch, before its bytes are sent, predicted heights below the mirror's);
- 600 ticks, one batch per tick (a sphere, a rolling wheel, a capsule whose quaternion is
  not of norm 1 and a rolling wheel with grousers, which the twin presses lug by lug as the
  server does: TwinPrediction.addWheel): at every compared ACK the JavaScript client's replay of the
  server's ticks equals the server's heights in every cell, and with nothing pending the
  prediction is the mirror;
- a second connection ploughs the same window: the replay then differs from the server, and
  after every reconciliation with nothing pending the prediction equals the mirror; at the
  end the mirror equals GET /v1/heights and holds the other's rut;
- a load-driven wheel (colliderCreate's loadN, the Prediction's dims load_n) rolled with slip on a
  second daemon's bekker world for 300 ticks: every compared ACK exact (the WebAssembly twin
  runs the server's search for its height from the state its replay reached; without load_n
  in the twin 0 of 300 were), its rut deeper than the posed rim could press, and the heights the
  server found arrive in FORCES (colliderCreate's forcesHeight: the header flag and each
  entry's f64 height_m, decoded by web/terrad_codec.mjs) below the posed one; a NaN, negative
  or infinite load is refused naming load_n; then rolled back with the next soil-state restore
  failing (the twin library's test hook, terrad_twin_fault_restores): Prediction.errors counts
  it with the twin's sentence in lastError, nothing is thrown from the ACK handler (before, the
  Error escaped the websocket's message handler and ended the driver), and the later ACKs are
  taken, compared and reset to the mirror;
- bad input: a Prediction on a mirror without its snapshot, an unknown model, grousers with
  a negative, fractional or huge count, a height over the radius, no thickness: refused with
  an error naming the field.
Skips (77) without node, twin_trace or build/terrad_twin.wasm (the last fails instead under
make test: service_harness.need_twin_wasm).
"""
import json
import os
import shutil
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (SOIL_PREDICT_REGION, SOURCE, Checks, Daemon,  # noqa: E402
                             need_twin_wasm, skip, soil_predict_config, twin_config)

TRACE = os.environ.get("TERRAD_TWIN_TRACE", "")
DRIVE = os.path.join(SOURCE, "tests", "support", "predict_drive.mjs")
NODE_WEBSOCKET = os.path.join(SOURCE, "tests", "support", "node_websocket.mjs")
if not os.path.exists(TRACE):
    skip("twin_trace not built")
WASM = need_twin_wasm()
if not shutil.which("node"):
    skip("node missing")
check = Checks()
SCENE = {"name": "predict-js", "world": {"width": 256, "height": 256, "cell_size_m": 0.05},
         "terrain": {"kind": "dunes", "min_height_m": 0.35, "max_height_m": 0.45,
                     "wavelength_m": 4, "octaves": 3, "seed": 7},
         "material": {"roughness": 0.4, "repose_deg": 30}, "colliders": []}
REGION = (64, 80, 128, 96)


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-predict-js-") as tmp:
        scene, config = os.path.join(tmp, "scene.json"), os.path.join(tmp, "twin.json")
        with open(scene, "w") as f:
            json.dump(SCENE, f)
        with open(config, "w") as f:
            json.dump(twin_config(scene), f)
        with check.running(Daemon(extra=["--scene", scene, "--no-data"])) as d:
            p = subprocess.run(["node", "--import", NODE_WEBSOCKET, "--no-warnings", DRIVE, d.ws,
                                WASM, config, *map(str, REGION)],
                               capture_output=True, text=True, timeout=240)
            if not check(p.returncode == 0, f"the Node driver ran ({p.returncode}):\n{p.stderr[-3000:]}"):
                return
            out = json.loads(p.stdout.strip().splitlines()[-1])
            drive, other, final = out["drive"], out["other"], out["final"]
            print(f"JS drove 600 ticks: {drive}; with another client: {other}; "
                  f"first rut seen early: {out.get('early')}", flush=True)
            early = out.get("early") or {}
            check(early.get("cells", 0) > 0 and early["ackedSeq"] < early["seq"],
                  f"the prediction shows the rut before the server's ACK of its batch ({early})")
            check(drive["replayed"] >= 10 and drive["exact"] == drive["replayed"],
                  f"every compared ACK: the JavaScript replay equals the server in every cell "
                  f"({drive['exact']} of {drive['replayed']}; {drive['skipped']} not compared)")
            check(out["settled"], "with nothing pending, the prediction is the server's state")
            check(min(out["ruts"]) > 20, f"sphere, wheel, capsule and lugged wheel left ruts "
                  f"({out['ruts']} cells of their rows lower)")
            check(out.get("refusedLugs") and all(r == "ok" for r in out["refusedLugs"]),
                  f"bad grousers are refused naming the field ({out.get('refusedLugs')})")
            check(other["replayed"] > other["exact"],
                  f"another client's rut makes the replay differ ({other})")
            check(other["resets"] > 0 and other["resetsEqual"] == other["resets"] and final["settled"],
                  f"after every reconciliation the prediction is the server's ({other})")
            tick, http = d.heights(*REGION)
            check(http == final["heights"] and tick >= final["tick"],
                  "the mirror equals GET /v1/heights once all is acknowledged")
            check(out["rutB"] > 20, f"the other client's rut is in the window ({out['rutB']} cells)")
            check("snapshot" in out.get("refusedIncomplete", ""),
                  f"a mirror without its snapshot is refused ({out.get('refusedIncomplete')})")
            check("model" in out.get("refusedModel", ""),
                  f"an unknown model is refused naming it ({out.get('refusedModel')})")
            check(not out["errors"], f"no server errors ({out['errors'][:3]})")
        soil, soil_cfg = soil_predict_config(tmp)
        with open(config, "w") as f:
            json.dump(soil_cfg, f)
        with check.running(Daemon(extra=["--scene", soil, "--no-data"])) as d:
            p = subprocess.run(["node", "--import", NODE_WEBSOCKET, "--no-warnings", DRIVE, d.ws,
                                WASM, config, *map(str, SOIL_PREDICT_REGION), "loaded"],
                               capture_output=True, text=True, timeout=240)
            if not check(p.returncode == 0, f"the Node driver ran loaded ({p.returncode}):\n{p.stderr[-3000:]}"):
                return
            out = json.loads(p.stdout.strip().splitlines()[-1])
            drive = out["drive"]
            print(f"JS load-driven wheel, 300 ticks: {drive}; rut {out['rut']} units", flush=True)
            check(drive["replayed"] >= 10 and drive["exact"] == drive["replayed"] and out["settled"],
                  f"load-driven wheel: every compared ACK exact, and the prediction the mirror "
                  f"at the end ({drive['exact']} of {drive['replayed']}; {drive['skipped']} not "
                  f"compared; settled {out['settled']})")
            check(out["rut"] > 50, f"the server sank the wheel below its posed rim ({out['rut']} units)")
            found = out["found"]
            # every found height below the posed rim, and the wheel sank 5 mm or more: the first
            # ticks' found heights are within a few mm of 0.5, and which ticks' FORCES a client
            # sees first depends on when it joined, so the bound is on the deepest, not the least
            check(len(found) > 10 and max(found) < 0.5 and min(found) < 0.5 - 0.005,
                  f"FORCES' height extension, decoded by the JS codec: the heights the server "
                  f"found, below the posed 0.5 m ({len(found)}, {min(found, default=None)}.."
                  f"{max(found, default=None)} m)")
            check(all(r == "ok" for r in out["refused"]),
                  f"a NaN, negative or infinite load is refused naming load_n ({out['refused']})")
            check(drive["errors"] == 0 and drive["lastError"] == "",
                  f"no prediction errors while rolling ({drive['errors']}: {drive['lastError']!r})")
            r = out["restore"]
            print(f"JS restore failed: {r}", flush=True)
            check(r["errors"] == 1 and "soil state" in r["lastError"],
                  f"the failed restore is counted with the twin's sentence ({r['errors']}: "
                  f"{r['lastError']!r})")
            check(r["reconciled"] >= 10 and r["replayed"] >= 10,
                  f"the ACKs after it are taken and compared ({r['reconciled']}, {r['replayed']})")
            check(r["resets"] > 10 and r["resetsEqual"] == r["resets"],
                  f"with nothing pending, the prediction is the server's state at every ACK after "
                  f"it ({r['resets'] - r['resetsEqual']} of {r['resets']} not)")
            check(not out["errors"], f"no server errors ({out['errors'][:3]})")


main()
check.finish()  # also after a driver that did not run (main returns early)
