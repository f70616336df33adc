// Base snapshots in the viewer (PROTOCOL.md "Base snapshots", issue 32 item 2), in real
// headless Chromium against the real daemon on loopback: worlds dug by craters (HTTP edits)
// before the page loads, so the page is a late joiner. With the twin (GET /terrad_twin.wasm) the
// page asks for base snapshots, rebuilds the scene's base under its window on the twin and is
// sent only the digging (encoding 2); checked, each against GET /v1/heights cell for cell:
// - a world wider than the viewer's whole-world limit: its 1024-cell window around the camera
//   target cuts tiles on the left and right; then more craters, and the window again;
// - a world small enough to be shown whole, one of its tiles stamped to a sand pile at its slope
//   limits (PROTOCOL.md "Slope snapshots"; the page offers them with base snapshots): the whole
//   world, that tile in encoding 3, then more craters, again;
// - the same page when the twin cannot be loaded (its fetch answered 404, as from a daemon built
//   without the WebAssembly toolchain): plain snapshots (encoding 1), and the heights are exact.
// Without the decoding the page cannot read the encoding 2 rectangles its hello asked for (the
// frames are refused as bad_value), its window never completes and the wait for it times out;
// with the base not added back the heights differ from GET /v1/heights.
// Run by tests/integration/web/test_viewer_base.sh (node --test); its own file, not *.test.mjs,
// so the viewer's suite (test_viewer.sh) does not run it twice.
import { test, after } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { haveBrowser, launchPage, startDaemon, stopDaemon, until } from '../support/browser.mjs';

const skip = !haveBrowser && 'needs /usr/bin/chromium, node_modules/playwright-core and the terrad binary';
const WAIT = 300000; // generous: software GL on a loaded 2-core machine
const scene = (name, width, height, seed) => ({
  name, world: { width, height, cell_size_m: 0.05 },
  terrain: { kind: 'dunes', min_height_m: 0.3, max_height_m: 0.5, wavelength_m: 4, octaves: 3, seed },
  colliders: [],
});
const cleanup = [];
after(async () => {
  for (const f of cleanup.reverse()) await f();
});

async function daemonWith(s) {
  const dir = mkdtempSync(path.join(tmpdir(), 'terrad-viewer-base-'));
  cleanup.push(() => rmSync(dir, { recursive: true, force: true }));
  writeFileSync(path.join(dir, 'scene.json'), JSON.stringify(s));
  const d = await startDaemon(0, 0, ['--scene', path.join(dir, 'scene.json')]);
  cleanup.push(() => stopDaemon(d));
  d.http = `http://127.0.0.1:${d.ports.http}`;
  d.page = `${d.http}/?ws=${d.ports.ws}`;
  return d;
}

// n craters by the HTTP edit, each answered once its tick is durable.
async function craters(d, s, seed, n) {
  for (let i = 0; i < n; i++) {
    const k = seed * 1000 + i;
    const body = { op: 'crater', x: (k * 37) % s.world.width, y: (k * 91) % s.world.height, radius: 3 + (k % 12), depth: 300 + ((k * 53) % 1800) };
    const res = await fetch(`${d.http}/v1/worlds/${s.name}/edits`, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
    assert.equal(res.status, 200, `crater ${i}: ${await res.text()}`);
  }
}

// Tile (1, 1) stamped to its base plus a sand pile: the lowest of cones 300 units a cell steep
// axially, 420 diagonally (under the slope stage's thresholds, so it stays), from seeded apexes,
// so almost every cell sits at a bound of its neighbours — encoding 3's case (as
// test_join_base.py's stamp_pile).
async function stampPile(d, s) {
  const [x0, y0, w, h] = [64, 64, 64, 64];
  const b = Buffer.from(await (await fetch(`${d.http}/v1/heights?x=${x0}&y=${y0}&w=${w}&h=${h}&base=1`)).arrayBuffer());
  assert.equal(b.length, 4 * w * h, "the pile's base");
  const apexes = Array.from({ length: 9 }, (_, k) => [(k * 29) % w, (k * 47) % h, -600 + ((k * 173) % 500)]);
  const data = Buffer.alloc(4 * w * h);
  for (let y = 0; y < h; y++) {
    for (let x = 0; x < w; x++) {
      const z = Math.min(...apexes.map(([ax, ay, c]) => {
        const [dx, dy] = [Math.abs(x - ax), Math.abs(y - ay)];
        return c + 300 * (Math.max(dx, dy) - Math.min(dx, dy)) + 420 * Math.min(dx, dy);
      }));
      data.writeInt32LE(b.readInt32LE(4 * (y * w + x)) + z, 4 * (y * w + x));
    }
  }
  const body = { op: 'stamp', x: x0, y: y0, w, h, data: data.toString('base64') };
  const res = await fetch(`${d.http}/v1/worlds/${s.name}/edits`, { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
  assert.equal(res.status, 200, `the pile's stamp: ${await res.text()}`);
}

async function serverHeights(d, r) {
  const b = Buffer.from(await (await fetch(`${d.http}/v1/heights?x=${r.x}&y=${r.y}&w=${r.w}&h=${r.h}`)).arrayBuffer());
  return Array.from({ length: r.w * r.h }, (_, i) => b.readInt32LE(4 * i));
}

// Waits until the page's heights equal GET /v1/heights of its window (asked again each time:
// the deltas of the last edits may still be on their way); returns the window.
async function exact(page, d, what) {
  const r = await until(`${what}: the page holding its window`, () => page.evaluate(() => window.terrad.ready && window.terrad.region), WAIT);
  let differing = -1;
  await until(`${what}: the page's heights equal GET /v1/heights`, async () => {
    const want = await serverHeights(d, r);
    differing = await page.evaluate((w) => {
      const h = window.terrad.heights;
      return h.length === w.length ? h.reduce((n, v, i) => n + (v !== w[i]), 0) : -1;
    }, want);
    return differing === 0;
  }, WAIT, 500).catch((e) => assert.fail(`${e.message} (${differing} cells differ)`));
  return r;
}

test('the viewer joins dug worlds with base snapshots: a cut window and the whole world are exact, also after more digging; without the twin, plain snapshots', { skip, timeout: 1500000 }, async () => {
  const b = await launchPage({ width: 480, height: 320 });
  cleanup.push(() => b.close());
  const { page } = b;
  page.on('console', (m) => { if (/base|twin|mirror|refused/.test(m.text())) console.log('page:', m.text()); });

  const wide = scene('viewer-base-wide', 1100, 300, 11); // 330,000 cells: more than the viewer shows whole
  const dw = await daemonWith(wide);
  await craters(dw, wide, 1, 40);
  await page.goto(dw.page);
  let r = await exact(page, dw, 'wide world');
  assert.equal(r.w, 1024, `a 1024-cell window (${JSON.stringify(r)})`);
  assert.ok(r.x % 64 !== 0 && (r.x + r.w) % 64 !== 0, `the window cuts tiles on both sides (${JSON.stringify(r)})`);
  let s = await page.evaluate(() => window.terrad.snapshots);
  assert.ok(s.asked && s.agreed && s.base > 0 && s.absolute === 0, `base snapshots only (${JSON.stringify(s)})`);
  await craters(dw, wide, 2, 30); // deltas go on from the snapshots' versions
  await exact(page, dw, 'wide world after more craters');

  const whole = scene('viewer-base-whole', 320, 200, 12);
  const dh = await daemonWith(whole);
  await craters(dh, whole, 3, 40);
  await stampPile(dh, whole);
  await page.goto(dh.page);
  r = await exact(page, dh, 'whole world');
  assert.deepEqual(r, { x: 0, y: 0, w: 320, h: 200 }, 'the whole world');
  s = await page.evaluate(() => window.terrad.snapshots);
  assert.ok(s.asked && s.agreed && s.base > 0 && s.absolute === 0, `base snapshots only (${JSON.stringify(s)})`);
  assert.ok(s.agreedSlope && s.slope > 0, `the sand pile's tile in slope snapshots (${JSON.stringify(s)})`);
  await craters(dh, whole, 4, 30);
  await exact(page, dh, 'whole world after more craters');

  // The twin cannot be loaded: the page does not ask, and plain snapshots are exact too.
  await page.route('**/terrad_twin.wasm', (route) => route.fulfill({ status: 404, body: 'no twin' }));
  await page.goto(dh.page);
  await exact(page, dh, 'whole world without the twin');
  s = await page.evaluate(() => window.terrad.snapshots);
  assert.ok(!s.asked && !s.agreed && s.base === 0 && s.absolute > 0, `plain snapshots only (${JSON.stringify(s)})`);
});
