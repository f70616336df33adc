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
 * No scratch and no depth buffer: the depth stage's "min into the array" is
 * the model, so each collider's depth is cast straight into the heights
 * (collider_depth_cpu lowers a cell to the collider's lowest point), then
 * the cut is clamped at the floor. Heights are never below the floor (the
 * world refuses such a base and no model puts one there), so the clamp only
 * undoes what the cut took under it. With a depth given (bottom_override:
 * the unit tests) the same rule runs from that array.
 */
#include "sim/sim_internal.h"

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
        if (bottom && bottom[i] < h) {
            /* cut to the collider, but a column above the floor stays above it */
            int32_t cut = bottom[i] > p->floor ? bottom[i] : p->floor;
            if (cut < h)
                h = cut;
        }
        job->heights[i] = h;
    }
    if (bottom)
        return SIM_WINDOW_OK;
    sim_window_cast(job, 1, 1, job->heights); /* the swept collider, as sim_window_depth */
    for (int64_t i = 0; i < n; i++)
        if (job->heights[i] < p->floor)
            job->heights[i] = p->floor;
    return SIM_WINDOW_OK;
}
