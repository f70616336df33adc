/*
 * sim_engine.c: one deformation tick over a world (DESIGN.md steps 3-7).
 *
 * Active areas: each collider's footprint is its bounding box at the last
 * pose and at this one (so a fast collider sweeps the cells in between),
 * plus a margin; colliders entirely above the terrain under them are
 * skipped. Footprints that share a cell are merged until the windows are
 * disjoint — simulating overlapping areas separately is what corrupted the
 * original's volume. Every window of the tick goes to the backend as one
 * batch; a window the backend refuses (height limit) leaves the world as it
 * was. The diff of each window against its gathered copy gives a tight dirty
 * rectangle for the wire and the log.
 */
#include "sim/sim.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static int grow(void **buf, int64_t *capacity, int64_t needed, size_t elem)
{
    if (needed <= *capacity)
        return 0;
    int64_t cap = *capacity ? *capacity : 16;
    while (cap < needed)
        cap *= 2;
    void *p = realloc(*buf, (size_t)cap * elem);
    if (!p)
        return -1;
    *buf = p;
    *capacity = cap;
    return 0;
}

static int clamp_to_int(double v)
{
    if (!(v > -1e9))
        return -1000000000;
    if (v > 1e9)
        return 1000000000;
    return (int)floor(v);
}

static int32_t units_clamped(double metres, int32_t units_per_m)
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
    if (c->has_previous) {
        vec3d plo, phi;
        collider_bounds(c->geometry, c->previous_pose, &plo, &phi);
        lo.x = fmin(lo.x, plo.x);
        lo.y = fmin(lo.y, plo.y);
        lo.z = fmin(lo.z, plo.z);
        hi.x = fmax(hi.x, phi.x);
        hi.y = fmax(hi.y, phi.y);
    }
    int x0 = clamp_to_int(lo.x / w->cell_size_m) - margin;
    int y0 = clamp_to_int(lo.y / w->cell_size_m) - margin;
    int x1 = clamp_to_int(hi.x / w->cell_size_m) + margin;
    int y1 = clamp_to_int(hi.y / w->cell_size_m) + margin;
    world_rect r = {x0, y0, x1 - x0 + 1, y1 - y0 + 1};
    if (!world_clip_rect(w, &r))
        return (world_rect){0, 0, 0, 0};
    int32_t hmin, hmax;
    world_rect_height_range(w, r, &hmin, &hmax);
    if ((int64_t)units_clamped(lo.z, w->units_per_m) > (int64_t)hmax + p->obstacle_gap)
        return (world_rect){0, 0, 0, 0}; /* flying above everything it could touch */
    return r;
}

static int compare_rects(const void *a, const void *b)
{
    const world_rect *r = a, *s = b;
    if (r->y != s->y)
        return (r->y > s->y) - (r->y < s->y);
    return (r->x > s->x) - (r->x < s->x);
}

int sim_plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                     int collider_count, int margin_cells, world_rect *footprints, world_rect **out,
                     int *out_count)
{
    world_rect *rects = malloc(((size_t)collider_count + 1) * sizeof *rects);
    if (!rects)
        return -1;
    int n = 0;
    for (int i = 0; i < collider_count; i++) {
        footprints[i] = collider_footprint(w, p, &colliders[i], margin_cells);
        if (footprints[i].w > 0)
            rects[n++] = footprints[i];
    }
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

int sim_engine_init(sim_engine *e, world *w, const sim_params *p, sim_backend *backend,
                    int margin_cells, error_text *err)
{
    memset(e, 0, sizeof *e);
    if (margin_cells < 0 || margin_cells > 4096) {
        error_set(err, "active_margin_cells: must be in [0, 4096] (got %d)", margin_cells);
        return -1;
    }
    e->world = w;
    e->params = *p;
    e->backend = backend;
    e->margin_cells = margin_cells;
    return 0;
}

void sim_engine_free(sim_engine *e)
{
    free(e->windows);
    free(e->jobs);
    free(e->status);
    free(e->dirty);
    free(e->dirty_window);
    free(e->window_offsets);
    free(e->footprints);
    free(e->window_colliders);
    free(e->heights);
    free(e->before);
    free(e->bottom);
    memset(e, 0, sizeof *e);
}

world_rect sim_engine_window(const sim_engine *e, int i, const int32_t **before,
                             const int32_t **after)
{
    *before = e->before + e->window_offsets[i];
    *after = e->heights + e->window_offsets[i];
    return e->windows[i];
}

/* Tight bounding box of the cells that differ; w == 0 when none does. */
static world_rect diff_rect(world_rect r, const int32_t *before, const int32_t *after)
{
    int x0 = r.w, y0 = r.h, x1 = -1, y1 = -1;
    for (int y = 0; y < r.h; y++) {
        const int32_t *a = before + (int64_t)y * r.w, *b = after + (int64_t)y * r.w;
        if (memcmp(a, b, (size_t)r.w * sizeof *a) == 0)
            continue;
        for (int x = 0; x < r.w; x++) {
            if (a[x] != b[x]) {
                if (x < x0)
                    x0 = x;
                if (x > x1)
                    x1 = x;
            }
        }
        if (y < y0)
            y0 = y;
        y1 = y;
    }
    if (x1 < 0)
        return (world_rect){0, 0, 0, 0};
    return (world_rect){r.x + x0, r.y + y0, x1 - x0 + 1, y1 - y0 + 1};
}

static uint64_t engine_scratch_bytes(const sim_engine *e)
{
    return (uint64_t)e->cell_capacity * 3 * sizeof(int32_t) +
           (uint64_t)e->window_capacity *
               (sizeof(world_rect) * 2 + sizeof(sim_window_job) + sizeof(int)) +
           (uint64_t)e->footprint_capacity * sizeof(world_rect) +
           (uint64_t)e->window_collider_capacity * sizeof(sim_collider);
}

int sim_engine_tick(sim_engine *e, const sim_collider *colliders, int collider_count,
                    sim_tick_report *report, error_text *err)
{
    memset(report, 0, sizeof *report);
    world *w = e->world;
    double t_start = time_now_ms();
    int64_t cap = e->footprint_capacity;
    if (grow((void **)&e->footprints, &cap, collider_count + 1, sizeof *e->footprints) != 0)
        goto oom;
    e->footprint_capacity = (int)cap;

    world_rect *windows = NULL;
    int count = 0;
    if (sim_plan_windows(w, &e->params, colliders, collider_count, e->margin_cells, e->footprints,
                         &windows, &count) != 0)
        goto oom;
    cap = e->window_capacity;
    int64_t cap2 = cap, cap3 = cap, cap4 = cap, cap5 = cap, cap6 = cap;
    if (grow((void **)&e->jobs, &cap, count + 1, sizeof *e->jobs) != 0 ||
        grow((void **)&e->dirty_window, &cap5, count + 1, sizeof *e->dirty_window) != 0 ||
        grow((void **)&e->window_offsets, &cap6, count + 1, sizeof *e->window_offsets) != 0 ||
        grow((void **)&e->status, &cap2, count + 1, sizeof *e->status) != 0 ||
        grow((void **)&e->dirty, &cap3, count + 1, sizeof *e->dirty) != 0 ||
        grow((void **)&e->windows, &cap4, count + 1, sizeof *e->windows) != 0) {
        free(windows);
        goto oom;
    }
    e->window_capacity = (int)cap;
    memcpy(e->windows, windows, (size_t)count * sizeof *windows);
    free(windows);

    /* Cells and collider references of the whole batch. */
    int64_t cells = 0, refs = 0;
    for (int i = 0; i < count; i++) {
        cells += (int64_t)e->windows[i].w * e->windows[i].h;
        for (int c = 0; c < collider_count; c++)
            refs += e->footprints[c].w > 0 && world_rects_overlap(e->footprints[c], e->windows[i]);
    }
    int64_t ccap = e->cell_capacity, ccap2 = ccap, ccap3 = ccap;
    if (grow((void **)&e->heights, &ccap, cells + 1, sizeof(int32_t)) != 0 ||
        grow((void **)&e->before, &ccap2, cells + 1, sizeof(int32_t)) != 0 ||
        grow((void **)&e->bottom, &ccap3, cells + 1, sizeof(int32_t)) != 0)
        goto oom;
    e->cell_capacity = ccap;
    int64_t rcap = e->window_collider_capacity;
    if (grow((void **)&e->window_colliders, &rcap, refs + 1, sizeof(sim_collider)) != 0)
        goto oom;
    e->window_collider_capacity = (int)rcap;

    int64_t offset = 0;
    int ref = 0;
    for (int i = 0; i < count; i++) {
        world_rect r = e->windows[i];
        sim_window_job *job = &e->jobs[i];
        memset(job, 0, sizeof *job);
        e->window_offsets[i] = offset;
        job->rect = r;
        job->cell_size_m = w->cell_size_m;
        job->units_per_m = w->units_per_m;
        job->heights = e->heights + offset;
        job->world = w;
        world_gather_window(w, r, job->heights);
        memcpy(e->before + offset, job->heights, (size_t)r.w * r.h * sizeof(int32_t));
        int32_t hmin, hmax;
        world_rect_height_range(w, r, &hmin, &hmax);
        int32_t zmin = hmin;
        job->colliders = e->window_colliders + ref;
        for (int c = 0; c < collider_count; c++) {
            if (e->footprints[c].w == 0 || !world_rects_overlap(e->footprints[c], r))
                continue;
            e->window_colliders[ref++] = colliders[c];
            job->collider_count++;
            vec3d lo, hi;
            collider_bounds(colliders[c].geometry, colliders[c].pose, &lo, &hi);
            int32_t z = units_clamped(lo.z, w->units_per_m);
            if (z < zmin)
                zmin = z;
        }
        job->depth_low = zmin - 1 > e->params.floor ? zmin - 1 : e->params.floor;
        job->depth_high = hmax + e->params.obstacle_gap + 1;
        if (e->depth_from_cpu) {
            int32_t *bottom = e->bottom + offset;
            for (int64_t k = 0; k < (int64_t)r.w * r.h; k++)
                bottom[k] = COLLIDER_BOTTOM_NONE;
            for (int c = 0; c < job->collider_count; c++)
                collider_depth_cpu(job->colliders[c].geometry, job->colliders[c].pose, r,
                                   w->cell_size_m, w->units_per_m, bottom);
            job->bottom_override = bottom;
        }
        offset += (int64_t)r.w * r.h;
    }
    report->gather_scatter_ms += time_now_ms() - t_start;

    if (count > 0 && e->backend->run_windows(e->backend, &e->params, e->jobs, count, e->status,
                                             &report->times, err) != 0)
        return -1;

    double t_scatter = time_now_ms();
    offset = 0;
    report->dirty = e->dirty;
    report->dirty_window = e->dirty_window;
    for (int i = 0; i < count; i++) {
        world_rect r = e->windows[i];
        int64_t n = (int64_t)r.w * r.h;
        if (e->status[i] == SIM_WINDOW_OK) {
            world_rect d = diff_rect(r, e->before + offset, e->heights + offset);
            if (d.w > 0) {
                world_scatter_window(w, r, e->heights + offset);
                if (e->backend->window_scattered)
                    e->backend->window_scattered(e->backend, i, w, r);
                e->dirty_window[report->dirty_count] = i;
                e->dirty[report->dirty_count++] = d;
            }
        } else {
            report->refused_windows++;
        }
        offset += n;
    }
    report->window_count = count;
    report->active_cells = cells;
    report->gather_scatter_ms += time_now_ms() - t_scatter;
    if (cells > e->peak_active_cells)
        e->peak_active_cells = cells;
    uint64_t scratch = engine_scratch_bytes(e) + e->backend->scratch_bytes(e->backend);
    if (scratch > e->peak_scratch_bytes)
        e->peak_scratch_bytes = scratch;
    return 0;
oom:
    error_set(err, "sim: out of memory planning %d colliders", collider_count);
    return -1;
}
