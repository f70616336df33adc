#!/usr/bin/python3
"""service_harness.need_twin_wasm for the shell tests (test_viewer.sh, test_viewer_predict.sh,
test_ts_client.sh): exits 0 when the WebAssembly twin is built; otherwise 1 under make test
(TERRAD_REQUIRE_WASM=1) or 77 (skipped), saying why. Not a test itself."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from service_harness import need_twin_wasm  # noqa: E402

print(need_twin_wasm())
