/*
 * sim_plan.c: the plan step of the tick (docs/design.md, "One tick") —
 * colliders' footprints become the tick's windows.
 *
 * Each collider's footprint is the bounding box of its swept poses, from the
 * last pose to this one (collider_sweep_bounds: the sub-step poses the depth
 * stage presses with, so a rotating collider is covered too), plus a margin;
 * colliders entirely above the terrain under them are skipped. Footprints
 * that share a cell are merged until the windows are disjoint — simulating
 * overlapping areas separately is what corrupted the original's volume.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdlib.h>

static int clamp_to_int(double v)
{
    if (!(v > -1e9))
        return -1000000000;
    if (v > 1e9)
        return 1000000000;
    return (int)floor(v);
}

int32_t sim_units_clamped(double metres, int32_t units_per_m)
{
    double u = floor(metres * units_per_m);
    if (!(u > WORLD_HEIGHT_MIN - 1.0))
        return WORLD_HEIGHT_MIN - 1;
    if (u > WORLD_HEIGHT_MAX + 1.0)
        return WORLD_HEIGHT_MAX + 1;
    return (int32_t)u;
}

static world_rect collider_footprint(const world *w, const sim_params *p, const sim_collider *c,
                                     int margin)
{
    vec3d lo, hi;
    collider_bounds(c->geometry, c->pose, &lo, &hi);
    sim_collider_sweep_bounds(c, w->cell_size_m, &lo, &hi);
    int x0 = clamp_to_int(lo.x / w->cell_size_m) - margin;
    int y0 = clamp_to_int(lo.y / w->cell_size_m) - margin;
    int x1 = clamp_to_int(hi.x / w->cell_size_m) + margin;
    int y1 = clamp_to_int(hi.y / w->cell_size_m) + margin;
    world_rect r = {x0, y0, x1 - x0 + 1, y1 - y0 + 1};
    if (!world_clip_rect(w, &r))
        return (world_rect){0, 0, 0, 0};
    /* a load-driven collider's height is the engine's to find: never skipped;
     * any other is skipped when it flies above everything it could touch,
     * lowest point > highest cell + obstacle gap */
    if (!(c->load_n > 0.0) &&
        !world_rect_reaches(w, r,
                            (int64_t)sim_units_clamped(lo.z, w->units_per_m) - p->obstacle_gap))
        return (world_rect){0, 0, 0, 0};
    return r;
}

sim_collider sim_collider_for_tick(int id, const collider_geometry *geometry, collider_pose pose,
                                   collider_pose previous_pose, int has_previous, double load_n)
{
    sim_collider c = {.id = id,
                      .geometry = geometry,
                      .pose = pose,
                      .previous_pose = previous_pose,
                      .has_previous = has_previous,
                      .load_n = load_n};
    if (load_n > 0.0 && has_previous)
        c.pose.position.z = previous_pose.position.z;
    return c;
}

int sim_collider_sweep_steps(const sim_collider *c, double cell_size_m)
{
    if (!c->has_previous)
        return 1;
    return collider_sweep_steps(c->geometry, c->previous_pose, c->pose, cell_size_m);
}

collider_pose sim_collider_sweep_pose(const sim_collider *c, int k, int steps)
{
    if (!c->has_previous)
        return c->pose;
    return collider_sweep_pose(c->previous_pose, c->pose, k, steps);
}

void sim_collider_sweep_bounds(const sim_collider *c, double cell_size_m, vec3d *lo, vec3d *hi)
{
    if (!c->has_previous) {
        collider_bounds(c->geometry, c->pose, lo, hi);
        return;
    }
    collider_sweep_bounds(c->geometry, c->previous_pose, c->pose,
                          sim_collider_sweep_steps(c, cell_size_m), lo, hi);
}

static int compare_rects(const void *a, const void *b)
{
    const world_rect *r = a, *s = b;
    if (r->y != s->y)
        return (r->y > s->y) - (r->y < s->y);
    return (r->x > s->x) - (r->x < s->x);
}

int sim_plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                     int collider_count, int margin_cells, const world_rect *extra, int extra_count,
                     world_rect *footprints, world_rect **out, int *out_count)
{
    world_rect *rects = malloc(((size_t)collider_count + extra_count + 1) * sizeof *rects);
    if (!rects)
        return -1;
    int n = 0;
    /* deferred writes its trail up to trail_range cells around a point */
    if (p->model == SIM_MODEL_DEFERRED && p->trail_range_cells + 1 > margin_cells)
        margin_cells = p->trail_range_cells + 1;
    for (int i = 0; i < collider_count; i++) {
        footprints[i] = collider_footprint(w, p, &colliders[i], margin_cells);
        if (footprints[i].w > 0)
            rects[n++] = footprints[i];
    }
    for (int i = 0; i < extra_count; i++)
        rects[n++] = extra[i];
    for (int changed = 1; changed;) {
        changed = 0;
        for (int i = 0; i < n; i++) {
            for (int j = i + 1; j < n; j++) {
                if (world_rects_overlap(rects[i], rects[j])) {
                    rects[i] = world_rect_union(rects[i], rects[j]);
                    rects[j] = rects[--n];
                    changed = 1;
                    j = i; /* the grown rectangle may now meet earlier ones */
                }
            }
        }
    }
    /* Split windows wider than the distance arithmetic allows (a collider the
     * size of a 65536² world); each piece still keeps its volume exactly. */
    int pieces = 0;
    for (int i = 0; i < n; i++)
        pieces += ((rects[i].w + SIM_WINDOW_SIDE_MAX - 1) / SIM_WINDOW_SIDE_MAX) *
                  ((rects[i].h + SIM_WINDOW_SIDE_MAX - 1) / SIM_WINDOW_SIDE_MAX);
    world_rect *result = malloc(((size_t)pieces + 1) * sizeof *result);
    if (!result) {
        free(rects);
        return -1;
    }
    int k = 0;
    for (int i = 0; i < n; i++) {
        for (int y = 0; y < rects[i].h; y += SIM_WINDOW_SIDE_MAX) {
            for (int x = 0; x < rects[i].w; x += SIM_WINDOW_SIDE_MAX) {
                world_rect r = {rects[i].x + x, rects[i].y + y, rects[i].w - x, rects[i].h - y};
                if (r.w > SIM_WINDOW_SIDE_MAX)
                    r.w = SIM_WINDOW_SIDE_MAX;
                if (r.h > SIM_WINDOW_SIDE_MAX)
                    r.h = SIM_WINDOW_SIDE_MAX;
                result[k++] = r;
            }
        }
    }
    free(rects);
    qsort(result, (size_t)k, sizeof *result, compare_rects);
    *out = result;
    *out_count = k;
    return 0;
}
