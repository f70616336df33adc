// terrad-client: terrad's websocket client for Node (20+) and browsers, with TypeScript types
// (issue 23; docs/engines.md, "TypeScript"). An async client over the viewer's own codec
// (web/terrad_codec.mjs: hello, subscriptions and their mirrors, colliders, pose batches,
// DELTA, ACK, CONTACT, FORCES, CHECKSUM: a desync repaired by itself; base snapshots, the base
// rebuilt on the twin), the worlds API (HTTP) and prediction on the daemon's twin as
// WebAssembly (web/twin.mjs, web/predict.mjs). Those three files are compiled into this
// package from web/, never copied by hand: one codec for the viewer and every JS client.
import * as P from '../../../web/terrad_codec.mjs';
import { loadTwinModule } from '../../../web/twin.mjs';
import { Prediction } from '../../../web/predict.mjs';

export { P as codec, Prediction, loadTwinModule };

/** A pose as POSE_BATCH carries it: metres and a quaternion (w, x, y, z). */
export interface Pose {
  id: number;
  x: number;
  y: number;
  z: number;
  qw: number;
  qx: number;
  qy: number;
  qz: number;
}

/** The server's `world` message (PROTOCOL.md). */
export interface World {
  type: 'world';
  width: number;
  height: number;
  cell_size_m: number;
  units_per_m: number;
  tick_hz: number;
  tile_size: number;
  tick: number;
  /** with ConnectOptions.baseSnapshots: true when this client's snapshots come against the
   * scene's base (PROTOCOL.md "Base snapshots"), false when the twin cannot make this world's
   * base (they stay absolute) */
  snapshot_base?: boolean;
  /** with ConnectOptions.slopeSnapshots: true when the server may send slope snapshots
   * (encoding 3, PROTOCOL.md "Slope snapshots") */
  snapshot_slope?: boolean;
  /** with snapshot_base true: the scene's twin config, from which the client rebuilds the base */
  base?: Record<string, number | string>;
  [key: string]: unknown;
}

/** A subscription's copy of the server's heights (web/terrad_codec.mjs `Mirror`). */
export interface Mirror {
  x: number;
  y: number;
  w: number;
  h: number;
  heights: Int32Array;
  /** the scene's base terrain over the region (base snapshots: rebuilt on the twin), else null */
  readonly base: Int32Array | null;
  readonly complete: boolean;
}

export type Shape = 'sphere' | 'box' | 'capsule' | 'cylinder' | 'wheel' | 'mesh';
/** collider_create's fields: radius, half_extents, half_length, width, vertices, indices. */
export type Dims = Record<string, number | number[]>;
/** A wheel's lugs (PROTOCOL.md collider_create "grousers"): metres. */
export type Grousers = { count: number; height: number; thickness: number };

/** An `error` message from the server, as a rejection: its name, code, field and ref. */
export class TerradError extends Error {
  readonly code: number;
  readonly field: string;
  readonly ref: unknown;
  constructor(readonly reply: { name?: string; code?: number; message?: string; field?: string; ref?: unknown }) {
    super(`${reply.name ?? 'error'}: ${reply.message ?? ''}`);
    this.code = reply.code ?? 0;
    this.field = reply.field ?? '';
    this.ref = reply.ref;
  }
}

export interface ConnectOptions {
  token?: string;
  /** the client's name in the server's log (hello's `client`) */
  name?: string;
  /** a world made by POST /v1/worlds ('' for the daemon's own) */
  world?: string;
  /** bytes per second the server may send this client (PROTOCOL.md "Budgets": near tiles
   * every tick, far ones later, exact once the terrain settles); absent: the server's default.
   * `world.budget` says the one in force. */
  budget?: number;
  /** snapshots against the scene's base terrain (PROTOCOL.md "Base snapshots"): a client joining
   * a world dug for an hour is sent only the digging, and rebuilds the base of each subscription
   * on the twin (twinWasm) before its snapshot is read. `world.snapshot_base` says whether the
   * server agreed (false: a base the twin cannot make; snapshots stay absolute). Needs twinWasm. */
  baseSnapshots?: boolean;
  /** with baseSnapshots, offer slope snapshots too (encoding 3, PROTOCOL.md "Slope snapshots"):
   * the server sends each snapshot piece in the shorter of encodings 2 and 3 (about a fifth
   * fewer bytes on ground driven over for long). `world.snapshot_slope` says whether it agreed. */
  slopeSnapshots?: boolean;
  /** the bytes of terrad_twin.wasm (Worlds.twinWasm(), GET /terrad_twin.wasm): for baseSnapshots */
  twinWasm?: BufferSource;
  /** how long a reply may take (ms, default 60,000) */
  timeoutMs?: number;
  /** the WebSocket class (default globalThis.WebSocket: browsers, Node 22, Node 20 with --experimental-websocket;
   *  Node 18: the `ws` package's WebSocket) */
  WebSocket?: typeof WebSocket;
}

type Events = {
  delta: (tick: bigint, rects: unknown[]) => void;
  ack: (tick: bigint, seq: number) => void;
  contact: (contact: ReturnType<typeof P.decodeContact>) => void;
  forces: (forces: ReturnType<typeof P.decodeForces>) => void;
  /** a COLLIDERS frame (a subscription made with colliders): every collider in view; with the
   *  grousers option each entry has `grousers`, a lugged wheel's {count, height, thickness} or null */
  colliders: (colliders: ReturnType<typeof P.decodeColliders>) => void;
  /** a CHECKSUM frame compared: the tiles [x, y] found differing and asked for again */
  checksum: (tick: bigint, subscription: number, asked: number[][]) => void;
  error: (error: TerradError) => void;
};

/** Desync detection (PROTOCOL.md "CHECKSUM"): CHECKSUM frames compared, the last one's tick,
 *  tiles found differing from the server's and tiles asked for again (each is repaired by
 *  its snapshot, the other tiles' deltas going on). */
export interface DesyncStats {
  checksumFrames: number;
  checksumTick: bigint;
  tilesDiffering: number;
  tilesResynced: number;
}

/** A spectator's start (PROTOCOL.md "Spectate"): the window, the past tick and the pace. */
export interface SpectateOptions {
  fromTick: number | bigint;
  /** 1..8 times the world's tick rate (default 1) */
  speed?: number;
  /** play only the ticks spectateStep() asks for */
  step?: boolean;
}

/** One connection to a daemon. */
export class TerradClient {
  world!: World;
  /** the latest tick the server's frames named */
  tick = 0n;
  /** the latest ACK's batch sequence */
  ackedSeq = -1;
  readonly mirrors = new Map<number, Mirror>();
  /** a spectator's tick: its mirror holds the window as of it (the last replayed tick's ACK) */
  spectateTick = -1n;
  /** the server's spectate_end (reason "live" once it caught up, or "stopped"), else null */
  spectateEnded: { reason: string; tick: number; id: number; message?: string } | null = null;
  readonly desync: DesyncStats = { checksumFrames: 0, checksumTick: 0n, tilesDiffering: 0, tilesResynced: 0 };
  private ws: WebSocket;
  private seq = 0;
  private refN = 0;
  private timeoutMs: number;
  private waiting: { test: (m: any) => boolean; ok: (m: any) => void; fail: (e: Error) => void }[] = [];
  private listeners: { [K in keyof Events]: Events[K][] } = { delta: [], ack: [], contact: [], forces: [], colliders: [], checksum: [], error: [] };
  private predictions = new Map<number, Prediction>();
  /** the twin module that rebuilds the base of each subscription (base snapshots), else null */
  private twins: Awaited<ReturnType<typeof loadTwinModule>> | null = null;
  /** subscriptions whose base could not be rebuilt: subscribe() rejects with the error */
  private baseFailed = new Map<number, Error>();
  private closed: Error | null = null;
  /** between spectating and spectate_end: ACKs are the replay's tick marks */
  private watching = false;
  /** PROTOCOL.md "seen": the server bounds this client's lag by the tick it says it handled */
  private seen = new P.SeenReporter((m: object) => { if (!this.closed) this.sendJson(m); });

  private constructor(ws: WebSocket, timeoutMs: number) {
    this.ws = ws;
    this.timeoutMs = timeoutMs;
  }

  /** Connects, says hello and resolves once the server's `world` message arrived. */
  static async connect(url: string, opts: ConnectOptions = {}): Promise<TerradClient> {
    if (opts.baseSnapshots && !opts.twinWasm) throw new Error('baseSnapshots: needs twinWasm, the bytes of terrad_twin.wasm (Worlds.twinWasm())');
    const twins = opts.baseSnapshots ? await loadTwinModule(opts.twinWasm!) : null;
    const WS = opts.WebSocket ?? (globalThis as any).WebSocket;
    if (!WS) throw new Error('WebSocket: none in this runtime (Node 20: run with --experimental-websocket; Node 18: pass opts.WebSocket, e.g. the ws package\'s)');
    const ws: WebSocket = new WS(url, P.SUBPROTOCOL);
    ws.binaryType = 'arraybuffer';
    const c = new TerradClient(ws, opts.timeoutMs ?? 60000);
    c.twins = twins;
    ws.onmessage = (e: MessageEvent) => (typeof e.data === 'string' ? c.onText(e.data) : c.onBinary(new Uint8Array(e.data)));
    ws.onclose = (e: CloseEvent) => c.fail(new Error(`connection closed (${e.code}${e.reason ? ` ${e.reason}` : ''})`));
    await new Promise<void>((ok, fail) => {
      ws.onopen = () => ok();
      ws.onerror = () => fail(new Error(`cannot connect to ${url}`));
    });
    ws.onerror = () => {};
    const world = c.reply((m) => m.type === 'world');
    c.sendJson(P.hello(opts.token ?? '', opts.name ?? 'terrad-client-js', opts.world ?? '', opts.budget ?? -1, !!twins,
                       !!twins && !!opts.slopeSnapshots));
    c.world = (await world) as World;
    c.tick = BigInt(c.world.tick ?? 0);
    return c;
  }

  on<K extends keyof Events>(event: K, fn: Events[K]): this {
    this.listeners[event].push(fn);
    return this;
  }

  /** A budgeted client's focus in cells: its nearest tiles come every tick, far ones later
   * (no arguments: its own colliders again). No reply. */
  focus(x?: number, y?: number): void {
    this.sendJson(P.focus(x, y));
  }

  /** Subscribes to a rectangle of cells; resolves to the subscription's id. colliders: COLLIDERS
   *  frames too (the 'colliders' event); grousers (with colliders): their entries carry the wheels'
   *  grousers (PROTOCOL.md "COLLIDERS", the extension). */
  async subscribe(x: number, y: number, w: number, h: number, opts: { colliders?: boolean; grousers?: boolean } = {}): Promise<number> {
    const ref = `sub-${++this.refN}`;
    const m = await this.request(P.subscribe(x, y, w, h, ref, !!opts.colliders, false, !!opts.grousers), ref, 'subscribed');
    const e = this.baseFailed.get(m.id);
    if (e) { // its base snapshots could not be applied: not kept
      this.baseFailed.delete(m.id);
      this.mirrors.delete(m.id);
      this.sendJson(P.unsubscribe(m.id));
      throw e;
    }
    return m.id;
  }

  /**
   * Watches a window from a past tick (PROTOCOL.md "Spectate"): the frames a live subscriber got,
   * replayed from the world's log at opts.speed (1..8) times its tick rate, or with opts.step one
   * spectateStep() at a time, until the live tick (then spectateEnded says so; subscribe to go
   * on live). Resolves to the key of its mirror in mirrors (negative: never a subscription's);
   * spectateTick is the tick it holds. Rejects with the server's error naming the field (a tick
   * the log no longer holds, a speed out of range).
   */
  async spectate(x: number, y: number, w: number, h: number, opts: SpectateOptions): Promise<number> {
    const ref = `spec-${++this.refN}`;
    const m: any = { type: 'spectate', ref, x, y, w, h, from_tick: Number(opts.fromTick) };
    if (opts.step) m.step = true;
    else if (opts.speed !== undefined) m.speed = opts.speed;
    this.spectateEnded = null;
    this.spectateTick = -1n;
    const got = await this.request(m, ref, 'spectating');
    return -got.id;
  }

  /** A stepping spectator plays `ticks` more ticks. */
  spectateStep(ticks = 1): void {
    this.sendJson({ type: 'spectate_step', ticks });
  }

  /** Stops watching; resolves to the server's spectate_end (reason "stopped"). */
  async spectateStop(): Promise<{ reason: string; tick: number; id: number }> {
    const ref = `spec-${++this.refN}`;
    return this.request({ type: 'spectate_stop', ref }, ref, 'spectate_end');
  }

  /** Resolves to the subscription's mirror once it holds the server's snapshot. */
  async waitComplete(sid: number): Promise<Mirror> {
    await this.until(`subscription ${sid}'s snapshot`, () => !!this.mirrors.get(sid)?.complete);
    return this.mirrors.get(sid)!;
  }

  /** Creates a collider of this client; resolves to its id (rejects with the server's error naming the field).
   *  opts.loadN: load-driven (bekker worlds), its height the server's (and the predictions'); opts.forcesHeight:
   *  its FORCES entries carry height_m, the height the server found (PROTOCOL.md "FORCES"). While predicting,
   *  opts.material other than "default" is refused before anything is sent (an Error naming material), as the
   *  Python client does: the twin presses with the world's one material, so such a collider's prediction
   *  would be wrong (docs/engines.md "Prediction", Limits). */
  async createCollider(shape: Shape, dims: Dims, opts: { material?: string; feedback?: boolean; grousers?: Grousers; loadN?: number; forcesHeight?: boolean } = {}): Promise<number> {
    if (this.predictions.size > 0 && (opts.material ?? 'default') !== 'default')
      throw new Error(`material: while predicting, a collider has the default material ("${opts.material}" cannot be predicted)`);
    const ref = `col-${++this.refN}`;
    const m = await this.request(P.colliderCreate(shape, dims, { ...opts, ref }), ref, 'collider_created');
    // the twin presses the lugs too, and finds a load-driven collider's height as the server does
    const own = { ...dims, ...(opts.grousers ? { grousers: opts.grousers } : {}), ...(opts.loadN !== undefined ? { load_n: opts.loadN } : {}) };
    for (const p of this.predictions.values()) p.own.set(m.id, { shape, dims: own });
    for (const p of this.predictions.values()) p.addCollider(m.id, shape, own);
    return m.id;
  }

  deleteCollider(id: number): void {
    for (const p of this.predictions.values()) {
      p.removeCollider(id);
      p.own.delete(id);
    }
    this.sendJson(P.colliderDelete(id));
  }

  /** Sends one pose batch; returns its sequence. Predicting subscriptions tick their twin first. */
  sendPoses(poses: Pose[]): number {
    const seq = this.seq++ >>> 0;
    for (const p of this.predictions.values()) p.onSend(seq, poses.filter((q) => p.own.has(q.id)));
    this.ws.send(P.encodePoseBatch(seq, poses));
    return seq;
  }

  /** Resolves to the tick of the ACK that acknowledges batch seq (or a later one). */
  async waitAck(seq: number): Promise<bigint> {
    await this.until(`the ACK of batch ${seq}`, () => this.ackedSeq !== -1 && ((this.ackedSeq - seq) >>> 0) < 0x80000000);
    return this.tick;
  }

  /**
   * Prediction on subscription sid (complete): this client's colliders' poses are applied at once
   * on the twin (wasm: the bytes of terrad_twin.wasm, e.g. from GET /terrad_twin.wasm; config: the
   * world's parameters, e.g. GET /v1/twin); every ACK reconciles exactly. Make it before creating
   * the colliders it predicts (docs/engines.md, "Prediction"). An event the twin fails on (a soil
   * state it could not restore at an ACK) is counted in its `errors`, the reason in `lastError`,
   * never thrown from this client's message handler.
   */
  async predict(sid: number, config: Record<string, number | string>, wasm: BufferSource): Promise<Prediction> {
    const mirror = this.mirrors.get(sid);
    if (!mirror) throw new Error(`sid: no subscription ${sid}`);
    const twins = await loadTwinModule(wasm);
    const p = new Prediction(twins, this.world, mirror, config, new Map());
    this.predictions.set(sid, p);
    return p;
  }

  close(): void {
    for (const p of this.predictions.values()) p.destroy();
    this.predictions.clear();
    this.closed = new Error('closed by the client');
    this.seen.reset();
    this.ws.close(1000);
  }

  // ---- internals ----

  private sendJson(m: object): void {
    this.ws.send(JSON.stringify(m));
  }

  private request(m: object, ref: string, type: string): Promise<any> {
    const r = this.reply((x) => (x.type === type || x.type === 'error') && x.ref === ref);
    this.sendJson(m);
    return r.then((x) => {
      if (x.type === 'error') throw new TerradError(x);
      return x;
    });
  }

  private reply(test: (m: any) => boolean): Promise<any> {
    if (this.closed) return Promise.reject(this.closed);
    return new Promise((ok, fail) => {
      const w = { test, ok, fail };
      const t = setTimeout(() => {
        this.waiting = this.waiting.filter((x) => x !== w);
        fail(new Error(`no reply within ${this.timeoutMs} ms`));
      }, this.timeoutMs);
      w.ok = (m) => { clearTimeout(t); ok(m); };
      w.fail = (e) => { clearTimeout(t); fail(e); };
      this.waiting.push(w);
    });
  }

  private async until(what: string, cond: () => boolean): Promise<void> {
    const end = Date.now() + this.timeoutMs;
    while (!cond()) {
      if (this.closed) throw this.closed;
      if (Date.now() > end) throw new Error(`timed out waiting for ${what}`);
      await new Promise((r) => setTimeout(r, 5));
    }
  }

  private fail(e: Error): void {
    this.closed ??= e;
    this.seen.reset();
    for (const w of this.waiting.splice(0)) w.fail(e);
  }

  private onText(text: string): void {
    const m: any = P.parseControl(text);
    if (m.type === 'subscribed') this.mirrors.set(m.id, this.mirrorOf(m));
    if (m.type === 'spectating') { // absolute snapshots, its own versions: a plain mirror
      this.mirrors.set(-m.id, new P.Mirror(m.x, m.y, m.w, m.h, this.world.tile_size) as unknown as Mirror);
      this.watching = true;
    }
    if (m.type === 'spectate_end') {
      this.spectateEnded = m;
      this.watching = false;
    }
    if (m.type === 'error') this.seen.refused(m);
    if (m.type === 'error') for (const f of this.listeners.error) f(new TerradError(m));
    const w = this.waiting.find((x) => x.test(m));
    if (w) {
      this.waiting = this.waiting.filter((x) => x !== w);
      w.ok(m);
    }
  }

  /** A subscription's mirror; with base snapshots agreed, the scene's base over its region is
   * rebuilt on the twin here, before any of its snapshot's frames is read (PROTOCOL.md "Base
   * snapshots"). */
  private mirrorOf(m: { id: number; x: number; y: number; w: number; h: number }): Mirror {
    const mirror = new P.Mirror(m.x, m.y, m.w, m.h, this.world.tile_size);
    const base = this.world.base;
    if (this.twins && this.world.snapshot_base && base && typeof base === 'object') {
      try {
        const twin = this.twins.create(base, m.x, m.y, m.w, m.h, null);
        try {
          mirror.base = twin.read();
        } finally {
          twin.destroy();
        }
      } catch (e) {
        this.baseFailed.set(m.id, new Error(`base snapshots: the twin cannot make this world's base (${(e as Error).message})`));
      }
    }
    return mirror as unknown as Mirror;
  }

  private onBinary(b: Uint8Array): void {
    const t = P.decodeHeader(b);
    if (t === P.MsgType.DELTA) {
      const { tick, rects } = P.decodeDelta(b);
      for (const [id, m] of this.mirrors) {
        try {
          (m as any).apply(rects);
        } catch {
          this.sendJson(P.resync(id)); // a stale base or a bad frame: the snapshot again
        }
      }
      this.tick = tick > this.tick ? tick : this.tick;
      for (const f of this.listeners.delta) f(tick, rects);
    } else if (t === P.MsgType.ACK) {
      const { tick, seq } = P.decodeAck(b);
      if (this.watching) this.spectateTick = tick; // a replayed tick's mark, not a batch's ACK
      else this.ackedSeq = seq;
      this.tick = tick > this.tick ? tick : this.tick;
      for (const p of this.predictions.values()) p.onAck(tick, seq);
      for (const f of this.listeners.ack) f(tick, seq);
    } else if (t === P.MsgType.CONTACT) {
      const c = P.decodeContact(b);
      for (const f of this.listeners.contact) f(c);
    } else if (t === P.MsgType.FORCES) {
      const c = P.decodeForces(b);
      for (const f of this.listeners.forces) f(c);
    } else if (t === P.MsgType.COLLIDERS) {
      const c = P.decodeColliders(b);
      for (const f of this.listeners.colliders) f(c);
    } else if (t === P.MsgType.CHECKSUM) {
      this.onChecksum(b);
    } else if (t === P.MsgType.PING) {
      this.ws.send(P.encodePing(P.decodePing(b).nonce, true));
    }
    this.seen.handled(b); // after its listeners: handled
  }

  /** PROTOCOL.md "CHECKSUM": every frame before it is applied, so the mirror holds its tick; each
   *  held tile that differs is forgotten (its deltas skipped) and asked for again, at most
   *  max_resync_tiles per request (the rest at the next CHECKSUM). */
  private onChecksum(b: Uint8Array): void {
    const limits = (this.world.limits ?? {}) as Record<string, number>;
    const r = P.checkMirrors(this.mirrors, b, this.desync, limits.max_resync_tiles ?? 64);
    if (r.resync) this.sendJson(r.resync);
    for (const f of this.listeners.checksum) f(r.tick, r.subscription, r.asked);
  }
}

/** The world lifecycle API of a single daemon (HTTP; docs/openapi.yaml "worlds"). */
export class Worlds {
  /** base: the daemon's HTTP address, e.g. 'http://127.0.0.1:8080'; token: an admin token where needed. */
  constructor(readonly base: string, readonly token = '') {}
  list(): Promise<Record<string, unknown>[]> {
    return P.listWorlds(this.base, { token: this.token });
  }
  create(name: string, opts: { scene?: object; sceneName?: string } = {}): Promise<Record<string, unknown>> {
    return P.createWorld(this.base, name, { ...opts, token: this.token });
  }
  remove(name: string, opts: { keep?: boolean } = {}): Promise<Record<string, unknown>> {
    return P.deleteWorld(this.base, name, { ...opts, token: this.token });
  }
  /** The world's parameters as the twin's config keys (GET /v1/twin): for predict(). */
  async twinConfig(): Promise<Record<string, number | string>> {
    const res = await fetch(`${this.base.replace(/\/$/, '')}/v1/twin`, { headers: this.token ? { Authorization: `Bearer ${this.token}` } : {} });
    const doc = await res.json();
    if (!res.ok) throw new P.WorldError(res.status, doc.error || res.statusText, '');
    return doc;
  }
  /** The twin as WebAssembly (GET /terrad_twin.wasm): for predict(). */
  async twinWasm(): Promise<ArrayBuffer> {
    const res = await fetch(`${this.base.replace(/\/$/, '')}/terrad_twin.wasm`);
    if (!res.ok) throw new P.WorldError(res.status, 'the daemon was built without the WebAssembly twin', '');
    return res.arrayBuffer();
  }
}
