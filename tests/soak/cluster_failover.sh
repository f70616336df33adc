#!/bin/bash
# The full failover soak of cluster mode (docs/cluster.md), two parts:
#  1. tests/integration/cluster/test_cluster_worlds_failover.py: 3 NATS servers, 3 terrad nodes
#     that tick up to 3 worlds each, 6 worlds; 12 SIGKILLs of the owner of a random world
#     at a random moment while a client drives in it (each kill moves all the worlds of
#     that node), one SIGKILL of a NATS server in the middle; after each, every moved
#     world ticks on another node within 5 s (issue 11), Σh is unchanged and, after a
#     settled kill, GET /v1/heights equals the client's mirror of its last ACK;
#  2. tests/integration/cluster/test_cluster_serve.py: 2 worlds, 12 kills of one world's owner,
#     then the SIGSTOP/SIGCONT fencing check.
# Both parts run whatever the first one says; the soak fails when either does.
# `make test` runs both with 2-3 kills and no figure of speed (and test_cluster_failover
# kills an owner 10 times and a NATS server once at the store level).
set -uo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
seed="${TERRAD_CLUSTER_SEED:-$RANDOM}"
echo "cluster_failover: seed $seed"
export TERRAD_CLUSTER_KILLS="${TERRAD_CLUSTER_KILLS:-12}" TERRAD_CLUSTER_SEED="$seed"
status=0
TERRAD_TAKEOVER_S="${TERRAD_TAKEOVER_S:-5}" \
    /usr/bin/python3 "$here/../integration/cluster/test_cluster_worlds_failover.py" || status=1
/usr/bin/python3 "$here/../integration/cluster/test_cluster_serve.py" || status=1
exit $status
