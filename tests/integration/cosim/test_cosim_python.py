#!/usr/bin/python3
# ctest-timeout: 600
"""Lockstep co-simulation from Python (issue 30, items 1 and 2), against a real daemon on
loopback:

- terrad.WheelVecEnv, the reset()/step(actions) vectorised environment: three worlds stepped as
  one give, for each world, exactly the observations, rewards, terminated, truncated and ticks
  (NumPy arrays, compared bit for bit) and the heights that the same world's actions give when it
  is stepped alone; the arrays have the interface's shapes and types; a wheel that reaches the end
  of its bin is terminated at that step and never truncated; in a run whose max_steps comes before
  any wheel's end every world is truncated at max_steps and after, never before;
- every refusal of a STEP names its field, counts in terrad_steps_refused_total{field} and leaves
  the world as it was: ticks 0 and sets not 0/1/ticks (bad_value), ticks over max_step_ticks and
  count over max_poses_per_batch (too_large), a NaN pose (poses[i]), another client's collider
  (not_owner), a wall-clocked world (clock), a second driver (driver), a viewer (forbidden); the
  world's tick has not moved and its driver steps on;
- the budgets hold per stepped tick: a stepped pose whose sweep passes max_sweep_cells is refused
  alone at its tick (limit_colliders), and the step still runs and is answered.

Behaviour only: every wait is for a condition, with a generous deadline.
"""
import asyncio
import os
import struct
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, json_call, metric_value, tp  # noqa: E402

check = Checks()
K, STEPS = 3, 110


def actions(t):
    """Each world's slip at step t: different per world and over time."""
    return np.array([0.1 + 0.002 * t, 0.35 - 0.003 * t, -0.2 + 0.004 * (t % 17)], np.float32)


def run(d, prefix, which, steps=STEPS, max_steps=STEPS - 5):
    """Runs the worlds `which` (indices into actions) as one WheelVecEnv for `steps` steps; returns
    per world the list of (obs, reward, terminated, truncated, tick) and its final heights."""
    env = tp.WheelVecEnv(d.http, d.ws, len(which), prefix=prefix, ticks_per_step=4,
                         max_steps=max_steps)
    rows = {i: [] for i in which}
    try:
        obs, info = env.reset()
        check(obs.shape == (len(which), 6) and obs.dtype == np.float32, f"{prefix}: reset obs {obs.shape}")
        for t in range(steps):
            a = actions(t)[list(which)]
            obs, rew, term, trunc, info = env.step(a)
            if t == 0:
                check(rew.shape == (len(which),) and rew.dtype == np.float32 and term.dtype == bool
                      and trunc.dtype == bool and info["tick"].dtype == np.int64, f"{prefix}: step arrays")
            for k, i in enumerate(which):
                rows[i].append((obs[k].tobytes(), rew[k].tobytes(), bool(term[k]), bool(trunc[k]),
                                int(info["tick"][k])))
        hs = {}
        for k, i in enumerate(which):
            status, body, _ = d.get(f"/v1/heights?x=0&y=0&w=160&h=24&world={prefix}-{k}", timeout=60)
            hs[i] = body if status == 200 else None
        return rows, hs
    finally:
        env.close()


def vecenv(d):
    many, many_h = run(d, "many", (0, 1, 2))
    for i in range(K):
        alone, alone_h = run(d, f"alone{i}", (i,))
        check(alone[i] == many[i], f"world {i}: stepped alone == stepped as one of {K} (every array, every step)")
        check(alone_h[i] is not None and alone_h[i] == many_h[i], f"world {i}: heights alone == as one")
    rows = many[0]
    first_end = next((t for t, r in enumerate(rows) if r[2]), None)
    check(first_end is not None and first_end < STEPS - 5, f"world 0 reaches the end of its bin (step {first_end})")
    check(all(r[2] for r in rows[first_end:]), "terminated stays set until reset")
    check(any(np.frombuffer(r[0], np.float32)[3] > 0 for r in rows), "the wheel sinks in (sinkage > 0)")
    ticks = [r[4] for r in rows]
    check(ticks[:5] == [5, 9, 13, 17, 21], f"four ticks a step after the reset's one: {ticks[:5]}")
    ends(many, STEPS - 5)
    # every wheel here reaches the end of its bin before STEPS - 5 steps: truncation is checked
    # on a run whose max_steps comes first (6 steps of 4 ticks: no wheel gets that far)
    short, _ = run(d, "short", (0, 1, 2), steps=9, max_steps=6)
    check(ends(short, 6) == K, f"every world of a run shorter than its bin is truncated at max_steps")


def ends(rows, max_steps):
    """Checks each world's terminated/truncated flags: max_steps steps make step index
    max_steps - 1 the last; a world not terminated by then is truncated there and after, never
    before; a terminated one never is, and none is both at once. Returns how many truncated."""
    last, truncated = max_steps - 1, 0
    for i, rs in rows.items():
        trunc = [t for t, r in enumerate(rs) if r[3]]
        term = next((t for t, r in enumerate(rs) if r[2]), None)
        check(not any(r[2] and r[3] for r in rs), f"world {i}: never terminated and truncated at once")
        if term is not None and term <= last:
            check(not trunc, f"world {i}: terminated at step {term}, never truncated ({trunc[:1]})")
        else:
            truncated += 1
            check(trunc[:1] == [last] and all(r[2] or r[3] for r in rs[last:]),
                  f"world {i}: not terminated by step {last}, truncated at max_steps (step {last}) "
                  f"and after ({trunc[:1]}, terminated at {term})")
    return truncated


def raw_step(seq, ticks, count, sets, poses=b""):
    return bytes([0x54, 1, 0x04, 0]) + struct.pack("<IIHH", seq, ticks, count, sets) + poses


def pose_bytes(cid, x, y, z, qw=1.0):
    return struct.pack("<I7f", cid, x, y, z, qw, 0.0, 0.0, 0.0)


async def refused(c, frame, seq):
    """Sends a raw STEP frame; returns the error answering it (ref "step:SEQ")."""
    await c.ws.send(frame)
    ref = f"step:{seq}"
    await c.wait_for(lambda: any(e.get("ref") == ref for e in c.errors), 30)
    e = next(e for e in c.errors if e.get("ref") == ref)
    return e


async def refusals(d):
    scene = tp.wheel_scene()
    json_call(d.http, "POST", "/v1/worlds", {"name": "r", "scene": scene})
    json_call(d.http, "POST", "/v1/worlds", {"name": "wall", "clock": "wall", "scene": scene})
    async with tp.Client(d.ws, world="r", name="driver") as c, \
            tp.Client(d.ws, world="r", name="other") as o, \
            tp.Client(d.ws, world="wall", name="walker") as w:
        check(c.world.get("clock") == "client" and w.world.get("clock") == "wall", "world message says the clock")
        wheel = await c.create_collider("wheel", radius=0.15, width=0.1, load_n=60)
        theirs = await o.create_collider("sphere", radius=0.1)
        p = tp.Pose(wheel, 0.6, 0.24, 0.45, 1, 0, 0, 0)
        t0 = await c.step(1, [[p]])
        check(t0 == 1, f"first step ends at tick 1 ({t0})")
        lim = c.world["limits"]
        cases = [
            ("ticks", "bad_value", raw_step(100, 0, 0, 0)),
            ("ticks", "too_large", raw_step(101, lim["max_step_ticks"] + 1, 0, 0)),
            ("sets", "bad_value", raw_step(102, 3, 1, 2, pose_bytes(wheel, 0.6, 0.24, 0.45) * 2)),
            ("count", "too_large", raw_step(103, 1, lim["max_poses_per_batch"] + 1, 1,
                                            pose_bytes(wheel, 0.6, 0.24, 0.45) * (lim["max_poses_per_batch"] + 1))),
            ("poses[0]", "bad_value", raw_step(104, 1, 1, 1, pose_bytes(wheel, float("nan"), 0.24, 0.45))),
            ("poses[0]", "not_owner", raw_step(105, 1, 1, 1, pose_bytes(theirs, 0.6, 0.24, 0.45))),
            ("frame", "bad_frame", raw_step(106, 1, 1, 1, b"\0" * 7)),
        ]
        for field, name, frame in cases:
            e = await refused(c, frame, struct.unpack_from("<I", frame, 4)[0])
            check(e["name"] == name and e["message"].startswith(field),
                  f"{field or name}: {e['name']}: {e['message']}")
        e = await refused(w, raw_step(7, 1, 0, 0), 7)
        check(e["name"] == "bad_value" and e["message"].startswith("clock"), f"wall world: {e['message']}")
        e = await refused(o, raw_step(8, 1, 0, 0), 8)
        check(e["name"] == "forbidden" and e["message"].startswith("driver"), f"second driver: {e['message']}")
        status, doc = json_call(d.http, "GET", "/v1/worlds")
        tick = {x["name"]: x["tick"] for x in doc["worlds"]}["r"]
        check(tick == 1, f"no refused step ticked the world (tick {tick})")
        t1 = await c.step(2)
        check(t1 == 3, f"the driver steps on: tick {t1}")
        # the budgets hold per stepped tick: a pose 2 m away in one tick would pass
        # max_sweep_cells; that pose alone is refused at its tick, the step still runs and is answered
        t2 = await c.step(1, [[tp.Pose(wheel, 2.6, 0.24, 0.45, 1, 0, 0, 0)]])
        await c.wait_for(lambda: any(e.get("name") == "limit_colliders" for e in c.errors), 30)
        e = next(e for e in c.errors if e.get("name") == "limit_colliders")
        check(t2 == t1 + 1 and "max_sweep_cells" in e["message"],
              f"a stepped tick's sweep past max_sweep_cells refused ({t2}): {e['message']}")
        try:
            await c.step(1, [[tp.Pose(theirs, 0.6, 0.24, 0.45, 1, 0, 0, 0)]])
            check(False, "a step with another client's collider raises")
        except tp.ServerError as err:
            check(err.msg.get("name") == "not_owner", f"Client.step raises ServerError: {err}")
    _, text = d.metrics()
    for field in ("ticks", "sets", "count", "poses", "frame", "clock", "driver"):
        v = metric_value(text, "terrad_steps_refused_total", {"field": field})
        check(v and v >= 1, f"terrad_steps_refused_total{{field={field}}} = {v}")


with check.running(Daemon(name="cosim-python", config={"limits": {"max_sweep_cells": 3000}})) as d:
    vecenv(d)
    asyncio.run(refusals(d))
check.finish()
