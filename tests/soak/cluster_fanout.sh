#!/bin/bash
# The full fan-out soak of cluster mode (tests/integration/cluster/test_cluster_fanout.py,
# docs/cluster.md "any node serves any world"): 3 NATS servers (3 replicas), 3 terrad
# nodes, 300 read-only viewers of one world spread over the nodes; at the end every
# viewer holds the owner's heights. `make test` runs the same test with 60 viewers on
# one NATS server.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
TERRAD_FANOUT_VIEWERS="${TERRAD_FANOUT_VIEWERS:-300}" TERRAD_FANOUT_NATS="${TERRAD_FANOUT_NATS:-3}" \
    TERRAD_FANOUT_NODES="${TERRAD_FANOUT_NODES:-3}" \
    exec /usr/bin/python3 "$here/../integration/cluster/test_cluster_fanout.py"
