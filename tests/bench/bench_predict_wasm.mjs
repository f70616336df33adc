// bench_predict_wasm.mjs: bench_predict.py's two figures for the WebAssembly twin under Node
// (web/twin.mjs): predict (set_pose, tick, read) and reconcile (write, place, tick, read,
// write, place, two ticks with reads), mean ms per tick. Prints one JSON line.
// Usage: node bench_predict_wasm.mjs MODULE.wasm W H TICKS
import { readFileSync } from 'node:fs';
import { loadTwinModule } from '../../web/twin.mjs';

const [wasm, W, H, N] = process.argv.slice(2);
const w = Number(W), h = Number(H), ticks = Number(N);
const m = await loadTwinModule(readFileSync(wasm));
const x0 = 100, y0 = 100, cell = 0.05, ys = (y0 + h / 2) * cell, q = [1, 0, 0, 0];
const twin = m.create({ width: 1024, height: 1024, 'terrain.height_m': 0.4 }, x0, y0, w, h, null);
twin.addCollider(1, 'sphere', { radius: 0.3 });
const pose = (i) => [(x0 + 8 + ((w - 16) * (i % ticks)) / ticks) * cell, ys, 0.64];
let server, t = performance.now();
for (let i = 0; i < ticks; i++) {
    twin.setPose(1, pose(i), q);
    twin.tick();
    server = twin.read();
}
const predict = (performance.now() - t) / ticks;
t = performance.now();
for (let i = 0; i < ticks; i++) {
    twin.write(x0, y0, w, h, server);
    twin.place(1, pose(i), q);
    twin.setPose(1, pose(i + 1), q);
    twin.tick();
    twin.read();
    twin.write(x0, y0, w, h, server);
    twin.place(1, pose(i + 1), q);
    for (const k of [2, 3]) {
        twin.setPose(1, pose(i + k), q);
        twin.tick();
        twin.read();
    }
}
const reconcile = (performance.now() - t) / ticks;
twin.destroy();
console.log(JSON.stringify({ predict, reconcile }));
