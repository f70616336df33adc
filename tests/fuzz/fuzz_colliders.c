/*
 * fuzz_colliders: libFuzzer target for the COLLIDERS decoder (the viewer's
 * side of proto/c/terrad_proto.h: where every collider in view is).
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * very same bytes; decoded entries have a known owner and kind, finite
 * non-negative dimensions, finite positions and a near-unit quaternion; a
 * small caller capacity is refused, never overrun.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static terrad_collider_state states[TERRAD_MAX_COUNT];
static uint8_t out[TERRAD_COLLIDERS_FIXED + TERRAD_MAX_COUNT * TERRAD_COLLIDER_STATE_SIZE];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    uint64_t tick = 0;
    size_t count = 0;
    terrad_collider_state few[2];
    size_t few_count = 0;
    int rc_few = terrad_colliders_decode(data, size, &tick, few, 2, &few_count);
    if (rc_few == TERRAD_OK && few_count > 2)
        abort();

    int rc = terrad_colliders_decode(data, size, &tick, states, TERRAD_MAX_COUNT, &count);
    if (rc != TERRAD_OK)
        return 0;
    if (size != TERRAD_COLLIDERS_FIXED + count * TERRAD_COLLIDER_STATE_SIZE)
        abort();
    for (size_t i = 0; i < count; i++) {
        const terrad_collider_state *c = &states[i];
        if (c->owner > TERRAD_OWNER_DEMO || c->kind > TERRAD_KIND_LAST)
            abort();
        double n = 0;
        for (int k = 0; k < 3; k++)
            if (!(c->dims[k] >= 0) || !isfinite(c->dims[k]) || !isfinite(c->p[k]))
                abort();
        for (int k = 0; k < 4; k++)
            n += (double)c->q[k] * c->q[k];
        if (!(n >= 0.81 && n <= 1.21))
            abort();
    }
    size_t len = 0;
    if (terrad_colliders_encode(out, sizeof out, &len, tick, states, count) != TERRAD_OK ||
        len != size || memcmp(out, data, size) != 0)
        abort();
    return 0;
}
