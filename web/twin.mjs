// twin.mjs: the twin library (server/twin/terrad_twin.h) as WebAssembly, for browsers and Node:
// the daemon's CPU twin compiled from the same C source (build/terrad_twin.wasm, docs/engines.md),
// wrapped in a small class. The module is a WASI reactor with no start function; the few WASI
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
    // config: {key: number | string} in terrad_twin.h's keys (strings for model, metric,
    // terrain.kind); heights: Int32Array of w * h, or null for the untouched base terrain.
    create(config, x, y, w, h, heights) {
        const c = this.x.terrad_twin_config_new();
        try {
            for (const [key, value] of Object.entries(config)) {
                if (typeof value === 'string')
                    this.withStrings([key, value], (k, v) =>
                        this.check(this.x.terrad_twin_config_set_name(c, k, v, this.err)));
                else
                    this.withStrings([key], (k) =>
                        this.check(this.x.terrad_twin_config_set(c, k, value, this.err)));
            }
            const hp = heights ? this.alloc(heights) : 0;
            const t = this.x.terrad_twin_create(c, x, y, w, h, hp, this.err);
            if (hp) this.x.free(hp);
            if (!t) this.check(-1);
            return new Twin(this, t, { x, y, w, h });
        } finally {
            this.x.terrad_twin_config_free(c);
        }
    }
}

export class Twin {
    constructor(m, ptr, window) {
        this.m = m;
        this.ptr = ptr;
        this.window = window;
    }
    addCollider(id, shape, { radius = 0, halfLength = 0, halfExtents = [0, 0, 0] } = {}) {
        const m = this.m;
        m.withStrings([shape], (s) => m.check(m.x.terrad_twin_add_collider(this.ptr, id, s, radius,
            halfLength, halfExtents[0], halfExtents[1], halfExtents[2], m.err)));
    }
    // vertices: Float32Array (xyz), indices: Uint32Array (3 per triangle)
    addMesh(id, vertices, indices) {
        const m = this.m;
        const v = m.alloc(vertices);
        const i = m.alloc(indices);
        try {
            m.check(m.x.terrad_twin_add_mesh(this.ptr, id, v, vertices.length / 3, i,
                indices.length / 3, m.err));
        } finally {
            m.x.free(v);
            m.x.free(i);
        }
    }
    removeCollider(id) {
        this.m.check(this.m.x.terrad_twin_remove_collider(this.ptr, id, this.m.err));
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
