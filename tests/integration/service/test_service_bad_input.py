#!/usr/bin/python3
# ctest-timeout: 240
"""A corpus of bad input against the real daemon (loopback, CPU backend, no
demo actors, a token required): truncated, malformed, oversized and unknown
frames, wrong versions, a wrong token, messages before hello, NaN/Inf poses,
unknown and foreign collider ids, subscriptions outside the world, bad
JSON, values out of range, limits, a flood over the rate limit.

Each gets its error code and name from proto/PROTOCOL.md (and the close code
where the error is fatal); a well-behaved client keeps working meanwhile and
its ticks keep coming; Σh and every height of the world are unchanged; and
/metrics counts the refusals in terrad_refused_messages_total{reason=...}.
"""
import asyncio
import json
import math
import os
import struct
import sys
import time
import traceback

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, RecordingClient, metric_value, skip  # noqa: E402

import terrad as tp  # noqa: E402

check = Checks()
TOKEN = "s3cret-token"
HEADER = bytes((0x54, 1, 1, 0))  # a POSE_BATCH header


def batch(seq, poses):
    """A POSE_BATCH packed by hand (no codec checks): poses are 8-tuples."""
    out = HEADER + struct.pack("<IH", seq, len(poses))
    for p in poses:
        out += struct.pack("<I7f", *p)
    return out


async def connect(d, token=TOKEN, do_hello=True, name="bad-input"):
    import websockets
    ws = await websockets.connect(d.ws, subprotocols=[tp.SUBPROTOCOL], max_size=1 << 24,
                                  close_timeout=2)
    if do_hello:
        await ws.send(json.dumps(tp.hello(token, name)))
        msg = json.loads(await asyncio.wait_for(ws.recv(), 5))
        if msg.get("type") != "world":
            raise RuntimeError(f"hello answered with {msg}")
    return ws


async def next_json(ws, timeout=3.0, want=None):
    """The next text message (skipping binary frames), or None on timeout or close."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while True:
        left = deadline - loop.time()
        if left <= 0:
            return None
        try:
            data = await asyncio.wait_for(ws.recv(), left)
        except (asyncio.TimeoutError, Exception):
            return None
        if isinstance(data, str):
            msg = json.loads(data)
            if want is None or msg.get("type") in want:
                return msg


def close_code(ws):
    rc = getattr(ws, "close_rcvd", None)
    return rc.code if rc is not None else getattr(ws, "close_code", None)


async def wait_closed(ws, timeout=3.0):
    try:
        await asyncio.wait_for(ws.wait_closed(), timeout)
    except asyncio.TimeoutError:
        return None
    return close_code(ws)


class Expect:
    """Bookkeeping of provoked errors, for the /metrics check."""

    def __init__(self):
        self.by_name = {}
        self.flood_sent = 0

    async def error(self, ws, send, name, what, ref=..., fatal=False, close=None, also=()):
        """Send (bytes, str, or a JSON dict), expect an error `name` (or one of
        `also`); for fatal errors the close code `close`."""
        if isinstance(send, dict):
            send = json.dumps(send)
        await ws.send(send)
        msg = await next_json(ws, want=("error",))
        names = (name,) + tuple(also)
        got = msg and msg.get("name")
        ok = bool(msg) and got in names and msg.get("code") == tp.ERROR_CODES.get(got)
        check(ok, f"{what}: expected error {'/'.join(names)}, got {msg}")
        if msg:
            self.by_name[got] = self.by_name.get(got, 0) + 1
            check(isinstance(msg.get("message"), str) and 0 < len(msg["message"]) <= 512,
                  f"{what}: the error has a message")
            if ref is not ...:
                check(msg.get("ref") == ref, f"{what}: error ref {msg.get('ref')!r}, expected {ref!r}")
        if fatal:
            code = await wait_closed(ws)
            check(code == close, f"{what}: closed with {close}, got {code}")
            if msg:
                check(msg.get("fatal") is True, f"{what}: the error says fatal: {msg}")
        return msg

    async def still_open(self, ws, what):
        """A request that must still be answered (the connection goes on)."""
        try:
            await ws.send(json.dumps({"type": "subscribe", "x": 0, "y": 0, "w": 1, "h": 1,
                                      "ref": "alive"}))
            msg = await next_json(ws, want=("subscribed", "error"))
        except Exception as e:  # noqa: BLE001
            msg = repr(e)
        ok = isinstance(msg, dict) and msg.get("type") == "subscribed" and msg.get("ref") == "alive"
        check(ok, f"{what}: the connection goes on ({msg})")
        if ok:
            await ws.send(json.dumps({"type": "unsubscribe", "id": msg["id"]}))
            await next_json(ws, want=("unsubscribed", "error"))


async def good_client_task(d, stop, stats):
    """The well-behaved client: subscribed, sending an empty batch every
    tick, counting ACK ticks."""
    c = RecordingClient(d.ws, token=TOKEN, name="good-client", record=False)
    await c.connect()
    sid = await c.subscribe(100, 100, 64, 64)
    cid = await c.create_collider("sphere", radius=0.2)
    stats["client"] = c
    stats["sid"] = sid
    hz = c.world.get("tick_hz") or 60
    while not stop.is_set():
        await c.send_poses([tp.Pose(cid, 6.0, 6.0, 50.0)])  # far above the terrain
        await asyncio.sleep(1 / hz)
    await asyncio.sleep(0.2)


async def corpus(d, ex):
    world = d.world()
    W, H = world["width"], world["height"]

    # ---- handshake --------------------------------------------------------
    ws = await connect(d, do_hello=False)
    await ex.error(ws, {"type": "hello", "protocol": 2, "token": TOKEN, "client": "v2"},
                   "bad_version", "hello with protocol 2", fatal=True, close=4003)
    ws = await connect(d, do_hello=False)
    await ex.error(ws, {"type": "hello", "protocol": 1, "token": "wrong", "client": "x"},
                   "unauthorized", "hello with a wrong token", fatal=True, close=4013)
    ws = await connect(d, do_hello=False)
    await ex.error(ws, {"type": "hello", "protocol": 1, "client": "x"},
                   "unauthorized", "hello without a token", fatal=True, close=4013,
                   also=("bad_value",))
    ws = await connect(d, do_hello=False)
    await ex.error(ws, {"type": "subscribe", "x": 0, "y": 0, "w": 4, "h": 4, "ref": "early"},
                   "unauthorized", "subscribe before hello", fatal=True, close=4013)
    ws = await connect(d, do_hello=False)
    await ex.error(ws, batch(1, []), "unauthorized", "a pose batch before hello", fatal=True,
                   close=4013)
    ws = await connect(d, do_hello=False)
    await ex.error(ws, "not json at all", "unauthorized", "garbage before hello", fatal=True,
                   close=4013, also=("bad_json",))
    ws = await connect(d, do_hello=False)
    t0 = time.monotonic()
    msg = await next_json(ws, timeout=4.0, want=("error",))
    code = await wait_closed(ws)
    check(msg is not None and msg.get("name") == "unauthorized" and code == 4013,
          f"no hello within hello_timeout_s: unauthorized + 4013 ({msg}, {code}, "
          f"{time.monotonic() - t0:.1f} s)")
    if msg:
        ex.by_name["unauthorized"] = ex.by_name.get("unauthorized", 0) + 1

    # ---- binary frames ---------------------------------------------------
    ws = await connect(d)
    await ex.error(ws, b"T", "bad_frame", "a 1-byte frame")
    await ex.error(ws, HEADER, "bad_frame", "a header-only POSE_BATCH")
    await ex.error(ws, HEADER + struct.pack("<IH", 7, 1) + bytes(20), "bad_frame",
                   "a truncated pose")
    await ex.error(ws, batch(8, []) + b"\0", "bad_frame", "a trailing byte")
    await ex.error(ws, bytes((0x55, 1, 1, 0)) + struct.pack("<IH", 9, 0), "bad_frame", "wrong magic")
    await ex.error(ws, bytes((0x54, 1, 1, 1)) + struct.pack("<IH", 10, 0), "bad_frame",
                   "reserved flags set")
    await ex.error(ws, bytes((0x54, 2, 1, 0)) + struct.pack("<IH", 11, 0), "bad_version",
                   "binary version byte 2")
    await ex.error(ws, bytes((0x54, 0, 1, 0)) + struct.pack("<IH", 12, 0), "bad_version",
                   "binary version byte 0")
    await ex.error(ws, bytes((0x54, 1, 0x7F, 0)) + bytes(8), "unknown_type", "binary type 0x7f")
    await ex.error(ws, tp.encode_delta(5, []), "unknown_type", "a DELTA sent to the server")
    await ex.error(ws, tp.encode_ack(5, 1), "unknown_type", "an ACK sent to the server")
    await ex.still_open(ws, "after malformed binary frames")
    # PING is answered by a PONG with the same nonce
    await ws.send(tp.encode_ping(0xDEADBEEF12345678))
    pong = None
    for _ in range(20):
        try:
            data = await asyncio.wait_for(ws.recv(), 2)
        except Exception:  # noqa: BLE001
            break
        if isinstance(data, bytes) and tp.decode_header(data) == tp.MsgType.PONG:
            pong = tp.decode_ping(data)[1]
            break
    check(pong == 0xDEADBEEF12345678, f"PING answered with a PONG of the same nonce ({pong})")

    # ---- oversized -------------------------------------------------------
    maxb = d.limits.get("max_message_bytes", 1 << 20)
    await ex.error(ws, batch(20, []) + bytes(maxb + 100), "too_large", "a binary frame over max_message_bytes")
    await ex.error(ws, json.dumps({"type": "subscribe", "pad": "x" * (maxb + 10)}), "too_large",
                   "a text frame over max_message_bytes")
    await ex.still_open(ws, "after oversized frames")
    await ex.error(ws, tp.encode_pose_batch(21, [tp.Pose(1, 0, 0, 0)] * 65), "too_large",
                   "65 poses in a batch (max_poses_per_batch 64)", ref=21, also=("unknown_collider",))
    ws2 = await connect(d)
    await ws2.send(bytes(4 * maxb + 4096))
    code = await wait_closed(ws2, 5)
    check(code == 1009, f"a frame over 4 x max_message_bytes closes with 1009 (got {code})")

    # ---- JSON ------------------------------------------------------------
    await ex.error(ws, "{not json", "bad_json", "malformed JSON")
    await ex.error(ws, "[1, 2, 3]", "bad_json", "a JSON array")
    await ex.error(ws, json.dumps({"type": 5}), "bad_json", "a numeric type")
    await ex.error(ws, json.dumps({"no_type": 1}), "bad_json", "no type")
    await ex.error(ws, "\"hello\"", "bad_json", "a JSON string")
    await ex.error(ws, {"type": "frobnicate", "ref": "f1"}, "unknown_type", "an unknown JSON type",
                   ref="f1")
    await ex.error(ws, {"type": "hello", "protocol": 1, "token": TOKEN, "ref": "h2"}, "bad_value",
                   "a second hello", also=("unknown_type", "unauthorized"))
    await ex.still_open(ws, "after bad JSON")

    # ---- colliders -------------------------------------------------------
    async def create(sock, ref, **fields):
        await sock.send(json.dumps(dict({"type": "collider_create", "ref": ref}, **fields)))
        return await next_json(sock, want=("collider_created", "error"))

    await ex.error(ws, {"type": "collider_create", "shape": "torus", "radius": 1, "ref": "c1"},
                   "unsupported_collider", "an unknown shape", ref="c1")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": 0.5,
                        "material": "lava", "ref": "c2"},
                   "unsupported_collider", "an unknown material", ref="c2")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": -1, "ref": "c3"},
                   "bad_value", "a negative radius", ref="c3")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": 1e9, "ref": "c4"},
                   "bad_value", "a radius over max_collider_extent_m", ref="c4")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": "1", "ref": "c5"},
                   "bad_value", "a radius given as a string", ref="c5")
    await ex.error(ws, {"type": "collider_create", "shape": "box", "half_extents": [1, 1],
                        "ref": "c6"}, "bad_value", "a box with two half extents", ref="c6")
    await ex.error(ws, {"type": "collider_create", "shape": "mesh",
                        "vertices": [0, 0, 0, 1, 0, 0, 0, 1, 0], "indices": [0, 1, 3], "ref": "c7"},
                   "bad_value", "a mesh index past its vertices", ref="c7")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": 0.5,
                        "pose": {"p": [1, 1, 1e40], "q": [1, 0, 0, 0]}, "ref": "c8"},
                   "bad_value", "a first pose out of float range", ref="c8")

    # my collider (parked far above the terrain) and another client's
    mine = await create(ws, "m1", shape="sphere", radius=0.3,
                        pose={"p": [2.0, 2.0, 50.0], "q": [1, 0, 0, 0]})
    check(mine and mine.get("type") == "collider_created", f"collider_create with a pose: {mine}")
    other_ws = await connect(d, name="other")
    theirs = await create(other_ws, "o1", shape="sphere", radius=0.3,
                          pose={"p": [3.0, 3.0, 50.0], "q": [1, 0, 0, 0]})
    check(theirs and theirs.get("type") == "collider_created", f"another client's collider: {theirs}")
    mid = mine["id"] if mine else 1
    tid = theirs["id"] if theirs else 2
    up = (2.0, 2.0, 50.0)
    nan, inf = float("nan"), float("inf")
    await ex.error(ws, batch(100, [(mid, nan, 2.0, 50.0, 1, 0, 0, 0)]), "bad_value", "a NaN x", ref=100)
    await ex.error(ws, batch(101, [(mid, 2.0, 2.0, inf, 1, 0, 0, 0)]), "bad_value", "an Inf z", ref=101)
    await ex.error(ws, batch(102, [(mid, *up, -inf, 0, 0, 0)]), "bad_value", "a -Inf qw", ref=102)
    await ex.error(ws, batch(103, [(mid, *up, 0, 0, 0, 0)]), "bad_value", "a zero quaternion", ref=103)
    await ex.error(ws, batch(104, [(mid, *up, 2, 0, 0, 0)]), "bad_value", "a quaternion of length 2",
                   ref=104)
    m = await ex.error(ws, batch(105, [(0x7FFFFF01, *up, 1, 0, 0, 0)]), "unknown_collider",
                       "a pose for an unknown collider", ref=105)
    check(m is None or m.get("collider") == 0x7FFFFF01, f"the error names the collider: {m}")
    m = await ex.error(ws, batch(106, [(tid, *up, 1, 0, 0, 0)]), "not_owner",
                       "a pose for another client's collider", ref=106)
    check(m is None or m.get("collider") == tid, f"the error names the collider: {m}")
    # a batch is applied whole or not at all: a good pose next to a foreign one
    await ex.error(ws, batch(107, [(mid, 2.0, 2.0, 40.0, 1, 0, 0, 0), (tid, *up, 1, 0, 0, 0)]),
                   "not_owner", "a batch with one foreign pose", ref=107)
    await ex.error(ws, {"type": "collider_delete", "id": tid, "ref": "d1"}, "not_owner",
                   "deleting another client's collider", ref="d1")
    await ex.error(ws, {"type": "collider_delete", "id": 0x7FFFFF02, "ref": "d2"},
                   "unknown_collider", "deleting an unknown collider", ref="d2")
    await ex.error(ws, {"type": "collider_delete", "ref": "d3"}, "bad_value",
                   "collider_delete without an id", ref="d3")
    # the refused batches were not used: no ACK names their sequence numbers
    await ws.send(batch(108, [(mid, 2.0, 2.0, 45.0, 1, 0, 0, 0)]))
    acks = []
    deadline = time.monotonic() + 2
    while time.monotonic() < deadline:
        try:
            data = await asyncio.wait_for(ws.recv(), 0.3)
        except asyncio.TimeoutError:
            continue
        if isinstance(data, bytes) and tp.decode_header(data) == tp.MsgType.ACK:
            acks.append(tp.decode_ack(data)[1])
            if acks[-1] == 108:
                break
    check(108 in acks and not any(100 <= s <= 107 for s in acks),
          f"refused batches are never acknowledged, the next good one is (ACK seqs {acks})")
    # an empty batch is a valid way to ask for an ACK (PROTOCOL.md POSE_BATCH)
    await ws.send(batch(109, []))
    acks = []
    deadline = time.monotonic() + 2
    while time.monotonic() < deadline and 109 not in acks:
        try:
            data = await asyncio.wait_for(ws.recv(), 0.3)
        except asyncio.TimeoutError:
            continue
        if isinstance(data, bytes) and tp.decode_header(data) == tp.MsgType.ACK:
            acks.append(tp.decode_ack(data)[1])
    check(109 in acks, f"an empty POSE_BATCH is acknowledged (ACK seqs {acks})")

    # ---- subscriptions ---------------------------------------------------
    await ex.error(ws, {"type": "subscribe", "x": W - 4, "y": 0, "w": 8, "h": 8, "ref": "s1"},
                   "outside_world", "a subscription past the east edge", ref="s1")
    await ex.error(ws, {"type": "subscribe", "x": 0, "y": H, "w": 1, "h": 1, "ref": "s2"},
                   "outside_world", "a subscription past the north edge", ref="s2")
    await ex.error(ws, {"type": "subscribe", "x": -1, "y": 0, "w": 4, "h": 4, "ref": "s3"},
                   "outside_world", "a subscription at x = -1", ref="s3", also=("bad_value",))
    await ex.error(ws, {"type": "subscribe", "x": 0, "y": 0, "w": 1 << 40, "h": 1, "ref": "s4"},
                   "outside_world", "a subscription 2^40 cells wide", ref="s4", also=("bad_value",))
    await ex.error(ws, {"type": "subscribe", "x": 0, "y": 0, "w": 0, "h": 4, "ref": "s5"},
                   "bad_value", "a subscription of width 0", ref="s5")
    await ex.error(ws, {"type": "subscribe", "x": 0.5, "y": 0, "w": 4, "h": 4, "ref": "s6"},
                   "bad_value", "a fractional x", ref="s6")
    await ex.error(ws, {"type": "unsubscribe", "id": 999, "ref": "u1"}, "unknown_subscription",
                   "unsubscribe of an unknown id", ref="u1")
    await ex.error(ws, {"type": "resync", "id": 999, "ref": "r1"}, "unknown_subscription",
                   "resync of an unknown id", ref="r1")
    limit = d.limits.get("max_subscriptions", 16)
    sids = []
    for i in range(limit):
        await ws.send(json.dumps({"type": "subscribe", "x": i, "y": 0, "w": 1, "h": 1}))
        m = await next_json(ws, want=("subscribed", "error"))
        if m and m.get("type") == "subscribed":
            sids.append(m["id"])
    check(len(sids) == limit, f"{limit} subscriptions accepted ({len(sids)})")
    await ex.error(ws, {"type": "subscribe", "x": 0, "y": 0, "w": 1, "h": 1, "ref": "s17"},
                   "limit_subscriptions", "one subscription over max_subscriptions", ref="s17")
    for s in sids:
        await ws.send(json.dumps({"type": "unsubscribe", "id": s}))
        await next_json(ws, want=("unsubscribed", "error"))
    climit = d.limits.get("max_colliders", 64)
    made = 1  # "m1"
    _, corner0 = d.heights(0, 0, 32, 32)
    for i in range(climit - 1):
        m = await create(ws, f"k{i}", shape="sphere", radius=0.1)
        made += bool(m and m.get("type") == "collider_created")
    check(made == climit, f"{climit} colliders accepted ({made})")
    await asyncio.sleep(0.3)
    _, corner1 = d.heights(0, 0, 32, 32)
    changed = sum(1 for a, b in zip(corner0, corner1) if a != b)
    check(changed == 0, f"colliders created without a pose do nothing until their first POSE_BATCH "
                        f"(PROTOCOL.md collider_create): {changed} cells near the origin changed")
    await ex.error(ws, {"type": "collider_create", "shape": "sphere", "radius": 0.1, "ref": "k*"},
                   "limit_colliders", "one collider over max_colliders", ref="k*")
    await ex.still_open(ws, "after refused requests")

    # ---- a flood over the rate limit (shorter than the 10 s that is fatal) ------
    flood = await connect(d, name="flood")
    n = int(d.limits.get("messages_burst", 480) + 2 * d.limits.get("max_messages_per_s", 240))
    for i in range(n):
        await flood.send(batch(1000 + i, []))
    got = 0
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        m = await next_json(flood, timeout=0.5, want=("error",))
        if m is None:
            break
        if m.get("name") == "rate_limited":
            got += 1
    check(got >= 1, f"a flood of {n} messages gets rate_limited errors ({got})")
    ex.by_name["rate_limited"] = ex.by_name.get("rate_limited", 0) + got
    ex.flood_sent = n  # errors may be coalesced; the metric counts dropped messages
    await asyncio.sleep(1.5)
    await ex.still_open(flood, "after a short flood")
    for s in (ws, other_ws, flood):
        await s.close()


async def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    d = Daemon(backend="cpu", token=TOKEN, config={"limits": {"hello_timeout_s": 2,
                                                           # max_colliders is what is checked
                                                           "max_active_cells": 65536}},
               name="terrad-bad-input")
    with check.running(d):
        world = d.world()
        W, H = world["width"], world["height"]
        # the limits in force, from a world message
        ws = await connect(d)
        await ws.send(json.dumps({"type": "resync"}))  # harmless with no subscriptions
        await ws.close()
        c = tp.TerradClient(d.ws, token=TOKEN)
        await c.connect()
        d.limits = c.world.get("limits", {})
        await c.close()

        _, metrics0 = d.metrics()
        vol0 = d.stats()["volume"]
        _, before = d.heights(0, 0, W, H)

        stop = asyncio.Event()
        good = {}
        task = asyncio.get_running_loop().create_task(good_client_task(d, stop, good))
        # the good client is connected and served before the corpus starts (a condition: a
        # loaded machine takes longer than any fixed wait)
        deadline = asyncio.get_running_loop().time() + 60
        while not (good.get("client") and good["client"].counts["ACK"]) and \
                asyncio.get_running_loop().time() < deadline and not task.done():
            await asyncio.sleep(0.05)
        c = good.get("client")
        check(c is not None, "the good client connected before the corpus")
        acks0 = c.counts["ACK"] if c else 0
        t0 = time.monotonic()
        stats0 = d.stats()
        ex = Expect()
        try:
            await corpus(d, ex)
        except Exception:  # noqa: BLE001
            check(False, "the corpus raised:\n" + traceback.format_exc())
        dt = time.monotonic() - t0
        stats1 = d.stats()
        stop.set()
        await task
        hz = c.world.get("tick_hz") or 60
        check(d.alive(), "the daemon is alive after the corpus")
        acks = c.counts["ACK"] - acks0
        # behaviour, not speed (rates go to make bench): the good client was
        # served during the corpus and is still served after it
        check(acks > 0, f"the good client's ticks kept coming: {acks} ACKs in {dt:.1f} s")
        rate = (stats1["tick"] - stats0["tick"]) / dt
        print(f"info: {rate:.1f} ticks per second during the corpus (configured {hz})", flush=True)
        check(stats1["tick"] > stats0["tick"], "ticks advanced during the corpus")
        check(not c.errors, f"the good client got no errors: {c.errors[:3]}")
        check(c.mirrors[good["sid"]].complete, "the good client's subscription is held")
        await c.close()

        vol1 = d.stats()["volume"]
        check(vol0 == vol1, f"Σh unchanged by bad input: {vol0} -> {vol1}")
        _, after = d.heights(0, 0, W, H)
        diff = [i for i in range(len(before)) if before[i] != after[i]]
        where = ""
        if diff:
            xs = [i % W for i in diff]
            ys = [i // W for i in diff]
            where = f"; cells x {min(xs)}..{max(xs)}, y {min(ys)}..{max(ys)}"
        check(not diff, f"every height of the world unchanged by bad input ({len(diff)} changed{where})")

        status, metrics1 = d.metrics()
        check(status == 200, "GET /metrics")
        for name, n in sorted(ex.by_name.items()):
            a = metric_value(metrics0, "terrad_refused_messages_total", {"reason": name}) or 0
            b = metric_value(metrics1, "terrad_refused_messages_total", {"reason": name})
            most = n + 5 if name != "rate_limited" else ex.flood_sent
            check(b is not None and b - a >= min(n, 1) and b - a <= most,
                  f"/metrics terrad_refused_messages_total{{reason=\"{name}\"}} grew by "
                  f"{None if b is None else b - a} for {n} refusals")
    check.finish()


if __name__ == "__main__":
    asyncio.run(main())
