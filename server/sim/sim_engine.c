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
 *
 * Models (docs/models.md): the persson-* models go to the backend; the others
 * run their CPU window functions here (model_<name>.c, chosen per window by
 * the params' model), with only the inputs they need prepared — depth for
 * subtract and diffusion, base heights for refill and deferred — and only
 * their scratch allocated, so a subtract scene holds no jump-flooding or
 * displacement buffers at all. Subtract's refill keeps the windows that are
 * still below base in the next tick's plan until they are full again.
 */
#include "sim/sim.h"

#include "ground/ground.h"

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

/* Footprints plus extra rectangles (subtract's refilling windows) → windows. */
static int plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                        int collider_count, int margin_cells, const world_rect *extra,
                        int extra_count, world_rect *footprints, world_rect **out, int *out_count)
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

int sim_plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                     int collider_count, int margin_cells, world_rect *footprints, world_rect **out,
                     int *out_count)
{
    return plan_windows(w, p, colliders, collider_count, margin_cells, NULL, 0, footprints, out,
                        out_count);
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

void sim_engine_set_ground(sim_engine *e, struct ground *g)
{
    /* The uniform path only when it computes the same: one material whose
     * row is the params' own and no compaction memory. */
    ground_material_row own = sim_material_row_from_params(&e->params, 0);
    int same =
        g && g->uniform && !g->uses_compaction && memcmp(&g->table.rows[0], &own, sizeof own) == 0;
    e->ground = g && !same ? g : NULL;
}

/* Per-cell layers of the tick's windows, packed like the heights; only those
 * the scene needs. */
static int ground_grow(sim_engine *e, int64_t cells)
{
    if (!e->ground || cells <= e->ground_capacity)
        return 0;
    int64_t cap = e->ground_capacity ? e->ground_capacity : 1024;
    while (cap < cells)
        cap *= 2;
    if (!e->ground->uniform) {
        uint8_t *ids = realloc(e->material_ids, (size_t)cap);
        if (!ids)
            return -1;
        e->material_ids = ids;
    }
    if (e->ground->uses_compaction) {
        uint16_t *m = realloc(e->compaction, (size_t)cap * sizeof *m);
        if (!m)
            return -1;
        e->compaction = m;
    }
    e->ground_capacity = cap;
    return 0;
}

static void ground_gather_job(sim_engine *e, sim_window_job *job, int64_t offset)
{
    if (!e->ground)
        return;
    job->materials = &e->ground->table;
    if (!e->ground->uniform) {
        job->material_ids = e->material_ids + offset;
        ground_gather_ids(e->ground, job->rect, e->material_ids + offset);
    }
    if (e->ground->uses_compaction) {
        job->compaction = e->compaction + offset;
        ground_gather_compaction(e->ground, job->rect, job->compaction);
    }
}

void sim_engine_free(sim_engine *e)
{
    free(e->material_ids);
    free(e->compaction);
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
    free(e->model_scratch);
    free(e->base);
    free(e->refilling);
    free(e->footprints_out);
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

/* Scratch held now, by stage; the engine's packed windows are gather_scatter,
 * the depth it casts for a model is depth, the models' own is model. */
static void engine_memory(const sim_engine *e, sim_stage_memory *m)
{
    memset(m, 0, sizeof *m);
    if (e->backend->stage_bytes)
        e->backend->stage_bytes(e->backend, m);
    else
        m->backend_other = e->backend->scratch_bytes(e->backend);
    m->gather_scatter =
        (uint64_t)e->cell_capacity * 2 * sizeof(int32_t) +
        (uint64_t)e->window_capacity * (sizeof(world_rect) * 2 + sizeof(sim_window_job) +
                                        sizeof(int) + sizeof(int64_t) + sizeof(int)) +
        (uint64_t)e->footprint_capacity * sizeof(world_rect) +
        (uint64_t)e->window_collider_capacity * sizeof(sim_collider);
    m->depth += (uint64_t)e->bottom_capacity * sizeof(int32_t);
    m->model = (uint64_t)e->model_scratch_capacity * sizeof(int32_t) +
               (uint64_t)e->base_capacity * sizeof(int32_t) +
               (uint64_t)e->refilling_capacity * sizeof(world_rect) +
               (uint64_t)e->footprint_out_capacity * sizeof(sim_footprint);
}

uint64_t sim_stage_memory_total(const sim_stage_memory *m)
{
    return m->depth + m->classify + m->jump_flood + m->displace + m->even_slopes +
           m->backend_other + m->model + m->gather_scatter;
}

static void memory_peak(sim_stage_memory *peak, const sim_stage_memory *now)
{
    uint64_t *p = &peak->depth;
    const uint64_t *n = &now->depth;
    for (size_t i = 0; i < sizeof *peak / sizeof(uint64_t); i++)
        if (n[i] > p[i])
            p[i] = n[i];
}

/* Run the tick's windows through a non-persson model on the CPU. */
static int run_model_windows(sim_engine *e, int count, sim_tick_report *report, error_text *err)
{
    const sim_params *p = &e->params;
    int64_t largest = 0;
    int refs = 0;
    for (int i = 0; i < count; i++) {
        int64_t n = (int64_t)e->windows[i].w * e->windows[i].h;
        if (n > largest)
            largest = n;
        refs += e->jobs[i].collider_count;
    }
    int64_t need = sim_model_scratch_cells(p->model, largest);
    if (grow((void **)&e->model_scratch, &e->model_scratch_capacity, need + 1, sizeof(int32_t)) !=
        0)
        goto oom;
    if (p->model == SIM_MODEL_DECALS) {
        int64_t cap = e->footprint_out_capacity;
        if (grow((void **)&e->footprints_out, &cap, refs + 1, sizeof(sim_footprint)) != 0)
            goto oom;
        e->footprint_out_capacity = (int)cap;
    }
    int needs_depth = sim_model_needs_depth(p->model);
    int64_t offset = 0;
    for (int i = 0; i < count; i++) {
        sim_window_job *job = &e->jobs[i];
        int64_t n = (int64_t)job->rect.w * job->rect.h;
        double t0 = time_now_ms();
        if (needs_depth && !job->bottom_override) {
            int32_t *bottom = e->bottom + offset;
            for (int64_t k = 0; k < n; k++)
                bottom[k] = COLLIDER_BOTTOM_NONE;
            for (int c = 0; c < job->collider_count; c++)
                collider_depth_cpu(job->colliders[c].geometry, job->colliders[c].pose, job->rect,
                                   job->cell_size_m, job->units_per_m, bottom);
            job->bottom_override = bottom;
        }
        double t1 = time_now_ms();
        if (p->model == SIM_MODEL_DECALS) {
            e->status[i] = SIM_WINDOW_OK;
            report->footprint_count += sim_decals_window(
                p, job, e->model_scratch, e->footprints_out + report->footprint_count,
                e->footprint_out_capacity - report->footprint_count);
        } else {
            e->status[i] = sim_model_window(p, job, e->model_scratch);
        }
        report->times.depth += t1 - t0;
        report->model_ms += time_now_ms() - t1;
        offset += n;
    }
    report->footprints = e->footprints_out;
    return 0;
oom:
    error_set(err, "sim: out of memory for the %s model's scratch", sim_model_name(p->model));
    return -1;
}

/* subtract: the windows that still hold cells below base refill next tick. */
static int keep_refilling(sim_engine *e, int count)
{
    e->refilling_count = 0;
    int64_t offset = 0;
    for (int i = 0; i < count; i++) {
        world_rect r = e->windows[i];
        int64_t n = (int64_t)r.w * r.h;
        const int32_t *now =
            e->status[i] == SIM_WINDOW_OK ? e->heights + offset : e->before + offset;
        int below = 0;
        for (int64_t k = 0; k < n && !below; k++)
            below = now[k] < e->base[offset + k];
        if (below) {
            int64_t cap = e->refilling_capacity;
            if (grow((void **)&e->refilling, &cap, e->refilling_count + 1, sizeof(world_rect)) != 0)
                return -1;
            e->refilling_capacity = (int)cap;
            e->refilling[e->refilling_count++] = r;
        }
        offset += n;
    }
    return 0;
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
    int refilling = e->params.model == SIM_MODEL_SUBTRACT && e->params.refill_q16_per_tick > 0;
    if (plan_windows(w, &e->params, colliders, collider_count, e->margin_cells, e->refilling,
                     refilling ? e->refilling_count : 0, e->footprints, &windows, &count) != 0)
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
    int persson = sim_model_is_persson(e->params.model);
    int needs_base = !persson && sim_model_needs_base(&e->params);
    int64_t ccap = e->cell_capacity, ccap2 = ccap;
    if (grow((void **)&e->heights, &ccap, cells + 1, sizeof(int32_t)) != 0 ||
        grow((void **)&e->before, &ccap2, cells + 1, sizeof(int32_t)) != 0 ||
        ground_grow(e, cells + 1) != 0)
        goto oom;
    e->cell_capacity = ccap;
    /* depth on the engine's side only where something reads it */
    if ((e->depth_from_cpu || (!persson && sim_model_needs_depth(e->params.model))) &&
        grow((void **)&e->bottom, &e->bottom_capacity, cells + 1, sizeof(int32_t)) != 0)
        goto oom;
    if (needs_base && grow((void **)&e->base, &e->base_capacity, cells + 1, sizeof(int32_t)) != 0)
        goto oom;
    int32_t refill_units = 0;
    if (refilling) {
        /* whole units this tick, the fraction carried to the next */
        e->refill_q16_accumulated += e->params.refill_q16_per_tick;
        int64_t units = e->refill_q16_accumulated >> 16;
        e->refill_q16_accumulated &= 0xffff;
        refill_units = units > WORLD_HEIGHT_MAX ? WORLD_HEIGHT_MAX : (int32_t)units;
    }
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
        ground_gather_job(e, job, offset);
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
        if (needs_base && world_base_fill_rect(w, r, e->base + offset) == 0)
            job->base_heights = e->base + offset;
        job->refill_units = refill_units;
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

    if (count > 0 && persson &&
        e->backend->run_windows(e->backend, &e->params, e->jobs, count, e->status, &report->times,
                                err) != 0)
        return -1;
    if (count > 0 && !persson) {
        if (!e->warned_cpu_model && strcmp(e->backend->name, "cpu") != 0) {
            log_info("sim: model %s has no %s version; it runs on the CPU",
                     sim_model_name(e->params.model), e->backend->name);
            e->warned_cpu_model = 1;
        }
        if (run_model_windows(e, count, report, err) != 0)
            return -1;
    }

    double t_scatter = time_now_ms();
    offset = 0;
    report->dirty = e->dirty;
    report->dirty_window = e->dirty_window;
    for (int i = 0; i < count; i++) {
        world_rect r = e->windows[i];
        int64_t n = (int64_t)r.w * r.h;
        if (e->status[i] == SIM_WINDOW_OK) {
            if (e->jobs[i].compaction &&
                ground_scatter_compaction(e->ground, r, e->jobs[i].compaction, err) != 0)
                return -1;
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
    if (refilling && keep_refilling(e, count) != 0)
        goto oom;
    engine_memory(e, &e->memory);
    memory_peak(&e->peak_memory, &e->memory);
    uint64_t scratch = sim_stage_memory_total(&e->memory);
    if (scratch > e->peak_scratch_bytes)
        e->peak_scratch_bytes = scratch;
    return 0;
oom:
    error_set(err, "sim: out of memory planning %d colliders", collider_count);
    return -1;
}
