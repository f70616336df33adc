/*
 * fuzz_pose_batch: libFuzzer target for the decoders of the frames a server
 * reads from clients (proto/c/terrad_proto.h): the header, POSE_BATCH (with
 * the server's limit of 64 poses and with the wire's 65535), and the small
 * fixed frames (ACK, PING, PONG).
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * very same bytes; a batch refused with too_large under the small limit
 * decodes under the large one; every decoded pose is finite with |q|^2 in
 * [0.81, 1.21].
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static terrad_pose poses[TERRAD_MAX_COUNT];
static uint8_t out[TERRAD_POSE_BATCH_FIXED + TERRAD_MAX_COUNT * TERRAD_POSE_SIZE];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    terrad_header h;
    int hrc = terrad_header_decode(data, size, &h);

    uint32_t seq = 0;
    size_t count = 0;
    int small = terrad_pose_batch_decode(data, size, &seq, poses, 64, &count);
    int rc = terrad_pose_batch_decode(data, size, &seq, poses, TERRAD_MAX_COUNT, &count);
    if (small == TERRAD_E_TOO_LARGE && rc != TERRAD_OK)
        abort(); /* only the count limit differs */
    if (rc == TERRAD_OK) {
        if (hrc != TERRAD_OK || h.type != TERRAD_MSG_POSE_BATCH)
            abort();
        for (size_t i = 0; i < count; i++) {
            const terrad_pose *p = &poses[i];
            double n2 = (double)p->qw * p->qw + (double)p->qx * p->qx + (double)p->qy * p->qy +
                        (double)p->qz * p->qz;
            if (!isfinite(p->x) || !isfinite(p->y) || !isfinite(p->z) || !(n2 >= 0.81) ||
                !(n2 <= 1.21))
                abort();
        }
        size_t len = 0;
        if (terrad_pose_batch_encode(out, sizeof out, &len, seq, poses, count) != TERRAD_OK ||
            len != size || memcmp(out, data, size) != 0)
            abort();
    }

    uint64_t tick = 0, nonce = 0;
    uint8_t type = 0;
    size_t len = 0;
    if (terrad_ack_decode(data, size, &tick, &seq) == TERRAD_OK) {
        if (terrad_ack_encode(out, sizeof out, &len, tick, seq) != TERRAD_OK || len != size ||
            memcmp(out, data, size) != 0)
            abort();
    }
    if (terrad_ping_decode(data, size, &type, &nonce) == TERRAD_OK) {
        if (terrad_ping_encode(out, sizeof out, &len, type, nonce) != TERRAD_OK || len != size ||
            memcmp(out, data, size) != 0)
            abort();
    }
    return 0;
}
