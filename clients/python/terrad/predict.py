"""Client-side prediction of a subscription's heights (docs/engines.md, "Prediction"): a
player sees their own rut in the frame they move, not a round trip later.

    sid = await client.subscribe(x, y, w, h)
    await client.wait_complete(sid)
    pred = client.predict(sid, {"model": "persson-ssbo", ...})   # the world's parameters
    wheel = await client.create_collider("wheel", radius=0.3, width=0.2)
    await client.send_poses([Pose(wheel, ...)])   # the twin ticks at once
    pred.heights()                                 # the rut is there already

The Prediction is the twin library's (terrad_twin_prediction_* in terrad_twin.h, through
terrad.twin's ctypes): the steps below are C, the same code the C client and the JavaScript
clients (as WebAssembly) run. Each pose
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

If the twin fails on one of these events (at an ACK, a soil state it could not restore: out
of memory), the ACK is taken all the same: `errors` counts it and `last_error` keeps the twin's
sentence, nothing is raised, and the client goes on (its other frames are handled, the next
ACK compares and resets as before).

Exact when: the world's parameters given to predict() are the server's (the scene's model,
material and margin), the window has a halo wide enough for the own colliders' reach
(docs/engines.md, "Halo"), and ACKs are not coalesced (a slow client's ACKs may be; the step-1
count then shows it and step 2 still resets to the server's state).
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from .proto import Pose
from .twin import (_ERR_MAX, PredictionStats, Twin, TwinError, grouser_numbers, int32s,
                   load_library, make_config)

if TYPE_CHECKING:
    from .client import Client


def _stat(name: str) -> Any:
    """A counter of the library's terrad_twin_prediction_stats, read when asked."""
    return property(lambda self: int(getattr(self._stats(), name)), doc=f"stats: {name}")


class Prediction:
    """A predicting twin on one subscription of a Client (Client.predict makes it).

    heights(): the predicted heights, the server's at the last ACK plus the own batches
    sent since. Counters: predicted (batches ticked at once), reconciled (ACKs taken),
    replayed (ACKs whose replay was compared with the server), exact (of those, 0 cells
    differing), last_differing (cells of the last comparison), skipped (ACKs not compared:
    the mirror was resyncing, the gap was longer than max_replay_ticks, or several batches
    were acknowledged after a gap of ticks, so which tick took each is unknown), on_time (ACKs
    of tick t, batch seq, where the heights predicted for seq before the ACK were the
    server's at t: the batches landed one per tick, as the prediction assumes), errors (the
    client's events the twin failed on: an ACK taken with the soil state not restored, out of
    memory, or a batch not predicted; nothing is raised) and last_error (the twin's sentence
    for the last of them, "" while none). pending: the seqs sent and not acknowledged yet;
    twin: the prediction's twin (terrad.twin.Twin), to read.
    """

    predicted = _stat("predicted")
    reconciled = _stat("reconciled")
    replayed = _stat("replayed")
    exact = _stat("exact")
    skipped = _stat("skipped")
    on_time = _stat("on_time")
    last_differing = _stat("last_differing")

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
        self._lib = load_library(library)
        self._err = ctypes.create_string_buffer(_ERR_MAX)
        self._p: int | None = None
        self._cells = m.w * m.h
        self.errors = 0
        self.last_error = ""
        c = make_config(self._lib, cfg, self._err)
        try:
            p = self._lib.terrad_twin_prediction_create(
                c, m.x, m.y, m.w, m.h, int32s(m.heights, self._cells, "heights"),
                max_replay_ticks or 0, self._err)
        finally:
            self._lib.terrad_twin_config_free(c)
        if not p:
            raise TwinError(self._err.value.decode(errors="replace"))
        self._p = p
        self.twin = Twin.view(self._lib, self._lib.terrad_twin_prediction_twin(p), m.x, m.y,
                              m.w, m.h)
        self._on_predict: list[Callable[[int], None]] = []
        try:
            for cid, (shape, dims) in client.own_colliders.items():
                self.add_collider(cid, shape, dims)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self._p is not None:
            self.twin.close()
            self._lib.terrad_twin_prediction_destroy(self._p)
            self._p = None

    def __del__(self) -> None:
        if getattr(self, "_p", None) is not None:
            self.close()

    def _handle(self) -> int:
        if self._p is None:
            raise TwinError("prediction: closed")
        return self._p

    def _check(self, rc: int) -> None:
        if rc != 0:
            raise TwinError(self._err.value.decode(errors="replace"))

    def _took(self, rc: int) -> None:
        """The twin's call for one of the client's events returned rc: a failure is counted
        with its sentence, not raised (the client goes on)."""
        if rc != 0:
            self.errors += 1
            self.last_error = self._err.value.decode(errors="replace")

    def _stats(self) -> PredictionStats:
        return self._lib.terrad_twin_prediction_get_stats(self._handle()).contents

    @property
    def pending(self) -> list[int]:
        """The seqs of the batches sent and not acknowledged yet, oldest first."""
        n = self._lib.terrad_twin_prediction_pending(self._handle(), None, 0)
        seqs = (ctypes.c_uint32 * max(n, 1))()
        self._lib.terrad_twin_prediction_pending(self._handle(), seqs, n)
        return list(seqs[:n])

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
        this): sphere, box, capsule, cylinder, wheel (with its grousers, if any), mesh; with
        load_n, load-driven as on the server (its height the soil's, found each tick)."""
        if dims.get("material", "default") != "default" or "pose" in dims:
            raise TwinError(f"collider {cid}: a predicted collider has the default material "
                            "and gets its poses from send_poses (no pose at creation)")
        p = self._handle()
        if shape == "mesh":
            v, i = dims["vertices"], dims["indices"]
            self._check(self._lib.terrad_twin_prediction_add_mesh(
                p, cid, (ctypes.c_float * len(v))(*v), len(v) // 3,
                (ctypes.c_uint32 * len(i))(*i), len(i) // 3, self._err))
        elif shape == "wheel":
            self._check(self._lib.terrad_twin_prediction_add_wheel(
                p, cid, dims.get("radius", 0.0), dims["width"] / 2,
                *grouser_numbers(dims.get("grousers")), self._err))
        else:
            hx, hy, hz = dims.get("half_extents", (0.0, 0.0, 0.0))
            half_length = dims.get("half_length", 0.0)
            self._check(self._lib.terrad_twin_prediction_add_collider(
                p, cid, shape.encode(), dims.get("radius", 0.0), half_length, hx, hy, hz,
                self._err))
        if dims.get("load_n") is not None:
            self._check(self._lib.terrad_twin_prediction_set_load(p, cid, float(dims["load_n"]),
                                                                  self._err))

    def remove_collider(self, cid: int) -> None:
        self._check(self._lib.terrad_twin_prediction_remove_collider(self._handle(), cid,
                                                                     self._err))

    # ---- sending and reconciling -----------------------------------------------------------

    def on_send(self, seq: int, poses: list[Pose]) -> None:
        """Batch seq is about to be sent: tick it locally at once."""
        ids = (ctypes.c_uint32 * max(len(poses), 1))(*(p.id for p in poses))
        values = (ctypes.c_double * max(7 * len(poses), 1))(
            *(v for p in poses for v in (p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz)))
        self._took(self._lib.terrad_twin_prediction_sent(self._handle(), seq, ids, values,
                                                         len(poses), self._err))
        for cb in list(self._on_predict):
            cb(seq)

    def on_ack(self, tick: int, seq: int) -> None:
        """The server's ACK of tick t (batch seq); the mirror holds the server's heights at t
        (or is resyncing: then the batches are forgotten and the next ACK reconciles). A
        soil state the twin could not restore is counted (errors, last_error), not raised."""
        m = self.client.mirrors.get(self.sid)
        server = int32s(m.heights, self._cells, "heights") if m is not None and m.complete \
            else None
        self._took(self._lib.terrad_twin_prediction_acked(self._handle(), tick, seq, server,
                                                          self._err))
