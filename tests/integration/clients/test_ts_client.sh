#!/usr/bin/env bash
# ctest-timeout: 600
# The TypeScript package clients/js (terrad-client): `npm pack` makes its tarball (prepack runs
# tsc: web/'s codec, twin loader and prediction compiled in with the client, .d.ts for all), a
# fresh directory installs it, a TypeScript application is type-checked against its declarations
# (clients/js/test/consumer.ts), the Node example (clients/js/examples/drive_wheel.ts) is compiled
# against it, and clients/js/test/*.test.mjs run against the real daemon with the installed
# package under node's test runner (example.test.mjs runs the example). Skips (77) without node,
# node_modules/typescript (make web-deps) or the WebAssembly twin predict() runs (build/
# terrad_twin.wasm; under make test, TERRAD_REQUIRE_WASM=1, that fails instead).
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../../.." && pwd)}"
export TERRAD_BIN="${TERRAD_BIN:-$src/build/terrad}"
command -v node >/dev/null || { echo "SKIP: node missing"; exit 77; }
[ -e "$src/node_modules/typescript" ] || { echo "SKIP: node_modules/typescript missing (make web-deps)"; exit 77; }
/usr/bin/python3 "$src/tests/support/need_twin_wasm.py" || exit $?
tmp=$(mktemp -d); trap 'rm -rf "$tmp"; rm -rf "$src/clients/js/dist"' EXIT
set -e
cd "$src/clients/js"
tarball=$(npm pack --silent --pack-destination "$tmp" | tail -1)
echo "packed: $tarball"
tar -tzf "$tmp/$tarball" | sort | sed 's/^/  /'
mkdir "$tmp/app" && cd "$tmp/app"
printf '{"name":"app","private":true,"type":"module"}\n' > package.json
npm install --silent --offline --no-audit --no-fund "$tmp/$tarball"
cp "$src/clients/js/test/consumer.ts" .
printf '{"compilerOptions":{"target":"ES2022","module":"NodeNext","moduleResolution":"NodeNext","lib":["ES2022","DOM"],"strict":true,"noEmit":true,"skipLibCheck":false},"files":["consumer.ts"]}\n' > tsconfig.json
node "$src/node_modules/typescript/bin/tsc" -p tsconfig.json
echo "consumer.ts type-checks against the installed declarations"
# The package's Node example, as the tarball ships it, compiled against the installed package
# as its header says; clients/js/test/example.test.mjs runs the result against a daemon.
cp node_modules/terrad-client/examples/drive_wheel.ts .
printf '{"compilerOptions":{"target":"ES2022","module":"NodeNext","moduleResolution":"NodeNext","lib":["ES2022","DOM"],"strict":true,"outDir":"."},"files":["drive_wheel.ts"]}\n' > tsconfig.example.json
node "$src/node_modules/typescript/bin/tsc" -p tsconfig.example.json
echo "examples/drive_wheel.ts compiles against the installed package"
cd "$src"
TERRAD_CLIENT_DIR="$tmp/app" node --import "$src/tests/support/node_websocket.mjs" --no-warnings --test --test-reporter=spec clients/js/test/
