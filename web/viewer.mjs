// terrad viewer: a live WebGL2 view of the deforming terrain (issue 4).
// Connects to the websocket (subprotocol terrad.v1), subscribes to the region in view,
// mirrors it with the protocol's tile-version rules and renders it as a lit mesh.
// Where the websocket is: the daemon says (GET v1/websocket, asked relative to the page's own
// URL before each connection: its ws port, at the host the browser used, or the --public-ws-url
// a proxy needs), never guessed from the page's port. ?ws=PORT or ?ws=URL overrides it.
// With the twin (WebAssembly, GET /terrad_twin.wasm) the page asks for base snapshots
// (PROTOCOL.md "Base snapshots") and rebuilds the scene's base under each window itself: a
// page joining a world dug for an hour is sent only the digging. Without it: plain snapshots.
import * as P from './terrad_codec.mjs';
import { ViewerPrediction, union } from './viewer_predict.mjs';

const $ = (id) => document.getElementById(id);
const params = new URLSearchParams(location.search);
// A daemon with tokens (docs/security.md): open the viewer as /#token=tdk_… — the fragment never
// reaches a server or its logs; the token goes in the hello and as a bearer token to /v1/*.
const token = new URLSearchParams(location.hash.slice(1)).get('token') || '';
const apiInit = { cache: 'no-store', headers: token ? { Authorization: `Bearer ${token}` } : {} };
let wsUrl = ''; // the last one connected to (or tried)
// The page's bandwidth budget (PROTOCOL.md "Budgets"), ?budget=BYTES_PER_S (0: none): 128 KiB/s by
// default, twice what a game's whole stream is usually allowed (Roblox, Valheim: 50–64 kB/s), since
// a viewer watches a whole world; the tiles near the camera target (its focus) come first.
const BUDGET = params.has('budget') ? Math.max(0, Math.floor(Number(params.get('budget')) || 0)) : 131072;
let budgetRefused = false; // the daemon's max_budget_bytes_per_s is lower: take its default instead
let baseRefused = false; // the twin could not make this world's base: plain snapshots from then on
// The websocket's URL: the page's ?ws= override, else the daemon's answer.
async function websocketUrl() {
  const given = params.get('ws');
  if (given) return /^\d+$/.test(given) ? `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.hostname}:${given}/` : given;
  const r = await fetch(new URL('v1/websocket', location.href), apiInit);
  const body = await r.json();
  if (!r.ok || typeof body.url !== 'string') throw new Error(`GET v1/websocket: ${r.status} ${body.error || ''}`);
  return body.url;
}
const MAX_FULL = 512 * 512; // whole world when it is at most this many cells: every chunk at full detail
const WINDOW = 1024; // else a WINDOW x WINDOW subscription around the camera target, chunked LoD
const CHUNK = 64; // cells per chunk side (one tile); LoD level l draws every 2^l-th cell
const LOD_LEVELS = 5; // steps 1, 2, 4, 8, 16
const LOD_DIST = 1.5; // a chunk drops one level each time its distance doubles past LOD_DIST chunk sizes
const DRIVE_SPEED = 3; // m/s towards the point dragged to
const SINK_M = 0.05;

const app = {
  state: 'connecting', connected: false, tick: 0, framesDrawn: 0, world: null,
  mirror: null, baseline: null, subs: new Map(), activeSub: 0, wantRegion: null,
  own: null, lastError: '', bytes: 0, rate: 0, seq: 0, lastBatch: 0,
  keyClock: { s: 0, maxStep: 0 }, // frame time the keys drove for (see frame())
  colliders: [], collidersTick: 0, // the latest COLLIDERS frame: every collider in view
  dirtyBox: null, // window cells changed since the last texture upload: {x0, y0, x1, y1}
  chunks: [], skirts: true, background: [0.114, 0.129, 0.161], dragTarget: null,
  ackedSeq: 0, shown: null, // the last ACK's batch; the heights the last frame drew (see shownHeights)
  drawn: { frame: 0, seq: 0, ackedSeq: 0, lower: 0 }, // what the last frame drew (test hook)
  desync: { checksumFrames: 0, checksumTick: 0n, tilesDiffering: 0, tilesResynced: 0 }, // CHECKSUM frames
  twins: null, // the twin module when this connection asked for base snapshots (hello), else null
  snapshots: { absolute: 0, base: 0, slope: 0 }, // snapshot rectangles received: encodings 1, 2 and 3
};
// The page's own rut at once while it drives (viewer_predict.mjs): the predict toggle.
const prediction = new ViewerPrediction(apiInit);
let ws = null, retries = 0, refN = 0;
// PROTOCOL.md "seen": the page says which tick it has drawn from, so a page that cannot keep up
// (a slow machine, a background tab) is resynchronised instead of falling ever further behind.
const seenReporter = new P.SeenReporter((m) => send(m));

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

async function connect() {
  setState(retries ? 'reconnecting…' : 'connecting');
  let sock;
  try {
    wsUrl = await websocketUrl(); // asked again each time: a restarted daemon may have moved it
    app.twins = baseRefused ? null : await prediction.loadModule(); // null: plain snapshots
    sock = new WebSocket(wsUrl, P.SUBPROTOCOL);
  } catch (e) {
    app.lastError = String(e.message || e);
    $('o-error').textContent = app.lastError;
    scheduleReconnect();
    return;
  }
  sock.binaryType = 'arraybuffer';
  ws = sock;
  sock.onopen = () => {
    if (ws !== sock) return;
    send(P.hello(token, 'terrad-web', '', budgetRefused ? -1 : BUDGET, !!app.twins, !!app.twins));
  };
  sock.onmessage = (ev) => {
    if (ws !== sock) return;
    if (typeof ev.data === 'string') {
      app.bytes += ev.data.length;
      onJson(ev.data);
    } else {
      app.bytes += ev.data.byteLength;
      const frame = new Uint8Array(ev.data);
      onBinary(frame);
      seenReporter.handled(frame);
    }
  };
  sock.onclose = () => {
    if (ws !== sock) return;
    ws = null;
    app.connected = false;
    app.snapshotShown = false;
    app.subs.clear();
    if (app.own) app.own.id = 0; // the server deletes a client's colliders when it leaves
    prediction.reset(); // its ACKs are gone with the connection
    seenReporter.reset();
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
      prediction.load().then(showPredict);
      if (app.own) createCollider();
      break;
    case 'subscribed': {
      const mir = new P.Mirror(m.x, m.y, m.w, m.h, app.world.tile_size);
      if (app.twins && app.world.snapshot_base && app.world.base && typeof app.world.base === 'object') {
        // its snapshots come less the scene's base: rebuilt here before any of them is read
        try {
          const twin = app.twins.create(app.world.base, m.x, m.y, m.w, m.h, null);
          try {
            mir.base = twin.read();
          } finally {
            twin.destroy();
          }
        } catch (e) {
          console.warn('base snapshots refused:', e.message, '-> plain snapshots');
          baseRefused = true;
          ws?.close(); // reconnects with a hello that does not ask
          break;
        }
      }
      app.subs.set(m.id, mir);
      app.activeSub = m.id;
      break;
    }
    case 'collider_created':
      if (app.own) app.own.id = m.id;
      break;
    case 'error':
      if (!app.connected && /^budget:/.test(m.message || '') && !budgetRefused) {
        budgetRefused = true; // over the daemon's limit: hello again with the daemon's own budget
        send(P.hello(token, 'terrad-web', '', -1, !!app.twins, !!app.twins));
        break;
      }
      seenReporter.refused(m);
      if (m.ref === 'seen' && m.name === 'unknown_type') break; // a daemon from before "seen"
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
      for (const r of rects) {
        if (r.encoding === P.Encoding.SNAPSHOT) app.snapshots.absolute++;
        else if (r.encoding === P.Encoding.BASE) app.snapshots.base++;
        else if (r.encoding === P.Encoding.BASE_SLOPE) app.snapshots.slope++;
      }
      for (const [id, mir] of app.subs) {
        try {
          if (mir.apply(rects) > 0 && mir === app.mirror) markDirty(mir, rects);
        } catch (e) {
          console.warn('mirror', e.message, '-> resync');
          send(P.resync(id));
        }
      }
      app.tick = Math.max(app.tick, Number(tick));
      promoteSubscription();
    } else if (t === P.MsgType.ACK) {
      const { tick, seq } = P.decodeAck(b);
      app.tick = Math.max(app.tick, Number(tick));
      app.ackedSeq = seq;
      markBox(prediction.onAck(tick, seq)); // the mirror holds the server's heights at tick
    } else if (t === P.MsgType.CONTACT) {
      const c = P.decodeContact(b);
      app.tick = Math.max(app.tick, Number(c.tick));
      app.contacts = c.contacts;
    } else if (t === P.MsgType.COLLIDERS) {
      const c = P.decodeColliders(b);
      if (c.tick >= app.collidersTick) {
        app.collidersTick = c.tick;
        // the server repeats an unchanged list once a second: redraw only for a change
        const key = JSON.stringify(c.colliders);
        if (key !== app.collidersKey) app.collidersChanged = true;
        app.collidersKey = key;
        app.colliders = c.colliders;
      }
    } else if (t === P.MsgType.CHECKSUM) {
      // desync detection: a tile that differs is asked for again and redrawn from its snapshot
      const r = P.checkMirrors(app.subs, b, app.desync, app.world?.limits?.max_resync_tiles ?? 64);
      if (r.resync) {
        console.warn(`subscription ${r.subscription}: ${r.asked.length} tile(s) differ from the server's at tick ${r.tick}: asked for again`);
        send(r.resync);
      }
      showDesync();
    } else if (t === P.MsgType.PING) {
      send(P.encodePing(P.decodePing(b).nonce, true));
    }
  } catch (e) {
    console.warn('frame refused', e.message);
  }
}

// The status table's desync row: CHECKSUM frames compared, tiles repaired.
function showDesync() {
  const d = app.desync;
  $('o-desync').textContent = `${d.checksumFrames} checked · ${d.tilesResynced} tile${d.tilesResynced === 1 ? '' : 's'} repaired`;
}

// The part of the rendered window the rectangles touched: only it is uploaded again.
function markDirty(m, rects) {
  let b = app.dirtyBox;
  for (const r of rects) {
    const x0 = Math.max(r.x, m.x) - m.x, y0 = Math.max(r.y, m.y) - m.y;
    const x1 = Math.min(r.x + r.w, m.x + m.w) - m.x, y1 = Math.min(r.y + r.h, m.y + m.h) - m.y;
    if (x0 >= x1 || y0 >= y1) continue;
    b = b ? { x0: Math.min(b.x0, x0), y0: Math.min(b.y0, y0), x1: Math.max(b.x1, x1), y1: Math.max(b.y1, y1) } : { x0, y0, x1, y1 };
  }
  if (b) {
    app.dirtyBox = b;
    app.dirty = true;
  }
}

// A box of window cells whose shown heights changed (the predicted sub-window), or null.
function markBox(b) {
  if (!b || !app.mirror) return;
  app.dirtyBox = union(app.dirtyBox, b);
  app.dirty = true;
}

// The heights a frame draws: the mirror's, with the predicted sub-window pasted in while the
// page drives with prediction on.
function shownHeights(m) {
  return (app.shown = prediction.heights(m, app.shown));
}

// The scene's base terrain under a window (GET /v1/heights?...&base=1): the terrain is coloured
// by h - base, so every trail shows, also those dug before the page loaded. Until it arrives
// (or if it cannot) the window's first snapshot stands in.
async function fetchBase(r) {
  try {
    const res = await fetch(`/v1/heights?x=${r.x}&y=${r.y}&w=${r.w}&h=${r.h}&base=1`, apiInit);
    if (!res.ok) return;
    const buf = await res.arrayBuffer();
    const v = new DataView(buf), n = r.w * r.h;
    if (buf.byteLength !== 4 * n || app.baselineRegion !== r) return; // a newer window since
    const base = new Int32Array(n);
    for (let i = 0; i < n; i++) base[i] = v.getInt32(4 * i, true);
    app.baseline = base;
    app.baseFromServer = true;
    app.meshDirty = true;
  } catch (e) {
    console.warn('base terrain not available:', e.message);
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
      app.baselineRegion = { x: mir.x, y: mir.y, w: mir.w, h: mir.h };
      if (mir.base) { // base snapshots: the twin made the scene's base already
        app.baseline = mir.base;
        app.baseFromServer = true;
      } else {
        app.baseline = mir.heights.slice(); // until the base terrain arrives
        app.baseFromServer = false;
        fetchBase(app.baselineRegion);
      }
    }
    app.dirty = true;
    app.meshDirty = true;
    app.dirtyBox = { x0: 0, y0: 0, x1: mir.w, y1: mir.h };
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
  // the budget's focus: the camera target, told again once it has moved half a tile
  const fx = Math.floor(app.target[0] / w.cell_size_m), fy = Math.floor(app.target[1] / w.cell_size_m);
  if (force || !app.focus || Math.abs(app.focus[0] - fx) + Math.abs(app.focus[1] - fy) >= CHUNK / 2) {
    app.focus = [fx, fy];
    send(P.focus(Math.max(0, Math.min(w.width, fx)), Math.max(0, Math.min(w.height, fy))));
  }
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
  // with COLLIDERS frames, and their wheels' grousers (PROTOCOL.md "COLLIDERS": the extension)
  send(P.subscribe(r.x, r.y, r.w, r.h, `sub-${++refN}`, true, false, true));
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

// Height in metres of the mirror under (x, y): the base terrain (baseline) surface, so a
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
    const poses = [{ id: o.id, x: o.x, y: o.y, z: o.z, qw: 1, qx: 0, qy: 0, qz: 0 }];
    markBox(prediction.ensure(app.world, app.mirror, o));
    markBox(prediction.onSend(app.seq, poses)); // the twin ticks before the bytes leave
    send(P.encodePoseBatch(app.seq++, poses));
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
$('predict').addEventListener('click', () => {
  prediction.enabled = !prediction.enabled;
  markBox(prediction.drop()); // off: the mirror alone; on: the next pose starts it
  showPredict();
  $('predict').blur();
});
function showPredict() {
  const b = $('predict');
  b.textContent = prediction.enabled ? 'predict: on' : 'predict: off';
  b.classList.toggle('on', prediction.enabled && prediction.available);
  b.disabled = !prediction.available;
  b.title = prediction.available ? 'show the own rut at once (on) or only the server\'s heights (off)'
    : `prediction not available: ${prediction.reason}`;
}

// Move the collider towards the dragged-to point at DRIVE_SPEED.
function dragDrive(dt) {
  const o = app.own, t = app.dragTarget;
  if (!o || !t || !driving()) return;
  const dx = t[0] - o.x, dy = t[1] - o.y, d = Math.hypot(dx, dy), v = DRIVE_SPEED * dt;
  if (d < 1e-3) return;
  const k = Math.min(1, v / d);
  drive(dx * k, dy * k);
}

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
// Drive mode: the page's collider is on the ground (the drive button is lit). Then a
// one-pointer drag (mouse or touch) without shift steers it: the collider heads for the
// terrain point under the pointer. Two fingers still zoom and pan; shift/right drag pans.
const driving = () => !!app.own && !!app.own.id && !app.own.lifted;
function steerTo(e) {
  const r = canvas.getBoundingClientRect();
  const p = pick(e.clientX - r.left, e.clientY - r.top);
  if (p) app.dragTarget = p;
}
canvas.addEventListener('pointerdown', (e) => {
  canvas.setPointerCapture(e.pointerId);
  pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, steer: driving() && !e.shiftKey && e.button === 0 && pointers.size === 0 });
  if (pointers.size > 1) {
    for (const q of pointers.values()) q.steer = false;
    app.dragTarget = null;
  }
  if (pointers.get(e.pointerId).steer) steerTo(e);
});
canvas.addEventListener('pointermove', (e) => {
  const p = pointers.get(e.pointerId);
  if (!p) return;
  const dx = e.clientX - p.x, dy = e.clientY - p.y;
  if (p.steer) steerTo(e);
  else if (pointers.size === 1) {
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
const up = (e) => {
  const p = pointers.get(e.pointerId);
  pointers.delete(e.pointerId);
  if (p && p.steer) app.dragTarget = null; // let go: the collider stops where it is
};
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

// The terrain is drawn chunk by chunk (CHUNK² cells each) straight from the heights
// texture: a vertex is (gl_VertexID → grid cell) at the chunk's LoD step, so one index
// buffer per level serves every chunk. Cracks between chunks of different levels are
// hidden by skirts: every chunk's border is repeated uSkirt metres lower and joined to
// it by a vertical strip. Skirts, not stitched edges, because a chunk then never
// depends on its neighbours' levels (one index buffer per level instead of 16 edge
// variants, levels change per frame without touching neighbours), as in Ulrich's
// chunked LoD that the large-terrain paper builds on.
const TERRAIN_VS = `#version 300 es
precision highp float; precision highp int;
uniform highp sampler2D uH; uniform highp sampler2D uB;
uniform ivec2 uSize; uniform vec2 uOrigin; uniform float uCell; uniform mat4 uMVP;
uniform ivec2 uChunk; uniform int uStep; uniform int uN; uniform float uSkirt;
out vec3 vN; out float vD; out float vH;
float h(int i, int j) { return texelFetch(uH, ivec2(clamp(i, 0, uSize.x - 1), clamp(j, 0, uSize.y - 1)), 0).r; }
void main() {
  int v = gl_VertexID, gi, gj;
  float drop = 0.0;
  if (v < uN * uN) { gi = v % uN; gj = v / uN; }
  else { // skirt vertex: border vertex t of edge e (bottom, right, top, left), lowered
    int k = v - uN * uN, e = k / uN, t = k % uN;
    gi = e == 0 || e == 2 ? t : (e == 1 ? uN - 1 : 0);
    gj = e == 1 || e == 3 ? t : (e == 2 ? uN - 1 : 0);
    drop = uSkirt;
  }
  int i = min(uChunk.x + gi * uStep, uSize.x - 1), j = min(uChunk.y + gj * uStep, uSize.y - 1);
  float z = h(i, j);
  // normal from central differences at full resolution (one-sided at the window's border)
  int il = max(i - 1, 0), ir = min(i + 1, uSize.x - 1), jd = max(j - 1, 0), ju = min(j + 1, uSize.y - 1);
  float dzx = (h(ir, j) - h(il, j)) / (float(max(ir - il, 1)) * uCell);
  float dzy = (h(i, ju) - h(i, jd)) / (float(max(ju - jd, 1)) * uCell);
  vN = normalize(vec3(-dzx, -dzy, 1.0));
  vD = z - texelFetch(uB, ivec2(i, j), 0).r;
  vH = z;
  gl_Position = uMVP * vec4(uOrigin + (vec2(i, j) + 0.5) * uCell, z - drop, 1.0);
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
// Colliders: a unit shape (sphere, box, cylinder along y) scaled, rotated and placed.
const SHAPE_VS = `#version 300 es
precision highp float;
in vec3 aP; in vec3 aN;
uniform mat4 uMVP; uniform vec3 uPos; uniform vec3 uScale; uniform vec4 uQ;
out vec3 vN;
vec3 rot(vec4 q, vec3 v) { vec3 u = q.yzw; return v + 2.0 * cross(u, cross(u, v) + q.x * v); }
void main() {
  vN = rot(uQ, aN / uScale);
  gl_Position = uMVP * vec4(uPos + rot(uQ, aP * uScale), 1.0);
}`;
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

// One chunk's triangles at LoD step `step`: the (n-1)² grid quads, then the skirt strips.
function chunkIndices(step) {
  const n = CHUNK / step + 1, idx = [];
  for (let j = 0; j + 1 < n; j++)
    for (let i = 0; i + 1 < n; i++) {
      const a = j * n + i;
      idx.push(a, a + 1, a + n, a + 1, a + n + 1, a + n);
    }
  const border = (e, t) => (e === 0 ? t : e === 1 ? t * n + n - 1 : e === 2 ? (n - 1) * n + t : t * n);
  for (let e = 0; e < 4; e++)
    for (let t = 0; t + 1 < n; t++) {
      const a = border(e, t), b = border(e, t + 1), sa = n * n + e * n + t, sb = sa + 1;
      idx.push(a, b, sa, b, sb, sa);
    }
  return new Uint32Array(idx);
}

function shapeMesh(kind) {
  const p = [], nrm = [], idx = [];
  if (kind === 'box') {
    for (const [ax, s] of [[0, 1], [0, -1], [1, 1], [1, -1], [2, 1], [2, -1]]) {
      const u = (ax + 1) % 3, v = (ax + 2) % 3, base = p.length / 3;
      for (const [a, b] of [[-1, -1], [1, -1], [1, 1], [-1, 1]]) {
        const q = [0, 0, 0], n = [0, 0, 0];
        q[ax] = s; q[u] = a; q[v] = b; n[ax] = s;
        p.push(...q); nrm.push(...n);
      }
      idx.push(base, base + 1, base + 2, base, base + 2, base + 3);
    }
  } else if (kind === 'cylinder') { // axis y, radius 1, y in [-1, 1]
    const S = 24;
    for (let k = 0; k <= S; k++) {
      const a = (k / S) * 2 * Math.PI, x = Math.cos(a), z = Math.sin(a);
      p.push(x, -1, z, x, 1, z); nrm.push(x, 0, z, x, 0, z);
    }
    for (let k = 0; k < S; k++) idx.push(2 * k, 2 * k + 1, 2 * k + 2, 2 * k + 1, 2 * k + 3, 2 * k + 2);
    for (const y of [-1, 1]) {
      const c = p.length / 3;
      p.push(0, y, 0); nrm.push(0, y, 0);
      for (let k = 0; k <= S; k++) {
        const a = (k / S) * 2 * Math.PI;
        p.push(Math.cos(a), y, Math.sin(a)); nrm.push(0, y, 0);
      }
      for (let k = 0; k < S; k++) idx.push(c, c + 1 + k, c + 2 + k);
    }
  } else { // sphere
    const S = 16, R = 10;
    for (let a = 0; a <= R; a++)
      for (let b = 0; b <= S; b++) {
        const th = (a / R) * Math.PI, ph = (b / S) * 2 * Math.PI;
        const v = [Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th)];
        p.push(...v); nrm.push(...v);
      }
    for (let a = 0; a < R; a++)
      for (let b = 0; b < S; b++) {
        const i = a * (S + 1) + b;
        idx.push(i, i + S + 1, i + 1, i + 1, i + S + 1, i + S + 2);
      }
  }
  const vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  for (const [name, data] of [['aP', p], ['aN', nrm]]) {
    const vb = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, vb);
    gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(data), gl.STATIC_DRAW);
    const loc = gl.getAttribLocation(shape.p, name);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, 3, gl.FLOAT, false, 0, 0);
  }
  const ib = gl.createBuffer();
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ib);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, new Uint16Array(idx), gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  return { vao, count: idx.length };
}

let terrain, shape, gpu = {};
function initGL() {
  terrain = program(TERRAIN_VS, TERRAIN_FS);
  shape = program(SHAPE_VS, SHAPE_FS);
  gpu.vao = gl.createVertexArray(); // no attributes: vertices come from gl_VertexID
  gpu.levels = [];
  gl.bindVertexArray(gpu.vao);
  for (let l = 0; l < LOD_LEVELS; l++) {
    const ibo = gl.createBuffer(), idx = chunkIndices(1 << l);
    gpu.levels.push({ ibo, count: idx.length, gridCount: (CHUNK >> l) ** 2 * 6 });
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, ibo);
    gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
  }
  gl.bindVertexArray(null);
  gpu.texH = gl.createTexture();
  gpu.texB = gl.createTexture();
  gpu.shapes = { sphere: shapeMesh('sphere'), box: shapeMesh('box'), cylinder: shapeMesh('cylinder') };
}

function toMetres(ints, upm, out) {
  for (let i = 0; i < ints.length; i++) out[i] = ints[i] / upm;
  return out;
}

function allocTexture(tex, w, h, data) {
  gl.bindTexture(gl.TEXTURE_2D, tex);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
  gl.pixelStorei(gl.UNPACK_ROW_LENGTH, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_PIXELS, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_ROWS, 0);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.R32F, w, h, 0, gl.RED, gl.FLOAT, data);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
}

// A new window: both textures anew, and the skirt depth from its height range.
function rebuildMesh(m, hs) {
  const upm = app.world.units_per_m;
  gpu.metres = new Float32Array(m.w * m.h);
  allocTexture(gpu.texB, m.w, m.h, toMetres(app.baseline, upm, new Float32Array(m.w * m.h)));
  allocTexture(gpu.texH, m.w, m.h, toMetres(hs, upm, gpu.metres));
  let lo = Infinity, hi = -Infinity;
  for (const v of hs) {
    if (v < lo) lo = v;
    if (v > hi) hi = v;
  }
  // deeper than any gap can be: the window's relief plus what deformation may add
  gpu.skirt = (hi - lo) / upm + 0.5;
  app.dirtyBox = null;
}

// Upload only the rows and columns the last deltas touched.
function uploadDirty(m, hs) {
  const b = app.dirtyBox;
  app.dirtyBox = null;
  if (!b) return;
  const upm = app.world.units_per_m, f = gpu.metres;
  for (let j = b.y0; j < b.y1; j++)
    for (let i = b.x0, k = j * m.w + b.x0; i < b.x1; i++, k++) f[k] = hs[k] / upm;
  gl.bindTexture(gl.TEXTURE_2D, gpu.texH);
  gl.pixelStorei(gl.UNPACK_ROW_LENGTH, m.w);
  gl.pixelStorei(gl.UNPACK_SKIP_PIXELS, b.x0);
  gl.pixelStorei(gl.UNPACK_SKIP_ROWS, b.y0);
  gl.texSubImage2D(gl.TEXTURE_2D, 0, b.x0, b.y0, b.x1 - b.x0, b.y1 - b.y0, gl.RED, gl.FLOAT, f);
  gl.pixelStorei(gl.UNPACK_ROW_LENGTH, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_PIXELS, 0);
  gl.pixelStorei(gl.UNPACK_SKIP_ROWS, 0);
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
// General 4x4 inverse (column-major), for un-projecting the pointer.
function invert(m) {
  const a = m, inv = new Array(16);
  inv[0] = a[5] * a[10] * a[15] - a[5] * a[11] * a[14] - a[9] * a[6] * a[15] + a[9] * a[7] * a[14] + a[13] * a[6] * a[11] - a[13] * a[7] * a[10];
  inv[4] = -a[4] * a[10] * a[15] + a[4] * a[11] * a[14] + a[8] * a[6] * a[15] - a[8] * a[7] * a[14] - a[12] * a[6] * a[11] + a[12] * a[7] * a[10];
  inv[8] = a[4] * a[9] * a[15] - a[4] * a[11] * a[13] - a[8] * a[5] * a[15] + a[8] * a[7] * a[13] + a[12] * a[5] * a[11] - a[12] * a[7] * a[9];
  inv[12] = -a[4] * a[9] * a[14] + a[4] * a[10] * a[13] + a[8] * a[5] * a[14] - a[8] * a[6] * a[13] - a[12] * a[5] * a[10] + a[12] * a[6] * a[9];
  inv[1] = -a[1] * a[10] * a[15] + a[1] * a[11] * a[14] + a[9] * a[2] * a[15] - a[9] * a[3] * a[14] - a[13] * a[2] * a[11] + a[13] * a[3] * a[10];
  inv[5] = a[0] * a[10] * a[15] - a[0] * a[11] * a[14] - a[8] * a[2] * a[15] + a[8] * a[3] * a[14] + a[12] * a[2] * a[11] - a[12] * a[3] * a[10];
  inv[9] = -a[0] * a[9] * a[15] + a[0] * a[11] * a[13] + a[8] * a[1] * a[15] - a[8] * a[3] * a[13] - a[12] * a[1] * a[11] + a[12] * a[3] * a[9];
  inv[13] = a[0] * a[9] * a[14] - a[0] * a[10] * a[13] - a[8] * a[1] * a[14] + a[8] * a[2] * a[13] + a[12] * a[1] * a[10] - a[12] * a[2] * a[9];
  inv[2] = a[1] * a[6] * a[15] - a[1] * a[7] * a[14] - a[5] * a[2] * a[15] + a[5] * a[3] * a[14] + a[13] * a[2] * a[7] - a[13] * a[3] * a[6];
  inv[6] = -a[0] * a[6] * a[15] + a[0] * a[7] * a[14] + a[4] * a[2] * a[15] - a[4] * a[3] * a[14] - a[12] * a[2] * a[7] + a[12] * a[3] * a[6];
  inv[10] = a[0] * a[5] * a[15] - a[0] * a[7] * a[13] - a[4] * a[1] * a[15] + a[4] * a[3] * a[13] + a[12] * a[1] * a[7] - a[12] * a[3] * a[5];
  inv[14] = -a[0] * a[5] * a[14] + a[0] * a[6] * a[13] + a[4] * a[1] * a[14] - a[4] * a[2] * a[13] - a[12] * a[1] * a[6] + a[12] * a[2] * a[5];
  inv[3] = -a[1] * a[6] * a[11] + a[1] * a[7] * a[10] + a[5] * a[2] * a[11] - a[5] * a[3] * a[10] - a[9] * a[2] * a[7] + a[9] * a[3] * a[6];
  inv[7] = a[0] * a[6] * a[11] - a[0] * a[7] * a[10] - a[4] * a[2] * a[11] + a[4] * a[3] * a[10] + a[8] * a[2] * a[7] - a[8] * a[3] * a[6];
  inv[11] = -a[0] * a[5] * a[11] + a[0] * a[7] * a[9] + a[4] * a[1] * a[11] - a[4] * a[3] * a[9] - a[8] * a[1] * a[7] + a[8] * a[3] * a[5];
  inv[15] = a[0] * a[5] * a[10] - a[0] * a[6] * a[9] - a[4] * a[1] * a[10] + a[4] * a[2] * a[9] + a[8] * a[1] * a[6] - a[8] * a[2] * a[5];
  const det = a[0] * inv[0] + a[1] * inv[4] + a[2] * inv[8] + a[3] * inv[12];
  return det ? inv.map((v) => v / det) : null;
}

// The terrain point under a CSS pixel: the pointer's ray marched through the height
// field (coarse steps, then bisection), or null when it misses the window.
function pick(cx, cy) {
  const m = app.mvp, mir = app.mirror, w = app.world;
  if (!m || !mir || !w) return null;
  const inv = invert(m);
  if (!inv) return null;
  const ndc = [(cx / canvas.clientWidth) * 2 - 1, 1 - (cy / canvas.clientHeight) * 2];
  const un = (z) => {
    const c = [0, 1, 2, 3].map((r) => inv[r] * ndc[0] + inv[4 + r] * ndc[1] + inv[8 + r] * z + inv[12 + r]);
    return [c[0] / c[3], c[1] / c[3], c[2] / c[3]];
  };
  const a = un(-1), b = un(1);
  const at = (t) => [a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t];
  const inside = (p) => p[0] >= mir.x * w.cell_size_m && p[1] >= mir.y * w.cell_size_m &&
    p[0] < (mir.x + mir.w) * w.cell_size_m && p[1] < (mir.y + mir.h) * w.cell_size_m;
  const below = (p) => inside(p) && p[2] <= heightAt(p[0], p[1]);
  const len = Math.hypot(b[0] - a[0], b[1] - a[1], b[2] - a[2]);
  const steps = Math.min(20000, Math.ceil(len / (w.cell_size_m * 2)));
  let prev = 0;
  for (let k = 1; k <= steps; k++) {
    const t = k / steps;
    if (below(at(t))) {
      let lo = prev, hi = t;
      for (let r = 0; r < 30; r++) {
        const mid = (lo + hi) / 2;
        if (below(at(mid))) hi = mid;
        else lo = mid;
      }
      const p = at(hi);
      return [p[0], p[1], heightAt(p[0], p[1])];
    }
    prev = t;
  }
  return null;
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

// LoD level per chunk from its distance to the eye; windows up to MAX_FULL cells stay at
// full detail everywhere.
function chooseLevels(m, w, eye) {
  const out = [], cell = w.cell_size_m, lod = m.w * m.h > MAX_FULL;
  for (let cy = 0; cy < m.h; cy += CHUNK)
    for (let cx = 0; cx < m.w; cx += CHUNK) {
      let level = 0;
      if (lod) {
        const x = (m.x + cx + Math.min(CHUNK, m.w - cx) / 2) * cell, y = (m.y + cy + Math.min(CHUNK, m.h - cy) / 2) * cell;
        const d = Math.hypot(x - eye[0], y - eye[1], heightAt(x, y) - eye[2]);
        level = Math.max(0, Math.min(LOD_LEVELS - 1, Math.floor(Math.log2(d / (LOD_DIST * CHUNK * cell)))));
      }
      out.push({ x: cx, y: cy, level });
    }
  return out;
}

// [colour, drawable] per collider: the page's own (local pose, highlighted), then the
// COLLIDERS frame's others and demo actors.
const COLOURS = { own: [0.9, 0.2, 0.25], other: [0.25, 0.55, 0.95], demo: [0.55, 0.62, 0.5] };
function drawables() {
  const list = [], o = app.own;
  if (o && o.id) list.push({ colour: COLOURS.own, kind: P.ColliderKind.SPHERE, dims: [o.radius, 0, 0], p: [o.x, o.y, o.z], q: [1, 0, 0, 0] });
  for (const c of app.colliders) {
    if (o && c.id === o.id) continue;
    list.push({ ...c, colour: c.owner === P.Owner.OWN ? COLOURS.own : c.owner === P.Owner.OTHER ? COLOURS.other : COLOURS.demo });
  }
  return list;
}

function drawShape(mesh, pos, scale, q, colour) {
  gl.uniform3fv(shape.u.uPos, pos);
  gl.uniform3fv(shape.u.uScale, scale);
  gl.uniform4fv(shape.u.uQ, q);
  gl.uniform3fv(shape.u.uColor, colour);
  gl.bindVertexArray(mesh.vao);
  gl.drawElements(gl.TRIANGLES, mesh.count, gl.UNSIGNED_SHORT, 0);
}

const qmul = ([aw, ax, ay, az], [bw, bx, by, bz]) => [aw * bw - ax * bx - ay * by - az * bz,
  aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw];
const qrot = (q, v) => { const r = qmul(qmul(q, [0, ...v]), [q[0], -q[1], -q[2], -q[3]]); return r.slice(1); };

// A lugged wheel's grousers (the COLLIDERS extension) as boxes, as server/collider/lugs.c presses
// them: lug k along the entry's -z turned 2πk/count about its y, a plate across the whole width,
// thickness along the rim, from r - max(height, thickness) (inside the rim) out to r + height.
// [{p, half, q}]: centre, half extents, orientation.
function lugBoxes(c) {
  const g = c.grousers;
  if (!g || c.kind !== P.ColliderKind.CYLINDER) return [];
  const [r, hl] = c.dims, inner = Math.max(r - Math.max(g.height, g.thickness), 0), outer = r + g.height;
  const qn = Math.hypot(...c.q) || 1, q = c.q.map((v) => v / qn), out = [];
  for (let k = 0; k < g.count; k++) {
    const a = (Math.PI * k) / g.count, ql = qmul(q, [Math.cos(a), 0, Math.sin(a), 0]);
    const o = qrot(ql, [0, 0, -(inner + outer) / 2]);
    out.push({ p: [c.p[0] + o[0], c.p[1] + o[1], c.p[2] + o[2]], half: [g.thickness / 2, hl, (outer - inner) / 2], q: ql });
  }
  return out;
}

function drawCollider(c) {
  const K = P.ColliderKind, S = gpu.shapes, [a, b, d] = c.dims;
  const qn = Math.hypot(...c.q) || 1, q = c.q.map((v) => v / qn);
  if (c.kind === K.SPHERE) drawShape(S.sphere, c.p, [a, a, a], q, c.colour);
  else if (c.kind === K.BOX || c.kind === K.MESH) drawShape(S.box, c.p, [a, b, d], q, c.colour);
  else {
    drawShape(S.cylinder, c.p, [a, b, a], q, c.colour);
    for (const l of lugBoxes(c)) drawShape(S.box, l.p, l.half, l.q, c.colour);
    if (c.kind === K.CAPSULE) // hemispheres at both ends of the axis (the entry's y)
      for (const s of [-1, 1]) {
        const [qw, qx, qy, qz] = q, y = s * b; // rotate (0, y, 0) by q
        const off = [2 * (qx * qy - qw * qz) * y, (1 - 2 * (qx * qx + qz * qz)) * y, 2 * (qy * qz + qw * qx) * y];
        drawShape(S.sphere, [c.p[0] + off[0], c.p[1] + off[1], c.p[2] + off[2]], [a, a, a], q, c.colour);
      }
  }
}

function draw() {
  resize();
  gl.viewport(0, 0, canvas.width, canvas.height);
  gl.clearColor(...app.background, 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  const m = app.mirror, w = app.world;
  if (!m || !w) return;
  if (app.meshDirty || app.dirty) {
    const hs = (app.uploaded = shownHeights(m));
    if (app.meshDirty) rebuildMesh(m, hs);
    else uploadDirty(m, hs);
  }
  noteDrawn(m, app.uploaded || m.heights);
  app.meshDirty = false;
  app.dirty = false;
  const extent = Math.max(m.w, m.h) * w.cell_size_m;
  if (!cam.dist) cam.dist = Math.min(extent, 512 * w.cell_size_m) * 1.25;
  cam.maxDist = extent * 4;
  const tz = heightAt(app.target[0], app.target[1]);
  const t = [app.target[0], app.target[1], tz];
  const e = [t[0] + cam.dist * Math.cos(cam.pitch) * Math.cos(cam.yaw), t[1] + cam.dist * Math.cos(cam.pitch) * Math.sin(cam.yaw), t[2] + cam.dist * Math.sin(cam.pitch)];
  const mvp = mul(perspective(0.8, canvas.width / canvas.height, cam.dist * 0.01, cam.dist * 10 + extent), lookAt(e, t, [0, 0, 1]));
  app.mvp = mvp;
  app.eye = e;
  gl.enable(gl.DEPTH_TEST);
  gl.useProgram(terrain.p);
  gl.uniformMatrix4fv(terrain.u.uMVP, false, mvp);
  gl.uniform2i(terrain.u.uSize, m.w, m.h);
  gl.uniform2f(terrain.u.uOrigin, m.x * w.cell_size_m, m.y * w.cell_size_m);
  gl.uniform1f(terrain.u.uCell, w.cell_size_m);
  gl.uniform3fv(terrain.u.uLight, LIGHT);
  gl.uniform1f(terrain.u.uScale, 0.04);
  gl.uniform1f(terrain.u.uSkirt, gpu.skirt);
  gl.activeTexture(gl.TEXTURE0);
  gl.bindTexture(gl.TEXTURE_2D, gpu.texH);
  gl.uniform1i(terrain.u.uH, 0);
  gl.activeTexture(gl.TEXTURE1);
  gl.bindTexture(gl.TEXTURE_2D, gpu.texB);
  gl.uniform1i(terrain.u.uB, 1);
  gl.bindVertexArray(gpu.vao);
  app.chunks = chooseLevels(m, w, e);
  for (const c of app.chunks) {
    const lv = gpu.levels[c.level];
    gl.uniform2i(terrain.u.uChunk, c.x, c.y);
    gl.uniform1i(terrain.u.uStep, 1 << c.level);
    gl.uniform1i(terrain.u.uN, (CHUNK >> c.level) + 1);
    gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, lv.ibo);
    gl.drawElements(gl.TRIANGLES, app.skirts ? lv.count : lv.gridCount, gl.UNSIGNED_INT, 0);
  }
  gl.useProgram(shape.p);
  gl.uniformMatrix4fv(shape.u.uMVP, false, mvp);
  gl.uniform3fv(shape.u.uLight, LIGHT);
  for (const c of drawables()) drawCollider(c);
  gl.bindVertexArray(null);
  app.framesDrawn++;
  // What scripts/screenshot waits for: this frame showed the world's snapshot, coloured against
  // the scene's base terrain, while connected (not the "connecting" screen, not a stale world).
  app.snapshotShown = app.connected && app.baseFromServer;
}

// What this frame draws, for the tests: the last batch sent, the last ACK, and how many cells
// are drawn lower than the mirror holds (the predicted rut the server has not sent yet).
function noteDrawn(m, hs) {
  let lower = 0;
  const b = prediction.box(); // only there may the drawn heights differ from the mirror's
  if (b && hs !== m.heights && hs.length === m.heights.length)
    for (let j = b.y0; j < b.y1; j++)
      for (let k = j * m.w + b.x0, e = j * m.w + b.x1; k < e; k++) if (hs[k] < m.heights[k]) lower++;
  app.drawn = { frame: app.framesDrawn + 1, seq: app.seq - 1, ackedSeq: app.ackedSeq, lower };
}

let last = performance.now();
function frame(now) {
  // The page's collider moves at real-time speed whatever the frame rate: a slow frame (software
  // GL) drives the whole time it took, in steps of at most 50 ms that each send their pose, so
  // the path is not skipped either. Past a second (a hidden tab) the rest is dropped.
  const elapsed = Math.min(1, (now - last) / 1000);
  last = now;
  if (app.own && keys.size) {
    // the page's own clock of key driving, so a test can check the distance against the time
    // the page integrated rather than against its own (loaded) wall clock
    app.keyClock.s += elapsed;
    app.keyClock.maxStep = Math.max(app.keyClock.maxStep, elapsed);
  }
  for (let left = elapsed; left > 1e-6; left -= 0.05) {
    keyDrive(Math.min(0.05, left));
    dragDrive(Math.min(0.05, left));
  }
  sendPoses(now);
  // Draw only when something changed: software GL is slow, keep the main thread free.
  const o = app.own, sig = [canvas.clientWidth, canvas.clientHeight, devicePixelRatio, cam.yaw, cam.pitch, cam.dist,
    ...(app.target || []), o ? o.x + o.y + o.z + o.id : 0, app.mirror ? app.mirror.x + app.mirror.w : -1, app.skirts, ...app.background].join();
  const need = app.dirty || app.meshDirty || app.collidersChanged || sig !== app.lastSig || now - (app.lastDraw || 0) > 1000;
  if (gl && need && !app.hold) {
    app.lastSig = sig;
    app.lastDraw = now;
    app.collidersChanged = false;
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
    const r = await fetch('/v1/stats', apiInit);
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
  // the heights a frame would draw now (the mirror with the prediction pasted in) and what
  // the last frame drew: {frame, seq, ackedSeq, lower}
  get shown() { return app.mirror ? Int32Array.from(prediction.heights(app.mirror)) : null; },
  get drawn() { return { ...app.drawn }; },
  // the height (units) the last frame drew at world point (x, y) metres; null outside the window
  drawnAt(x, y) {
    const m = app.mirror, w = app.world;
    if (!m || !w) return null;
    const i = Math.floor(x / w.cell_size_m) - m.x, j = Math.floor(y / w.cell_size_m) - m.y;
    if (i < 0 || j < 0 || i >= m.w || j >= m.h) return null;
    return (app.uploaded || m.heights)[j * m.w + i];
  },
  // the prediction: {enabled, available, reason, active, window, pending, predicted,
  // reconciled, replayed, exact, skipped, onTime, lastDiffering, errors, lastError} (predict.mjs's counters)
  get prediction() { return prediction.stats(); },
  // desync detection (PROTOCOL.md "CHECKSUM"): {checksumFrames, checksumTick, tilesDiffering, tilesResynced}
  get desync() { return { ...app.desync, checksumTick: Number(app.desync.checksumTick) }; },
  // base snapshots (PROTOCOL.md "Base snapshots", "Slope snapshots"): asked for (the twin
  // loaded; slope snapshots are offered with them), agreed by the world message, and the
  // snapshot rectangles received: {asked, agreed, agreedSlope, absolute, base, slope}
  get snapshots() {
    return { asked: !!app.twins, agreed: !!app.world?.snapshot_base, agreedSlope: !!app.world?.snapshot_slope, ...app.snapshots };
  },
  get seq() { return app.seq; },
  get ackedSeq() { return app.ackedSeq; },
  get region() { const m = app.mirror; return m ? { x: m.x, y: m.y, w: m.w, h: m.h } : null; },
  get connected() { return app.connected; },
  get framesDrawn() { return app.framesDrawn; },
  // true once a frame has drawn the world's snapshot against its base terrain while connected:
  // the moment a picture of the page shows the terrain (scripts/screenshot waits for it)
  get ready() { return app.connected && !!app.snapshotShown; },
  // 1 once the colours are against the scene's base terrain (not the first snapshot)
  get baseFromServer() { return !!app.baseFromServer; },
  get collider() { return app.own ? { ...app.own } : null; },
  get world() { return app.world; },
  get wsUrl() { return wsUrl; },
  // the latest COLLIDERS frame: [{id, owner (0 own, 1 other, 2 demo), kind, dims, p, q, and a
  // lugged wheel's grousers}]
  get colliders() { return app.colliders.map((c) => ({ ...c })); },
  // the boxes drawn for a collider's grousers: [{p, half, q}] (none for a smooth one)
  lugs(id) { const c = app.colliders.find((k) => k.id === id); return c ? lugBoxes(c) : []; },
  // the chunks drawn last frame: [{x, y (window cells), level (LoD, step 2^level)}]
  get chunks() { return app.chunks.map((c) => ({ ...c })); },
  get camera() { return { ...cam, target: app.target ? [...app.target] : null, eye: app.eye ? [...app.eye] : null }; },
  // seconds of frame time the keys drove the collider for, and the longest single frame of it
  get keyClock() { return { ...app.keyClock }; },
  get dragTarget() { return app.dragTarget ? [...app.dragTarget] : null; },
  // test hooks: camera, background colour, skirts on/off (off shows the cracks they hide)
  setCamera({ yaw, pitch, dist, target } = {}) {
    if (yaw !== undefined) cam.yaw = yaw;
    if (pitch !== undefined) cam.pitch = pitch;
    if (dist !== undefined) cam.dist = dist;
    if (target) {
      app.target = [target[0], target[1], 0];
      followCamera(false);
    }
  },
  setBackground(rgb) { app.background = rgb.slice(0, 3); },
  // true keeps the last frame on the canvas (no redraws), so that a screenshot under software GL
  // does not wait behind frames (scripts/screenshot); the connection and the mirror go on
  hold(on) { app.hold = !!on; },
  setSkirts(on) { app.skirts = !!on; },
  pick,
  createCollider,
  drive,
  lift() { if (app.own) app.own.lifted = true; },
  lower() { if (app.own) app.own.lifted = false; },
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
