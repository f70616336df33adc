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
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from service_harness import Checks  # noqa: E402
import compaction_drive as cd  # noqa: E402

check = Checks()
WORLD = "memory"
HALF = len(cd.FIRST) // 2


def state(read, stats):
    """Heights, memory and then stats() (/v1/stats) of a world read by
    read(x, y, w, h, layer=None)."""
    _, hs = read(0, 0, cd.W, cd.H)
    _, mem = read(0, 0, cd.W, cd.H, layer="compaction")
    return cd.state(hs, mem, stats())


def node_state(n):
    return state(ch.node_reader(n, WORLD), lambda: n.stats(WORLD))


def twin(d):
    """The reference: the twin daemon, the same passes, never failed."""
    out = {"start": state(d.heights, d.stats)}
    asyncio.run(cd.drive(check, d.ws, d.heights, cd.FIRST[:HALF], 0.02))
    asyncio.run(cd.drive(check, d.ws, d.heights, cd.FIRST[HALF:], 0.02))
    out["middle"] = out["recovered"] = state(d.heights, d.stats)
    asyncio.run(cd.drive(check, d.ws, d.heights, cd.SECOND, 0.03))
    out["end"] = state(d.heights, d.stats)
    return out


def failover(nodes):
    owner, other = ch.owner_and_standby(check, nodes, WORLD)
    if owner is None:
        return None
    out = {"start": node_state(owner)}
    read = ch.node_reader(owner, WORLD)
    ch.drive_across_compaction(
        check, owner, WORLD,
        lambda: asyncio.run(cd.drive(check, owner.ws, read, cd.FIRST[:HALF], 0.02, world=WORLD)),
        lambda: asyncio.run(cd.drive(check, owner.ws, read, cd.FIRST[HALF:], 0.02, world=WORLD)))
    out["middle"] = node_state(owner)
    relayed = ch.node_reader(other, WORLD)(0, 0, cd.W, cd.H, layer="compaction")[1]
    check(relayed == out["middle"]["memory"],
          f"{other.name}, which does not tick the world, serves its memory as the owner does "
          "(/v1/heights?world=...&layer=compaction asked of the owner over NATS)")
    new = ch.take_over(check, owner, other, WORLD)
    if new is None:
        return None
    out["recovered"] = node_state(new)
    asyncio.run(cd.drive(check, new.ws, ch.node_reader(new, WORLD), cd.SECOND, 0.03, world=WORLD))
    out["end"] = node_state(new)
    return out


def main():
    ch.run_failover_test(check, WORLD, cd.scene_file(), twin, failover, cd.compare)


if __name__ == "__main__":
    main()
