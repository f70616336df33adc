#!/usr/bin/env bash
# ctest-timeout: 900 (generous: software GL on a loaded 2-core machine)
# The viewer finds and repairs a desync by itself (PROTOCOL.md "CHECKSUM"), in real headless
# Chromium against the real daemon: tests/web/viewer_desync.mjs under node's test runner.
exec "$(dirname "$0")/../../support/viewer_test.sh" tests/web/viewer_desync.mjs
