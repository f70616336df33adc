#!/usr/bin/python3
# ctest-timeout: 900
"""Lockstep co-simulation (issue 30, items 1 and 2): client-clocked worlds stepped by a real C
client (tests/support/c_cosim_drive.c, over libterrad-client's terrad_client_step_many) against
real daemons on loopback:

- determinism: the same 2,000-step script (a four-wheeled rover on bekker soil, two wheels
  load-driven and two pose-driven; steps of one tick, of three ticks with a pose set each, of
  two ticks holding) run in two worlds stepped as one on a daemon with --threads 1, then in two
  worlds each stepped alone on a daemon with --threads 2 and TERRAD_NO_AVX2=1: every FORCES
  entry of every tick (floats compared bit for bit), every STEPPED tick, every height of the
  mirror, the world's Σh and Σ compacted soil (/v1/stats) and its data directory byte for byte
  (the log records hold every tick's changed heights and per-cell soil state) are identical in
  all four;
- kill -9 keeps every acknowledged step (--durability every-tick): a driver that stops after
  its steps leaves a world whose recovered tick is at least the last STEPPED tick and whose
  heights are the client's mirror; a daemon killed while a driver is stepping recovers at
  least the last tick the driver saw acknowledged;
- a wall-clocked world refuses a STEP naming "clock"; a second would-be driver is refused
  naming "driver"; "clock" of neither kind is refused by POST /v1/worlds naming "clock";
- the daemon's own world (--scene) client-clocked does not tick by itself, and a driver steps it;
  waiting past the 10 s watchdog limit it stays healthy (/healthz, /readyz 200), and its demo
  actors give the same heights whether height reads come between the steps or not;
- under --durability group:MS (a tick's frames held until the sync that covers it) every step is
  answered: the step's end syncs, as no later tick would publish them.

Behaviour only: every wait is for a condition, with a generous deadline.
"""
import os
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (COSIM_DRIVE, COSIM_H, COSIM_W, Checks, Daemon,  # noqa: E402
                             cosim_acked, cosim_mirror, cosim_paused, cosim_scene, json_call,
                             json_file)
from waiting import wait_for  # noqa: E402

check = Checks()
W, H = COSIM_W, COSIM_H  # c_cosim_drive's world
STEPS = 2000


def create(d, name, clock="client"):
    status, doc = json_call(d.http, "POST", "/v1/worlds", {"name": name, "clock": clock, "scene": cosim_scene()})
    check(status == 201, f"POST /v1/worlds {name} ({clock}): {status} {doc}")


def drive(d, worlds, mode, steps=STEPS, out=None):
    """Runs c_cosim_drive to its end; returns {world: its output text}."""
    out = out or tempfile.mkdtemp(prefix="terrad-cosim-")
    prefix = os.path.join(out, "drive")
    r = subprocess.run([COSIM_DRIVE, str(d.ws_port), ",".join(worlds), str(steps), prefix, mode],
                       capture_output=True, text=True, timeout=600)
    check(r.returncode == 0, f"c_cosim_drive {mode} {worlds}: rc {r.returncode}: {r.stderr[-2000:]}")
    texts = {}
    for w in worlds:
        with open(f"{prefix}.{w}") as f:
            texts[w] = f.read()
    return texts


def stats(d, world):
    status, doc = json_call(d.http, "GET", f"/v1/stats?world={world}")
    return (doc.get("volume"), doc.get("soil_compacted")) if status == 200 else None


def heights(d, world):
    status, body, _ = d.get(f"/v1/heights?x=0&y=0&w={W}&h={H}&world={world}", timeout=60)
    import struct
    return list(struct.unpack(f"<{W * H}i", body)) if status == 200 and len(body) == 4 * W * H else None


def world_tick(d, world):
    status, doc = json_call(d.http, "GET", "/v1/worlds")
    ticks = {w["name"]: w["tick"] for w in doc.get("worlds", [])} if status == 200 else {}
    return ticks.get(world)


def store_bytes(d, world):
    """Every file of world's data directory (its log records hold each tick's changed heights
    and per-cell soil state), by name; LOCK left out."""
    root = os.path.join(d.data_dir, "worlds", world)
    out = {}
    for dirpath, _, files in os.walk(root):
        for name in files:
            if name != "LOCK":
                with open(os.path.join(dirpath, name), "rb") as f:
                    out[os.path.relpath(os.path.join(dirpath, name), root)] = f.read()
    return out


def determinism():
    runs = {}
    with check.running(Daemon(extra=["--threads", "1"], name="threads-1")) as d:
        create(d, "a")
        create(d, "b")
        texts = drive(d, ["a", "b"], "many")
        for w in ("a", "b"):
            runs[f"1 thread, stepped as one: {w}"] = (texts[w], stats(d, w), store_bytes(d, w))
    with check.running(Daemon(extra=["--threads", "2"], env={"TERRAD_NO_AVX2": "1"},
                              name="threads-2")) as d:
        create(d, "a")
        create(d, "b")
        texts = drive(d, ["a", "b"], "alone")
        for w in ("a", "b"):
            runs[f"2 threads, no AVX2, stepped alone: {w}"] = (texts[w], stats(d, w), store_bytes(d, w))
    (first, (text, st, logged)), *rest = runs.items()
    forces = text.count("\nF ")
    check(forces > 4 * STEPS, f"{first}: {forces} FORCES entries")
    check(text.count("STEPPED ") == STEPS, f"{first}: a STEPPED per step")
    m = cosim_mirror(text)
    check(len(m) == W * H and len(set(m)) > 10, f"{first}: the mirror holds the rover's ruts")
    check(st and st[1] and st[1] > 0, f"{first}: soil compacted ({st})")
    check(any(n.startswith("wal-") and len(b) > 1000 for n, b in logged.items()),
          f"{first}: its log holds the ticks ({sorted(logged)})")
    for name, (t, s, lg) in rest:
        check(t == text, f"{name}: FORCES, STEPPED ticks and heights identical to {first}")
        check(s == st, f"{name}: volume and compacted soil {s} == {st}")
        check(lg == logged, f"{name}: its data directory (every tick's heights and soil state, "
              f"as logged) byte for byte that of {first}")


def kill9():
    data = tempfile.mkdtemp(prefix="terrad-cosim-data-")
    out = tempfile.mkdtemp(prefix="terrad-cosim-")
    d = Daemon(data_dir=data, durability="every-tick", name="before-kill")
    create(d, "k")
    create(d, "m")
    # a driver that stops after its steps: the world waits, the daemon dies
    p, lines = cosim_paused(d.ws_port, "k", 300, os.path.join(out, "drive"))
    last = cosim_acked(lines)
    check(last > 0 and lines[-1].startswith("PAUSED"), f"paused driver: {lines[-3:]}")
    d.kill9()
    p.kill()
    p.wait()
    with open(os.path.join(out, "drive.k")) as f:
        mirror = cosim_mirror(f.read())
    d = Daemon(data_dir=data, durability="every-tick", name="after-kill")
    try:
        tick = wait_for(lambda: world_tick(d, "k"), 60)
        check(tick is not None and tick >= last, f"recovered tick {tick} >= the last STEPPED tick {last}")
        check(heights(d, "k") == mirror, "recovered heights == the driver's mirror at its last STEPPED tick")
        # a daemon killed while its driver steps
        p = subprocess.Popen([COSIM_DRIVE, str(d.ws_port), "m", str(STEPS), os.path.join(out, "drive")],
                             stdout=subprocess.PIPE, text=True)
        lines = []
        for line in p.stdout:
            lines.append(line)
            if len(lines) >= 400:
                break
        d.kill9()
        lines += p.stdout.readlines()
        p.wait()
        last = cosim_acked(lines)
        check(p.returncode != 0 and 400 <= len(lines) < STEPS, f"the driver lost its daemon after {len(lines)} steps")
    finally:
        d.stop()
    with check.running(Daemon(data_dir=data, durability="every-tick", name="after-second-kill")) as d:
        tick = wait_for(lambda: world_tick(d, "m"), 60)
        check(tick is not None and tick >= last, f"recovered tick {tick} >= the last STEPPED tick {last} seen")


def refusals():
    with check.running(Daemon(name="refusals")) as d:
        create(d, "wall", clock="wall")
        create(d, "c")
        status, doc = json_call(d.http, "GET", "/v1/worlds")
        clocks = {w["name"]: w.get("clock") for w in doc.get("worlds", [])}
        check(clocks.get("wall") == "wall" and clocks.get("c") == "client", f"GET /v1/worlds says the clock: {clocks}")
        status, doc = json_call(d.http, "POST", "/v1/worlds", {"name": "x", "clock": "sundial", "scene": cosim_scene()})
        check(status == 400 and doc.get("field") == "clock", f"clock sundial: {status} {doc}")
        bad = cosim_scene(clock="sundial")
        status, doc = json_call(d.http, "POST", "/v1/worlds", {"name": "y", "scene": bad})
        check(status == 422 and "clock" in doc.get("error", ""), f"scene clock sundial: {status} {doc}")
        out = tempfile.mkdtemp(prefix="terrad-cosim-")
        r = subprocess.run([COSIM_DRIVE, str(d.ws_port), "wall", "3", os.path.join(out, "w")],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode != 0 and "client-clocked" in r.stderr, f"a wall world is not stepped: {r.stderr}")
        # one driver at a time: a second driver is refused naming driver while the first waits
        p, _ = cosim_paused(d.ws_port, "c", 5, os.path.join(out, "d1"))
        r = subprocess.run([COSIM_DRIVE, str(d.ws_port), "c", "5", os.path.join(out, "d2")],
                           capture_output=True, text=True, timeout=120)
        check(r.returncode != 0 and "driver: client" in r.stderr, f"second driver: {r.stderr}")
        p.kill()
        p.wait()
        # the first driver gone, the next one drives
        ok = wait_for(lambda: subprocess.run([COSIM_DRIVE, str(d.ws_port), "c", "5", os.path.join(out, "d3")],
                                             capture_output=True, timeout=120).returncode == 0, 60, step=0.5)
        check(ok, "a new driver once the first left")
        _, text = d.metrics()
        check('terrad_steps_refused_total{field="driver"} 1' in text, "driver refusal counted")


def group_commit():
    """Under --durability group:MS a tick's frames wait for the sync that covers it; a
    client-clocked world has no later tick to publish them, so its step's end syncs: every
    step is answered, its ticks durable."""
    with check.running(Daemon(durability="group:400", name="group-commit")) as d:
        create(d, "g")
        texts = drive(d, ["g"], "many", steps=40)
        check(texts["g"].count("STEPPED ") == 40, "every step answered under group:400")


def default_world():
    """The daemon's own world (--scene) may be client-clocked too: it waits for its driver, and
    a driver (hello naming the scene) steps it as any created world. Waiting for its driver is not
    a stall: /healthz stays 200 past the 10 s watchdog limit with no step yet (issue 30: it
    answered 503 "tick", and a liveness probe would have restarted the daemon). Its demo actors go
    by its steps, not by how many height reads came between them (issue 30: the ticker's count,
    bumped by each read, posed them): the same steps give the same heights with reads between."""
    path = json_file(cosim_scene(clock="client"), "terrad-cosim-scene")
    try:
        with check.running(Daemon(extra=["--scene", path], demo=True, name="default-world")) as d:
            check(d.stats()["tick"] == 0, "a client-clocked default world does not tick by itself")
            time.sleep(12.5)  # past SERVE_STALL_LIMIT_MS (10 s) with no step: a condition of time
            status, body, _ = d.get("/healthz")
            check(status == 200, f"/healthz while it waits for its driver: {status} {body!r}")
            status, body, _ = d.get("/readyz")
            check(status == 200, f"/readyz while it waits for its driver: {status} {body!r}")
            texts = drive(d, ["cosim"], "many", steps=30)
            tick = int(texts["cosim"].split("STEPPED ")[-1].split()[0])
            # /v1/stats is published by the sim thread right after the tick; with --durability
            # none the STEPPED may reach the driver a moment before it (a condition, not a time)
            seen = [d.stats()["tick"]]
            deadline = time.time() + 60
            while seen[-1] < tick and time.time() < deadline:
                time.sleep(0.05)
                seen.append(d.stats()["tick"])
            check(seen[-1] == tick and max(seen) <= tick,
                  f"its tick is the last STEPPED, and no tick more: {seen[-1]} == {tick} (max {max(seen)})")
            quiet = heights(d, "cosim")
        with check.running(Daemon(extra=["--scene", path], demo=True, name="default-world-reads")) as d:
            stop = threading.Event()
            reads = [0]

            def read_heights():
                while not stop.is_set():
                    d.get(f"/v1/heights?x=0&y=0&w=8&h=8&world=cosim", timeout=60)
                    reads[0] += 1

            reader = threading.Thread(target=read_heights)
            reader.start()
            try:
                texts = drive(d, ["cosim"], "many", steps=30)
            finally:
                stop.set()
                reader.join()
            check(reads[0] > 0, f"height reads came between the steps ({reads[0]})")
            check(heights(d, "cosim") == quiet, "the same steps give the same heights, read between or not")
    finally:
        os.unlink(path)

determinism()
kill9()
refusals()
group_commit()
default_world()
check.finish()
