/*
 * fuzz_contact: libFuzzer target for the CONTACT decoder (client side of
 * proto/c/terrad_proto.h).
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * very same bytes; decoded entries have volume >= 0, area >= 0 and finite
 * floats; the count never exceeds what the frame can hold.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static terrad_contact contacts[TERRAD_MAX_COUNT];
static uint8_t out[TERRAD_CONTACT_FIXED + TERRAD_MAX_COUNT * TERRAD_CONTACT_SIZE];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint64_t tick = 0;
    size_t count = 0;
    /* a small caller capacity must be refused, never overrun */
    terrad_contact few[2];
    size_t few_count = 0;
    int rc_few = terrad_contact_decode(data, size, &tick, few, 2, &few_count);
    if (rc_few == TERRAD_OK && few_count > 2)
        abort();

    int rc = terrad_contact_decode(data, size, &tick, contacts, TERRAD_MAX_COUNT, &count);
    if (rc != TERRAD_OK)
        return 0;
    if (size != TERRAD_CONTACT_FIXED + count * TERRAD_CONTACT_SIZE)
        abort();
    for (size_t i = 0; i < count; i++) {
        const terrad_contact *c = &contacts[i];
        if (c->volume < 0 || !(c->area_m2 >= 0) || !isfinite(c->area_m2) ||
            !isfinite(c->support_height_m))
            abort();
        for (int k = 0; k < 3; k++)
            if (!isfinite(c->deepest[k]) || !isfinite(c->normal[k]))
                abort();
    }
    size_t len = 0;
    if (terrad_contact_encode(out, sizeof out, &len, tick, contacts, count) != TERRAD_OK ||
        len != size || memcmp(out, data, size) != 0)
        abort();
    return 0;
}
