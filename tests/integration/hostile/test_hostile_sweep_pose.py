#!/usr/bin/python3
"""One client's sweep is bounded (issue 20's leftover: a lone fast client
sweeping a large collider was charged against the tick's budget but never
held, so nothing bounded it). A real daemon at the default limits
(max_sweep_cells 32,768) and two real websocket clients:

  - heavy: a 2 m sphere (window 89^2 = 7,921 cells, 206 per pose's depth, a
    lane of 89; 8,127 at rest without feedback: within max_active_cells
    8,192) posed at P0,
    then 100 cells away in one pose (200 sweep sub-steps: ~58 k cells). That
    pose is refused: error limit_colliders naming the collider, the pose's
    position and max_sweep_cells (ref = the batch's seq); the batch is still
    acknowledged; COLLIDERS shows the sphere still at P0; the refusal is
    counted in terrad_refused_messages_total{reason="limit_colliders"}. Then
    a pose 10 cells from P0 (20 sub-steps: ~12.8 k cells) is accepted with no
    error: the sphere swept from where it stood (from the refused pose it
    would have been 90 cells, refused again).
  - light: a 0.3 m sphere moved one cell per batch throughout; every batch is
    acknowledged and it never gets an error.

Behaviour only: waits are by condition with generous deadlines.
"""
# ctest-timeout: 240
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, RecordingClient, metric_value, tp  # noqa: E402

X0, Y, FAR, NEAR = 200, 384, 100, 10  # cells: start, row, the refused and the accepted move
Z = 5.0  # metres: above the dunes (the cost is the same in the air)
WAIT_S = 90


def refused(d):
    return metric_value(d.metrics()[1], "terrad_refused_messages_total",
                        {"reason": "limit_colliders"}) or 0


async def light_loop(light, lid, cell, stop, seqs):
    k = 0
    while not stop.is_set():
        seqs.append(await light.send_poses([tp.Pose(lid, (X0 + k % 50) * cell, 128 * cell, Z)]))
        k += 1
        await asyncio.sleep(0.05)


async def seen_at(client, seq):
    """Until the batch seq is acknowledged and a COLLIDERS frame of its tick or
    later is in (sent when the list changes, at most every 3 ticks, and an
    unchanged one again after 60)."""
    await client.wait_ack(seq, WAIT_S)
    tick = min(t for t, s in client.acks if s >= seq)
    await client.wait_for(lambda: client.colliders_tick >= tick, WAIT_S)


async def sweep_pose(check, d):
    world = d.world()
    cell = world["cell_size_m"]
    heavy = RecordingClient(d.ws, name="heavy", record=False)
    light = RecordingClient(d.ws, name="light", record=False)
    await heavy.connect()
    await light.connect()
    got = heavy.world.get("limits", {}).get("max_sweep_cells")
    check(got == 32768, f"the world message's limits carry max_sweep_cells 32768 ({got})")
    hid = (await heavy.request(tp.collider_create("sphere", feedback=False, radius=2.0),
                               "collider_created"))["id"]
    lid = await light.create_collider("sphere", radius=0.3)
    await heavy.subscribe(X0 - 64, Y - 64, FAR + 128, 128, colliders=True)
    stop, light_seqs = asyncio.Event(), []
    loop = asyncio.create_task(light_loop(light, lid, cell, stop, light_seqs))
    before = refused(d)

    p0 = (X0 * cell, Y * cell, Z)
    await heavy.wait_ack(await heavy.send_poses([tp.Pose(hid, *p0)]), WAIT_S)
    check(not heavy.errors, f"the pose at P0 is accepted ({heavy.errors[:1]})")

    far_seq = await heavy.send_poses([tp.Pose(hid, (X0 + FAR) * cell, Y * cell, Z)])
    await seen_at(heavy, far_seq)
    errs = [e for e in heavy.errors if e.get("ref") == far_seq]
    e = errs[0] if errs else {}
    msg = e.get("message", "")
    check(e.get("name") == "limit_colliders" and e.get("collider") == hid,
          f"the far pose is refused with limit_colliders naming collider {hid}: {e}")
    check("max_sweep_cells (32768)" in msg and f"collider {hid} at ({(X0 + FAR) * cell:.3f}, "
          f"{Y * cell:.3f}, {Z:.3f})" in msg and f"POSE_BATCH {far_seq}" in msg,
          f"the message names the batch, the pose's position and the budget: {msg!r}")
    st = heavy.colliders.get(hid)
    at = st.p if st else None
    check(at is not None and all(abs(a - b) < 1e-3 for a, b in zip(at, p0)),
          f"COLLIDERS shows the sphere still at P0 {p0}: {at}")
    n = refused(d)
    check(n >= before + 1, f"terrad_refused_messages_total{{reason=limit_colliders}} counts it "
          f"({before} -> {n})")

    count = len(heavy.errors)
    near_seq = await heavy.send_poses([tp.Pose(hid, (X0 + NEAR) * cell, Y * cell, Z)])
    await seen_at(heavy, near_seq)
    check(len(heavy.errors) == count,
          f"a pose {NEAR} cells from P0 is accepted: the sphere swept from where it stood "
          f"({heavy.errors[count:count + 1]})")
    st = heavy.colliders.get(hid)
    want = ((X0 + NEAR) * cell, Y * cell, Z)
    check(st is not None and all(abs(a - b) < 1e-3 for a, b in zip(st.p, want)),
          f"COLLIDERS shows it at {want}: {st.p if st else None}")

    stop.set()
    await loop
    await light.wait_ack(light_seqs[-1], WAIT_S)
    check(not light.errors, f"the light client got no error ({light.errors[:1]})")
    check(len(light_seqs) > 3 and light.acked_seq == light_seqs[-1],
          f"every one of the light client's {len(light_seqs)} batches was acknowledged")
    check(d.alive(), "the daemon goes on")
    await heavy.close()
    await light.close()


def main():
    check = Checks()
    d = Daemon(tick_hz=20, name="terrad-sweep-pose")
    with check.running(d):
        asyncio.run(sweep_pose(check, d))
    check.finish()


if __name__ == "__main__":
    main()
