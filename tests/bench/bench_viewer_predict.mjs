// bench_viewer_predict.mjs: key-to-visible latency of the viewer's own rut, with and without
// prediction (web/viewer_predict.mjs), in headless Chromium against the real daemon, the page's
// websocket through tests/support/tcp_relay.mjs delaying each direction by DELAY_MS (an RTT of
// 2 * DELAY_MS on loopback). Each trial moves the page's sphere 0.4 m onto untouched ground in
// one batch (window.terrad.drive) and counts the frames and ms until a drawn frame shows the
// cell under its new centre lower than before. Then, per mode, STEADY_S seconds of driving a
// small step every frame: the prediction's own ms per drawn frame (ViewerPrediction's cost
// counters: the twin's tick per batch, the reconciliation per ACK, pasting the sub-window into
// the drawn heights) and the bytes the relay carried each way per second and per pose batch
// (prediction sends nothing, so the bytes per batch are the same in both modes). Prints one JSON
// line; bench_viewer_predict.py runs it for make bench. Never fails on a figure.
//
// Usage: node bench_viewer_predict.mjs [DELAY_MS] [TRIALS]
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { haveBrowser, launchPage, sleep, startDaemon, stopDaemon, until } from '../support/browser.mjs';
import { startRelay } from '../support/tcp_relay.mjs';

const DELAY_MS = Number(process.argv[2] ?? 50), TRIALS = Number(process.argv[3] ?? 8);
const WAIT = 120000, STEADY_S = 4;
if (!haveBrowser) {
  console.log(JSON.stringify({ skipped: 'needs /usr/bin/chromium, node_modules/playwright-core and build/terrad' }));
  process.exit(0);
}
const SCENE = {
  name: 'bench-viewer-predict', world: { width: 192, height: 128, cell_size_m: 0.05 },
  terrain: { kind: 'flat', height_m: 0.4 }, colliders: [],
};
const dir = mkdtempSync(path.join(tmpdir(), 'terrad-bench-viewer-'));
writeFileSync(path.join(dir, 'scene.json'), JSON.stringify(SCENE));
const daemon = await startDaemon(0, 0, ['--scene', path.join(dir, 'scene.json')]);
const relay = await startRelay(daemon.ports.ws, { delayMs: DELAY_MS });
const browser = await launchPage({ width: 480, height: 320 });
const page = browser.page;
const out = { delay_ms_each_way: DELAY_MS, trials: TRIALS };
try {
  await page.goto(`http://127.0.0.1:${daemon.ports.http}/?ws=${relay.port}`);
  await until('the page shows the world', () => page.evaluate(() => window.terrad.ready), WAIT);
  await until('the twin', () => page.evaluate(() => window.terrad.prediction.available), WAIT);
  await page.click('#drive');
  await until('the page\'s collider', () => page.evaluate(() => window.terrad.collider && window.terrad.collider.id), WAIT);
  for (const [mode, row] of [['prediction', 2.0], ['server only', 4.4]]) {
    const want = mode === 'prediction';
    if ((await page.evaluate(() => window.terrad.prediction.enabled)) !== want) await page.click('#predict');
    // lifted to the row's start, then down and settled
    await page.evaluate(([row]) => {
      const t = window.terrad, c = t.collider;
      t.lift();
      t.drive(1.2 - c.x, row - c.y);
    }, [row]);
    await sleep(500);
    await page.evaluate(() => window.terrad.lower());
    if (want) await until('the prediction runs', () => page.evaluate(() => window.terrad.prediction.active), WAIT);
    await sleep(1000);
    const runs = [];
    for (let i = 0; i < TRIALS; i++) {
      runs.push(await page.evaluate(async ([dx, limit]) => {
        const t = window.terrad, c = t.collider, x = c.x + dx, y = c.y;
        const before = t.drawnAt(x, y), f0 = t.framesDrawn, t0 = performance.now();
        t.drive(dx, 0);
        for (;;) {
          await new Promise((r) => requestAnimationFrame(r));
          if (t.drawnAt(x, y) < before - 50) return { ms: performance.now() - t0, frames: t.framesDrawn - f0 };
          if (performance.now() - t0 > limit) return { ms: null, frames: null };
        }
      }, [0.4, 10000]));
      await sleep(400);
    }
    const ok = runs.filter((r) => r.ms !== null);
    const median = (a) => { const s = [...a].sort((p, q) => p - q); return s.length ? s[s.length >> 1] : null; };
    out[mode] = { median_ms: median(ok.map((r) => r.ms)), median_frames: median(ok.map((r) => r.frames)),
      seen: ok.length, runs: runs.map((r) => r.ms === null ? null : Math.round(r.ms)) };
    // Steady driving: 0.01 m a frame along x, a pose batch each frame, as a held key does.
    const up0 = relay.bytes.up, down0 = relay.bytes.down;
    const steady = await page.evaluate(async (seconds) => {
      const t = window.terrad, c0 = t.prediction.cost, f0 = t.framesDrawn, t0 = performance.now();
      let batches = 0;
      while (performance.now() - t0 < seconds * 1000) {
        t.drive(0.01, 0);
        batches++;
        await new Promise((r) => requestAnimationFrame(r));
      }
      const c1 = t.prediction.cost, frames = t.framesDrawn - f0, s = (performance.now() - t0) / 1000;
      const d = (k) => c1[k] - c0[k];
      return { seconds: s, frames, batches, ms_per_frame: frames ? (d('sendMs') + d('ackMs') + d('pasteMs')) / frames : null,
        ms_per_send: d('sends') ? d('sendMs') / d('sends') : null, ms_per_ack: d('acks') ? d('ackMs') / d('acks') : null,
        ms_per_paste: d('pastes') ? d('pasteMs') / d('pastes') : null };
    }, STEADY_S);
    const up = relay.bytes.up - up0, down = relay.bytes.down - down0;
    out[mode].steady = { ...steady, up_bytes_per_s: up / steady.seconds, down_bytes_per_s: down / steady.seconds,
      up_bytes_per_batch: up / steady.batches, down_bytes_per_batch: down / steady.batches };
  }
} finally {
  await browser.close();
  await relay.close();
  await stopDaemon(daemon);
  rmSync(dir, { recursive: true, force: true });
}
console.log(JSON.stringify(out));
