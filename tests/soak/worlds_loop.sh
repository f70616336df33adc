#!/bin/bash
# The world lifecycle API's long loop (tests/integration/service/test_worlds_api.py):
# 300 creates and deletes of one world name with clients connected, then the
# descriptor and thread counts back to their level. `make test` runs 50.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
TERRAD_WORLDS_ITERATIONS="${TERRAD_WORLDS_ITERATIONS:-300}" \
    exec /usr/bin/python3 "$here/../integration/service/test_worlds_api.py"
