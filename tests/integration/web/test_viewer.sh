#!/usr/bin/env bash
# ctest-timeout: 1500 (generous: 7-12 min on a loaded 2-core machine; a deadline, not a speed)
# The browser viewer (web/) in real headless Chromium, driven by npm's playwright-core,
# against the real daemon: tests/web/*.test.mjs under node's test runner.
# Skips (77) without /usr/bin/chromium, node or node_modules/playwright-core (make web-deps), or
# without the WebAssembly twin the page predicts with (build/terrad_twin.wasm; under make test,
# TERRAD_REQUIRE_WASM=1, that fails instead): tests/support/viewer_test.sh's frame.
source "$(dirname "$0")/../../support/viewer_test.sh" --twin
out=$(mktemp); trap 'rm -f "$out"' EXIT
node --test --test-reporter=tap tests/web/ 2>&1 | tee "$out"
rc=${PIPESTATUS[0]}
pass=$(sed -n 's/^# pass \([0-9]*\)$/\1/p' "$out" | tail -1)
fail=$(sed -n 's/^# fail \([0-9]*\)$/\1/p' "$out" | tail -1)
pass=${pass:-0}; fail=${fail:-0}
if [ "$rc" -ne 0 ] && [ "$fail" -eq 0 ]; then fail=1; fi
echo "$pass passed, $fail failed"
[ "$rc" -eq 0 ] && [ "$fail" -eq 0 ]
