/*
 * model_subtract.c: depth-buffer subtraction (Aquilio; Batman: Arkham
 * Origins, thesis ch. 3.3; Wasmut ch. 2.2.1 / 4.2.1). Each column is cut down
 * to the lowest collider point above it: height = min(height, bottom), never
 * below the world's floor. Nothing is displaced, so the volume a collider
 * cuts away is lost — the model's documented promise is only "Σh never
 * grows, except by refill, and refill never passes the base terrain".
 *
 * Refill (snow falling back, as in Arkham Origins and the blog's
 * accumulation): a cell below the base terrain rises by refill_units this
 * tick (the engine turns metres per second into whole units per tick and
 * carries the fraction), capped at its base height, before the cut — so a
 * collider resting on a cell keeps it down. The engine keeps windows with
 * cells still below base in its tick until they are full again.
 *
 * One pass, no scratch: the engine's depth is the only input.
 */
#include "sim/sim.h"

sim_window_status sim_subtract_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    (void)scratch;
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    const int32_t *bottom = job->bottom_override;
    const int32_t *base = job->base_heights;
    int32_t refill = job->refill_units > 0 ? job->refill_units : 0;
    for (int64_t i = 0; i < n; i++) {
        int32_t h = job->heights[i];
        if (base && refill > 0 && h < base[i]) {
            /* int64: h + refill cannot wrap; the cap is the base itself */
            int64_t up = (int64_t)h + refill;
            h = up > base[i] ? base[i] : (int32_t)up;
        }
        if (bottom[i] < h) {
            /* cut to the collider, but a column above the floor stays above it */
            int32_t cut = bottom[i] > p->floor ? bottom[i] : p->floor;
            if (cut < h)
                h = cut;
        }
        job->heights[i] = h;
    }
    return SIM_WINDOW_OK;
}
