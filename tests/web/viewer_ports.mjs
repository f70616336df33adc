// The viewer finds its websocket by asking the daemon (issue 28, item 2), in real headless
// Chromium against the real daemon: it used to guess the HTTP port + 1, so a daemon on ports
// that are not neighbours, or behind a proxy, showed "reconnecting…" at tick 0 forever.
//   - a daemon whose websocket port is not its HTTP port + 1: the page opened at the HTTP port
//     with no ?ws= draws the world live (frames arrive, the tick advances);
//   - the same page reached through a TCP relay on yet another port (the Host the browser used
//     is the relay's): live too, the websocket straight at the daemon's port;
//   - a daemon behind relays for both ports, told the public websocket URL (--public-ws-url):
//     the page's websocket goes through the websocket relay (its bytes counted), live;
//   - bad values of --public-ws-url and its config key are refused, naming them.
// Without the change the first three fail ("timed out waiting for the page live"), the last
// fails on an option the daemon does not know.
import { test, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { mkdtempSync, rmSync, writeFileSync } from 'node:fs';
import net from 'node:net';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { BIN, haveBrowser, launchPage, startDaemon, stopDaemon, until } from '../support/browser.mjs';
import { startRelay } from '../support/tcp_relay.mjs';

const skip = !haveBrowser && 'needs /usr/bin/chromium, node_modules/playwright-core and the terrad binary';
const cleanup = [];
after(async () => {
  for (const f of cleanup.reverse()) await f();
});

// A free loopback port (closed again: the daemon takes it a moment later).
function freePort() {
  return new Promise((resolve, reject) => {
    const s = net.createServer();
    s.once('error', reject);
    s.listen(0, '127.0.0.1', () => {
      const { port } = s.address();
      s.close(() => resolve(port));
    });
  });
}

// Two free ports that are not neighbours, HTTP first.
async function apartPorts() {
  for (;;) {
    const http = await freePort(), ws = await freePort();
    if (ws !== http + 1 && ws !== http && Math.abs(ws - http) > 1) return { http, ws };
  }
}

// A daemon with two demo actors (deltas every tick), on the given ports.
async function daemon(http, ws, extra = []) {
  const d = await startDaemon(http, ws, ['--demo-actors', '2', '--no-data', ...extra]);
  cleanup.push(() => stopDaemon(d));
  return d;
}

// Such a daemon on two free ports that are not neighbours; setup(ports) returns its extra
// arguments. A port found free may be taken by another process before the daemon binds it
// (a fresh clone's suite beside another once lost one so: "cannot listen ... (in use"); the
// daemon then exits, and new ports are tried.
async function daemonApart(setup = async () => []) {
  for (let attempt = 1; ; attempt++) {
    const ports = await apartPorts();
    const extra = await setup(ports);
    try {
      return { ports, d: await daemon(ports.http, ports.ws, extra) };
    } catch (e) {
      if (attempt >= 5 || !/in use/.test(String(e.message))) throw e;
    }
  }
}

// Open url in a fresh page and wait until it is drawn live: the snapshot drawn, frames
// arriving and the tick advancing. Returns the page's websocket URL.
async function assertLive(url) {
  const b = await launchPage();
  try {
    await b.page.goto(url);
    await until('the page live', () => b.page.evaluate(() => window.terrad && window.terrad.state === 'live' && window.terrad.framesDrawn > 2), 90000);
    const first = await b.page.evaluate(() => ({ tick: window.terrad.tick, frames: window.terrad.framesDrawn }));
    await until('the tick to advance', () => b.page.evaluate((t) => window.terrad.tick >= t + 10, first.tick), 60000);
    await until('more frames drawn', () => b.page.evaluate((n) => window.terrad.framesDrawn > n + 2, first.frames), 60000);
    assert.equal(await b.page.evaluate(() => window.terrad.state), 'live');
    return await b.page.evaluate(() => window.terrad.wsUrl);
  } finally {
    await b.close();
  }
}

async function websocketAnswer(port) {
  const r = await fetch(`http://127.0.0.1:${port}/v1/websocket`);
  assert.equal(r.status, 200);
  return r.json();
}

test('ports that are not neighbours, and through a relay on another port: live', { skip, timeout: 400000 }, async () => {
  const { ports, d } = await daemonApart();
  assert.deepEqual(d.ports, ports, 'the daemon took the ports it was given');
  const said = await websocketAnswer(ports.http);
  assert.deepEqual(said, { url: `ws://127.0.0.1:${ports.ws}/`, port: ports.ws, subprotocol: 'terrad.v1', from: 'host' });
  assert.equal(await assertLive(`http://127.0.0.1:${ports.http}/`), `ws://127.0.0.1:${ports.ws}/`);

  const relay = await startRelay(ports.http); // the page's own port is the relay's
  cleanup.push(() => relay.close());
  assert.notEqual(relay.port + 1, ports.ws);
  assert.equal(await assertLive(`http://127.0.0.1:${relay.port}/`), `ws://127.0.0.1:${ports.ws}/`);
  assert.ok(relay.bytes.down > 0, 'the page came through the relay');
});

test('behind relays for both ports, told the public websocket URL: live through them', { skip, timeout: 400000 }, async () => {
  let wsRelay;
  const { ports, d } = await daemonApart(async (p) => {
    const relay = await startRelay(p.ws); // what a proxy would be, on ports of its own
    cleanup.push(() => relay.close());
    wsRelay = relay;
    return ['--public-ws-url', `ws://127.0.0.1:${relay.port}/`];
  });
  const publicUrl = `ws://127.0.0.1:${wsRelay.port}/`;
  const httpRelay = await startRelay(d.ports.http);
  cleanup.push(() => httpRelay.close());
  const said = await websocketAnswer(httpRelay.port);
  assert.deepEqual(said, { url: publicUrl, port: ports.ws, subprotocol: 'terrad.v1', from: 'public_ws_url' });
  const before = wsRelay.bytes.down;
  assert.equal(await assertLive(`http://127.0.0.1:${httpRelay.port}/`), publicUrl);
  assert.ok(wsRelay.bytes.down > before + 10000, `the page's websocket went through the public URL (${wsRelay.bytes.down} bytes)`);
});

test('bad values of --public-ws-url and public_ws_url are refused, naming them', { skip }, () => {
  const dir = mkdtempSync(path.join(tmpdir(), 'terrad-ws-url-'));
  try {
    const run = (args) => spawnSync(BIN, ['serve', '--no-demo', '--no-data', '--http-port', '0', '--ws-port', '0', ...args],
      { cwd: dir, encoding: 'utf8', timeout: 30000 });
    for (const bad of ['http://127.0.0.1:9000/', 'ws://', 'ws://a b/', 'wss://host/"quote', `ws://${'h'.repeat(600)}/`]) {
      const r = run(['--public-ws-url', bad]);
      assert.notEqual(r.status, 0, `${bad} refused`);
      assert.match(r.stderr, /--public-ws-url: /, `the refusal of ${bad} names the option: ${r.stderr}`);
    }
    for (const bad of [5, 'tcp://x/', '']) {
      const file = path.join(dir, 'c.json');
      writeFileSync(file, JSON.stringify({ public_ws_url: bad }));
      const r = run(['--config', file]);
      assert.notEqual(r.status, 0, `${JSON.stringify(bad)} refused`);
      assert.match(r.stderr, /public_ws_url: /, `the refusal of ${JSON.stringify(bad)} names the key: ${r.stderr}`);
    }
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});
