#!/usr/bin/python3
"""The Python codec of proto/ against the shared test vectors.

- Every valid vector decodes to its fields and encodes back to its bytes
  (rectangle payloads: decoded from the C encoder's exact zstd bytes; packing
  checked byte for byte; compression by round trip).
- Every invalid vector raises its error; every prefix of a valid frame is
  refused; the mirror scenarios end in the recorded heights and versions.
- A randomized round trip of the rectangle codec and of a mirror following a
  changing world.
- TerradClient against a small in-process stand-in server on loopback (the
  real daemon's tests drive it against terrad itself).

Run with /usr/bin/python3 (needs python3-zstandard, python3-websockets).
"""
import asyncio
import json
import math
import os
import random
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import SOURCE, Checks  # noqa: E402
from terrad import proto as tp  # noqa: E402

check = Checks()


def raises(fn, name):
    try:
        fn()
    except tp.ProtoError as e:
        return e.name == name or e.name
    return "no error"


def pose_of(d):
    return tp.Pose(d["id"], d["x"], d["y"], d["z"], d["qw"], d["qx"], d["qy"], d["qz"])


def contact_of(d):
    return tp.Contact(d["id"], int(d["volume"]), d["cells"], d["area_m2"], tuple(d["deepest"]),
                      tuple(d["normal"]), d["support_height_m"])


def f32(v):
    import struct
    return struct.unpack("<f", struct.pack("<f", v))[0]


def decode_any(t, b):
    """The decoder for t; a DELTA that decodes has each rectangle decompressed."""
    if t == "POSE_BATCH":
        return tp.decode_pose_batch(b)
    if t == "DELTA":
        tick, rects = tp.decode_delta(b)
        for r in rects:
            tp.rect_decompress(r.data, r.w * r.h)
        return tick, rects
    if t == "CONTACT":
        return tp.decode_contact(b)
    if t == "ACK":
        return tp.decode_ack(b)
    if t == "COLLIDERS":
        return tp.decode_colliders(b)
    if t == "FOOTPRINTS":
        return tp.decode_footprints(b)
    if t == "FORCES":
        return tp.decode_forces(b)
    if t == "STEP":
        return tp.decode_step(b)
    if t == "STEPPED":
        return tp.decode_stepped(b)
    if t == "CHECKSUM":
        return tp.decode_checksum(b)
    return tp.decode_ping(b)


def check_valid(v):
    name, t, f = v["name"], v["type"], v["fields"]
    b = bytes.fromhex(v["hex"])
    if t == "POSE_BATCH":
        seq, poses = tp.decode_pose_batch(b)
        want = [pose_of(p) for p in f["poses"]]
        check(seq == f["seq"], f"{name}: seq")
        check(poses == [tp.Pose(p.id, *(f32(a) for a in (p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz))) for p in want],
              f"{name}: poses")
        check(tp.encode_pose_batch(f["seq"], want) == b, f"{name}: encode")
    elif t == "DELTA":
        tick, rects = tp.decode_delta(b)
        check(tick == int(f["tick"]), f"{name}: tick")
        check(len(rects) == len(f["rects"]), f"{name}: count")
        want = []
        for i, (r, d) in enumerate(zip(rects, f["rects"])):
            w = tp.Rect(d["x"], d["y"], d["w"], d["h"], d["base_version"], d["new_version"], d["encoding"],
                        bytes.fromhex(d["data_hex"]))
            want.append(w)
            check(r == w, f"{name}: rect {i} fields")
            cells = w.w * w.h
            values = tp.rect_decompress(r.data, cells)
            check(values == d["values"], f"{name}: rect {i} decompress")
            check(raises(lambda: tp.rect_decompress(r.data, cells, cells - 1), "too_large") is True,
                  f"{name}: rect {i} refuses more than max_cells")
            check(tp.rect_pack(d["values"]) == bytes.fromhex(d["packed_hex"]), f"{name}: rect {i} packing")
            check(tp.rect_unpack(bytes.fromhex(d["packed_hex"])) == d["values"], f"{name}: rect {i} unpack")
            z = tp.rect_compress(d["values"])
            check(tp.rect_decompress(z, cells) == d["values"], f"{name}: rect {i} compress round trip")
            if "old" in d:
                check(tp.rect_diff(d["old"], d["new"]) == d["values"], f"{name}: rect {i} diff")
                h = list(d["old"])
                check(tp.apply_values(w, values, h, w.x, w.y, w.w, w.h) == cells and h == d["new"],
                      f"{name}: rect {i} apply")
        check(tp.encode_delta(int(f["tick"]), want) == b, f"{name}: encode")
    elif t == "CONTACT":
        tick, cs = tp.decode_contact(b)
        want = [contact_of(c) for c in f["contacts"]]
        check(tick == int(f["tick"]), f"{name}: tick")
        check(cs == [tp.Contact(c.id, c.volume, c.cells, f32(c.area_m2), tuple(map(f32, c.deepest)),
                                tuple(map(f32, c.normal)), f32(c.support_height_m)) for c in want],
              f"{name}: contacts")
        check(tp.encode_contact(int(f["tick"]), want) == b, f"{name}: encode")
    elif t == "COLLIDERS":
        tick, cs = tp.decode_colliders(b)
        # the grousers extension: each entry's grousers (null: none) as float32 values
        lugs = [c.get("grousers") and {"count": c["grousers"]["count"], "height": f32(c["grousers"]["height"]),
                                       "thickness": f32(c["grousers"]["thickness"])} for c in f["colliders"]]
        want = [tp.ColliderState(c["id"], c["owner"], c["kind"], tuple(map(f32, c["dims"])), tuple(map(f32, c["p"])),
                                 tuple(map(f32, c["q"])), g) for c, g in zip(f["colliders"], lugs)]
        check(tick == int(f["tick"]), f"{name}: tick")
        check(cs == want, f"{name}: colliders")
        check(tp.encode_colliders(int(f["tick"]), want, grousers=bool(f.get("grousers"))) == b,
              f"{name}: encode")
    elif t == "FOOTPRINTS":
        tick, es = tp.decode_footprints(b)
        want = [tp.Footprint(e["collider"], f32(e["x"]), f32(e["y"]), f32(e["yaw"]), f32(e["size_m"]),
                             f32(e["strength_m"])) for e in f["footprints"]]
        check(tick == int(f["tick"]), f"{name}: tick")
        check(es == want, f"{name}: footprints")
        check(tp.encode_footprints(int(f["tick"]), want) == b, f"{name}: encode")
    elif t == "FORCES":
        tick, fs = tp.decode_forces(b)
        want = [tp.Force(e["id"], tuple(map(f32, e["force"])), tuple(map(f32, e["torque"])), f32(e["sinkage_m"]),
                         f32(e["area_m2"]), f32(e["patch_width_m"]), f32(e["slip"]), e["cells"])
                for e in f["forces"]]
        check(tick == int(f["tick"]), f"{name}: tick")
        check(fs == want, f"{name}: forces")
        check(tp.encode_forces(int(f["tick"]), want) == b, f"{name}: encode")
    elif t == "STEP":
        seq, ticks, sets = tp.decode_step(b)
        want = [pose_of(p) for p in f["poses"]]
        n = f["count"]
        want_sets = [want[k * n:(k + 1) * n] for k in range(f["sets"])]
        check((seq, ticks) == (f["seq"], f["ticks"]), f"{name}: head")
        check(sets == [[tp.Pose(p.id, *(f32(a) for a in (p.x, p.y, p.z, p.qw, p.qx, p.qy, p.qz)))
                        for p in s] for s in want_sets], f"{name}: poses")
        check(tp.encode_step(f["seq"], f["ticks"], want_sets) == b, f"{name}: encode")
    elif t == "STEPPED":
        check(tp.decode_stepped(b) == (int(f["tick"]), f["seq"], f["ticks"]), f"{name}: decode")
        check(tp.encode_stepped(int(f["tick"]), f["seq"], f["ticks"]) == b, f"{name}: encode")
    elif t == "CHECKSUM":
        want = [tp.TileSum(e["tile_x"], e["tile_y"], e["version"], int(e["hash"])) for e in f["tiles"]]
        check(tp.decode_checksum(b) == (int(f["tick"]), f["subscription"], want), f"{name}: decode")
        check(tp.encode_checksum(int(f["tick"]), f["subscription"], want) == b, f"{name}: encode")
    elif t == "ACK":
        check(tp.decode_ack(b) == (int(f["tick"]), f["seq"]), f"{name}: decode")
        check(tp.encode_ack(int(f["tick"]), f["seq"]) == b, f"{name}: encode")
    else:
        kind, nonce = tp.decode_ping(b)
        check(kind.name == t and nonce == int(f["nonce"]), f"{name}: decode")
        check(tp.encode_ping(int(f["nonce"]), pong=(t == "PONG")) == b, f"{name}: encode")
    # Every proper prefix is refused with a protocol error.
    ok = True
    for cut in range(len(b)):
        try:
            decode_any(t, b[:cut])
            ok = False
        except tp.ProtoError:
            pass
    check(ok, f"{name}: a prefix decoded")
    check(tp.decode(b)[0].name == t, f"{name}: generic decode")


def check_vectors(doc):
    check(doc["protocol"] == tp.PROTOCOL_VERSION, "protocol version")
    check({e["code"]: e["name"] for e in doc["errors"]} == tp.ERRORS, "error table")
    check({e["code"]: e["name"] for e in doc["types"]} == {t.value: t.name for t in tp.MsgType}, "type table")
    for v in doc["vectors"]:
        if v["valid"]:
            try:
                check_valid(v)
            except Exception as e:  # a crash is one failure, not the end of the run
                check(False, f"{v['name']}: raised {e!r}")
        else:
            got = raises(lambda: decode_any(v["type"], bytes.fromhex(v["hex"])), v["error"])
            check(got is True, f"{v['name']}: got {got}, want {v['error']}")


def check_hashes(doc):
    """The tile hash of every "hashes" entry, and a mirror's view of one of its tiles."""
    for e in doc["hashes"]:
        check(tp.heights_hash(e["heights"], e["w"], e["w"], e["h"]) == int(e["hash"]), f"hash: {e['about']}")
    m = tp.Mirror(30, 40, 100, 70, 64)
    m.heights = [i * 3 for i in range(100 * 70)]
    m.versions[4] = 5  # tile (1, 1): its part is region columns 34..97, rows 24..69
    want = tp.heights_hash(m.heights, 100, 64, 46, 24 * 100 + 34)
    s = tp.TileSum(1, 1, 5, want)
    check(m.tile_differs(s) == 0, "a mirror agrees with its own hash")
    m.heights[30 * 100 + 40] += 1
    check(m.tile_differs(s) == 1, "one height changed: the tile differs")
    check(m.tile_differs(tp.TileSum(0, 1, 5, 0)) == 0, "a tile not held is not compared")
    check(m.tile_differs(tp.TileSum(3, 1, 5, 0)) == -1, "a tile outside the region")
    # a whole frame at once (NumPy, when there is one): the same verdicts as tile by tile
    m.versions = [3, 0, 4, 5, 5, 5]
    sums = [tp.TileSum(tx, ty, 5, tp.heights_hash(m.heights, 100, min(tx * 64 + 64, 130) - max(tx * 64, 30),
                                                  min(ty * 64 + 64, 110) - max(ty * 64, 40),
                                                  (max(ty * 64, 40) - 40) * 100 + max(tx * 64, 30) - 30))
            for ty in range(2) for tx in range(3)]
    m.heights[69 * 100 + 99] = -m.heights[69 * 100 + 99] - 1  # the last cell of tile (2, 1)
    want = [(s.tile_x, s.tile_y) for s in sums if m.tile_differs(s) == 1]
    check(want == [(0, 0), (2, 0), (2, 1)], f"tile by tile: {want}")
    check(m.tiles_differing(sums) == want, f"a whole frame: {m.tiles_differing(sums)}")


def check_coded_rects(doc):
    """Each "base_rects" payload (encoding 2, PROTOCOL.md "Base snapshots") and "slope_rects"
    payload (encoding 3, "Slope snapshots") decodes to its values, or is refused with its
    error."""
    for key, decompress in (("base_rects", tp.rect_decompress_base),
                            ("slope_rects", tp.rect_decompress_slope)):
        check(len(doc[key]) >= 8, f"{key}: {len(doc[key])} vectors")
        for e in doc[key]:
            data, w, h = bytes.fromhex(e["data_hex"]), e["w"], e["h"]
            if e["error"]:
                got = raises(lambda: decompress(data, w, h, w * h), e["error"])
                check(got is True, f"{key}: {e['about']}: got {got}")
            else:
                check(decompress(data, w, h, w * h) == e["values"], f"{key}: {e['about']}")


def check_scenarios(doc):
    for s in doc["mirror_scenarios"]:
        r = s["region"]
        m = tp.Mirror(r["x"], r["y"], r["w"], r["h"], s["tile_size"])
        for i, st in enumerate(s["steps"]):
            _, rects = tp.decode_delta(bytes.fromhex(st["frame_hex"]))
            try:
                m.apply(rects)
                err = ""
            except tp.ProtoError as e:
                err = e.name
            check(err == st["error"], f"{s['name']} step {i}: got '{err}', want '{st['error']}'")
            check(m.heights == st["heights"], f"{s['name']} step {i}: heights")
            check(m.versions == st["versions"], f"{s['name']} step {i}: versions")


def check_refusals():
    check(raises(lambda: tp.encode_pose_batch(0, [tp.Pose(1, float("nan"), 0, 0)]), "bad_value") is True,
          "encode NaN pose")
    check(raises(lambda: tp.encode_pose_batch(0, [tp.Pose(1, 1e39, 0, 0)]), "bad_value") is True,
          "encode a float past float32")
    check(raises(lambda: tp.encode_pose_batch(0, [tp.Pose(1, 0, 0, 0, 0, 0, 0, 0)]), "bad_value") is True,
          "encode zero quaternion")
    b = tp.encode_pose_batch(0, [tp.Pose(1, 0, 0, 0)] * 2)
    check(raises(lambda: tp.decode_pose_batch(b, max_poses=1), "too_large") is True, "two poses, room for one")
    check(tp.zigzag32(-1) == 1 and tp.zigzag32(2**31 - 1) == 0xFFFFFFFE and tp.zigzag32(-(2**31)) == 0xFFFFFFFF,
          "zigzag")
    check(tp.unzigzag32(0xFFFFFFFF) == -(2**31) and tp.unzigzag32(0xFFFFFFFE) == 2**31 - 1, "unzigzag")
    check(raises(lambda: tp.parse_control("{"), "bad_json") is True, "bad JSON")
    check(raises(lambda: tp.parse_control("[1]"), "bad_json") is True, "JSON not an object")
    check(raises(lambda: tp.parse_control('{"type": 3}'), "bad_json") is True, "type not a string")
    check(tp.parse_control('{"type": "hello"}')["type"] == "hello", "JSON object")
    check(tp.error("not_owner", "x", "r1") == {"type": "error", "code": 7, "name": "not_owner", "message": "x",
                                               "ref": "r1"}, "error builder")


def check_random(rng):
    bad = 0
    for it in range(60):
        w, h = rng.randint(1, 64), rng.randint(1, 64)
        old = [rng.randint(-(2**31), 2**31 - 1) for _ in range(w * h)]
        mode = it % 4
        if mode == 0:
            new = list(old)
        elif mode == 1:
            new = [tp._wrap(o + rng.randint(-100, 100)) for o in old]
        elif mode == 2:
            new = [rng.randint(-(2**31), 2**31 - 1) for _ in old]
        else:
            new = [rng.choice((-(2**31), 2**31 - 1)) for _ in old]
        d = tp.rect_diff(old, new)
        z = tp.rect_compress(d)
        back = tp.rect_decompress(z, w * h)
        r = tp.Rect(-9, 4, w, h, 1, 2, 0, z)
        heights = list(old)
        tp.apply_values(r, back, heights, -9, 4, w, h)
        if back != d or heights != new:
            bad += 1
        if w * h > 1 and raises(lambda: tp.rect_decompress(z, w * h - 1), "bad_compression") is not True:
            bad += 1
    check(bad == 0, f"random rectangle round trips: {bad} bad")

    # A world, per-tile versions, random edits; the mirror of a region follows.
    W, H, T = 40, 30, 8
    world = [rng.randint(0, 100000) for _ in range(W * H)]
    tver = {}
    rx, ry, rw, rh = 3, 2, 31, 25
    m = tp.Mirror(rx, ry, rw, rh, T)
    bad = 0
    for tick in range(120):
        rects = []
        if tick % 50 == 0:
            for ty in range(H // T + 1):
                for tx in range(W // T):
                    x0, y0 = max(tx * T, rx), max(ty * T, ry)
                    x1, y1 = min(tx * T + T, rx + rw), min(ty * T + T, ry + rh)
                    if x0 >= x1 or y0 >= y1:
                        continue
                    vals = [world[y * W + x] for y in range(y0, y1) for x in range(x0, x1)]
                    rects.append(tp.Rect(x0, y0, x1 - x0, y1 - y0, 0, tver.get((tx, ty), 1), 1, tp.rect_compress(vals)))
        else:
            for tx, ty in {(rng.randrange(W // T), rng.randrange(H // T)) for _ in range(3)}:
                x0, y0 = tx * T + rng.randrange(T), ty * T + rng.randrange(T)
                w, h = rng.randint(1, T - x0 % T), rng.randint(1, T - y0 % T)
                vals = []
                for y in range(y0, y0 + h):
                    for x in range(x0, x0 + w):
                        dv = rng.randint(-1000, 1000)
                        world[y * W + x] += dv
                        vals.append(dv)
                base = tver.get((tx, ty), 1)
                tver[(tx, ty)] = base + 1
                rects.append(tp.Rect(x0, y0, w, h, base, base + 1, 0, tp.rect_compress(vals)))
        _, got = tp.decode_delta(tp.encode_delta(tick, rects))
        try:
            m.apply(got)
        except tp.ProtoError:
            bad += 1
        for y in range(rh):
            if m.heights[y * rw:(y + 1) * rw] != world[(ry + y) * W + rx:(ry + y) * W + rx + rw]:
                bad += 1
                break
    check(bad == 0, f"random mirror: {bad} bad ticks")


# ---- TerradClient against a stand-in server ---------------------------------


async def check_client():
    import websockets

    world = {"type": "world", "protocol": 1, "width": 64, "height": 64, "cell_size_m": 0.05,
             "units_per_m": 10000, "tick_hz": 60, "tick": 0, "tile_size": 16, "models": ["persson"],
             "materials": ["default"], "limits": {}}
    heights = [(x * 7 + y * 13) for y in range(64) for x in range(64)]
    tiles = {}
    seen = {}

    async def handler(ws, path=None):
        hello = json.loads(await ws.recv())
        seen["hello"] = hello
        seen["subprotocol"] = ws.subprotocol
        if hello.get("protocol") != 1:
            await ws.send(json.dumps(tp.error("bad_version", "server speaks protocol 1")))
            await ws.close(4003)
            return
        await ws.send(json.dumps(world))
        async for data in ws:
            if isinstance(data, bytes):
                if tp.decode_header(data) == tp.MsgType.PONG:
                    seen["pong"] = tp.decode_ping(data)[1]
                    continue
                seq, poses = tp.decode_pose_batch(data)
                seen["poses"] = poses
                # One tick: lower cells (20..22, 20) by 500 in tile (1, 1).
                vals = []
                for x in range(20, 23):
                    heights[20 * 64 + x] -= 500
                    vals.append(-500)
                base = tiles.get((1, 1), 1)
                tiles[(1, 1)] = base + 1
                await ws.send(tp.encode_delta(7, [tp.Rect(20, 20, 3, 1, base, base + 1, 0, tp.rect_compress(vals))]))
                await ws.send(tp.encode_contact(7, [tp.Contact(poses[0].id, 1500, 3, 0.0075, (1.05, 1.0, 0.0),
                                                               (0.0, 0.0, 1.0), 0.0)]))
                await ws.send(tp.encode_ack(7, seq))
                continue
            msg = json.loads(data)
            ref = msg.get("ref")
            if msg["type"] == "collider_create":
                if msg["shape"] not in ("sphere", "wheel"):
                    await ws.send(json.dumps(tp.error("unsupported_collider", msg["shape"], ref)))
                else:
                    await ws.send(json.dumps({"type": "collider_created", "id": 5, "ref": ref}))
            elif msg["type"] == "subscribe":
                x, y, w, h = msg["x"], msg["y"], msg["w"], msg["h"]
                await ws.send(json.dumps({"type": "subscribed", "id": 1, "x": x, "y": y, "w": w, "h": h, "ref": ref}))
                rects = []
                for ty in range(y // 16, (y + h - 1) // 16 + 1):
                    for tx in range(x // 16, (x + w - 1) // 16 + 1):
                        x0, y0 = max(tx * 16, x), max(ty * 16, y)
                        x1, y1 = min(tx * 16 + 16, x + w), min(ty * 16 + 16, y + h)
                        vals = [heights[j * 64 + i] for j in range(y0, y1) for i in range(x0, x1)]
                        rects.append(tp.Rect(x0, y0, x1 - x0, y1 - y0, 0, tiles.get((tx, ty), 1), 1,
                                             tp.rect_compress(vals)))
                await ws.send(tp.encode_delta(0, rects))
                await ws.send(tp.encode_ping(99))

    async with websockets.serve(handler, "127.0.0.1", 0, subprotocols=[tp.SUBPROTOCOL]) as server:
        port = server.sockets[0].getsockname()[1]
        async with tp.TerradClient(f"ws://127.0.0.1:{port}/", token="t0k", name="test") as c:
            check(seen["hello"] == {"type": "hello", "protocol": 1, "token": "t0k", "client": "test"}, "client hello")
            check(seen["subprotocol"] == "terrad.v1", "client offers terrad.v1")
            check(c.world["tile_size"] == 16, "client got the world")
            cid = await c.create_collider("wheel", radius=0.35, width=0.25)
            check(cid == 5, "client create collider")
            try:
                await c.create_collider("mesh", vertices=[], indices=[])
                check(False, "client: refused collider raises")
            except tp.ServerError as e:
                check(e.name == "unsupported_collider" and e.code == 18, "client: refused collider raises")
            sid = await c.subscribe(10, 12, 30, 20)
            await c.wait_for(lambda: sid in c.mirrors and c.mirrors[sid].complete, 5)
            seq = await c.send_poses([tp.Pose(cid, 1.0, 1.0, 0.3)])
            await c.wait_ack(seq, 5)
            await c.wait_for(lambda: c.contact_tick == 7, 5)
            m = c.mirrors[sid]
            want = [heights[(12 + j) * 64 + 10 + i] for j in range(20) for i in range(30)]
            check(m.heights == want, "client mirror equals the server's heights")
            check(seen["poses"][0].id == cid, "server got the pose")
            check(c.contacts[cid].volume == 1500, "client got contact feedback")
            check(not c.errors, f"client errors: {c.errors}")
            check(seen.get("pong") == 99, "client answers PING with PONG")

        # A client speaking another protocol version is refused.
        import websockets.exceptions  # noqa: F401
        c = tp.TerradClient(f"ws://127.0.0.1:{port}/")
        orig = tp.PROTOCOL_VERSION
        tp.PROTOCOL_VERSION = 2
        try:
            await c.connect()
            check(False, "bad version refused")
        except tp.ServerError as e:
            check(e.name == "bad_version", "bad version refused")
        finally:
            tp.PROTOCOL_VERSION = orig
            await c.ws.close()


def check_forces_heights():
    """FORCES' height extension (PROTOCOL.md "FORCES"): flagged, 56-byte entries, the height
    back bit for bit; a plain frame has none; the flag on another type, another flag bit, a
    length that does not match the flag and a height that is not finite are refused."""
    f = tp.Force(7, (1.5, -2.0, 80.0), (0.1, 3.0, 0.0), 0.0120000001, 0.01, 0.1, 0.2, 400,
                 0.6478531234567)
    b = tp.encode_forces(42, [f], heights=True)
    check(b[3] == tp.FORCES_FLAG_HEIGHT and len(b) == 14 + 56, "heights: flagged, 56 bytes")
    tick, fs = tp.decode_forces(b)
    check(tick == 42 and fs[0].height_m == 0.6478531234567, f"the height back: {fs}")
    plain = tp.encode_forces(42, [tp.Force(*[getattr(f, k) for k in ("id", "force", "torque",
                                  "sinkage_m", "area_m2", "patch_width_m", "slip", "cells")])])
    check(plain[3] == 0 and len(plain) == 14 + 48 and tp.decode_forces(plain)[1][0].height_m is
          None, "a plain frame: no flag, no height")
    contact = bytearray(tp.encode_contact(1, []))
    contact[3] = tp.FORCES_FLAG_HEIGHT
    check(raises(lambda: tp.decode_header(bytes(contact)), "bad_frame") is True,
          "the flag on another type is bad_frame")
    check(raises(lambda: tp.decode_forces(b[:3] + bytes([2]) + b[4:]), "bad_frame") is True,
          "another FORCES flag is bad_frame")
    check(raises(lambda: tp.decode_forces(plain[:3] + bytes([1]) + plain[4:]), "bad_frame") is True,
          "the flag on 48-byte entries is bad_frame")
    check(raises(lambda: tp.decode_forces(b[:62] + struct.pack("<d", math.nan)), "bad_value") is True,
          "a height that is not finite is bad_value")


def main():
    with open(os.path.join(SOURCE, "proto", "vectors", "vectors.json")) as f:
        doc = json.load(f)
    check_vectors(doc)
    check_scenarios(doc)
    check_hashes(doc)
    check_coded_rects(doc)
    check_refusals()
    check_forces_heights()
    check_random(random.Random(1234))
    try:
        asyncio.run(asyncio.wait_for(check_client(), 30))
    except Exception as e:
        check(False, f"client test raised {e!r}")
    check.finish()


if __name__ == "__main__":
    main()
