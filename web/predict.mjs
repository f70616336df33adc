// predict.mjs: client-side prediction for JavaScript clients (browsers and Node), the same
// steps as the Python client's terrad/predict.py (docs/engines.md, "Prediction"). A
// Prediction runs the WebAssembly twin (twin.mjs) on one subscription's window: each pose
// batch the client sends is one tick of the twin at once, with the client's own colliders
// at their new poses; at the server's ACK of tick t (batch seq), when the mirror holds the
// server's heights at t, it replays the server's ticks from the previous ACK's heights with
// the poses the ACKs say the server used and counts the cells that differ (0 whenever no
// other collider or edit touched the window), then resets the window to the mirror, places
// the own colliders where tick t left them and applies the batches sent after seq again.
// Nothing extra goes on the wire. The caller wires it to its connection: onSend before a
// POSE_BATCH's bytes leave, onAck after an ACK (whose DELTAs the mirror has applied).

const QUARTER_X = [0.7071067811865476, 0.7071067811865476, 0, 0];

// collider.c's quat_normalize and quat_multiply, operation for operation (doubles in both).
function normalize([w, x, y, z]) {
    const n = Math.sqrt(w * w + x * x + y * y + z * z);
    if (!(n > 1e-300) || !Number.isFinite(n)) return [1, 0, 0, 0];
    return [w / n, x / n, y / n, z / n];
}

function multiply(a, b) {
    return [a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]];
}

// A pose {id, x, y, z, qw, qx, qy, qz} as the server uses it: float32 on the wire, the
// quaternion normalised, a capsule's or cylinder's turned from the wire's z axis to y.
export function serverPose(p, axisZ) {
    const f = [p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz].map(Math.fround);
    let q = normalize(f.slice(3));
    if (axisZ) q = normalize(multiply(q, QUARTER_X));
    return [f.slice(0, 3), q];
}

const U32 = 0x100000000;
const upTo = (s, seq) => (seq - s + U32) % U32 < 0x80000000; // s <= seq, wrapping

function sameHeights(a, b) {
    if (a.length !== b.length) return false;
    for (let i = 0; i < a.length; i++) if (a[i] !== b[i]) return false;
    return true;
}

export class Prediction {
    // twinModule: loadTwinModule(...)'s module; world: the server's world message; mirror:
    // the subscription's complete Mirror (terrad_codec.mjs); config: the world's parameters
    // in the twin's keys (model, material, margin_cells, terrain.*); own: Map id ->
    // {shape, dims} of this client's colliders.
    constructor(twinModule, world, mirror, config = {}, own = new Map(), maxReplayTicks) {
        if (!mirror || !mirror.complete) throw new Error('mirror: the subscription has no snapshot yet');
        const cfg = {};
        for (const k of ['width', 'height', 'cell_size_m', 'units_per_m', 'tick_hz'])
            if (k in world) cfg[k] = world[k];
        Object.assign(cfg, config);
        this.mirror = mirror;
        this.own = own;
        this.twin = twinModule.create(cfg, mirror.x, mirror.y, mirror.w, mirror.h, mirror.heights);
        this.base = Int32Array.from(mirror.heights); // the server's heights at the last ACK
        this.baseTick = null;
        this.maxReplayTicks = maxReplayTicks ?? Math.trunc(4 * (cfg.tick_hz ?? 60));
        this.axisZ = new Map();
        this.acked = new Map(); // id -> [p, q] where the last acknowledged tick left it
        this.pending = []; // {seq, batch: Map id -> [p, q], predicted: Int32Array}
        // The counters, one assignment each so that tsc declares them for the TypeScript package.
        this.predicted = 0; // pose batches ticked locally
        this.reconciled = 0; // ACKs taken
        this.replayed = 0; // ACKs whose replay was compared with the server's heights
        this.exact = 0; // of those, with 0 cells differing
        this.skipped = 0; // ACKs not compared (resyncing, a long gap)
        this.onTime = 0; // ACKs whose batch's prediction already was the server's heights
        this.lastDiffering = 0; // cells of the last comparison
        for (const [id, { shape, dims }] of own) this.addCollider(id, shape, dims);
    }

    destroy() {
        this.twin.destroy();
    }

    heights() {
        return this.twin.read();
    }

    // dims as in collider_create: sphere radius; box half_extents; capsule / cylinder radius,
    // half_length; wheel radius, width; mesh vertices, indices (flat).
    addCollider(id, shape, dims) {
        if ((dims.material ?? 'default') !== 'default' || dims.pose)
            throw new Error(`collider ${id}: a predicted collider has the default material and gets its poses from POSE_BATCH`);
        if (shape === 'sphere') this.twin.addCollider(id, 'sphere', { radius: dims.radius });
        else if (shape === 'box') this.twin.addCollider(id, 'box', { halfExtents: dims.half_extents });
        else if (shape === 'capsule' || shape === 'cylinder')
            this.twin.addCollider(id, shape, { radius: dims.radius, halfLength: dims.half_length });
        else if (shape === 'wheel') this.twin.addCollider(id, 'cylinder', { radius: dims.radius, halfLength: dims.width / 2 });
        else if (shape === 'mesh') this.twin.addMesh(id, Float32Array.from(dims.vertices), Uint32Array.from(dims.indices));
        else throw new Error(`shape: "${shape}" cannot be predicted`);
        this.axisZ.set(id, shape === 'capsule' || shape === 'cylinder');
    }

    removeCollider(id) {
        if (!this.axisZ.has(id)) return;
        this.twin.removeCollider(id);
        this.axisZ.delete(id);
        this.acked.delete(id);
    }

    apply(batch) {
        for (const [id, [p, q]] of batch) if (this.axisZ.has(id)) this.twin.setPose(id, p, q);
        this.twin.tick();
        return this.twin.read();
    }

    // For own colliders the server had already posed when this Prediction was made (a window
    // made or moved while driving): call it on an ACK of tick, with the mirror at that tick
    // (right after the ACK, as the Prediction was made). last: Map id -> the pose (as sent) of
    // the latest acknowledged batch that moved it; later: [{seq, poses}] sent after the ACK's
    // seq, applied again as predictions. The next ACK then compares as with any other.
    resume(tick, last, later) {
        for (const [id, p] of last) if (this.axisZ.has(id)) this.acked.set(id, serverPose(p, this.axisZ.get(id)));
        this.baseTick = Number(tick);
        this.restart(this.base);
        this.pending = later.map(({ seq, poses }) => {
            const batch = new Map(poses.map((p) => [p.id, serverPose(p, this.axisZ.get(p.id) ?? false)]));
            return { seq, batch, predicted: this.apply(batch) };
        });
    }

    // Batch seq (poses as encodePoseBatch takes them) is about to be sent.
    onSend(seq, poses) {
        const batch = new Map(poses.map((p) => [p.id, serverPose(p, this.axisZ.get(p.id) ?? false)]));
        this.pending.push({ seq, batch, predicted: this.apply(batch) });
        this.predicted++;
    }

    restart(heights) {
        const { x, y, w, h } = this.mirror;
        this.twin.write(x, y, w, h, heights);
        for (const id of [...this.axisZ.keys()]) {
            if (this.acked.has(id)) {
                this.twin.place(id, ...this.acked.get(id));
            } else { // remove and add: the twin forgets a pose it was given
                this.twin.removeCollider(id);
                this.axisZ.delete(id);
                const { shape, dims } = this.own.get(id);
                this.addCollider(id, shape, dims);
            }
        }
    }

    // The server's ACK of tick (a BigInt or number), batch seq; the mirror is at that tick.
    onAck(tick, seq) {
        tick = Number(tick);
        const done = this.pending.filter((e) => upTo(e.seq, seq));
        this.pending = this.pending.filter((e) => !upTo(e.seq, seq));
        const keep = () => done.forEach((e) => e.batch.forEach((pose, id) => this.acked.set(id, pose)));
        if (!this.mirror.complete) { // resyncing: reconcile at the next ACK with heights
            this.skipped++;
            keep();
            return;
        }
        const server = this.mirror.heights;
        const last = done[done.length - 1];
        if (last && last.seq === seq && sameHeights(last.predicted, server)) this.onTime++;
        const gap = this.acked.size === 0 ? 1 : this.baseTick === null ? 0 : tick - this.baseTick;
        // Batches acknowledged together after a gap of ticks may have been taken at different
        // ticks of it (a slow client's older ACK is replaced by the newer one, PROTOCOL.md
        // "Slow clients"): which tick took which is not known, so that ACK is not compared.
        const spread = gap > 1 && done.length > 1;
        if (gap >= 1 && gap <= this.maxReplayTicks && !spread) {
            this.restart(this.base);
            for (let i = 0; i < gap - 1; i++) this.twin.tick(); // ticks without an ACK: poses stood still
            const merged = new Map();
            done.forEach((e) => e.batch.forEach((pose, id) => merged.set(id, pose)));
            const replay = this.apply(merged);
            let differing = 0;
            for (let i = 0; i < replay.length; i++) if (replay[i] !== server[i]) differing++;
            this.lastDiffering = differing;
            this.replayed++;
            if (differing === 0) this.exact++;
        } else {
            this.skipped++;
        }
        keep();
        this.base = Int32Array.from(server);
        this.baseTick = tick;
        this.restart(this.base);
        for (const e of this.pending) e.predicted = this.apply(e.batch);
        this.reconciled++;
    }
}
