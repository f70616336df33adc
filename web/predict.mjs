// predict.mjs: client-side prediction for JavaScript clients (browsers and Node), docs/engines.md
// "Prediction". A Prediction is the twin library's (terrad_twin_prediction_* in terrad_twin.h,
// run here as WebAssembly through twin.mjs): the same C that the C client and Python call, so
// the steps are written once. Each pose batch the client sends is one tick of the twin at once,
// with the client's own colliders at their new poses; at the server's ACK of tick t (batch seq),
// when the mirror holds the server's heights at t, the library replays the server's ticks from
// the previous ACK's heights with the poses the ACKs say the server used and counts the cells
// that differ (0 whenever no other collider or edit touched the window), then resets the window
// to the mirror, places the own colliders where tick t left them and applies the batches sent
// after seq again. Nothing extra goes on the wire. The caller wires it to its connection: onSend
// before a POSE_BATCH's bytes leave, onAck after an ACK (whose DELTAs the mirror has applied).
// Neither throws: an event the twin fails on (at an ACK, a soil state it could not restore, out
// of memory: the ACK is taken all the same) is counted in `errors` with the twin's sentence in
// `lastError`, so the caller's message handler goes on and the next ACK compares and resets.

export class Prediction {
    // twinModule: loadTwinModule(...)'s module; world: the server's world message; mirror:
    // the subscription's complete Mirror (terrad_codec.mjs), or anything with x, y, w, h,
    // complete and heights; config: the world's parameters in the twin's keys (model,
    // material, margin_cells, terrain.*); own: Map id -> {shape, dims} of this client's
    // colliders.
    constructor(twinModule, world, mirror, config = {}, own = new Map(), maxReplayTicks = 0) {
        if (!mirror || !mirror.complete) throw new Error('mirror: the subscription has no snapshot yet');
        const cfg = {};
        for (const k of ['width', 'height', 'cell_size_m', 'units_per_m', 'tick_hz'])
            if (k in world) cfg[k] = world[k];
        Object.assign(cfg, config);
        this.mirror = mirror;
        this.own = own;
        this.errors = 0; // the client's events the twin failed on (onSend, onAck, resume)
        this.lastError = ''; // the twin's sentence for the last of them
        this.twin = twinModule.createPrediction(cfg, mirror.x, mirror.y, mirror.w, mirror.h, mirror.heights, maxReplayTicks);
        try {
            for (const [id, { shape, dims }] of own) this.addCollider(id, shape, dims);
        } catch (e) {
            this.destroy();
            throw e;
        }
    }

    destroy() {
        if (this.twin.ptr) this.twin.destroy();
    }

    heights() {
        return this.twin.heights();
    }

    // The counters (terrad_twin_prediction_stats), read from the library when asked.
    get predicted() { return this.twin.stats().predicted; } // pose batches ticked locally
    get reconciled() { return this.twin.stats().reconciled; } // ACKs taken
    get replayed() { return this.twin.stats().replayed; } // ACKs whose replay was compared with the server's heights
    get exact() { return this.twin.stats().exact; } // of those, with 0 cells differing
    get skipped() { return this.twin.stats().skipped; } // ACKs not compared (resyncing, a long gap)
    get onTime() { return this.twin.stats().onTime; } // ACKs whose batch's prediction already was the server's heights
    get lastDiffering() { return this.twin.stats().lastDiffering; } // cells of the last comparison
    // The seqs of the batches sent and not acknowledged yet, oldest first.
    get pending() { return this.twin.pending(); }

    // dims as in collider_create: sphere radius; box half_extents; capsule / cylinder radius,
    // half_length; wheel radius, width and its grousers {count, height, thickness}, if any;
    // mesh vertices, indices (flat); load_n: load-driven (its height the soil's, found as the
    // server finds it).
    addCollider(id, shape, dims) {
        if ((dims.material ?? 'default') !== 'default' || dims.pose)
            throw new Error(`collider ${id}: a predicted collider has the default material and gets its poses from POSE_BATCH`);
        if (shape === 'mesh') this.twin.addMesh(id, Float32Array.from(dims.vertices), Uint32Array.from(dims.indices));
        else if (shape === 'wheel') this.twin.addWheel(id, { radius: dims.radius, halfLength: dims.width / 2, grousers: dims.grousers });
        else this.twin.addCollider(id, shape, { radius: dims.radius, halfExtents: dims.half_extents, halfLength: dims.half_length });
        if (dims.load_n != null) this.twin.setLoad(id, dims.load_n);
    }

    removeCollider(id) {
        this.twin.removeCollider(id);
    }

    // For own colliders the server had already posed when this Prediction was made (a window
    // made or moved while driving): call it on an ACK of tick, with the mirror at that tick
    // (right after the ACK, as the Prediction was made). last: Map id -> the pose (as sent) of
    // the latest acknowledged batch that moved it; later: [{seq, poses}] sent after the ACK's
    // seq, applied again as predictions. The next ACK then compares as with any other.
    resume(tick, last, later) {
        this.took(() => this.twin.resume(tick, [...last].map(([id, p]) => ({ ...p, id }))));
        for (const { seq, poses } of later) this.onSend(seq, poses);
    }

    // Batch seq (poses as encodePoseBatch takes them) is about to be sent.
    onSend(seq, poses) {
        this.took(() => this.twin.sent(seq, poses));
    }

    // The server's ACK of tick (a BigInt or number), batch seq; the mirror is at that tick.
    onAck(tick, seq) {
        this.took(() => this.twin.acked(tick, seq, this.mirror.complete ? this.mirror.heights : null));
    }

    // One of the client's events into the twin: a failure is counted with its sentence, not
    // thrown (the ACK or batch was taken as far as the twin could; the client goes on).
    took(call) {
        try {
            call();
        } catch (e) {
            this.errors++;
            this.lastError = String(e.message || e);
        }
    }
}
