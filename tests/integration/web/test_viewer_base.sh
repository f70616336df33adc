#!/usr/bin/env bash
# ctest-timeout: 1500 (generous: software GL on a loaded 2-core machine)
# Base snapshots in the viewer (PROTOCOL.md "Base snapshots"), in real headless Chromium against
# the real daemon: tests/web/viewer_base.mjs under node's test runner. Skips (77) without
# /usr/bin/chromium, node, node_modules/playwright-core (make web-deps) or the daemon's
# WebAssembly twin the page rebuilds the base with (build/terrad_twin.wasm); without the twin it
# fails instead under make test (TERRAD_REQUIRE_WASM=1): tests/support/viewer_test.sh.
exec "$(dirname "$0")/../../support/viewer_test.sh" --twin tests/web/viewer_base.mjs
