#!/bin/bash
# The full failover soak of cluster mode (tests/integration/test_cluster_serve.py,
# docs/cluster.md): 3 NATS servers, 3 terrad nodes, 2 worlds; 12 SIGKILLs of the
# owner of a world, each followed by the takeover and recovery checks, then the
# SIGSTOP/SIGCONT fencing check. `make test` runs the same test with 3 kills
# (and test_cluster_failover kills an owner 10 times and a NATS server once).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
TERRAD_CLUSTER_KILLS="${TERRAD_CLUSTER_KILLS:-12}" TERRAD_CLUSTER_SEED="${TERRAD_CLUSTER_SEED:-$RANDOM}" \
    exec /usr/bin/python3 "$here/../integration/test_cluster_serve.py"
