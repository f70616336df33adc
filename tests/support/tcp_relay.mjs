// tcp_relay.mjs: a loopback TCP relay for the browser tests and benches: what a slow or
// stalled network does to a client, with real bytes. Each direction keeps its bytes in order
// and forwards them delayMs after they arrived (an RTT of 2 * delayMs on loopback, for
// make bench); hold('down', true) keeps every byte from the server until hold('down', false)
// (the test's way to show what the page draws before the server's answer has arrived).
// bytes.up / bytes.down count what each direction carried (make bench's bytes per second).
import net from 'node:net';

export function startRelay(targetPort, { delayMs = 0, host = '127.0.0.1' } = {}) {
    const held = { up: false, down: false };
    const pumps = new Set();
    const sockets = new Set();
    const server = net.createServer((client) => {
        const upstream = net.connect(targetPort, host);
        sockets.add(client);
        sockets.add(upstream);
        const up = pipe(client, upstream, 'up'), down = pipe(upstream, client, 'down');
        const end = () => {
            pumps.delete(up);
            pumps.delete(down);
            client.destroy();
            upstream.destroy();
            sockets.delete(client);
            sockets.delete(upstream);
        };
        client.on('close', end);
        upstream.on('close', end);
        client.on('error', end);
        upstream.on('error', end);
    });
    // Bytes from src reach dst in order, delayMs after they arrived, not while held.
    function pipe(src, dst, dir) {
        const queue = [];
        let timer = null;
        const pump = () => {
            timer = null;
            const now = Date.now();
            while (queue.length && !held[dir] && queue[0].at <= now) dst.write(queue.shift().data);
            if (queue.length && !held[dir]) timer = setTimeout(pump, Math.max(0, queue[0].at - now));
        };
        src.on('data', (data) => {
            relay.bytes[dir] += data.length;
            queue.push({ at: Date.now() + relay.delayMs, data });
            if (!timer) pump();
        });
        const p = { kick: () => { if (!timer) pump(); } };
        pumps.add(p);
        return p;
    }
    const relay = {
        delayMs,
        port: 0,
        bytes: { up: 0, down: 0 },
        hold(dir, on) {
            held[dir] = !!on;
            if (!on) for (const p of pumps) p.kick();
        },
        close() {
            for (const s of sockets) s.destroy();
            return new Promise((r) => server.close(() => r()));
        },
    };
    return new Promise((resolve, reject) => {
        server.once('error', reject);
        server.listen(0, host, () => {
            relay.port = server.address().port;
            resolve(relay);
        });
    });
}
