#!/usr/bin/env bash
# The frame of a viewer test (tests/integration/web/test_viewer*.sh): the daemon binary from
# the build, then node's test runner on the test file named (tests/web/*.mjs) in the source tree.
# Skips (77) without /usr/bin/chromium, node or node_modules/playwright-core (make web-deps);
# with --twin also without the WebAssembly twin the page predicts with (build/terrad_twin.wasm;
# under make test, TERRAD_REQUIRE_WASM=1, that fails instead: tests/support/need_twin_wasm.py).
# Not a test itself: usage  viewer_test.sh [--twin] tests/web/FILE.mjs; sourced with no file
# (test_viewer.sh, which runs a directory with its own summary), the frame ends before node.
set -uo pipefail
twin=0
if [ "${1:-}" = --twin ]; then twin=1; shift; fi
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
cd "$src"
for need in /usr/bin/chromium node_modules/playwright-core; do
    if [ ! -e "$need" ]; then echo "SKIP: $need missing (apt-get install chromium; make web-deps)"; exit 77; fi
done
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
if [ "$twin" = 1 ]; then /usr/bin/python3 tests/support/need_twin_wasm.py || exit $?; fi
if [ $# -eq 0 ]; then return 0 2>/dev/null || exit 0; fi
exec node --test --test-reporter=spec "$1"
