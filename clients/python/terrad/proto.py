"""terrad wire protocol for Python: the codecs (no network).

The specification is proto/PROTOCOL.md; this module follows it field by field
and is checked against proto/vectors/vectors.json, like the C codec. It is the
one Python copy of the codec: terrad.client builds the asyncio client on it.

Needs the zstandard module (pip install zstandard; Debian: python3-zstandard).

    encode_pose_batch / decode_pose_batch, encode_delta / decode_delta,
    encode_contact / decode_contact, encode_ack / decode_ack,
    encode_ping / decode_ping, encode_colliders / decode_colliders,
    encode_footprints / decode_footprints, encode_forces / decode_forces,
    decode_header, decode (any binary
    frame), rect_diff, rect_pack, rect_unpack, rect_compress, rect_decompress,
    apply_values, Mirror (a client-side copy of one region with tile
    versions), and builders of the JSON control messages.

Every decoder raises ProtoError(code) with the protocol's error name; none
reads past its buffer or trusts a count before checking it against the length.
"""

from __future__ import annotations

import json
import math
import struct
from array import array as _array
from dataclasses import dataclass
from enum import IntEnum
from typing import NamedTuple

try:  # optional: CHECKSUM comparisons of many tiles at once (Mirror.tiles_differing)
    import numpy as _np
except ImportError:
    _np = None

try:
    import zstandard as _zstd
except ImportError as _e:  # pragma: no cover - the package is a declared dependency
    raise ImportError(
        "terrad needs the Python module 'zstandard' (zstd compression of the height deltas): "
        "pip install zstandard, or your distribution's package (Debian: python3-zstandard)",
        name="zstandard") from _e

__all__ = [
    "PROTOCOL_VERSION", "MAGIC", "SUBPROTOCOL", "HEADER_SIZE", "POSE_SIZE", "RECT_FIXED",
    "CONTACT_SIZE", "ACK_SIZE", "PING_SIZE", "COLLIDER_STATE_SIZE", "FOOTPRINT_SIZE", "FORCE_SIZE",
    "FORCES_FLAG_HEIGHT", "COLLIDERS_FLAG_GROUSERS", "COLLIDER_GROUSERS_SIZE", "GROUSERS_MAX",
    "FOOTPRINT_YAW_MAX", "MAX_COUNT", "ZSTD_LEVEL", "ERRORS", "ERROR_CODES", "MsgType", "Encoding",
    "ProtoError", "ServerError", "Pose", "Rect", "Contact", "ColliderState", "Footprint",
    "decode_header", "encode_pose_batch", "decode_pose_batch", "check_rect", "encode_delta",
    "decode_delta", "encode_contact", "decode_contact", "encode_colliders", "decode_colliders",
    "encode_footprints", "decode_footprints", "Force", "encode_forces", "decode_forces", "encode_ack", "decode_ack", "encode_ping",
    "decode_ping", "decode", "wrap32", "zigzag32", "unzigzag32", "rect_diff", "rect_pack",
    "rect_unpack", "rect_compress", "rect_decompress", "rect_decompress_base",
    "rect_decompress_slope", "apply_values", "Mirror", "hello",
    "collider_create", "collider_delete", "subscribe", "unsubscribe", "resync", "focus", "error",
    "edit", "stamp_data", "parse_control", "subscribe_events", "STEP_FIXED", "STEPPED_SIZE",
    "encode_step", "decode_step", "encode_stepped", "decode_stepped", "seen", "frame_tick",
    "CHECKSUM_FIXED", "TILE_SUM_SIZE", "HASH_SEED", "HASH_PRIME", "TileSum", "heights_hash",
    "encode_checksum", "decode_checksum", "spectate", "spectate_step", "spectate_stop",
]

PROTOCOL_VERSION = 1
MAGIC = 0x54
SUBPROTOCOL = "terrad.v1"
HEADER_SIZE = 4
POSE_SIZE = 32
RECT_FIXED = 25
CONTACT_SIZE = 48
ACK_SIZE = 16
PING_SIZE = 12
COLLIDER_STATE_SIZE = 48
FOOTPRINT_SIZE = 24
FORCE_SIZE = 48
FORCES_FLAG_HEIGHT = 0x01  # FORCES header flag: an f64 height after each entry (opt-in)
COLLIDERS_FLAG_GROUSERS = 0x01  # COLLIDERS header flag: each entry's grousers after it (opt-in)
COLLIDER_GROUSERS_SIZE = 12  # u16 count, u16 reserved, f32 height, f32 thickness
GROUSERS_MAX = 360
FOOTPRINT_YAW_MAX = 3.1415998935699463  # pi rounded up to float32
MAX_COUNT = 65535
ZSTD_LEVEL = 3


class MsgType(IntEnum):
    POSE_BATCH = 0x01
    PING = 0x02
    PONG = 0x03
    STEP = 0x04
    DELTA = 0x10
    CONTACT = 0x11
    ACK = 0x12
    COLLIDERS = 0x13
    FOOTPRINTS = 0x14
    FORCES = 0x15
    STEPPED = 0x16
    CHECKSUM = 0x17


class Encoding(IntEnum):
    DELTA = 0
    SNAPSHOT = 1
    BASE = 2  # a snapshot less the scene's base (PROTOCOL.md "Base snapshots"): asked for in hello
    BASE_SLOPE = 3  # the same, slope-bounded coding (PROTOCOL.md "Slope snapshots"): offered in hello


ERRORS = {
    1: "bad_frame",
    2: "unknown_type",
    3: "bad_version",
    4: "too_large",
    5: "bad_value",
    6: "unknown_collider",
    7: "not_owner",
    8: "limit_colliders",
    9: "limit_subscriptions",
    10: "rate_limited",
    11: "outside_world",
    12: "bad_json",
    13: "unauthorized",
    14: "refused_height_limit",
    15: "store_unavailable",
    16: "bad_compression",
    17: "stale_base",
    18: "unsupported_collider",
    19: "unknown_subscription",
    20: "shutting_down",
    21: "internal",
    22: "forbidden",
}
ERROR_CODES = {name: code for code, name in ERRORS.items()}


class ProtoError(Exception):
    """A protocol error: .code (int) and .name (e.g. "bad_frame")."""

    def __init__(self, code: int | str, message: str = ""):
        if isinstance(code, str):
            code = ERROR_CODES[code]
        self.code = code
        self.name = ERRORS.get(code, "unknown")
        self.message = message
        super().__init__(f"{self.name}: {message}" if message else self.name)


class ServerError(ProtoError):
    """An error message the server sent: also .ref, the request it answers."""

    def __init__(self, msg: dict):
        super().__init__(int(msg.get("code", 21)), str(msg.get("message", "")))
        self.ref = msg.get("ref")
        self.msg = msg


@dataclass
class Pose:
    id: int
    x: float
    y: float
    z: float
    qw: float = 1.0
    qx: float = 0.0
    qy: float = 0.0
    qz: float = 0.0


@dataclass
class Rect:
    x: int
    y: int
    w: int
    h: int
    base_version: int
    new_version: int
    encoding: int
    data: bytes


@dataclass
class Contact:
    id: int
    volume: int
    cells: int
    area_m2: float
    deepest: tuple
    normal: tuple
    support_height_m: float


@dataclass
class ColliderState:
    """One COLLIDERS entry: owner 0 own / 1 other / 2 demo; kind 0 sphere, 1 box,
    2 capsule, 3 cylinder, 4 mesh bounds; dims, p (x, y, z), q (qw, qx, qy, qz).
    grousers: a wheel's lugs from the grousers extension (a subscription with
    grousers=True), {"count": N, "height": m, "thickness": m} as float32 values, lug 0
    along the entry's -z turned with q; None for none, or in a frame without it."""
    id: int
    owner: int
    kind: int
    dims: tuple
    p: tuple
    q: tuple
    grousers: dict | None = None


@dataclass
class Footprint:
    """One FOOTPRINTS event of the decals model: collider id, centre x, y (m),
    yaw (rad, within +-FOOTPRINT_YAW_MAX), size (m, > 0), strength (m, > 0)."""
    collider: int
    x: float
    y: float
    yaw: float
    size_m: float
    strength_m: float


@dataclass
class Force:
    """One FORCES entry (worlds of the bekker model): the soil's push on a collider in one
    tick. force (N) and torque (N m, about the collider's pose position) as (x, y, z) in the
    world frame; sinkage_m, area_m2, patch_width_m (>= 0); slip (wheels; 0 otherwise);
    cells in contact. height_m: the collider's pose height (m) the tick deformed at — a
    load-driven collider's, the height the server found — when the frame carries heights
    (the collider was created with forces_height=True: PROTOCOL.md "FORCES"); None otherwise."""
    id: int
    force: tuple
    torque: tuple
    sinkage_m: float
    area_m2: float
    patch_width_m: float
    slip: float
    cells: int
    height_m: float | None = None


# ---- helpers -----------------------------------------------------------------

_U32 = 0xFFFFFFFF


def _f32(v) -> float:
    """Round to float32; NaN/Inf or out of float32 range is bad_value."""
    try:
        r = struct.unpack("<f", struct.pack("<f", v))[0]
    except (OverflowError, struct.error, TypeError) as e:
        raise ProtoError("bad_value", f"not a float32: {v!r}") from e
    if not math.isfinite(r):
        raise ProtoError("bad_value", f"not finite: {v!r}")
    return r


def _header(t: int) -> bytes:
    return bytes((MAGIC, PROTOCOL_VERSION, t, 0))


def decode_header(buf: bytes) -> MsgType:
    """Checks length, magic, version, type and flags, in that order."""
    if len(buf) < HEADER_SIZE:
        raise ProtoError("bad_frame", "shorter than the header")
    if buf[0] != MAGIC:
        raise ProtoError("bad_frame", f"magic 0x{buf[0]:02x}")
    if buf[1] != PROTOCOL_VERSION:
        raise ProtoError("bad_version", f"protocol version {buf[1]}, this codec speaks {PROTOCOL_VERSION}")
    try:
        t = MsgType(buf[2])
    except ValueError:
        raise ProtoError("unknown_type", f"type 0x{buf[2]:02x}") from None
    # the flags defined, each an extension a client asks for: FORCES' heights, COLLIDERS' grousers
    defined = {MsgType.FORCES: FORCES_FLAG_HEIGHT, MsgType.COLLIDERS: COLLIDERS_FLAG_GROUSERS}
    if buf[3] & ~defined.get(t, 0):
        raise ProtoError("bad_frame", "reserved flags set")
    return t


def _expect(buf: bytes, t: MsgType) -> None:
    got = decode_header(buf)
    if got != t:
        raise ProtoError("unknown_type", f"{got.name} where {t.name} was expected")


def _check_quaternion(qw, qx, qy, qz) -> None:
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    if n2 < 0.81 or n2 > 1.21:
        raise ProtoError("bad_value", f"|q|^2 = {n2} outside [0.81, 1.21]")


# ---- POSE_BATCH ----------------------------------------------------------------

_POSE = struct.Struct("<I7f")


def _pack_pose(p: Pose) -> bytes:
    """One pose entry (POSE_BATCH, STEP): float32 values (_f32 refuses what is not finite),
    a unit quaternion."""
    v = [_f32(a) for a in (p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz)]
    _check_quaternion(*v[3:])
    return _POSE.pack(p.id, *v)


def _unpack_pose(buf: bytes, pos: int) -> Pose:
    pid, *v = _POSE.unpack_from(buf, pos)
    if not all(math.isfinite(a) for a in v):
        raise ProtoError("bad_value", f"pose of collider {pid} is not finite")
    _check_quaternion(*v[3:])
    return Pose(pid, *v)


def encode_pose_batch(seq: int, poses: list[Pose]) -> bytes:
    return _encode_list(MsgType.POSE_BATCH, "<IH", seq & _U32, poses, "poses", _pack_pose)


def decode_pose_batch(buf: bytes, max_poses: int = MAX_COUNT) -> tuple[int, list[Pose]]:
    _expect(buf, MsgType.POSE_BATCH)
    if len(buf) < 10:
        raise ProtoError("bad_frame", "truncated")
    seq, count = struct.unpack_from("<IH", buf, 4)
    if len(buf) - 10 != count * POSE_SIZE:
        raise ProtoError("bad_frame", f"count {count} does not match {len(buf) - 10} bytes of poses")
    if count > max_poses:
        raise ProtoError("too_large", f"{count} poses, at most {max_poses}")
    return seq, [_unpack_pose(buf, 10 + i * POSE_SIZE) for i in range(count)]


# ---- STEP and STEPPED (client-clocked worlds) ---------------------------------------

STEP_FIXED = 16
STEPPED_SIZE = 20


def encode_step(seq: int, ticks: int, sets: list[list[Pose]]) -> bytes:
    """A STEP: `ticks` ticks; sets [] holds every collider, one set poses them at the first
    tick (held after), `ticks` sets pose them at every tick. Every set has the same count."""
    count = len(sets[0]) if sets else 0
    if ticks < 1 or (len(sets) > 1 and len(sets) != ticks):
        raise ProtoError("bad_value", f"ticks {ticks} with {len(sets)} sets (0, 1 or ticks)")
    if any(len(s) != count for s in sets) or count > MAX_COUNT or len(sets) > MAX_COUNT:
        raise ProtoError("bad_value", "every set must have the same count (<= 65535)")
    out = [_header(MsgType.STEP), struct.pack("<IIHH", seq & _U32, ticks, count, len(sets))]
    return b"".join(out + [_pack_pose(p) for s in sets for p in s])


def decode_step(buf: bytes, max_poses: int = MAX_COUNT * 64) -> tuple[int, int, list[list[Pose]]]:
    """(seq, ticks, sets)."""
    _expect(buf, MsgType.STEP)
    if len(buf) < STEP_FIXED:
        raise ProtoError("bad_frame", "truncated")
    seq, ticks, count, nsets = struct.unpack_from("<IIHH", buf, 4)
    if len(buf) - STEP_FIXED != count * nsets * POSE_SIZE:
        raise ProtoError("bad_frame", f"{nsets} sets of {count} do not match the frame")
    if ticks == 0 or (nsets > 1 and nsets != ticks):
        raise ProtoError("bad_value", f"ticks {ticks} with {nsets} sets")
    if count * nsets > max_poses:
        raise ProtoError("too_large", f"{count * nsets} poses")
    sets = [[_unpack_pose(buf, STEP_FIXED + (k * count + i) * POSE_SIZE) for i in range(count)]
            for k in range(nsets)]
    return seq, ticks, sets


def encode_stepped(tick: int, seq: int, ticks: int) -> bytes:
    if ticks < 1:
        raise ProtoError("bad_value", "ticks 0")
    return _header(MsgType.STEPPED) + struct.pack("<QII", tick, seq, ticks)


def decode_stepped(buf: bytes) -> tuple[int, int, int]:
    """(tick, seq, ticks): step seq's ticks ran, the last being tick, and are durable."""
    _expect(buf, MsgType.STEPPED)
    if len(buf) != STEPPED_SIZE:
        raise ProtoError("bad_frame", f"STEPPED of {len(buf)} bytes")
    tick, seq, ticks = struct.unpack_from("<QII", buf, 4)
    if ticks == 0:
        raise ProtoError("bad_value", "STEPPED of 0 ticks")
    return tick, seq, ticks


# ---- CHECKSUM (desync detection) -----------------------------------------------------

CHECKSUM_FIXED = 18
TILE_SUM_SIZE = 20
HASH_SEED = 0xCBF29CE484222325
HASH_PRIME = 0x100000001B3
_U64 = (1 << 64) - 1
_TILE_SUM = struct.Struct("<iiIQ")


class TileSum(NamedTuple):
    tile_x: int
    tile_y: int
    version: int
    hash: int


def heights_hash(heights, stride: int, w: int, h: int, start: int = 0) -> int:
    """PROTOCOL.md "Tile hash": FNV-1a 64 over the heights as u32 words, row-major, of the
    w x h heights at heights[start + j * stride + i]."""
    x = HASH_SEED
    for j in range(h):
        o = start + j * stride
        for v in heights[o:o + w]:
            x = ((x ^ (v & _U32)) * HASH_PRIME) & _U64
    return x


def encode_checksum(tick: int, subscription: int, tiles: list[TileSum]) -> bytes:
    if subscription <= 0 or len(tiles) > MAX_COUNT:
        raise ProtoError("bad_value", "subscription 0 or too many tiles")
    out = [_header(MsgType.CHECKSUM), struct.pack("<QIH", tick, subscription, len(tiles))]
    for t in tiles:
        if t.tile_x < 0 or t.tile_y < 0 or t.version == 0:
            raise ProtoError("bad_value", f"tile ({t.tile_x}, {t.tile_y}) of version {t.version}")
        out.append(_TILE_SUM.pack(t.tile_x, t.tile_y, t.version, t.hash))
    return b"".join(out)


def decode_checksum(buf: bytes) -> tuple[int, int, list[TileSum]]:
    """(tick, subscription, tiles): each tile's version and heights hash at tick."""
    _expect(buf, MsgType.CHECKSUM)
    if len(buf) < CHECKSUM_FIXED:
        raise ProtoError("bad_frame", "truncated")
    tick, sub, count = struct.unpack_from("<QIH", buf, 4)
    if len(buf) - CHECKSUM_FIXED != count * TILE_SUM_SIZE:
        raise ProtoError("bad_frame", f"count {count} does not match the frame")
    if sub == 0:
        raise ProtoError("bad_value", "subscription 0")
    tiles = [TileSum(*_TILE_SUM.unpack_from(buf, CHECKSUM_FIXED + i * TILE_SUM_SIZE))
             for i in range(count)]
    for t in tiles:
        if t.tile_x < 0 or t.tile_y < 0 or t.version == 0:
            raise ProtoError("bad_value", f"tile ({t.tile_x}, {t.tile_y}) of version {t.version}")
    return tick, sub, tiles


# ---- DELTA -----------------------------------------------------------------------

_RECT = struct.Struct("<iiHHIIBI")


def check_rect(r: Rect) -> None:
    """Field checks of one rectangle; raises bad_value."""
    if not (1 <= r.w <= 0xFFFF and 1 <= r.h <= 0xFFFF):
        raise ProtoError("bad_value", f"size {r.w} x {r.h}")
    if not (-(2**31) <= r.x and r.x + r.w - 1 <= 2**31 - 1 and -(2**31) <= r.y and r.y + r.h - 1 <= 2**31 - 1):
        raise ProtoError("bad_value", "rectangle past the int32 range")
    if not (0 < r.new_version <= _U32 and 0 <= r.base_version <= _U32):
        raise ProtoError("bad_value", "version out of range")
    if r.encoding == Encoding.DELTA:
        if r.base_version == 0 or r.base_version == r.new_version:
            raise ProtoError("bad_value", "a delta needs base_version >= 1 and != new_version")
    elif r.encoding in (Encoding.SNAPSHOT, Encoding.BASE, Encoding.BASE_SLOPE):
        if r.base_version != 0:
            raise ProtoError("bad_value", "a snapshot has base_version 0")
    else:
        raise ProtoError("bad_value", f"encoding {r.encoding}")
    if len(r.data) == 0:
        raise ProtoError("bad_value", "empty payload")


def encode_delta(tick: int, rects: list[Rect]) -> bytes:
    if len(rects) > MAX_COUNT:
        raise ProtoError("too_large", f"{len(rects)} rectangles")
    out = [_header(MsgType.DELTA), struct.pack("<QH", tick, len(rects))]
    for r in rects:
        check_rect(r)
        out.append(_RECT.pack(r.x, r.y, r.w, r.h, r.base_version, r.new_version, r.encoding, len(r.data)))
        out.append(bytes(r.data))
    return b"".join(out)


def decode_delta(buf: bytes, max_rects: int = MAX_COUNT) -> tuple[int, list[Rect]]:
    """Validates the whole frame; rectangle payloads stay compressed."""
    _expect(buf, MsgType.DELTA)
    if len(buf) < 14:
        raise ProtoError("bad_frame", "truncated")
    tick, count = struct.unpack_from("<QH", buf, 4)
    if (len(buf) - 14) // RECT_FIXED < count:
        raise ProtoError("bad_frame", f"count {count} larger than the frame")
    if count > max_rects:
        raise ProtoError("too_large", f"{count} rectangles, at most {max_rects}")
    pos = 14
    rects = []
    mv = memoryview(buf)
    for _ in range(count):
        if len(buf) - pos < RECT_FIXED:
            raise ProtoError("bad_frame", "rectangle header truncated")
        x, y, w, h, base, new, enc, n = _RECT.unpack_from(buf, pos)
        pos += RECT_FIXED
        if len(buf) - pos < n:
            raise ProtoError("bad_frame", "payload past the end of the frame")
        r = Rect(x, y, w, h, base, new, enc, bytes(mv[pos:pos + n]))
        pos += n
        check_rect(r)
        rects.append(r)
    if pos != len(buf):
        raise ProtoError("bad_frame", f"{len(buf) - pos} bytes after the last rectangle")
    return tick, rects


# ---- tick lists: CONTACT, COLLIDERS, FOOTPRINTS, FORCES ----------------------------------
# One outline: the header, the tick (u64), a count (u16), then count entries of one fixed
# size; each frame gives its entry's packer and unpacker (each checks its entry). POSE_BATCH
# is the same outline with a seq (u32) for the tick (_encode_list's head).


def _encode_list(t: MsgType, head: str, first: int, entries: list, what: str, pack) -> bytes:
    if len(entries) > MAX_COUNT:
        raise ProtoError("too_large", f"{len(entries)} {what}")
    return b"".join([_header(t), struct.pack(head, first, len(entries))] +
                    [pack(e) for e in entries])


def _encode_tick_list(t: MsgType, tick: int, entries: list, what: str, pack) -> bytes:
    return _encode_list(t, "<QH", tick, entries, what, pack)


def _decode_tick_list(buf: bytes, t: MsgType, size: int, cap: int, what: str,
                      unpack) -> tuple[int, list]:
    _expect(buf, t)
    if len(buf) < 14:
        raise ProtoError("bad_frame", "truncated")
    tick, count = struct.unpack_from("<QH", buf, 4)
    if len(buf) - 14 != count * size:
        raise ProtoError("bad_frame", f"count {count} does not match {len(buf) - 14} bytes")
    if count > cap:
        raise ProtoError("too_large", f"{count} {what}")
    return tick, [unpack(buf, 14 + i * size) for i in range(count)]


# CONTACT

_CONTACT = struct.Struct("<IqI8f")


def _pack_contact(c: Contact) -> bytes:
    f = [_f32(a) for a in (c.area_m2, *c.deepest, *c.normal, c.support_height_m)]
    if c.volume < 0 or f[0] < 0:
        raise ProtoError("bad_value", "negative volume or area")
    return _CONTACT.pack(c.id, c.volume, c.cells, *f)


def _unpack_contact(buf: bytes, pos: int) -> Contact:
    cid, vol, cells, *f = _CONTACT.unpack_from(buf, pos)
    if not all(math.isfinite(a) for a in f):
        raise ProtoError("bad_value", f"contact of collider {cid} is not finite")
    if vol < 0 or f[0] < 0:
        raise ProtoError("bad_value", "negative volume or area")
    return Contact(cid, vol, cells, f[0], tuple(f[1:4]), tuple(f[4:7]), f[7])


def encode_contact(tick: int, contacts: list[Contact]) -> bytes:
    return _encode_tick_list(MsgType.CONTACT, tick, contacts, "contacts", _pack_contact)


def decode_contact(buf: bytes, max_contacts: int = MAX_COUNT) -> tuple[int, list[Contact]]:
    return _decode_tick_list(buf, MsgType.CONTACT, CONTACT_SIZE, max_contacts, "contacts",
                             _unpack_contact)


# COLLIDERS

_COLLIDER_STATE = struct.Struct("<IBBH10f")


def _check_collider_state(cid, owner, kind, f) -> None:
    if owner > 2:
        raise ProtoError("bad_value", f"collider {cid}: owner {owner}")
    if kind > 4:
        raise ProtoError("bad_value", f"collider {cid}: kind {kind}")
    if not all(math.isfinite(a) for a in f):
        raise ProtoError("bad_value", f"collider {cid} is not finite")
    if min(f[0:3]) < 0:
        raise ProtoError("bad_value", f"collider {cid}: negative dimension")
    _check_quaternion(*f[6:10])


def _pack_collider_state(c: ColliderState) -> bytes:
    f = [_f32(a) for a in (*c.dims, *c.p, *c.q)]
    _check_collider_state(c.id, c.owner, c.kind, f)
    return _COLLIDER_STATE.pack(c.id, c.owner, c.kind, 0, *f)


def _unpack_collider_state(buf: bytes, pos: int) -> ColliderState:
    cid, owner, kind, reserved, *f = _COLLIDER_STATE.unpack_from(buf, pos)
    if reserved != 0:
        raise ProtoError("bad_value", f"collider {cid}: reserved bytes set")
    _check_collider_state(cid, owner, kind, f)
    return ColliderState(cid, owner, kind, tuple(f[0:3]), tuple(f[3:6]), tuple(f[6:10]))


_GROUSERS = struct.Struct("<HHff")


def _check_grousers(c: ColliderState, count: int, height: float, thickness: float) -> None:
    if count == 0:
        if height != 0 or thickness != 0:
            raise ProtoError("bad_value", f"collider {c.id}: no grousers but a height or thickness")
        return
    if count > GROUSERS_MAX or c.kind != 3:
        raise ProtoError("bad_value", f"collider {c.id}: {count} grousers on kind {c.kind} "
                         f"(1..{GROUSERS_MAX}, on a cylinder only)")
    if not (0 < height <= c.dims[0] and 0 < thickness <= c.dims[0]):
        raise ProtoError("bad_value", f"collider {c.id}: grousers {height} m tall, {thickness} m "
                         f"thick (each > 0 and <= the radius {c.dims[0]})")


def _pack_collider_grousers(c: ColliderState) -> bytes:
    g = c.grousers or {"count": 0, "height": 0.0, "thickness": 0.0}
    count, height, thickness = int(g["count"]), _f32(g["height"]), _f32(g["thickness"])
    _check_grousers(c, count, height, thickness)
    return _pack_collider_state(c) + _GROUSERS.pack(count, 0, height, thickness)


def _unpack_collider_grousers(buf: bytes, pos: int) -> ColliderState:
    c = _unpack_collider_state(buf, pos)
    count, reserved, height, thickness = _GROUSERS.unpack_from(buf, pos + COLLIDER_STATE_SIZE)
    if reserved != 0:
        raise ProtoError("bad_value", f"collider {c.id}: the grousers' reserved bytes set")
    _check_grousers(c, count, height, thickness)
    if count:
        c.grousers = {"count": count, "height": height, "thickness": thickness}
    return c


def encode_colliders(tick: int, states: list[ColliderState], grousers: bool = False) -> bytes:
    """grousers: the extension (header flag COLLIDERS_FLAG_GROUSERS, each entry's grousers
    after it, none where an entry's grousers is None)."""
    if not grousers:
        return _encode_tick_list(MsgType.COLLIDERS, tick, states, "colliders",
                                 _pack_collider_state)
    out = _encode_tick_list(MsgType.COLLIDERS, tick, states, "colliders", _pack_collider_grousers)
    return out[:3] + bytes([COLLIDERS_FLAG_GROUSERS]) + out[4:]


def decode_colliders(buf: bytes, max_colliders: int = MAX_COUNT) -> tuple[int, list[ColliderState]]:
    """Both forms: with the header flag COLLIDERS_FLAG_GROUSERS a lugged wheel's entry has its
    grousers."""
    if len(buf) >= HEADER_SIZE and buf[3] & COLLIDERS_FLAG_GROUSERS:
        return _decode_tick_list(buf, MsgType.COLLIDERS, COLLIDER_STATE_SIZE + COLLIDER_GROUSERS_SIZE,
                                 max_colliders, "colliders", _unpack_collider_grousers)
    return _decode_tick_list(buf, MsgType.COLLIDERS, COLLIDER_STATE_SIZE, max_colliders,
                             "colliders", _unpack_collider_state)


# FOOTPRINTS

_FOOTPRINT = struct.Struct("<I5f")


def _check_footprint(cid, f) -> None:
    if not all(math.isfinite(a) for a in f):
        raise ProtoError("bad_value", f"footprint of collider {cid} is not finite")
    if abs(f[2]) > FOOTPRINT_YAW_MAX:
        raise ProtoError("bad_value", f"footprint of collider {cid}: yaw {f[2]} outside [-pi, pi]")
    if not (f[3] > 0 and f[4] > 0):
        raise ProtoError("bad_value", f"footprint of collider {cid}: size and strength must be > 0")


def _pack_footprint(e: Footprint) -> bytes:
    f = [_f32(a) for a in (e.x, e.y, e.yaw, e.size_m, e.strength_m)]
    _check_footprint(e.collider, f)
    return _FOOTPRINT.pack(e.collider, *f)


def _unpack_footprint(buf: bytes, pos: int) -> Footprint:
    cid, *f = _FOOTPRINT.unpack_from(buf, pos)
    _check_footprint(cid, f)
    return Footprint(cid, *f)


def encode_footprints(tick: int, events: list[Footprint]) -> bytes:
    return _encode_tick_list(MsgType.FOOTPRINTS, tick, events, "footprints", _pack_footprint)


def decode_footprints(buf: bytes, max_events: int = MAX_COUNT) -> tuple[int, list[Footprint]]:
    return _decode_tick_list(buf, MsgType.FOOTPRINTS, FOOTPRINT_SIZE, max_events, "footprints",
                             _unpack_footprint)


# FORCES

_FORCE = struct.Struct("<I10fI")


def _check_force(cid, f) -> None:
    if not all(math.isfinite(a) for a in f):
        raise ProtoError("bad_value", f"forces of collider {cid} are not finite")
    if f[6] < 0 or f[7] < 0 or f[8] < 0:
        raise ProtoError("bad_value", f"forces of collider {cid}: sinkage, area and patch "
                         "width must be >= 0")


def _pack_force(e: Force) -> bytes:
    f = [_f32(a) for a in (*e.force, *e.torque, e.sinkage_m, e.area_m2, e.patch_width_m, e.slip)]
    _check_force(e.id, f)
    return _FORCE.pack(e.id, *f, e.cells)


def _unpack_force(buf: bytes, pos: int) -> Force:
    cid, *f, cells = _FORCE.unpack_from(buf, pos)
    _check_force(cid, f)
    return Force(cid, tuple(f[0:3]), tuple(f[3:6]), *f[6:10], cells)


_HEIGHT = struct.Struct("<d")


def _pack_force_height(e: Force) -> bytes:
    if e.height_m is None or not math.isfinite(e.height_m):
        raise ProtoError("bad_value", f"forces of collider {e.id}: height_m must be a finite "
                         "number in a frame with heights")
    return _pack_force(e) + _HEIGHT.pack(e.height_m)


def _unpack_force_height(buf: bytes, pos: int) -> Force:
    f = _unpack_force(buf, pos)
    (f.height_m,) = _HEIGHT.unpack_from(buf, pos + FORCE_SIZE)
    if not math.isfinite(f.height_m):
        raise ProtoError("bad_value", f"forces of collider {f.id}: height is not finite")
    return f


def encode_forces(tick: int, forces: list[Force], heights: bool = False) -> bytes:
    """heights: the extension (header flag FORCES_FLAG_HEIGHT, an f64 height after each
    entry); every entry's height_m must then be set."""
    if not heights:
        return _encode_tick_list(MsgType.FORCES, tick, forces, "forces", _pack_force)
    out = _encode_tick_list(MsgType.FORCES, tick, forces, "forces", _pack_force_height)
    return out[:3] + bytes([FORCES_FLAG_HEIGHT]) + out[4:]


def decode_forces(buf: bytes, max_forces: int = MAX_COUNT) -> tuple[int, list[Force]]:
    """Both forms: with the header flag FORCES_FLAG_HEIGHT each Force has its height_m."""
    if len(buf) >= HEADER_SIZE and buf[3] & FORCES_FLAG_HEIGHT:
        return _decode_tick_list(buf, MsgType.FORCES, FORCE_SIZE + 8, max_forces, "forces",
                                 _unpack_force_height)
    return _decode_tick_list(buf, MsgType.FORCES, FORCE_SIZE, max_forces, "forces",
                             _unpack_force)


# ---- ACK, PING, PONG -------------------------------------------------------------------


def encode_ack(tick: int, seq: int) -> bytes:
    return _header(MsgType.ACK) + struct.pack("<QI", tick, seq)


def decode_ack(buf: bytes) -> tuple[int, int]:
    _expect(buf, MsgType.ACK)
    if len(buf) != ACK_SIZE:
        raise ProtoError("bad_frame", f"ACK of {len(buf)} bytes")
    tick, seq = struct.unpack_from("<QI", buf, 4)
    return tick, seq


def encode_ping(nonce: int, pong: bool = False) -> bytes:
    return _header(MsgType.PONG if pong else MsgType.PING) + struct.pack("<Q", nonce)


def decode_ping(buf: bytes) -> tuple[MsgType, int]:
    t = decode_header(buf)
    if t not in (MsgType.PING, MsgType.PONG):
        raise ProtoError("unknown_type", f"{t.name} where PING or PONG was expected")
    if len(buf) != PING_SIZE:
        raise ProtoError("bad_frame", f"{t.name} of {len(buf)} bytes")
    return t, struct.unpack_from("<Q", buf, 4)[0]


# Each binary frame's decoder, by its type (PING and PONG: decode_ping, below).
_DECODERS = {
    MsgType.POSE_BATCH: decode_pose_batch, MsgType.DELTA: decode_delta,
    MsgType.CONTACT: decode_contact, MsgType.ACK: decode_ack, MsgType.COLLIDERS: decode_colliders,
    MsgType.FOOTPRINTS: decode_footprints, MsgType.FORCES: decode_forces,
    MsgType.STEP: decode_step, MsgType.STEPPED: decode_stepped, MsgType.CHECKSUM: decode_checksum,
}


def decode(buf: bytes):
    """Any binary frame: (MsgType, decoded tuple); a PING or PONG's nonce."""
    t = decode_header(buf)
    if t in _DECODERS:
        return t, _DECODERS[t](buf)
    return t, decode_ping(buf)[1]


# ---- rectangle payloads ------------------------------------------------------------------


def wrap32(v: int) -> int:
    """v modulo 2^32 as a signed int32 (the deltas' wrapping arithmetic)."""
    return ((v + 2**31) & _U32) - 2**31


_wrap = wrap32


def zigzag32(v: int) -> int:
    return ((v << 1) ^ (v >> 31)) & _U32


def unzigzag32(u: int) -> int:
    return (u >> 1) ^ -(u & 1)


def rect_diff(old: list[int], new: list[int]) -> list[int]:
    """new - old per cell, wrapping modulo 2^32 (exact for any int32 pair)."""
    return [_wrap(n - o) for o, n in zip(old, new)]


def rect_pack(values: list[int]) -> bytes:
    return struct.pack(f"<{len(values)}I", *[((v << 1) ^ (v >> 31)) & _U32 for v in values])


def rect_unpack(data: bytes) -> list[int]:
    n = len(data) // 4
    return [(u >> 1) ^ -(u & 1) for u in struct.unpack(f"<{n}I", data[:4 * n])]


def rect_compress(values: list[int], level: int = ZSTD_LEVEL) -> bytes:
    """Pack and compress as one zstd frame with its content size."""
    return _zstd.ZstdCompressor(level=level, write_content_size=True).compress(rect_pack(values))


def rect_decompress(data: bytes, cells: int, max_cells: int | None = None) -> list[int]:
    """Exactly one zstd frame declaring and holding 4 * cells bytes, else
    bad_compression; more than max_cells cells is too_large."""
    if cells <= 0 or (max_cells is not None and cells > max_cells):
        raise ProtoError("too_large", f"{cells} cells")
    raw = cells * 4
    try:
        declared = _zstd.frame_content_size(data)
    except _zstd.ZstdError as e:
        raise ProtoError("bad_compression", str(e)) from None
    if declared != raw:
        raise ProtoError("bad_compression", f"frame declares {declared} bytes, the rectangle needs {raw}")
    d = _zstd.ZstdDecompressor().decompressobj()
    try:
        out = d.decompress(data)
    except _zstd.ZstdError as e:
        raise ProtoError("bad_compression", str(e)) from None
    if not d.eof or d.unused_data or len(out) != raw:
        raise ProtoError("bad_compression", "not exactly one complete zstd frame of the declared size")
    return rect_unpack(out)


def _range_decoder(data: bytes, start: int):
    """LZMA's binary range decoder over data[start:] (PROTOCOL.md "Base snapshots", step 5):
    (bit(probs, i), direct(), residual(unary, mant, c) -> u or None, short() -> ran past the end)."""
    n_in = len(data)
    state = [0xFFFFFFFF, 0, start, False]  # range, code, position, ran short

    def byte() -> int:
        at = state[2]
        if at < n_in:
            state[2] = at + 1
            return data[at]
        state[3] = True
        return 0

    for _ in range(5):
        state[1] = ((state[1] << 8) | byte()) & _U32

    def bit(probs: list[int], i: int) -> int:
        rng, code, p = state[0], state[1], probs[i]
        bound = (rng >> 11) * p
        if code < bound:
            rng = bound
            probs[i] = p + ((2048 - p) >> 4)
            b = 0
        else:
            code -= bound
            rng -= bound
            probs[i] = p - (p >> 4)
            b = 1
        while rng < (1 << 24):
            rng = (rng << 8) & _U32
            code = ((code << 8) | byte()) & _U32
        state[0], state[1] = rng, code
        return b

    def direct() -> int:
        rng = state[0] >> 1
        code = state[1]
        b = 1 if code >= rng else 0
        if b:
            code -= rng
        while rng < (1 << 24):
            rng = (rng << 8) & _U32
            code = ((code << 8) | byte()) & _U32
        state[0], state[1] = rng, code
        return b

    def residual(unary: list[list[int]], mant: list[list[list[int]]], c: int) -> int | None:
        """A zigzagged residual in context c (Elias-gamma form, step 4); None past 2^32 - 1
        or past the payload's end."""
        n = 0
        uc = unary[c]
        while n < 32 and bit(uc, n):
            n += 1
        v = 1
        mc = mant[c][n]
        for k in range(n - 1, -1, -1):
            v = (v << 1) | (bit(mc, n - 1 - k) if k >= n - 2 else direct())
        if v - 1 > _U32 or state[3]:
            return None
        return v - 1

    return bit, direct, residual, lambda: state[3]


def _residual_models():
    """Encoding 2's models at the start of a rectangle: unary[12][33], mant[12][33][2]."""
    return [[1024] * 33 for _ in range(12)], [[[1024, 1024] for _ in range(33)] for _ in range(12)]


def _base_context(z: list[int], w: int, x: int, y: int, i: int) -> int:
    """Encoding 2's context of cell (x, y): the bit length of the neighbours' |residuals|."""
    a = (z[i - 1] + 1) >> 1 if x else ((z[i - w] + 1) >> 1 if y else 0)
    b2 = (z[i - w] + 1) >> 1 if y else a
    return min(11, (a + b2).bit_length())


def _base_predict(d: list[int], w: int, x: int, y: int, i: int) -> int:
    """Encoding 2's prediction (d as u32), not yet wrapped."""
    if y == 0:
        return d[i - 1] if x else 0
    if x == 0:
        return d[i - w]
    return d[i - 1] + d[i - w] - d[i - w - 1]


def _check_cells(w: int, h: int, max_cells: int | None) -> int:
    cells = w * h
    if cells <= 0 or (max_cells is not None and cells > max_cells):
        raise ProtoError("too_large", f"{cells} cells")
    return cells


def rect_decompress_base(data: bytes, w: int, h: int, max_cells: int | None = None) -> list[int]:
    """A base snapshot rectangle's w * h values h - base (PROTOCOL.md "Base snapshots";
    the same coder as proto/c/terrad_proto_base.c): bad_compression for a payload that ends
    before the last cell or a value past 2^32; more than max_cells cells is too_large."""
    cells = _check_cells(w, h, max_cells)
    if len(data) < 5:
        raise ProtoError("bad_compression", "a base payload of fewer than 5 bytes")
    unary, mant = _residual_models()
    _, _, residual, _ = _range_decoder(data, 0)
    z = [0] * cells  # zigzagged residuals
    d = [0] * cells  # h - base, as u32
    for y in range(h):
        row = y * w
        for x in range(w):
            i = row + x
            u = residual(unary, mant, _base_context(z, w, x, y, i))
            if u is None:
                raise ProtoError("bad_compression", "a base payload that ends early or holds a value past 2^32")
            z[i] = u
            d[i] = (((u >> 1) ^ -(u & 1)) + _base_predict(d, w, x, y, i)) & _U32
    return [v - (1 << 32) if v >= (1 << 31) else v for v in d]


def rect_decompress_slope(data: bytes, w: int, h: int, max_cells: int | None = None) -> list[int]:
    """A slope snapshot rectangle's w * h values h - base (encoding 3, PROTOCOL.md "Slope
    snapshots"; the coder of proto/c/terrad_proto_base.c): bad_compression for a payload of
    fewer than 13 bytes, one that ends before the last cell, or a value past 2^32 or a bound
    outside int32; more than max_cells cells is too_large."""
    cells = _check_cells(w, h, max_cells)
    if len(data) < 13:
        raise ProtoError("bad_compression", "a slope payload of fewer than 13 bytes")
    lim_a, lim_b = struct.unpack_from("<II", data, 0)
    unary, mant = _residual_models()
    cls = [[1024] * 4 for _ in range(64)]
    bit, _, residual, short = _range_decoder(data, 8)
    z = [0] * cells  # zigzagged residuals
    d = [0] * cells  # h - base, as u32
    s = [0] * cells  # h - base, as int32
    k = [0] * cells  # class: 0 none, 1 at the upper bound, 2 at the lower one
    for y in range(h):
        row = y * w
        for x in range(w):
            i = row + x
            nbs = []
            if x:
                nbs.append((s[i - 1], lim_a))
            if y:
                nbs.append((s[i - w], lim_a))
                if x:
                    nbs.append((s[i - w - 1], lim_b))
                if x + 1 < w:
                    nbs.append((s[i - w + 1], lim_b))
            p = _base_predict(d, w, x, y, i) & _U32
            p = p - (1 << 32) if p >= (1 << 31) else p
            v = None
            kk = 0
            if nbs:
                lo = min(n + lim for n, lim in nbs)
                hi = max(n - lim for n, lim in nbs)
                if hi <= lo:
                    p = min(max(p, hi), lo)
                cc = ((k[i - 1] if x else 3) * 16 + (k[i - w] if y else 3) * 4
                      + (k[i - w + 1] if y and x + 1 < w else 3))
                pc = cls[cc]
                if bit(pc, 0):
                    kk = 1
                    v = lo - bit(pc, 2)
                elif bit(pc, 1):
                    kk = 2
                    v = hi + bit(pc, 3)
                c = min(11, (lo - hi).bit_length()) if lo >= hi else _base_context(z, w, x, y, i)
            else:
                c = _base_context(z, w, x, y, i)
            k[i] = kk
            if v is None:
                u = residual(unary, mant, c)
                if u is None:
                    raise ProtoError("bad_compression", "a slope payload that ends early or holds a value past 2^32")
                v = _wrap(p + ((u >> 1) ^ -(u & 1)))
            elif not (-(2**31) <= v < 2**31) or short():
                raise ProtoError("bad_compression", "a slope payload that ends early or puts a cell outside int32")
            s[i] = v
            d[i] = v & _U32
            z[i] = zigzag32(_wrap(v - p))
    return s


def apply_values(r: Rect, values: list[int], heights: list[int], hx: int, hy: int, hw: int, hh: int) -> int:
    """Apply decoded values to a heights array covering (hx, hy, hw, hh),
    clipped: snapshots replace, deltas add (wrapping). Cells touched."""
    x0, y0 = max(r.x, hx), max(r.y, hy)
    x1, y1 = min(r.x + r.w, hx + hw), min(r.y + r.h, hy + hh)
    if x0 >= x1 or y0 >= y1:
        return 0
    n = x1 - x0
    for y in range(y0, y1):
        s = (y - r.y) * r.w + (x0 - r.x)
        d = (y - hy) * hw + (x0 - hx)
        if r.encoding == Encoding.SNAPSHOT:
            heights[d:d + n] = values[s:s + n]
        else:
            heights[d:d + n] = [_wrap(a + b) for a, b in zip(heights[d:d + n], values[s:s + n])]
    return n * (y1 - y0)


class Mirror:
    """A client's copy of one region with a version per tile (PROTOCOL.md,
    "Versions"). Version 0: not held yet. Same rules as terrad_mirror_apply."""

    def __init__(self, x: int, y: int, w: int, h: int, tile_size: int):
        if w <= 0 or h <= 0 or tile_size <= 0:
            raise ProtoError("bad_value", "empty region or tile size")
        self.x, self.y, self.w, self.h, self.tile_size = x, y, w, h, tile_size
        self.tx0, self.ty0 = x // tile_size, y // tile_size
        self.tiles_x = (x + w - 1) // tile_size - self.tx0 + 1
        self.tiles_y = (y + h - 1) // tile_size - self.ty0 + 1
        self.heights = [0] * (w * h)
        self.versions = [0] * (self.tiles_x * self.tiles_y)
        # the scene's base over the region (w * h), for base snapshot rectangles
        # (PROTOCOL.md "Base snapshots"); None: such a rectangle is bad_value
        self.base: list[int] | None = None

    @property
    def complete(self) -> bool:
        return all(self.versions)

    def _classify(self, r: Rect):
        """(tile index or None, apply?); raises bad_value / stale_base."""
        T = self.tile_size
        tx, ty = r.x // T, r.y // T
        if (r.x + r.w - 1) // T != tx or (r.y + r.h - 1) // T != ty:
            raise ProtoError("bad_value", "rectangle spans tiles")
        if not (self.tx0 <= tx < self.tx0 + self.tiles_x and self.ty0 <= ty < self.ty0 + self.tiles_y):
            return None, False
        t = (tx - self.tx0) + (ty - self.ty0) * self.tiles_x
        if r.encoding != Encoding.DELTA:  # a snapshot, absolute or against the base
            part = (max(r.x, self.x), max(r.y, self.y), min(r.x + r.w, self.x + self.w), min(r.y + r.h, self.y + self.h))
            tpart = (max(tx * T, self.x), max(ty * T, self.y), min(tx * T + T, self.x + self.w), min(ty * T + T, self.y + self.h))
            return t, part == tpart
        held = self.versions[t]
        if held == 0:
            return t, False
        if held != r.base_version:
            raise ProtoError("stale_base", f"tile held at {held}, delta from {r.base_version}")
        return t, True

    def _apply_base(self, r: Rect, diff: list[int]) -> None:
        """heights = base + diff (wrapping) where the rectangle meets the region."""
        assert self.base is not None
        x0, y0 = max(r.x, self.x), max(r.y, self.y)
        x1, y1 = min(r.x + r.w, self.x + self.w), min(r.y + r.h, self.y + self.h)
        for y in range(y0, y1):
            s = (y - r.y) * r.w + (x0 - r.x)
            o = (y - self.y) * self.w + (x0 - self.x)
            n = x1 - x0
            self.heights[o:o + n] = [_wrap(b + v) for b, v in zip(self.base[o:o + n], diff[s:s + n])]

    def apply(self, rects: list[Rect], max_cells: int = 1 << 22) -> None:
        """Apply one DELTA frame's rectangles; all or nothing for stale_base."""
        for r in rects:
            _, ok = self._classify(r)
            if ok and r.w * r.h > max_cells:
                raise ProtoError("too_large", f"{r.w} x {r.h} rectangle")
        try:
            for r in rects:
                try:
                    t, ok = self._classify(r)
                except ProtoError as e:
                    # A second rectangle of a tile this frame already advanced.
                    if e.name != "stale_base":
                        raise
                    T = self.tile_size
                    t = (r.x // T - self.tx0) + (r.y // T - self.ty0) * self.tiles_x
                    if self.versions[t] != r.new_version:
                        raise
                    ok = True
                if not ok:
                    continue
                if r.encoding in (Encoding.BASE, Encoding.BASE_SLOPE):
                    if self.base is None:
                        raise ProtoError("bad_value", "a base snapshot for a mirror without the base")
                    decompress = rect_decompress_base if r.encoding == Encoding.BASE else rect_decompress_slope
                    self._apply_base(r, decompress(r.data, r.w, r.h, max_cells))
                    self.versions[t] = r.new_version
                    continue
                values = rect_decompress(r.data, r.w * r.h, max_cells)
                apply_values(r, values, self.heights, self.x, self.y, self.w, self.h)
                self.versions[t] = r.new_version
        except ProtoError:
            self.versions = [0] * len(self.versions)
            raise

    def tile_differs(self, s: TileSum) -> int:
        """One CHECKSUM entry against the mirror (terrad_mirror_tile_differs): 1 when the
        tile is held and its version or hash differs, 0 when it agrees or is not held, -1
        when the region does not touch it."""
        T = self.tile_size
        if not (self.tx0 <= s.tile_x < self.tx0 + self.tiles_x and self.ty0 <= s.tile_y < self.ty0 + self.tiles_y):
            return -1
        t = (s.tile_x - self.tx0) + (s.tile_y - self.ty0) * self.tiles_x
        if self.versions[t] == 0:
            return 0
        if self.versions[t] != s.version:
            return 1
        x0, y0 = max(s.tile_x * T, self.x), max(s.tile_y * T, self.y)
        x1, y1 = min(s.tile_x * T + T, self.x + self.w), min(s.tile_y * T + T, self.y + self.h)
        start = (y0 - self.y) * self.w + (x0 - self.x)
        return int(heights_hash(self.heights, self.w, x1 - x0, y1 - y0, start) != s.hash)

    def tiles_differing(self, sums: list[TileSum]) -> list[tuple[int, int]]:
        """The (tile x, tile y) of every entry of one CHECKSUM frame for which tile_differs is
        1. With NumPy the hashes of tile parts of one shape are computed side by side (one
        pass over their cells for all of them: a whole 512 x 512 window in milliseconds, not
        the tenths of a second a Python loop takes); without it, one tile at a time."""
        T = self.tile_size
        todo = []  # (entry, x0, y0, w, h) of held tiles whose version agrees
        out = []
        for s in sums:
            if not (self.tx0 <= s.tile_x < self.tx0 + self.tiles_x and self.ty0 <= s.tile_y < self.ty0 + self.tiles_y):
                continue
            held = self.versions[(s.tile_x - self.tx0) + (s.tile_y - self.ty0) * self.tiles_x]
            if held == 0:
                continue
            if held != s.version:
                out.append((s.tile_x, s.tile_y))
                continue
            x0, y0 = max(s.tile_x * T, self.x), max(s.tile_y * T, self.y)
            x1, y1 = min(s.tile_x * T + T, self.x + self.w), min(s.tile_y * T + T, self.y + self.h)
            todo.append((s, x0 - self.x, y0 - self.y, x1 - x0, y1 - y0))
        if _np is None or len(todo) < 2:
            for s, x0, y0, w, h in todo:
                if heights_hash(self.heights, self.w, w, h, y0 * self.w + x0) != s.hash:
                    out.append((s.tile_x, s.tile_y))
            return out
        try:
            words = _array("i", self.heights)
        except OverflowError:  # a height outside int32 (the list was written to): its u32 word
            words = _array("I", [v & _U32 for v in self.heights])
        grid = _np.frombuffer(words, dtype=_np.uint32).reshape(self.h, self.w)
        shapes: dict[tuple[int, int], list] = {}
        for t in todo:
            shapes.setdefault((t[3], t[4]), []).append(t)
        for (w, h), group in shapes.items():
            cells = _np.stack([grid[y0:y0 + h, x0:x0 + w].reshape(-1) for _, x0, y0, _, _ in group])
            cells = _np.ascontiguousarray(cells.T.astype(_np.uint64))
            x = _np.full(len(group), HASH_SEED, dtype=_np.uint64)
            prime = _np.uint64(HASH_PRIME)
            for k in range(w * h):
                x ^= cells[k]
                x *= prime
            out += [(s.tile_x, s.tile_y) for (s, *_), got in zip(group, x.tolist()) if got != s.hash]
        return out

    def forget_tile(self, tile_x: int, tile_y: int) -> None:
        """Not held any more (its deltas skipped) until a snapshot of it arrives."""
        t = (tile_x - self.tx0) + (tile_y - self.ty0) * self.tiles_x
        self.versions[t] = 0


# ---- JSON control messages ---------------------------------------------------------------


def hello(token: str = "", client: str = "terrad-python", world: str = "",
          budget: int | None = None, snapshot_base: bool = False,
          snapshot_slope: bool = False) -> dict:
    """world: the world a cluster node should serve (sent only when given). budget: the
    most bytes per second this client wants to be sent (PROTOCOL.md "Budgets"; None: the
    server's default, 0: none). snapshot_base: ask for snapshots against the scene's base
    (PROTOCOL.md "Base snapshots"); snapshot_slope: with it, offer slope snapshots too
    (encoding 3, PROTOCOL.md "Slope snapshots": the server sends the shorter coding)."""
    msg = {"type": "hello", "protocol": PROTOCOL_VERSION, "token": token, "client": client}
    if world:
        msg["world"] = world
    if budget is not None:
        msg["budget"] = budget
    if snapshot_base:
        msg["snapshot_base"] = True
    if snapshot_slope:
        msg["snapshot_slope"] = True
    return msg


def collider_create(shape: str, material: str = "default", ref=None, feedback: bool = True,
                    load_n=None, grousers=None, forces_height: bool = False, **dims) -> dict:
    """shape: sphere (radius), box (half_extents), capsule (radius,
    half_length), cylinder (radius, half_length), wheel (radius, width), mesh
    (vertices, indices). Optional pose=Pose-like dict {"p":[x,y,z],"q":[w,x,y,z]}.
    load_n: a vertical load in newtons (bekker worlds): the server sets the height
    that carries it each tick (PROTOCOL.md "Load-driven colliders").
    grousers: a wheel's lugs, {"count": N, "height": m, "thickness": m}.
    forces_height: this client's FORCES frames carry each entry's height (Force.height_m: a
    load-driven collider's found height; PROTOCOL.md "FORCES")."""
    msg = {"type": "collider_create", "shape": shape, "material": material, "feedback": feedback}
    if load_n is not None:
        msg["load_n"] = load_n
    if grousers is not None:
        msg["grousers"] = {"count": int(grousers["count"]), "height": float(grousers["height"]),
                           "thickness": float(grousers["thickness"])}
    if forces_height:
        msg["forces_height"] = True
    msg.update(dims)
    if ref is not None:
        msg["ref"] = ref
    return msg


def collider_delete(cid: int, ref=None) -> dict:
    return _with_ref({"type": "collider_delete", "id": cid}, ref)


def subscribe(x: int, y: int, w: int, h: int, ref=None, colliders: bool = False,
              footprints: bool = False, grousers: bool = False) -> dict:
    """grousers (with colliders): COLLIDERS entries carry the wheels' grousers (the
    extension, PROTOCOL.md "COLLIDERS")."""
    m = {"type": "subscribe", "x": x, "y": y, "w": w, "h": h}
    if colliders:
        m["colliders"] = True
    if grousers:
        m["grousers"] = True
    if footprints:
        m["footprints"] = True
    return _with_ref(m, ref)


def unsubscribe(sid: int, ref=None) -> dict:
    return _with_ref({"type": "unsubscribe", "id": sid}, ref)


def subscribe_events(events=("world_created", "world_deleted"), ref=None) -> dict:
    """Admin: {"type": "event", "event": ..., "world": ...} for each world made or ended."""
    return _with_ref({"type": "subscribe_events", "events": list(events)}, ref)


def spectate(x: int, y: int, w: int, h: int, from_tick: int, speed: int | None = None,
             step: bool = False, ref=None) -> dict:
    """Watch a window from a past tick (PROTOCOL.md "Spectate"): its snapshot as of
    from_tick, then each tick's deltas and an ACK of the tick, at speed (1..8) times the
    world's tick rate, or (step=True) as many ticks as spectate_step messages ask for."""
    m: dict = {"type": "spectate", "x": x, "y": y, "w": w, "h": h, "from_tick": from_tick}
    if step:
        m["step"] = True
    elif speed is not None:
        m["speed"] = speed
    return _with_ref(m, ref)


def spectate_step(ticks: int = 1, ref=None) -> dict:
    return _with_ref({"type": "spectate_step", "ticks": ticks}, ref)


def spectate_stop(ref=None) -> dict:
    return _with_ref({"type": "spectate_stop"}, ref)


def focus(x: float | None = None, y: float | None = None) -> dict:
    """A budgeted client's focus point in cells (PROTOCOL.md "focus"); None: cleared (its
    colliders are the focus again)."""
    msg: dict = {"type": "focus"}
    if x is not None and y is not None:
        msg["x"], msg["y"] = x, y
    return msg


def resync(sid: int | None = None, ref=None, tiles=None) -> dict:
    """tiles: [(tile x, tile y), ...] of subscription sid: snapshots of only those."""
    msg: dict = {"type": "resync"}
    if sid is not None:
        msg["id"] = sid
    if tiles is not None:
        msg["tiles"] = [[int(x), int(y)] for x, y in tiles]
    return _with_ref(msg, ref)


def seen(tick: int) -> dict:
    """The latest tick whose frames this client has handled (PROTOCOL.md "seen"): the server
    bounds the client's lag by it, end to end."""
    return {"type": "seen", "tick": tick, "ref": "seen"}  # ref: an older daemon's refusal names it


def frame_tick(data: bytes) -> int:
    """The tick a server frame carries (DELTA and after: u64 at offset 4), 0 for others."""
    if len(data) >= 12 and data[2] >= MsgType.DELTA:
        return struct.unpack_from("<Q", data, 4)[0]
    return 0


def edit(op: str, ref=None, **fields) -> dict:
    """A terrain edit (PROTOCOL.md "edit"): op crater (x, y, radius, depth, rim), stamp
    (x, y, w, h, data, mode, mask, format), reset (x, y, w, h, or none: the whole world),
    add / remove (x, y, w, h, amount). Cells and height units, integers."""
    return _with_ref({"type": "edit", "op": op, **fields}, ref)


def stamp_data(values) -> str:
    """A stamp's int32 heights (row-major) as the base64 its "data" field carries."""
    import base64
    return base64.b64encode(struct.pack(f"<{len(values)}i", *values)).decode("ascii")


def error(code: int | str, message: str = "", ref=None) -> dict:
    if isinstance(code, str):
        code = ERROR_CODES[code]
    return {"type": "error", "code": code, "name": ERRORS[code], "message": message, "ref": ref}


def _with_ref(msg: dict, ref) -> dict:
    if ref is not None:
        msg["ref"] = ref
    return msg


def parse_control(text: str | bytes) -> dict:
    """A JSON text frame: an object with a string "type", else bad_json."""
    try:
        msg = json.loads(text)
    except (ValueError, UnicodeDecodeError) as e:
        raise ProtoError("bad_json", str(e)) from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise ProtoError("bad_json", 'not an object with a string "type"')
    return msg


def __getattr__(name: str):
    """The client lived in this module before it was a package (terrad_proto.TerradClient):
    the name still resolves, to terrad.client.Client."""
    if name in ("TerradClient", "Client"):
        from .client import Client
        return Client
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
