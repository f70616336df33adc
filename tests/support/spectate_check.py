"""Spectators' exactness (PROTOCOL.md "Spectate"), shared by test_spectate (a single daemon's
data directory) and test_cluster_spectate (a cluster node's JetStream log): a live viewer that
keeps its mirror after every DELTA frame, a drive that changes the window (a sphere pressed
along a track, two craters by edit), a spectator of the window, and the comparison of the
spectator's mirror at each of its ticks with the viewer's (and with GET /v1/heights?tick=N).

Not a test itself (ctest registers only test_*.py). Run with /usr/bin/python3.
"""
from service_harness import RecordingClient
import compaction_drive as cd
import terrad as tp

WAIT = 120  # seconds: generous, a loaded 2-core machine
REGION = (0, 0, cd.W, cd.H)


class Viewer(tp.TerradClient):
    """A live subscriber that keeps its mirror after every DELTA frame, by tick (the last
    frame of tick t leaves the mirror at t; a tick without frames left it as it was)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.by_tick = {}

    async def _on_binary(self, data):
        await super()._on_binary(data)
        if tp.decode_header(data) == tp.MsgType.DELTA:
            m = next(iter(self.mirrors.values()), None)
            if m is not None and m.complete:
                self.by_tick[self.tick] = list(m.heights)

    def at(self, tick):
        """The viewer's mirror at tick (None before its snapshot)."""
        held = [t for t in self.by_tick if t <= tick]
        return self.by_tick[max(held)] if held else None


async def drive(ws, poses, craters=(), world=""):
    """A driver on websocket ws presses a sphere at each x of poses along the track (waiting
    for each ACK), and makes a crater by edit after the poses whose index is in craters."""
    c = RecordingClient(ws, name="driver", record=False, world=world)
    await c.connect()
    sphere = await c.create_collider("sphere", radius=cd.RADIUS)
    z = cd.GROUND + cd.RADIUS - 0.03
    for i, x in enumerate(poses):
        seq = await c.send_poses([tp.Pose(sphere, x, cd.Y, z, 1.0, 0.0, 0.0, 0.0)])
        await c.wait_ack(seq, WAIT)
        if i in craters:  # edits are logged and spectated like the collider's ruts
            await c.edit("crater", x=20 + i, y=20, radius=6, depth=500)
    await c.close()


async def spectate(ws, what, from_tick, tick_now, speed=8, world=""):
    """A spectator of REGION from from_tick until its spectate_end: (its subscription id, the
    client, the world's tick when it started: tick_now())."""
    s = RecordingClient(ws, name=f"spectator-{what}", keep=10 ** 6, world=world)
    await s.connect()
    started_at = tick_now()
    sid = await s.spectate(*REGION, from_tick, speed=speed, timeout=WAIT)
    await s.wait_for(lambda: s.spectate_ended is not None, WAIT * 2)
    return sid, s, started_at


def compare(check, viewer, s, sid, what, from_tick, started_at, read_past):
    """The spectator s (subscription sid, from from_tick) against the viewer at every tick it
    saw; read_past(tick): the window as GET /v1/heights?tick=N gives it (None: refused)."""
    seen = sorted(t for t in s.history if t >= from_tick)
    same, first_bad = 0, None
    for t in seen:
        mine = s.history[t].get(sid)
        live = viewer.at(t)
        if live is None:  # before the viewer's snapshot: what the log holds for that tick
            live = read_past(t)
        ok = mine is not None and mine[1] and live is not None and mine[0] == live
        same += ok
        if not ok and first_bad is None:
            first_bad = (t, "incomplete" if mine is None or not mine[1] else
                         sum(a != b for a, b in zip(mine[0], live or [])))
    changed = [t for t in viewer.by_tick if t > from_tick]
    if from_tick == 0:
        check(s.history[0][sid][0] == read_past(0),
              f"{what}: its first mirror is the world's base (GET /v1/heights?tick=0)")
    check(len(seen) >= len(changed) and seen and seen[0] == from_tick,
          f"{what}: the spectator saw every tick from {from_tick} ({len(seen)} ticks, "
          f"{len(changed)} of them changed the window)")
    check(same == len(seen), f"{what}: its mirror equals the live viewer's at all {len(seen)} ticks "
                             f"({same} equal; first differing: {first_bad})")
    check(viewer.at(seen[0]) != viewer.at(seen[-1]),
          f"{what}: the window changed while it watched (so the comparison can fail)")
    samples = [seen[0], seen[len(seen) // 3], seen[2 * len(seen) // 3], seen[-1]]
    past = [read_past(t) == s.history[t][sid][0] for t in samples]
    check(all(past), f"{what}: and GET /v1/heights?tick=N at ticks {samples} ({past})")
    end = s.spectate_ended
    check(end and end["reason"] == "live" and end["tick"] >= started_at,
          f"{what}: spectate_end \"live\" once it caught up with the live tick ({end}, "
          f"started at {started_at})")
    check(s.desync["checksum_frames"] == 0,
          f"{what}: no CHECKSUM frame reached the spectator ({s.desync['checksum_frames']})")
