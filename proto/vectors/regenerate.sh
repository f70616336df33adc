#!/bin/sh
# Rebuild proto/vectors/vectors.json with the C encoder. Run from anywhere.
set -eu
root=$(cd "$(dirname "$0")/../.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
${CC:-cc} -std=c11 -Wall -Wextra -Werror -D_GNU_SOURCE -I"$root/proto/c" \
    "$root/proto/vectors/gen_vectors.c" "$root"/proto/c/*.c \
    -o "$tmp/gen_vectors" -lzstd -lcjson -lm
"$tmp/gen_vectors" > "$tmp/vectors.json"
mv "$tmp/vectors.json" "$root/proto/vectors/vectors.json"
echo "wrote $root/proto/vectors/vectors.json"
