"""Client-side prediction of a subscription's heights (docs/engines.md, "Prediction"): a
player sees their own rut in the frame they move, not a round trip later.

    sid = await client.subscribe(x, y, w, h)
    await client.wait_complete(sid)
    pred = client.predict(sid, {"model": "persson-ssbo", ...})   # the world's parameters
    wheel = await client.create_collider("wheel", radius=0.3, width=0.2)
    await client.send_poses([Pose(wheel, ...)])   # the twin ticks at once
    pred.heights()                                 # the rut is there already

The Prediction runs the twin library (terrad.twin) on the subscription's window. Each pose
batch the client sends is one tick of the twin, at once, with the client's own colliders at
their new poses. The server stays the authority: when its ACK of tick t (batch seq) arrives,
the client's mirror holds the server's heights at t. The twin then

1. replays, from the server's heights at the previous ACK, the ticks up to t with the poses
   the server used — the ACKs say which: tick t used batch seq, and a tick without an ACK used
   the poses of the tick before — and counts the cells where that replay differs from the
   server at t (`last_differing`; 0 whenever no other collider or edit touched the window:
   server and client twin are the same code, bit for bit);
2. takes the server's heights at t (its mirror), puts its colliders where tick t left them,
   and applies the batches sent after seq again, one tick each.

So any difference another client's collider, an edit or a late batch made is gone at every
ACK. Prediction sends nothing: the wire is the same with it on or off.

Exact when: the world's parameters given to predict() are the server's (the scene's model,
material and margin), the window has a halo wide enough for the own colliders' reach
(docs/engines.md, "Halo"), and ACKs are not coalesced (a slow client's ACKs may be; the step-1
count then shows it and step 2 still resets to the server's state).
"""

from __future__ import annotations

import array
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .proto import Pose, _f32
from .twin import Twin, TwinError

if TYPE_CHECKING:
    from .client import Client

_QUARTER_X = (0.70710678118654752440, 0.70710678118654752440, 0.0, 0.0)


def _normalize(q: tuple[float, ...]) -> tuple[float, ...]:
    """collider.c's quat_normalize, operation for operation (so the result is its bits)."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 1e-300) or not math.isfinite(n):
        return (1.0, 0.0, 0.0, 0.0)
    return (w / n, x / n, y / n, z / n)


def _multiply(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, ...]:
    """collider.c's quat_multiply."""
    return (a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0])


def server_pose(p: Pose, axis_z: bool) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The pose exactly as the server uses it: every number through float32 (the wire), the
    quaternion normalised, and for a capsule or cylinder (axis z on the wire, y in the
    engine) turned a quarter about x (net_control_orientation)."""
    v = [_f32(a) for a in (p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz)]
    q = _normalize(tuple(v[3:]))
    if axis_z:
        q = _normalize(_multiply(q, _QUARTER_X))
    return (v[0], v[1], v[2]), q


class Prediction:
    """A predicting twin on one subscription of a Client (Client.predict makes it).

    heights(): the predicted heights, the server's at the last ACK plus the own batches
    sent since. Counters: predicted (batches ticked at once), reconciled (ACKs taken),
    replayed (ACKs whose replay was compared with the server), exact (of those, 0 cells
    differing), last_differing (cells of the last comparison), skipped (ACKs not compared:
    the mirror was resyncing, the gap was longer than max_replay_ticks, or several batches
    were acknowledged after a gap of ticks, so which tick took each is unknown), on_time (ACKs
    of tick t, batch seq, where the heights predicted for seq before the ACK were the
    server's at t: the batches landed one per tick, as the prediction assumes).
    """

    def __init__(self, client: Client, sid: int, config: dict[str, Any],
                 library: str | None = None, max_replay_ticks: int | None = None):
        m = client.mirrors.get(sid)
        if m is None:
            raise ValueError(f"sid: no subscription {sid}")
        if not m.complete:
            raise ValueError(f"sid: subscription {sid} has no snapshot yet (wait_complete)")
        world = client.world
        cfg: dict[str, Any] = {k: world[k] for k in ("width", "height", "cell_size_m",
                                                    "units_per_m", "tick_hz") if k in world}
        cfg.update(config)
        self.client, self.sid = client, sid
        self.twin = Twin(cfg, m.x, m.y, m.w, m.h, m.heights, library)
        self.base = list(m.heights)  # the server's heights at the last ACK
        self.base_tick: int | None = None
        self.max_replay_ticks = (max_replay_ticks if max_replay_ticks is not None
                                 else int(4 * float(cfg.get("tick_hz", 60))))
        self.axis_z: dict[int, bool] = {}
        self.acked: dict[int, tuple[tuple[float, ...], tuple[float, ...]]] = {}
        # sent, not acknowledged: (seq, the batch's server poses, a digest of its prediction)
        self.pending: list[tuple[int, dict[int, Any], int]] = []
        self.predicted = self.reconciled = self.replayed = self.exact = self.skipped = 0
        self.on_time = 0
        self.last_differing = 0
        self._on_predict: list[Callable[[int], None]] = []
        for cid, (shape, dims) in client.own_colliders.items():
            self.add_collider(cid, shape, dims)

    def close(self) -> None:
        self.twin.close()

    def on_predict(self, callback: Callable[[int], None]) -> None:
        """callback(seq) right after batch seq was ticked locally, before it is sent."""
        self._on_predict.append(callback)

    def heights(self) -> Any:
        """The predicted heights: NumPy int32 (h, w) or a list of rows, like Client.heights."""
        from .client import heights_grid
        return heights_grid(list(self.twin.read()), self.twin.w, self.twin.h)

    # ---- the client's own colliders -------------------------------------------------------

    def add_collider(self, cid: int, shape: str, dims: dict[str, Any]) -> None:
        """The twin's copy of a collider this client created (Client.create_collider calls
        this): sphere, box, capsule, cylinder, wheel, mesh."""
        if shape == "sphere":
            self.twin.add_collider(cid, "sphere", radius=dims["radius"])
        elif shape == "box":
            self.twin.add_collider(cid, "box", half_extents=dims["half_extents"])
        elif shape in ("capsule", "cylinder"):
            self.twin.add_collider(cid, shape, radius=dims["radius"],
                                   half_length=dims["half_length"])
        elif shape == "wheel":
            self.twin.add_collider(cid, "cylinder", radius=dims["radius"],
                                   half_length=dims["width"] / 2)
        elif shape == "mesh":
            self.twin.add_mesh(cid, dims["vertices"], dims["indices"])
        else:
            raise TwinError(f"shape: {shape!r} cannot be predicted")
        if dims.get("material", "default") != "default" or "pose" in dims:
            self.twin.remove_collider(cid)
            raise TwinError(f"collider {cid}: a predicted collider has the default material "
                            "and gets its poses from send_poses (no pose at creation)")
        self.axis_z[cid] = shape in ("capsule", "cylinder")

    def remove_collider(self, cid: int) -> None:
        if cid in self.axis_z:
            self.twin.remove_collider(cid)
            del self.axis_z[cid]
            self.acked.pop(cid, None)

    # ---- sending and reconciling -----------------------------------------------------------

    def _apply(self, batch: dict[int, Any]) -> int:
        """One tick of the twin with these poses; a digest of the heights it left."""
        for cid, (p, q) in batch.items():
            if cid in self.axis_z:
                self.twin.set_pose(cid, p, q)
        self.twin.tick()
        return hash(self.twin.read().tobytes())

    def on_send(self, seq: int, poses: list[Pose]) -> None:
        """Batch seq is about to be sent: tick it locally at once."""
        batch = {p.id: server_pose(p, self.axis_z.get(p.id, False)) for p in poses}
        self.pending.append((seq, batch, self._apply(batch)))
        self.predicted += 1
        for cb in list(self._on_predict):
            cb(seq)

    def _restart(self, heights: list[int]) -> None:
        """The twin at the server's heights, each collider where the acknowledged tick left
        it (one without an acknowledged pose has none)."""
        self.twin.write(heights)
        for cid in list(self.axis_z):
            if cid in self.acked:
                self.twin.place(cid, *self.acked[cid])
            else:  # remove and add: the twin forgets a pose it was given
                self.twin.remove_collider(cid)
                shape, dims = self.client.own_colliders[cid]
                self.add_collider(cid, shape, dims)

    def on_ack(self, tick: int, seq: int) -> None:
        """The server's ACK of tick t (batch seq); the mirror holds the server's heights at t."""
        m = self.client.mirrors.get(self.sid)
        done = [e for e in self.pending if (seq - e[0]) & 0xFFFFFFFF < 0x80000000]
        self.pending = [e for e in self.pending if (seq - e[0]) & 0xFFFFFFFF >= 0x80000000]
        used = [b for _, b, _ in done]
        if m is None or not m.complete:
            self.skipped += 1  # resyncing: reconcile at the next ACK that has the heights
            for b in used:
                for cid, pose in b.items():
                    self.acked[cid] = pose
            return
        server = m.heights
        if done and done[-1][0] == seq:  # was batch seq's prediction the server's tick t?
            self.on_time += done[-1][2] == hash(array.array("i", server).tobytes())
        if not self.acked:
            gap = 1  # nothing of ours pressed before t: the idle ticks changed nothing
        else:
            gap = tick - self.base_tick if self.base_tick is not None else 0
        # Batches acknowledged together after a gap of ticks may have been taken at different
        # ticks of it (a slow client's older ACK is replaced by the newer one, PROTOCOL.md
        # "Slow clients"): which tick took which is not known, so that ACK is not compared.
        spread = gap > 1 and len(used) > 1
        if 1 <= gap <= self.max_replay_ticks and not spread:
            self._restart(self.base)
            for _ in range(gap - 1):  # ticks without an ACK: the poses stood still
                self.twin.tick()
            merged: dict[int, Any] = {}
            for b in used:  # a tick takes the latest pose of each collider
                merged.update(b)
            self._apply(merged)
            replay = self.twin.read()
            self.last_differing = sum(1 for a, b in zip(replay, server) if a != b)
            self.replayed += 1
            self.exact += self.last_differing == 0
        else:
            self.skipped += 1
        for b in used:
            for cid, pose in b.items():
                self.acked[cid] = pose
        self.base = list(server)
        self.base_tick = tick
        self._restart(self.base)
        self.pending = [(s, b, self._apply(b)) for s, b, _ in self.pending]
        self.reconciled += 1
