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

#include <stdint.h>
#include <string.h>

static const int ring_dx[8] = {1, -1, 0, 0, 1, -1, 1, -1};
static const int ring_dy[8] = {0, 0, 1, -1, 1, 1, -1, -1};

/* Scratch, in int32 cells: bottom, cls, label, queue, owner, ring count,
 * given, new heights (8n), component totals as int64 (2n + 1 for
 * alignment), and the erosion's 2n. */
int64_t sim_sumner_scratch_cells(int w, int h)
{
    int64_t n = (int64_t)w * h;
    return 12 * n + 2;
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

sim_window_status sim_sumner_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    int w = job->rect.w, h = job->rect.h;
    int n = w * h;
    int32_t *heights = job->heights;
    int32_t *bottom = scratch;
    int32_t *cls = bottom + n;
    int32_t *label = cls + n;
    int32_t *queue = label + n;
    int32_t *owner = queue + n;
    int32_t *ring_count = owner + n;
    int32_t *given = ring_count + n;
    int32_t *next = given + n;
    int64_t *total = (int64_t *)(void *)(((uintptr_t)(next + n) + 7) & ~(uintptr_t)7);
    int32_t *erosion_scratch = (int32_t *)(void *)(total + n);

    /* 1-2: ray-cast columns, penetration and class (raw into next, moved into given). */
    sumner_depth(job, bottom);
    if (job->materials)
        sim_classify_materials(p, job->materials, job->material_ids, job->compaction, n, heights,
                               bottom, next, given, cls);
    else
        sim_classify(p, n, heights, bottom, next, given, cls);
    /* The engine keeps this only if the window is accepted. */
    if (job->materials && job->compaction)
        sim_compaction_commit(job->materials, job->material_ids, n, next, given, job->compaction);

    /* 3: components of the footprint and their first rings. */
    int32_t components = label_footprint(w, h, cls, label, queue);
    for (int32_t c = 0; c < components; c++) {
        total[c] = 0;
        ring_count[c] = 0;
    }
    for (int i = 0; i < n; i++)
        if (cls[i] == SIM_CELL_PENETRATING)
            total[label[i]] += given[i];
    for (int i = 0; i < n; i++) {
        owner[i] = -1;
        if (cls[i] != SIM_CELL_SEED)
            continue;
        int x = i % w, y = i / w;
        for (int j = 0; j < 8; j++) {
            int qx = x + ring_dx[j], qy = y + ring_dy[j];
            if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                continue;
            int32_t l = label[qy * w + qx];
            /* a cell touching two components belongs to the lower label */
            if (l >= 0 && (owner[i] < 0 || l < owner[i]))
                owner[i] = l;
        }
        if (owner[i] >= 0)
            ring_count[owner[i]]++;
    }

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
