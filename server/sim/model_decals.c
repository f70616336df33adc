/*
 * model_decals.c: no deformation at all. Each tick, every collider that
 * touches the ground gives one footprint event — where (the centre of the
 * cells it presses into), its heading, its size (the side of a square with
 * the pressed area) and its strength (the deepest penetration) — for clients
 * that only want cheap visuals, as Wasmut's billboards (ch. 4.2.3). The
 * heights never change, so Σh is exact trivially; the events are the
 * engine's report (sim_tick_report.footprints).
 *
 * Per collider, its own depth is cast over the window (the shared depth
 * would mix colliders), so scratch is one int32 per cell.
 */
#include "sim/sim_internal.h"

#include <math.h>

int sim_decals_window(const sim_params *p, const sim_window_job *job, int32_t *scratch,
                      sim_footprint *out, int out_capacity)
{
    int w = job->rect.w, h = job->rect.h;
    int count = 0;
    for (int c = 0; c < job->collider_count && count < out_capacity; c++) {
        const sim_collider *col = &job->colliders[c];
        sim_window_job one = *job; /* this collider's own depth */
        one.colliders = col;
        one.collider_count = 1;
        sim_window_depth(&one, scratch);
        int64_t touched = 0, deepest = 0;
        double sx = 0.0, sy = 0.0;
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++) {
                int64_t i = (int64_t)y * w + x;
                int64_t pen = (int64_t)job->heights[i] - scratch[i];
                if (scratch[i] == COLLIDER_BOTTOM_NONE || pen <= 0)
                    continue;
                touched++;
                sx += x + 0.5;
                sy += y + 0.5;
                if (pen > deepest)
                    deepest = pen;
            }
        }
        if (touched == 0 || deepest < p->decal_min_strength)
            continue;
        quatd q = col->pose.orientation;
        sim_footprint *f = &out[count++];
        f->collider_id = col->id;
        f->x_m = (job->rect.x + sx / (double)touched) * job->cell_size_m;
        f->y_m = (job->rect.y + sy / (double)touched) * job->cell_size_m;
        f->yaw_rad = atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z));
        f->size_m = sqrt((double)touched) * job->cell_size_m;
        f->strength_m = (double)deepest / job->units_per_m;
    }
    return count;
}
