// The viewer repairs a desync by itself (PROTOCOL.md "CHECKSUM", issue 32 item 4), in real
// headless Chromium against the real daemon on loopback (no demo actors: the terrain holds
// still, so the page's heights can be compared with GET /v1/heights at any tick): once the page
// holds its window and two CHECKSUM frames found nothing, one height of its mirror is changed
// on purpose (window.terrad.heights is the mirror's own array); within a generous deadline the
// page has found that one tile differing, asked for it alone and holds it again, two more
// CHECKSUM frames find nothing, the status table says so, and its heights equal GET /v1/heights.
// Without the checksums the wait for the differing tile times out and the heights keep the
// changed cell.
import { test, after } from 'node:test';
import assert from 'node:assert/strict';
import { haveBrowser, launchPage, startDaemon, stopDaemon, until } from '../support/browser.mjs';

const skip = !haveBrowser && 'needs /usr/bin/chromium, node_modules/playwright-core and the terrad binary';
const cleanup = [];
after(async () => {
  for (const f of cleanup.reverse()) await f();
});

test('a corrupted mirror is found by a CHECKSUM and repaired tile by tile', { skip, timeout: 600000 }, async () => {
  const d = await startDaemon(0, 0, ['--no-data']);
  cleanup.push(() => stopDaemon(d));
  const b = await launchPage();
  cleanup.push(() => b.close());
  const { page } = b;
  await page.goto(`http://127.0.0.1:${d.ports.http}/?ws=${d.ports.ws}`);
  const T = 300000; // software GL on a loaded 2-core machine: generous
  await until('the page holding its window', () => page.evaluate(() => window.terrad.ready && !!window.terrad.region), T);
  const desync = () => page.evaluate(() => window.terrad.desync);
  let frames = (await desync()).checksumFrames;
  await until('two CHECKSUM frames', async () => (await desync()).checksumFrames >= frames + 2, T);
  assert.equal((await desync()).tilesDiffering, 0, 'a fresh mirror agrees with the server');
  const r = await page.evaluate(() => window.terrad.region);
  const buf = Buffer.from(await (await fetch(`http://127.0.0.1:${d.ports.http}/v1/heights?x=${r.x}&y=${r.y}&w=${r.w}&h=${r.h}`)).arrayBuffer());
  const server = Array.from({ length: r.w * r.h }, (_, i) => buf.readInt32LE(4 * i));
  // A page that falls behind (software GL under load) is resent its whole window by the slow
  // client path, which repairs the cell too: then change it again, up to five times, until a
  // CHECKSUM has found it. Drawing is held meanwhile (the mirror and the connection go on), so
  // that the page keeps up.
  await page.evaluate(() => window.terrad.hold(true));
  let repaired = -1;
  for (let attempt = 0; attempt < 5 && repaired < 0; attempt++) {
    const cell = Math.floor(r.h / 2) * r.w + Math.floor(r.w / 2) + 37 * attempt;
    const asked = (await desync()).tilesResynced;
    const changed = await page.evaluate((k) => (window.terrad.heights[k] += 11), cell); // behind the page's back
    assert.equal(changed, server[cell] + 11, 'the page holds a changed height');
    const t0 = Date.now();
    await until('the page\'s heights equal GET /v1/heights again', () => page.evaluate((want) => {
      const h = window.terrad.heights;
      return h.length === want.length && h.every((v, i) => v === want[i]);
    }, server), T);
    if ((await desync()).tilesResynced > asked) repaired = Date.now() - t0;
    else console.log('repaired by a whole resync (the page fell behind): again');
  }
  assert.ok(repaired >= 0, 'a CHECKSUM found the changed tile and the page asked for it');
  frames = (await desync()).checksumFrames;
  await until('two more CHECKSUM frames', async () => (await desync()).checksumFrames >= frames + 2, T);
  const s = await desync();
  console.log(`repaired within ${repaired} ms; ${JSON.stringify({ ...s, checksumTick: String(s.checksumTick) })}`);
  assert.equal(s.tilesDiffering, s.tilesResynced, 'each tile found differing was asked for alone, then nothing');
  const shown = await page.evaluate(() => document.getElementById('o-desync').textContent);
  assert.match(shown, new RegExp(`${s.tilesResynced} tiles? repaired`), `the status table says so (${shown})`);
});
