#!/usr/bin/python3
"""A really full disk (issue 20, item 3): the data directory on a small tmpfs
(mounted here, 16 MiB), with demo actors and a client ploughing a wide trench
(durability every-tick, so every tick writes a record of several KiB). A
filler file takes all but LEAVE bytes, and the log fills the rest itself.

Before the fix the store's retry wrote a 4 KiB probe into the pages the failed
record had taken and the truncate gave back, logged "writable again:
deformation resumes" while the disk was still full, failed the next record,
and /readyz flapped. Checked:

  - /readyz goes to 503 once the disk is full and stays 503, polled for many
    retry periods, and the log never says "writable again" meanwhile;
  - once the filler goes, /readyz is 200 again, "writable again" is logged
    exactly once, and /readyz does not fall back to 503;
  - nothing committed is lost: after kill -9, the data directory as of the
    tick GET /v1/heights last served (`terrad export --tick`) is those
    heights, and a restart recovers at least that tick.

Needs root to mount a tmpfs (the CI container runs as root); elsewhere it
skips (exit 77) and test_store_diskfull covers the full disk through the
store's fault hook.
"""
# ctest-timeout: 600
import asyncio
import errno
import os
import shutil
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, export_heights, skip, tp  # noqa: E402

check = Checks()
SIZE = "16m"
LEAVE = 512 * 1024  # bytes the filler leaves for the log to fill


def fill(path):
    """Write path until the file system has no byte left (ENOSPC at 1 byte),
    then give LEAVE bytes back."""
    with open(path, "wb", buffering=0) as f:
        chunk = 1 << 20
        while chunk >= 1:
            try:
                f.write(b"\xa5" * chunk)
            except OSError as e:
                if e.errno != errno.ENOSPC:
                    raise
                chunk //= 2
        f.truncate(max(0, f.tell() - LEAVE))


def poll_ready(d, seconds):
    """/readyz statuses every 0.2 s for seconds."""
    out, end = [], time.time() + seconds
    while time.time() < end:
        out.append(d.get("/readyz", timeout=30)[0])
        time.sleep(0.2)
    return out


def wait_ready(d, want, timeout=60.0):
    end = time.time() + timeout
    while time.time() < end:
        if d.get("/readyz", timeout=30)[0] == want:
            return True
        time.sleep(0.1)
    return False


async def scenario(d, mnt):
    loop = asyncio.get_running_loop()
    w = d.world()
    cell, upm = w["cell_size_m"], w["units_per_m"]
    client = tp.TerradClient(d.ws, name="tmpfs-full")
    await client.connect()
    # without feedback: 2 m fits the default max_active_cells (docs/service.md)
    cid = await client.request(tp.collider_create("sphere", feedback=False, radius=2.0),
                               "collider_created")
    cid = cid["id"]
    y = 256
    _, row = await loop.run_in_executor(None, d.heights, 0, y, w["width"], 1)
    z = min(row) / upm - 0.3 + 2.0  # below every cell of the row: each pose deforms
    state = {"x": 10, "last_seq": None, "run": True}

    async def plough():
        while state["run"]:
            state["x"] = 50 + (state["x"] - 40) % (w["width"] - 100)
            state["last_seq"] = await client.send_poses([tp.Pose(cid, state["x"] * cell, y * cell,
                                                                 z)])
            await asyncio.sleep(0.05)

    task = asyncio.create_task(plough())
    await asyncio.sleep(1.0)
    check((await loop.run_in_executor(None, d.get, "/readyz"))[0] == 200, "ready before the fill")

    filler = os.path.join(mnt, "filler")
    await loop.run_in_executor(None, fill, filler)
    # the log fills the last LEAVE bytes itself, at the tick rate: slow on a loaded machine
    # (make test-stress took over 60 s), so a generous deadline
    full = await loop.run_in_executor(None, wait_ready, d, 503, 300.0)
    status, body, _ = await loop.run_in_executor(None, d.get, "/readyz")
    check(full and b"No space left" in body, f"/readyz 503 names the full disk: {status} {body!r}")
    at_full = len(d.lines)
    statuses = await loop.run_in_executor(None, poll_ready, d, 8.0)
    check(statuses and all(s == 503 for s in statuses),
          f"/readyz stays 503 while the disk is full ({len(statuses)} polls): {statuses}")
    during = [x for x in d.lines[at_full:] if "writable again" in x]
    check(not during, f"never 'writable again' while the disk is full: {during[:3]}")

    os.unlink(filler)
    back = await loop.run_in_executor(None, wait_ready, d, 200, 300.0)  # generous: a loaded machine
    check(back, "/readyz 200 once the filler is gone")
    after = await loop.run_in_executor(None, poll_ready, d, 4.0)
    check(all(s == 200 for s in after), f"/readyz stays 200 once space is back: {after}")
    again = [x for x in d.lines[at_full:] if "writable again" in x]
    check(len(again) == 1, f"'writable again' logged once: {again}")

    state["run"] = False
    await task
    region = (0, 0, w["width"], w["height"])
    t, hs = await loop.run_in_executor(None, d.heights, *region)
    await client.close()
    return t, hs


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    tmp = tempfile.mkdtemp(prefix="terrad-tmpfs-")
    mnt = os.path.join(tmp, "mnt")
    os.mkdir(mnt)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={SIZE}", "tmpfs", mnt],
                       capture_output=True, text=True)
    if r.returncode != 0:
        shutil.rmtree(tmp, ignore_errors=True)
        skip(f"cannot mount a tmpfs here ({r.stderr.strip()}): test_store_diskfull covers the "
             "full disk through the fault hook")
    try:
        data = os.path.join(mnt, "data")
        d = Daemon(backend="cpu", demo=True, data_dir=data, durability="every-tick",
                   name="terrad-tmpfs")
        check.daemons.append(d)
        got = None
        try:
            got = asyncio.run(scenario(d, mnt))
        except Exception as e:  # noqa: BLE001
            check(False, f"the scenario raised: {e!r}")
        check(d.kill9() is not None, "kill -9")
        if got:
            tick, before = got
            disk, log = export_heights(data, tick, os.path.join(tmp, "export.raw"))
            changed = None if disk is None else sum(a != b for a, b in zip(before, disk))
            check(disk is not None and len(disk) == len(before) and changed == 0,
                  f"after kill -9 the data directory as of tick {tick} is the heights served "
                  f"then ({changed} cells differ; {log.strip()[-300:]})")
            d2 = Daemon(backend="cpu", demo=False, data_dir=data, durability="every-tick",
                        name="terrad-tmpfs-restart")
            with check.running(d2):
                t2, _ = d2.heights(0, 0, 1, 1)
                check(t2 is not None and t2 >= tick,
                      f"the restart recovers at least tick {tick} ({t2})")
    finally:
        subprocess.run(["umount", "-l", mnt], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
