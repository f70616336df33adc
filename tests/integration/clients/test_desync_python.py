#!/usr/bin/python3
# ctest-timeout: 300
"""Desync detection and repair with the Python client (PROTOCOL.md "CHECKSUM", "resync" with
"tiles"; issue 32 item 4), against a real daemon on loopback (--backend cpu, no demo actors):

- bad input first, on the connection that is then repaired: a resync whose tiles lie outside
  the subscription or the world (outside_world; one at x 2147483647, whose cells overflowed an
  int before it was bounded at parse time), more than max_resync_tiles of them (too_large), tiles that
  are not an array, not [x, y] pairs of integers >= 0, tiles without an id, and an unknown id:
  each refused with an error naming the field (tiles, tiles[i], id), counted in
  terrad_resync_refused_total{field}; the connection and the daemon go on (the same client
  then repairs its mirror);
- a 200 x 150 window (tiles clipped at three edges) is held, two CHECKSUM frames find nothing;
  one height of its mirror is changed on purpose, and within a generous deadline the client
  has found that one tile differing, asked for it alone and holds it again; its mirror equals
  GET /v1/heights and the counters moved on both sides.

Without the checksums the mirror keeps the changed height and the wait for the differing tile
times out, so the repair checks fail.
"""
import asyncio
import json
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value, run, tp  # noqa: E402

check = Checks()
WINDOW = (40, 30, 200, 150)  # x, y, w, h cells: tiles 0..3 x 0..2, clipped on three sides


async def refused(c, msg):
    """The error answering msg (sent with a ref), or None when it was not refused."""
    try:
        await c.request(msg, "never", timeout=20)
    except tp.ServerError as e:
        return e.msg
    except Exception:  # noqa: BLE001
        return None
    return None


async def bad_input(c, d, sid):
    cases = [
        ({"type": "resync", "id": sid, "tiles": [[0, 0], [7, 7]]}, "outside_world", "tiles[1]"),
        # x * tile_size past INT32_MAX: refused at parse time (it overflowed an int, UB)
        ({"type": "resync", "id": sid, "tiles": [[2147483647, 0]]}, "outside_world", "tiles[0]"),
        ({"type": "resync", "id": sid, "tiles": [[0, 0]] * 65}, "too_large", "tiles"),
        ({"type": "resync", "id": sid, "tiles": "0,0"}, "bad_value", "tiles"),
        ({"type": "resync", "id": sid, "tiles": []}, "bad_value", "tiles"),
        ({"type": "resync", "id": sid, "tiles": [[1]]}, "bad_value", "tiles[0]"),
        ({"type": "resync", "id": sid, "tiles": [[0, 0], [-1, 0]]}, "bad_value", "tiles[1]"),
        ({"type": "resync", "id": sid, "tiles": [[0.5, 0]]}, "bad_value", "tiles[0]"),
        ({"type": "resync", "tiles": [[0, 0]]}, "bad_value", "id"),
        ({"type": "resync", "id": sid + 100, "tiles": [[0, 0]]}, "unknown_subscription", "id"),
    ]
    for msg, name, field in cases:
        e = await refused(c, msg)
        check(e is not None and e.get("name") == name and e.get("message", "").startswith(field + ":"),
              f"{json.dumps(msg)[:80]}: refused with {name} naming {field} (got {e})")
    _, m = d.metrics()
    check(metric_value(m, "terrad_resync_refused_total", {"field": "tiles"}) == 8,
          "terrad_resync_refused_total{field=tiles} counted the eight")
    check(metric_value(m, "terrad_resync_refused_total", {"field": "id"}) == 2,
          "terrad_resync_refused_total{field=id} counted the two")
    check(metric_value(m, "terrad_resync_tiles_requested_total") == 0, "nothing was asked for")


async def body(d):
    async with tp.Client(d.ws) as c:
        sid = await c.subscribe(*WINDOW)
        await c.wait_complete(sid, timeout=60)
        await bad_input(c, d, sid)
        check(d.alive(), "the daemon goes on after the bad input")
        frames = c.desync["checksum_frames"]
        await c.wait_for(lambda: c.desync["checksum_frames"] >= frames + 2 and c.mirrors[sid].complete, 60)
        check(c.desync["tiles_differing"] == 0, "a fresh mirror agrees with every CHECKSUM")
        m = c.mirrors[sid]
        m.heights[(WINDOW[3] // 2) * WINDOW[2] + WINDOW[2] // 2] -= 3  # behind the client's back
        t0 = asyncio.get_running_loop().time()
        await c.wait_for(lambda: c.desync["tiles_resynced"] >= 1 and m.complete, 60)
        repaired = asyncio.get_running_loop().time() - t0
        check(c.desync["tiles_differing"] == 1 and c.desync["tiles_resynced"] == 1,
              f"one tile found differing and asked for alone ({c.desync})")
        frames = c.desync["checksum_frames"]
        await c.wait_for(lambda: c.desync["checksum_frames"] >= frames + 2, 60)
        check(c.desync["tiles_differing"] == 1, "two more CHECKSUM frames find nothing")
        _, http = d.heights(*WINDOW)
        check(m.heights == http, "the repaired mirror equals GET /v1/heights of the window")
        print(f"repaired in {repaired:.3f} s; {c.desync}", flush=True)
    _, text = d.metrics()
    check(metric_value(text, "terrad_resync_tiles_requested_total") == 1, "the daemon counted the tile asked for")
    check(metric_value(text, "terrad_tile_resyncs_total") == 1, "and its snapshot")


def main():
    with check.running(Daemon()) as d:
        run(body(d))
    check.finish()


if __name__ == "__main__":
    main()
