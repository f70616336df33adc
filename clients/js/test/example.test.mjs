// The package's Node example (clients/js/examples/drive_wheel.ts, compiled against the installed
// package by tests/integration/clients/test_ts_client.sh into $TERRAD_CLIENT_DIR/drive_wheel.js) run
// against a real daemon with demo actors deforming the world, as the Python drive example is:
// its mirror at the ACK of the tick GET /v1/heights names must equal those heights (exit 0).
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { existsSync } from 'node:fs';
import path from 'node:path';
import { startDaemon, stopDaemon } from '../../../tests/support/browser.mjs';

const APP = process.env.TERRAD_CLIENT_DIR;
const EXAMPLE = APP && path.join(APP, 'drive_wheel.js');
const skip = !(EXAMPLE && existsSync(EXAMPLE)) && 'the compiled example is missing: run tests/integration/clients/test_ts_client.sh';
let daemon;

before(async () => {
  if (!skip) daemon = await startDaemon(0, 0, ['--demo-actors', '6']);
});
after(() => stopDaemon(daemon));

test('the Node example drives a wheel and its mirror equals GET /v1/heights', { skip, timeout: 180000 }, async () => {
  const child = spawn(process.execPath, [...process.execArgv, '--no-warnings', EXAMPLE,
    `ws://127.0.0.1:${daemon.ports.ws}/`, `http://127.0.0.1:${daemon.ports.http}/`], { cwd: APP });
  let out = '';
  child.stdout.on('data', (d) => (out += d));
  child.stderr.on('data', (d) => (out += d));
  const code = await new Promise((r) => child.on('exit', r));
  console.log(out.trim());
  assert.equal(code, 0, `the example exits 0: ${out}`);
  assert.match(out, /the mirror == GET \/v1\/heights over \d+x48 cells/);
  assert.match(out, /prediction: the rut in [1-9]\d* cells before the server had it/);
});
