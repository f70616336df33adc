#!/usr/bin/python3
# ctest-timeout: 480
"""The per-cell compaction memory (docs/materials.md "Compaction memory", docs/storage.md
"Per-cell state") of the persson models and of sumner survives kill -9 of the real daemon
exactly (issue 28). For each of the two (the same scene, its model set):

- a real client presses a sphere along one track across fresh snow (the snow preset, which
  remembers up to 30 cm) and a crust (snow remembering 5 mm at most), then back over it
  deeper, against a daemon with a data directory (durability every-tick);
- run A (the reference) is never killed; run B is killed with SIGKILL between the two
  passes and restarted on its data directory. Both clients do the same thing at the same
  point (close, reconnect, create the sphere again), so the two runs differ only by the crash;
- the memory is read as a client would: every cell's through GET /v1/heights?layer=compaction
  and its sum through /v1/stats `compacted`;
- after the restart run B's heights and every cell's memory are as before the kill; after
  the second pass — which sinks less where the first compacted, so it reads the recovered
  memory — its heights, memory and the units it compacted equal A's exactly;
- at every point of both runs the promises of docs/materials.md hold: the memory never
  passes its material's maximum, and Σh + Σmemory is what it was at the start (across the
  kill too).

Before the memory was kept (records, snapshots), the restarted daemon began at zero memory:
every memory check after the kill failed and the second pass compacted more (issue 28
measured 101 cells differing by up to 230 units). The drive and the checks are
tests/support/compaction_drive.py's, shared with test_cluster_compaction_failover.
"""
import asyncio
import os
import shutil
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import Checks, Daemon, metric_value  # noqa: E402
import compaction_drive as cd  # noqa: E402

check = Checks()


def state(d):
    _, hs = d.heights(0, 0, cd.W, cd.H)
    _, mem = d.heights(0, 0, cd.W, cd.H, layer="compaction")
    return cd.state(hs, mem, d.stats())


def bad_layers(d):
    """A layer the daemon does not have, or the base's memory: 400 naming the field, and
    the daemon goes on."""
    before = metric_value(d.metrics()[1], "terrad_http_bad_requests_total") or 0
    for query, say in (("layer=memory", "parameter layer must be heights or compaction"),
                       ("layer=compaction&base=1", "parameter layer")):
        status, body, _ = d.get(f"/v1/heights?x=0&y=0&w=2&h=2&{query}")
        check(status == 400 and say.encode() in body,
              f"/v1/heights?{query}: 400 naming the field ({status} {body[:120]!r})")
    after = metric_value(d.metrics()[1], "terrad_http_bad_requests_total")
    check(after == before + 2, f"both counted in terrad_http_bad_requests_total ({before} -> {after})")
    check(d.stats()["ready"], "and the daemon goes on")


def run(scene, data, crash):
    """One run on data directory `data`; crash: kill -9 and restart between the passes."""
    label = "crashed" if crash else "reference"
    args = dict(extra=["--scene", scene], durability="every-tick")
    d = Daemon(data_dir=data, name=f"terrad-{label}", **args)
    check.daemons.append(d)
    out = {}
    try:
        if not crash:
            bad_layers(d)
        out["start"] = state(d)
        asyncio.run(cd.drive(check, d.ws, d.heights, cd.FIRST, 0.02))
        out["middle"] = state(d)
        if crash:
            d.kill9()
            d = Daemon(data_dir=data, name=f"terrad-{label}-restarted", **args)
            check.daemons.append(d)
        out["recovered"] = state(d)
        asyncio.run(cd.drive(check, d.ws, d.heights, cd.SECOND, 0.03))  # deeper
        out["end"] = state(d)
    finally:
        d.stop()
    return out


def main():
    for model in (None, "sumner"):  # the persson default, then sumner
        scene = cd.scene_file(model)
        dirs = [tempfile.mkdtemp(prefix="terrad-compaction-recovery-") for _ in range(2)]
        try:
            ref = run(scene, dirs[0], crash=False)
            got = run(scene, dirs[1], crash=True)
            cd.compare(check, ref, got, f"kill -9 and restart ({model or 'persson'})")
        finally:
            os.unlink(scene)
            for p in dirs:
                shutil.rmtree(p, ignore_errors=True)
    check.finish()


if __name__ == "__main__":
    main()
