#!/usr/bin/env bash
# The frame of a viewer test (tests/integration/web/test_viewer_*.sh): the daemon binary from
# the build, then node's test runner on the test file named (tests/web/*.mjs) in the source tree.
# Skips (77) without /usr/bin/chromium, node or node_modules/playwright-core (make web-deps).
# Not a test itself: usage  viewer_test.sh tests/web/FILE.mjs
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
cd "$src"
for need in /usr/bin/chromium node_modules/playwright-core; do
    if [ ! -e "$need" ]; then echo "SKIP: $need missing (apt-get install chromium; make web-deps)"; exit 77; fi
done
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
exec node --test --test-reporter=spec "$1"
