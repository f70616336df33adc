// terrad viewer: a live WebGL2 view of the deforming terrain (issue 4).
// Connects to the websocket (subprotocol terrad.v1), subscribes to the region in view,
// mirrors it with the protocol's tile-version rules and renders it as a lit mesh.
// The websocket port: ?ws=PORT, else the page's HTTP port + 1 (the daemon's default pair).
import * as P from './terrad_codec.mjs';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
const httpPort = Number(location.port || (location.protocol === 'https:' ? 443 : 80));
const wsPort = Number(params.get('ws')) || httpPort + 1;
const wsUrl = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.hostname}:${wsPort}/`;
const MAX_FULL = 512 * 512; // whole world when it is at most this many cells
const WINDOW = 512; // else a WINDOW x WINDOW subscription around the camera target
const SINK_M = 0.05;

const app = {
  state: 'connecting', connected: false, tick: 0, framesDrawn: 0, world: null,
  mirror: null, baseline: null, subs: new Map(), activeSub: 0, wantRegion: null,
  own: null, lastError: '', bytes: 0, rate: 0, seq: 0, lastBatch: 0,
};
let ws = null, retries = 0, refN = 0;

// ---- connection ----

function setState(s) {
  app.state = s;
  const el = $('o-state');
  el.textContent = s;
  el.className = s === 'live' ? 'state-live' : s === 'open' || s === 'connecting' ? '' : 'state-down';
}

function send(obj) {
  if (ws && ws.readyState === WebSocket.OPEN) ws.send(typeof obj === 'object' && !(obj instanceof Uint8Array) ? JSON.stringify(obj) : obj);
}

function connect() {
  setState(retries ? 'reconnecting…' : 'connecting');
  let sock;
  try {
    sock = new WebSocket(wsUrl, P.SUBPROTOCOL);
  } catch (e) {
    scheduleReconnect();
    return;
  }
  sock.binaryType = 'arraybuffer';
  ws = sock;
  sock.onopen = () => {
    if (ws !== sock) return;
    send(P.hello('', 'terrad-web'));
  };
  sock.onmessage = (ev) => {
    if (ws !== sock) return;
    if (typeof ev.data === 'string') {
      app.bytes += ev.data.length;
      onJson(ev.data);
    } else {
      app.bytes += ev.data.byteLength;
      onBinary(new Uint8Array(ev.data));
    }
  };
  sock.onclose = () => {
    if (ws !== sock) return;
    ws = null;
    app.connected = false;
    app.subs.clear();
    if (app.own) app.own.id = 0; // the server deletes a client's colliders when it leaves
    scheduleReconnect();
  };
  sock.onerror = () => {};
}

function scheduleReconnect() {
  setState('reconnecting…');
  const delay = Math.min(2000, 200 * 2 ** Math.min(retries, 4)) * (0.8 + 0.4 * Math.random());
  retries++;
  setTimeout(connect, delay);
}

function onJson(text) {
  let m;
  try {
    m = P.parseControl(text);
  } catch (e) {
    return;
  }
  switch (m.type) {
    case 'world':
      app.world = m;
      app.connected = true;
      retries = 0;
      app.tick = Number(m.tick) || 0; // a restarted daemon counts from its own tick
      setState('open');
      if (!app.target) app.target = [m.width * m.cell_size_m / 2, m.height * m.cell_size_m / 2, 0];
      app.wantRegion = null;
      followCamera(true);
      if (app.own) createCollider();
      break;
    case 'subscribed': {
      const mir = new P.Mirror(m.x, m.y, m.w, m.h, app.world.tile_size);
      app.subs.set(m.id, mir);
      app.activeSub = m.id;
      break;
    }
    case 'collider_created':
      if (app.own) app.own.id = m.id;
      break;
    case 'error':
      app.lastError = `${m.name}: ${m.message}`;
      $('o-error').textContent = app.lastError;
      console.warn('terrad error', m);
      break;
  }
}

function onBinary(b) {
  let t;
  try {
    t = P.decodeHeader(b);
    if (t === P.MsgType.DELTA) {
      const { tick, rects } = P.decodeDelta(b);
      for (const [id, mir] of app.subs) {
        try {
          if (mir.apply(rects) > 0 && mir === app.mirror) app.dirty = true;
        } catch (e) {
          console.warn('mirror', e.message, '-> resync');
          send(P.resync(id));
        }
      }
      app.tick = Math.max(app.tick, Number(tick));
      promoteSubscription();
    } else if (t === P.MsgType.ACK) {
      app.tick = Math.max(app.tick, Number(P.decodeAck(b).tick));
    } else if (t === P.MsgType.CONTACT) {
      const c = P.decodeContact(b);
      app.tick = Math.max(app.tick, Number(c.tick));
      app.contacts = c.contacts;
    } else if (t === P.MsgType.PING) {
      send(P.encodePing(P.decodePing(b).nonce, true));
    }
  } catch (e) {
    console.warn('frame refused', e.message);
  }
}

// The newest complete subscription becomes the rendered one; older ones are dropped.
function promoteSubscription() {
  const mir = app.subs.get(app.activeSub);
  if (!mir || !mir.complete) return;
  if (app.mirror !== mir) {
    const same = app.mirror && app.baseline && app.baselineRegion &&
      ['x', 'y', 'w', 'h'].every((k) => app.baselineRegion[k] === mir[k]);
    app.mirror = mir;
    if (!same) {
      app.baseline = mir.heights.slice();
      app.baselineRegion = { x: mir.x, y: mir.y, w: mir.w, h: mir.h };
    }
    app.dirty = true;
    app.meshDirty = true;
    setState('live');
  }
  for (const id of [...app.subs.keys()]) {
    if (id !== app.activeSub) {
      app.subs.delete(id);
      send(P.unsubscribe(id));
    }
  }
}

// Whole world when small enough, else a window around the camera target.
function followCamera(force) {
  const w = app.world;
  if (!w || !app.connected) return;
  let r;
  if (w.width * w.height <= MAX_FULL) r = { x: 0, y: 0, w: w.width, h: w.height };
  else {
    const ww = Math.min(WINDOW, w.width), wh = Math.min(WINDOW, w.height);
    const cx = Math.floor(app.target[0] / w.cell_size_m), cy = Math.floor(app.target[1] / w.cell_size_m);
    r = {
      x: Math.max(0, Math.min(w.width - ww, cx - (ww >> 1))),
      y: Math.max(0, Math.min(w.height - wh, cy - (wh >> 1))), w: ww, h: wh,
    };
  }
  const cur = app.wantRegion;
  if (!force && cur && Math.abs(cur.x - r.x) < WINDOW / 4 && Math.abs(cur.y - r.y) < WINDOW / 4) return;
  if (!force && cur && cur.x === r.x && cur.y === r.y) return;
  app.wantRegion = r;
  send(P.subscribe(r.x, r.y, r.w, r.h, `sub-${++refN}`));
}

// ---- driving ----

function createCollider() {
  if (!app.world) return false;
  if (!app.own) {
    app.own = { id: 0, radius: 0.3, x: app.target[0], y: app.target[1], z: 0 };
    $('drive').classList.add('on');
  }
  app.own.id = 0;
  send(P.colliderCreate('sphere', { radius: app.own.radius }, { feedback: true, ref: `col-${++refN}` }));
  return true;
}

// Height in metres of the mirror under (x, y): the start (baseline) surface, so a
// stopped collider stops digging and the terrain settles.
function heightAt(x, y, buf) {
  const m = app.mirror, w = app.world;
  if (!m || !w) return 0;
  const i = Math.floor(x / w.cell_size_m) - m.x, j = Math.floor(y / w.cell_size_m) - m.y;
  if (i < 0 || j < 0 || i >= m.w || j >= m.h) return 0;
  return (buf || m.heights)[j * m.w + i] / w.units_per_m;
}

function drive(dx, dy) {
  const o = app.own, w = app.world;
  if (!o || !w) return;
  const maxX = w.width * w.cell_size_m, maxY = w.height * w.cell_size_m;
  o.x = Math.max(0, Math.min(maxX - 1e-3, o.x + dx));
  o.y = Math.max(0, Math.min(maxY - 1e-3, o.y + dy));
  o.lifted = false;
  sendPoses(performance.now()); // now, not at the next frame: slow frames must not skip the path
}

function sendPoses(now) {
  const o = app.own;
  if (o && o.id) {
    o.z = o.lifted ? heightAt(o.x, o.y) + o.radius + 1 : heightAt(o.x, o.y, app.baseline) + o.radius - SINK_M;
    send(P.encodePoseBatch(app.seq++, [{ id: o.id, x: o.x, y: o.y, z: o.z, qw: 1, qx: 0, qy: 0, qz: 0 }]));
    app.lastBatch = now;
  } else if (app.connected && now - app.lastBatch > 250) {
    send(P.encodePoseBatch(app.seq++, [])); // an empty batch asks for an ACK: keeps the tick current
    app.lastBatch = now;
  }
}

const keys = new Set();
addEventListener('keydown', (e) => {
  if (['KeyW', 'KeyA', 'KeyS', 'KeyD', 'ArrowUp', 'ArrowDown', 'ArrowLeft', 'ArrowRight'].includes(e.code)) {
    keys.add(e.code);
    e.preventDefault();
  }
});
addEventListener('keyup', (e) => keys.delete(e.code));
addEventListener('blur', () => keys.clear());
$('drive').addEventListener('click', () => {
  if (!app.own) createCollider();
  else {
    app.own.lifted = !app.own.lifted;
  }
  $('drive').classList.toggle('on', !!app.own && !app.own.lifted);
  $('drive').blur();
});

function keyDrive(dt) {
  if (!app.own || !keys.size) return;
  let f = 0, s = 0;
  if (keys.has('KeyW') || keys.has('ArrowUp')) f += 1;
  if (keys.has('KeyS') || keys.has('ArrowDown')) f -= 1;
  if (keys.has('KeyA') || keys.has('ArrowLeft')) s += 1;
  if (keys.has('KeyD') || keys.has('ArrowRight')) s -= 1;
  const v = 1.5 * dt, yaw = cam.yaw;
  // forward = away from the camera, in the ground plane
  const fx = -Math.cos(yaw), fy = -Math.sin(yaw);
  drive((f * fx - s * fy) * v, (f * fy + s * fx) * v);
}

// ---- camera ----

const cam = { yaw: -Math.PI / 2 - 0.5, pitch: 0.75, dist: 0 };
const pointers = new Map();
const canvas = $('view');
canvas.addEventListener('pointerdown', (e) => {
  canvas.setPointerCapture(e.pointerId);
  pointers.set(e.pointerId, { x: e.clientX, y: e.clientY });
});
canvas.addEventListener('pointermove', (e) => {
  const p = pointers.get(e.pointerId);
  if (!p) return;
  const dx = e.clientX - p.x, dy = e.clientY - p.y;
  if (pointers.size === 1) {
    if (e.shiftKey || e.buttons === 4 || e.buttons === 2) pan(dx, dy);
    else {
      cam.yaw -= dx * 0.006;
      cam.pitch = Math.max(0.08, Math.min(1.5, cam.pitch + dy * 0.006));
    }
  } else if (pointers.size === 2) {
    const [a, b] = [...pointers.values()];
    const before = Math.hypot(a.x - b.x, a.y - b.y);
    p.x = e.clientX;
    p.y = e.clientY;
    const after = Math.hypot(a.x - b.x, a.y - b.y);
    if (before > 0 && after > 0) zoom(before / after);
    pan(dx / 2, dy / 2);
  }
  p.x = e.clientX;
  p.y = e.clientY;
});
const up = (e) => pointers.delete(e.pointerId);
canvas.addEventListener('pointerup', up);
canvas.addEventListener('pointercancel', up);
canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  zoom(Math.exp(e.deltaY * 0.001));
}, { passive: false });

function zoom(f) {
  cam.dist = Math.max(0.5, Math.min(cam.maxDist || 1e4, cam.dist * f));
}
function pan(dx, dy) {
  if (!app.target) return;
  const s = cam.dist * 0.0015;
  const c = Math.cos(cam.yaw), sn = Math.sin(cam.yaw);
  app.target[0] += (dx * sn + dy * c) * s;
  app.target[1] += (-dx * c + dy * sn) * s;
  if (app.world) {
    app.target[0] = Math.max(0, Math.min(app.world.width * app.world.cell_size_m, app.target[0]));
    app.target[1] = Math.max(0, Math.min(app.world.height * app.world.cell_size_m, app.target[1]));
  }
  followCamera(false);
}

// ---- rendering ----

const gl = canvas.getContext('webgl2', { antialias: true, preserveDrawingBuffer: true });
if (!gl) $('o-error').textContent = 'WebGL2 is not available in this browser';

const TERRAIN_VS = `#version 300 es
precision highp float; precision highp int;
uniform highp sampler2D uH; uniform highp sampler2D uB;
uniform ivec2 uSize; uniform vec2 uOrigin; uniform float uCell; uniform mat4 uMVP;
out vec3 vN; out float vD; out float vH;
float h(int i, int j) { return texelFetch(uH, ivec2(clamp(i, 0, uSize.x - 1), clamp(j, 0, uSize.y - 1)), 0).r; }
void main() {
  int i = gl_VertexID % uSize.x, j = gl_VertexID / uSize.x;
  float z = h(i, j);
  // normal from central differences (one-sided at the region's border)
  int il = max(i - 1, 0), ir = min(i + 1, uSize.x - 1), jd = max(j - 1, 0), ju = min(j + 1, uSize.y - 1);
  float dzx = (h(ir, j) - h(il, j)) / (float(max(ir - il, 1)) * uCell);
  float dzy = (h(i, ju) - h(i, jd)) / (float(max(ju - jd, 1)) * uCell);
  vN = normalize(vec3(-dzx, -dzy, 1.0));
  vD = z - texelFetch(uB, ivec2(i, j), 0).r;
  vH = z;
  gl_Position = uMVP * vec4(uOrigin + (vec2(i, j) + 0.5) * uCell, z, 1.0);
}`;
const TERRAIN_FS = `#version 300 es
precision highp float;
in vec3 vN; in float vD; in float vH;
uniform vec3 uLight; uniform float uScale;
out vec4 o;
void main() {
  vec3 n = normalize(vN);
  vec3 snow = vec3(0.93, 0.94, 0.96) - 0.05 * clamp(vH * 0.5, -1.0, 1.0);
  vec3 dug = vec3(0.22, 0.45, 0.95), piled = vec3(0.98, 0.55, 0.18);
  float t = clamp(abs(vD) / uScale, 0.0, 1.0);
  vec3 base = mix(snow, vD < 0.0 ? dug : piled, smoothstep(0.0, 1.0, sqrt(t)));
  float diff = max(dot(n, uLight), 0.0);
  vec3 c = base * (0.28 + 0.72 * diff) + vec3(0.02, 0.03, 0.05);
  o = vec4(pow(c, vec3(1.0 / 1.1)), 1.0);
}`;
const SHAPE_VS = `#version 300 es
precision highp float;
in vec3 aP; uniform mat4 uMVP; uniform vec3 uC; uniform float uR;
out vec3 vN;
void main() { vN = aP; gl_Position = uMVP * vec4(uC + aP * uR, 1.0); }`;
const SHAPE_FS = `#version 300 es
precision highp float;
in vec3 vN; uniform vec3 uLight; uniform vec3 uColor; out vec4 o;
void main() { float d = max(dot(normalize(vN), uLight), 0.0); o = vec4(uColor * (0.3 + 0.7 * d), 1.0); }`;

function program(vs, fs) {
  const p = gl.createProgram();
  for (const [type, src] of [[gl.VERTEX_SHADER, vs], [gl.FRAGMENT_SHADER, fs]]) {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    gl.attachShader(p, s);
  }
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const u = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const name = gl.getActiveUniform(p, i).name;
    u[name] = gl.getUniformLocation(p, name);
  }
  return { p, u };
}

let terrain, shape, gpu = {};
function initGL() {
  terrain = program(TERRAIN_VS, TERRAIN_FS);
  shape = program(SHAPE_VS, SHAPE_FS);
  gpu.vao = gl.createVertexArray();
  gpu.ibo = gl.createBuffer();
  gpu.texH = gl.createTexture();
  gpu.texB = gl.createTexture();
  // a UV sphere for colliders
  const pts = [], idx = [], S = 16, R = 10;
  for (let a = 0; a <= R; a++)
    for (let b = 0; b <= S; b++) {
      const th = (a / R) * Math.PI, ph = (b / S) * 2 * Math.PI;
      pts.push(Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th));
    }
  for (let a = 0; a < R; a++)
    for (let b = 0; b < S; b++) {
      const i = a * (S + 1) + b;
      idx.push(i, i + S + 1, i + 1, i + 1, i + S + 1, i + S + 2);
    }
  gpu.sphere = gl.createVertexArray();
  gl.bindVertexArray(gpu.sphere);
  const vb = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, vb);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(pts), gl.STATIC_DRAW);
  const loc = gl.getAttribLocation(shape.p, 'aP');
  gl.enableVertexAttribArray(loc);
  gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
  const ib = gl.createBuffer();
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint16Array(idx), gl.STATIC_DRAW);
  gpu.sphereCount = idx.length;
  gl.bindVertexArray(null);
}

function uploadTexture(tex, ints, w, h, upm) {
  const f = new Float32Array(ints.length);
  for (let i = 0; i < ints.length; i++) f[i] = ints[i] / upm;
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.R32F, w, h, 0, gl.RED, gl.FLOAT, f);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
}

function rebuildMesh(m) {
  const idx = new Uint32Array((m.w - 1) * (m.h - 1) * 6);
  let k = 0;
  for (let j = 0; j + 1 < m.h; j++)
    for (let i = 0; i + 1 < m.w; i++) {
      const a = j * m.w + i;
      idx[k++] = a; idx[k++] = a + 1; idx[k++] = a + m.w;
      idx[k++] = a + 1; idx[k++] = a + m.w + 1; idx[k++] = a + m.w;
    }
  gl.bindVertexArray(gpu.vao);
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, gpu.ibo);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  gpu.count = idx.length;
  uploadTexture(gpu.texB, app.baseline, m.w, m.h, app.world.units_per_m);
}

// column-major 4x4 helpers
function perspective(fovy, aspect, near, far) {
  const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return [f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0];
}
function lookAt(e, t, u) {
  const sub = (a, b) => a.map((v, i) => v - b[i]);
  const norm = (a) => { const l = Math.hypot(...a) || 1; return a.map((v) => v / l); };
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const z = norm(sub(e, t)), x = norm(cross(u, z)), y = cross(z, x);
  return [x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, e), -dot(y, e), -dot(z, e), 1];
}
function mul(a, b) {
  const o = new Array(16).fill(0);
  for (let c = 0; c < 4; c++) for (let r = 0; r < 4; r++) for (let k = 0; k < 4; k++) o[c * 4 + r] += a[k * 4 + r] * b[c * 4 + k];
  return o;
}

function resize() {
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
}

const LIGHT = (() => { const l = [0.45, -0.35, 0.82], n = Math.hypot(...l); return l.map((v) => v / n); })();

function draw() {
  resize();
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(0.114, 0.129, 0.161, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  const m = app.mirror, w = app.world;
  if (!m || !w) return;
  if (app.meshDirty) {
    rebuildMesh(m);
    app.meshDirty = false;
  }
  if (app.dirty) {
    uploadTexture(gpu.texH, m.heights, m.w, m.h, w.units_per_m);
    app.dirty = false;
  }
  const extent = Math.max(m.w, m.h) * w.cell_size_m;
  if (!cam.dist) cam.dist = extent * 1.25;
  cam.maxDist = extent * 4;
  const tz = heightAt(app.target[0], app.target[1]);
  const t = [app.target[0], app.target[1], tz];
  const e = [t[0] + cam.dist * Math.cos(cam.pitch) * Math.cos(cam.yaw), t[1] + cam.dist * Math.cos(cam.pitch) * Math.sin(cam.yaw), t[2] + cam.dist * Math.sin(cam.pitch)];
  const mvp = mul(perspective(0.8, canvas.width / canvas.height, cam.dist * 0.01, cam.dist * 10), lookAt(e, t, [0, 0, 1]));
  app.mvp = mvp;
  gl.enable(gl.DEPTH_TEST);
  gl.useProgram(terrain.p);
  gl.uniformMatrix4fv(terrain.u.uMVP, false, mvp);
  gl.uniform2i(terrain.u.uSize, m.w, m.h);
  gl.uniform2f(terrain.u.uOrigin, m.x * w.cell_size_m, m.y * w.cell_size_m);
  gl.uniform1f(terrain.u.uCell, w.cell_size_m);
  gl.uniform3fv(terrain.u.uLight, LIGHT);
  gl.uniform1f(terrain.u.uScale, 0.04);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, gpu.texH);
  gl.uniform1i(terrain.u.uH, 0);
  gl.activeTexture(gl.TEXTURE1);
  gl.bindTexture(gl.TEXTURE_2D, gpu.texB);
  gl.uniform1i(terrain.u.uB, 1);
  gl.bindVertexArray(gpu.vao);
  gl.drawElements(gl.TRIANGLES, gpu.count, gl.UNSIGNED_INT, 0);
  const o = app.own;
  if (o && o.id) {
    gl.useProgram(shape.p);
    gl.uniformMatrix4fv(shape.u.uMVP, false, mvp);
    gl.uniform3f(shape.u.uC, o.x, o.y, o.z);
    gl.uniform1f(shape.u.uR, o.radius);
    gl.uniform3fv(shape.u.uLight, LIGHT);
    gl.uniform3f(shape.u.uColor, 0.85, 0.2, 0.25);
    gl.bindVertexArray(gpu.sphere);
    gl.drawElements(gl.TRIANGLES, gpu.sphereCount, gl.UNSIGNED_SHORT, 0);
  }
  gl.bindVertexArray(null);
  app.framesDrawn++;
}

let last = performance.now();
function frame(now) {
  const dt = Math.min(0.1, (now - last) / 1000);
  last = now;
  keyDrive(dt);
  sendPoses(now);
  // Draw only when something changed: software GL is slow, keep the main thread free.
  const o = app.own, sig = [canvas.clientWidth, canvas.clientHeight, devicePixelRatio, cam.yaw, cam.pitch, cam.dist,
    ...(app.target || []), o ? o.x + o.y + o.z + o.id : 0, app.mirror ? app.mirror.x + app.mirror.w : -1].join();
  const need = app.dirty || app.meshDirty || sig !== app.lastSig || now - (app.lastDraw || 0) > 1000;
  if (gl && need) {
    app.lastSig = sig;
    app.lastDraw = now;
    try {
      draw();
    } catch (e) {
      $('o-error').textContent = String(e.message || e);
      throw e;
    }
  }
  requestAnimationFrame(frame);
}

// ---- overlay ----

function fmtBytes(n) {
  return n > 1e6 ? `${(n / 1e6).toFixed(2)} MB/s` : n > 1e3 ? `${(n / 1e3).toFixed(1)} kB/s` : `${n} B/s`;
}
async function pollStats() {
  try {
    const r = await fetch('/v1/stats', { cache: 'no-store' });
    const text = await r.text();
    const s = JSON.parse(text);
    // Σh as the exact integer from the JSON text (JSON.parse would round past 2^53)
    const vol = /"volume"\s*:\s*(-?\d+)/.exec(text);
    $('o-volume').textContent = vol ? vol[1] : '–';
    $('o-ticktime').textContent = typeof s.last_tick_ms === 'number' ? `${s.last_tick_ms.toFixed(2)} ms` : '–';
    $('o-clients').textContent = String(s.clients ?? '–');
    $('o-colliders').textContent = String(s.colliders ?? '–');
    app.stats = s;
  } catch (e) {
    $('o-volume').textContent = '–';
  }
}
setInterval(pollStats, 500);
setInterval(() => {
  app.rate = app.bytes;
  app.bytes = 0;
  $('o-rate').textContent = fmtBytes(app.rate);
}, 1000);
setInterval(() => {
  $('o-tick').textContent = String(app.tick);
  const m = app.mirror;
  $('o-region').textContent = m ? `${m.w}×${m.h} at ${m.x},${m.y}` : '–';
}, 100);

// ---- test and console hooks ----

window.terrad = {
  get state() { return app.state; },
  get tick() { return app.tick; },
  get heights() { return app.mirror ? app.mirror.heights : null; },
  get region() { const m = app.mirror; return m ? { x: m.x, y: m.y, w: m.w, h: m.h } : null; },
  get connected() { return app.connected; },
  get framesDrawn() { return app.framesDrawn; },
  get collider() { return app.own ? { ...app.own } : null; },
  get world() { return app.world; },
  get wsUrl() { return wsUrl; },
  createCollider,
  drive,
  lift() { if (app.own) app.own.lifted = true; },
  // CSS pixel position of a world point (z defaults to the terrain there)
  project(x, y, z) {
    const m = app.mvp;
    if (!m) return null;
    if (z === undefined) z = heightAt(x, y);
    const c = [0, 1, 2, 3].map((r) => m[r] * x + m[4 + r] * y + m[8 + r] * z + m[12 + r]);
    return [(c[0] / c[3] * 0.5 + 0.5) * canvas.clientWidth, (0.5 - c[1] / c[3] * 0.5) * canvas.clientHeight];
  },
};

if (gl) initGL();
pollStats();
connect();
requestAnimationFrame(frame);
