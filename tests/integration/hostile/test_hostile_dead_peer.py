#!/usr/bin/python3
"""A dead peer must not wedge the websocket thread (issue 15, item 1).

Each attacker is a separate process with a small receive buffer: it opens a
raw websocket, says hello, subscribes 16 times to 0,0,512,512 (whole-world
snapshots it never reads) and 5 s later closes its end (FIN) with its window
shut, then lingers. Before the fix the net thread then spun inside one
lws_service call (recv() = 0 forever, libwebsockets waiting to flush output
the peer will never take): new clients timed out and SIGTERM never finished. With 1, 2 and 20 such peers: a new
client still gets its world message, /readyz and /healthz answer, and SIGTERM
stops the daemon with status 0 (the harness waits a generous 30 s).
"""
# ctest-timeout: 400
import asyncio
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, hello_ok  # noqa: E402

ATTACKER = r'''
import base64, json, os, socket, struct, sys, time
port = int(sys.argv[1])
s = socket.socket()
s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
s.connect(("127.0.0.1", port))
key = base64.b64encode(os.urandom(16)).decode()
s.sendall(("GET / HTTP/1.1\r\nHost: 127.0.0.1\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
           "Sec-WebSocket-Key: %s\r\nSec-WebSocket-Version: 13\r\n"
           "Sec-WebSocket-Protocol: terrad.v1\r\n\r\n" % key).encode())
buf = b""
while b"\r\n\r\n" not in buf:
    chunk = s.recv(4096)
    if not chunk:
        sys.exit(2)
    buf += chunk

def frame(text):
    data = text.encode()
    mask = os.urandom(4)
    n = len(data)
    head = bytes([0x81]) + (bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n))
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data))

s.sendall(frame(json.dumps({"type": "hello", "protocol": 1, "token": "", "client": "dead-peer"})))
for i in range(16):
    s.sendall(frame(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": 512, "h": 512, "ref": i})))
print("ready", flush=True)
time.sleep(5)
# Its end closes (FIN) with its receive window shut and the server's send buffer full; the
# process lingers, as a dying client's socket does while its exit is held up, so the server
# sees the EOF with its own output stuck. It dies when the test is done with it.
s.shutdown(socket.SHUT_WR)
print("closed", flush=True)
time.sleep(600)
'''


def probe(d, path):
    try:
        return d.get(path, timeout=10)[0]
    except Exception:  # noqa: BLE001
        return None


def one_round(check, peers):
    d = Daemon()
    with check.running(d):
        procs = [subprocess.Popen([sys.executable, "-c", ATTACKER, str(d.ws_port)],
                                  stdout=subprocess.PIPE, text=True) for _ in range(peers)]
        ready = sum(1 for p in procs if p.stdout.readline().strip() == "ready")
        check(ready == peers, f"{peers} peers: every attacker subscribed ({ready})")
        closed = sum(1 for p in procs if p.stdout.readline().strip() == "closed")
        check(closed == peers, f"{peers} peers: every attacker closed its end ({closed})")
        time.sleep(2)  # the net thread would now spin on their EOFs
        ok = False
        try:
            ok = asyncio.run(hello_ok(d, "after-dead-peers", timeout=20))
        except Exception as e:  # noqa: BLE001
            print(f"{peers} peers: new client: {e!r}")
        check(ok, f"{peers} dead peers: a new client gets its world message")
        check(probe(d, "/readyz") is not None, f"{peers} dead peers: /readyz answers")
        check(probe(d, "/healthz") == 200, f"{peers} dead peers: /healthz is 200")
        t0 = time.monotonic()
        st = d.stop(timeout=30)
        check(st == 0, f"{peers} dead peers: SIGTERM exits 0 within 30 s ({st}, "
                       f"{time.monotonic() - t0:.1f} s)")
        for p in procs:
            p.kill()
            p.wait()


def main():
    check = Checks()
    for peers in (1, 2, 20):
        one_round(check, peers)
    check.finish()


if __name__ == "__main__":
    main()
