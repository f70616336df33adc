// viewer_predict.mjs: the viewer's prediction (issue 23, docs/engines.md "Prediction"). While
// the page drives its collider, predict.mjs runs the daemon's twin (WebAssembly, served at
// /terrad_twin.wasm, with the world's parameters from GET /v1/twin) on a sub-window of the
// rendered mirror around that collider: each pose batch the page sends is one tick of the
// twin at once, so the page's own rut is drawn in the frame it moves, not a round trip later;
// every ACK reconciles the sub-window exactly with the server's heights. The frame draws the
// mirror with the predicted sub-window pasted in (heights()). Nothing extra goes on the wire.
// The same module rebuilds the scene's base terrain under each window for base snapshots
// (PROTOCOL.md "Base snapshots": the page asks for them when the module loaded, see
// viewer.mjs), so a page joining a dug world is sent only the digging.
import { loadTwinModule } from './twin.mjs';
import { Prediction } from './predict.mjs';

// The predicted sub-window's side in cells (at most: the mirror's own size below it). Its cost
// per batch and per ACK grows with its area (docs/engines.md, "What it costs"): 160² keeps
// both within a few ms of a frame as WebAssembly.
export const PREDICT_CELLS = 160;
// Re-centre the sub-window when the collider comes this close (cells) to its edge: the halo
// the twin needs for a sphere's reach, a tick's move and the model's margin (docs/engines.md,
// "Halo") is far less for the viewer's 0.3 m sphere on any cell size of 2 cm or more.
const EDGE = 32;
const U32 = 0x100000000;

// Part of a Mirror, as Prediction reads it: the window (world cells) and its heights.
class SubMirror {
    constructor(parent, x, y, w, h) {
        Object.assign(this, { parent, x, y, w, h });
    }
    get complete() {
        return this.parent.complete;
    }
    get heights() {
        const p = this.parent, out = new Int32Array(this.w * this.h);
        for (let j = 0; j < this.h; j++) {
            const k = (this.y - p.y + j) * p.w + this.x - p.x;
            out.set(p.heights.subarray(k, k + this.w), j * this.w);
        }
        return out;
    }
}

export class ViewerPrediction {
    constructor(apiInit) {
        this.apiInit = apiInit;
        this.enabled = true; // the toggle: on by default, active while the page drives
        this.module = null;
        this.config = null;
        this.reason = 'loading';
        this.pred = null;
        this.loading = null;
        this.moduleLoading = null; // loadModule()'s promise, kept once it loaded
        this.want = null; // a Prediction to make at the next ACK: {world, mirror, id, radius, cx, cy}
        this.sent = []; // the page's batches after the last ACK: [{seq, poses}]
        this.last = new Map(); // id -> the pose of its latest acknowledged batch
        // What the prediction costs the page's main thread (make bench: ms per frame):
        // milliseconds spent in each step since the page loaded, and how many times.
        this.cost = { sendMs: 0, sends: 0, ackMs: 0, acks: 0, pasteMs: 0, pastes: 0 };
    }

    // The twin module (GET /terrad_twin.wasm), loaded once; null when the daemon has none
    // (built without the WebAssembly toolchain) or it cannot load: asked again next time.
    loadModule() {
        if (this.module) return Promise.resolve(this.module);
        this.moduleLoading ??= (async () => {
            try {
                const wasm = await fetch('/terrad_twin.wasm', { cache: 'no-store' });
                if (!wasm.ok) throw new Error(`GET /terrad_twin.wasm: ${wasm.status} (built without the WebAssembly toolchain)`);
                this.module = await loadTwinModule(await wasm.arrayBuffer());
            } catch (e) {
                this.moduleError = String(e.message || e);
                console.warn('twin not available:', this.moduleError);
            }
            this.moduleLoading = null;
            return this.module;
        })();
        return this.moduleLoading;
    }

    // The twin module and the world's parameters, once per world message (a restarted
    // daemon may serve another world). A daemon without them leaves prediction unavailable.
    load() {
        this.drop();
        this.config = null;
        this.reason = 'loading';
        this.loading = (async () => {
            try {
                const cfg = await fetch('/v1/twin', this.apiInit);
                const body = await cfg.json();
                if (!cfg.ok) throw new Error(body.error || `GET /v1/twin: ${cfg.status}`);
                if (!(await this.loadModule())) throw new Error(this.moduleError);
                this.config = body;
                this.reason = '';
            } catch (e) {
                this.reason = String(e.message || e);
                console.warn('prediction not available:', this.reason);
            }
        })();
        return this.loading;
    }

    get available() {
        return !!(this.module && this.config);
    }

    // Called before each batch of the page's collider o ({id, radius, x, y}) in mirror: is the
    // Prediction there and o well inside its sub-window? If not, one is made (or moved) at the
    // next ACK, when the mirror holds exactly that tick's heights (onAck). Returns the box of
    // window cells whose shown heights changed (prediction off: its sub-window), or null.
    ensure(world, mirror, o) {
        if (!this.enabled || !this.available || !mirror || !o || !o.id) {
            this.want = null;
            return this.drop();
        }
        const cell = world.cell_size_m;
        const cx = Math.floor(o.x / cell) - mirror.x, cy = Math.floor(o.y / cell) - mirror.y;
        const p = this.pred;
        const fits = p && p.mirror.parent === mirror && p.ownId === o.id && p.radius === o.radius;
        this.want = fits && this.inside(p.mirror, mirror, cx, cy) ? null : { world, mirror, id: o.id, radius: o.radius, cx, cy };
        return fits ? null : this.drop(); // another mirror or collider: its old prediction is void
    }

    // The wanted Prediction, made from the mirror at an ACK's tick: the page's collider was
    // posed before (resume), its batches after the ACK are predicted again.
    make(tick) {
        const { world, mirror, id, radius, cx, cy } = this.want;
        this.want = null;
        if (!mirror.complete) return null;
        const w = Math.min(PREDICT_CELLS, mirror.w), h = Math.min(PREDICT_CELLS, mirror.h);
        const x = Math.max(0, Math.min(mirror.w - w, cx - (w >> 1))), y = Math.max(0, Math.min(mirror.h - h, cy - (h >> 1)));
        const old = this.drop();
        const sub = new SubMirror(mirror, mirror.x + x, mirror.y + y, w, h);
        try {
            this.pred = new Prediction(this.module, world, sub, this.config, new Map([[id, { shape: 'sphere', dims: { radius } }]]));
            Object.assign(this.pred, { ownId: id, radius });
            const mine = (poses) => poses.filter((q) => q.id === id);
            this.pred.resume(tick, new Map(this.last.has(id) ? [[id, this.last.get(id)]] : []),
                this.sent.map(({ seq, poses }) => ({ seq, poses: mine(poses) })));
        } catch (e) {
            this.drop();
            this.reason = String(e.message || e);
            this.enabled = false;
            console.warn('prediction refused:', this.reason);
            return old;
        }
        return union(old, this.box());
    }

    // Is (cx, cy) (mirror cells) at least EDGE cells inside sub, or against the mirror's edge?
    inside(sub, mirror, cx, cy) {
        const x0 = sub.x - mirror.x, y0 = sub.y - mirror.y;
        const ok = (c, lo, n, full) => (c - lo >= EDGE || lo === 0) && (lo + n - c > EDGE || lo + n === full);
        return ok(cx, x0, sub.w, mirror.w) && ok(cy, y0, sub.h, mirror.h);
    }

    // The sub-window as a box of mirror cells {x0, y0, x1, y1}, or null.
    box() {
        const p = this.pred;
        if (!p) return null;
        const s = p.mirror, m = s.parent;
        return { x0: s.x - m.x, y0: s.y - m.y, x1: s.x - m.x + s.w, y1: s.y - m.y + s.h };
    }

    // Prediction off (or moved): the sub-window shows the mirror again.
    drop() {
        const b = this.box();
        if (this.pred) this.pred.destroy();
        this.pred = null;
        return b;
    }

    active(mirror) {
        return !!this.pred && this.pred.mirror.parent === mirror;
    }

    // Batch seq with these poses is about to be sent: its tick runs on the twin now. The page's
    // batches since the last ACK are kept for a Prediction made at the next one.
    onSend(seq, poses) {
        this.sent.push({ seq, poses });
        if (!this.pred) return null;
        const t0 = performance.now();
        this.pred.onSend(seq, poses.filter((q) => q.id === this.pred.ownId));
        this.cost.sendMs += performance.now() - t0;
        this.cost.sends++;
        return this.box();
    }

    // The server's ACK (after the mirror applied that tick's DELTAs): reconcile, and make the
    // wanted Prediction now that the mirror holds that tick.
    onAck(tick, seq) {
        const upTo = (s) => (seq - s + U32) % U32 < 0x80000000;
        for (const b of this.sent.filter((e) => upTo(e.seq))) for (const q of b.poses) this.last.set(q.id, q);
        this.sent = this.sent.filter((e) => !upTo(e.seq));
        let box = null;
        const t0 = performance.now();
        if (this.pred) {
            this.pred.onAck(tick, seq);
            box = this.box();
        }
        if (this.want && this.enabled && this.available) box = union(box, this.make(tick));
        if (this.pred) {
            this.cost.ackMs += performance.now() - t0;
            this.cost.acks++;
        }
        return box;
    }

    // The connection is gone: its colliders and batches with it.
    reset() {
        this.sent = [];
        this.last = new Map();
        this.want = null;
        return this.drop();
    }

    // The heights to draw for mirror: its own, or a copy (into buf when it fits) with the
    // predicted sub-window pasted in.
    heights(mirror, buf) {
        if (!this.active(mirror)) return mirror.heights;
        const t0 = performance.now();
        const reuse = buf && buf !== mirror.heights && buf.length === mirror.heights.length; // never the mirror's own
        const out = reuse ? buf : new Int32Array(mirror.heights.length);
        out.set(mirror.heights);
        const s = this.pred.mirror, ph = this.pred.heights();
        for (let j = 0; j < s.h; j++)
            out.set(ph.subarray(j * s.w, (j + 1) * s.w), (s.y - mirror.y + j) * mirror.w + s.x - mirror.x);
        this.cost.pasteMs += performance.now() - t0;
        this.cost.pastes++;
        return out;
    }

    // For the overlay and the tests: the Prediction's counters (predict.mjs) and its window.
    stats() {
        const p = this.pred;
        const s = { enabled: this.enabled, available: this.available, reason: this.reason, active: !!p, cost: { ...this.cost } };
        if (!p) return s;
        const { x, y, w, h } = p.mirror;
        return { ...s, window: { x, y, w, h }, pending: p.pending.length, predicted: p.predicted, reconciled: p.reconciled,
            replayed: p.replayed, exact: p.exact, skipped: p.skipped, onTime: p.onTime, lastDiffering: p.lastDiffering,
            errors: p.errors, lastError: p.lastError };
    }
}

export function union(a, b) {
    if (!a) return b;
    if (!b) return a;
    return { x0: Math.min(a.x0, b.x0), y0: Math.min(a.y0, b.y0), x1: Math.max(a.x1, b.x1), y1: Math.max(a.y1, b.y1) };
}
