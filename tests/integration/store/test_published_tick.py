#!/usr/bin/python3
"""A tick a client was told of is never "in the future" anywhere: the world's published tick
(hub_published_tick, set first in service_tick's row 9, before the status, the frames and the
reads; docs/design.md "One tick") is what spectate's from_tick is judged against, not the tick
of the frames the websocket thread has dispatched.

- A daemon with demo actors (every tick changes the world, so every tick is logged) under
  --durability group:10000: each tick's frames are held until the sync that covers it, the
  first one about 10 s after the store opened, so meanwhile the websocket thread has
  dispatched no tick while /v1/stats and GET /v1/heights (X-Terrad-Tick) go on naming them.
- The world message a client gets at hello names a tick no later than /v1/stats right after.
- POST /v1/worlds/NAME/edits is answered with its tick only once the store has made that tick
  durable (terrad_store_durable_tick right after the answer is at least it): without the
  holding (service_edits_answer answered at once) the answer came up to 10 s before the sync.
- GET /v1/heights answers as of tick T; `spectate` from T on a fresh connection is accepted
  (`spectating`, then spectate_end "live": its replay is at the live tick); so is a spectate
  from the tick /v1/stats names; GET /v1/heights?tick=T rebuilds exactly what the live read
  answered. A from_tick 100,000 ticks ahead is still refused, naming from_tick.

Without the change (net_spectate.c judged from_tick against the websocket thread's own tick,
which stays behind while the frames are held) the spectate from T is refused as "in the
future (the world is at tick 0)": the spectate checks fail. The window is the group's 10 s;
on a machine so loaded that the test reaches the spectates only after the first sync, the
old code would pass them too (it never makes this test fail with the change).
"""
import asyncio
import os
import struct
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (Checks, Daemon, RecordingClient, metric_value, post_edit,  # noqa: E402
                             wait_until)
import terrad as tp  # noqa: E402

check = Checks()
WAIT = 120  # seconds: generous, a loaded 2-core machine
W = H = 32


async def spectate_from(d, tick, what):
    """A spectate of a small window from tick on a fresh connection: (accepted, why)."""
    s = RecordingClient(d.ws, name=f"spectator-{what}")
    await s.connect()
    try:
        await s.spectate(0, 0, W, H, tick, speed=8, timeout=WAIT)
    except tp.ServerError as e:
        await s.close()
        return False, e.msg
    await s.wait_for(lambda: s.spectate_ended is not None, WAIT)
    ended = s.spectate_ended
    await s.close()
    return True, ended


async def run(d):
    check(wait_until(lambda: d.stats()["tick"] >= 20, WAIT), "the world ticks")
    c = RecordingClient(d.ws, name="hello")
    await c.connect()
    told = c.world["tick"]
    stats_tick = d.stats()["tick"]
    check(told <= stats_tick,
          f"the world message's tick ({told}) is no later than /v1/stats' after it ({stats_tick})")
    await c.close()

    status, body, headers = d.get_busy(f"/v1/heights?x=0&y=0&w={W}&h={H}")
    check(status == 200 and headers.get("X-Terrad-Tick"), f"a live read ({status})")
    read_tick = int(headers.get("X-Terrad-Tick"))
    live = list(struct.unpack(f"<{W * H}i", body))
    ok, why = await spectate_from(d, read_tick, "read")
    check(ok, f"spectate from the tick a live read named ({read_tick}): accepted ({why})")
    check(ok and why.get("reason") == "live", f"and played to the live tick ({why})")

    stats_tick = d.stats()["tick"]
    ok, why = await spectate_from(d, stats_tick, "stats")
    check(ok, f"spectate from the tick /v1/stats named ({stats_tick}): accepted ({why})")

    status, body, _ = d.get_busy(f"/v1/heights?x=0&y=0&w={W}&h={H}&tick={read_tick}", timeout=60)
    check(status == 200 and list(struct.unpack(f"<{W * H}i", body)) == live,
          f"?tick={read_tick} rebuilds what the live read answered ({status})")

    ok, why = await spectate_from(d, stats_tick + 100000, "future")
    check(not ok and why.get("message", "").startswith("from_tick:"),
          f"a from_tick 100,000 ticks ahead is refused, naming from_tick ({why})")

    # An HTTP edit's answer is an acknowledgement: it waits for the sync that makes its tick
    # durable (service_edits_answer holds it with the tick's frames), so a crash after it
    # cannot lose the edit.
    name = d.world().get("world") or "default-dunes"
    st, a = post_edit(d, name, {"op": "add", "x": 1, "y": 1, "w": 2, "h": 2, "amount": 5})
    _, text = d.metrics()
    durable = metric_value(text, "terrad_store_durable_tick")
    check(st == 200 and durable is not None and durable >= a.get("tick", float("inf")),
          f"an HTTP edit is answered once its tick is durable ({st} {a}; the durable tick "
          f"right after: {durable})")
    check(d.stats()["ready"], "and the daemon goes on")


def main():
    with check.running(Daemon(demo=True, durability="group:10000")) as d:
        asyncio.run(run(d))
    check.finish()


if __name__ == "__main__":
    main()
