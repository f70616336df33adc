/*
 * fuzz_footprints: libFuzzer target for the FOOTPRINTS decoder (the decals
 * model's events as a client of proto/c/terrad_proto.h reads them).
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * very same bytes; decoded events have finite positions, a yaw within
 * +-TERRAD_FOOTPRINT_YAW_MAX and a size and strength > 0; a small caller
 * capacity is refused, never overrun.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static terrad_footprint events[TERRAD_MAX_COUNT];
static uint8_t out[TERRAD_FOOTPRINTS_FIXED + TERRAD_MAX_COUNT * TERRAD_FOOTPRINT_SIZE];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint64_t tick = 0;
    size_t count = 0;
    terrad_footprint few[2];
    size_t few_count = 0;
    int rc_few = terrad_footprints_decode(data, size, &tick, few, 2, &few_count);
    if (rc_few == TERRAD_OK && few_count > 2)
        abort();

    int rc = terrad_footprints_decode(data, size, &tick, events, TERRAD_MAX_COUNT, &count);
    if (rc != TERRAD_OK)
        return 0;
    if (size != TERRAD_FOOTPRINTS_FIXED + count * TERRAD_FOOTPRINT_SIZE)
        abort();
    for (size_t i = 0; i < count; i++) {
        const terrad_footprint *f = &events[i];
        if (!isfinite(f->x) || !isfinite(f->y) || !(fabsf(f->yaw) <= TERRAD_FOOTPRINT_YAW_MAX) ||
            !(f->size_m > 0.0f) || !isfinite(f->size_m) || !(f->strength_m > 0.0f) ||
            !isfinite(f->strength_m))
            abort();
    }
    size_t len = 0;
    if (terrad_footprints_encode(out, sizeof out, &len, tick, events, count) != TERRAD_OK ||
        len != size || memcmp(out, data, size) != 0)
        abort();
    return 0;
}
