#!/usr/bin/env bash
# ctest-timeout: 900 (generous: software GL on a loaded 2-core machine)
# The viewer learns its websocket from the daemon (issue 28, item 2): ports that are not
# neighbours, a relay in front, a public websocket URL, in real headless Chromium against the
# real daemon: tests/web/viewer_ports.mjs under node's test runner (tests/support/viewer_test.sh:
# skips without chromium, node or playwright-core).
exec "$(dirname "$0")/../../support/viewer_test.sh" tests/web/viewer_ports.mjs
