/*
 * model_sumner.c: Sumner, O'Brien and Hodgins 1999 ("Animating Sand, Mud,
 * and Snow"), as summarised in Persson's thesis ch. 3.6.1, on the CPU, in
 * integers. It is the accuracy reference beside Persson's GPU pipeline: the
 * tick's dispatch (sim_engine_tick) calls sim_sumner_window once per window
 * instead of a backend's stages when a scene picks the sumner model.
 *
 * Per window:
 *   1. ray-cast columns: the lowest collider point above each cell
 *      (collider_depth_cpu, the same depth as the CPU twin's);
 *   2. columns the collider is inside lose their penetration; the share
 *      `compression` of it is compacted away, the rest is displaced;
 *   3. contour map: the footprint (penetrated columns and obstacle columns,
 *      a collider resting just above) is split into 8-connected components;
 *      the free cells at distance 1 from a component are its first ring;
 *      a moving component's ring is the part not behind it (ring_owners);
 *   4. each component's displaced material is spread evenly over its first
 *      ring; the integer remainder goes one unit each to the first ring
 *      cells in row-major order (deterministic);
 *   5. erosion: slopes steeper than the angle of repose are relaxed by the
 *      slope-evening iterations of the Persson stages (sim_even_slopes), which
 *      move material by integer fluxes only, never into the footprint.
 *
 * Volume: every displaced unit lands in exactly one first-ring cell of the
 * same window, and erosion moves integers between columns, so with
 * compression 0 Σh is unchanged. A component with no free cell around it
 * (a collider covering the whole window) keeps its material in its columns.
 * If any column would leave [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX] the window is
 * refused (SIM_WINDOW_HEIGHT_LIMIT) and job->heights are left as they were.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

static const int ring_dx[8] = {1, -1, 0, 0, 1, -1, 1, -1};
static const int ring_dy[8] = {0, 0, 1, -1, 1, 1, -1, -1};

/* Scratch, in int32 cells: bottom, cls, label, queue, owner, ring count,
 * given, new heights (8n), component totals as int64 (2n + 1 for
 * alignment), and the erosion's 4n. */
int64_t sim_sumner_scratch_cells(int w, int h)
{
    int64_t n = (int64_t)w * h;
    return 14 * n + 2;
}

/* Label the 8-connected components of the footprint (cls != SEED) in
 * row-major order of their first cell; free cells get -1. Returns the count. */
static int32_t label_footprint(int w, int h, const int32_t *cls, int32_t *label, int32_t *queue)
{
    int n = w * h;
    for (int i = 0; i < n; i++)
        label[i] = -1;
    int32_t count = 0;
    for (int start = 0; start < n; start++) {
        if (cls[start] == SIM_CELL_SEED || label[start] >= 0)
            continue;
        int head = 0, tail = 0;
        queue[tail++] = start;
        label[start] = count;
        while (head < tail) {
            int i = queue[head++];
            int x = i % w, y = i / w;
            for (int j = 0; j < 8; j++) {
                int qx = x + ring_dx[j], qy = y + ring_dy[j];
                if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                    continue;
                int q = qy * w + qx;
                if (cls[q] != SIM_CELL_SEED && label[q] < 0) {
                    label[q] = count;
                    queue[tail++] = q;
                }
            }
        }
        count++;
    }
    return count;
}

/* Horizontal motion of each component this tick, into motion[2c], [2c+1]:
 * the sum of the moves (pose - previous pose) of the colliders whose swept
 * bounds hold one of its penetrating cells. seen (components) is scratch. */
static void component_motion(const sim_window_job *job, int w, int h, const int32_t *cls,
                             const int32_t *label, int32_t components, int32_t *seen,
                             double *motion)
{
    for (int32_t c = 0; c < components; c++) {
        seen[c] = -1;
        motion[2 * c] = motion[2 * c + 1] = 0.0;
    }
    for (int k = 0; k < job->collider_count; k++) {
        const sim_collider *col = &job->colliders[k];
        if (!col->has_previous)
            continue;
        double mx = col->pose.position.x - col->previous_pose.position.x;
        double my = col->pose.position.y - col->previous_pose.position.y;
        if (!(mx != 0.0 || my != 0.0) || !isfinite(mx) || !isfinite(my))
            continue;
        vec3d lo, hi;
        sim_collider_sweep_bounds(col, job->cell_size_m, &lo, &hi);
        double x0 = floor(lo.x / job->cell_size_m) - job->rect.x;
        double x1 = floor(hi.x / job->cell_size_m) - job->rect.x;
        double y0 = floor(lo.y / job->cell_size_m) - job->rect.y;
        double y1 = floor(hi.y / job->cell_size_m) - job->rect.y;
        int ax = x0 < 0.0  ? 0
                 : x0 >= w ? w
                           : (int)x0,
            bx = x1 < 0.0  ? -1
                 : x1 >= w ? w - 1
                           : (int)x1;
        int ay = y0 < 0.0  ? 0
                 : y0 >= h ? h
                           : (int)y0,
            by = y1 < 0.0  ? -1
                 : y1 >= h ? h - 1
                           : (int)y1;
        for (int y = ay; y <= by; y++) {
            for (int x = ax; x <= bx; x++) {
                int i = y * w + x;
                if (cls[i] != SIM_CELL_PENETRATING || seen[label[i]] == k)
                    continue;
                seen[label[i]] = k;
                motion[2 * label[i]] += mx;
                motion[2 * label[i] + 1] += my;
            }
        }
    }
}

/*
 * First rings, with the direction of motion (Onoue and Nishita's rule, as
 * Persson's thesis ch. 3 summarises it): a moving component passes material
 * only to ring cells that are not behind it, d_motion . d_column >= 0, where
 * d_column points from a footprint cell to the ring cell beside it. Without
 * it the ring behind a fast collider lies in the trench the collider just
 * dug and refills it at every tick boundary (a dotted trail at 40 cells per
 * tick; issue 12, item 2). A collider at rest has no direction and keeps the
 * whole ring; a component with no ring cell ahead or beside it keeps the
 * whole ring too. owner[i]: the component a free cell receives for (the
 * lowest label among those that may give to it), or -1.
 */
static void ring_owners(const sim_window_job *job, int w, int h, const int32_t *cls,
                        const int32_t *label, int32_t components, int32_t *any, double *motion,
                        int32_t *owner, int32_t *ring_count)
{
    int n = w * h;
    component_motion(job, w, h, cls, label, components, any, motion);
    for (int32_t c = 0; c < components; c++)
        ring_count[c] = 0;
    for (int i = 0; i < n; i++) {
        owner[i] = any[i] = -1;
        if (cls[i] != SIM_CELL_SEED)
            continue;
        int x = i % w, y = i / w;
        for (int j = 0; j < 8; j++) {
            int qx = x + ring_dx[j], qy = y + ring_dy[j];
            if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                continue;
            int32_t l = label[qy * w + qx];
            if (l < 0)
                continue;
            /* a cell touching two components belongs to the lower label */
            if (any[i] < 0 || l < any[i])
                any[i] = l;
            /* d_column = -(ring_dx, ring_dy): ahead or beside when motion . d >= 0 */
            int ahead = motion[2 * l] * ring_dx[j] + motion[2 * l + 1] * ring_dy[j] <= 0.0;
            if (ahead && (owner[i] < 0 || l < owner[i]))
                owner[i] = l;
        }
        if (owner[i] >= 0)
            ring_count[owner[i]]++;
    }
    /* a component with no ring cell ahead or beside it takes its whole ring
     * (motion is no longer needed: it holds that flag now) */
    for (int32_t c = 0; c < components; c++)
        motion[c] = ring_count[c] == 0 ? 1.0 : 0.0;
    for (int i = 0; i < n; i++) {
        if (owner[i] < 0 && any[i] >= 0 && motion[any[i]] != 0.0) {
            owner[i] = any[i];
            ring_count[owner[i]]++;
        }
    }
}

static void sumner_depth(const sim_window_job *job, int32_t *bottom)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    if (job->bottom_override) {
        memcpy(bottom, job->bottom_override, (size_t)n * sizeof *bottom);
    } else {
        sim_window_depth(job, bottom);
    }
    if (job->bottom_out)
        memcpy(job->bottom_out, bottom, (size_t)n * sizeof *bottom);
}

int64_t sim_settle_scratch_cells(int w, int h)
{
    return 12 * (int64_t)w * h + 2;
}

sim_window_status sim_sumner_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    int n = job->rect.w * job->rect.h;
    int32_t *bottom = scratch;
    int32_t *cls = bottom + n;
    int32_t *settle = cls + n;
    int32_t *raw = SIM_SETTLE_RAW(settle, n), *moved = SIM_SETTLE_MOVED(settle, n);

    /* 1-2: ray-cast columns, penetration and class. */
    sumner_depth(job, bottom);
    if (job->materials)
        sim_classify_materials(p, job->materials, job->material_ids, job->compaction, n,
                               job->heights, bottom, raw, moved, cls);
    else
        sim_classify(p, n, job->heights, bottom, raw, moved, cls);
    /* The engine keeps this only if the window is accepted. */
    if (job->materials && job->compaction)
        sim_compaction_commit(job->materials, job->material_ids, n, raw, moved, job->compaction);
    return sim_sumner_settle(p, job, cls, settle);
}

/* Steps 2 (the new heights) to 5; raw in `next`, moved in `given` on entry. */
sim_window_status sim_sumner_settle(const sim_params *p, sim_window_job *job, const int32_t *cls,
                                    int32_t *scratch)
{
    int w = job->rect.w, h = job->rect.h;
    int n = w * h;
    int32_t *heights = job->heights;
    int32_t *label = scratch;
    int32_t *queue = label + n;
    int32_t *owner = queue + n;
    int32_t *ring_count = owner + n;
    int32_t *given = ring_count + n;
    int32_t *next = given + n;
    int64_t *total = (int64_t *)(void *)(((uintptr_t)(next + n) + 7) & ~(uintptr_t)7);
    int32_t *erosion_scratch = (int32_t *)(void *)(total + n);

    /* 3: components of the footprint and their first rings. */
    int32_t components = label_footprint(w, h, cls, label, queue);
    for (int32_t c = 0; c < components; c++) {
        total[c] = 0;
        ring_count[c] = 0;
    }
    for (int i = 0; i < n; i++)
        if (cls[i] == SIM_CELL_PENETRATING)
            total[label[i]] += given[i];
    ring_owners(job, w, h, cls, label, components, queue, (double *)(void *)erosion_scratch, owner,
                ring_count);

    /* 2 (cont.): new heights into `next`; a component with no ring keeps its
     * displaced material home and loses only the compacted part. */
    for (int i = 0; i < n; i++) {
        int32_t raw = next[i], moved = given[i];
        if (cls[i] == SIM_CELL_PENETRATING && ring_count[label[i]] == 0)
            next[i] = heights[i] - (raw - moved);
        else
            next[i] = heights[i] - raw;
    }

    /* 4: even spread over the first ring, remainder row-major. */
    for (int32_t c = 0; c < components; c++)
        given[c] = 0;
    for (int i = 0; i < n; i++) {
        int32_t c = owner[i];
        if (c < 0)
            continue;
        int64_t share = total[c] / ring_count[c];
        int64_t remainder = total[c] % ring_count[c];
        int64_t add = share + (given[c] < remainder ? 1 : 0);
        given[c]++;
        if (add > (int64_t)WORLD_HEIGHT_MAX - next[i])
            return SIM_WINDOW_HEIGHT_LIMIT; /* job->heights untouched */
        next[i] += (int32_t)add;
    }
    memcpy(heights, next, (size_t)n * sizeof *heights);

    /* 5: erosion towards the angle of repose, never into the footprint. */
    if (job->materials)
        sim_even_slopes_materials(p, job->materials, job->material_ids, w, h, cls, heights,
                                  erosion_scratch);
    else
        sim_even_slopes(p, w, h, cls, heights, erosion_scratch);
    return SIM_WINDOW_OK;
}
