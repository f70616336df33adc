/*
 * fuzz_ack_ping: libFuzzer target for the small fixed-size decoders of
 * proto/c/terrad_proto.h — the frame header, ACK and PING/PONG.
 *
 * Oracles besides the sanitizers: a frame that decodes has exactly its fixed
 * size and re-encodes to the very same bytes; the header decoder never
 * accepts a wrong magic or version.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    terrad_header h;
    if (terrad_header_decode(data, size, &h) == TERRAD_OK &&
        (size < TERRAD_HEADER_SIZE || data[0] != TERRAD_PROTO_MAGIC ||
         data[1] != TERRAD_PROTO_VERSION))
        abort();

    uint8_t out[64];
    size_t len = 0;
    uint64_t tick = 0;
    uint32_t seq = 0;
    if (terrad_ack_decode(data, size, &tick, &seq) == TERRAD_OK) {
        if (size != TERRAD_ACK_SIZE ||
            terrad_ack_encode(out, sizeof out, &len, tick, seq) != TERRAD_OK || len != size ||
            memcmp(out, data, size) != 0)
            abort();
    }
    uint8_t type = 0;
    uint64_t nonce = 0;
    if (terrad_ping_decode(data, size, &type, &nonce) == TERRAD_OK) {
        if (size != TERRAD_PING_SIZE || (type != TERRAD_MSG_PING && type != TERRAD_MSG_PONG) ||
            terrad_ping_encode(out, sizeof out, &len, type, nonce) != TERRAD_OK || len != size ||
            memcmp(out, data, size) != 0)
            abort();
    }
    return 0;
}
