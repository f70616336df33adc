#!/usr/bin/python3
# ctest-timeout: 180
"""world_created / world_deleted events on a single daemon (issue 22, item 5;
PROTOCOL.md "Events"), against the real daemon and real websocket clients:

- an admin connection that sent subscribe_events gets world_created when
  POST /v1/worlds creates a world and world_deleted when DELETE ends it;
- one subscribed to world_deleted only gets no world_created;
- a viewer's subscribe_events is refused (forbidden) and its connection
  goes on; an unknown event name is refused naming events[i]; a missing
  "events" names events;
- HTTP edits racing a DELETE of their world each end with an answer — applied
  (200), or refused at once because the world stopped (503 shutting_down) or
  is gone (404) — never by the edit's 10 s timeout (504).
Waits are by condition with generous deadlines; no speed is checked."""
import asyncio
import hashlib
import json
import os
import shutil
import sys
import time
import tempfile
import threading

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, EventWatcher, json_call  # noqa: E402

check = Checks()
ADMIN, VIEWER = "admin-token-for-events", "viewer-token-for-events"


def call(d, method, path, body=None):
    return json_call(d.http, method, path, body, token=ADMIN)


async def scenario(d):
    viewer = await EventWatcher(d, token=VIEWER).connect()
    answer = await viewer.subscribe()
    check(answer and answer.get("type") == "error" and answer.get("name") == "forbidden",
          f"a viewer's subscribe_events is refused: {answer}")
    admin = await EventWatcher(d, token=ADMIN).connect()
    answer = await admin.subscribe(["world_created", "nope"])
    check(answer and answer.get("name") == "bad_value" and
          answer.get("message", "").startswith("events[1]"),
          f"an unknown event name is refused naming events[1]: {answer}")
    await admin.ws.send(json.dumps({"type": "subscribe_events", "ref": "ev"}))
    answer = await admin._next(lambda m: m.get("ref") == "ev", 60)
    check(answer and answer.get("name") == "bad_value" and
          answer.get("message", "").startswith("events:"), f"no events: refused naming it: {answer}")
    answer = await admin.subscribe()
    check(answer and answer.get("type") == "events_subscribed" and
          answer.get("events") == ["world_created", "world_deleted"],
          f"an admin subscribes to both events: {answer}")
    deletes = await EventWatcher(d, token=ADMIN).connect()
    answer = await deletes.subscribe(["world_deleted"])
    check(answer and answer.get("events") == ["world_deleted"], f"world_deleted only: {answer}")
    loop = asyncio.get_running_loop()
    scene = {"name": "ev", "world": {"width": 32, "height": 32, "cell_size_m": 0.05},
             "terrain": {"kind": "flat", "height_m": 0.5}}
    status, doc = await loop.run_in_executor(None, call, d, "POST", "/v1/worlds",
                                             {"name": "ev-1", "scene": scene})
    check(status == 201, f"create ev-1: {status} {doc}")
    event = await admin.next_event()
    check(event == {"type": "event", "event": "world_created", "world": "ev-1"},
          f"the admin hears world_created ev-1: {event}")
    status, doc = await loop.run_in_executor(None, call, d, "DELETE", "/v1/worlds/ev-1")
    check(status == 200, f"delete ev-1: {status} {doc}")
    event = await admin.next_event()
    check(event == {"type": "event", "event": "world_deleted", "world": "ev-1"},
          f"the admin hears world_deleted ev-1: {event}")
    event = await deletes.next_event()
    check(event and event.get("event") == "world_deleted" and event.get("world") == "ev-1",
          f"the world_deleted-only admin's first event is world_deleted ev-1: {event}")
    await viewer.ws.send(json.dumps({"type": "unsubscribe", "id": 99, "ref": "still"}))
    answer = await viewer._next(lambda m: m.get("ref") == "still", 60)
    check(answer is not None, f"the viewer's connection went on after its refusal: {answer}")
    for w in (viewer, admin, deletes):
        await w.close()


def edits_racing_delete(d):
    scene = {"name": "race", "world": {"width": 32, "height": 32, "cell_size_m": 0.05},
             "terrain": {"kind": "flat", "height_m": 0.5}}
    status, doc = call(d, "POST", "/v1/worlds", {"name": "ev-race", "scene": scene})
    check(status == 201, f"create ev-race: {status} {doc}")
    answers, stop = [], threading.Event()

    def hammer():
        while not stop.is_set():
            status, doc = call(d, "POST", "/v1/worlds/ev-race/edits",
                               {"op": "add", "x": 1, "y": 1, "w": 2, "h": 2, "amount": 1})
            answers.append((status, doc))
            if status == 404:
                return

    threads = [threading.Thread(target=hammer) for _ in range(6)]
    for t in threads:
        t.start()
    end = time.monotonic() + 60
    while time.monotonic() < end and not any(s == 200 for s, _ in answers):
        time.sleep(0.05)
    status, doc = call(d, "DELETE", "/v1/worlds/ev-race")
    check(status == 200, f"delete ev-race while edits come: {status} {doc}")
    stop.set()
    for t in threads:
        t.join(150)
    statuses = sorted({s for s, _ in answers})
    check(any(s == 200 for s, _ in answers), f"edits were applied before the delete: {statuses}")
    check(set(statuses) <= {200, 404, 503}, f"every racing edit got an answer, none timed out: "
          f"{statuses}")
    refused = [doc for s, doc in answers if s == 503]
    check(all(r.get("name") == "shutting_down" and "ev-race" in r.get("error", "")
              for r in refused), f"a refused edit names the stopped world: {refused[:2]}")


def main():
    tmp = tempfile.mkdtemp(prefix="terrad-events-")
    auth = os.path.join(tmp, "auth")
    with open(auth, "w") as f:
        f.write(f"admin game {hashlib.sha256(ADMIN.encode()).hexdigest()}\n"
                f"viewer watch {hashlib.sha256(VIEWER.encode()).hexdigest()}\n")
    d = Daemon(extra=["--auth-file", auth])
    d.http_token = ADMIN
    check.daemons.append(d)
    try:
        asyncio.run(scenario(d))
        edits_racing_delete(d)
    except Exception:  # noqa: BLE001
        import traceback
        check(False, "the test raised:\n" + traceback.format_exc())
    finally:
        d.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
