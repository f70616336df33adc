#!/usr/bin/python3
# ctest-timeout: 600
"""
The websocket server (server/net) against a hand-driven hub: a small C
harness (tests/support/net_harness.c, built by CMake) links net, hub and the
rest of terrad_core, plays a fake sim thread (snapshots for subscribe/resync,
tile deltas on request) and is driven over stdin; Python clients check the protocol's refusals, fan-out, rate
limits, slow clients and shutdown (proto/PROTOCOL.md).
"""
import asyncio, json, os, struct, sys, tempfile, time

import websockets


def find_harness():
    """tests/support/net_harness.c, built by CMake next to terrad (ctest sets TERRAD_NET_HARNESS)."""
    src = os.environ.get("TERRAD_SOURCE_DIR", os.getcwd())
    bin_ = os.environ.get("TERRAD_BIN", os.path.join(src, "build", "terrad"))
    path = os.environ.get("TERRAD_NET_HARNESS", os.path.join(os.path.dirname(bin_), "net_harness"))
    if not os.access(path, os.X_OK):
        print("no", path, "(build first)")
        sys.exit(1)
    return path


SUB = "terrad.v1"


class Harness:
    async def start(self, env=None):
        e = dict(os.environ)
        e.update(env or {})
        self.p = await asyncio.create_subprocess_exec(HARNESS, "secret", stdin=asyncio.subprocess.PIPE,
                                                      stdout=asyncio.subprocess.PIPE,
                                                      stderr=asyncio.subprocess.PIPE, env=e)
        self.lines = []
        self.log = []  # the server's log lines (also echoed to stderr for ctest's output)
        self.event = asyncio.Event()
        self.log_reader = asyncio.create_task(self._read_log())
        line = (await self.p.stdout.readline()).decode()
        assert line.startswith("PORT "), line
        self.port = int(line.split()[1])
        self.reader = asyncio.create_task(self._read())
        self.uri = f"ws://127.0.0.1:{self.port}/"

    async def _read(self):
        while True:
            l = await self.p.stdout.readline()
            if not l:
                break
            self.lines.append(l.decode().strip())
            self.event.set()

    async def _read_log(self):
        while True:
            l = await self.p.stderr.readline()
            if not l:
                break
            sys.stderr.write(l.decode(errors="replace"))
            self.log.append(l.decode(errors="replace").strip())

    async def cmd(self, text):
        self.p.stdin.write((text + "\n").encode())
        await self.p.stdin.drain()

    async def wait_line(self, pred, timeout=5.0, start=0):
        t0 = time.time()
        while time.time() - t0 < timeout:
            for l in self.lines[start:]:
                if pred(l):
                    return l
            self.event.clear()
            try:
                await asyncio.wait_for(self.event.wait(), 0.2)
            except asyncio.TimeoutError:
                pass
        raise AssertionError("no line matching; last: %r" % self.lines[-5:])

    async def stats(self):
        n = len(self.lines)
        await self.cmd("stats")
        return await self.wait_line(lambda l: l.startswith("STATS"), start=n)

    async def stop(self):
        await self.cmd("quit")
        l = await self.wait_line(lambda l: l.startswith("STOPPED"), timeout=10)
        await self.p.wait()
        return l


async def connect(h, token="secret", hello=True, name="t"):
    ws = await websockets.connect(h.uri, subprotocols=[SUB], max_size=1 << 26)
    if hello:
        await ws.send(json.dumps({"type": "hello", "protocol": 1, "token": token, "client": name}))
        w = json.loads(await ws.recv())
        assert w["type"] == "world", w
        return ws, w
    return ws, None


async def recv_json(ws, timeout=3.0):
    while True:
        m = await asyncio.wait_for(ws.recv(), timeout)
        if isinstance(m, str):
            return json.loads(m)


async def expect_error(ws, name, timeout=3.0):
    m = await recv_json(ws, timeout)
    assert m["type"] == "error" and m["name"] == name, m
    return m


async def expect_close(ws, code, timeout=3.0):
    try:
        while True:
            await asyncio.wait_for(ws.recv(), timeout)
    except websockets.ConnectionClosed as e:
        assert e.code == code, (e.code, e.reason)
        return e.reason


def pose_batch(seq, poses, version=1):
    b = struct.pack("<BBBBIH", 0x54, version, 1, 0, seq, len(poses))
    for (cid, x, y, z, qw, qx, qy, qz) in poses:
        b += struct.pack("<I7f", cid, x, y, z, qw, qx, qy, qz)
    return b


async def ping_ok(ws, nonce=7):
    await ws.send(struct.pack("<BBBBQ", 0x54, 1, 2, 0, nonce))
    while True:
        m = await asyncio.wait_for(ws.recv(), 3)
        if isinstance(m, bytes) and m[2] == 3:
            assert struct.unpack("<Q", m[4:12])[0] == nonce
            return True



async def scenario_main():
    h = Harness()
    await h.start()
    t_all = time.time()

    # handshake + world
    ws, w = await connect(h)
    for k in ["protocol", "server", "width", "height", "cell_size_m", "units_per_m", "height_range", "tick_hz",
              "tick", "tile_size", "models", "materials", "shapes", "limits"]:
        assert k in w, k
    assert w["limits"]["max_message_bytes"] == 1048576 and w["width"] == 300 and w["models"] == ["persson-ssbo"]
    await h.wait_line(lambda l: l.startswith("CMD kind=0"))
    print("handshake ok", w["server"], "client_id", w.get("client_id"))

    # no subprotocol
    try:
        x = await websockets.connect(h.uri)
        print("!! no-subprotocol connect accepted, subprotocol =", x.subprotocol)
        await x.close()
    except Exception as e:
        print("no subprotocol refused:", type(e).__name__, e)

    # wrong token
    x, _ = await connect(h, hello=False)
    await x.send(json.dumps({"type": "hello", "protocol": 1, "token": "nope"}))
    e = await expect_error(x, "unauthorized")
    assert e["fatal"] is True
    await expect_close(x, 4013)
    print("wrong token ok")

    # wrong version
    x, _ = await connect(h, hello=False)
    await x.send(json.dumps({"type": "hello", "protocol": 2, "token": "secret"}))
    await expect_error(x, "bad_version")
    await expect_close(x, 4003)
    print("wrong version ok")

    # first message not hello (binary), and bad json first
    x, _ = await connect(h, hello=False)
    await x.send(b"\x54\x01\x02\x00" + b"\0" * 8)
    await expect_error(x, "unauthorized")
    await expect_close(x, 4013)
    x, _ = await connect(h, hello=False)
    await x.send("{nope")
    await expect_error(x, "unauthorized")
    await expect_close(x, 4013)
    print("not-hello-first ok")

    # bad json, unknown type, ref echo; connection stays
    await ws.send("{not json")
    await expect_error(ws, "bad_json")
    await ws.send("[1,2]")
    await expect_error(ws, "bad_json")
    await ws.send(json.dumps({"type": "frobnicate", "ref": "abc"}))
    e = await expect_error(ws, "unknown_type")
    assert e["ref"] == "abc"
    await ws.send(json.dumps({"type": "subscribe", "ref": "x" * 65}))
    await expect_error(ws, "bad_value")
    assert await ping_ok(ws)
    print("bad json ok")

    # oversize (keeps connection), 4x oversize (1009)
    await ws.send("x" * (1048576 + 10))
    await expect_error(ws, "too_large")
    assert await ping_ok(ws)
    big, _ = await connect(h)
    try:
        await big.send(b"\x54" * (4 * 1048576 + 100))
    except websockets.ConnectionClosed:
        pass
    await expect_close(big, 1009, timeout=5)
    print("oversize ok")

    # binary header errors
    await ws.send(b"\x54\x01")
    await expect_error(ws, "bad_frame")
    await ws.send(b"\x55\x01\x01\x00")
    await expect_error(ws, "bad_frame")
    await ws.send(b"\x54\x02\x01\x00")
    await expect_error(ws, "bad_version")
    await ws.send(b"\x54\x01\x7f\x00")
    await expect_error(ws, "unknown_type")
    await ws.send(b"\x54\x01\x10\x00" + b"\0" * 10)
    await expect_error(ws, "unknown_type")
    await ws.send(pose_batch(1, [])[:-1])
    await expect_error(ws, "bad_frame")
    print("binary header errors ok")

    # colliders
    async def create(sock, **kw):
        msg = {"type": "collider_create"}
        msg.update(kw)
        await sock.send(json.dumps(msg))
        return await recv_json(sock)

    r = await create(ws, shape="sphere", radius=0.5, ref=11)
    assert r["type"] == "collider_created" and r["ref"] == 11, r
    sphere = r["id"]
    r = await create(ws, shape="capsule", radius=0.3, half_length=1.0, pose={"p": [1, 2, 3], "q": [1, 0, 0, 0]})
    assert r["type"] == "collider_created", r
    capsule = r["id"]
    l = await h.wait_line(lambda l: l.startswith("CMD kind=2") and f"collider={capsule} " in l)
    assert "pose=1,2,3/0.707107,0.707107,0,0" in l, l
    r = await create(ws, shape="wheel", radius=0.4, width=0.3, material="sand", feedback=False)
    assert r["type"] == "collider_created", r
    l = await h.wait_line(lambda l: l.startswith("CMD kind=2") and f"collider={r['id']} " in l)
    assert "hl=0.15" in l and "mat=sand" in l and "fb=0" in l and "pose=0,0,0/0,0,0,0" in l, l
    r = await create(ws, shape="mesh", vertices=[0, 0, 0, 1, 0, 0, 0, 1, 0], indices=[0, 1, 2])
    assert r["type"] == "collider_created", r
    await h.wait_line(lambda l: l.startswith("CMD kind=2") and f"collider={r['id']} " in l and "mesh=1" in l)
    r = await create(ws, shape="mesh", vertices=[0, 0, 0, 1, 0, 0, 0, 1, 0], indices=[0, 1, 3])
    assert r["name"] == "bad_value", r
    r = await create(ws, shape="mesh", vertices=[0.001] * (3 * 16385), indices=[0, 1, 2])
    assert r["name"] == "too_large", r
    r = await create(ws, shape="torus", radius=1)
    assert r["name"] == "unsupported_collider", r
    r = await create(ws, shape="sphere", radius=1, material="lava")
    assert r["name"] == "unsupported_collider", r
    r = await create(ws, shape="sphere", radius=51)
    assert r["name"] == "bad_value", r
    r = await create(ws, shape="sphere", radius="1")
    assert r["name"] == "bad_value", r
    r = await create(ws, shape="box", half_extents=[1, 1, 0])
    assert r["name"] == "bad_value", r
    r = await create(ws, shape="sphere", radius=1, pose={"p": [0, 0, 0], "q": [2, 0, 0, 0]})
    assert r["name"] == "bad_value", r
    print("collider create ok:", r["message"])

    # poses: ok, NaN, foreign, unknown
    await ws.send(pose_batch(77, [(sphere, 1.5, 2.5, 0.25, 1, 0, 0, 0)]))
    await h.wait_line(lambda l: l.startswith(f"POSE collider={sphere} ") and "seq=77" in l)
    await ws.send(pose_batch(78, [(sphere, 1, 1, 1, 1, 0, 0, 0), (capsule, float("nan"), 0, 0, 1, 0, 0, 0)]))
    e = await expect_error(ws, "bad_value")
    assert e["ref"] == 78 and e["collider"] == capsule, e
    ws2, _ = await connect(h, name="other")
    await ws2.send(pose_batch(5, [(sphere, 1, 1, 1, 1, 0, 0, 0)]))
    e = await expect_error(ws2, "not_owner")
    assert e["collider"] == sphere and e["ref"] == 5
    await ws2.send(pose_batch(6, [(99999, 1, 1, 1, 1, 0, 0, 0)]))
    await expect_error(ws2, "unknown_collider")
    await ws2.send(json.dumps({"type": "collider_delete", "id": sphere}))
    await expect_error(ws2, "not_owner")
    await ws2.send(pose_batch(7, [(1, 0, 0, 0, 1, 0, 0, 0)] * 65))
    await expect_error(ws2, "too_large")
    await ws.send(json.dumps({"type": "collider_delete", "id": sphere, "ref": "d"}))
    r = await recv_json(ws)
    assert r["type"] == "collider_deleted" and r["id"] == sphere and r["ref"] == "d", r
    await ws.send(pose_batch(79, [(sphere, 1, 1, 1, 1, 0, 0, 0)]))
    await expect_error(ws, "unknown_collider")
    print("poses ok")

    # subscriptions
    await ws.send(json.dumps({"type": "subscribe", "x": 250, "y": 0, "w": 60, "h": 10}))
    await expect_error(ws, "outside_world")
    await ws.send(json.dumps({"type": "subscribe", "x": -1, "y": 0, "w": 6, "h": 10}))
    await expect_error(ws, "outside_world")
    await ws.send(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": 0, "h": 10}))
    await expect_error(ws, "bad_value")
    await ws.send(json.dumps({"type": "unsubscribe", "id": 42}))
    await expect_error(ws, "unknown_subscription")
    print("subscription refusals ok")

    # fan-out: A (0,0)-tile, B spans tiles (0,0),(1,0); C elsewhere
    async def sub(sock, x, y, w_, h_):
        await sock.send(json.dumps({"type": "subscribe", "x": x, "y": y, "w": w_, "h": h_}))
        r = await recv_json(sock)
        assert r["type"] == "subscribed", r
        # snapshot marker frame
        while True:
            m = await asyncio.wait_for(sock.recv(), 3)
            if isinstance(m, bytes) and m[4:6] == b"\xee\xee":
                return r["id"]

    A, _ = await connect(h, name="A")
    B, _ = await connect(h, name="B")
    C, _ = await connect(h, name="C")
    await sub(A, 0, 0, 64, 64)
    await sub(B, 60, 0, 10, 10)
    await sub(C, 128, 128, 10, 10)
    await h.cmd("delta 0 0 100")
    await h.cmd("delta 1 0 100")
    await h.cmd("delta 4 3 100")  # tile (256..300, 192..200): clipped edge tile, nobody
    got = {}
    for name, sock in (("A", A), ("B", B), ("C", C)):
        got[name] = []
        try:
            while True:
                m = await asyncio.wait_for(sock.recv(), 2)  # generous: a loaded machine
                if isinstance(m, bytes):
                    got[name].append((m[5], m[4]))
        except asyncio.TimeoutError:
            pass
    print("fan-out:", got)
    assert got["A"] == [(0, 0)] and got["B"] == [(0, 0), (1, 0)] and got["C"] == [], got

    # rate limit (not one error per message). The bounds follow from the limits (240/s, burst
    # 480, one rate_limited error a second) and the time the flood really took, so a loaded
    # machine that stretches it changes the bounds, not the verdict.
    t0 = time.time()
    for i in range(1500):
        await ws2.send(b"\x54\x01\x02\x00" + struct.pack("<Q", i))
    errs = pongs = 0
    t_last = t0
    try:
        while True:
            m = await asyncio.wait_for(ws2.recv(), 3)
            t_last = time.time()
            if isinstance(m, str):
                assert json.loads(m)["name"] == "rate_limited", m
                errs += 1
            else:
                pongs += 1
    except asyncio.TimeoutError:
        pass
    window = t_last - t0  # the server handled the flood within it
    print(f"rate flood: {pongs} pongs, {errs} rate_limited errors in {window:.2f} s")
    assert 400 <= pongs <= 480 + 240 * window + 1, (pongs, window)
    assert (errs >= 1 or pongs == 1500) and errs <= 1 + int(window), (errs, window)

    # slow client: D subscribes then stops reading while tiles flood
    D, _ = await connect(h, name="D")
    await sub(D, 0, 0, 128, 64)
    print(await h.stats())
    await h.cmd("snapbytes 200000")
    await h.cmd("flood 0 0 65536 20")  # ~1.3 MB per tick, 78 MB/s
    rss = []
    for i in range(8):
        await asyncio.sleep(1)
        s = await h.stats()
        rss.append(int(s.split("rss_kb=")[1].split()[0]))
        # keep A, B, C reading (they subscribe tile 0,0 too)
        for sock in (A, B, C, ws):
            try:
                while True:
                    await asyncio.wait_for(sock.recv(), 0.01)
            except asyncio.TimeoutError:
                pass
    print("slow: rss kB per second:", rss)
    print(await h.stats())
    await h.cmd("noflood")
    await asyncio.sleep(0.3)
    # D reads again: a snapshot (eeee), then deltas again
    seen_snap = False
    total = 0
    t0 = time.time()
    while not seen_snap and time.time() - t0 < 10:
        m = await asyncio.wait_for(D.recv(), 5)
        total += 1
        seen_snap = isinstance(m, bytes) and m[4:6] == b"\xee\xee"
    await asyncio.sleep(0.2)
    await h.cmd("delta 0 0 100")
    await h.cmd("delta 0 0 100")
    after = []
    try:
        while True:
            m = await asyncio.wait_for(D.recv(), 1)
            if isinstance(m, bytes):
                after.append(m[4:6])
    except asyncio.TimeoutError:
        pass
    print(f"slow client after reading again: frames before snapshot={total} snapshot={seen_snap} after={after}")
    # a loaded machine may still be draining the old backlog (more deltas, another snapshot):
    # what matters is that after the last snapshot come exactly the two new deltas
    tail = after[len(after) - after[::-1].index(b"\xee\xee"):] if b"\xee\xee" in after else after
    assert seen_snap and tail.count(b"\x00\x00") == 2, after
    assert max(rss) < 80000, rss  # kB: a few clients with 8 MB pending each at most

    # shutdown
    t0 = time.time()
    await h.cmd("quit")
    e = await expect_error(ws, "shutting_down", timeout=30)  # generous: a loaded machine
    await expect_close(ws, 1001, timeout=30)
    print(await h.wait_line(lambda l: l.startswith("STOPPED"), timeout=10))
    await h.p.wait()
    print("all ok in %.1f s" % (time.time() - t_all))



async def flood(ws, limit_s, stall=None):
    """Send pings at ~100/s (5 x the harness's RATE=20) for limit_s or until the server
    closes; the close (code, seconds since the flood began) or None, and the errors read.
    With stall (a TERRAD_FAULT_STALL file), the net thread is stopped for 1.5 s in every
    3 s: a server too slow to read, not a client that paused."""
    t0 = time.time()
    errs = 0
    closed = None

    async def reader():
        nonlocal errs, closed
        try:
            while True:
                if isinstance(await ws.recv(), str):
                    errs += 1
        except websockets.ConnectionClosed as ex:
            closed = (ex.code, time.time() - t0)

    async def staller():
        while True:
            await asyncio.sleep(1.5)
            with open(stall, "w") as f:
                f.write("net\n")
            await asyncio.sleep(1.5)
            os.unlink(stall)

    r = asyncio.create_task(reader())
    st = asyncio.create_task(staller()) if stall else None
    try:
        while closed is None and time.time() - t0 < limit_s:
            await ws.send(b"\x54\x01\x02\x00" + b"\0" * 8)
            await asyncio.sleep(0.01)
    except websockets.ConnectionClosed:
        pass
    if st:
        st.cancel()
        if os.path.exists(stall):
            os.unlink(stall)
    await asyncio.sleep(0.5)
    if closed is None and time.time() - t0 >= limit_s:
        r.cancel()
    return closed, errs


async def scenario_flood_read_late():
    """A flood the server reads late is still a flood (test-stress found it: a starved net
    thread left gaps of over a second between refusals and each gap started the 10 s
    again). The fault hook stops the net thread for 1.5 s in every 3 s while the client
    floods; it must still be closed with 4010, after its 10 s."""
    fd, stall = tempfile.mkstemp(prefix="terrad-stall-")
    os.close(fd)
    os.unlink(stall)
    h = Harness()
    await h.start({"RATE": "20", "TERRAD_FAULT_STALL": stall})
    G, _ = await connect(h, name="G")
    closed, errs = await flood(G, 120, stall=stall)
    print(f"flood read late: closed={closed} errors={errs}")
    assert closed and closed[1] > 9.5, closed
    # What is pinned here is the server's decision: it closed G as a flood, with 4010, and not
    # before the 10 s (the client's clock above). On a starved machine the close frame itself
    # has been seen lost (1 run in ~10 beside stress-ng, and once in CI: the client saw the
    # TCP connection end, 1006, in the same millisecond as the server's close, with 150
    # stalled pings still unread on the server's side); its delivery is what scenario_limits'
    # floods check, on a net thread that is not stalled. So a 1006 here must be matched by the
    # server's own log line saying it closed G with 4010.
    if closed[0] != 4010:
        assert closed[0] == 1006, closed
        said = [l for l in h.log if '(127.0.0.1, G) disconnected: the server closed with code 4010' in l]
        assert said, ("client saw", closed, "server log", h.log[-5:])
    print(await h.stop())


async def scenario_limits():
    h = Harness()
    await h.start({"HELLO_TIMEOUT": "0.5", "RATE": "20"})
    # hello timeout
    x, _ = await connect(h, hello=False)
    t0 = time.time()
    e = await expect_error(x, "unauthorized")
    await expect_close(x, 4013)
    print("hello timeout after %.2f s: %s" % (time.time() - t0, e["message"]))

    # overflow of the hub's outbound queue: subscribers get fresh snapshots
    A, _ = await connect(h, name="A")
    await A.send(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": 10, "h": 10}))
    assert (await recv_json(A))["type"] == "subscribed"
    # the subscribe's snapshot first: a burst that overflows the queue while that snapshot is
    # still queued is answered by one fresh snapshot, not two (seen once under load)
    m = await asyncio.wait_for(A.recv(), 120)
    assert isinstance(m, bytes) and m[4:6] == b"\xee\xee", m[:8]
    n = len(h.lines)
    await h.cmd("burst 0 0 16 70000")
    print(await h.wait_line(lambda l: l.startswith("OK burst"), start=n))
    deltas = snaps = 0
    # until the resync's snapshot came (generously: a loaded machine is slow), then 1 s of quiet
    deadline = time.time() + 120
    try:
        while True:
            wait = 1.0 if snaps >= 1 else max(0.1, deadline - time.time())
            m = await asyncio.wait_for(A.recv(), wait)
            if isinstance(m, bytes):
                if m[4:6] == b"\xee\xee":
                    snaps += 1
                else:
                    deltas += 1
    except asyncio.TimeoutError:
        pass
    print(f"overflow: deltas={deltas} snapshots after the burst={snaps}")
    assert snaps == 1  # the resync's

    await h.cmd("snapbytes 1000000")
    # a raw client that never reads, asking for 1 MB snapshots: closed at the hard bound
    import socket, os, base64
    def frame(text):
        data = text.encode()
        mask = os.urandom(4)
        hdr = bytes([0x81])
        n = len(data)
        hdr += bytes([0x80 | n]) if n < 126 else bytes([0x80 | 126]) + struct.pack(">H", n)
        return hdr + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data))
    sk = socket.socket()
    sk.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sk.connect(("127.0.0.1", h.port))
    key = base64.b64encode(os.urandom(16)).decode()
    sk.sendall((f"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: terrad.v1\r\n\r\n").encode())
    time.sleep(0.2)
    # hello, subscribe and 38 resyncs in ONE write: the server handles the whole read before it
    # writes to this client, so 39 snapshots of 1 MB are queued (past the ~34 MB hard bound)
    # before anything could pause its reading. Sent one by one, a loaded server read them in
    # several pieces; its first partial write to this never-reading client paused reading
    # (net_peer.c), the queue stayed under the bound and the client stayed open: not a bug
    # (memory stays bounded), but a test whose outcome depended on the machine's speed.
    frames = [frame(json.dumps({"type": "hello", "protocol": 1, "token": "secret"})),
              frame(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": 10, "h": 10}))]
    frames += [frame(json.dumps({"type": "resync"})) for _ in range(38)]
    sk.sendall(b"".join(frames))
    deadline = time.time() + 120  # a condition, not a time: a loaded machine builds 39 MB slowly
    while True:
        await asyncio.sleep(0.5)
        s = await h.stats()
        if "clients=1 " in s + " " or time.time() > deadline:
            break
    print(s)
    assert "clients=1" in s, s  # only A: the raw client was closed
    sk.close()

    # sustained flood: 4010 after 10 s
    F, _ = await connect(h, name="F")
    closed, errs = await flood(F, 120)
    print(f"flood: closed={closed} errors={errs}")
    # the flood limit closes it, and not before its 10 s window (no upper bound: a loaded
    # machine may be late, which is not a bug)
    assert closed and closed[0] == 4010 and closed[1] > 9.5, closed

    # a client that really pauses is forgiven: 3 s of flood, 7 s of silence (more than the
    # 3 s of allowance a flood may owe plus the 2 s burst), then a new flood gets its own 10 s
    P, _ = await connect(h, name="P")
    closed, _ = await flood(P, 3)
    assert closed is None, closed
    await asyncio.sleep(7)
    closed, errs = await flood(P, 120)
    print(f"flood after a pause: closed={closed} errors={errs}")
    assert closed and closed[0] == 4010 and closed[1] > 9.5, closed
    print(await h.stop())



async def main():
    await scenario_main()
    await scenario_limits()
    await scenario_flood_read_late()


if __name__ == "__main__":
    HARNESS = find_harness()
    asyncio.run(main())
