// node_websocket.mjs: a WebSocket for the Node processes of the tests, loaded with
// `node --import tests/support/node_websocket.mjs`. Node 22 has a global WebSocket; Debian 12's
// Node 18 has none and Node 20 only behind --experimental-websocket (a bad option on 18), so the
// tests' Node side (clients/js's tests and example, predict_drive.mjs) takes the `ws` package's
// WebSocket (a devDependency, installed by `make web-deps`), whose browser-style API
// (binaryType, addEventListener, onmessage with event.data) is what the clients use.
if (typeof globalThis.WebSocket === 'undefined') {
  const { WebSocket } = await import('ws');
  globalThis.WebSocket = WebSocket;
}
