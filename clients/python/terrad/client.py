"""terrad's asyncio client: hello, colliders, poses, subscriptions with exact local mirrors,
contact feedback, and a public callback for every kind of frame.

    async with Client("ws://127.0.0.1:8081/") as client:
        wheel = await client.create_collider("wheel", radius=0.35, width=0.25)
        sid = await client.subscribe(0, 0, 256, 256)
        client.on(MsgType.ACK, lambda tick, seq: print("tick", tick, "used batch", seq))
        await client.send_poses([Pose(wheel, 10.0, 10.0, 0.3)])
        heights = client.heights(sid)   # NumPy int32 array (h, w), or a list of rows

Needs the websockets module (pip install websockets; Debian: python3-websockets) and the
codec's zstandard; NumPy is optional.
"""

from __future__ import annotations

import asyncio
import inspect
import json
from collections.abc import Awaitable, Callable
from typing import Any, Union

from .predict import Prediction
from .twin import TwinError
from .proto import (_U32, SUBPROTOCOL, ColliderState, Contact, Footprint, Force, Mirror, MsgType,
                    Pose, ProtoError, ServerError, collider_create, collider_delete,
                    decode_ack, decode_checksum, decode_colliders, decode_contact, decode_delta,
                    decode_footprints, decode_forces, decode_header, decode_ping, decode_stepped,
                    encode_ping, encode_step,
                    edit, encode_pose_batch, error, focus, frame_tick, hello, parse_control,
                    resync, seen, spectate, spectate_step, spectate_stop, subscribe,
                    unsubscribe)

try:
    import numpy as _np
except ImportError:  # NumPy is optional: heights come as lists of rows without it
    _np = None  # type: ignore[assignment]

HAVE_NUMPY = _np is not None

#: What `Client.on` takes: a MsgType, or "message" for the JSON control messages.
FrameKind = Union[MsgType, str]
Callback = Callable[..., Union[None, Awaitable[None]]]

#: The arguments each kind of callback is called with.
#: How often, at most, a client tells the server the tick it has handled ("seen").
SEEN_INTERVAL_S = 0.1

CALLBACK_ARGS: dict[FrameKind, str] = {
    MsgType.DELTA: "(tick, rects) after the mirrors applied them",
    MsgType.CONTACT: "(tick, contacts)",
    MsgType.ACK: "(tick, seq)",
    MsgType.COLLIDERS: "(tick, states)",
    MsgType.FOOTPRINTS: "(tick, events)",
    MsgType.FORCES: "(tick, forces)",
    MsgType.STEPPED: "(tick, seq, ticks): a STEP of this client ran and is durable",
    MsgType.CHECKSUM: "(tick, subscription, differing): the tiles [(x, y)] found differing and asked for again",
    MsgType.PING: "(nonce,) after the client answered with a PONG",
    MsgType.PONG: "(nonce,)",
    "message": "(msg,) every JSON control message, a dict",
}


def heights_grid(values: list[int], w: int, h: int) -> Any:
    """Row-major int32 heights as a NumPy array of shape (h, w) when NumPy is present, else
    as a list of h rows; both index as grid[row][column]."""
    if len(values) != w * h:
        raise ValueError(f"{len(values)} values for a {w} x {h} grid")
    if _np is not None:
        return _np.array(values, dtype=_np.int32).reshape(h, w)
    return [list(values[r * w:(r + 1) * w]) for r in range(h)]


def _websockets():
    try:
        import websockets
    except ImportError as e:
        raise ImportError(
            "terrad.Client needs the Python module 'websockets': pip install websockets, or "
            "your distribution's package (Debian: python3-websockets)", name="websockets") from e
    return websockets


class Client:
    """A terrad client over websockets (asyncio).

    Server errors answering a request raise ServerError from that request; others are kept in
    .errors. A mirror that falls out of step (stale_base, a bad payload) asks the server for a
    resync by itself.

    State kept up to date from the frames: world (the hello answer), mirrors (subscription id ->
    Mirror), contacts (collider id -> the latest Contact), forces (collider id -> the latest
    Force: the soil's push, in worlds of the bekker model), colliders (the latest COLLIDERS
    frame, by id), footprints (every FOOTPRINTS event, in order), tick (of the last DELTA),
    acked_tick and acked_seq (of the last ACK), errors (unsolicited error messages), desync
    (PROTOCOL.md "CHECKSUM": checksum_frames compared, checksum_tick, tiles_differing found,
    tiles_resynced asked for again; a differing tile is repaired by itself).

    Callbacks: `on(kind, callback)` for every kind of frame (CALLBACK_ARGS); a callback may be
    a plain function or a coroutine function, and runs on the client's event loop after the
    state above was updated."""

    def __init__(self, uri: str, token: str = "", name: str = "terrad-python",
                 max_size: int = 1 << 24, world: str = "", say_seen: bool = True,
                 budget: int | None = None, base_snapshots: bool = False,
                 slope_snapshots: bool = False, **connect_kwargs: Any):
        """connect_kwargs go to websockets.connect (for example sock=, max_queue=,
        ping_interval=None for a client that may stop reading for a while). world: the
        world a cluster node should serve this client (docs/cluster.md); "" for a single
        daemon's one world. say_seen: tell the server the tick handled (PROTOCOL.md "seen"),
        so that it bounds this client's lag end to end; False: only its own queue is judged.
        budget: bytes per second the server may send this client (PROTOCOL.md "Budgets":
        near tiles first, far ones later, exact once the terrain settles); None: the
        server's default; world["budget"] says the one in force.
        base_snapshots: ask for snapshots against the scene's base terrain (PROTOCOL.md "Base
        snapshots"; a late joiner's window in a fraction of the bytes), which this client
        rebuilds with the twin library (terrad.twin); the mirrors hold the same heights.
        slope_snapshots: offer slope snapshots too (PROTOCOL.md "Slope snapshots": with base
        snapshots the server sends each piece in the shorter of encodings 2 and 3; about a
        fifth fewer bytes on ground driven over for long); world["snapshot_slope"] says
        whether it agreed (never without base_snapshots)."""
        self.base_snapshots = base_snapshots
        self.slope_snapshots = slope_snapshots
        self.uri, self.token, self.name, self.max_size = uri, token, name, max_size
        self.world_name = world
        self.budget = budget
        self.connect_kwargs = connect_kwargs
        self.ws: Any = None
        self.world: dict[str, Any] = {}
        self.mirrors: dict[int, Mirror] = {}
        self.contacts: dict[int, Contact] = {}
        self.forces: dict[int, Force] = {}
        self.forces_tick = 0
        self.colliders: dict[int, ColliderState] = {}
        self.colliders_tick = 0
        self.footprints: list[Footprint] = []
        self.footprints_tick = 0
        self.contact_tick = 0
        self.acked_tick = 0
        self.acked_seq = 0
        self.spectate_ended: dict[str, Any] | None = None  # the last spectate_end
        self.tick = 0
        self.errors: list[dict[str, Any]] = []
        self.desync = {"checksum_frames": 0, "checksum_tick": 0, "tiles_differing": 0, "tiles_resynced": 0}
        # this client's colliders (id -> (shape, create fields)) and predicting subscriptions
        self.own_colliders: dict[int, tuple[str, dict[str, Any]]] = {}
        self.predictions: dict[int, Prediction] = {}
        self._callbacks: dict[FrameKind, list[Callback]] = {}
        self._seq = 0
        self._ref = 0
        self._pending: dict[str, asyncio.Future[dict[str, Any]]] = {}
        self._step_seq = 0
        self._steps: dict[int, asyncio.Future[int]] = {}  # STEP seq -> its STEPPED tick
        self._reader: asyncio.Task[None] | None = None
        # PROTOCOL.md "seen": the latest tick handled, and what and when the server was told
        self.say_seen = say_seen
        self._handled = self._said = 0
        self._said_at = 0.0
        self._seen_later: asyncio.Task[None] | None = None
        self._changed = asyncio.Event()

    async def __aenter__(self) -> Client:
        await self.connect()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    # ---- callbacks ----------------------------------------------------------------------

    def on(self, kind: FrameKind, callback: Callback) -> Callback:
        """Call callback for every frame of this kind (a MsgType, or "message" for JSON
        control messages), with the arguments CALLBACK_ARGS lists. Returns callback."""
        if kind not in CALLBACK_ARGS:
            raise ValueError(f"no callback for {kind!r}; one of {list(CALLBACK_ARGS)}")
        self._callbacks.setdefault(kind, []).append(callback)
        return callback

    def off(self, kind: FrameKind, callback: Callback) -> None:
        """Remove a callback added with on()."""
        self._callbacks.get(kind, []).remove(callback)

    async def _emit(self, kind: FrameKind, *args: Any) -> None:
        for cb in list(self._callbacks.get(kind, ())):
            r = cb(*args)
            if inspect.isawaitable(r):
                await r

    # ---- connection and requests ------------------------------------------------------------

    async def connect(self) -> dict[str, Any]:
        websockets = _websockets()
        self.ws = await websockets.connect(self.uri, subprotocols=[SUBPROTOCOL],
                                           max_size=self.max_size, **self.connect_kwargs)
        await self.ws.send(json.dumps(hello(self.token, self.name, self.world_name, self.budget,
                                            self.base_snapshots, self.slope_snapshots)))
        msg = parse_control(await self.ws.recv())
        if msg["type"] == "error":
            raise ServerError(msg)
        if msg["type"] != "world":
            raise ProtoError("bad_json", f"expected world, got {msg['type']}")
        self.world = msg
        self._reader = asyncio.get_running_loop().create_task(self._read())
        return msg

    async def close(self) -> None:
        if self._seen_later is not None:
            self._seen_later.cancel()
        if self.ws is not None:
            await self.ws.close()
        if self._reader is not None:
            try:
                await self._reader
            except Exception:
                pass

    async def request(self, msg: dict[str, Any], reply: str, timeout: float = 10.0) -> dict[str, Any]:
        """Send a control message with a fresh ref and wait for its reply."""
        self._ref += 1
        ref = f"r{self._ref}"
        msg["ref"] = ref
        fut: asyncio.Future[dict[str, Any]] = asyncio.get_running_loop().create_future()
        self._pending[ref] = fut
        await self.ws.send(json.dumps(msg))
        try:
            got = await asyncio.wait_for(fut, timeout)
        finally:
            self._pending.pop(ref, None)
        if got["type"] != reply:
            raise ProtoError("bad_json", f"expected {reply}, got {got['type']}")
        return got

    async def create_collider(self, shape: str, material: str = "default", **dims: Any) -> int:
        """shape: sphere (radius), box (half_extents), capsule and cylinder (radius,
        half_length), wheel (radius, width), mesh (vertices, indices); returns its id.
        load_n=N (bekker worlds): load-driven, the server sets the height that carries N
        newtons each tick (forces[id] reports the sinkage and the force).
        grousers={"count": N, "height": m, "thickness": m}: a wheel's lugs."""
        fields = dict(dims, material=material)
        if self.predictions and (material != "default" or "pose" in dims):
            raise ValueError("material / pose: while predicting, a collider has the default "
                             "material and gets its poses from send_poses")
        cid = (await self.request(collider_create(shape, material, **dims), "collider_created"))["id"]
        self.own_colliders[cid] = (shape, fields)
        for pred in self.predictions.values():
            pred.add_collider(cid, shape, fields)
        return cid

    async def delete_collider(self, cid: int) -> None:
        await self.request(collider_delete(cid), "collider_deleted")
        self.own_colliders.pop(cid, None)
        for pred in self.predictions.values():
            pred.remove_collider(cid)

    def predict(self, sid: int, config: dict[str, Any] | None = None,
                library: str | None = None) -> Prediction:
        """Predict subscription sid's heights on the twin library (terrad.predict): this
        client's own colliders press its window at once, and every ACK reconciles it with
        the server. config: the world's parameters under the twin's keys (model, material,
        margin_cells, terrain.*; the world message gives the extent, cell size, units and
        tick rate). Needs the complete snapshot (wait_complete) and libterrad-twin."""
        if sid in self.predictions:
            return self.predictions[sid]
        pred = Prediction(self, sid, config or {}, library)
        self.predictions[sid] = pred
        return pred

    def stop_predicting(self, sid: int) -> None:
        pred = self.predictions.pop(sid, None)
        if pred is not None:
            pred.close()

    async def send_poses(self, poses: list[Pose]) -> int:
        """Send one batch; returns its sequence number (see wait_ack)."""
        seq = (self._seq + 1) & _U32
        frame = encode_pose_batch(seq, poses)  # refuses bad poses before any prediction
        self._seq = seq
        for pred in self.predictions.values():
            pred.on_send(seq, poses)  # the own rut, before the bytes leave
        await self.ws.send(frame)
        return seq

    async def step_send(self, ticks: int = 1, sets: list[list[Pose]] | None = None) -> asyncio.Future[int]:
        """Send a STEP to a client-clocked world (PROTOCOL.md "STEP"): `ticks` ticks; sets
        None or [] holds every collider, [poses] poses them at the first tick, one list per
        tick poses them at every tick. Returns a future of the step's last tick, set by its
        STEPPED (every tick's frames came first) or failed with ServerError naming the field."""
        seq = (self._step_seq + 1) & _U32
        frame = encode_step(seq, ticks, sets or [])
        self._step_seq = seq
        fut: asyncio.Future[int] = asyncio.get_running_loop().create_future()
        self._steps[seq] = fut
        await self.ws.send(frame)
        return fut

    async def step(self, ticks: int = 1, sets: list[list[Pose]] | None = None,
                   timeout: float = 60.0) -> int:
        """step_send, then wait for its STEPPED: returns the step's last tick."""
        fut = await self.step_send(ticks, sets)
        try:
            return await asyncio.wait_for(fut, timeout)
        finally:
            self._steps = {k: f for k, f in self._steps.items() if not f.done()}

    async def edit(self, op: str, **fields: Any) -> dict[str, Any]:
        """A terrain edit (crater, stamp, reset, add, remove; see proto.edit). Returns the
        server's "edited" reply once its tick is committed: the tick it took effect, the
        exact volume_change (height units) and the rectangle it could change; a refusal
        raises ServerError naming the field."""
        return await self.request(edit(op, **fields), "edited")

    async def subscribe(self, x: int, y: int, w: int, h: int, colliders: bool = False,
                        footprints: bool = False, grousers: bool = False) -> int:
        """Subscribe to a region (cells); its snapshot and then its deltas keep mirrors[id]
        exact. colliders / footprints: also COLLIDERS / FOOTPRINTS frames for it; grousers
        (with colliders): their entries carry the wheels' grousers (ColliderState.grousers)."""
        got = await self.request(subscribe(x, y, w, h, colliders=colliders,
                                           footprints=footprints, grousers=grousers),
                                 "subscribed")
        return got["id"]

    async def spectate(self, x: int, y: int, w: int, h: int, from_tick: int, speed: int = 1,
                       step: bool = False, timeout: float = 60.0) -> int:
        """Watch a window from a past tick (PROTOCOL.md "Spectate"): the frames a live
        subscriber got, played at speed (1..8) times the tick rate, or with step=True one
        spectate_step at a time, until the live tick (then spectate_ended holds the server's
        spectate_end; subscribe to go on live). Returns the key of its mirror in mirrors
        (negative: never a subscription's); its acked_tick is the tick the mirror holds. A
        refusal (a tick the log no longer holds, a speed out of range) raises ServerError
        naming the field."""
        self.spectate_ended = None
        got = await self.request(spectate(x, y, w, h, from_tick, speed=speed, step=step),
                                 "spectating", timeout)
        return -int(got["id"])

    async def spectate_step(self, ticks: int = 1) -> None:
        """A stepping spectator: play `ticks` more ticks."""
        await self.ws.send(json.dumps(spectate_step(ticks)))

    async def spectate_stop(self) -> dict[str, Any]:
        """Stop watching: the server's spectate_end (reason "stopped")."""
        return await self.request(spectate_stop(), "spectate_end")

    async def unsubscribe(self, sid: int) -> None:
        await self.request(unsubscribe(sid), "unsubscribed")
        self.mirrors.pop(sid, None)
        self.stop_predicting(sid)

    async def focus(self, x: float | None = None, y: float | None = None) -> None:
        """Where a budgeted client looks (cells): its nearest tiles come every tick, far ones
        later. None: its own colliders again."""
        await self.ws.send(json.dumps(focus(x, y)))

    async def resync(self, sid: int | None = None, tiles: list[tuple[int, int]] | None = None) -> None:
        """Fresh snapshots of subscription sid (None: all); tiles: of only those tiles."""
        await self.ws.send(json.dumps(resync(sid, tiles=tiles)))

    # ---- waiting and reading the state ----------------------------------------------------

    async def wait_for(self, predicate: Callable[[], bool], timeout: float = 10.0) -> None:
        """Wait until predicate() holds, re-checked after every message."""
        async def loop() -> None:
            while not predicate():
                self._changed.clear()
                await self._changed.wait()
        await asyncio.wait_for(loop(), timeout)

    async def wait_ack(self, seq: int, timeout: float = 10.0) -> None:
        """Wait until the server has used pose batch seq (or a later one) in a tick."""
        await self.wait_for(lambda: self.acked_seq >= seq, timeout)

    async def wait_complete(self, sid: int, timeout: float = 10.0) -> None:
        """Wait until every tile of subscription sid is held (its snapshot arrived)."""
        await self.wait_for(lambda: sid in self.mirrors and self.mirrors[sid].complete, timeout)

    def heights(self, sid: int) -> Any:
        """A copy of subscription sid's heights (height units, world["units_per_m"] per metre)
        as of the last DELTA: heights_grid's NumPy array (h, w) or list of rows."""
        m = self.mirrors[sid]
        return heights_grid(m.heights, m.w, m.h)

    # ---- frames -------------------------------------------------------------------------

    async def _read(self) -> None:
        try:
            async for data in self.ws:
                if isinstance(data, str):
                    await self._on_json(data)
                else:
                    await self._on_binary(data)
                    await self._say_seen(frame_tick(data))
                self._changed.set()
        finally:
            for fut in [*self._pending.values(), *self._steps.values()]:
                if not fut.done():
                    fut.set_exception(ConnectionError("connection closed"))
            self._changed.set()

    async def _say_seen(self, tick: int) -> None:
        """Tell the server the latest tick handled (the frame's callbacks have run), at most
        every SEEN_INTERVAL_S: it bounds this client's lag by it, frames waiting in this
        client's own buffers included (PROTOCOL.md "seen")."""
        self._handled = max(self._handled, tick)
        if not self.say_seen or self._handled <= self._said:
            return
        loop = asyncio.get_running_loop()
        wait = self._said_at + SEEN_INTERVAL_S - loop.time()
        if wait <= 0:
            self._said, self._said_at = self._handled, loop.time()
            try:
                await self.ws.send(json.dumps(seen(self._handled)))
            except _websockets().ConnectionClosed:
                # The server closed after this frame; its closing error may still be queued
                # behind it: the reader goes on to read it (and then ends on the close).
                pass
        elif self._seen_later is None:  # the last frames before a pause are said too
            self._seen_later = loop.create_task(self._say_seen_later(wait))

    async def _say_seen_later(self, wait: float) -> None:
        await asyncio.sleep(wait)
        self._seen_later = None
        try:
            await self._say_seen(0)
        except Exception:  # noqa: BLE001 - the connection closed meanwhile: the reader says why
            pass

    async def _on_json(self, text: str) -> None:
        msg = parse_control(text)
        t = msg["type"]
        if t == "subscribed":
            mirror = Mirror(msg["x"], msg["y"], msg["w"], msg["h"], self.world["tile_size"])
            if self.world.get("snapshot_base") and isinstance(self.world.get("base"), dict):
                # its snapshots come less the base: rebuilt here before any of them is read
                from .twin import Twin
                with Twin(self.world["base"], msg["x"], msg["y"], msg["w"], msg["h"]) as base:
                    mirror.base = list(base.read())
            self.mirrors[msg["id"]] = mirror
        elif t == "spectating":  # its mirror: the key spectate returns
            self.mirrors[-int(msg["id"])] = Mirror(msg["x"], msg["y"], msg["w"], msg["h"],
                                                   self.world["tile_size"])
        elif t == "spectate_end":
            self.spectate_ended = msg
        ref = msg.get("ref")
        fut = self._pending.get(ref) if isinstance(ref, str) else None
        step = self._steps.pop(int(ref[5:]), None) if isinstance(ref, str) and ref.startswith("step:") else None
        if t == "error" and step is not None:
            if not step.done():
                step.set_exception(ServerError(msg))
        elif t == "error" and ref == "seen" and msg.get("name") == "unknown_type":
            self.say_seen = False  # a daemon from before "seen": it bounds only its own queue
        elif t == "error":
            if fut and not fut.done():
                fut.set_exception(ServerError(msg))
            else:
                self.errors.append(msg)
                del self.errors[:-100]
        elif fut and not fut.done():
            fut.set_result(msg)
        await self._emit("message", msg)

    async def _on_checksum(self, data: bytes) -> None:
        """PROTOCOL.md "CHECKSUM": every frame before it is applied, so the mirror holds its
        tick; each held tile that differs is forgotten (its deltas skipped) and asked for
        again, at most max_resync_tiles per request (the rest at the next CHECKSUM)."""
        tick, sid, tiles = decode_checksum(data)
        d = self.desync
        d["checksum_frames"] += 1
        d["checksum_tick"] = tick
        m = self.mirrors.get(sid)
        differing = m.tiles_differing(tiles) if m is not None else []
        d["tiles_differing"] += len(differing)
        asked = differing[:int(self.world.get("limits", {}).get("max_resync_tiles", 64))]
        if asked and m is not None:
            for x, y in asked:
                m.forget_tile(x, y)
            await self.resync(sid, tiles=asked)
            d["tiles_resynced"] += len(asked)
        await self._emit(MsgType.CHECKSUM, tick, sid, asked)

    async def _on_binary(self, data: bytes) -> None:
        t = decode_header(data)
        if t == MsgType.DELTA:
            tick, rects = decode_delta(data)
            self.tick = tick
            for sid, m in self.mirrors.items():
                try:
                    m.apply(rects)
                except ProtoError as e:
                    self.errors.append(error(e.code, f"subscription {sid}: {e.message}"))
                    await self.resync(sid)
            await self._emit(t, tick, rects)
        elif t == MsgType.CONTACT:
            self.contact_tick, cs = decode_contact(data)
            self.contacts = {c.id: c for c in cs}
            await self._emit(t, self.contact_tick, cs)
        elif t == MsgType.FORCES:
            self.forces_tick, fs = decode_forces(data)
            self.forces = {f.id: f for f in fs}
            await self._emit(t, self.forces_tick, fs)
        elif t == MsgType.COLLIDERS:
            self.colliders_tick, states = decode_colliders(data)
            self.colliders = {c.id: c for c in states}
            await self._emit(t, self.colliders_tick, states)
        elif t == MsgType.FOOTPRINTS:
            self.footprints_tick, events = decode_footprints(data)
            self.footprints.extend(events)
            await self._emit(t, self.footprints_tick, events)
        elif t == MsgType.ACK:
            self.acked_tick, self.acked_seq = decode_ack(data)
            for sid, pred in self.predictions.items():
                try:
                    pred.on_ack(self.acked_tick, self.acked_seq)  # the mirror is at this tick
                except (TwinError, OSError) as e:  # the connection and the mirror go on
                    self.errors.append(error("internal", f"prediction of {sid}: {e}"))
            await self._emit(t, self.acked_tick, self.acked_seq)
        elif t == MsgType.CHECKSUM:
            await self._on_checksum(data)
        elif t == MsgType.STEPPED:
            tick, seq, ticks = decode_stepped(data)
            fut = self._steps.pop(seq, None)
            if fut is not None and not fut.done():
                fut.set_result(tick)
            await self._emit(t, tick, seq, ticks)
        elif t == MsgType.PING:
            nonce = decode_ping(data)[1]
            await self.ws.send(encode_ping(nonce, pong=True))
            await self._emit(t, nonce)
        elif t == MsgType.PONG:
            await self._emit(t, decode_ping(data)[1])


#: The name the client had before it became a package.
TerradClient = Client
