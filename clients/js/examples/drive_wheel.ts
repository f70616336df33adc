// drive_wheel.ts: the terrad-client package from Node, doing what the Python drive example does
// (clients/python/examples/drive_wheel.py; docs/engines.md "TypeScript"). It connects, creates a
// wheel, subscribes to the strip it drives along and sends a pose every tick for three seconds,
// with prediction on when the daemon serves its twin (GET /v1/twin, /terrad_twin.wasm). Then it
// parks the wheel above the snow (a pose each half tick, so an ACK closes every tick), asks the
// server for the strip's heights (GET /v1/heights, which names its tick in X-Terrad-Tick) and
// compares them with the mirror it kept at that very tick's ACK: they must be equal, cell for
// cell, even while other colliders (the demo actors) keep deforming the world.
//
//   npm install terrad-client typescript && npx tsc   (tsconfig: module NodeNext, see below)
//   node --experimental-websocket drive_wheel.js [ws://127.0.0.1:8081/] [http://127.0.0.1:8080/]
//
// Exit status 0 when the mirror equals the server's heights, 1 otherwise. Only the package's
// public API and fetch.
import { TerradClient, TerradError, Worlds, type Prediction } from 'terrad-client';

// Node's process, declared here so the example type-checks without @types/node.
declare const process: { argv: string[]; exitCode?: number };
const sleep = (ms: number) => new Promise((r) => setTimeout(r, ms));

async function getHeights(http: string, x: number, y: number, w: number, h: number): Promise<[bigint, Int32Array]> {
  const res = await fetch(`${http.replace(/\/$/, '')}/v1/heights?x=${x}&y=${y}&w=${w}&h=${h}`);
  if (!res.ok) throw new Error(`GET /v1/heights: ${res.status} ${await res.text()}`);
  const body = new Uint8Array(await res.arrayBuffer());
  if (body.length !== 4 * w * h) throw new Error(`/v1/heights answered ${body.length} bytes for ${w} x ${h} cells`);
  const view = new DataView(body.buffer, body.byteOffset, body.byteLength);
  return [BigInt(res.headers.get('X-Terrad-Tick') ?? '-1'), Int32Array.from({ length: w * h }, (_, i) => view.getInt32(4 * i, true))];
}

async function drive(wsUrl: string, http: string): Promise<boolean> {
  const client = await TerradClient.connect(wsUrl, { name: 'drive-wheel-ts' });
  try {
    const world = client.world;
    const cell = world.cell_size_m, units = world.units_per_m, hz = world.tick_hz;
    const yCell = Math.floor(world.height / 2);
    const region = [8, yCell - 24, Math.min(world.width - 16, 160), 48] as const;
    const sid = await client.subscribe(...region);
    const mirror = await client.waitComplete(sid);
    // Every DELTA of tick t arrives before the ACK of tick t: keep the mirror at each ACK.
    const history = new Map<bigint, Int32Array>();
    client.on('ack', (tick) => {
      history.set(tick, Int32Array.from(mirror.heights));
      history.delete(tick - 600n);
    });

    // Prediction, where the daemon serves its twin (a world of per-cell materials has none).
    let pred: Prediction | null = null;
    try {
      const worlds = new Worlds(http);
      pred = await client.predict(sid, await worlds.twinConfig(), await worlds.twinWasm());
    } catch (e) {
      console.log(`no prediction: ${(e as Error).message}`);
    }

    const [, start] = await getHeights(http, region[0] + 12, yCell, 1, 1);
    const ground = start[0] / units;
    const radius = 0.3;
    const wheel = await client.createCollider('wheel', { radius, width: 0.2 }, { feedback: true });
    let deepest = 0;
    client.on('contact', (frame) => {
      for (const c of frame.contacts) if (c.id === wheel) deepest = Math.max(deepest, Number(c.volume));
    });
    const x0 = (region[0] + 12) * cell, x1 = (region[0] + region[2] - 12) * cell;
    const y = (yCell + 0.5) * cell;
    const ticks = Math.round(3 * hz);
    let early = 0;
    for (let i = 0; i < ticks; i++) {
      const x = x0 + ((x1 - x0) * i) / (ticks - 1);
      const angle = (x - x0) / radius; // rolling about the axle (local y)
      client.sendPoses([{ id: wheel, x, y, z: ground + radius - 0.06, qw: Math.cos(angle / 2), qx: 0, qy: Math.sin(angle / 2), qz: 0 }]);
      if (pred && !early) {
        // the batch has just left: whatever is lower than the mirror is the predicted rut
        const mine = pred.heights();
        for (let k = 0; k < mine.length; k++) if (mine[k] < mirror.heights[k]) early++;
      }
      await sleep(1000 / hz);
    }

    let parked = true;
    const acker = (async () => {
      while (parked) {
        client.sendPoses([{ id: wheel, x: x1, y, z: ground + 5, qw: 1, qx: 0, qy: 0, qz: 0 }]);
        await sleep(500 / hz); // twice per tick: every tick gets its ACK
      }
    })();
    let mine: Int32Array | undefined, server: Int32Array = new Int32Array(), tick = -1n;
    try {
      for (let i = 0; i < 5 && !mine; i++) {
        // a tick that happened to get no batch has no ACK: read again
        [tick, server] = await getHeights(http, ...region);
        const end = Date.now() + 10000;
        while (client.tick < tick && Date.now() < end) await sleep(10);
        mine = history.get(tick);
      }
    } finally {
      parked = false;
      await acker;
    }
    const same = !!mine && mine.length === server.length && mine.every((v, k) => v === server[k]);
    console.log(`drove ${ticks} ticks; at tick ${tick} the mirror ${same ? '==' : '!='} GET /v1/heights over ${region[2]}x${region[3]} cells`);
    console.log(`deepest contact while driving: ${deepest} height units x cells`);
    if (pred)
      console.log(`prediction: the rut in ${early} cells before the server had it; ${pred.exact} of ${pred.replayed} compared ACKs exact` +
        ' (a demo actor in the strip makes a replay differ; the next ACK resets it)');
    return same;
  } catch (e) {
    console.log(e instanceof TerradError ? `refused: ${e.message} (field ${e.field})` : `failed: ${(e as Error).message}`);
    return false;
  } finally {
    client.close();
  }
}

const [wsUrl = 'ws://127.0.0.1:8081/', http = 'http://127.0.0.1:8080/'] = process.argv.slice(2);
process.exitCode = (await drive(wsUrl, http)) ? 0 : 1;
