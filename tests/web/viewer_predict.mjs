// The viewer's prediction (issue 23, web/viewer_predict.mjs) in real headless Chromium against
// the real daemon on loopback, the page's websocket through a TCP relay (tests/support/
// tcp_relay.mjs) that can hold every byte from the server: while it holds, no ACK and no DELTA
// can reach the page, so a rut the page draws then is its own prediction. Checked:
// - prediction on: the frame after a move draws the rut before the server's answer (cells drawn
//   lower than the mirror, with the batch unacknowledged); once the answers flow, every
//   compared ACK's replay equals the server's heights (0 cells differ), the drawn heights settle
//   on the mirror and the mirror equals GET /v1/heights;
// - the toggle off: the same move draws the mirror only, until the server's deltas arrive;
// - a daemon without a twin config for its world (/v1/twin 404) leaves the toggle disabled,
//   saying why, and the page goes on.
// Run by tests/integration/web/test_viewer_predict.sh (node --test); its own file, not *.test.mjs,
// so the viewer's suite (test_viewer.sh) does not run it twice.
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { haveBrowser, launchPage, root, startDaemon, stopDaemon, until } from '../support/browser.mjs';
import { startRelay } from '../support/tcp_relay.mjs';

const skip = !haveBrowser && 'needs /usr/bin/chromium, node_modules/playwright-core and the terrad binary';
const WAIT = 120000; // generous: software GL on a loaded 2-core machine
const SCENE = {
  name: 'viewer-predict', world: { width: 192, height: 128, cell_size_m: 0.05 },
  terrain: { kind: 'dunes', min_height_m: 0.35, max_height_m: 0.45, wavelength_m: 4, octaves: 3, seed: 7 },
  material: { roughness: 0.4, repose_deg: 30 }, colliders: [],
};

let daemon, relay, browser, page, dir;

before(async () => {
  if (skip) return;
  dir = mkdtempSync(path.join(tmpdir(), 'terrad-viewer-predict-'));
  const scene = path.join(dir, 'scene.json');
  writeFileSync(scene, JSON.stringify(SCENE));
  daemon = await startDaemon(0, 0, ['--scene', scene]);
  relay = await startRelay(daemon.ports.ws);
  browser = await launchPage({ width: 480, height: 320 });
  page = browser.page;
  await page.goto(`http://127.0.0.1:${daemon.ports.http}/?budget=0&ws=${relay.port}`);
});

after(async () => {
  if (relay) relay.hold('down', false);
  if (browser) await browser.close();
  if (relay) await relay.close();
  await stopDaemon(daemon);
  if (dir) rmSync(dir, { recursive: true, force: true });
});

const stats = () => page.evaluate(() => window.terrad.prediction);
// Drive the page's collider n steps of dx metres, one batch each, ~60 a second.
const drive = (n, dx) => page.evaluate(async ([n, dx]) => {
  for (let i = 0; i < n; i++) {
    window.terrad.drive(dx, 0);
    await new Promise((r) => setTimeout(r, 16));
  }
  return window.terrad.seq - 1;
}, [n, dx]);
// Cells the page would draw now that differ from its mirror, and how many are lower.
const versusMirror = () => page.evaluate(() => {
  const s = window.terrad.shown, m = window.terrad.heights;
  let lower = 0, differ = 0;
  for (let i = 0; i < m.length; i++) {
    if (s[i] !== m[i]) differ++;
    if (s[i] < m[i]) lower++;
  }
  return { lower, differ };
});
// A frame drawn after now that uploaded heights: {frame, seq, ackedSeq, lower}.
async function nextDrawn(seq) {
  return until('a frame with the batch', async () => {
    const d = await page.evaluate(() => window.terrad.drawn);
    return d.seq >= seq && d;
  }, WAIT);
}

async function serverHeights() {
  const r = await page.evaluate(() => window.terrad.region);
  const res = await fetch(`http://127.0.0.1:${daemon.ports.http}/v1/heights?x=${r.x}&y=${r.y}&w=${r.w}&h=${r.h}`);
  const b = Buffer.from(await res.arrayBuffer());
  return Array.from({ length: r.w * r.h }, (_, i) => b.readInt32LE(4 * i));
}

test('driving, the page draws its own rut before the server has answered; every ACK reconciles exactly', { skip, timeout: 300000 }, async () => {
  await until('the page shows the world', () => page.evaluate(() => window.terrad.ready), WAIT);
  await until('the twin and the world\'s parameters', async () => (await stats()).available, WAIT);
  assert.equal(await page.textContent('#predict'), 'predict: on', 'prediction is on by default');
  await page.click('#drive');
  await until('the page\'s collider', () => page.evaluate(() => window.terrad.collider && window.terrad.collider.id), WAIT);
  await until('the prediction runs', async () => (await stats()).active, WAIT);
  const first = (await stats()).window;

  relay.hold('down', true); // from here no ACK and no DELTA reaches the page
  // ACKs already on their way may still land; none of a batch sent from here on can
  const from = await page.evaluate(() => window.terrad.seq);
  const seq = await drive(20, 0.05); // a metre, onto cells the sphere has not pressed
  const now = await versusMirror();
  assert.ok(now.lower > 0, `the rut is in the page's heights at once (${now.lower} cells lower than the mirror)`);
  const drawn = await nextDrawn(seq);
  assert.ok(drawn.lower > 0, `a frame drew it (${JSON.stringify(drawn)})`);
  assert.ok(drawn.ackedSeq < from, `before any ACK of those batches arrived (${drawn.ackedSeq} < ${from})`);
  relay.hold('down', false);

  // Answers flowing again: more driving, reconciled at every ACK.
  const last = await drive(60, 0.03); // past the sub-window's edge: it re-centres on the way
  await until('the ACK of the last batch', () => page.evaluate((s) => window.terrad.ackedSeq >= s, last), WAIT);
  // A slow page's ACKs that acknowledge several batches after a gap are not compared (which tick
  // took which is unknown: predict.mjs): drive on, back and forth, until 10 were compared.
  for (let k = 0; (await stats()).replayed < 10; k++) {
    if (k > 200) assert.fail(`fewer than 10 ACKs compared: ${JSON.stringify(await stats())}`);
    const s = await drive(10, k % 2 ? -0.01 : 0.01);
    await until('its ACK', () => page.evaluate((q) => window.terrad.ackedSeq >= q, s), WAIT);
  }
  await page.evaluate(() => window.terrad.lift());
  const s = await stats();
  assert.ok(s.window.x > first.x, `the sub-window followed the collider (${JSON.stringify(first)} -> ${JSON.stringify(s.window)})`);
  assert.ok(s.replayed >= 10 && s.exact === s.replayed,
    `every compared ACK: the page's replay equals the server in every cell (${s.exact} of ${s.replayed}; ${s.skipped} not compared)`);
  // Lifted, nothing of the page presses: the drawn heights are the server's.
  await until('the drawn heights equal the mirror', async () => (await versusMirror()).differ === 0, WAIT, 200);
  await until('the mirror equals GET /v1/heights', async () => {
    const [mine, server] = [await page.evaluate(() => Array.from(window.terrad.heights)), await serverHeights()];
    return mine.length === server.length && mine.every((v, i) => v === server[i]);
  }, WAIT, 300);
  const errors = await page.textContent('#o-error');
  assert.equal(errors, '', 'no server errors');
});

test('the toggle off shows only the server\'s heights: the rut after its deltas', { skip, timeout: 300000 }, async () => {
  await page.click('#predict');
  assert.equal(await page.textContent('#predict'), 'predict: off');
  await page.evaluate(() => window.terrad.lower());
  await until('prediction stops', async () => !(await stats()).active, WAIT);
  const before = await page.evaluate(() => Array.from(window.terrad.heights));
  relay.hold('down', true);
  const seq = await drive(20, -0.05);
  const drawn = await nextDrawn(seq);
  assert.equal(drawn.lower, 0, `no rut drawn before the server's answer (${JSON.stringify(drawn)})`);
  assert.equal((await versusMirror()).differ, 0, 'the page draws its mirror');
  relay.hold('down', false);
  await until('the server\'s rut arrives', () => page.evaluate((b) => {
    const m = window.terrad.heights;
    let lower = 0;
    for (let i = 0; i < m.length; i++) if (m[i] < b[i]) lower++;
    return lower > 0;
  }, before), WAIT);
  await page.click('#predict');
  assert.equal(await page.textContent('#predict'), 'predict: on');
  await until('prediction runs again', async () => (await stats()).active, WAIT);
});

test('a world the twin does not take: the toggle is disabled, says why, and the page goes on', { skip, timeout: 300000 }, async () => {
  // per-cell materials: GET /v1/twin answers 404 naming them
  const other = await startDaemon(0, 0, ['--scene', path.join(root, 'tests/scenes/materials-mixed.json')]);
  const second = { page: await browser.context.newPage() };
  second.close = () => second.page.close();
  try {
    const res = await fetch(`http://127.0.0.1:${other.ports.http}/v1/twin`);
    const body = await res.json();
    assert.equal(res.status, 404);
    assert.match(body.error, /per-cell materials/);
    await second.page.goto(`http://127.0.0.1:${other.ports.http}/?budget=0&ws=${other.ports.ws}`);
    await until('the page shows the world', () => second.page.evaluate(() => window.terrad.ready), WAIT);
    await until('the page gave up on prediction', () => second.page.evaluate(() => window.terrad.prediction.reason !== 'loading'), WAIT);
    assert.equal(await second.page.isDisabled('#predict'), true, 'the toggle is disabled');
    assert.match(await second.page.getAttribute('#predict', 'title'), /per-cell materials/, 'its title says why');
    await second.page.click('#drive');
    await until('the page drives without it', () => second.page.evaluate(() => window.terrad.collider && window.terrad.collider.id), WAIT);
    assert.equal((await second.page.evaluate(() => window.terrad.prediction)).active, false);
  } finally {
    await second.close();
    await stopDaemon(other);
  }
});
