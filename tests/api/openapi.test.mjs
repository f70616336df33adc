// docs/openapi.yaml against the real daemon (issue 14): the document is valid OpenAPI 3 (npm's
// @apidevtools/swagger-parser, which also resolves every $ref), and every answer of every
// endpoint - successes and each documented error - matches it: the status is one the
// operation lists (or its default), the Content-Type is one of that response's media types,
// JSON bodies validate against the response's schema (ajv), text bodies against theirs, and
// every documented header that is present validates too, while the headers an answer must carry
// (X-Terrad-Tick, -Rect, -Units-Per-Metre on heights; Allow on 405) are there. Every path of
// the document is fetched, and every status code it names explicitly is seen at least once.
// Run by tests/integration/service/test_openapi.sh (node --test).
import { test, before, after } from 'node:test';
import assert from 'node:assert/strict';
import { spawn } from 'node:child_process';
import { mkdirSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import http from 'node:http';
import { tmpdir } from 'node:os';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import SwaggerParser from '@apidevtools/swagger-parser';
import Ajv from 'ajv';
import * as C from '../../web/terrad_codec.mjs';

const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const BIN = process.env.TERRAD_BIN || path.join(root, 'build/terrad');
const SPEC = path.join(root, 'docs/openapi.yaml');

// OpenAPI 3.0 schemas are JSON Schema draft 4 with a few changes: exclusiveMinimum is a flag on
// minimum. Rewrite that one form into draft 7's, which ajv speaks.
function toJsonSchema(s) {
  if (Array.isArray(s)) return s.map(toJsonSchema);
  if (!s || typeof s !== 'object') return s;
  const out = {};
  for (const [k, v] of Object.entries(s)) out[k] = toJsonSchema(v);
  if (out.exclusiveMinimum === true) { out.exclusiveMinimum = out.minimum; delete out.minimum; }
  if (out.format === 'binary') delete out.format;
  return out;
}

function request(port, method, urlPath, { body, headers = {} } = {}) {
  return new Promise((resolve, reject) => {
    const req = http.request({ host: '127.0.0.1', port, method, path: urlPath, headers }, (res) => {
      const chunks = [];
      res.on('data', (c) => chunks.push(c));
      res.on('end', () => resolve({ status: res.statusCode, headers: res.headers, body: Buffer.concat(chunks) }));
    });
    req.on('error', reject);
    req.setTimeout(15000, () => req.destroy(new Error(`${method} ${urlPath}: timeout`)));
    if (body !== undefined) req.write(body);
    req.end();
  });
}

function startDaemon() {
  const dataDir = mkdtempSync(path.join(tmpdir(), 'terrad-openapi-'));
  // A small budget for /v1/heights answers held at once, so that 429 can be seen: 20,000 bytes
  // pass the 64x64 base read below (16,384) and refuse a 100x100 read (40,000).
  const config = path.join(dataDir, 'config.json');
  // a scene directory for POST /v1/worlds's scene_name, and room for one created world
  mkdirSync(path.join(dataDir, 'scenes'));
  writeFileSync(path.join(dataDir, 'scenes', 'pit.json'),
    JSON.stringify({ name: 'pit', world: { width: 64, height: 64, cell_size_m: 0.05 } }));
  writeFileSync(config, JSON.stringify({ limits: { max_heights_bytes_per_address: 20000, max_edit_cells: 100000 },
    scene_dir: path.join(dataDir, 'scenes'), max_worlds: 1 }));
  const args = ['serve', '--http-port', '0', '--ws-port', '0', '--backend', 'cpu', '--no-data',
    '--config', config];
  const proc = spawn(BIN, args, { stdio: ['ignore', 'ignore', 'pipe'], cwd: dataDir });
  proc.dataDir = dataDir;
  let err = '';
  return new Promise((resolve, reject) => {
    const t = setTimeout(() => reject(new Error(`daemon did not start: ${err}`)), 60000);
    proc.stderr.on('data', (d) => {
      err += d;
      const m = /http:\/\/127\.0\.0\.1:(\d+)\//.exec(err);
      if (m && !proc.port) { clearTimeout(t); proc.port = Number(m[1]); resolve(proc); }
    });
    proc.on('exit', (code) => { clearTimeout(t); if (!proc.port) reject(new Error(`daemon exited ${code}: ${err}`)); });
  });
}

let api, daemon, ajv;
const seen = new Map(); // path -> Set of statuses

before(async () => {
  api = await SwaggerParser.validate(SPEC); // throws with every problem on an invalid document
  ajv = new Ajv({ allErrors: true, strict: false });
  daemon = await startDaemon();
  // /readyz turns 200 once the world is up; the document says what both look like.
  const end = Date.now() + 30000;
  while ((await request(daemon.port, 'GET', '/readyz')).status !== 200) {
    if (Date.now() > end) throw new Error('daemon never ready');
    await new Promise((r) => setTimeout(r, 100));
  }
});

after(async () => {
  if (!daemon || daemon.exitCode !== null) return;
  const gone = new Promise((r) => daemon.once('exit', r));
  daemon.kill('SIGTERM');
  await gone;
  rmSync(daemon.dataDir, { recursive: true, force: true });
  assert.equal(daemon.exitCode, 0, 'SIGTERM stops the daemon with status 0');
});

// The spec's operation for a request path; paths not in the document are the viewer's files.
function operationFor(urlPath, method) {
  const p = urlPath.split('?')[0];
  const edits = /^\/v1\/worlds\/[^/]+\/edits$/.test(p) ? '/v1/worlds/{name}/edits'
    : /^\/v1\/worlds\/[^/]+$/.test(p) ? '/v1/worlds/{name}' : null;
  const key = edits || (api.paths[p] ? p : '/');
  const item = api.paths[key];
  // HEAD answers as GET, without the body
  const op = (method === 'POST' && item.post) || (method === 'DELETE' && item.delete) || item.get;
  return { key, op };
}

// Check one answer against the document; returns the parsed JSON body when there is one.
function conforms(what, urlPath, method, res) {
  const { key, op } = operationFor(urlPath, method);
  if (!seen.has(key)) seen.set(key, new Set());
  seen.get(key).add(`${method === 'HEAD' ? 'GET' : method} ${res.status}`);
  const response = op.responses[String(res.status)] || op.responses.default;
  assert.ok(response, `${what}: status ${res.status} is documented for ${key}`);
  const type = res.headers['content-type'];
  const media = response.content && response.content[type];
  assert.ok(media, `${what}: Content-Type "${type}" is one of ${Object.keys(response.content || {})}`);
  for (const [name, h] of Object.entries(response.headers || {})) {
    const v = res.headers[name.toLowerCase()];
    if (v === undefined) continue;
    const schema = toJsonSchema(h.schema);
    const value = schema.type === 'integer' ? Number(v) : v;
    assert.ok(ajv.validate(schema, value), `${what}: header ${name}: ${v}: ${ajv.errorsText()}`);
  }
  if (method === 'HEAD') {
    assert.equal(res.body.length, 0, `${what}: HEAD has no body`);
    return null;
  }
  const schema = toJsonSchema(media.schema);
  if (type === 'application/json') {
    const json = JSON.parse(res.body.toString('utf8'));
    assert.ok(ajv.validate(schema, json), `${what}: body ${res.body}: ${ajv.errorsText()}`);
    return json;
  }
  if (type.startsWith('text/')) {
    assert.ok(ajv.validate(schema, res.body.toString('utf8')), `${what}: body: ${ajv.errorsText()}`);
  }
  return null;
}

async function fetchChecked(what, urlPath, wantStatus, { method = 'GET', ...opts } = {}) {
  const res = await request(daemon.port, method, urlPath, opts);
  assert.equal(res.status, wantStatus, `${what}: ${method} ${urlPath}: ${res.status} ${res.body.slice(0, 200)}`);
  return { res, json: conforms(what, urlPath, method, res) };
}

test('the document is valid OpenAPI 3 and describes every endpoint', () => {
  assert.match(api.openapi, /^3\./);
  const version = /project\(terrad VERSION (\d+\.\d+\.\d+)/.exec(readFileSync(path.join(root, 'CMakeLists.txt'), 'utf8'))[1];
  assert.equal(api.info.version, version, 'info.version is the version of CMakeLists.txt\'s project()');
  for (const p of ['/healthz', '/readyz', '/metrics', '/v1/world', '/v1/twin', '/v1/stats', '/v1/heights',
    '/v1/websocket', '/v1/openapi.yaml', '/']) {
    assert.ok(api.paths[p] && api.paths[p].get, `GET ${p} is described`);
  }
});

test('probes, metrics, world and stats match the document', async () => {
  await fetchChecked('healthz', '/healthz', 200);
  await fetchChecked('readyz', '/readyz', 200);
  const { res } = await fetchChecked('metrics', '/metrics', 200);
  assert.match(res.body.toString(), /^# TYPE terrad_|^# HELP terrad_/m);
  const { json: world } = await fetchChecked('world', '/v1/world', 200);
  assert.ok(world.width > 0 && world.tile_size > 0);
  const { json: twin } = await fetchChecked('twin config', '/v1/twin', 200);
  assert.equal(twin.width, world.width);
  assert.equal(twin.model, world.models[0]);
  const { json: ws } = await fetchChecked('websocket', '/v1/websocket', 200);
  assert.match(ws.url, /^ws:\/\/127\.0\.0\.1:\d+\/$/);
  assert.equal(ws.url, `ws://127.0.0.1:${ws.port}/`);
  await fetchChecked('websocket without a usable Host', '/v1/websocket', 400, { headers: { Host: 'bad"host' } });
  const { json: stats } = await fetchChecked('stats', '/v1/stats', 200);
  assert.equal(stats.ready, true);
  await fetchChecked('HEAD stats', '/v1/stats', 200, { method: 'HEAD' });
  await fetchChecked('viewer', '/', 200);
  await fetchChecked('a file that is not there', '/no-such-file.js', 404);
});

test('heights in both formats, with their headers, match the document', async () => {
  const { res } = await fetchChecked('heights int32', '/v1/heights?x=3&y=5&w=7&h=2', 200);
  assert.equal(res.body.length, 7 * 2 * 4);
  assert.equal(res.headers['x-terrad-rect'], '3,5,7,2');
  assert.ok(Number(res.headers['x-terrad-tick']) > 0);
  assert.ok(Number(res.headers['x-terrad-units-per-metre']) > 0);
  const { res: png } = await fetchChecked('heights png16', '/v1/heights?x=0&y=0&w=16&h=8&format=png16', 200);
  assert.deepEqual([...png.body.subarray(1, 4)], [0x50, 0x4e, 0x47]); // "PNG"
  assert.ok(png.headers['x-terrad-offset'] !== undefined && png.headers['x-terrad-clipped'] !== undefined);
  await fetchChecked('heights format=int32', '/v1/heights?x=0&y=0&w=1&h=1&format=int32', 200);
  // the base terrain: tick 0, read without the sim; the demo actors dig below it over time
  const { res: base } = await fetchChecked('base heights', '/v1/heights?x=0&y=0&w=64&h=64&base=1', 200);
  assert.equal(base.headers['x-terrad-tick'], '0');
  assert.equal(base.body.length, 64 * 64 * 4);
  const b = new Int32Array(base.body.buffer, base.body.byteOffset, 64 * 64);
  assert.ok(Math.max(...b) > Math.min(...b), 'the default scene\'s base is not flat');
  await fetchChecked('base=2', '/v1/heights?x=0&y=0&w=1&h=1&base=2', 400);
});

test('POST /v1/worlds/{name}/edits: applied, and every refusal, as the document says', async () => {
  const post = (what, name, body, want) => fetchChecked(what, `/v1/worlds/${name}/edits`, want, {
    method: 'POST', body: typeof body === 'string' ? body : JSON.stringify(body),
    headers: { 'Content-Type': 'application/json' } });
  const { json } = await post('an add', 'default-dunes', { op: 'add', x: 1, y: 2, w: 3, h: 4, amount: 10 }, 200);
  assert.equal(json.volume_change, 120);
  await post('a crater', 'default-dunes', { op: 'crater', x: 40, y: 40, radius: 5, depth: 900 }, 200);
  await post('not JSON', 'default-dunes', '{', 400);
  await post('an unknown op', 'default-dunes', { op: 'explode' }, 400);
  await post('another world', 'elsewhere', { op: 'reset' }, 404);
  await post('over max_edit_cells', 'default-dunes', { op: 'add', x: 0, y: 0, w: 400, h: 400, amount: 1 }, 413);
  await post('past the height range', 'default-dunes', { op: 'add', x: 0, y: 0, w: 2, h: 2, amount: 536870912 }, 422);
});

test('POST, GET /v1/worlds and DELETE /v1/worlds/{name}, and their refusals, as the document says', async () => {
  const post = (what, body, want) => fetchChecked(what, '/v1/worlds', want, {
    method: 'POST', body: typeof body === 'string' ? body : JSON.stringify(body),
    headers: { 'Content-Type': 'application/json' } });
  const { json: made } = await post('a world from scene_name', { name: 'pit-1', scene_name: 'pit' }, 201);
  assert.equal(made.name, 'pit-1');
  const { json: list } = await fetchChecked('the list', '/v1/worlds', 200);
  assert.deepEqual(list.worlds.map((w) => w.name), ['default-dunes', 'pit-1']);
  await post('a duplicate', { name: 'pit-1', scene_name: 'pit' }, 409);
  await post('one too many', { name: 'pit-2', scene: { name: 'p', world: { width: 8, height: 8, cell_size_m: 0.1 } } }, 409);
  await post('no such scene', { name: 'pit-3', scene_name: 'nowhere' }, 404);
  await post('an unsafe name', { name: 'a b', scene_name: 'pit' }, 400);
  await post('NaN', '{"name": "n", "scene": {"world": {"cell_size_m": NaN}}}', 400);
  await fetchChecked('delete', '/v1/worlds/pit-1', 200, { method: 'DELETE' });
  await post('a bad scene', { name: 'pit-4', scene: { name: 'p', world: { width: -1 } } }, 422);
  await fetchChecked('delete again', '/v1/worlds/pit-1', 404, { method: 'DELETE' });
  await fetchChecked('delete the default world', '/v1/worlds/default-dunes', 409, { method: 'DELETE' });
});

test('the JS client (web/terrad_codec.mjs) creates, lists and deletes a world', async () => {
  const base = `http://127.0.0.1:${daemon.port}`;
  const made = await C.createWorld(base, 'js-1', { scene: { name: 'js', world: { width: 16, height: 16, cell_size_m: 0.1 } } });
  assert.equal(made.state, 'running');
  assert.deepEqual((await C.listWorlds(base)).map((w) => w.name), ['default-dunes', 'js-1']);
  await assert.rejects(C.createWorld(base, 'js-2', { sceneName: 'pit' }),
    (e) => e instanceof C.WorldError && e.status === 409 && e.field === 'max_worlds');
  assert.equal((await C.deleteWorld(base, 'js-1')).deleted, true);
  await assert.rejects(C.deleteWorld(base, 'js-1'), (e) => e.status === 404 && e.field === 'name');
  assert.deepEqual((await C.listWorlds(base)).map((w) => w.name), ['default-dunes']);
});

test('the document is served at /v1/openapi.yaml, byte for byte', async () => {
  const { res } = await fetchChecked('openapi', '/v1/openapi.yaml', 200);
  assert.equal(res.headers['content-type'], 'application/yaml');
  assert.ok(res.body.equals(readFileSync(SPEC)), '/v1/openapi.yaml is docs/openapi.yaml');
});

test('every documented error answers as the document says', async () => {
  await fetchChecked('missing parameter', '/v1/heights?x=0&y=0&w=4', 400);
  await fetchChecked('not an integer', '/v1/heights?x=a&y=0&w=4&h=4', 400);
  await fetchChecked('bad format', '/v1/heights?x=0&y=0&w=4&h=4&format=float', 400);
  await fetchChecked('outside the world', '/v1/heights?x=0&y=0&w=100000&h=1', 400);
  await fetchChecked('too many cells', '/v1/heights?x=0&y=0&w=4096&h=4096', 413);
  await fetchChecked('over the address\'s heights budget', '/v1/heights?x=0&y=0&w=100&h=100', 429);
  const { res } = await fetchChecked('POST', '/v1/stats', 405, { method: 'POST' });
  assert.equal(res.headers.allow, 'GET, HEAD');
  await fetchChecked('a body', '/v1/stats', 413, { body: 'x'.repeat(64), headers: { 'Content-Length': '64' } });
  await fetchChecked('a long query', `/v1/heights?x=0&y=0&w=1&h=1&pad=${'a'.repeat(1100)}`, 414);
  await fetchChecked('dot-dot', '/a/../v1/stats', 400);
  // the daemon here keeps no data directory: no log to replay a past tick from
  await fetchChecked('replay without a log', '/v1/heights?x=0&y=0&w=4&h=4&tick=1', 404);
  await fetchChecked('past stats without a log', '/v1/stats?tick=1', 404);
  await fetchChecked('past stats, not a tick', '/v1/stats?tick=abc', 400);
});

test('POST /v1/drain: a body is 400; the drain is 202, and with no client to wait for the daemon exits 0', async () => {
  await fetchChecked('a body', '/v1/drain', 400, { method: 'POST', body: '{}', headers: { 'Content-Length': '2' } });
  const gone = new Promise((r) => daemon.once('exit', r));
  const { json } = await fetchChecked('drain', '/v1/drain', 202, { method: 'POST' });
  assert.equal(json.draining, true);
  await gone;
  assert.equal(daemon.exitCode, 0, 'the drained daemon exits with status 0');
  rmSync(daemon.dataDir, { recursive: true, force: true });
});

test('every path was fetched and every explicit status was seen', () => {
  for (const [p, item] of Object.entries(api.paths)) {
    assert.ok(seen.has(p), `${p} was fetched`);
    for (const [method, op] of Object.entries(item)) {
      if (!['get', 'post', 'delete'].includes(method)) continue;
      for (const status of Object.keys(op.responses)) {
        if (status === 'default' || (p === '/readyz' && status === '503')) continue; // 503: before ready only
        if (p === '/v1/heights' && status === '503') continue; // only while the tick is stuck
        // a cluster node's answer for a world another node ticks: test_cluster_any_node
        if (p === '/v1/heights' && status === '504') continue;
        // a past tick whose log was compacted away needs a data directory: test_replay_heights
        if ((p === '/v1/heights' || p === '/v1/stats') && status === '410') continue;
        const want = `${method.toUpperCase()} ${status}`;
        assert.ok(seen.get(p).has(want), `${p}: ${want} was seen (${[...seen.get(p)]})`);
      }
    }
  }
});
