#!/bin/bash
# The full crash soak of the data directory (tests/integration/store/test_store_crash.py):
# 20 SIGKILLs of the daemon under load, each followed by the recovery checks.
# `make test` runs the same test with 5 kills.
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
TERRAD_CRASH_KILLS="${TERRAD_CRASH_KILLS:-20}" TERRAD_CRASH_SEED="${TERRAD_CRASH_SEED:-$RANDOM}" \
    exec /usr/bin/python3 "$here/../integration/store/test_store_crash.py"
