#!/usr/bin/python3
# ctest-timeout: 300
"""The drain of a single daemon (issue 32, item 5; docs/fleet.md), against the
real daemon, real signals and a real websocket client that drives a collider
through the terrain it mirrors. Twice: once started by SIGTERM, once by the
admin call POST /v1/drain. Each time, while the client drives:

- before: /healthz and /readyz answer 200 (on the --probe-port listener);
- once draining: /readyz answers 503 naming the drain while /healthz stays
  200 (Kubernetes' conventions: alive, not ready);
- the connected client gets a "draining" control message naming the reason
  and the grace, and is still served (ACKs of its poses go on);
- a new websocket hello is refused with error shutting_down naming the drain
  and close 4020; POST /v1/worlds is refused with 503 naming it; GET
  /v1/worlds says the default world's lifecycle is "draining";
- the admin call: without a token 401, with a body 400 naming "body"; a
  second call says the drain was already on; an admin that subscribed to
  world_state events hears the default world go "driven" once the client's
  collider is in it, then "draining";
- once the client has its last ACK and leaves, the daemon exits 0 by itself
  (the grace is far longer), and every tick the client saw acknowledged is on
  disk: `terrad export --tick T` of its window equals the client's mirror at
  T, and a daemon restarted on the data directory recovers at least tick T.
Waits are by condition with generous deadlines; no speed is checked.
Without the drain (SIGTERM stopping at once) no client is told and the daemon
exits while the client drives: the first checks after the signal fail."""
import asyncio
import hashlib
import os
import re
import shutil
import signal
import sys
import tempfile
import time
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import (  # noqa: E402
    Checks, Daemon, EventWatcher, RecordingClient, export_heights, json_call, raw_hello, tp)

check = Checks()
ADMIN = "admin-token-for-the-drain"
GRACE_MS = 120000  # far longer than the test: the daemon must stop because the client left
WAIT = 120  # seconds: generous deadlines for a loaded 2-core machine


def probe(port, path):
    """(status, body text) of a GET on the probe listener."""
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=10) as r:
            return r.status, r.read().decode()
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode()


def probe_port(d):
    for line in d.lines:
        m = re.search(r"probes: http://127\.0\.0\.1:(\d+)/healthz", line)
        if m:
            return int(m.group(1))
    raise RuntimeError("the daemon did not print its probe port")


async def until(cond, timeout=WAIT):
    end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > end:
            return False
        await asyncio.sleep(0.05)
    return True


async def drive(client, sid, stop, sent):
    """A sphere sweeping the window's middle row, pressed 0.15 m into the
    terrain under it (read from the mirror); sent[0]: the last batch's seq."""
    w = client.world
    cs, upm = w["cell_size_m"], w["units_per_m"]
    cid = await client.create_collider("sphere", radius=0.4)
    m = client.mirrors[sid]
    y = (m.y + m.h / 2) * cs
    x, vx = (m.x + 2) * cs, 2.0
    while not stop.is_set():
        x += vx / 60
        if x < (m.x + 1) * cs or x > (m.x + m.w - 1) * cs:
            vx = -vx
        cx, cy = int(x / cs) - m.x, int(y / cs) - m.y
        ground = m.heights[cy * m.w + cx] / upm
        sent[0] = await client.send_poses([tp.Pose(cid, x, y, ground + 0.25, 1, 0, 0, 0)])
        await asyncio.sleep(1 / 60)


async def scenario(d, data, how):
    port = probe_port(d)
    token = ADMIN if how == "admin" else ""
    watcher = None
    if how == "admin":  # an allocator watching the world's lifecycle (world_state events)
        st, body = json_call(d.http, "GET", "/v1/worlds", token=ADMIN)
        name = body["worlds"][0]["name"] if st == 200 else "?"
        check(st == 200 and body["worlds"][0].get("lifecycle") == "ready",
              f"admin: before any client the default world is ready ({st} {body})")
        watcher = await EventWatcher(d, token=ADMIN, events=("world_state",)).connect()
        answer = await watcher.subscribe()
        check(answer and answer.get("type") == "events_subscribed",
              f"admin: subscribe_events world_state is accepted ({answer})")
    c = RecordingClient(d.ws, token=token, name=f"drain-{how}", keep=600)
    notices = []
    c.on("message", lambda msg: notices.append(msg) if msg.get("type") == "draining" else None)
    await c.connect()
    ww, wh = c.world["width"], c.world["height"]
    region = (ww // 4, wh // 2 - 16, min(128, ww // 2), 32)
    sid = await c.subscribe(*region)
    await c.wait_complete(sid, WAIT)
    stop, sent = asyncio.Event(), [0]
    task = asyncio.create_task(drive(c, sid, stop, sent))
    check(await until(lambda: c.acked_tick > 0), f"{how}: the client's poses are acknowledged")
    if watcher:
        ev = await watcher.next_event(WAIT, "world_state", name)
        check(ev and ev.get("state") == "driven",
              f"admin: a world_state event says the world is driven once a collider is in it ({ev})")
    check(probe(port, "/healthz")[0] == 200 and probe(port, "/readyz")[0] == 200,
          f"{how}: before the drain /healthz and /readyz are 200")

    if how == "signal":
        d.proc.send_signal(signal.SIGTERM)
        reason = "SIGTERM"
    else:
        st, body = json_call(d.http, "POST", "/v1/drain", raw=b"")
        check(st == 401, f"admin: POST /v1/drain without a token is refused 401 ({st} {body})")
        st, body = json_call(d.http, "POST", "/v1/drain", raw=b"{}", token=ADMIN)
        check(st == 400 and "body" in body.get("error", ""),
              f"admin: POST /v1/drain with a body is refused 400 naming body ({st} {body})")
        check(probe(port, "/readyz")[0] == 200, "admin: a refused drain call drains nothing")
        st, body = json_call(d.http, "POST", "/v1/drain", raw=b"", token=ADMIN)
        check(st == 202 and body.get("draining") is True and body.get("grace_ms") == GRACE_MS,
              f"admin: POST /v1/drain answers 202 with the grace ({st} {body})")
        reason = "POST /v1/drain"

    check(await until(lambda: notices), f"{how}: the connected client is told it drains")
    n = notices[0] if notices else {}
    check(reason in n.get("reason", "") and n.get("grace_ms") == GRACE_MS,
          f"{how}: the notice names the reason and the grace ({n})")
    st, body = probe(port, "/readyz")
    check(st == 503 and "draining" in body and reason in body,
          f"{how}: /readyz is 503 naming the drain ({st} {body!r})")
    check(probe(port, "/healthz")[0] == 200, f"{how}: /healthz stays 200 while draining")
    check(d.get("/healthz")[0] == 200, f"{how}: /healthz on the main port stays 200")

    answer, code = await raw_hello(d, "", token=token)
    check(answer.get("type") == "error" and answer.get("name") == "shutting_down"
          and "draining" in answer.get("message", "") and code == 4020,
          f"{how}: a new client is refused naming the drain, close 4020 ({answer}, {code})")
    st, body = json_call(d.http, "POST", "/v1/worlds",
                         {"name": "late", "scene": {"name": "late", "width": 64, "height": 64}},
                         token=ADMIN if how == "admin" else None)
    check(st == 503 and "draining" in body.get("error", ""),
          f"{how}: POST /v1/worlds is refused 503 naming the drain ({st} {body})")
    st, body = json_call(d.http, "GET", "/v1/worlds", token=ADMIN if how == "admin" else None)
    lifecycles = [w.get("lifecycle") for w in body.get("worlds", [])] if st == 200 else []
    check(lifecycles[:1] == ["draining"], f"{how}: GET /v1/worlds says draining ({st} {body})")
    if how == "admin":
        st, body = json_call(d.http, "POST", "/v1/drain", raw=b"", token=ADMIN)
        check(st == 202 and body.get("already") is True,
              f"admin: a second POST /v1/drain says it was already on ({st} {body})")
        ev = await watcher.next_event(WAIT, "world_state", name)
        check(ev and ev.get("state") == "draining",
              f"admin: a world_state event says the world is draining ({ev})")
        await watcher.close()

    told_at = c.acked_tick
    check(await until(lambda: c.acked_tick > told_at + 5),
          f"{how}: the client is still served while draining (ACKs {told_at} → {c.acked_tick})")
    check(d.alive(), f"{how}: the daemon waits for its client")
    stop.set()
    await task
    last = sent[0]
    check(await until(lambda: c.acked_seq >= last), f"{how}: the last pose batch is acknowledged")
    tick = c.acked_tick
    copy = c.history.get(tick, {}).get(sid)
    await c.close()

    loop = asyncio.get_running_loop()
    try:
        rc = await loop.run_in_executor(None, d.proc.wait, WAIT)
    except Exception:  # noqa: BLE001  (subprocess.TimeoutExpired)
        rc = None
    check(rc == 0, f"{how}: the daemon exits 0 once its client left ({rc})")
    check("every client has left" in d.log(), f"{how}: the log says why the drain ended")
    if copy is None:
        check(False, f"{how}: no mirror copy at the last ACK (tick {tick})")
        return
    heights, complete = copy
    out = os.path.join(data, "export.raw")
    exported, err = export_heights(data, tick, out, region)
    check(complete and exported == heights,
          f"{how}: the export of tick {tick} equals the client's mirror at its last ACK ({err})")
    again = Daemon(backend="cpu", data_dir=data, durability="every-tick", name=f"restart-{how}")
    check.daemons.append(again)
    with check.running(again):
        recovered = again.stats()["tick"]
        check(recovered >= tick, f"{how}: the restart recovers tick {recovered} >= {tick}")


def main():
    for how in ("signal", "admin"):
        data = tempfile.mkdtemp(prefix=f"terrad-drain-{how}-")
        auth = None
        extra = ["--drain-grace-ms", str(GRACE_MS), "--probe-port", "0"]
        try:
            if how == "admin":
                fd, auth = tempfile.mkstemp(prefix="terrad-auth-")
                with os.fdopen(fd, "w") as f:
                    f.write(f"admin admin {hashlib.sha256(ADMIN.encode()).hexdigest()}\n")
                extra += ["--auth-file", auth]
            d = Daemon(backend="cpu", data_dir=data, durability="every-tick", extra=extra,
                       name=f"terrad-drain-{how}")
            d.http_token = ADMIN if how == "admin" else None
            with check.running(d):
                asyncio.run(scenario(d, data, how))
        finally:
            shutil.rmtree(data, ignore_errors=True)
            if auth:
                os.unlink(auth)
    check.finish()


if __name__ == "__main__":
    main()
