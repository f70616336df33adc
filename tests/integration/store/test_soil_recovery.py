#!/usr/bin/python3
# ctest-timeout: 300
"""The bekker model's per-cell soil state (plastic sinkage, shear displacement, compacted
volume; docs/storage.md "Soil state") survives kill -9 of the real daemon exactly:

- a real client drives a wheel (with slip) along a rut on a bekker scene, then back over
  it, against a daemon with a data directory (durability every-tick);
- run A (the reference) is never killed; run B is killed with SIGKILL between the two
  passes and restarted on its data directory. Both clients do the same thing at the same
  point (close, reconnect, create the wheel again), so the two runs differ only by the crash;
- after the restart run B's heights and Σ compacted (/v1/stats `soil_compacted`) are A's
  at the same point, and after the second pass — which sinks less where the first pressed,
  so it reads the recovered plastic state — its heights, Σ compacted and every FORCES
  entry of the pass are bit-identical to A's.

The drive and the comparison are tests/support/soil_drive.py's, shared with
test_cluster_soil_failover (the same on a cluster node killed -9).
"""
import asyncio
import os
import shutil
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon  # noqa: E402
import soil_drive as sd  # noqa: E402

check = Checks()


def state(d):
    _, hs = d.heights(0, 0, sd.W, sd.H)
    return hs, d.stats()["soil_compacted"]


def run(data, crash):
    """One run on data directory `data`; crash: kill -9 and restart between the passes."""
    label = "crashed" if crash else "reference"
    args = dict(extra=["--scene", SCENE], durability="every-tick")
    d = Daemon(data_dir=data, name=f"terrad-{label}", **args)
    check.daemons.append(d)
    try:
        asyncio.run(sd.drive(check, d.ws, sd.FIRST, 0.02))
        middle = state(d)
        if crash:
            d.kill9()
            d = Daemon(data_dir=data, name=f"terrad-{label}-restarted", **args)
            check.daemons.append(d)
            recovered = state(d)
        else:
            recovered = middle
        second = asyncio.run(sd.drive(check, d.ws, sd.SECOND, 0.03))  # deeper: in contact
        end = state(d)
    finally:
        d.stop()
    return middle, recovered, second, end


def main():
    global SCENE
    SCENE = sd.scene_file()
    dirs = [tempfile.mkdtemp(prefix="terrad-soil-recovery-") for _ in range(2)]
    try:
        ref = run(dirs[0], crash=False)
        got = run(dirs[1], crash=True)
        sd.compare(check, ref, got, "kill -9 and restart")
    finally:
        os.unlink(SCENE)
        for p in dirs:
            shutil.rmtree(p, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
