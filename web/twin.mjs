// twin.mjs: the twin library (server/twin/terrad_twin.h) as WebAssembly, for browsers and Node:
// the daemon's CPU twin compiled from the same C source (build/terrad_twin.wasm, docs/engines.md),
// wrapped in a small class, with its prediction (terrad_twin_prediction_*: the one copy every
// client runs, predict.mjs calls it). The module is a WASI reactor with no start function; the few WASI
// calls libc may make (the clock for the engine's timings, stderr for a log line) are answered
// here, so no WASI runtime is needed. Errors from the library are thrown with its sentence.

const ENOSYS = 52;
const EBADF = 8;

function wasiShim(memory) {
    const view = () => new DataView(memory().buffer);
    const decoder = new TextDecoder();
    const nosys = () => ENOSYS;
    return {
        clock_time_get(_id, _precision, out) {
            const ns = BigInt(Math.round(performance.now() * 1e6));
            view().setBigUint64(out, ns, true);
            return 0;
        },
        fd_write(fd, iovs, count, written) {
            const v = view();
            let text = '';
            let total = 0;
            for (let i = 0; i < count; i++) {
                const ptr = v.getUint32(iovs + 8 * i, true);
                const len = v.getUint32(iovs + 8 * i + 4, true);
                text += decoder.decode(new Uint8Array(memory().buffer, ptr, len));
                total += len;
            }
            if (fd === 1 || fd === 2) console.error(text.replace(/\n$/, ''));
            v.setUint32(written, total, true);
            return 0;
        },
        fd_prestat_get: () => EBADF,
        proc_exit(code) {
            throw new Error(`terrad twin: exit ${code}`);
        },
        fd_close: nosys, fd_fdstat_get: nosys, fd_fdstat_set_flags: nosys, fd_filestat_get: nosys,
        fd_prestat_dir_name: nosys, fd_read: nosys, fd_seek: nosys, path_open: nosys,
    };
}

const ERROR_MAX = 256; // TERRAD_TWIN_ERROR_MAX

// Instantiate the module from its bytes (fetch(...).arrayBuffer() or fs.readFileSync).
export async function loadTwinModule(bytes) {
    let exports = null;
    const memory = () => exports.memory;
    const { instance } = await WebAssembly.instantiate(bytes, {
        wasi_snapshot_preview1: wasiShim(memory),
    });
    exports = instance.exports;
    return new TwinModule(exports);
}

class TwinModule {
    constructor(x) {
        this.x = x;
        this.err = x.malloc(ERROR_MAX);
    }
    // Copy bytes into the module's heap; the caller frees the pointer.
    alloc(bytes) {
        const p = this.x.malloc(Math.max(1, bytes.byteLength));
        if (!p) throw new Error('terrad twin: out of memory');
        new Uint8Array(this.x.memory.buffer, p, bytes.byteLength).set(
            new Uint8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength));
        return p;
    }
    string(s) {
        return this.alloc(new TextEncoder().encode(s + '\0'));
    }
    check(rc) {
        if (rc === 0) return rc;
        const mem = new Uint8Array(this.x.memory.buffer, this.err, ERROR_MAX);
        const end = mem.indexOf(0);
        throw new Error(`terrad twin: ${new TextDecoder().decode(mem.subarray(0, end < 0 ? ERROR_MAX : end))}`);
    }
    withStrings(strings, fn) {
        const ptrs = strings.map((s) => this.string(s));
        try {
            return fn(...ptrs);
        } finally {
            ptrs.forEach((p) => this.x.free(p));
        }
    }
    // fn(vertices, vertexCount, indices, triangleCount) with a mesh in the module's heap;
    // vertices: Float32Array (xyz), indices: Uint32Array (3 per triangle). Throws fn's error.
    withMesh(vertices, indices, fn) {
        const v = this.alloc(vertices);
        const i = this.alloc(indices);
        try {
            this.check(fn(v, vertices.length / 3, i, indices.length / 3));
        } finally {
            this.x.free(v);
            this.x.free(i);
        }
    }
    // config: {key: number | string} in terrad_twin.h's keys (strings for model, metric,
    // terrain.kind) into a new terrad_twin_config; the caller frees it.
    config(config) {
        const c = this.x.terrad_twin_config_new();
        if (!c) throw new Error('terrad twin: out of memory');
        try {
            for (const [key, value] of Object.entries(config)) {
                if (typeof value === 'string')
                    this.withStrings([key, value], (k, v) =>
                        this.check(this.x.terrad_twin_config_set_name(c, k, v, this.err)));
                else
                    this.withStrings([key], (k) =>
                        this.check(this.x.terrad_twin_config_set(c, k, value, this.err)));
            }
        } catch (e) {
            this.x.terrad_twin_config_free(c);
            throw e;
        }
        return c;
    }
    // heights: Int32Array of w * h, or null for the untouched base terrain.
    create(config, x, y, w, h, heights) {
        const c = this.config(config);
        try {
            const hp = heights ? this.alloc(heights) : 0;
            const t = this.x.terrad_twin_create(c, x, y, w, h, hp, this.err);
            if (hp) this.x.free(hp);
            if (!t) this.check(-1);
            return new Twin(this, t, { x, y, w, h });
        } finally {
            this.x.terrad_twin_config_free(c);
        }
    }
    // The library's prediction of a window from the server's heights there (Int32Array of
    // w * h); maxReplayTicks 0: 4 s of ticks. See TwinPrediction and predict.mjs.
    createPrediction(config, x, y, w, h, heights, maxReplayTicks = 0) {
        const c = this.config(config);
        try {
            const hp = this.alloc(heights);
            const p = this.x.terrad_twin_prediction_create(c, x, y, w, h, hp, maxReplayTicks, this.err);
            this.x.free(hp);
            if (!p) this.check(-1);
            return new TwinPrediction(this, p, { x, y, w, h });
        } finally {
            this.x.terrad_twin_config_free(c);
        }
    }
}

// A twin or a prediction in the module's heap.
class Handle {
    constructor(m, ptr, window) {
        this.m = m;
        this.ptr = ptr;
        this.window = window;
    }
    // fn(shape, radius, halfLength, hx, hy, hz) with the shape's name in the module's heap
    withShape(shape, { radius = 0, halfLength = 0, halfExtents = [0, 0, 0] }, fn) {
        this.m.withStrings([shape], (s) => this.m.check(fn(s, radius, halfLength, halfExtents[0], halfExtents[1], halfExtents[2])));
    }
    // fn(radius, halfLength, count, height, thickness): a wheel and its grousers (none: smooth).
    // The numbers go as they are (f64): the library refuses a bad one naming its field.
    withWheel({ radius = 0, halfLength = 0, grousers = null }, fn) {
        const g = grousers ?? { count: 0, height: 0, thickness: 0 };
        this.m.check(fn(radius, halfLength, g.count, g.height, g.thickness));
    }
}

const STATS = ['predicted', 'reconciled', 'replayed', 'exact', 'skipped', 'onTime', 'lastDiffering', 'pending'];

// terrad_twin_prediction_* (terrad_twin.h, "Prediction"): poses are {id, x, y, z, qw, qx, qy,
// qz} as on the wire (the library takes them through float32 and turns them as the server does).
export class TwinPrediction extends Handle {
    // shape: sphere {radius}, box {halfExtents}, capsule / cylinder {radius, halfLength} (the
    // wire's axis z), wheel {radius, halfLength: half its width}
    addCollider(id, shape, dims = {}) {
        this.withShape(shape, dims, (s, ...sizes) => this.m.x.terrad_twin_prediction_add_collider(this.ptr, id, s, ...sizes, this.m.err));
    }
    // The wire's wheel {radius, halfLength: half its width, grousers: {count, height, thickness}
    // (PROTOCOL.md collider_create) or none}
    addWheel(id, dims) {
        this.withWheel(dims, (...sizes) => this.m.x.terrad_twin_prediction_add_wheel(this.ptr, id, ...sizes, this.m.err));
    }
    // vertices: Float32Array (xyz), indices: Uint32Array (3 per triangle)
    addMesh(id, vertices, indices) {
        this.m.withMesh(vertices, indices, (v, nv, i, nt) => this.m.x.terrad_twin_prediction_add_mesh(this.ptr, id, v, nv, i, nt, this.m.err));
    }
    removeCollider(id) {
        this.m.check(this.m.x.terrad_twin_prediction_remove_collider(this.ptr, id, this.m.err));
    }
    // Load-driven (the wire's load_n, bekker worlds): the twin finds its height each tick as the
    // server does (terrad_twin_prediction_set_load); 0: pose-driven.
    setLoad(id, loadN) {
        this.m.check(this.m.x.terrad_twin_prediction_set_load(this.ptr, id, loadN, this.m.err));
    }
    // fn(ids, values, count) with the poses in the module's heap
    withPoses(poses, fn) {
        const m = this.m;
        const ids = m.alloc(Uint32Array.from(poses, (p) => p.id));
        const values = m.alloc(Float64Array.from(poses.flatMap((p) => [p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz])));
        try {
            m.check(fn(ids, values, poses.length));
        } finally {
            m.x.free(ids);
            m.x.free(values);
        }
    }
    // Batch seq is being sent: one tick of the twin at once.
    sent(seq, poses) {
        this.withPoses(poses, (ids, v, n) => this.m.x.terrad_twin_prediction_sent(this.ptr, seq, ids, v, n, this.m.err));
    }
    // The ACK of tick (BigInt or number), batch seq; server: the mirror's heights at tick
    // (Int32Array), or null while it resyncs.
    acked(tick, seq, server) {
        const m = this.m;
        const hp = server ? m.alloc(server) : 0;
        try {
            m.check(m.x.terrad_twin_prediction_acked(this.ptr, BigInt(tick), seq, hp, m.err));
        } finally {
            if (hp) m.x.free(hp);
        }
    }
    // Own colliders the server had posed before this prediction was made at the ACK of tick:
    // the poses of the latest acknowledged batches that moved them.
    resume(tick, poses) {
        this.withPoses(poses, (ids, v, n) => this.m.x.terrad_twin_prediction_resume(this.ptr, BigInt(tick), ids, v, n, this.m.err));
    }
    heights() {
        const { w, h } = this.window;
        const p = this.m.x.terrad_twin_prediction_heights(this.ptr);
        return new Int32Array(this.m.x.memory.buffer.slice(p, p + w * h * 4));
    }
    // {predicted, reconciled, replayed, exact, skipped, onTime, lastDiffering, pending}
    stats() {
        const v = new DataView(this.m.x.memory.buffer, this.m.x.terrad_twin_prediction_get_stats(this.ptr), 8 * STATS.length);
        return Object.fromEntries(STATS.map((k, i) => [k, Number(v.getBigUint64(8 * i, true))]));
    }
    // The seqs of the batches sent and not acknowledged yet, oldest first.
    pending() {
        const m = this.m;
        const n = m.x.terrad_twin_prediction_pending(this.ptr, 0, 0);
        const p = m.x.malloc(Math.max(1, 4 * n));
        try {
            m.x.terrad_twin_prediction_pending(this.ptr, p, n);
            return Array.from(new Uint32Array(m.x.memory.buffer.slice(p, p + 4 * n)));
        } finally {
            m.x.free(p);
        }
    }
    destroy() {
        this.m.x.terrad_twin_prediction_destroy(this.ptr);
        this.ptr = 0;
    }
}

export class Twin extends Handle {
    addCollider(id, shape, dims = {}) {
        this.withShape(shape, dims, (s, ...sizes) => this.m.x.terrad_twin_add_collider(this.ptr, id, s, ...sizes, this.m.err));
    }
    // A cylinder (axle local y) {radius, halfLength, grousers: {count, height, thickness} or none}
    addWheel(id, dims) {
        this.withWheel(dims, (...sizes) => this.m.x.terrad_twin_add_wheel(this.ptr, id, ...sizes, this.m.err));
    }
    // vertices: Float32Array (xyz), indices: Uint32Array (3 per triangle)
    addMesh(id, vertices, indices) {
        this.m.withMesh(vertices, indices, (v, nv, i, nt) => this.m.x.terrad_twin_add_mesh(this.ptr, id, v, nv, i, nt, this.m.err));
    }
    removeCollider(id) {
        this.m.check(this.m.x.terrad_twin_remove_collider(this.ptr, id, this.m.err));
    }
    // Load-driven (bekker): each tick the height where the soil carries loadN newtons
    // (terrad_twin_set_load); 0: pose-driven.
    setLoad(id, loadN) {
        this.m.check(this.m.x.terrad_twin_set_load(this.ptr, id, loadN, this.m.err));
    }
    // position [x, y, z] metres, orientation [w, x, y, z]
    setPose(id, [x, y, z], [qw, qx, qy, qz]) {
        this.m.check(this.m.x.terrad_twin_set_pose(this.ptr, id, x, y, z, qw, qx, qy, qz, this.m.err));
    }
    // The collider stood here in the last tick: the next tick sweeps from this pose (a
    // predicting client's reset to the server's acknowledged tick, docs/engines.md).
    place(id, [x, y, z], [qw, qx, qy, qz]) {
        this.m.check(this.m.x.terrad_twin_place(this.ptr, id, x, y, z, qw, qx, qy, qz, this.m.err));
    }
    tick() {
        this.m.check(this.m.x.terrad_twin_tick(this.ptr, this.m.err));
    }
    read(x = this.window.x, y = this.window.y, w = this.window.w, h = this.window.h) {
        const m = this.m;
        const p = m.x.malloc(w * h * 4);
        try {
            m.check(m.x.terrad_twin_read(this.ptr, x, y, w, h, p, m.err));
            return new Int32Array(m.x.memory.buffer.slice(p, p + w * h * 4));
        } finally {
            m.x.free(p);
        }
    }
    write(x, y, w, h, heights) {
        const m = this.m;
        const p = m.alloc(heights);
        try {
            m.check(m.x.terrad_twin_write(this.ptr, x, y, w, h, p, m.err));
        } finally {
            m.x.free(p);
        }
    }
    destroy() {
        this.m.x.terrad_twin_destroy(this.ptr);
        this.ptr = 0;
    }
}
