#!/usr/bin/env node
// scripts/screenshot.mjs: a PNG of a running daemon's viewer, taken in headless Chromium.
//   node scripts/screenshot.mjs [--url URL] [--out FILE] [--size WxH] [--timeout S]
//   make screenshot [URL=...] [OUT=...]
// URL defaults to http://127.0.0.1:8080/ (make run's; the page asks the daemon for its websocket,
// add #token=tdk_... for a daemon with tokens), OUT to test-artifacts/screenshot.png, the size to
// 1280x800, each wait (page load, first snapshot drawn, capture) to 180 s: software WebGL
// on a busy machine draws a frame in seconds.
//
// Why not `chromium --headless --screenshot`: with --virtual-time-budget the page's websocket and
// animation frames never settle (it hangs), and without it the picture is taken before the
// snapshot arrives ("connecting"). This drives the page with playwright-core (make web-deps) in
// Debian's /usr/bin/chromium with a fresh profile, waits for the page's own condition
// (window.terrad.ready: connected, and a frame drawn from the world's snapshot against its base
// terrain; web/viewer.mjs), lets two more frames draw, holds the last one (window.terrad.hold)
// and takes the picture.
// Exit status 0 with one line on stdout naming the file, else 1 with the reason on stderr.
import { mkdtempSync, mkdirSync, rmSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';

const CHROMIUM = '/usr/bin/chromium';
// Software GL (SwiftShader) for WebGL2 without a GPU; no network, updates or first-run screens.
const FLAGS = ['--no-sandbox', '--disable-gpu', '--enable-unsafe-swiftshader', '--disable-background-networking',
  '--disable-component-update', '--disable-sync', '--no-first-run'];

function usage(msg) {
  if (msg) console.error(`screenshot: ${msg}`);
  console.error('usage: node scripts/screenshot.mjs [--url URL] [--out FILE] [--size WxH] [--timeout SECONDS]');
  process.exit(msg ? 2 : 0);
}

const opt = { url: 'http://127.0.0.1:8080/', out: 'test-artifacts/screenshot.png', width: 1280, height: 800, timeout: 180 };
const argv = process.argv.slice(2);
for (let i = 0; i < argv.length; i++) {
  const a = argv[i], v = argv[i + 1];
  if (a === '-h' || a === '--help') usage();
  if (v === undefined) usage(`${a} needs a value`);
  i++;
  if (a === '--url') opt.url = v;
  else if (a === '--out') opt.out = v;
  else if (a === '--size') {
    const m = /^(\d+)x(\d+)$/.exec(v);
    if (!m || +m[1] < 16 || +m[2] < 16 || +m[1] > 8192 || +m[2] > 8192) usage(`--size: '${v}' is not WxH (16..8192)`);
    opt.width = +m[1];
    opt.height = +m[2];
  } else if (a === '--timeout') {
    if (!(+v > 0)) usage(`--timeout: '${v}' is not a positive number of seconds`);
    opt.timeout = +v;
  } else usage(`unknown option '${a}'`);
}
if (!existsSync(CHROMIUM)) {
  console.error(`screenshot: ${CHROMIUM} missing (scripts/deps --test installs chromium)`);
  process.exit(1);
}
let chromium;
try {
  ({ chromium } = await import('playwright-core'));
} catch {
  console.error('screenshot: playwright-core missing (make web-deps)');
  process.exit(1);
}

const profile = mkdtempSync(path.join(tmpdir(), 'terrad-screenshot-profile-'));
let context, status = 1;
try {
  context = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM, headless: true, args: FLAGS,
    viewport: { width: opt.width, height: opt.height }, deviceScaleFactor: 1,
  });
  const page = context.pages()[0] || (await context.newPage());
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  try {
    await page.goto(opt.url, { timeout: opt.timeout * 1000 });
  } catch (e) {
    throw new Error(`cannot load ${opt.url} (is the daemon running there?): ${e.message.split('\n')[0]}`);
  }
  try {
    await page.waitForFunction(() => window.terrad && window.terrad.ready, null,
      { timeout: opt.timeout * 1000, polling: 100 });
  } catch {
    const state = await page.evaluate(() => (window.terrad ? window.terrad.state : 'no viewer on this page')).catch(() => '?');
    throw new Error(`the viewer at ${opt.url} did not show the terrain within ${opt.timeout} s ` +
      `(its state: ${state}${errors.length ? `; page errors: ${errors.join('; ')}` : ''})`);
  }
  // Two more frames, so the picture has the overlay's figures and the newest deltas.
  const drawn = await page.evaluate(() => window.terrad.framesDrawn);
  await page.waitForFunction((n) => window.terrad.framesDrawn >= n + 2, drawn, { timeout: opt.timeout * 1000 });
  // Hold that frame: under software GL a page that keeps drawing makes the capture wait behind it.
  const tick = await page.evaluate(() => { window.terrad.hold(true); return window.terrad.tick; });
  mkdirSync(path.dirname(path.resolve(opt.out)), { recursive: true });
  await page.screenshot({ path: opt.out, timeout: opt.timeout * 1000 });
  console.log(`screenshot: ${opt.out} (${opt.width}x${opt.height}) of ${opt.url} at tick ${tick}`);
  status = 0;
} catch (e) {
  console.error(`screenshot: ${e.message.split('\n')[0]}`);
} finally {
  if (context) await context.close().catch(() => {});
  rmSync(profile, { recursive: true, force: true });
}
process.exit(status);
