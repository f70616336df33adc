#!/usr/bin/env bash
# ctest-timeout: 180
# docs/openapi.yaml: validated with npm's @apidevtools/swagger-parser, and every endpoint's answers
# from the real daemon checked against it with ajv (tests/api/openapi.test.mjs, node's test runner).
# Skips (77) without node or node_modules (make web-deps).
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
cd "$src"
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
for need in node_modules/@apidevtools/swagger-parser node_modules/ajv; do
    [ -e "$need" ] || { echo "SKIP: $need missing (make web-deps)"; exit 77; }
done
out=$(mktemp); trap 'rm -f "$out"' EXIT
node --test --test-reporter=tap tests/api/ 2>&1 | tee "$out"
rc=${PIPESTATUS[0]}
pass=$(sed -n 's/^# pass \([0-9]*\)$/\1/p' "$out" | tail -1)
fail=$(sed -n 's/^# fail \([0-9]*\)$/\1/p' "$out" | tail -1)
pass=${pass:-0}; fail=${fail:-0}
if [ "$rc" -ne 0 ] && [ "$fail" -eq 0 ]; then fail=1; fi
echo "$pass passed, $fail failed"
[ "$rc" -eq 0 ] && [ "$fail" -eq 0 ]
