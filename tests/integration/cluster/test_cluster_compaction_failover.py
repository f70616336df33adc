#!/usr/bin/python3
# ctest-timeout: 420
"""test_cluster_compaction_failover: a persson world whose materials remember compaction (snow
and a 5 mm crust) keeps every cell's compaction memory through a failover on a cluster (a real
nats-server with JetStream, two `terrad serve --cluster` nodes on loopback; issue 28,
docs/storage.md "Per-cell state", docs/cluster.md):

- the world's owner is driven by a real client: a sphere pressed along one track across both
  materials, in two halves; between them the test waits until the owner has compacted the
  log into tile snapshots, so the takeover reads both kinds of JetStream record that carry
  the memory (TRS3 snapshots, then TRC3 log records after them);
- the owner is killed with SIGKILL; the other node takes the world from JetStream (its log
  names the snapshots and records it recovered from); every height and every cell's memory
  (GET /v1/heights?layer=compaction) are as before the kill, and /v1/stats `compacted` too;
- a second pass back over the track on the new owner, which sinks less where the first
  compacted (so it reads the recovered memory), gives heights, memory and the units it
  compacted identical to a twin single daemon that ran the same passes and never failed;
- the memory never passes its material's maximum and Σh + Σmemory is what it was at the start,
  on both, across the failover too.

The drive and the comparison are tests/support/compaction_drive.py's (shared with
test_compaction_recovery); waits are by condition with generous deadlines. Skipped (77) when
nats-server is not installed.
"""
import asyncio
import os
import re
import sys
import time
import urllib.error

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import owner_of  # noqa: E402
from service_harness import Checks, Daemon  # noqa: E402
import compaction_drive as cd  # noqa: E402

check = Checks()
WORLD = "memory"
HALF = len(cd.FIRST) // 2
COMPACTED_RE = re.compile(r"cluster: world memory: \d+ tiles compacted")
RECOVERED_RE = re.compile(
    r"cluster: world memory recovered at tick \d+ from (\d+) tile snapshots and (\d+) log records")


def node_reader(n):
    """read(x, y, w, h, layer=None) of node n's world, asked again on a 503 (a sim thread
    too busy to serve the read in time on a loaded machine) for up to a minute."""
    def read(x, y, w, h, layer=None):
        end = time.monotonic() + 60
        while True:
            try:
                return n.heights(WORLD, x, y, w, h, layer=layer)
            except urllib.error.HTTPError as e:
                if e.code != 503 or time.monotonic() > end:
                    raise
                time.sleep(0.2)
    return read


def node_state(n):
    read = node_reader(n)
    _, hs = read(0, 0, cd.W, cd.H)
    _, mem = read(0, 0, cd.W, cd.H, layer="compaction")
    return cd.state(hs, mem, n.stats(WORLD))


def daemon_state(d):
    _, hs = d.heights(0, 0, cd.W, cd.H)
    _, mem = d.heights(0, 0, cd.W, cd.H, layer="compaction")
    return cd.state(hs, mem, d.stats())


def twin(scene):
    """The reference: a single daemon, the same passes, never failed."""
    d = Daemon(extra=["--scene", scene], name="terrad-twin", durability="every-tick")
    check.daemons.append(d)
    try:
        out = {"start": daemon_state(d)}
        asyncio.run(cd.drive(check, d.ws, d.heights, cd.FIRST[:HALF], 0.02))
        asyncio.run(cd.drive(check, d.ws, d.heights, cd.FIRST[HALF:], 0.02))
        out["middle"] = out["recovered"] = daemon_state(d)
        asyncio.run(cd.drive(check, d.ws, d.heights, cd.SECOND, 0.03))
        out["end"] = daemon_state(d)
        return out
    finally:
        d.stop()


def compactions(n):
    return sum(1 for line in list(n.lines) if COMPACTED_RE.search(line))


def failover(nodes):
    owner = owner_of(nodes, WORLD, 60)
    if not check(owner is not None, "a node takes the world"):
        return None
    ch.wait_for(lambda: all(n.up() for n in nodes), 60)
    other = next(n for n in nodes if n is not owner)
    out = {"start": node_state(owner)}
    read = node_reader(owner)
    asyncio.run(cd.drive(check, owner.ws, read, cd.FIRST[:HALF], 0.02, world=WORLD))
    before = compactions(owner)
    check(ch.wait_for(lambda: compactions(owner) > before, 120),
          "the owner compacts the log into tile snapshots after the first half")
    asyncio.run(cd.drive(check, owner.ws, read, cd.FIRST[HALF:], 0.02, world=WORLD))
    out["middle"] = node_state(owner)
    relayed = node_reader(other)(0, 0, cd.W, cd.H, layer="compaction")[1]
    check(relayed == out["middle"]["memory"],
          f"{other.name}, which does not tick the world, serves its memory as the owner does "
          "(/v1/heights?world=...&layer=compaction asked of the owner over NATS)")
    owner.kill9()
    new = owner_of([other], WORLD, 120)
    if not check(new is not None, f"{other.name} takes the world after the kill"):
        return None
    said = [m for m in map(RECOVERED_RE.search, list(new.lines)) if m]
    tiles, records = (int(said[-1].group(1)), int(said[-1].group(2))) if said else (0, 0)
    check(tiles > 0 and records > 0,
          f"the new owner recovered from tile snapshots ({tiles}) and log records after them "
          f"({records})")
    out["recovered"] = node_state(new)
    asyncio.run(cd.drive(check, new.ws, node_reader(new), cd.SECOND, 0.03, world=WORLD))
    out["end"] = node_state(new)
    return out


def main():
    ch.run_failover_test(check, WORLD, cd.scene_file(), twin, failover, cd.compare)


if __name__ == "__main__":
    main()
