// The terrad wire protocol, version 1, in JavaScript (proto/PROTOCOL.md).
// Binary frames, the rectangle codec (zigzag + one zstd frame, decoded with fzstd; base
// snapshots: range-coded residuals against the scene's base), the client mirror with its
// tile-version rules, and the JSON control builders.
// Checked against proto/vectors/vectors.json by tests/web/codec.test.mjs.
// 64-bit fields (tick, nonce, volume) decode as BigInt.
import { Decompress } from './vendor/fzstd.js';

export const PROTOCOL_VERSION = 1;
export const MAGIC = 0x54;
export const SUBPROTOCOL = 'terrad.v1';
export const MsgType = { POSE_BATCH: 0x01, PING: 0x02, PONG: 0x03, STEP: 0x04, DELTA: 0x10, CONTACT: 0x11, ACK: 0x12, COLLIDERS: 0x13, FOOTPRINTS: 0x14, FORCES: 0x15, STEPPED: 0x16, CHECKSUM: 0x17 };
const TYPE_NAMES = { 1: 'POSE_BATCH', 2: 'PING', 3: 'PONG', 4: 'STEP', 16: 'DELTA', 17: 'CONTACT', 18: 'ACK', 19: 'COLLIDERS', 20: 'FOOTPRINTS', 21: 'FORCES', 22: 'STEPPED', 23: 'CHECKSUM' };
export const Owner = { OWN: 0, OTHER: 1, DEMO: 2 };
export const ColliderKind = { SPHERE: 0, BOX: 1, CAPSULE: 2, CYLINDER: 3, MESH: 4 };
// BASE: a snapshot less the scene's base terrain (PROTOCOL.md "Base snapshots"), only to a
// client whose hello asked for snapshot_base; BASE_SLOPE: the same in the slope-bounded coding
// (PROTOCOL.md "Slope snapshots"), only to a client whose hello also offered snapshot_slope
export const Encoding = { DELTA: 0, SNAPSHOT: 1, BASE: 2, BASE_SLOPE: 3 };
export const ERRORS = {
  bad_frame: 1, unknown_type: 2, bad_version: 3, too_large: 4, bad_value: 5, unknown_collider: 6,
  not_owner: 7, limit_colliders: 8, limit_subscriptions: 9, rate_limited: 10, outside_world: 11,
  bad_json: 12, unauthorized: 13, refused_height_limit: 14, store_unavailable: 15,
  bad_compression: 16, stale_base: 17, unsupported_collider: 18, unknown_subscription: 19,
  shutting_down: 20, internal: 21, forbidden: 22,
};
const POSE_SIZE = 32, RECT_FIXED = 25, CONTACT_SIZE = 48, ACK_SIZE = 16, PING_SIZE = 12, COLLIDER_STATE_SIZE = 48;
const FOOTPRINT_SIZE = 24;
const FORCE_SIZE = 48;
export const FORCES_FLAG_HEIGHT = 0x01; // FORCES header flag: an f64 height after each entry (opt-in)
export const COLLIDERS_FLAG_GROUSERS = 0x01; // COLLIDERS header flag: each entry's grousers after it (opt-in)
const COLLIDER_GROUSERS_SIZE = 12, GROUSERS_MAX = 360;
const FOOTPRINT_YAW_MAX = Math.fround(3.1416); // pi rounded up to float32
const MAX_COUNT = 0xffff;

export class ProtoError extends Error {
  constructor(error, message = '') {
    super(`${error}: ${message}`);
    this.name = 'ProtoError';
    this.error = error; // the name from the error table
    this.code = ERRORS[error];
  }
}

const bytes = (buf) => (buf instanceof Uint8Array ? buf : new Uint8Array(buf));
const view = (b) => new DataView(b.buffer, b.byteOffset, b.byteLength);

// ---- header ----

export function decodeHeader(buf) {
  const b = bytes(buf);
  if (b.length < 4) throw new ProtoError('bad_frame', 'shorter than the header');
  if (b[0] !== MAGIC) throw new ProtoError('bad_frame', `magic 0x${b[0].toString(16)}`);
  if (b[1] !== PROTOCOL_VERSION) throw new ProtoError('bad_version', `protocol version ${b[1]}`);
  if (!(b[2] in TYPE_NAMES)) throw new ProtoError('unknown_type', `type 0x${b[2].toString(16)}`);
  // the flags defined, each an extension a client asks for: FORCES' heights, COLLIDERS' grousers
  const defined = b[2] === MsgType.FORCES ? FORCES_FLAG_HEIGHT : b[2] === MsgType.COLLIDERS ? COLLIDERS_FLAG_GROUSERS : 0;
  if (b[3] & ~defined) throw new ProtoError('bad_frame', 'reserved flags set');
  return b[2];
}

function expect(b, t) {
  const got = decodeHeader(b);
  if (got !== t) throw new ProtoError('unknown_type', `${TYPE_NAMES[got]} where ${TYPE_NAMES[t]} was expected`);
}

function checkQuaternion(qw, qx, qy, qz) {
  const n2 = qw * qw + qx * qx + qy * qy + qz * qz;
  if (!(n2 >= 0.81 && n2 <= 1.21)) throw new ProtoError('bad_value', `|q|^2 = ${n2} outside [0.81, 1.21]`);
}

// ---- POSE_BATCH ----

/** poses: [{id, x, y, z, qw, qx, qy, qz}] -> Uint8Array */
export function encodePoseBatch(seq, poses) {
  if (poses.length > MAX_COUNT) throw new ProtoError('too_large', `${poses.length} poses`);
  const b = new Uint8Array(10 + POSE_SIZE * poses.length);
  const v = view(b);
  b.set([MAGIC, PROTOCOL_VERSION, MsgType.POSE_BATCH, 0]);
  v.setUint32(4, seq >>> 0, true);
  v.setUint16(8, poses.length, true);
  poses.forEach((p, i) => writePose(v, 10 + i * POSE_SIZE, p));
  return b;
}

/** One pose at offset o (POSE_BATCH and STEP): checked, written as u32 id and 7 f32. */
function writePose(v, o, p) {
  const f = [p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz].map(Math.fround);
  if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `pose of collider ${p.id} is not finite`);
  checkQuaternion(f[3], f[4], f[5], f[6]);
  v.setUint32(o, p.id >>> 0, true);
  f.forEach((a, k) => v.setFloat32(o + 4 + 4 * k, a, true));
}

/** The pose at offset o, checked. */
function readPose(v, o) {
  const id = v.getUint32(o, true);
  const f = [];
  for (let k = 0; k < 7; k++) f.push(v.getFloat32(o + 4 + 4 * k, true));
  if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `pose of collider ${id} is not finite`);
  checkQuaternion(f[3], f[4], f[5], f[6]);
  return { id, x: f[0], y: f[1], z: f[2], qw: f[3], qx: f[4], qy: f[5], qz: f[6] };
}

export function decodePoseBatch(buf) {
  const b = bytes(buf);
  expect(b, MsgType.POSE_BATCH);
  if (b.length < 10) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const seq = v.getUint32(4, true), count = v.getUint16(8, true);
  if (b.length - 10 !== count * POSE_SIZE) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  const poses = [];
  for (let i = 0; i < count; i++) poses.push(readPose(v, 10 + i * POSE_SIZE));
  return { seq, poses };
}

// ---- DELTA ----

export function checkRect(r) {
  if (!(r.w >= 1 && r.w <= 0xffff && r.h >= 1 && r.h <= 0xffff)) throw new ProtoError('bad_value', `size ${r.w} x ${r.h}`);
  if (r.x + r.w - 1 > 2147483647 || r.y + r.h - 1 > 2147483647) throw new ProtoError('bad_value', 'rectangle past the int32 range');
  if (!(r.new_version > 0)) throw new ProtoError('bad_value', 'version out of range');
  if (r.encoding === Encoding.DELTA) {
    if (r.base_version === 0 || r.base_version === r.new_version)
      throw new ProtoError('bad_value', 'a delta needs base_version >= 1 and != new_version');
  } else if (r.encoding === Encoding.SNAPSHOT || r.encoding === Encoding.BASE || r.encoding === Encoding.BASE_SLOPE) {
    if (r.base_version !== 0) throw new ProtoError('bad_value', 'a snapshot has base_version 0');
  } else throw new ProtoError('bad_value', `encoding ${r.encoding}`);
  if (r.data.length === 0) throw new ProtoError('bad_value', 'empty payload');
}

/** Validates the whole frame; payloads stay compressed (rect.data, a view into buf). */
export function decodeDelta(buf) {
  const b = bytes(buf);
  expect(b, MsgType.DELTA);
  if (b.length < 14) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), count = v.getUint16(12, true);
  if (Math.floor((b.length - 14) / RECT_FIXED) < count) throw new ProtoError('bad_frame', `count ${count} larger than the frame`);
  let pos = 14;
  const rects = [];
  for (let i = 0; i < count; i++) {
    if (b.length - pos < RECT_FIXED) throw new ProtoError('bad_frame', 'rectangle header truncated');
    const r = {
      x: v.getInt32(pos, true), y: v.getInt32(pos + 4, true), w: v.getUint16(pos + 8, true), h: v.getUint16(pos + 10, true),
      base_version: v.getUint32(pos + 12, true), new_version: v.getUint32(pos + 16, true), encoding: b[pos + 20],
    };
    const n = v.getUint32(pos + 21, true);
    pos += RECT_FIXED;
    if (b.length - pos < n) throw new ProtoError('bad_frame', 'payload past the end of the frame');
    r.data = b.subarray(pos, pos + n);
    pos += n;
    checkRect(r);
    rects.push(r);
  }
  if (pos !== b.length) throw new ProtoError('bad_frame', `${b.length - pos} bytes after the last rectangle`);
  return { tick, rects };
}

// ---- CONTACT, ACK, PING, PONG ----

export function decodeContact(buf) {
  const b = bytes(buf);
  expect(b, MsgType.CONTACT);
  if (b.length < 14) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), count = v.getUint16(12, true);
  if (b.length - 14 !== count * CONTACT_SIZE) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  const contacts = [];
  for (let i = 0; i < count; i++) {
    const o = 14 + i * CONTACT_SIZE;
    const id = v.getUint32(o, true), volume = v.getBigInt64(o + 4, true), cells = v.getUint32(o + 12, true);
    const f = [];
    for (let k = 0; k < 8; k++) f.push(v.getFloat32(o + 16 + 4 * k, true));
    if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `contact of collider ${id} is not finite`);
    if (volume < 0n || f[0] < 0) throw new ProtoError('bad_value', 'negative volume or area');
    contacts.push({ id, volume, cells, area_m2: f[0], deepest: f.slice(1, 4), normal: f.slice(4, 7), support_height_m: f[7] });
  }
  return { tick, contacts };
}

// COLLIDERS: every collider meeting the subscriber's regions, [{id, owner, kind, dims, p, q}], and with
// the header flag COLLIDERS_FLAG_GROUSERS (the grousers extension: a subscription made with grousers)
// each entry's grousers: {count, height, thickness} (m) on a lugged wheel, lug 0 along the entry's -z
// turned with q, else null.
export function decodeColliders(buf) {
  const b = bytes(buf);
  expect(b, MsgType.COLLIDERS);
  if (b.length < 14) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), count = v.getUint16(12, true);
  const lugged = (b[3] & COLLIDERS_FLAG_GROUSERS) !== 0, size = COLLIDER_STATE_SIZE + (lugged ? COLLIDER_GROUSERS_SIZE : 0);
  if (b.length - 14 !== count * size) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  const colliders = [];
  for (let i = 0; i < count; i++) {
    const o = 14 + i * size;
    const id = v.getUint32(o, true), owner = b[o + 4], kind = b[o + 5];
    if (v.getUint16(o + 6, true) !== 0) throw new ProtoError('bad_value', `collider ${id}: reserved bytes set`);
    if (owner > Owner.DEMO) throw new ProtoError('bad_value', `collider ${id}: owner ${owner}`);
    if (kind > ColliderKind.MESH) throw new ProtoError('bad_value', `collider ${id}: kind ${kind}`);
    const f = [];
    for (let k = 0; k < 10; k++) f.push(v.getFloat32(o + 8 + 4 * k, true));
    if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `collider ${id} is not finite`);
    if (f[0] < 0 || f[1] < 0 || f[2] < 0) throw new ProtoError('bad_value', `collider ${id}: negative dimension`);
    checkQuaternion(f[6], f[7], f[8], f[9]);
    const entry = { id, owner, kind, dims: f.slice(0, 3), p: f.slice(3, 6), q: f.slice(6, 10) };
    if (lugged) entry.grousers = decodeGrousers(v, o + COLLIDER_STATE_SIZE, entry);
    colliders.push(entry);
  }
  return { tick, colliders };
}

// One entry's grousers (the extension): null for none, else lugs on a cylinder's rim, each height and
// thickness > 0 and at most its radius.
function decodeGrousers(v, o, c) {
  const count = v.getUint16(o, true), height = v.getFloat32(o + 4, true), thickness = v.getFloat32(o + 8, true);
  if (v.getUint16(o + 2, true) !== 0) throw new ProtoError('bad_value', `collider ${c.id}: the grousers' reserved bytes set`);
  if (count === 0) {
    if (height !== 0 || thickness !== 0) throw new ProtoError('bad_value', `collider ${c.id}: no grousers but a height or thickness`);
    return null;
  }
  if (count > GROUSERS_MAX || c.kind !== ColliderKind.CYLINDER) throw new ProtoError('bad_value', `collider ${c.id}: ${count} grousers on kind ${c.kind}`);
  if (!(height > 0 && height <= c.dims[0] && thickness > 0 && thickness <= c.dims[0]))
    throw new ProtoError('bad_value', `collider ${c.id}: grousers ${height} m tall, ${thickness} m thick (each > 0 and <= the radius)`);
  return { count, height, thickness };
}

// FOOTPRINTS: the decals model's events inside the subscriber's regions,
// [{collider, x, y, yaw, size_m, strength_m}]: draw a decal of side size_m at (x, y), turned by yaw.
export function decodeFootprints(buf) {
  const b = bytes(buf);
  expect(b, MsgType.FOOTPRINTS);
  if (b.length < 14) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), count = v.getUint16(12, true);
  if (b.length - 14 !== count * FOOTPRINT_SIZE) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  const footprints = [];
  for (let i = 0; i < count; i++) {
    const o = 14 + i * FOOTPRINT_SIZE;
    const collider = v.getUint32(o, true);
    const f = [];
    for (let k = 0; k < 5; k++) f.push(v.getFloat32(o + 4 + 4 * k, true));
    if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `footprint of collider ${collider} is not finite`);
    if (Math.abs(f[2]) > FOOTPRINT_YAW_MAX) throw new ProtoError('bad_value', `footprint of collider ${collider}: yaw ${f[2]}`);
    if (!(f[3] > 0 && f[4] > 0)) throw new ProtoError('bad_value', `footprint of collider ${collider}: size and strength must be > 0`);
    footprints.push({ collider, x: f[0], y: f[1], yaw: f[2], size_m: f[3], strength_m: f[4] });
  }
  return { tick, footprints };
}

// FORCES (worlds of the bekker model): the soil's push on each of the client's colliders with
// feedback, [{id, force: [x, y, z] N, torque: [x, y, z] N m about the pose position,
// sinkage_m, area_m2, patch_width_m, slip, cells}], and with the header flag FORCES_FLAG_HEIGHT
// (the height extension: a collider created with forcesHeight) each entry's height_m, the pose
// height the tick deformed at: a load-driven collider's is the one the server found.
export function decodeForces(buf) {
  const b = bytes(buf);
  expect(b, MsgType.FORCES);
  if (b.length < 14) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), count = v.getUint16(12, true);
  const withHeight = (b[3] & FORCES_FLAG_HEIGHT) !== 0, size = FORCE_SIZE + (withHeight ? 8 : 0);
  if (b.length - 14 !== count * size) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  const forces = [];
  for (let i = 0; i < count; i++) {
    const o = 14 + i * size;
    const id = v.getUint32(o, true);
    const f = [];
    for (let k = 0; k < 10; k++) f.push(v.getFloat32(o + 4 + 4 * k, true));
    if (!f.every(Number.isFinite)) throw new ProtoError('bad_value', `forces of collider ${id} are not finite`);
    if (f[6] < 0 || f[7] < 0 || f[8] < 0) throw new ProtoError('bad_value', `forces of collider ${id}: sinkage, area and patch width must be >= 0`);
    const entry = { id, force: f.slice(0, 3), torque: f.slice(3, 6), sinkage_m: f[6], area_m2: f[7],
      patch_width_m: f[8], slip: f[9], cells: v.getUint32(o + 44, true) };
    if (withHeight) {
      entry.height_m = v.getFloat64(o + FORCE_SIZE, true);
      if (!Number.isFinite(entry.height_m)) throw new ProtoError('bad_value', `forces of collider ${id}: height_m must be finite`);
    }
    forces.push(entry);
  }
  return { tick, forces };
}

export function decodeAck(buf) {
  const b = bytes(buf);
  expect(b, MsgType.ACK);
  if (b.length !== ACK_SIZE) throw new ProtoError('bad_frame', `ACK of ${b.length} bytes`);
  const v = view(b);
  return { tick: v.getBigUint64(4, true), seq: v.getUint32(12, true) };
}

// ---- STEP and STEPPED (client-clocked worlds, PROTOCOL.md "STEP") ----

const STEP_FIXED = 16, STEPPED_SIZE = 20;

/** A STEP of `ticks` ticks; sets: [] (hold), [poses] (the first tick's) or one array of poses per tick. */
export function encodeStep(seq, ticks, sets) {
  const count = sets.length ? sets[0].length : 0;
  if (!(ticks >= 1) || (sets.length > 1 && sets.length !== ticks)) throw new ProtoError('bad_value', `ticks ${ticks} with ${sets.length} sets`);
  if (sets.some((s) => s.length !== count)) throw new ProtoError('bad_value', 'every set must have the same count');
  const b = new Uint8Array(STEP_FIXED + POSE_SIZE * count * sets.length);
  const v = view(b);
  b.set([MAGIC, PROTOCOL_VERSION, MsgType.STEP, 0]);
  v.setUint32(4, seq >>> 0, true);
  v.setUint32(8, ticks >>> 0, true);
  v.setUint16(12, count, true);
  v.setUint16(14, sets.length, true);
  sets.flat().forEach((p, i) => writePose(v, STEP_FIXED + i * POSE_SIZE, p));
  return b;
}

export function decodeStep(buf) {
  const b = bytes(buf);
  expect(b, MsgType.STEP);
  if (b.length < STEP_FIXED) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const seq = v.getUint32(4, true), ticks = v.getUint32(8, true), count = v.getUint16(12, true), nsets = v.getUint16(14, true);
  if (b.length - STEP_FIXED !== count * nsets * POSE_SIZE) throw new ProtoError('bad_frame', `${nsets} sets of ${count} do not match the frame`);
  if (ticks === 0 || (nsets > 1 && nsets !== ticks)) throw new ProtoError('bad_value', `ticks ${ticks} with ${nsets} sets`);
  const sets = [];
  for (let k = 0; k < nsets; k++) {
    const s = [];
    for (let i = 0; i < count; i++) s.push(readPose(v, STEP_FIXED + (k * count + i) * POSE_SIZE));
    sets.push(s);
  }
  return { seq, ticks, sets };
}

export function decodeStepped(buf) {
  const b = bytes(buf);
  expect(b, MsgType.STEPPED);
  if (b.length !== STEPPED_SIZE) throw new ProtoError('bad_frame', `STEPPED of ${b.length} bytes`);
  const v = view(b);
  const ticks = v.getUint32(16, true);
  if (ticks === 0) throw new ProtoError('bad_value', 'STEPPED of 0 ticks');
  return { tick: v.getBigUint64(4, true), seq: v.getUint32(12, true), ticks };
}

// ---- CHECKSUM (desync detection, PROTOCOL.md "CHECKSUM") ----

const CHECKSUM_FIXED = 18, TILE_SUM_SIZE = 20;

/**
 * PROTOCOL.md "Tile hash": FNV-1a 64 over the heights as u32 words, row-major, of the w x h
 * heights at heights[start + j * stride + i], as a BigInt. Computed in two 32-bit halves:
 * the prime is 2^40 + 0x1b3, so (hi:lo) * prime = hi * 0x1b3 + lo * 2^8 (high word, with the
 * carry of lo * 0x1b3) : lo * 0x1b3 (low word), every partial product exact in a double.
 */
export function heightsHash(heights, stride, w, h, start = 0) {
  let hi = 0xcbf29ce4, lo = 0x84222325;
  for (let j = 0; j < h; j++) {
    const o = start + j * stride;
    for (let i = 0; i < w; i++) {
      const x = (lo ^ heights[o + i]) >>> 0;
      const p = x * 0x1b3;
      hi = (Math.imul(hi, 0x1b3) + Math.floor(p / 4294967296) + (x << 8)) >>> 0;
      lo = p >>> 0;
    }
  }
  return (BigInt(hi) << 32n) | BigInt(lo);
}

export function encodeChecksum(tick, subscription, tiles) {
  if (!(subscription > 0) || tiles.length > MAX_COUNT) throw new ProtoError('bad_value', 'subscription 0 or too many tiles');
  const b = new Uint8Array(CHECKSUM_FIXED + TILE_SUM_SIZE * tiles.length);
  const v = view(b);
  b.set([MAGIC, PROTOCOL_VERSION, MsgType.CHECKSUM, 0]);
  v.setBigUint64(4, BigInt(tick), true);
  v.setUint32(12, subscription, true);
  v.setUint16(16, tiles.length, true);
  tiles.forEach((t, i) => {
    if (t.tile_x < 0 || t.tile_y < 0 || t.version === 0) throw new ProtoError('bad_value', `tile (${t.tile_x}, ${t.tile_y}) of version ${t.version}`);
    const o = CHECKSUM_FIXED + i * TILE_SUM_SIZE;
    v.setInt32(o, t.tile_x, true);
    v.setInt32(o + 4, t.tile_y, true);
    v.setUint32(o + 8, t.version, true);
    v.setBigUint64(o + 12, BigInt(t.hash), true);
  });
  return b;
}

/** { tick, subscription, tiles: [{ tile_x, tile_y, version, hash (BigInt) }] } */
export function decodeChecksum(buf) {
  const b = bytes(buf);
  expect(b, MsgType.CHECKSUM);
  if (b.length < CHECKSUM_FIXED) throw new ProtoError('bad_frame', 'truncated');
  const v = view(b);
  const tick = v.getBigUint64(4, true), subscription = v.getUint32(12, true), count = v.getUint16(16, true);
  if (b.length - CHECKSUM_FIXED !== count * TILE_SUM_SIZE) throw new ProtoError('bad_frame', `count ${count} does not match the frame`);
  if (subscription === 0) throw new ProtoError('bad_value', 'subscription 0');
  const tiles = [];
  for (let i = 0; i < count; i++) {
    const o = CHECKSUM_FIXED + i * TILE_SUM_SIZE;
    const t = { tile_x: v.getInt32(o, true), tile_y: v.getInt32(o + 4, true), version: v.getUint32(o + 8, true), hash: v.getBigUint64(o + 12, true) };
    if (t.tile_x < 0 || t.tile_y < 0 || t.version === 0) throw new ProtoError('bad_value', `tile (${t.tile_x}, ${t.tile_y}) of version ${t.version}`);
    tiles.push(t);
  }
  return { tick, subscription, tiles };
}

/**
 * One CHECKSUM frame against a client's mirrors (a Map of subscription id → Mirror), every frame
 * before it applied (PROTOCOL.md "CHECKSUM"): counts into stats ({ checksumFrames, checksumTick,
 * tilesDiffering, tilesResynced }), forgets each held tile that differs (its deltas skipped until
 * its snapshot) and returns the `resync` with `tiles` to send (null: nothing differs), at most
 * maxTiles of them (limits.max_resync_tiles; the rest at the next CHECKSUM). The JS client and
 * the viewer both repair with it.
 */
export function checkMirrors(mirrors, buf, stats, maxTiles = 64) {
  const { tick, subscription, tiles } = decodeChecksum(buf);
  stats.checksumFrames++;
  stats.checksumTick = tick;
  const m = mirrors.get(subscription);
  const differing = m ? tiles.filter((s) => m.tileDiffers(s) === 1).map((s) => [s.tile_x, s.tile_y]) : [];
  stats.tilesDiffering += differing.length;
  const asked = differing.slice(0, maxTiles);
  for (const [x, y] of asked) m.forgetTile(x, y);
  stats.tilesResynced += asked.length;
  return { tick, subscription, asked, resync: asked.length ? resync(subscription, undefined, asked) : null };
}

export function decodePing(buf) {
  const b = bytes(buf);
  const t = decodeHeader(b);
  if (t !== MsgType.PING && t !== MsgType.PONG) throw new ProtoError('unknown_type', `${TYPE_NAMES[t]} where PING or PONG was expected`);
  if (b.length !== PING_SIZE) throw new ProtoError('bad_frame', `${TYPE_NAMES[t]} of ${b.length} bytes`);
  return { type: t, nonce: view(b).getBigUint64(4, true) };
}

export function encodePing(nonce, pong = false) {
  const b = new Uint8Array(PING_SIZE);
  b.set([MAGIC, PROTOCOL_VERSION, pong ? MsgType.PONG : MsgType.PING, 0]);
  view(b).setBigUint64(4, BigInt.asUintN(64, BigInt(nonce)), true);
  return b;
}

// ---- rectangle payloads ----

export const zigzag32 = (d) => ((d << 1) ^ (d >> 31)) >>> 0;
export const unzigzag32 = (u) => (u >>> 1) ^ -(u & 1);

/** values (int32s) -> the zigzag little-endian packing, 4 bytes each */
export function rectPack(values) {
  const b = new Uint8Array(4 * values.length);
  const v = view(b);
  for (let i = 0; i < values.length; i++) v.setUint32(4 * i, zigzag32(values[i] | 0), true);
  return b;
}

export function rectUnpack(b) {
  const v = view(b), n = b.length >> 2, out = new Int32Array(n);
  for (let i = 0; i < n; i++) out[i] = unzigzag32(v.getUint32(4 * i, true));
  return out;
}

/** Parses one zstd frame's header and walks its blocks: {contentSize, window, end}. */
function zstdFrameInfo(d) {
  const bad = (m) => new ProtoError('bad_compression', m);
  if (d.length < 6 || d[0] !== 0x28 || d[1] !== 0xb5 || d[2] !== 0x2f || d[3] !== 0xfd) throw bad('not a zstd frame');
  const fhd = d[4];
  const fcf = fhd >> 6, ss = (fhd >> 5) & 1, cc = (fhd >> 2) & 1, did = fhd & 3;
  if (fhd & 8) throw bad('reserved bit set');
  let p = 5, window = 0;
  if (!ss) {
    const wd = d[p++], wb = 2 ** (10 + (wd >> 3));
    window = wb + (wb / 8) * (wd & 7);
  }
  const dictBytes = [0, 1, 2, 4][did];
  let dict = 0;
  for (let i = 0; i < dictBytes; i++) dict += d[p + i] * 2 ** (8 * i);
  p += dictBytes;
  if (dict !== 0) throw bad('dictionary frames are not used');
  const fcsBytes = fcf === 0 ? ss : [0, 2, 4, 8][fcf];
  if (fcsBytes === 0) throw bad('frame without a declared content size');
  if (p + fcsBytes > d.length) throw bad('truncated frame header');
  let size = 0;
  for (let i = 0; i < fcsBytes; i++) size += d[p + i] * 2 ** (8 * i);
  if (fcsBytes === 2) size += 256;
  p += fcsBytes;
  if (ss) window = size;
  for (;;) {
    if (p + 3 > d.length) throw bad('truncated frame');
    const bh = d[p] | (d[p + 1] << 8) | (d[p + 2] << 16);
    const last = bh & 1, type = (bh >> 1) & 3, bsize = bh >>> 3;
    p += 3;
    if (type === 3) throw bad('reserved block type');
    p += type === 1 ? 1 : bsize;
    if (p > d.length) throw bad('truncated frame');
    if (last) break;
  }
  if (cc) p += 4;
  if (p > d.length) throw bad('truncated frame');
  return { contentSize: size, window, end: p };
}

/** One zstd frame declaring and holding exactly 4*cells bytes -> Int32Array of cells values. */
export function rectDecompress(data, cells, maxCells = Infinity) {
  const d = bytes(data);
  if (!(cells > 0) || cells > maxCells) throw new ProtoError('too_large', `${cells} cells`);
  const raw = cells * 4;
  const info = zstdFrameInfo(d);
  if (info.contentSize !== raw) throw new ProtoError('bad_compression', `frame declares ${info.contentSize} bytes, the rectangle needs ${raw}`);
  if (info.end !== d.length) throw new ProtoError('bad_compression', 'bytes after the zstd frame');
  if (info.window > Math.max(raw, 1 << 17) * 2 + (1 << 20)) throw new ProtoError('bad_compression', 'window larger than needed');
  const out = new Uint8Array(raw);
  let n = 0;
  try {
    const z = new Decompress((chunk) => {
      if (n + chunk.length > raw) throw new ProtoError('bad_compression', 'more bytes than declared');
      out.set(chunk, n);
      n += chunk.length;
    });
    z.push(d, true);
  } catch (e) {
    if (e instanceof ProtoError) throw e;
    throw new ProtoError('bad_compression', String(e && e.message ? e.message : e));
  }
  if (n !== raw) throw new ProtoError('bad_compression', `${n} bytes where ${raw} were declared`);
  return rectUnpack(out);
}

// ---- base snapshot rectangles (PROTOCOL.md "Base snapshots"; proto/c/terrad_proto_base.c) ----
// d = h - base per cell, predicted from the decoded neighbours (left + up - up-left), the
// residual zigzagged and coded bit by bit with LZMA's binary range coder: its bit length in
// unary, then its two top mantissa bits with adaptive probabilities per context (how large the
// left and upper residuals were), the rest direct. All arithmetic modulo 2^32: exact.

const B_CTX = 12, B_TOP = 0x1000000;

// LZMA's binary range decoder over d from byte start (PROTOCOL.md "Base snapshots", step 5):
// bit(probs, i), direct(), residual(unary, mant, c) (a zigzagged residual in Elias-gamma form,
// step 4; -1 past 2^32 - 1 or past the payload's end) and short() (it ran past the end).
function rangeDecoder(d, start) {
  const n = d.length;
  let at = start, short = false, range = 0xffffffff, code = 0;
  const byte = () => {
    if (at < n) return d[at++];
    short = true;
    return 0;
  };
  for (let k = 0; k < 5; k++) code = ((code << 8) | byte()) >>> 0;
  const norm = () => {
    while (range < B_TOP) {
      range = (range << 8) >>> 0;
      code = ((code << 8) | byte()) >>> 0;
    }
  };
  const bit = (probs, i) => {
    const p = probs[i], bound = (range >>> 11) * p; // < 2^32: p < 2048
    let b;
    if (code < bound) {
      range = bound;
      probs[i] = p + ((2048 - p) >> 4);
      b = 0;
    } else {
      code -= bound;
      range -= bound;
      probs[i] = p - (p >> 4);
      b = 1;
    }
    norm();
    return b;
  };
  const direct = () => {
    range >>>= 1;
    const b = code >= range ? 1 : 0;
    if (b) code -= range;
    norm();
    return b;
  };
  const residual = (unary, mant, c) => {
    let nb = 0;
    while (nb < 32 && bit(unary, c * 33 + nb)) nb++;
    let v = 1; // up to 2^33 - 1: a double, not 32-bit bitwise
    const m = (c * 33 + nb) * 2;
    for (let k = nb - 1; k >= 0; k--) v = v * 2 + (k >= nb - 2 ? bit(mant, m + nb - 1 - k) : direct());
    return v - 1 > 0xffffffff || short ? -1 : v - 1;
  };
  return { bit, direct, residual, short: () => short };
}

const residualModels = () => [new Uint16Array(B_CTX * 33).fill(1024), new Uint16Array(B_CTX * 33 * 2).fill(1024)];
const mag = (u) => Math.floor((u + 1) / 2); // |r| of a zigzagged residual, up to 2^31
// encoding 2's context of cell (x, y): the bit length of its neighbours' |residuals|, at most 11
function baseContext(z, w, x, y, i) {
  const a = x ? mag(z[i - 1]) : y ? mag(z[i - w]) : 0;
  const s = a + (y ? mag(z[i - w]) : a); // up to 2^32
  return s === 0 ? 0 : s >= 1024 ? B_CTX - 1 : 32 - Math.clz32(s);
}
// encoding 2's prediction of cell (x, y) from the decoded values, wrapped to int32
const basePredict = (out, w, x, y, i) =>
  (y === 0 ? (x ? out[i - 1] : 0) : x === 0 ? out[i - w] : out[i - 1] + out[i - w] - out[i - w - 1]) | 0;

/** A base snapshot rectangle's payload -> Int32Array of w * h values h - base; bad_compression
 *  for a payload shorter than 5 bytes, ending before the last cell or holding a value past
 *  2^32; more than maxCells cells is too_large. */
export function rectDecompressBase(data, w, h, maxCells = Infinity) {
  const d = bytes(data), cells = w * h;
  if (!(cells > 0) || cells > maxCells) throw new ProtoError('too_large', `${cells} cells`);
  if (d.length < 5) throw new ProtoError('bad_compression', 'a base payload of fewer than 5 bytes');
  const [unary, mant] = residualModels();
  const rc = rangeDecoder(d, 0);
  const z = new Uint32Array(cells); // the zigzagged residuals
  const out = new Int32Array(cells); // h - base
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const i = y * w + x;
      const u = rc.residual(unary, mant, baseContext(z, w, x, y, i));
      if (u < 0) throw new ProtoError('bad_compression', 'a base payload that ends early or holds a value past 2^32');
      z[i] = u;
      out[i] = (unzigzag32(u) + basePredict(out, w, x, y, i)) | 0; // |sum| < 2^34: exact, then wrapped
    }
  }
  return out;
}

// ---- slope snapshot rectangles (encoding 3, PROTOCOL.md "Slope snapshots") ----
// The same d = h - base, each cell bounded by its decoded left, upper, upper-left and
// upper-right neighbours and the payload's two limits (a axial, b diagonal): lo = min(n + limit),
// hi = max(n - limit). A cell first says whether it sits at lo (or lo - 1) or at hi (or hi + 1),
// with probabilities per context (its neighbours' classes); the others code a residual as
// encoding 2 does, against encoding 2's prediction clamped into [hi, lo], in a context of the
// bit length of lo - hi. Bounds reach past int32 (up to ~2^33): doubles, exact.

/** A slope snapshot rectangle's payload -> Int32Array of w * h values h - base;
 *  bad_compression for a payload shorter than 13 bytes, ending before the last cell, holding a
 *  value past 2^32 or placing a cell at a bound outside int32; more than maxCells cells is
 *  too_large. */
export function rectDecompressSlope(data, w, h, maxCells = Infinity) {
  const d = bytes(data), cells = w * h;
  if (!(cells > 0) || cells > maxCells) throw new ProtoError('too_large', `${cells} cells`);
  if (d.length < 13) throw new ProtoError('bad_compression', 'a slope payload of fewer than 13 bytes');
  const dv = new DataView(d.buffer, d.byteOffset, d.byteLength);
  const la = dv.getUint32(0, true), lb = dv.getUint32(4, true);
  const [unary, mant] = residualModels(), cls = new Uint16Array(64 * 4).fill(1024);
  const rc = rangeDecoder(d, 8);
  const z = new Uint32Array(cells); // the zigzagged residuals
  const k = new Uint8Array(cells); // 0: neither bound, 1: at the upper one, 2: at the lower one
  const out = new Int32Array(cells); // h - base
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const i = y * w + x;
      let lo = Infinity, hi = -Infinity;
      const bound = (n, lim) => {
        lo = Math.min(lo, n + lim);
        hi = Math.max(hi, n - lim);
      };
      if (x) bound(out[i - 1], la);
      if (y) bound(out[i - w], la);
      if (x && y) bound(out[i - w - 1], lb);
      if (y && x + 1 < w) bound(out[i - w + 1], lb);
      const any = x > 0 || y > 0;
      let p = basePredict(out, w, x, y, i);
      if (any && hi <= lo) p = Math.min(Math.max(p, hi), lo);
      let v = null;
      if (any) {
        const cc = ((x ? k[i - 1] : 3) * 16 + (y ? k[i - w] : 3) * 4 + (y && x + 1 < w ? k[i - w + 1] : 3)) * 4;
        if (rc.bit(cls, cc)) {
          k[i] = 1;
          v = lo - rc.bit(cls, cc + 2);
        } else if (rc.bit(cls, cc + 1)) {
          k[i] = 2;
          v = hi + rc.bit(cls, cc + 3);
        }
      }
      if (v === null) {
        const c = any && lo >= hi ? (lo - hi >= 1024 ? B_CTX - 1 : lo === hi ? 0 : 32 - Math.clz32(lo - hi)) : baseContext(z, w, x, y, i);
        const u = rc.residual(unary, mant, c);
        if (u < 0) throw new ProtoError('bad_compression', 'a slope payload that ends early or holds a value past 2^32');
        out[i] = (p + unzigzag32(u)) | 0; // |sum| < 2^35: exact, then wrapped
        z[i] = u;
      } else {
        if (v < -0x80000000 || v > 0x7fffffff || rc.short()) throw new ProtoError('bad_compression', 'a slope payload that ends early or puts a cell outside int32');
        out[i] = v;
        z[i] = zigzag32((v - p) | 0);
      }
    }
  }
  return out;
}

/** Applies decoded values to heights covering (hx, hy, hw, hh), clipped: a snapshot's replace,
 *  a delta's add, a base snapshot's (h - base) add to base, the scene's base over the same
 *  region (wrapping). Cells touched. */
export function applyValues(r, values, heights, hx, hy, hw, hh, base = null) {
  const x0 = Math.max(r.x, hx), y0 = Math.max(r.y, hy);
  const x1 = Math.min(r.x + r.w, hx + hw), y1 = Math.min(r.y + r.h, hy + hh);
  if (x0 >= x1 || y0 >= y1) return 0;
  const n = x1 - x0;
  for (let y = y0; y < y1; y++) {
    const s = (y - r.y) * r.w + (x0 - r.x), d = (y - hy) * hw + (x0 - hx);
    if (r.encoding === Encoding.SNAPSHOT) heights.set(values.subarray(s, s + n), d);
    else if (r.encoding === Encoding.BASE || r.encoding === Encoding.BASE_SLOPE) for (let i = 0; i < n; i++) heights[d + i] = (base[d + i] + values[s + i]) | 0;
    else for (let i = 0; i < n; i++) heights[d + i] = (heights[d + i] + values[s + i]) | 0;
  }
  return n * (y1 - y0);
}

const fdiv = (a, b) => Math.floor(a / b);

/** A client's copy of one region with a version per tile (PROTOCOL.md, "Versions"). */
export class Mirror {
  constructor(x, y, w, h, tileSize) {
    if (!(w > 0 && h > 0 && tileSize > 0)) throw new ProtoError('bad_value', 'empty region or tile size');
    Object.assign(this, { x, y, w, h, tileSize });
    this.tx0 = fdiv(x, tileSize);
    this.ty0 = fdiv(y, tileSize);
    this.tilesX = fdiv(x + w - 1, tileSize) - this.tx0 + 1;
    this.tilesY = fdiv(y + h - 1, tileSize) - this.ty0 + 1;
    this.heights = new Int32Array(w * h);
    this.versions = new Uint32Array(this.tilesX * this.tilesY);
    // the scene's base over the region (Int32Array of w * h, the twin's: PROTOCOL.md "Base
    // snapshots"), for base snapshot rectangles; null: such a rectangle is bad_value
    this.base = null;
  }

  get complete() {
    return this.versions.every((v) => v !== 0);
  }

  /** [tile index or -1, apply?]; throws bad_value / stale_base */
  classify(r) {
    const T = this.tileSize, tx = fdiv(r.x, T), ty = fdiv(r.y, T);
    if (fdiv(r.x + r.w - 1, T) !== tx || fdiv(r.y + r.h - 1, T) !== ty) throw new ProtoError('bad_value', 'rectangle spans tiles');
    if (!(tx >= this.tx0 && tx < this.tx0 + this.tilesX && ty >= this.ty0 && ty < this.ty0 + this.tilesY)) return [-1, false];
    const t = tx - this.tx0 + (ty - this.ty0) * this.tilesX;
    if (r.encoding !== Encoding.DELTA) { // a snapshot, absolute or against the base
      const part = [Math.max(r.x, this.x), Math.max(r.y, this.y), Math.min(r.x + r.w, this.x + this.w), Math.min(r.y + r.h, this.y + this.h)];
      const tpart = [Math.max(tx * T, this.x), Math.max(ty * T, this.y), Math.min(tx * T + T, this.x + this.w), Math.min(ty * T + T, this.y + this.h)];
      return [t, part.every((a, i) => a === tpart[i])];
    }
    const held = this.versions[t];
    if (held === 0) return [t, false];
    if (held !== r.base_version) throw new ProtoError('stale_base', `tile held at ${held}, delta from ${r.base_version}`);
    return [t, true];
  }

  /** Applies one DELTA frame's rectangles; all or nothing for stale_base. Returns cells changed. */
  apply(rects, maxCells = 1 << 22) {
    for (const r of rects) {
      const [, ok] = this.classify(r);
      if (ok && r.w * r.h > maxCells) throw new ProtoError('too_large', `${r.w} x ${r.h} rectangle`);
    }
    let touched = 0;
    try {
      for (const r of rects) {
        let t, ok;
        try {
          [t, ok] = this.classify(r);
        } catch (e) {
          // A second rectangle of a tile this frame already advanced.
          if (!(e instanceof ProtoError) || e.error !== 'stale_base') throw e;
          const T = this.tileSize;
          t = fdiv(r.x, T) - this.tx0 + (fdiv(r.y, T) - this.ty0) * this.tilesX;
          if (this.versions[t] !== r.new_version) throw e;
          ok = true;
        }
        if (!ok) continue;
        if (r.encoding === Encoding.BASE || r.encoding === Encoding.BASE_SLOPE) {
          if (!this.base) throw new ProtoError('bad_value', 'a base snapshot for a mirror without the base');
          const decompress = r.encoding === Encoding.BASE ? rectDecompressBase : rectDecompressSlope;
          touched += applyValues(r, decompress(r.data, r.w, r.h, maxCells), this.heights, this.x, this.y, this.w, this.h, this.base);
          this.versions[t] = r.new_version;
          continue;
        }
        const values = rectDecompress(r.data, r.w * r.h, maxCells);
        touched += applyValues(r, values, this.heights, this.x, this.y, this.w, this.h);
        this.versions[t] = r.new_version;
      }
    } catch (e) {
      this.versions.fill(0);
      throw e;
    }
    return touched;
  }

  /** One CHECKSUM entry against the mirror (terrad_mirror_tile_differs): 1 when the tile is held
   * and its version or hash differs, 0 when it agrees or is not held, -1 when the region does
   * not touch it. */
  tileDiffers(s) {
    const T = this.tileSize;
    if (!(s.tile_x >= this.tx0 && s.tile_x < this.tx0 + this.tilesX && s.tile_y >= this.ty0 && s.tile_y < this.ty0 + this.tilesY)) return -1;
    const t = s.tile_x - this.tx0 + (s.tile_y - this.ty0) * this.tilesX;
    if (this.versions[t] === 0) return 0;
    if (this.versions[t] !== s.version) return 1;
    const x0 = Math.max(s.tile_x * T, this.x), y0 = Math.max(s.tile_y * T, this.y);
    const x1 = Math.min(s.tile_x * T + T, this.x + this.w), y1 = Math.min(s.tile_y * T + T, this.y + this.h);
    const start = (y0 - this.y) * this.w + (x0 - this.x);
    return heightsHash(this.heights, this.w, x1 - x0, y1 - y0, start) === BigInt(s.hash) ? 0 : 1;
  }

  /** Not held any more (its deltas skipped) until a snapshot of it arrives. */
  forgetTile(tileX, tileY) {
    this.versions[tileX - this.tx0 + (tileY - this.ty0) * this.tilesX] = 0;
  }
}

// ---- JSON control messages ----

// world: a world created by POST /v1/worlds (or a cluster's world); '' for the default one.
// budget: bytes/s the server may send (PROTOCOL.md "Budgets"), 0 none; -1: the server's default
// snapshotBase: snapshots against the scene's base terrain, which the client rebuilds with the
// twin (PROTOCOL.md "Base snapshots"): the world message says whether the server agreed.
// snapshotSlope: with snapshotBase, offer slope snapshots too (encoding 3, PROTOCOL.md "Slope
// snapshots"; the server sends each piece in the shorter coding): the world message says
export const hello = (token = '', client = 'terrad-web', world = '', budget = -1, snapshotBase = false, snapshotSlope = false) =>
  ({ type: 'hello', protocol: PROTOCOL_VERSION, token, client, ...(world ? { world } : {}),
     ...(budget >= 0 ? { budget } : {}), ...(snapshotBase ? { snapshot_base: true } : {}),
     ...(snapshotBase && snapshotSlope ? { snapshot_slope: true } : {}) });
// a budgeted client's focus in cells (its nearest tiles first); no x, y: cleared
export const focus = (x = -1, y = -1) => (x < 0 || y < 0 ? { type: 'focus' } : { type: 'focus', x, y });
// grousers (with colliders): COLLIDERS entries carry the wheels' grousers (PROTOCOL.md "COLLIDERS")
export const subscribe = (x, y, w, h, ref, colliders = false, footprints = false, grousers = false) =>
  withRef({ type: 'subscribe', x, y, w, h, ...(colliders ? { colliders: true } : {}), ...(footprints ? { footprints: true } : {}),
    ...(grousers ? { grousers: true } : {}) }, ref);
export const unsubscribe = (id, ref) => withRef({ type: 'unsubscribe', id }, ref);
// admin: {type: 'event', event, world} for each world made or ended (PROTOCOL.md subscribe_events)
export const subscribeEvents = (events = ['world_created', 'world_deleted'], ref) =>
  withRef({ type: 'subscribe_events', events }, ref);
// tiles: [[tile x, tile y], ...] of subscription id: snapshots of only those (PROTOCOL.md "resync").
export const resync = (id, ref, tiles) =>
  withRef(id === undefined ? { type: 'resync' } : tiles ? { type: 'resync', id, tiles } : { type: 'resync', id }, ref);
// PROTOCOL.md "seen": the latest tick whose frames this client has handled.
export const seen = (tick) => ({ type: 'seen', tick, ref: 'seen' }); // ref: an older daemon's refusal names it
// The tick a server frame carries (DELTA and after: u64 at offset 4), 0 for others.
export function frameTick(buf) {
  const b = bytes(buf);
  return b.length >= 12 && b[2] >= MsgType.DELTA ? Number(new DataView(b.buffer, b.byteOffset, b.length).getBigUint64(4, true)) : 0;
}
// Tells the server the latest tick handled (send(message) sends a control message), at most
// every intervalMs, and once more after a pause so that the last frames are said too: the
// server bounds this client's lag by it, frames waiting in its own buffers included.
export class SeenReporter {
  constructor(send, intervalMs = 100) {
    Object.assign(this, { send, intervalMs, tick: 0, said: 0, at: 0, timer: null, off: false });
  }
  // after a frame's handling: its tick counts as handled
  handled(frame) {
    const t = frameTick(frame);
    if (t > this.tick) this.tick = t;
    this.say();
  }
  // the server's error about a seen (ref 'seen'): a daemon from before it says unknown_type
  refused(error) {
    if (error && error.ref === 'seen' && error.name === 'unknown_type') this.off = true;
  }
  say() {
    if (this.off || this.tick <= this.said) return;
    const wait = this.at + this.intervalMs - Date.now();
    if (wait <= 0) {
      this.said = this.tick;
      this.at = Date.now();
      this.send(seen(this.tick));
    } else if (!this.timer) {
      this.timer = setTimeout(() => { this.timer = null; this.say(); }, wait);
    }
  }
  // the connection ended: nothing more to say, and the next one starts from nothing
  reset() {
    clearTimeout(this.timer);
    Object.assign(this, { tick: 0, said: 0, at: 0, timer: null, off: false });
  }
}
export const colliderDelete = (id, ref) => withRef({ type: 'collider_delete', id }, ref);
// loadN: a vertical load in newtons (bekker worlds; PROTOCOL.md "Load-driven colliders"): the
// server sets the height that carries it each tick and reports it in FORCES.
// forcesHeight: this client's FORCES frames carry each entry's height_m (the height extension).
// grousers: a wheel's lugs {count, height, thickness} (metres; PROTOCOL.md collider_create).
/** @param {string} shape @param {object} [dims] @param {{material?: string, feedback?: boolean, pose?: object, ref?: string, loadN?: number, forcesHeight?: boolean, grousers?: {count: number, height: number, thickness: number}}} [opts] */
export function colliderCreate(shape, dims = {}, { material = 'default', feedback = true, pose, ref, loadN, forcesHeight, grousers } = {}) {
  const m = { type: 'collider_create', shape, material, feedback, ...dims };
  if (pose) m.pose = pose;
  if (loadN !== undefined) m.load_n = loadN;
  if (forcesHeight) m.forces_height = true;
  if (grousers !== undefined) m.grousers = grousers;
  return withRef(m, ref);
}
// A terrain edit (PROTOCOL.md "edit"): op crater | stamp | reset | add | remove, its fields in
// cells and height units, e.g. edit('crater', { x: 40, y: 40, radius: 8, depth: 20000 }).
export const edit = (op, fields = {}, ref) => withRef({ type: 'edit', op, ...fields }, ref);
// A stamp's int32 heights (row-major) as the base64 its "data" field carries.
export function stampData(values) {
  const b = new Uint8Array(values.length * 4);
  const v = new DataView(b.buffer);
  values.forEach((x, i) => v.setInt32(4 * i, x, true));
  let s = '';
  for (const byte of b) s += String.fromCharCode(byte);
  return btoa(s);
}
function withRef(m, ref) {
  if (ref !== undefined && ref !== null) m.ref = ref;
  return m;
}

export function parseControl(text) {
  let m;
  try {
    m = JSON.parse(text);
  } catch (e) {
    throw new ProtoError('bad_json', String(e.message));
  }
  if (typeof m !== 'object' || m === null || Array.isArray(m) || typeof m.type !== 'string') throw new ProtoError('bad_json', 'not an object with a string type');
  return m;
}

// ---- the world lifecycle API (HTTP, a single daemon; docs/openapi.yaml "worlds") ----
// base: the daemon's HTTP address, e.g. 'http://127.0.0.1:8080'; token: an admin token where the
// daemon has tokens (any known token lists). A refusal throws WorldError naming the field.

export class WorldError extends Error {
  constructor(status, message, field = '') {
    super(`${status}: ${message}`);
    this.status = status;
    this.field = field;
  }
}

async function worldRequest(base, method, path, body, token) {
  const headers = {};
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  if (token) headers.Authorization = `Bearer ${token}`;
  const res = await fetch(base.replace(/\/$/, '') + path,
    { method, headers, body: body === undefined ? undefined : JSON.stringify(body) });
  const doc = await res.json().catch(() => ({}));
  if (!res.ok) throw new WorldError(res.status, doc.error || res.statusText, doc.field || '');
  return doc;
}

// A world from scene (a scene object, as in a scene file) or sceneName (a scene of the daemon's
// --scene-dir); resolves to its entry once it serves (hello(token, client, name) joins it).
/** @param {string} base @param {string} name @param {{scene?: object, sceneName?: string, token?: string}} [opts] */
export function createWorld(base, name, { scene, sceneName, token = '' } = {}) {
  const body = { name };
  if (scene !== undefined) body.scene = scene;
  if (sceneName !== undefined) body.scene_name = sceneName;
  return worldRequest(base, 'POST', '/v1/worlds', body, token);
}

// Every world, the default one first: [{ name, state, default, scene, width, height, tick, ... }].
export async function listWorlds(base, { token = '' } = {}) {
  return (await worldRequest(base, 'GET', '/v1/worlds', undefined, token)).worlds;
}

// Ends a created world: its clients are closed with 4020 "world deleted"; keep: its storage is
// kept for replays. Resolves to { name, deleted: true, kept }.
export function deleteWorld(base, name, { keep = false, token = '' } = {}) {
  return worldRequest(base, 'DELETE', `/v1/worlds/${encodeURIComponent(name)}${keep ? '?keep=1' : ''}`,
    undefined, token);
}
