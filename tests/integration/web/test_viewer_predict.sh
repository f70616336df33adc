#!/usr/bin/env bash
# ctest-timeout: 900 (generous: software GL on a loaded 2-core machine)
# The viewer's prediction (issue 23) in real headless Chromium against the real daemon, through
# a TCP relay that can hold the server's bytes: tests/web/viewer_predict.mjs under node's test
# runner. Skips (77) without /usr/bin/chromium, node, node_modules/playwright-core (make web-deps)
# or the daemon's WebAssembly twin (build/terrad_twin.wasm: scripts/deps --build); without the
# twin it fails instead under make test (TERRAD_REQUIRE_WASM=1): tests/support/viewer_test.sh.
exec "$(dirname "$0")/../../support/viewer_test.sh" --twin tests/web/viewer_predict.mjs
