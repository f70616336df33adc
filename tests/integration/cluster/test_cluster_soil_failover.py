#!/usr/bin/python3
# ctest-timeout: 360
"""test_cluster_soil_failover: a bekker world on a cluster (a real nats-server with JetStream,
two `terrad serve --cluster` nodes on loopback) keeps its per-cell soil state (plastic
sinkage, shear displacement, compacted volume) through a failover (docs/cluster.md,
docs/storage.md "Soil state"):

- the world's owner is driven by a real client: a slipping wheel along a rut, in two halves;
  between them the test waits until the owner has compacted the log into tile snapshots, so
  the takeover reads both kinds of JetStream record that carry soil state (a snapshot, then
  log records after it);
- the owner is killed with SIGKILL; the other node takes the world from JetStream (its log
  names the snapshots and records it recovered from); every height and Σ compacted
  (/v1/stats `soil_compacted`) are as before the kill;
- a second pass back over the rut on the new owner, which sinks less where the first pressed
  (so it reads the recovered plastic state), gives heights, Σ compacted and every FORCES
  entry bit-identical to a twin single daemon that ran the same passes and never failed.

The drive and the comparison are tests/support/soil_drive.py's (shared with
test_soil_recovery); waits are by condition with generous deadlines. Skipped (77) when
nats-server is not installed.
"""
import asyncio
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from service_harness import Checks  # noqa: E402
import soil_drive as sd  # noqa: E402

check = Checks()
WORLD = "soil"
HALF = len(sd.FIRST) // 2


def state(read, stats):
    """Heights, then Σ compacted (stats(): /v1/stats), of a world read by read(x, y, w, h)."""
    _, hs = read(0, 0, sd.W, sd.H)
    return hs, stats()["soil_compacted"]


def node_state(n):
    return state(ch.node_reader(n, WORLD), lambda: n.stats(WORLD))


def twin(d):
    """The reference: the twin daemon, the same passes, never failed."""
    asyncio.run(sd.drive(check, d.ws, sd.FIRST[:HALF], 0.02))
    asyncio.run(sd.drive(check, d.ws, sd.FIRST[HALF:], 0.02))
    middle = state(d.heights, d.stats)
    second = asyncio.run(sd.drive(check, d.ws, sd.SECOND, 0.03))
    return middle, middle, second, state(d.heights, d.stats)


def failover(nodes):
    owner, other = ch.owner_and_standby(check, nodes, WORLD, "the bekker world")
    if owner is None:
        return None
    ch.drive_across_compaction(
        check, owner, WORLD,
        lambda: asyncio.run(sd.drive(check, owner.ws, sd.FIRST[:HALF], 0.02, world=WORLD)),
        lambda: asyncio.run(sd.drive(check, owner.ws, sd.FIRST[HALF:], 0.02, world=WORLD)))
    middle = node_state(owner)
    new = ch.take_over(check, owner, other, WORLD)
    if new is None:
        return None
    recovered = node_state(new)
    second = asyncio.run(sd.drive(check, new.ws, sd.SECOND, 0.03, world=WORLD))
    return middle, recovered, second, node_state(new)


def main():
    ch.run_failover_test(check, WORLD, sd.scene_file(), twin, failover, sd.compare)


if __name__ == "__main__":
    main()
