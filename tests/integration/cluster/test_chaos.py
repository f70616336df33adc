"""test_chaos: the short, fixed-seed run of `make chaos` (tests/chaos/chaos.py,
docs/cluster.md "Chaos"): 3 nats-servers, 3 terrad nodes, 3 worlds driven by
clients that record every ACK; 2 schedules of seed 65 — a node killed, then
another paused; two nodes killed one after the other — each followed by a
settled kill, and at the end every node killed at once. Checks that every
acknowledged tick is in the log each recovery read (recovered tick >= every
ACK received before it), the mirror equals the new owner's heights after a
settled kill, Σh is exact and each world's log is one history (fencing); and
that the run checked something: ACKs checked in each schedule, takeovers seen,
at least one settled check (--min-settled 1), no client session dead of an
exception. Behaviour only, no speed.

Why seed 65 and not a random or NATS-faulting one: its schedules hold node
faults only. A NATS server paused (or its stream leader killed) while the
nodes' leases run out can provoke nats-server 2.9's known, open fencing race
(two appends expecting the same last sequence both accepted, nats-server
#4320 / fixed in 2.11.0; docs/cluster.md "Chaos", schedule 164), which loses an
acknowledged tick about once in 200 schedules; the seed used before (22)
paused a NATS server in both schedules. NATS faults stay covered by the full
`make chaos` (unchanged). Without the fix of issue 28's lost tick (an ACK of a
tick whose commit failed) seed 22 failed: "c0: node t1 recovered it at tick
1438, but the client had ACKs of ticks up to 1439 before (1 acknowledged ticks
lost)"; node kills are the faults that provoked it. Every wait of the run is
cut to --budget-s 360, well under the ctest timeout (600), so a slow run fails
with its message and seed, not by ctest's kill. Skipped (77) when nats-server
is not installed.
"""
# ctest-timeout: 600
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "chaos"))
import chaos  # noqa: E402

if __name__ == "__main__":
    sys.exit(chaos.main(["--seed", "65", "--schedules", "2", "--fault-s", "8",
                         "--budget-s", "360", "--min-settled", "1"]))
