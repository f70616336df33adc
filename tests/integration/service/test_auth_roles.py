#!/usr/bin/python3
"""Roles (issue 15, "Authentication and transport"): tokens from an --auth-file
made with `terrad token add` (the file holds SHA-256 hashes only), each with a
role. A viewer subscribes but its collider_create, POSE_BATCH and STEP (the
refusal answers its step) are refused with `forbidden` naming the role; a driver creates, moves and deletes its own
colliders but not another's (`not_owner`); an admin deletes anyone's with
"any_owner": true; an
unknown token is refused at hello (4013). HTTP data endpoints need a bearer
token, probes do not; the C client library as a viewer gets `forbidden` too. A
reload that changes a token's role keeps its connection under the new role.
Editing the file and sending SIGHUP revokes a token: its
open connection is closed (4013), a new hello and HTTP request with it are
refused, the other clients go on; a malformed file on SIGHUP keeps the old
tokens. At start, a plain token or a malformed line in the file stops the
daemon with an error naming the line; --bind-any with an auth file starts
without --insecure-open. Counted in terrad_auth_refused_total{reason}.
"""
# ctest-timeout: 180
import asyncio
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, tp  # noqa: E402


def token_add(path, role, name):
    p = subprocess.run([BIN, "token", "add", "--auth-file", path, "--role", role, "--name", name],
                       capture_output=True, text=True, timeout=30)
    assert p.returncode == 0, p.stderr
    return p.stdout.strip()


def refused_count(d, reason):
    _, body, _ = d.get("/metrics", token="")
    m = re.search(r'terrad_auth_refused_total\{reason="%s"\} (\d+)' % reason, body.decode())
    return int(m.group(1)) if m else -1


async def expect_refused(check, uri, token, what):
    c = tp.TerradClient(uri, token=token, name="intruder")
    try:
        await c.connect()
        check(False, f"{what}: hello accepted")
    except tp.ServerError as e:
        check(e.name == "unauthorized", f"{what}: hello refused as unauthorized ({e})")
    finally:
        await c.close()


async def wait_closed(c, timeout=30):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and c.ws.close_code is None:
        await asyncio.sleep(0.05)
    return c.ws.close_code


async def roles(check, d, tok, path):
    viewer = tp.TerradClient(d.ws, token=tok["viewer"], name="viewer")
    d1 = tp.TerradClient(d.ws, token=tok["d1"], name="driver-1")
    d2 = tp.TerradClient(d.ws, token=tok["d2"], name="driver-2")
    admin = tp.TerradClient(d.ws, token=tok["admin"], name="admin")
    for c in (viewer, d1, d2, admin):
        await c.connect()
    try:
        check([c.world.get("role") for c in (viewer, d1, d2, admin)] ==
              ["viewer", "driver", "driver", "admin"], "the world message names the role")
        sid = await viewer.subscribe(0, 0, 64, 64)
        await viewer.wait_complete(sid, timeout=30)
        check(True, "a viewer subscribes and gets its snapshot")
        try:
            await viewer.create_collider("sphere", radius=0.5)
            check(False, "a viewer's collider_create is refused")
        except tp.ServerError as e:
            check(e.name == "forbidden" and "viewer" in e.message,
                  f"a viewer's collider_create: forbidden, naming the role ({e})")
        await viewer.send_poses([tp.Pose(1, 1.0, 1.0, 1.0)])
        await viewer.wait_for(lambda: any(m.get("code") == 22 for m in viewer.errors), 10)
        check(any("POSE_BATCH" in m.get("message", "") for m in viewer.errors),
              "a viewer's POSE_BATCH: forbidden")
        # a viewer's STEP (issue 30): the refusal carries the step's ref ("step:SEQ"), so the
        # client's wait for that step ends with the error, not a timeout
        try:
            await viewer.step(1, timeout=30)
            check(False, "a viewer's STEP is refused")
        except tp.ServerError as e:
            check(e.name == "forbidden" and e.message.startswith("STEP") and "viewer" in e.message,
                  f"a viewer's STEP: forbidden, naming the role, answered to its step ({e})")
        except asyncio.TimeoutError:
            check(False, "a viewer's STEP: its refusal names the step (the wait timed out)")
        # terrain edits (issue 22): a driver or an admin, never a viewer; HTTP alike
        try:
            await viewer.edit("add", x=0, y=0, w=2, h=2, amount=5)
            check(False, "a viewer's edit is refused")
        except tp.ServerError as e:
            check(e.name == "forbidden" and "viewer" in e.message,
                  f"a viewer's edit: forbidden, naming the role ({e})")
        r = await d1.edit("add", x=0, y=0, w=2, h=2, amount=5)
        r2 = await admin.edit("remove", x=0, y=0, w=2, h=2, amount=5)
        check(r["volume_change"] == 20 and r2["volume_change"] == -20,
              "a driver's and an admin's edits are applied")
        edits = f"/v1/worlds/{d.world().get('world') or 'default-dunes'}/edits"
        for who, want in (("viewer", 403), ("d1", 200), (None, 401)):
            req = urllib.request.Request(d.http + edits, method="POST",
                                         data=b'{"op":"add","x":0,"y":0,"w":1,"h":1,"amount":1}')
            if who:
                req.add_header("Authorization", f"Bearer {tok[who]}")
            try:
                with urllib.request.urlopen(req, timeout=30) as resp:
                    status = resp.status
            except urllib.error.HTTPError as e:
                status = e.code
            check(status == want, f"POST edits as {who or 'nobody'}: {want} ({status})")

        a = await d1.create_collider("sphere", radius=0.5)
        b = await d2.create_collider("sphere", radius=0.5)
        seq = await d1.send_poses([tp.Pose(a, 2.0, 2.0, 5.0)])
        await d1.wait_ack(seq, timeout=30)
        check(True, "a driver creates and moves its own collider (ACK)")
        try:
            await d2.delete_collider(a)
            check(False, "a driver cannot delete another's collider")
        except tp.ServerError as e:
            check(e.name == "not_owner", f"a driver deleting another's collider: not_owner ({e})")
        n_err = len(d2.errors)
        await d2.send_poses([tp.Pose(a, 3.0, 3.0, 5.0)])
        await d2.wait_for(lambda: len(d2.errors) > n_err, 10)
        check(d2.errors[-1].get("code") == 7, f"a driver moving another's collider: not_owner "
              f"({d2.errors[-1]})")
        try:
            await d2.request({"type": "collider_delete", "id": a, "any_owner": True},
                             "collider_deleted")
            check(False, "a driver's collider_delete with any_owner is refused")
        except tp.ServerError as e:
            check(e.name == "forbidden", f"a driver's any_owner delete: forbidden ({e})")
        try:
            await admin.delete_collider(b)
            check(False, "an admin's plain delete of another's collider is refused")
        except tp.ServerError as e:
            check(e.name == "not_owner", f"an admin's plain delete of another's: not_owner ({e})")
        await admin.request({"type": "collider_delete", "id": b, "any_owner": True},
                            "collider_deleted")
        check(True, "an admin deletes another client's collider with any_owner")
        await d1.delete_collider(a)
        check(True, "a driver deletes its own collider")

        await expect_refused(check, d.ws, "tdk_not-a-token", "an unknown token")
        await expect_refused(check, d.ws, "", "no token")
        status, _, hdr = d.get("/v1/world", token="")
        check(status == 401 and "Bearer" in (hdr.get("WWW-Authenticate") or ""),
              f"GET /v1/world without a token: 401 with WWW-Authenticate ({status})")
        check(d.get("/v1/stats", token="nope")[0] == 401, "GET /v1/stats with a wrong token: 401")
        check(d.get("/v1/world", token=tok["viewer"])[0] == 200, "GET /v1/world as a viewer: 200")
        check(d.get("/healthz", token="")[0] == 200 and d.get("/readyz", token="")[0] == 200,
              "probes need no token")
        check(refused_count(d, "forbidden") >= 3 and refused_count(d, "bad_token") >= 4,
              "terrad_auth_refused_total counts forbidden and bad_token")

        # the C client library with a viewer's token: subscribe works, create is forbidden
        probe = os.environ.get("TERRAD_C_CLIENT_PROBE",
                               os.path.join(os.path.dirname(BIN), "c_client_probe"))
        r = await asyncio.to_thread(subprocess.run, [probe, "127.0.0.1", str(d.ws_port), "-",
                                                     tok["viewer"], "viewer"],
                                    capture_output=True, text=True, timeout=90)
        check(r.returncode == 0 and "forbidden" in r.stdout,
              f"C client as a viewer: snapshot, then create forbidden: {r.stdout.strip()}")

        # a role changed by a reload: car-2 becomes a viewer and keeps its connection
        with open(path) as f:
            text = f.read()
        with open(path, "w") as f:
            f.write(text.replace("driver car-2 ", "viewer car-2 "))
        os.kill(d.pid, signal.SIGHUP)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any("is now role viewer" in l for l in d.lines):
            await asyncio.sleep(0.1)
        try:
            await d2.create_collider("sphere", radius=0.5)
            check(False, "a driver made a viewer by a reload cannot create")
        except tp.ServerError as e:
            check(e.name == "forbidden" and d2.ws.close_code is None,
                  f"a driver made a viewer by a reload keeps its connection, create forbidden ({e})")
        with open(path, "w") as f:
            f.write(text)
        os.kill(d.pid, signal.SIGHUP)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any("is now role driver" in l for l in d.lines):
            await asyncio.sleep(0.1)

        # revoke the viewer: the file without its line, then SIGHUP
        with open(path) as f:
            lines = [l for l in f if " viewer-1 " not in l]
        with open(path, "w") as f:
            f.writelines(lines)
        os.kill(d.pid, signal.SIGHUP)
        code = await wait_closed(viewer)
        check(code == 4013, f"the revoked viewer's connection is closed with 4013 ({code})")
        await expect_refused(check, d.ws, tok["viewer"], "a revoked token")
        check(d.get("/v1/world", token=tok["viewer"])[0] == 401, "HTTP with a revoked token: 401")
        sid = await d1.subscribe(0, 0, 32, 32)
        await d1.wait_complete(sid, timeout=30)
        check(d1.ws.close_code is None, "the other clients go on after the reload")
        check(refused_count(d, "revoked") == 1, "terrad_auth_refused_total{reason=\"revoked\"} 1")

        # a malformed file on SIGHUP: logged, the tokens in use stay
        with open(path, "a") as f:
            f.write("driver broken\n")
        os.kill(d.pid, signal.SIGHUP)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not any("the tokens in use stay" in l for l in d.lines):
            await asyncio.sleep(0.1)
        check(any("line 4" in l and "the tokens in use stay" in l for l in d.lines),
              "a malformed file on SIGHUP is logged naming the line, the old tokens kept")
        again = tp.TerradClient(d.ws, token=tok["d2"], name="driver-2-again")
        await again.connect()
        await again.close()
        check(d.alive(), "the daemon goes on")
    finally:
        for c in (viewer, d1, d2, admin):
            await c.close()


def start_refusals(check, tmp):
    base = [BIN, "serve", "--no-data", "--http-port", "0", "--ws-port", "0", "--backend", "cpu",
            "--no-demo", "--ticks", "2"]
    good = os.path.join(tmp, "good")
    token_add(good, "admin", "ops")
    cases = {
        "plain": ("viewer ok " + "ab" * 32 + "\nviewer someone tdk_abcdefghijklmnop\n", "line 2"),
        "short": ("# comment\n\ndriver car-1 deadbeef\n", "line 3"),
        "role": ("pilot car-1 " + "ab" * 32 + "\n", "line 1"),
        "dup": ("viewer a " + "ab" * 32 + "\ndriver a " + "cd" * 32 + "\n", "line 2"),
    }
    for name, (text, where) in cases.items():
        path = os.path.join(tmp, name)
        with open(path, "w") as f:
            f.write(text)
        p = subprocess.run(base + ["--auth-file", path], capture_output=True, text=True, timeout=60)
        check(p.returncode != 0 and path in p.stderr and where in p.stderr,
              f"an auth file with a {name} line stops the start naming {where} ({p.returncode}): "
              f"{p.stderr.strip().splitlines()[-1:]}")
    p = subprocess.run(base + ["--auth-file", os.path.join(tmp, "missing")], capture_output=True,
                       text=True, timeout=60)
    check(p.returncode != 0 and "missing" in p.stderr, "a missing auth file stops the start")
    p = subprocess.run(base + ["--bind-any", "--auth-file", good], capture_output=True, text=True,
                       timeout=60)
    check(p.returncode == 0, f"--bind-any with an auth file starts without --insecure-open "
          f"({p.returncode})")
    with open(good) as f:
        check("tdk_" not in f.read(), "the auth file holds no plain token")
    conf = os.path.join(tmp, "conf.json")
    with open(conf, "w") as f:
        json.dump({"auth_file": good, "bind_any": True}, f)
    p = subprocess.run(base + ["--config", conf], capture_output=True, text=True, timeout=60)
    check(p.returncode == 0 and "1 tokens from " + good in p.stderr,
          f"the config key auth_file is read ({p.returncode})")


def main():
    check = Checks()
    with tempfile.TemporaryDirectory(prefix="terrad-auth-") as tmp:
        start_refusals(check, tmp)
        path = os.path.join(tmp, "tokens")
        tok = {"admin": token_add(path, "admin", "ops"), "d1": token_add(path, "driver", "car-1"),
               "d2": token_add(path, "driver", "car-2"),
               "viewer": token_add(path, "viewer", "viewer-1")}
        check(all(t.startswith("tdk_") and len(t) == 47 for t in tok.values()),
              "terrad token add prints a fresh tdk_ token")
        check(oct(os.stat(path).st_mode & 0o777) == "0o600", "the auth file is made 0600")
        d = Daemon(extra=["--auth-file", path, "--no-data"], name="auth")
        d.http_token = tok["viewer"]
        with check.running(d):
            asyncio.run(roles(check, d, tok, path))
    check.finish()


if __name__ == "__main__":
    main()
