#!/usr/bin/env bash
# ctest-timeout: 600 (generous: apt-get --simulate alone took 90 s on the loaded 2-core machine)
# docker/Dockerfile without a Docker engine (docker/check-runtime): the Dockerfile lints clean
# (npm's dockerfile-utils, when make web-deps installed it), and every library the daemon
# loads - ldd's list and what libepoxy opens for the GL backend - comes from the runtime stage's
# packages, `scripts/deps --runtime` resolved by apt-get --simulate as if nothing were installed.
# Skips (77) without apt-get and dpkg (not a Debian machine).
set -uo pipefail
src="${TERRAD_SOURCE_DIR:-$(cd "$(dirname "$0")/../../.." && pwd)}"
bin="${TERRAD_BIN:-$src/build/terrad}"
command -v apt-get >/dev/null && command -v dpkg >/dev/null || { echo "SKIP: not Debian"; exit 77; }
if "$src/docker/check-runtime" "$bin"; then echo "1 passed, 0 failed"; else echo "0 passed, 1 failed"; exit 1; fi
