// browser.mjs: what the browser tests share (tests/web/*.mjs): the daemon on loopback ports it
// picks itself, headless Chromium (playwright-core, /usr/bin/chromium) with the flags
// docs/notes/toolchain.md gives for software GL, and a wait by condition.
import { spawn } from 'node:child_process';
import { mkdtempSync, rmSync, existsSync } from 'node:fs';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

export const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
export const BIN = process.env.TERRAD_BIN || path.join(root, 'build/terrad');
export const CHROMIUM = '/usr/bin/chromium';
export const FLAGS = ['--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run', '--disable-background-networking',
  '--disable-component-update', '--disable-sync', '--enable-unsafe-swiftshader'];
export const haveBrowser = existsSync(CHROMIUM) && existsSync(path.join(root, 'node_modules/playwright-core')) && existsSync(BIN);

export const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
export async function until(what, fn, ms = 15000, step = 100) {
  const end = Date.now() + ms;
  let last;
  for (;;) {
    last = await fn();
    if (last) return last;
    if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
    await sleep(step);
  }
}

export function startDaemon(httpPort = 0, wsPort = 0, extra = []) {
  const dataDir = mkdtempSync(path.join(tmpdir(), 'terrad-viewer-data-'));
  const args = ['serve', '--http-port', String(httpPort), '--ws-port', String(wsPort), '--backend', 'cpu', '--no-demo', '--durability', 'none', ...extra];
  const proc = spawn(BIN, args, { stdio: ['ignore', 'ignore', 'pipe'], cwd: dataDir });
  let err = '';
  return new Promise((resolve, reject) => {
    const t = setTimeout(() => reject(new Error(`daemon did not start: ${err}`)), 60000);
    proc.stderr.on('data', (d) => {
      err += d;
      const m = /http:\/\/127\.0\.0\.1:(\d+)\/ and ws:\/\/127\.0\.0\.1:(\d+)\//.exec(err);
      if (m && !proc.ports) {
        clearTimeout(t);
        proc.ports = { http: Number(m[1]), ws: Number(m[2]) };
        proc.dataDir = dataDir;
        resolve(proc);
      }
    });
    proc.on('exit', (code) => { clearTimeout(t); if (!proc.ports) reject(new Error(`daemon exited ${code}: ${err}`)); });
  });
}

export async function stopDaemon(proc) {
  if (!proc || proc.exitCode !== null || proc.signalCode) return;
  const gone = new Promise((r) => proc.once('exit', r));
  proc.kill('SIGTERM');
  const t = setTimeout(() => proc.kill('SIGKILL'), 5000);
  await gone;
  clearTimeout(t);
  rmSync(proc.dataDir, { recursive: true, force: true });
}

// Headless Chromium with a fresh profile: {context, page, close()}. Its actions (click, mouse,
// keyboard, screenshot) wait up to 3 minutes, not playwright's 30 s: under software GL on a busy
// 2-core machine a page that keeps drawing can hold an input event that long (a click in
// make test-stress once waited past 30 s), and a deadline here is a condition, not a speed.
export async function launchPage(viewport = { width: 720, height: 480 }) {
  const { chromium } = await import('playwright-core');
  const profile = mkdtempSync(path.join(tmpdir(), 'terrad-viewer-profile-'));
  const context = await chromium.launchPersistentContext(profile, {
    executablePath: CHROMIUM, headless: true, args: FLAGS, viewport, deviceScaleFactor: 1,
  });
  context.setDefaultTimeout(180000);
  const page = context.pages()[0] || (await context.newPage());
  page.on('pageerror', (e) => console.error('page error:', e.message));
  return {
    context, page, profile,
    async close() {
      await context.close();
      rmSync(profile, { recursive: true, force: true });
    },
  };
}
