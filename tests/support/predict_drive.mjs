// predict_drive.mjs: web/predict.mjs against a real daemon, for tests/integration/clients/test_predict_js.py.
// Two websocket connections (a WebSocket: run with --import tests/support/node_websocket.mjs) with the
// viewer's codec (web/terrad_codec.mjs): A subscribes to a window, predicts it on the
// WebAssembly twin and drives a sphere through it, one batch per tick; then B ploughs the
// same window while A keeps sending a lifted pose. Prints one JSON line of what it saw; the
// Python test asserts on it (and on GET /v1/heights).
//
// With a last argument `loaded` (a bekker world): one connection predicts the window and rolls a
// load-driven wheel (load_n: its height the server's, found where the soil carries the load)
// through it with slip 0.2 for 300 ticks instead, then back over the last third with the next
// soil-state restore failing (the twin library's test hook, terrad_twin_fault_restores, in
// this prediction's WebAssembly instance): what the Prediction counted and whether the
// connection's frames went on being handled.
//
// Usage: node --import tests/support/node_websocket.mjs predict_drive.mjs WS_URL MODULE.wasm CONFIG.json X Y W H [loaded]
import { readFileSync } from 'node:fs';
import { Mirror, MsgType, colliderCreate, decodeAck, decodeDelta, decodeForces, decodeHeader, encodePoseBatch, hello, parseControl, subscribe } from '../../web/terrad_codec.mjs';
import { loadTwinModule } from '../../web/twin.mjs';
import { Prediction } from '../../web/predict.mjs';

const [url, wasm, configPath, ...rect] = process.argv.slice(2);
const [RX, RY, RW, RH] = rect.map(Number);
const mode = rect[4] ?? 'predict';
const WAIT_MS = 120000; // generous: the machine may be loaded
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function until(what, fn) {
    const end = Date.now() + WAIT_MS;
    while (!fn()) {
        if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
        await sleep(5);
    }
}

class Conn {
    constructor(name) {
        this.name = name;
        this.replies = [];
        this.errors = [];
        this.mirrors = new Map();
        this.ackedSeq = 0;
        this.seq = 0;
        this.prediction = null;
        this.onAck = null;
        this.heights = []; // FORCES' height extension: [id, height_m] of each entry that has one
    }

    async open() {
        this.ws = new WebSocket(url, 'terrad.v1');
        this.ws.binaryType = 'arraybuffer';
        this.ws.onmessage = (e) => (typeof e.data === 'string' ? this.json(e.data) : this.binary(new Uint8Array(e.data)));
        await new Promise((ok, fail) => {
            this.ws.onopen = ok;
            this.ws.onerror = () => fail(new Error(`${this.name}: cannot connect to ${url}`));
        });
        this.ws.send(JSON.stringify(hello('', `predict-${this.name}`)));
        this.world = await this.reply('world');
    }

    json(text) {
        const m = parseControl(text);
        if (m.type === 'subscribed') this.mirrors.set(m.id, new Mirror(m.x, m.y, m.w, m.h, this.world.tile_size));
        if (m.type === 'error') this.errors.push(m);
        else this.replies.push(m);
    }

    binary(b) {
        const t = decodeHeader(b);
        if (t === MsgType.DELTA) {
            const { rects } = decodeDelta(b);
            for (const m of this.mirrors.values()) m.apply(rects);
        } else if (t === MsgType.ACK) {
            const { tick, seq } = decodeAck(b);
            this.ackedSeq = seq;
            this.ackedTick = tick;
            if (this.prediction) this.prediction.onAck(tick, seq);
            if (this.onAck) this.onAck();
        } else if (t === MsgType.FORCES) {
            for (const f of decodeForces(b).forces) if (f.height_m !== undefined) this.heights.push([f.id, f.height_m]);
        }
    }

    async reply(type) {
        let got;
        await until(`${this.name}: ${type}`, () => (got = this.replies.find((m) => m.type === type)));
        this.replies.splice(this.replies.indexOf(got), 1);
        return got;
    }

    async collider(shape, dims, opts = {}) {
        this.ws.send(JSON.stringify(colliderCreate(shape, dims, opts)));
        return (await this.reply('collider_created')).id;
    }

    send(poses) {
        this.seq++;
        const frame = encodePoseBatch(this.seq, poses);
        if (this.prediction) this.prediction.onSend(this.seq, poses); // before the bytes leave
        this.ws.send(frame);
        return this.seq;
    }
}

if (mode === 'loaded') {
    await loaded();
    process.exit(0);
}
const a = new Conn('a'), b = new Conn('b');
await a.open();
await b.open();
const { cell_size_m: cell, tick_hz: hz } = a.world;
a.ws.send(JSON.stringify(subscribe(RX, RY, RW, RH)));
const sid = (await a.reply('subscribed')).id;
const mirror = a.mirrors.get(sid);
await until('the snapshot', () => mirror.complete);
const start = Int32Array.from(mirror.heights);
const lowered = (row) => { // cells of a window row below where they started
    let c = 0;
    for (let k = row * RW; k < (row + 1) * RW; k++) if (mirror.heights[k] < start[k]) c++;
    return c;
};
const twinModule = await loadTwinModule(readFileSync(wasm));
const config = JSON.parse(readFileSync(configPath, 'utf8'));
const out = { errors: [] };
try {
    new Prediction(twinModule, a.world, new Mirror(RX, RY, RW, RH, a.world.tile_size), config);
} catch (e) {
    out.refusedIncomplete = String(e.message);
}
try {
    new Prediction(twinModule, a.world, mirror, { ...config, model: 'clay' });
} catch (e) {
    out.refusedModel = String(e.message);
}
const radius = 0.3, z = 0.4 + radius - 0.06;
const own = new Map();
const ball = await a.collider('sphere', { radius });
own.set(ball, { shape: 'sphere', dims: { radius } });
// A rolling wheel and a capsule lying along x (a quaternion of norm 1.04, turned from the
// wire's z axis): the server's pose arithmetic is the prediction's too.
const wheelDims = { radius, width: 0.2 }, capsuleDims = { radius: 0.12, half_length: 0.25 };
const wheel = await a.collider('wheel', wheelDims);
own.set(wheel, { shape: 'wheel', dims: wheelDims });
const capsule = await a.collider('capsule', capsuleDims);
own.set(capsule, { shape: 'capsule', dims: capsuleDims });
// A rolling wheel with grousers a cell tall: each lug stamps its own dent, on the server and
// in the prediction alike (the wire's grousers go into the twin's wheel).
const grousers = { count: 12, height: 0.05, thickness: 0.04 };
const lugged = await a.collider('wheel', wheelDims, { grousers });
own.set(lugged, { shape: 'wheel', dims: { ...wheelDims, grousers } });
const pred = (a.prediction = new Prediction(twinModule, a.world, mirror, config, own));
// Bad lugs: refused naming the field, and the prediction goes on.
out.refusedLugs = [[{ ...grousers, count: -1 }, 'grousers.count'], [{ ...grousers, count: 2.5 }, 'grousers.count'],
    [{ ...grousers, count: 1e12 }, 'grousers.count'], [{ ...grousers, height: 1 }, 'grousers.height'],
    [{ count: 12, height: 0.05 }, 'grousers.thickness']].map(([g, field]) => {
    try {
        pred.addCollider(999, 'wheel', { ...wheelDims, grousers: g });
        return `${field}: not refused`;
    } catch (e) {
        return String(e.message).includes(field) ? 'ok' : `${field}: ${e.message}`;
    }
});
const x0 = (RX + 24) * cell, x1 = (RX + RW - 24) * cell;
const pose = (id, i, n, row, dz = 0) => ({ id, x: x0 + ((x1 - x0) * i) / (n - 1), y: (row + 0.5) * cell, z: z + dz, qw: 1, qx: 0, qy: 0, qz: 0 });
const rowA = RY + 20, rowW = RY + 40, rowL = RY + 50, rowC = RY + 60, rowB = RY + 80, n = 600;
const rolling = (p) => ({ ...p, qw: Math.cos(p.x / radius / 2), qy: Math.sin(p.x / radius / 2) });
const ownPoses = (i, dz = 0) => {
    const cp = { ...pose(capsule, i, n, rowC, dz), z: 0.4 + 0.12 - 0.04 + dz, qw: 1.04 * Math.SQRT1_2, qy: 1.04 * Math.SQRT1_2 };
    return [pose(ball, i, n, rowA, dz), rolling(pose(wheel, i, n, rowW, dz)), cp, rolling(pose(lugged, i, n, rowL, dz))];
};
const t0 = Date.now();
for (let i = 0; i < n; i++) {
    const seq = a.send(ownPoses(i));
    if (!out.early) { // the batch is not even sent yet: the server cannot have its rut
        const mine = pred.heights();
        let lower = 0;
        for (let k = 0; k < mine.length; k++) if (mine[k] < mirror.heights[k]) lower++;
        if (lower) out.early = { cells: lower, seq, ackedSeq: a.ackedSeq };
    }
    await sleep(Math.max(0, t0 + ((i + 1) * 1000) / hz - Date.now()));
}
let last = a.send(ownPoses(n - 1, 5));
await until('the last ACK', () => a.ackedSeq >= last);
out.drive = { predicted: pred.predicted, reconciled: pred.reconciled, replayed: pred.replayed, exact: pred.exact, skipped: pred.skipped, onTime: pred.onTime };
out.settled = sameArrays(pred.heights(), mirror.heights);
out.ruts = [rowA, rowW, rowC, rowL].map((r) => lowered(r - RY));

// B ploughs A's window: only the server knows B's rut until A's next reconciliation.
const other = await b.collider('sphere', { radius });
const resets = [];
a.onAck = () => {
    if (pred.pending.length === 0) resets.push(sameArrays(pred.heights(), mirror.heights));
};
const before = { replayed: pred.replayed, exact: pred.exact };
const n2 = 240, t1 = Date.now();
for (let i = 0; i < n2; i++) {
    b.send([pose(other, i, n2, rowB)]);
    if (i % 2 === 0) a.send([pose(ball, n - 1, n, rowA, 5)]);
    await sleep(Math.max(0, t1 + ((i + 1) * 1000) / hz - Date.now()));
}
last = b.send([pose(other, n2 - 1, n2, rowB, 5)]);
await until('B\'s last ACK', () => b.ackedSeq >= last);
last = a.send([pose(ball, n - 1, n, rowA, 5)]);
await until('A\'s ACK after B', () => a.ackedSeq >= last);
out.other = { replayed: pred.replayed - before.replayed, exact: pred.exact - before.exact, resets: resets.length, resetsEqual: resets.filter(Boolean).length };
out.rutB = lowered(rowB - RY);
out.final = { tick: Number(a.ackedTick), settled: sameArrays(pred.heights(), mirror.heights), heights: Array.from(mirror.heights) };
out.errors = [...a.errors, ...b.errors];
console.log(JSON.stringify(out));
a.ws.close();
b.ws.close();
pred.destroy();
process.exit(0);

// A load-driven wheel, predicted: the counters, the rut's depth (units below the start), the
// heights the server found (FORCES' height extension) and whether a bad load is refused naming
// load_n.
async function loaded() {
    const c = new Conn('loaded');
    await c.open();
    const { cell_size_m: cell, tick_hz: hz } = c.world;
    c.ws.send(JSON.stringify(subscribe(RX, RY, RW, RH)));
    const mirror = c.mirrors.get((await c.reply('subscribed')).id);
    await until('the snapshot', () => mirror.complete);
    const start = Int32Array.from(mirror.heights);
    const config = JSON.parse(readFileSync(configPath, 'utf8'));
    const radius = 0.1, load = 40, z = 0.4 + radius; // the server's search starts there, once
    const wheel = await c.collider('wheel', { radius, width: 0.08 }, { loadN: load, forcesHeight: true });
    const own = new Map([[wheel, { shape: 'wheel', dims: { radius, width: 0.08, load_n: load } }]]);
    const pred = (c.prediction = new Prediction(await loadTwinModule(readFileSync(wasm)), c.world, mirror, config, own));
    const refused = [NaN, -3, Infinity].map((bad) => {
        try {
            pred.twin.setLoad(wheel, bad);
            return `${bad}: not refused`;
        } catch (e) {
            return String(e.message).includes('load_n') ? 'ok' : `${bad}: ${e.message}`;
        }
    });
    const x0 = (RX + 16) * cell, x1 = (RX + RW - 16) * cell, y = (RY + RH / 2) * cell, n = 300;
    const roll = async (from, to, n) => { // one batch a tick, until the last is acknowledged
        const t0 = Date.now();
        let last = 0;
        for (let i = 0; i < n; i++) {
            const x = from + ((to - from) * i) / (n - 1), angle = (x - from) / (radius * (1 - 0.2)); // slip 0.2
            last = c.send([{ id: wheel, x, y, z, qw: Math.cos(angle / 2), qx: 0, qy: Math.sin(angle / 2), qz: 0 }]);
            await sleep(Math.max(0, t0 + ((i + 1) * 1000) / hz - Date.now()));
        }
        await until('the last ACK', () => c.ackedSeq >= last);
    };
    await roll(x0, x1, n);
    let rut = 0;
    for (let k = 0; k < start.length; k++) rut = Math.max(rut, start[k] - mirror.heights[k]);
    const counters = () => ({ predicted: pred.predicted, reconciled: pred.reconciled, replayed: pred.replayed, exact: pred.exact, skipped: pred.skipped, onTime: pred.onTime, lastDiffering: pred.lastDiffering, errors: pred.errors, lastError: pred.lastError });
    const drive = counters(), settled = sameArrays(pred.heights(), mirror.heights);
    // Back over the last third with the next restore of the soil state failing: counted, and
    // the ACK handler (prediction first, then this drive's) goes on at every ACK after it.
    const resets = [];
    c.onAck = () => {
        if (pred.pending.length === 0) resets.push(sameArrays(pred.heights(), mirror.heights));
    };
    pred.twin.m.x.terrad_twin_fault_restores(1); // this instance's next restore: the next ACK's
    await roll(x1, x1 - (x1 - x0) / 3, 100);
    pred.twin.m.x.terrad_twin_fault_restores(0);
    const after = counters();
    console.log(JSON.stringify({
        drive, settled, rut, refused, errors: c.errors,
        found: c.heights.filter(([id]) => id === wheel).map(([, h]) => h),
        restore: { ...after, reconciled: after.reconciled - drive.reconciled, replayed: after.replayed - drive.replayed,
            exact: after.exact - drive.exact, resets: resets.length, resetsEqual: resets.filter(Boolean).length },
    }));
    c.ws.close();
    pred.destroy();
}

function sameArrays(x, y) {
    return x.length === y.length && x.every((v, i) => v === y[i]);
}
