#!/usr/bin/python3
# ctest-timeout: 300
"""Desync detection and repair with the C client (PROTOCOL.md "CHECKSUM", "resync" with
"tiles"; issue 32 item 4), against a real daemon on loopback (--backend cpu, no demo actors):
tests/support/c_client_probe.c in its desync mode subscribes to a 200 x 150 window (tiles
clipped at three of its edges), waits for two CHECKSUM frames that find nothing, changes one
height of its mirror's buffer behind the library's back, and waits until the library has
found that one tile differing, asked for it alone and holds it again, with two more
CHECKSUM frames finding nothing. Then the mirror it wrote equals GET /v1/heights of the window
and the daemon's counters moved: CHECKSUM frames sent, one tile asked for, one tile snapshot.

Without the checksums (a daemon that never sends CHECKSUM frames, or a client that does not
compare them) the probe times out waiting for the differing tile and the mirror keeps the
changed height, so both checks fail.
"""
import os
import struct
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "support"))
from service_harness import BIN, Checks, Daemon, built, metric_value  # noqa: E402

# the build always makes it (no optional dependency): missing, it is a failure, not a skip
PROBE = built(os.environ.get("TERRAD_C_CLIENT_PROBE", os.path.join(os.path.dirname(BIN), "c_client_probe")))
check = Checks()
WINDOW = (40, 30, 200, 150)  # x, y, w, h cells: 64-cell tiles clipped on three sides


def main():
    with tempfile.TemporaryDirectory(prefix="terrad-desync-c-") as tmp:
        out = os.path.join(tmp, "mirror.raw")
        with check.running(Daemon()) as d:
            r = subprocess.run([PROBE, "127.0.0.1", str(d.ws_port), "-", "-", "desync",
                                *map(str, WINDOW), out], capture_output=True, text=True, timeout=240)
            print(r.stdout + r.stderr, flush=True)
            check(r.returncode == 0 and "ok" in r.stdout.splitlines(),
                  "c_client_probe desync: the changed tile was found, asked for alone and repaired")
            n = WINDOW[2] * WINDOW[3]
            mirror = None
            if os.path.exists(out):
                with open(out, "rb") as f:
                    data = f.read()
                if len(data) == 4 * n:
                    mirror = list(struct.unpack(f"<{n}i", data))
            _, http = d.heights(*WINDOW)
            check(mirror is not None and mirror == http,
                  "the repaired mirror equals GET /v1/heights of the window")
            _, m = d.metrics()
            check((metric_value(m, "terrad_checksum_frames_total") or 0) >= 4,
                  "terrad_checksum_frames_total counted the CHECKSUM frames")
            check((metric_value(m, "terrad_checksum_bytes_total") or 0) > 0, "terrad_checksum_bytes_total")
            check(metric_value(m, "terrad_resync_tiles_requested_total") == 1,
                  "terrad_resync_tiles_requested_total: the one tile asked for")
            check(metric_value(m, "terrad_tile_resyncs_total") == 1,
                  "terrad_tile_resyncs_total: one tile snapshot queued")
    check.finish()


if __name__ == "__main__":
    main()
