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
import re
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
import cluster_harness as ch  # noqa: E402
from cluster_harness import owner_of  # noqa: E402
from service_harness import Checks, Daemon  # noqa: E402
import soil_drive as sd  # noqa: E402

check = Checks()
WORLD = "soil"
HALF = len(sd.FIRST) // 2
COMPACTED_RE = re.compile(r"cluster: world soil: \d+ tiles compacted")
RECOVERED_RE = re.compile(
    r"cluster: world soil recovered at tick \d+ from (\d+) tile snapshots and (\d+) log records")


def node_state(n):
    _, hs = n.heights(WORLD, 0, 0, sd.W, sd.H)
    return hs, n.stats(WORLD)["soil_compacted"]


def daemon_state(d):
    _, hs = d.heights(0, 0, sd.W, sd.H)
    return hs, d.stats()["soil_compacted"]


def twin(scene):
    """The reference: a single daemon, the same passes, never failed."""
    d = Daemon(extra=["--scene", scene], name="terrad-twin", durability="every-tick")
    check.daemons.append(d)
    try:
        asyncio.run(sd.drive(check, d.ws, sd.FIRST[:HALF], 0.02))
        asyncio.run(sd.drive(check, d.ws, sd.FIRST[HALF:], 0.02))
        middle = daemon_state(d)
        second = asyncio.run(sd.drive(check, d.ws, sd.SECOND, 0.03))
        return middle, middle, second, daemon_state(d)
    finally:
        d.stop()


def compactions(n):
    return sum(1 for line in list(n.lines) if COMPACTED_RE.search(line))


def failover(nodes):
    owner = owner_of(nodes, WORLD, 60)
    if not check(owner is not None, "a node takes the bekker world"):
        return None
    ch.wait_for(lambda: all(n.up() for n in nodes), 60)
    other = next(n for n in nodes if n is not owner)
    asyncio.run(sd.drive(check, owner.ws, sd.FIRST[:HALF], 0.02, world=WORLD))
    before = compactions(owner)
    check(ch.wait_for(lambda: compactions(owner) > before, 120),
          "the owner compacts the log into tile snapshots after the first half")
    asyncio.run(sd.drive(check, owner.ws, sd.FIRST[HALF:], 0.02, world=WORLD))
    middle = node_state(owner)
    owner.kill9()
    new = owner_of([other], WORLD, 120)
    if not check(new is not None, f"{other.name} takes the world after the kill"):
        return None
    said = [m for m in map(RECOVERED_RE.search, list(new.lines)) if m]
    tiles, records = (int(said[-1].group(1)), int(said[-1].group(2))) if said else (0, 0)
    check(tiles > 0 and records > 0,
          f"the new owner recovered from tile snapshots ({tiles}) and log records after them "
          f"({records})")
    recovered = node_state(new)
    second = asyncio.run(sd.drive(check, new.ws, sd.SECOND, 0.03, world=WORLD))
    return middle, recovered, second, node_state(new)


def main():
    ch.run_failover_test(check, WORLD, sd.scene_file(), twin, failover, sd.compare)


if __name__ == "__main__":
    main()
