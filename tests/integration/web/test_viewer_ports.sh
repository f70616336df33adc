#!/usr/bin/env bash
# ctest-timeout: 900 (generous: software GL on a loaded 2-core machine)
# The viewer learns its websocket from the daemon (issue 28, item 2): ports that are not
# neighbours, a relay in front, a public websocket URL, in real headless Chromium against the
# real daemon: tests/web/viewer_ports.mjs under node's test runner. Skips (77) without
# /usr/bin/chromium, node or node_modules/playwright-core (make web-deps).
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
cd "$src"
for need in /usr/bin/chromium node_modules/playwright-core; do
    if [ ! -e "$need" ]; then echo "SKIP: $need missing (apt-get install chromium; make web-deps)"; exit 77; fi
done
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
node --test --test-reporter=spec tests/web/viewer_ports.mjs
