#!/usr/bin/python3
"""A full disk, through the store's fault hook (--store-fault FILE: while FILE
exists every storage write fails with ENOSPC), on a daemon with demo actors
and a client driving a collider:

  - the daemon logs a clear error, /readyz answers 503 naming the storage,
    terrad_store_available is 0 and terrad_store_errors_total{kind="enospc"}
    counts;
  - it keeps serving reads (GET /v1/heights, new subscriptions' snapshots)
    and the world does not change (no deformation that could not be kept);
  - the client's pose batches are refused with store_unavailable;
  - when FILE goes, deformation resumes by itself;
  - after a restart nothing on disk is damaged (no tail cut) and the world is
    the one the daemon had, which `terrad export` also reads back (int32, its
    old name raw32, and a region as PNG16 whose values span 0..65535, read
    back through the mapping in its sidecar .json within one step).
"""
# ctest-timeout: 180
import asyncio
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from png_read import read_png  # noqa: E402
from service_harness import BIN, Checks, Daemon, metric_value, skip, tp  # noqa: E402

check = Checks()


def read_png16(path):
    """(width, height, values) of a 16-bit greyscale, non-interlaced PNG."""
    width, height, depth, channels, values = read_png(path)
    assert depth == 16 and channels == 1
    return width, height, values


def wait_until(pred, timeout=10.0):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if pred():
            return True
        time.sleep(0.05)
    return pred()


async def scenario(d, fault):
    loop = asyncio.get_running_loop()
    w = d.world()
    region = (0, 0, w["width"], w["height"])
    client = tp.TerradClient(d.ws, name="diskfull")
    await client.connect()
    await client.subscribe(0, 0, 128, 128)
    cid = await client.create_collider("sphere", radius=0.4)

    async def pose():
        return await client.send_poses([tp.Pose(cid, 5.0, 5.0, 100.0, 1, 0, 0, 0)])

    await client.wait_ack(await pose())
    ready = await loop.run_in_executor(None, d.get, "/readyz")
    check(ready[0] == 200, f"ready before the fault: {ready[0]}")

    open(fault, "w").close()  # the disk is full
    ok = await loop.run_in_executor(None, wait_until, lambda: d.get("/readyz")[0] == 503)
    status, body, _ = d.get("/readyz")
    check(ok and b"storage unavailable" in body and b"No space left" in body,
          f"/readyz 503 names the storage: {status} {body!r}")
    metrics = d.metrics()[1]
    check(metric_value(metrics, "terrad_store_available") == 0, "terrad_store_available 0")
    check((metric_value(metrics, "terrad_store_errors_total", {"kind": "enospc"}) or 0) >= 1,
          "terrad_store_errors_total{kind=enospc} counts")
    check(any("No space left on device" in line and "refused" in line for line in d.lines),
          "a clear log line")

    # while the disk stays full, the store never says it is writable again: its
    # retry must write new bytes, not only truncate and sync (which need no space)
    lines_at_fault = len(d.lines)
    statuses = []
    t_window = time.monotonic()
    for _ in range(12):
        await asyncio.sleep(0.25)
        statuses.append((await loop.run_in_executor(None, d.get, "/readyz"))[0])
    check(all(st == 503 for st in statuses), f"/readyz stays 503 while the disk is full: {statuses}")
    during = d.lines[lines_at_fault:]
    check(not any("writable again" in line for line in during),
          f"never 'writable again' while full: {[x for x in during if 'writable' in x][:3]}")
    errors = [line for line in during if "terrad error" in line]
    # once, then at most every 10 s (FAIL_LOG_MS): a loaded machine may stretch the window
    allowed = 1 + int((time.monotonic() - t_window) / 10)
    check(len(errors) <= allowed, f"the error is logged once, then at a bounded rate "
          f"(at most {allowed} in this window): {errors[:4]}")

    # reads go on; the world stands still although the demo actors move
    t1, h1 = await loop.run_in_executor(None, d.heights, *region)
    await asyncio.sleep(0.5)
    t2, h2 = await loop.run_in_executor(None, d.heights, *region)
    check(t2 > t1 and h1 == h2, f"reads served, ticks go on ({t1} -> {t2}), heights unchanged")
    volume_frozen = d.stats()["volume"]
    check(volume_frozen == sum(h2), "Σh equals the heights")
    sid2 = await client.subscribe(200, 200, 64, 64)
    await client.wait_for(lambda: client.mirrors[sid2].complete, 10)
    _, part = await loop.run_in_executor(None, d.heights, 200, 200, 64, 64)
    check(client.mirrors[sid2].heights == part, "a new subscription gets its snapshot")

    client.errors.clear()
    await pose()
    await client.wait_for(lambda: any(e.get("name") == "store_unavailable"
                                      for e in client.errors), 5)
    err = [e for e in client.errors if e.get("name") == "store_unavailable"]
    check(err and err[0]["code"] == 15 and "storage" in err[0]["message"],
          f"pose batch refused with store_unavailable: {err[:1]}")

    os.unlink(fault)  # space returns
    ok = await loop.run_in_executor(None, wait_until, lambda: d.get("/readyz")[0] == 200)
    check(ok, "/readyz 200 again once space returns")
    seq = await pose()
    await client.wait_ack(seq)
    check(True, "pose batches acknowledged again")
    ok = await loop.run_in_executor(
        None, wait_until, lambda: d.heights(*region)[1] != h2, 10)
    check(ok, "deformation resumes")
    check(metric_value(d.metrics()[1], "terrad_store_available") == 1, "terrad_store_available 1")
    await client.close()


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    tmp = tempfile.mkdtemp(prefix="terrad-diskfull-")
    data, fault = os.path.join(tmp, "data"), os.path.join(tmp, "disk-full")
    try:
        d = Daemon(backend="cpu", demo=True, data_dir=data, extra=["--store-fault", fault],
                   durability="every-tick", name="terrad-diskfull")
        w = None
        with check.running(d):
            w = d.world()
            asyncio.run(scenario(d, fault))
        if w is None:
            check.finish()
        # stopped with SIGTERM: its last world must come back whole
        before = None
        d2 = Daemon(backend="cpu", demo=False, data_dir=data, durability="every-tick",
                    name="terrad-diskfull-restart")
        with check.running(d2):
            metrics = d2.metrics()[1]
            check(metric_value(metrics, "terrad_store_cut_tail_bytes") == 0,
                  "restart: no torn or corrupt tail")
            _, before = d2.heights(0, 0, w["width"], w["height"])
        out = os.path.join(tmp, "export.raw")
        for fmt in (None, "int32", "raw32"):
            r = subprocess.run([BIN, "export", "--data", data, "--out", out] +
                               (["--format", fmt] if fmt else []), capture_output=True,
                               text=True, timeout=60)
            check(r.returncode == 0, f"export ({fmt or 'default'}): {r.stderr}")
            if r.returncode == 0:
                with open(out, "rb") as f:
                    body = f.read()
                check(list(struct.unpack(f"<{len(body) // 4}i", body)) == before,
                      f"terrad export ({fmt or 'default'}) reads back the world GET /v1/heights "
                      "served")
        # a region as PNG16 with its mapping in the sidecar
        png = os.path.join(tmp, "region.png")
        r = subprocess.run([BIN, "export", "--data", data, "--out", png, "--format", "png16",
                            "--region", "100,50,200,120"], capture_output=True, text=True,
                           timeout=60)
        check(r.returncode == 0 and "png16 height = value *" in r.stderr, f"png16 export: {r.stderr}")
        if r.returncode == 0:
            with open(png + ".json") as f:
                side = json.load(f)
            pw, ph, values = read_png16(png)
            want = [before[(50 + y) * w["width"] + 100 + x] for y in range(120) for x in range(200)]
            got = [v * side["scale_units"] + side["offset_units"] for v in values]
            worst = max(abs(a - b) for a, b in zip(got, want))
            check(min(want) < max(want), "the png16 region is not flat")
            check((min(values), max(values)) == (0, 65535) and side["offset_units"] == min(want),
                  f"png16 spans the full 16 bits ({min(values)}..{max(values)}, offset "
                  f"{side['offset_units']}, heights {min(want)}..{max(want)})")
            check(abs(side["scale_units"] * 65535 - (max(want) - min(want))) < 1e-6,
                  f"scale is the range over 65535 steps ({side['scale_units']})")
            check((pw, ph) == (200, 120) and (side["x"], side["y"]) == (100, 50) and
                  worst <= side["scale_units"],
                  f"png16 region read back within one step ({worst} <= {side['scale_units']})")
        r = subprocess.run([BIN, "export", "--data", data, "--out", png, "--format", "raw16"],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode == 2 and "int32 or png16" in r.stderr, f"unknown format: {r.stderr}")
        r = subprocess.run([BIN, "export", "--data", data, "--out", png, "--region", "500,0,64,8"],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode != 0 and "not inside" in r.stderr, f"region outside refused: {r.stderr}")
        r = subprocess.run([BIN, "export", "--data", os.path.join(tmp, "nothing"), "--out", png],
                           capture_output=True, text=True, timeout=60)
        check(r.returncode != 0 and "MANIFEST" in r.stderr, f"missing data dir named: {r.stderr}")
        fsync_failure(tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    check.finish()


def fsync_failure(tmp):
    """Group commit and a failed fdatasync (the fault file says "fsync"): the
    held ticks are never published as durable (no retried fdatasync turns into
    a success, as with fsyncgate); the daemon stops, and a restart recovers at
    least every tick a client saw."""
    data, fault = os.path.join(tmp, "data-fsync"), os.path.join(tmp, "fsync-fails")
    d = Daemon(backend="cpu", demo=True, data_dir=data, extra=["--store-fault", fault],
               durability="group:200", name="terrad-fsync")
    check.daemons.append(d)
    seen = {"tick": 0}

    async def watch():
        asyncio.get_running_loop().set_exception_handler(lambda loop, context: None)
        client = tp.TerradClient(d.ws, name="fsync-watch")
        await client.connect()
        await client.subscribe(0, 0, 256, 256)
        await client.wait_for(lambda: client.tick > 30, 120)
        with open(fault, "w") as f:
            f.write("fsync")
        deadline = time.time() + 120
        while d.alive() and time.time() < deadline:
            seen["tick"] = max(seen["tick"], client.tick)
            await asyncio.sleep(0.05)
        seen["tick"] = max(seen["tick"], client.tick)
        try:
            await client.close()
        except Exception:  # noqa: BLE001  (the daemon is gone)
            pass

    asyncio.run(watch())
    status = d.proc.wait(60) if d.alive() else d.proc.returncode
    d.thread.join(5)
    check(status == 70, f"a failed fdatasync under group commit stops the daemon (status {status})")
    check(any("fdatasync of the log failed" in line and "none of them was published" in line
              for line in d.lines), "the log says which ticks were not durable and were not published")
    if d.alive():
        d.kill9()
    os.unlink(fault)
    d2 = Daemon(backend="cpu", demo=False, data_dir=data, durability="group:200",
                name="terrad-fsync-restart")
    with check.running(d2):
        recovered = [line for line in d2.lines if "recovered tick" in line]
        tick = int(recovered[0].split("recovered tick ")[1].split()[0]) if recovered else -1
        check(tick >= seen["tick"] > 0,
              f"every tick the client saw ({seen['tick']}) is recovered ({tick})")
        check(d2.stats()["tick"] >= seen["tick"], "tick numbers go on from there")


if __name__ == "__main__":
    main()
