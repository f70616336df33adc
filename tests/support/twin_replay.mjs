// twin_replay.mjs: twin_replay.c's twin through WebAssembly — replays a twin_trace.c trace with
// web/twin.mjs over build/terrad_twin.wasm (Node 20) and writes the window's final heights as
// little-endian int32, row-major (`terrad simulate --out`'s format).
// Usage: node twin_replay.mjs MODULE.wasm TRACE OUT
import { readFileSync, writeFileSync } from 'node:fs';
import { loadTwinModule } from '../../web/twin.mjs';

const [wasmPath, tracePath, outPath] = process.argv.slice(2);
const m = await loadTwinModule(readFileSync(wasmPath));
const config = {};
let win = null;
let twin = null;
for (const line of readFileSync(tracePath, 'utf8').split('\n')) {
    const f = line.split(' ');
    switch (f[0]) {
    case 'set': config[f[1]] = Number(f[2]); break;
    case 'name': config[f[1]] = f[2]; break;
    case 'window': win = f.slice(1, 5).map(Number); break;
    case 'heights':
        twin = m.create(config, ...win, Int32Array.from(f.slice(1), Number));
        break;
    case 'base': twin = m.create(config, ...win, null); break;
    case 'collider':
        twin.addCollider(Number(f[1]), f[2], {
            radius: Number(f[3]), halfLength: Number(f[4]), halfExtents: f.slice(5, 8).map(Number),
        });
        break;
    case 'wheel':
        twin.addWheel(Number(f[1]), {
            radius: Number(f[2]), halfLength: Number(f[3]),
            grousers: { count: Number(f[4]), height: Number(f[5]), thickness: Number(f[6]) },
        });
        break;
    case 'mesh': {
        const nv = Number(f[2]);
        const nt = Number(f[3]);
        const v = Float32Array.from(f.slice(4, 4 + 3 * nv), Number);
        const ix = Uint32Array.from(f.slice(4 + 3 * nv, 4 + 3 * nv + 3 * nt), Number);
        twin.addMesh(Number(f[1]), v, ix);
        break;
    }
    case 'pose': {
        const p = f.slice(2).map(Number);
        twin.setPose(Number(f[1]), p.slice(0, 3), p.slice(3, 7));
        break;
    }
    case 'tick': twin.tick(); break;
    case '': break;
    default: throw new Error(`twin_replay.mjs: unknown line "${f[0]}"`);
    }
}
const h = twin.read();
writeFileSync(outPath, new Uint8Array(h.buffer, h.byteOffset, h.byteLength));
twin.destroy();
