/*
 * sim_slices.c: a fast collider's tick cut into one-cell slices, for the
 * models that are a rate or a history rather than a shape (diffusion, bekker;
 * issue 20, item 4). Row 4d of the tick: a model's window function asks how
 * many slices its window's tick needs, then runs each slice with every
 * collider at the next 1/L of its sweep, over that slice's part of the window
 * only, packed out of the window's arrays and written back. A collider that
 * crosses L cells in a tick then deforms the ground as one crossing a cell
 * per tick does over L ticks, so its trail does not depend on how the motion
 * is cut into ticks. A tick whose colliders move at most 1.5 cells is one
 * slice: exactly the unsliced tick.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <string.h>

/* Around a slice's colliders (sim_slice_rect): the default active_margin_cells. */
#define SLICE_MARGIN_CELLS 4

/* One per cell the fastest collider crosses: steps / 2 of its half-cell
 * sub-steps rounded down. A move of exactly one cell sums to a hair over it
 * in double and takes 3 sub-steps; it stays one slice. */
int sim_sweep_slices(const sim_window_job *job)
{
    int slices = 1;
    for (int c = 0; c < job->collider_count; c++) {
        int steps = sim_collider_sweep_steps(&job->colliders[c], job->cell_size_m);
        if (steps / 2 > slices)
            slices = steps / 2;
    }
    return slices;
}

/* One per cell the fastest collider's pose position travels (rounded to the
 * nearest: a move of 40 cells that sums to a hair under it in double is 40
 * one-cell slices), when that is more than 1.5 cells. Its turning is not counted: at the pose, a
 * wheel spinning in place presses where it stands, and a testbed wheel at slip 0.6 (its rim 1.75
 * cells a tick) is a slow tick, not a sliced one. */
int sim_travel_slices(const sim_window_job *job)
{
    int slices = 1;
    for (int c = 0; c < job->collider_count; c++) {
        const sim_collider *col = &job->colliders[c];
        if (!col->has_previous)
            continue;
        vec3d a = col->previous_pose.position, b = col->pose.position;
        double cells = sqrt((b.x - a.x) * (b.x - a.x) + (b.y - a.y) * (b.y - a.y) +
                            (b.z - a.z) * (b.z - a.z)) /
                       job->cell_size_m;
        if (cells > 1.5 && isfinite(cells) && cells >= slices + 0.5) {
            int steps = sim_collider_sweep_steps(col, job->cell_size_m);
            /* never more slices than the sweep has sub-steps to end them at */
            int whole = (int)floor(cells + 0.5);
            slices = whole < steps ? whole : steps;
        }
    }
    return slices;
}

int sim_slice_end(int j, int slices, int steps)
{
    return (int)((int64_t)j * steps / slices);
}

collider_pose sim_slice_pose(const sim_collider *c, double cell_size_m, int j, int slices)
{
    if (slices <= 1)
        return c->pose;
    int steps = sim_collider_sweep_steps(c, cell_size_m);
    return sim_collider_sweep_pose(c, sim_slice_end(j, slices, steps), steps);
}

/* The bounds of every collider's poses in slice j, from where it starts (the
 * part a collider crossing a cell per tick would have as its window), plus
 * SLICE_MARGIN_CELLS, within the window: the cost of a slice follows the
 * collider, not the sweep. */
world_rect sim_slice_rect(const sim_window_job *job, int j, int slices)
{
    double lo_x = INFINITY, lo_y = INFINITY, hi_x = -INFINITY, hi_y = -INFINITY;
    for (int c = 0; c < job->collider_count; c++) {
        const sim_collider *col = &job->colliders[c];
        int steps = sim_collider_sweep_steps(col, job->cell_size_m);
        int k0 = sim_slice_end(j - 1, slices, steps), k1 = sim_slice_end(j, slices, steps);
        for (int k = k0; k <= k1; k++) {
            vec3d lo, hi;
            collider_bounds(col->geometry, sim_collider_sweep_pose(col, k, steps), &lo, &hi);
            lo_x = fmin(lo_x, lo.x);
            lo_y = fmin(lo_y, lo.y);
            hi_x = fmax(hi_x, hi.x);
            hi_y = fmax(hi_y, hi.y);
        }
    }
    world_rect r = job->rect;
    if (!(lo_x <= hi_x && lo_y <= hi_y))
        return r; /* no collider: the whole window */
    double cell = job->cell_size_m;
    double x0 = fmax(floor(lo_x / cell) - SLICE_MARGIN_CELLS, r.x);
    double y0 = fmax(floor(lo_y / cell) - SLICE_MARGIN_CELLS, r.y);
    double x1 = fmin(floor(hi_x / cell) + SLICE_MARGIN_CELLS, (double)r.x + r.w - 1);
    double y1 = fmin(floor(hi_y / cell) + SLICE_MARGIN_CELLS, (double)r.y + r.h - 1);
    if (x1 < x0 || y1 < y0)
        return (world_rect){0, 0, 0, 0};
    return (world_rect){(int)x0, (int)y0, (int)(x1 - x0) + 1, (int)(y1 - y0) + 1};
}

void sim_slice_copy(world_rect window, world_rect part, void *cells, void *packed,
                    size_t cell_bytes, int in)
{
    size_t row_bytes = (size_t)part.w * cell_bytes;
    for (int y = 0; y < part.h; y++) {
        int64_t at = (int64_t)(part.y - window.y + y) * window.w + (part.x - window.x);
        unsigned char *row = (unsigned char *)cells + (size_t)at * cell_bytes;
        unsigned char *p = (unsigned char *)packed + (size_t)y * row_bytes;
        memcpy(in ? p : row, in ? row : p, row_bytes);
    }
}
