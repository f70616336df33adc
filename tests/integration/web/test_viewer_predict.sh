#!/usr/bin/env bash
# ctest-timeout: 900 (generous: software GL on a loaded 2-core machine)
# The viewer's prediction (issue 23) in real headless Chromium against the real daemon, through
# a TCP relay that can hold the server's bytes: tests/web/viewer_predict.mjs under node's test
# runner. Skips (77) without /usr/bin/chromium, node, node_modules/playwright-core (make web-deps)
# or the daemon's WebAssembly twin (build/terrad_twin.wasm: scripts/deps --build); without the
# twin it fails instead under make test (TERRAD_REQUIRE_WASM=1: tests/support/need_twin_wasm.py).
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
cd "$src"
for need in /usr/bin/chromium node_modules/playwright-core; do
    if [ ! -e "$need" ]; then echo "SKIP: $need missing (apt-get install chromium; make web-deps)"; exit 77; fi
done
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
/usr/bin/python3 tests/support/need_twin_wasm.py || exit $?
node --test --test-reporter=spec tests/web/viewer_predict.mjs
