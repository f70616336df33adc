#!/usr/bin/python3
"""A damaged data directory never starts silently (docs/storage.md, Recovery).

A daemon with demo actors deforms the world with a small --wal-segment-bytes
(so the log is compacted into tile snapshots several times and CONTROL lists
them) and is killed with SIGKILL. Then, on copies of its directory:

  - untouched: `terrad fsck` says clean (exit 0) and a daemon starts on it;
  - a bit flipped in the middle of the newest segment (good records follow);
  - the newest segment deleted;
  - a tile snapshot deleted;
  - the MANIFEST deleted;
each time a daemon refuses to start (exit 1) with an error naming the file,
`terrad fsck` exits 1 naming the same file and changes nothing, and
`terrad serve --recover-truncate` starts, saying what is lost; afterwards the
directory is clean again for fsck. A daemon restarted on it never reuses a
tick number (its ticks go on from at least the last one logged).
"""
# ctest-timeout: 300
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, skip  # noqa: E402

check = Checks()
REC_HEADER = 24
WAL_HEADER = 24


def segments(data):
    return sorted(n for n in os.listdir(data) if n.startswith("wal-") and n.endswith(".log"))


def records(path):
    """[(offset, length, tick)] of a segment's well-formed records."""
    with open(path, "rb") as f:
        b = f.read()
    out, at = [], WAL_HEADER
    while at + REC_HEADER <= len(b):
        magic, plen, tick = struct.unpack_from("<IIQ", b, at)
        if magic != 0x52445254 or at + REC_HEADER + plen > len(b):
            break
        out.append((at, REC_HEADER + plen, tick))
        at += REC_HEADER + plen
    return out


def serve(data, *extra, ticks=3):
    """A daemon on data that stops by itself after a few ticks: (status, stderr)."""
    args = [BIN, "serve", "--backend", "cpu", "--http-port", "0", "--ws-port", "0", "--no-demo",
            "--data", data, "--durability", "none", "--ticks", str(ticks)] + list(extra)
    p = subprocess.run(args, capture_output=True, text=True, timeout=240)
    return p.returncode, p.stderr


def fsck(data):
    p = subprocess.run([BIN, "fsck", "--data", data], capture_output=True, text=True, timeout=240)
    return p.returncode, p.stderr


def snapshot(data):
    """Names and sizes of every file under data, to see that fsck changes nothing."""
    out = {}
    for root, _, files in os.walk(data):
        for n in files:
            p = os.path.join(root, n)
            out[os.path.relpath(p, data)] = os.path.getsize(p)
    return out


def make_directory(tmp):
    """Deform with demo actors until there are tile snapshots and the newest
    segment holds enough records, then SIGKILL. Returns the directory."""
    data = os.path.join(tmp, "data")
    d = Daemon(backend="cpu", demo=True, data_dir=data, durability="every-tick",
               extra=["--wal-segment-bytes", "100000"], name="terrad-damage")
    check.daemons.append(d)
    deadline = time.time() + 120
    ready = False
    while time.time() < deadline and not ready:
        time.sleep(0.2)
        tiles = os.listdir(os.path.join(data, "tiles"))
        segs = segments(data)
        ready = (len([t for t in tiles if t.endswith(".snap")]) >= 2 and len(segs) >= 1
                 and len(records(os.path.join(data, segs[-1]))) >= 5)
    check(d.kill9() == -9, "the daemon was killed with SIGKILL")
    check(ready, "snapshots and a newest segment of at least 5 records within 120 s")
    return data


def case(tmp, pristine, name, damage_fn):
    data = os.path.join(tmp, name)
    shutil.copytree(pristine, data)
    named = damage_fn(data)
    before = snapshot(data)
    rc, err = fsck(data)
    check(rc == 1 and named in err, f"{name}: fsck exits 1 naming {named} ({rc}): {err[-600:]}")
    check(snapshot(data) == before, f"{name}: fsck changes nothing")
    rc, err = serve(data)
    check(rc == 1 and named in err and "refusing to start" in err,
          f"{name}: the daemon refuses to start naming {named} ({rc}): {err[-600:]}")
    check(snapshot(data) == before, f"{name}: a refused start changes nothing")
    rc, err = serve(data, "--recover-truncate")
    check(rc == 0 and "--recover-truncate: " in err and named in err,
          f"{name}: --recover-truncate starts and says what is lost ({rc}): {err[-800:]}")
    return data, err


def idle_restart(tmp):
    """Ticks that change nothing: after SIGKILL and after SIGTERM, a restarted
    daemon's ticks go on after every tick the first one showed (before, they
    were not logged and a restart reused their numbers: 648 before, 617 after)."""
    data = os.path.join(tmp, "idle")
    for how in ("SIGKILL", "SIGTERM"):
        d = Daemon(backend="cpu", demo=False, data_dir=data, durability="every-tick",
                   name=f"terrad-idle-{how}")
        check.daemons.append(d)
        start = d.stats()["tick"]
        deadline = time.time() + 120
        while d.stats()["tick"] < start + 100 and time.time() < deadline:
            time.sleep(0.1)
        before = d.stats()["tick"]
        if how == "SIGKILL":
            d.kill9()
        else:
            check(d.stop(timeout=120) == 0, "SIGTERM stops the idle daemon with status 0")
        d2 = Daemon(backend="cpu", demo=False, data_dir=data, durability="every-tick",
                    name=f"terrad-idle-{how}-restart")
        check.daemons.append(d2)
        after = d2.stats()["tick"]
        check(after > before, f"{how}: ticks never go backwards across a restart "
                              f"({before} before, {after} after)")
        d2.stop(timeout=120)


def main():
    if not os.access(BIN, os.X_OK):
        skip(f"no daemon binary at {BIN}")
    tmp = tempfile.mkdtemp(prefix="terrad-damage-")
    try:
        pristine = make_directory(tmp)
        newest = segments(pristine)[-1]
        recs = records(os.path.join(pristine, newest))
        last_logged = max(t for _, _, t in recs)

        # untouched: clean, starts, and goes on after the last logged tick
        clean = os.path.join(tmp, "clean")
        shutil.copytree(pristine, clean)
        rc, err = fsck(clean)
        check(rc == 0 and "is clean" in err, f"untouched: fsck clean ({rc}): {err[-400:]}")
        rc, err = serve(clean)
        check(rc == 0 and "refusing" not in err, f"untouched: starts ({rc}): {err[-400:]}")
        last = max(t for s in segments(clean) for _, _, t in records(os.path.join(clean, s)))
        check(last > last_logged, f"ticks go on after the last logged one ({last_logged} -> {last})")

        def flip(data):
            path = os.path.join(data, newest)
            off, length, _ = recs[len(recs) // 2]
            with open(path, "r+b") as f:
                f.seek(off + length // 2)
                b = f.read(1)
                f.seek(off + length // 2)
                f.write(bytes([b[0] ^ 0x10]))
            return newest

        _, err = case(tmp, pristine, "bitflip", flip)
        check("ticks " in err and "are lost" in err, f"bitflip: the lost ticks are listed: {err[-400:]}")

        def drop_newest(data):
            os.unlink(os.path.join(data, newest))
            return newest

        _, err = case(tmp, pristine, "newest-segment", drop_newest)
        missing = re.compile(re.escape(newest) + r" is missing \(CONTROL records segments \d+\.\.\d+\): "
                             r"(ticks after \d+ up to \d+ are lost|the ticks it held are lost, every "
                             r"tick after \d+ \(CONTROL last recorded tick \d+\))")
        check(missing.search(err),
              "newest-segment: the damage names the segment, CONTROL's range and what is lost: "
              f"{[line for line in err.splitlines() if 'damage' in line]}")

        def drop_tile(data):
            tile = sorted(t for t in os.listdir(os.path.join(data, "tiles")) if t.endswith(".snap"))[0]
            os.unlink(os.path.join(data, "tiles", tile))
            return tile

        case(tmp, pristine, "tile-snapshot", drop_tile)

        def drop_manifest(data):
            os.unlink(os.path.join(data, "MANIFEST"))
            return "MANIFEST"

        case(tmp, pristine, "manifest", drop_manifest)

        idle_restart(tmp)
        for name in ("bitflip", "newest-segment", "tile-snapshot", "manifest"):
            rc, err = fsck(os.path.join(tmp, name))
            check(rc == 0, f"{name}: clean after --recover-truncate ({rc}): {err[-400:]}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
