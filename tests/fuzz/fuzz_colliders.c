/*
 * fuzz_colliders: libFuzzer target for the COLLIDERS decoder (the viewer's
 * side of proto/c/terrad_proto.h: where every collider in view is).
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * very same bytes; decoded entries have a known owner and kind, finite
 * non-negative dimensions, finite positions and a near-unit quaternion; a
 * small caller capacity is refused, never overrun. A frame with the grousers
 * extension's flag (PROTOCOL.md "COLLIDERS") decodes to the same entries
 * plus each one's grousers: none all zero, else on a cylinder, at most 360,
 * height and thickness in (0, radius]; it re-encodes with them.
 */
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static terrad_collider_state states[TERRAD_MAX_COUNT];
static terrad_collider_grousers lugs[TERRAD_MAX_COUNT];
static uint8_t out[TERRAD_COLLIDERS_FIXED +
                   TERRAD_MAX_COUNT * (TERRAD_COLLIDER_STATE_SIZE + TERRAD_COLLIDER_GROUSERS_SIZE)];

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
    size_t nl = 0;
    if (terrad_colliders_grousers(data, size, lugs, TERRAD_MAX_COUNT, &nl) != TERRAD_OK)
        abort(); /* the extension's reader takes what the decoder takes */
    int flagged = (data[3] & TERRAD_COLLIDERS_FLAG_GROUSERS) != 0;
    if (nl != (flagged ? count : 0))
        abort();
    if (size != (flagged ? terrad_colliders_grousers_size(count) : terrad_colliders_size(count)))
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
        const terrad_collider_grousers *g = &lugs[i];
        if (flagged && g->count == 0 && (g->height_m != 0.0f || g->thickness_m != 0.0f))
            abort();
        if (flagged && g->count > 0 &&
            (g->count > TERRAD_GROUSERS_MAX || c->kind != TERRAD_KIND_CYLINDER ||
             !(g->height_m > 0.0f && g->height_m <= c->dims[0]) ||
             !(g->thickness_m > 0.0f && g->thickness_m <= c->dims[0])))
            abort();
    }
    size_t len = 0;
    rc = flagged
             ? terrad_colliders_encode_grousers(out, sizeof out, &len, tick, states, lugs, count)
             : terrad_colliders_encode(out, sizeof out, &len, tick, states, count);
    if (rc != TERRAD_OK || len != size || memcmp(out, data, size) != 0)
        abort();
    return 0;
}
