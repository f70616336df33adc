"""test_chaos: the short, fixed-seed run of `make chaos` (tests/chaos/chaos.py,
docs/cluster.md "Chaos"): 3 nats-servers, 3 terrad nodes, 3 worlds driven by
clients that record every ACK; 2 schedules of seed 22 — a node paused, the
stream leader's NATS server killed, another NATS server paused; a node killed,
a NATS server paused — each followed by a settled kill, and at the end every
node killed at once. Checks that every acknowledged tick is in the log each
recovery read (recovered tick >= every ACK received before it), the mirror
equals the new owner's heights after a settled kill, Σh is exact and each
world's log is one history (fencing); and that the run checked something:
ACKs checked in each schedule, takeovers seen, at least one settled check
(--min-settled 1), no client session dead of an exception. Behaviour only, no
speed.

Seed 22 holds every kind of fault, NATS ones included. For a while this test
ran seed 65 (node faults only) because a NATS server paused while the nodes'
leases ran out could provoke nats-server 2.9's fencing race (two appends
expecting the same last sequence both accepted; docs/cluster.md "The fencing
race of nats-server 2.9"); a take is now confirmed before the new owner
serves, so NATS faults are back. The race itself is made on purpose by
test_cluster_take_race (its followers stopped until both publishes reached the
leader; nats-server still serializes them now and then, so each order is tried
until they cross, up to 10 times). Without the fix of issue 28's lost tick (an
ACK of a tick whose commit failed) seed 22 failed: "c0: node t1 recovered it
at tick 1438, but the client had ACKs of ticks up to 1439 before (1
acknowledged ticks lost)". Every wait of the run is cut to --budget-s 360,
well under the ctest timeout (600), so a slow run fails with its message and
seed, not by ctest's kill. Skipped (77) when nats-server is not installed.
"""
# ctest-timeout: 600
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "chaos"))
import chaos  # noqa: E402

if __name__ == "__main__":
    sys.exit(chaos.main(["--seed", "22", "--schedules", "2", "--fault-s", "8",
                         "--budget-s", "360", "--min-settled", "1"]))
