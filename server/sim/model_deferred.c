/*
 * model_deferred.c: deferred deformation, Rise of the Tomb Raider's trail as
 * Wasmut implements it (ch. 2.2.2 and 4.2.2). It is point-based: a collider
 * is reduced to contact points — its lowest point ("foot") under the pose,
 * and, for a collider that moved, points every cell along the way from its
 * previous pose, so a fast collider leaves a continuous trail instead of
 * dots. Each point writes the quadratic profile
 *
 *     deformation = foot + d^2 * scale            (d: distance in cells)
 *
 * into an integer image over a square of trail_range cells by a minimum on
 * the pair (deformation, foot) — Wasmut's imageAtomicMin on a packed value.
 * A minimum is order-independent, so the image (and the heights) do not
 * depend on the order of colliders or points. Then each cell takes it:
 * where the deformation is below the snow, the snow drops to it; around the
 * depression a rounded rim rises, a quadratic bump of height
 * edge_height * depth over a ring of edge_width * radius (Wasmut's listing 7,
 * rewritten so the bump is zero at both ends of the ring).
 *
 * The rim is measured from the base terrain (job->base_heights), not from
 * the current heights, so standing still does not pile rims on rims: both
 * the cut (min where the profile is under the base) and the rim (max against
 * base + bump where it is above) are idempotent. A rim rises only on snow
 * that is not already cut below the base, so the trail an earlier tick left
 * stays a trench (issue 12, item 2).
 * Volume is not preserved — material is cut away and rims appear from
 * nothing; docs/models.md gives the drift measured here.
 *
 * All integer: Q16 scales, distances as integer square roots in Q8 cells.
 */
#include "sim/sim_internal.h"

#include <math.h>

static uint64_t isqrt_u64(uint64_t v)
{
    uint64_t r = (uint64_t)sqrt((double)v);
    while (r * r > v)
        r--;
    while ((r + 1) * (r + 1) <= v)
        r++;
    return r;
}

/* Distance in Q8 cells at which the profile has risen `rise` units. */
static int64_t profile_distance_q8(int64_t rise, int32_t scale_q16)
{
    if (rise <= 0)
        return 0;
    if (rise > ((int64_t)1 << 30))
        rise = (int64_t)1 << 30;
    return (int64_t)isqrt_u64(((uint64_t)rise << 32) / (uint64_t)scale_q16);
}

/* Lowest point of a collider under a pose, in units, clamped to the range. */
static int32_t foot_units(const sim_collider *c, collider_pose pose, int32_t units_per_m)
{
    vec3d lo, hi;
    collider_bounds(c->geometry, pose, &lo, &hi);
    double u = floor(lo.z * units_per_m);
    if (!(u > WORLD_HEIGHT_MIN))
        return WORLD_HEIGHT_MIN;
    if (u > WORLD_HEIGHT_MAX)
        return WORLD_HEIGHT_MAX;
    return (int32_t)u;
}

static void write_point(const sim_params *p, const sim_window_job *job, double px_m, double py_m,
                        int32_t foot, int32_t *deform, int32_t *foot_image)
{
    int w = job->rect.w, h = job->rect.h;
    double cx = floor(px_m / job->cell_size_m) - job->rect.x;
    double cy = floor(py_m / job->cell_size_m) - job->rect.y;
    int range = p->trail_range_cells;
    if (!(cx > -range - 1.0 && cx < w + range + 1.0 && cy > -range - 1.0 && cy < h + range + 1.0))
        return; /* nothing of its square lies in the window */
    int ix = (int)cx, iy = (int)cy;
    for (int dy = -range; dy <= range; dy++) {
        int y = iy + dy;
        if (y < 0 || y >= h)
            continue;
        for (int dx = -range; dx <= range; dx++) {
            int x = ix + dx;
            if (x < 0 || x >= w)
                continue;
            int64_t d2 = (int64_t)dx * dx + (int64_t)dy * dy;
            int64_t rise = (d2 * p->trail_scale_q16) >> 16;
            int64_t v = (int64_t)foot + rise;
            int32_t value = v > INT32_MAX ? INT32_MAX : (int32_t)v;
            int64_t i = (int64_t)y * w + x;
            /* the (value, foot) pair's minimum: order-independent */
            if (value < deform[i] || (value == deform[i] && foot < foot_image[i])) {
                deform[i] = value;
                foot_image[i] = foot;
            }
        }
    }
}

sim_window_status sim_deferred_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    int w = job->rect.w, h = job->rect.h;
    int64_t n = (int64_t)w * h;
    int32_t *deform = scratch, *foot_image = scratch + n;
    for (int64_t i = 0; i < n; i++)
        deform[i] = foot_image[i] = INT32_MAX;

    for (int c = 0; c < job->collider_count; c++) {
        const sim_collider *col = &job->colliders[c];
        int32_t foot = foot_units(col, col->pose, job->units_per_m);
        vec3d to = col->pose.position;
        if (!col->has_previous) {
            write_point(p, job, to.x, to.y, foot, deform, foot_image);
            continue;
        }
        /* points at most one cell apart from the previous pose to this one */
        vec3d from = col->previous_pose.position;
        int32_t foot_from = foot_units(col, col->previous_pose, job->units_per_m);
        double dist_cells = hypot(to.x - from.x, to.y - from.y) / job->cell_size_m;
        int steps = dist_cells < 1.0 ? 1 : dist_cells > 4096.0 ? 4096 : (int)ceil(dist_cells);
        for (int s = 1; s <= steps; s++) {
            double t = (double)s / steps;
            int32_t f = (int32_t)((double)foot_from + ((double)foot - foot_from) * t);
            write_point(p, job, from.x + (to.x - from.x) * t, from.y + (to.y - from.y) * t, f,
                        deform, foot_image);
        }
    }

    for (int64_t i = 0; i < n; i++) {
        if (foot_image[i] == INT32_MAX)
            continue;
        int32_t now = job->heights[i];
        int32_t snow = job->base_heights ? job->base_heights[i] : now;
        int32_t foot = foot_image[i];
        if (deform[i] < snow) {
            /* depression: down to the profile (never up, never under the floor) */
            int32_t cut = deform[i] > p->floor ? deform[i] : p->floor;
            if (cut < now)
                job->heights[i] = cut;
            continue;
        }
        /* a rim never refills a depression an earlier tick cut (now under the
         * base): else each tick's rim lands in the trail just behind a moving
         * collider and the trench becomes a row of dents at any speed */
        if (now < snow || foot >= snow || p->edge_height_q16 == 0 || p->trail_scale_q16 == 0)
            continue;
        /* rim: a quadratic bump over the ring [R, R + W] outside the depression */
        int64_t depth = (int64_t)snow - foot;
        int64_t d = profile_distance_q8((int64_t)deform[i] - foot, p->trail_scale_q16);
        int64_t radius = profile_distance_q8(depth, p->trail_scale_q16);
        int64_t width = (radius * p->edge_width_q16) >> 16;
        int64_t e = d - radius;
        if (width <= 0 || e <= 0 || e >= width)
            continue;
        int64_t t = (2 * e * 65536) / width - 65536; /* -1..1 in Q16 */
        int64_t q = 65536 - ((t * t) >> 16);         /* 1 - t^2 in Q16 */
        int64_t rim_height = (depth * p->edge_height_q16) >> 16;
        if (rim_height > WORLD_HEIGHT_MAX)
            rim_height = WORLD_HEIGHT_MAX;
        int64_t target = (int64_t)snow + ((rim_height * q) >> 16);
        if (target > WORLD_HEIGHT_MAX)
            target = WORLD_HEIGHT_MAX;
        if (target > now)
            job->heights[i] = (int32_t)target;
    }
    return SIM_WINDOW_OK;
}
