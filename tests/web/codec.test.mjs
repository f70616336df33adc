// The viewer's JavaScript codec (web/terrad_codec.mjs) against every test vector in
// proto/vectors/vectors.json (PROTOCOL.md, "Test vectors"), and the pinning of the
// vendored fzstd (web/vendor/fzstd.js must equal node_modules' copy: scripts/vendor-web).
import { test } from 'node:test';
import assert from 'node:assert/strict';
import { readFileSync, existsSync } from 'node:fs';
import { fileURLToPath } from 'node:url';
import path from 'node:path';
import * as C from '../../web/terrad_codec.mjs';

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const V = JSON.parse(readFileSync(path.join(root, 'proto/vectors/vectors.json'), 'utf8'));
const unhex = (h) => Uint8Array.from(h.match(/../g) || [], (x) => parseInt(x, 16));
const hex = (b) => Buffer.from(b).toString('hex');

const decoders = {
  POSE_BATCH: (b) => C.decodePoseBatch(b),
  DELTA: (b) => {
    const d = C.decodeDelta(b);
    d.values = d.rects.map((r) => C.rectDecompress(r.data, r.w * r.h, r.w * r.h));
    return d;
  },
  CONTACT: C.decodeContact,
  COLLIDERS: C.decodeColliders,
  FOOTPRINTS: C.decodeFootprints,
  FORCES: C.decodeForces,
  ACK: C.decodeAck,
  STEP: C.decodeStep,
  STEPPED: C.decodeStepped,
  CHECKSUM: C.decodeChecksum,
  PING: C.decodePing,
  PONG: C.decodePing,
};

function errorName(fn) {
  try {
    fn();
  } catch (e) {
    assert.ok(e instanceof C.ProtoError, `not a ProtoError: ${e && e.stack}`);
    return e.error;
  }
  return '';
}

test('error table matches the vectors', () => {
  for (const e of V.errors) assert.equal(C.ERRORS[e.name], e.code, e.name);
  for (const t of V.types) assert.equal(C.MsgType[t.name], t.code, t.name);
});

for (const v of V.vectors) {
  test(`vector ${v.name} (${v.type}, ${v.valid ? 'valid' : v.error})`, () => {
    const buf = unhex(v.hex);
    if (!v.valid) {
      assert.equal(errorName(() => decoders[v.type](buf)), v.error);
      return;
    }
    const d = decoders[v.type](buf);
    const f = v.fields;
    switch (v.type) {
      case 'POSE_BATCH':
        assert.equal(d.seq, f.seq);
        assert.deepEqual(d.poses, f.poses);
        assert.equal(hex(C.encodePoseBatch(f.seq, f.poses)), v.hex);
        break;
      case 'DELTA':
        assert.equal(String(d.tick), f.tick);
        assert.equal(d.rects.length, f.rects.length);
        f.rects.forEach((fr, i) => {
          const r = d.rects[i];
          for (const k of ['x', 'y', 'w', 'h', 'base_version', 'new_version', 'encoding']) assert.equal(r[k], fr[k], k);
          assert.equal(hex(r.data), fr.data_hex);
          assert.deepEqual(Array.from(d.values[i]), fr.values);
          assert.equal(hex(C.rectPack(fr.values)), fr.packed_hex);
          assert.deepEqual(Array.from(C.rectUnpack(unhex(fr.packed_hex))), fr.values);
          if (fr.old) fr.old.forEach((o, k) => assert.equal((o + fr.values[k]) | 0, fr.new[k]));
        });
        break;
      case 'CONTACT':
        assert.equal(String(d.tick), f.tick);
        // Floats in the vectors are f32 values printed in short form: compare as f32.
        assert.deepEqual(d.contacts.map((c) => ({ ...c, volume: String(c.volume) })), f.contacts.map((c) => ({
          ...c, area_m2: Math.fround(c.area_m2), deepest: c.deepest.map(Math.fround), normal: c.normal.map(Math.fround),
          support_height_m: Math.fround(c.support_height_m) })));
        break;
      case 'COLLIDERS':
        assert.equal(String(d.tick), f.tick);
        // the grousers extension (fields.grousers): each entry's grousers, null for none
        assert.deepEqual(d.colliders, f.colliders.map((c) => ({
          id: c.id, owner: c.owner, kind: c.kind, dims: c.dims.map(Math.fround), p: c.p.map(Math.fround), q: c.q.map(Math.fround),
          ...(f.grousers ? { grousers: c.grousers && { count: c.grousers.count, height: Math.fround(c.grousers.height),
            thickness: Math.fround(c.grousers.thickness) } } : {}) })));
        break;
      case 'FOOTPRINTS':
        assert.equal(String(d.tick), f.tick);
        assert.deepEqual(d.footprints, f.footprints.map((e) => ({
          collider: e.collider, x: Math.fround(e.x), y: Math.fround(e.y), yaw: Math.fround(e.yaw),
          size_m: Math.fround(e.size_m), strength_m: Math.fround(e.strength_m) })));
        break;
      case 'FORCES':
        assert.equal(String(d.tick), f.tick);
        assert.deepEqual(d.forces, f.forces.map((e) => ({
          id: e.id, force: e.force.map(Math.fround), torque: e.torque.map(Math.fround),
          sinkage_m: Math.fround(e.sinkage_m), area_m2: Math.fround(e.area_m2),
          patch_width_m: Math.fround(e.patch_width_m), slip: Math.fround(e.slip), cells: e.cells })));
        break;
      case 'ACK':
        assert.equal(String(d.tick), f.tick);
        assert.equal(d.seq, f.seq);
        break;
      case 'STEP': {
        assert.deepEqual([d.seq, d.ticks], [f.seq, f.ticks]);
        const sets = [];
        for (let k = 0; k < f.sets; k++) sets.push(f.poses.slice(k * f.count, (k + 1) * f.count));
        assert.deepEqual(d.sets, sets.map((s) => s.map((p) => ({ id: p.id, x: Math.fround(p.x), y: Math.fround(p.y),
          z: Math.fround(p.z), qw: Math.fround(p.qw), qx: Math.fround(p.qx), qy: Math.fround(p.qy), qz: Math.fround(p.qz) }))));
        assert.equal(hex(C.encodeStep(f.seq, f.ticks, sets)), v.hex);
        break;
      }
      case 'STEPPED':
        assert.deepEqual([String(d.tick), d.seq, d.ticks], [f.tick, f.seq, f.ticks]);
        break;
      case 'CHECKSUM': {
        const tiles = f.tiles.map((t) => ({ ...t, hash: BigInt(t.hash) }));
        assert.deepEqual([String(d.tick), d.subscription, d.tiles], [f.tick, f.subscription, tiles]);
        assert.equal(hex(C.encodeChecksum(BigInt(f.tick), f.subscription, tiles)), v.hex);
        break;
      }
      default:
        assert.equal(String(d.nonce), f.nonce);
        assert.equal(d.type, C.MsgType[v.type]);
        assert.equal(hex(C.encodePing(BigInt(f.nonce), v.type === 'PONG')), v.hex);
    }
    for (let n = 0; n < buf.length; n++) assert.notEqual(errorName(() => decoders[v.type](buf.subarray(0, n))), '', `prefix ${n}`);
  });
}

test('tile hashes match the vectors; a mirror compares its tiles', () => {
  for (const e of V.hashes) assert.equal(String(C.heightsHash(Int32Array.from(e.heights), e.w, e.w, e.h)), e.hash, e.about);
  const m = new C.Mirror(30, 40, 100, 70, 64);
  for (let i = 0; i < 100 * 70; i++) m.heights[i] = i * 3;
  m.versions[4] = 5; // tile (1, 1): its part is region columns 34..97, rows 24..69
  const s = { tile_x: 1, tile_y: 1, version: 5, hash: C.heightsHash(m.heights, 100, 64, 46, 24 * 100 + 34) };
  assert.equal(m.tileDiffers(s), 0);
  m.heights[30 * 100 + 40] += 1;
  assert.equal(m.tileDiffers(s), 1, 'one height changed: the tile differs');
  assert.equal(m.tileDiffers({ ...s, tile_x: 0 }), 0, 'a tile not held is not compared');
  assert.equal(m.tileDiffers({ ...s, tile_x: 3 }), -1, 'a tile outside the region');
});

for (const [key, decompress] of [['base_rects', C.rectDecompressBase], ['slope_rects', C.rectDecompressSlope]]) {
  test(`${key}: at least 8 vectors`, () => assert.ok(V[key].length >= 8));
  for (const e of V[key]) {
    test(`${key}: ${e.about} (${e.error || 'valid'})`, () => {
      const got = () => decompress(unhex(e.data_hex), e.w, e.h, e.w * e.h);
      if (e.error) assert.equal(errorName(got), e.error);
      else assert.deepEqual(Array.from(got()), e.values);
    });
  }
}

test('a mirror adds the base back under a base snapshot; without a base it is bad_value', () => {
  const e = V.base_rects.find((x) => !x.error && x.w === 24 && x.h === 20); // the crater
  // a 24 x 20 rectangle of tile (1, 0) of 32-cell tiles; the region cuts it on the left and below
  const r = { x: 32, y: 0, w: 24, h: 20, base_version: 0, new_version: 7, encoding: C.Encoding.BASE, data: unhex(e.data_hex) };
  C.checkRect(r);
  assert.equal(errorName(() => C.checkRect({ ...r, base_version: 3 })), 'bad_value', 'a base snapshot with a base_version');
  const m = new C.Mirror(40, 0, 16, 20, 32); // columns 40..55: the tile's part in the region
  assert.equal(errorName(() => m.apply([r])), 'bad_value', 'no base: refused');
  assert.deepEqual(Array.from(m.versions), [0]);
  m.base = Int32Array.from({ length: 16 * 20 }, (_, i) => 4000 + 3 * i - (i % 7) * 1000);
  assert.equal(m.apply([r]), 16 * 20);
  assert.deepEqual(Array.from(m.versions), [7]);
  for (let y = 0; y < 20; y++)
    for (let x = 0; x < 16; x++)
      assert.equal(m.heights[y * 16 + x], (m.base[y * 16 + x] + e.values[y * 24 + x + 8]) | 0, `cell ${x}, ${y}`);
  assert.deepEqual(C.hello('', 'x', '', -1, true), { type: 'hello', protocol: 1, token: '', client: 'x', snapshot_base: true });
  assert.deepEqual(C.hello('', 'x', '', -1, true, true), { type: 'hello', protocol: 1, token: '', client: 'x', snapshot_base: true, snapshot_slope: true });
  assert.deepEqual(C.hello('', 'x', '', -1, false, true), { type: 'hello', protocol: 1, token: '', client: 'x' }, 'slope only with base');
});

test('a mirror applies a slope snapshot (encoding 3) onto the base', () => {
  const e = V.slope_rects.find((x) => !x.error && x.w === 24 && x.h === 20); // the sand pile
  const r = { x: 32, y: 0, w: 24, h: 20, base_version: 0, new_version: 9, encoding: C.Encoding.BASE_SLOPE, data: unhex(e.data_hex) };
  C.checkRect(r);
  const m = new C.Mirror(40, 0, 16, 20, 32);
  assert.equal(errorName(() => m.apply([r])), 'bad_value', 'no base: refused');
  m.base = Int32Array.from({ length: 16 * 20 }, (_, i) => 4000 + 3 * i);
  assert.equal(m.apply([r]), 16 * 20);
  assert.deepEqual(Array.from(m.versions), [9]);
  for (let y = 0; y < 20; y++)
    for (let x = 0; x < 16; x++)
      assert.equal(m.heights[y * 16 + x], (m.base[y * 16 + x] + e.values[y * 24 + x + 8]) | 0, `cell ${x}, ${y}`);
});

test('zigzag edge values', () => {
  const cases = [[0, 0], [-1, 1], [1, 2], [2147483647, 0xfffffffe], [-2147483648, 0xffffffff]];
  for (const [d, u] of cases) {
    assert.equal(C.zigzag32(d), u);
    assert.equal(C.unzigzag32(u), d);
  }
});

for (const s of V.mirror_scenarios) {
  test(`mirror scenario ${s.name}`, () => {
    const m = new C.Mirror(s.region.x, s.region.y, s.region.w, s.region.h, s.tile_size);
    s.steps.forEach((st, i) => {
      const err = errorName(() => m.apply(C.decodeDelta(unhex(st.frame_hex)).rects));
      assert.equal(err, st.error, `step ${i}: ${st.about}`);
      assert.deepEqual(Array.from(m.heights), st.heights, `step ${i} heights: ${st.about}`);
      assert.deepEqual(Array.from(m.versions), st.versions, `step ${i} versions: ${st.about}`);
    });
  });
}

test('FORCES height extension (PROTOCOL.md "FORCES"): header flag 0x01, each entry 56 bytes ending in its f64 height', () => {
  const plain = unhex(V.vectors.find((v) => v.name === 'forces_two').hex);
  const count = C.decodeForces(plain).forces.length, heights = [0.4903, -1.25];
  const withHeights = (hs) => { // the vector's entries, each followed by its height
    const b = new Uint8Array(14 + 56 * count);
    b.set(plain.subarray(0, 14));
    b[3] = C.FORCES_FLAG_HEIGHT;
    for (let i = 0; i < count; i++) {
      b.set(plain.subarray(14 + 48 * i, 14 + 48 * (i + 1)), 14 + 56 * i);
      new DataView(b.buffer).setFloat64(14 + 56 * i + 48, hs[i], true);
    }
    return b;
  };
  const d = C.decodeForces(withHeights(heights));
  assert.deepEqual(d.forces.map((f) => f.height_m), heights);
  assert.deepEqual(d.forces.map(({ height_m, ...f }) => f), C.decodeForces(plain).forces);
  assert.ok(C.decodeForces(plain).forces.every((f) => !('height_m' in f)), 'no flag: no height_m');
  assert.equal(errorName(() => C.decodeForces(withHeights([NaN, 0]))), 'bad_value');
  assert.equal(errorName(() => C.decodeForces(withHeights(heights).subarray(0, 14 + 56 * count - 8))), 'bad_frame');
  const other = withHeights(heights);
  other[3] = 0x02;
  assert.equal(errorName(() => C.decodeForces(other)), 'bad_frame', 'a flag FORCES does not define');
  const ack = unhex(V.vectors.find((v) => v.type === 'ACK' && v.valid).hex);
  ack[3] = C.FORCES_FLAG_HEIGHT;
  assert.equal(errorName(() => C.decodeAck(ack)), 'bad_frame', 'the flag belongs to FORCES only');
  assert.deepEqual(C.colliderCreate('wheel', { radius: 0.1, width: 0.08 }, { loadN: 40, forcesHeight: true }),
    { type: 'collider_create', shape: 'wheel', material: 'default', feedback: true, radius: 0.1, width: 0.08, load_n: 40, forces_height: true });
});

test('control messages', () => {
  assert.deepEqual(C.hello('', 'x'), { type: 'hello', protocol: 1, token: '', client: 'x' });
  assert.deepEqual(C.hello('t', 'x', 'match-1'), { type: 'hello', protocol: 1, token: 't', client: 'x', world: 'match-1' });
  assert.deepEqual(C.subscribe(1, 2, 3, 4), { type: 'subscribe', x: 1, y: 2, w: 3, h: 4 });
  assert.deepEqual(C.colliderCreate('sphere', { radius: 0.3 }, { ref: 'a' }),
    { type: 'collider_create', shape: 'sphere', material: 'default', feedback: true, radius: 0.3, ref: 'a' });
  assert.deepEqual(C.edit('crater', { x: 4, y: 5, radius: 3, depth: 900, rim: false }, 'e1'),
    { type: 'edit', op: 'crater', x: 4, y: 5, radius: 3, depth: 900, rim: false, ref: 'e1' });
  assert.equal(C.stampData([1, -2, 0x7fffffff]), Buffer.from('01000000feffffffffffff7f', 'hex').toString('base64'));
  assert.equal(errorName(() => C.parseControl('[1]')), 'bad_json');
  assert.equal(C.parseControl('{"type":"world","x":1}').x, 1);
});

test('vendored fzstd equals the pinned npm copy', { skip: !existsSync(path.join(root, 'node_modules/fzstd')) && 'node_modules missing (npm ci)' }, () => {
  const lock = JSON.parse(readFileSync(path.join(root, 'package-lock.json'), 'utf8'));
  const pkg = JSON.parse(readFileSync(path.join(root, 'node_modules/fzstd/package.json'), 'utf8'));
  assert.equal(pkg.version, lock.packages['node_modules/fzstd'].version);
  assert.ok(readFileSync(path.join(root, 'web/vendor/fzstd.js')).equals(readFileSync(path.join(root, 'node_modules/fzstd/esm/index.mjs'))),
    'web/vendor/fzstd.js differs from node_modules/fzstd/esm/index.mjs: run scripts/vendor-web');
  assert.ok(readFileSync(path.join(root, 'web/vendor/fzstd.d.ts')).equals(readFileSync(path.join(root, 'node_modules/fzstd/lib/index.d.ts'))),
    'web/vendor/fzstd.d.ts (its types, for clients/js) differs from node_modules/fzstd/lib/index.d.ts: run scripts/vendor-web');
});
