/*
 * sim_engine.c: one deformation tick over a world (docs/design.md, "One
 * tick"). sim_engine_tick reads as the tick's table of contents:
 *
 *   plan     footprints → disjoint windows (sim_plan.c), plus subtract's
 *            windows still refilling
 *   gather   each window's heights (and ground layers) packed one after
 *            another, a job per window
 *   depth    the CPU depth the engine casts itself, for the models that
 *            read it (diffusion)
 *   model    the persson models on the backend, as one batch; the others
 *            through their CPU window functions (model_<name>.c)
 *   scatter  accepted windows back into the world; a tight dirty rectangle
 *            per changed window for the wire and the log
 *   commit   peaks, subtract's refilling windows, memory by stage
 *
 * A window the backend refuses (height limit) leaves the world as it was.
 * Only the inputs a model needs are prepared — depth for subtract and
 * diffusion, base heights for refill and deferred — and only its scratch
 * allocated, so a subtract scene holds no jump-flooding or displacement
 * buffers at all.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The tick's windows: entry i of every array is window i. They grow
 * together (one capacity); jobs and status are contiguous because the
 * backend runs the whole batch in one call, dirty and dirty_window because
 * the report hands them out. */
typedef struct engine_batch {
    int64_t capacity; /* windows */
    world_rect *windows;
    sim_window_job *jobs;
    int *status;
    int64_t *offsets; /* where each window starts in the packed cells */
    world_rect *dirty;
    int *dirty_window;
    world_rect *state_dirty; /* where the per-cell state (soil, compaction memory) changed */
    int count;
    int64_t cells; /* all windows' cells */
    int64_t refs;  /* collider references of all windows */
} engine_batch;

struct sim_engine {
    world *world;
    sim_params params;
    sim_backend *backend;
    int margin_cells;
    thread_owner owner; /* the sim thread, from the first tick */
    engine_batch batch;
    /* reusable scratch, grown to the largest tick seen */
    world_rect *footprints; /* per collider */
    int64_t footprint_capacity;
    sim_collider *window_colliders;
    int64_t window_collider_capacity;
    int32_t *heights, *before; /* all windows of a tick, packed */
    int64_t cell_capacity;
    int32_t *bottom; /* allocated only when the engine casts depth */
    int64_t bottom_capacity;
    /* the non-persson models */
    int32_t *model_scratch;
    int64_t model_scratch_capacity; /* int32 */
    int32_t *base;                  /* base heights of the packed windows (models that need them) */
    int64_t base_capacity;
    int64_t refill_q16_accumulated; /* subtract: refill's fraction carried over */
    world_rect *refilling;          /* subtract: windows with cells still below base */
    int refilling_count;
    int64_t refilling_capacity;
    sim_footprint *footprints_out; /* decals: the last tick's events */
    int64_t footprint_out_capacity;
    int warned_cpu_model; /* "runs on the CPU" said once */
    /* Per-cell materials and compaction memory (sim_engine_set_ground). */
    ground *ground;        /* not owned; NULL: one material, the params */
    uint8_t *material_ids; /* packed like the heights; only if not uniform */
    int64_t material_ids_capacity;
    uint16_t *compaction; /* likewise; only if some material compacts */
    int64_t compaction_capacity;
    /* the memory itself is the world's (world_compaction_*): as gathered (to
     * find what changed, and to undo a tick the store cannot log) and as the
     * backend left it, widened to the world's int32 */
    int32_t *compaction_before, *compaction_after;
    int64_t compaction_before_capacity, compaction_after_capacity;
    /* bekker: the per-cell soil state's packed windows (the state itself is
     * the world's: world_soil.c) as the model leaves them and as gathered (to
     * find what changed, and to undo a tick the store cannot log), a contact
     * per collider reference of the batch and per collider */
    int32_t *soil_state, *soil_before;
    int64_t soil_state_capacity, soil_before_capacity;
    int32_t *carry_copy; /* load-driven colliders' search: a window's heights + state */
    int64_t carry_copy_capacity;
    int *window_collider_source; /* per reference: the collider's index in the tick */
    int64_t window_collider_source_capacity;
    sim_contact *job_contacts;
    int64_t job_contacts_capacity;
    sim_contact *contacts;
    int64_t contacts_capacity;
    sim_engine_stats stats;
};

sim_engine *sim_engine_create(world *w, const sim_params *p, sim_backend *backend, int margin_cells,
                              error_text *err)
{
    if (margin_cells < 0 || margin_cells > 4096) {
        error_set(err, "active_margin_cells: must be in [0, 4096] (got %d)", margin_cells);
        return NULL;
    }
    sim_engine *e = calloc(1, sizeof *e);
    if (!e) {
        error_set(err, "sim: out of memory for the engine");
        return NULL;
    }
    e->world = w;
    e->params = *p;
    e->backend = backend;
    e->margin_cells = margin_cells;
    if (p->model == SIM_MODEL_BEKKER && world_layer_enable(w, WORLD_LAYER_SOIL) != 0) {
        free(e);
        error_set(err, "sim: out of memory for the soil state");
        return NULL;
    }
    return e;
}

void sim_engine_claim(sim_engine *e)
{
    thread_owner_claim(&e->owner, "sim");
}

void sim_engine_destroy(sim_engine *e)
{
    if (!e)
        return;
    engine_batch *b = &e->batch;
    free(b->windows);
    free(b->jobs);
    free(b->status);
    free(b->offsets);
    free(b->dirty);
    free(b->dirty_window);
    free(b->state_dirty);
    free(e->material_ids);
    free(e->compaction);
    free(e->compaction_before);
    free(e->compaction_after);
    free(e->footprints);
    free(e->window_colliders);
    free(e->heights);
    free(e->before);
    free(e->bottom);
    free(e->model_scratch);
    free(e->base);
    free(e->refilling);
    free(e->footprints_out);
    free(e->soil_state);
    free(e->soil_before);
    free(e->carry_copy);
    free(e->window_collider_source);
    free(e->job_contacts);
    free(e->contacts);
    free(e);
}

void sim_engine_set_ground(sim_engine *e, ground *g)
{
    /* The uniform path only when it computes the same: one material whose
     * row is the params' own (and, for bekker, whose soil is), and no
     * compaction memory. */
    ground_material_row own = sim_material_row_from_params(&e->params, 0);
    int same = g && g->uniform && !g->uses_compaction &&
               memcmp(&g->table.rows[0], &own, sizeof own) == 0 &&
               (e->params.model != SIM_MODEL_BEKKER ||
                memcmp(&g->table.soils[0], &e->params.soil, sizeof e->params.soil) == 0);
    e->ground = g && !same ? g : NULL;
    /* the world keeps the memory; a failure here is retried by the first
     * scatter that has something to keep */
    if (e->ground && e->ground->uses_compaction)
        (void)world_layer_enable(e->world, WORLD_LAYER_COMPACTION);
}

int64_t sim_engine_soil_compacted(const sim_engine *e)
{
    return world_layer_sum(e->world, WORLD_LAYER_SOIL, SIM_SOIL_COMPACTED);
}

void sim_engine_soil_cell(const sim_engine *e, int x, int y, int32_t *out)
{
    world_layer_cell(e->world, WORLD_LAYER_SOIL, x, y, out);
}

world *sim_engine_world(const sim_engine *e)
{
    return e->world;
}

sim_backend *sim_engine_backend(const sim_engine *e)
{
    return e->backend;
}

void sim_engine_get_stats(const sim_engine *e, sim_engine_stats *out)
{
    *out = e->stats;
    out->per_cell_materials = e->ground != NULL;
    out->refilling_windows = e->refilling_count;
}

world_rect sim_engine_window(const sim_engine *e, int i, const int32_t **before,
                             const int32_t **after)
{
    *before = e->before + e->batch.offsets[i];
    *after = e->heights + e->batch.offsets[i];
    return e->batch.windows[i];
}

void sim_engine_undo_state(sim_engine *e)
{
    const engine_batch *b = &e->batch;
    /* back to what was gathered: the tiles exist, nothing is allocated */
    for (int i = 0; i < b->count; i++) {
        if (b->status[i] != SIM_WINDOW_OK)
            continue;
        if (b->jobs[i].soil_state)
            (void)world_layer_scatter(e->world, WORLD_LAYER_SOIL, b->windows[i],
                                      e->soil_before + b->offsets[i] * SIM_SOIL_STATE_FIELDS);
        if (b->jobs[i].compaction)
            (void)world_layer_scatter(e->world, WORLD_LAYER_COMPACTION, b->windows[i],
                                      e->compaction_before + b->offsets[i]);
    }
}

uint64_t sim_stage_memory_total(const sim_stage_memory *m)
{
    uint64_t total = 0;
#define SIM_STAGE_MEMORY_ADD(name) total += m->name;
    SIM_MEMORY_STAGE_LIST(SIM_STAGE_MEMORY_ADD)
#undef SIM_STAGE_MEMORY_ADD
    return total;
}

/* ---- plan ---- */

/* Room for `count` windows in every array of the batch. */
static int batch_reserve(engine_batch *b, int64_t count)
{
    int64_t cap = b->capacity;
#define BATCH_GROW(array)                                                                          \
    (cap = b->capacity, array_grow((void **)&b->array, &cap, count, sizeof *b->array))
    if (BATCH_GROW(windows) != 0 || BATCH_GROW(jobs) != 0 || BATCH_GROW(status) != 0 ||
        BATCH_GROW(offsets) != 0 || BATCH_GROW(dirty) != 0 || BATCH_GROW(dirty_window) != 0 ||
        BATCH_GROW(state_dirty) != 0)
        return -1;
#undef BATCH_GROW
    b->capacity = cap;
    return 0;
}

/* The tick's windows into the batch; cells and collider references counted. */
static int tick_plan(sim_engine *e, const sim_collider *colliders, int collider_count,
                     int refilling)
{
    engine_batch *b = &e->batch;
    if (array_grow((void **)&e->footprints, &e->footprint_capacity, collider_count + 1,
                   sizeof *e->footprints) != 0)
        return -1;
    world_rect *windows = NULL;
    int count = 0;
    if (sim_plan_windows(e->world, &e->params, colliders, collider_count, e->margin_cells,
                         e->refilling, refilling ? e->refilling_count : 0, e->footprints, &windows,
                         &count) != 0)
        return -1;
    if (batch_reserve(b, count + 1) != 0) {
        free(windows);
        return -1;
    }
    memcpy(b->windows, windows, (size_t)count * sizeof *windows);
    free(windows);
    b->count = count;
    b->cells = 0;
    b->refs = 0;
    for (int i = 0; i < count; i++) {
        b->cells += (int64_t)b->windows[i].w * b->windows[i].h;
        for (int c = 0; c < collider_count; c++)
            b->refs +=
                e->footprints[c].w > 0 && world_rects_overlap(e->footprints[c], b->windows[i]);
    }
    return 0;
}

/* ---- gather ---- */

/* The packed per-cell arrays for the batch, only those this scene reads. */
static int tick_reserve_cells(sim_engine *e, int persson, int collider_count)
{
    int64_t need = e->batch.cells + 1, cap = e->cell_capacity;
    if (array_grow((void **)&e->heights, &cap, need, sizeof *e->heights) != 0 ||
        (cap = e->cell_capacity,
         array_grow((void **)&e->before, &cap, need, sizeof *e->before) != 0))
        return -1;
    e->cell_capacity = cap;
    if (e->ground && !e->ground->uniform &&
        array_grow((void **)&e->material_ids, &e->material_ids_capacity, need,
                   sizeof *e->material_ids) != 0)
        return -1;
    if (e->ground && e->ground->uses_compaction &&
        (array_grow((void **)&e->compaction, &e->compaction_capacity, need,
                    sizeof *e->compaction) != 0 ||
         array_grow((void **)&e->compaction_before, &e->compaction_before_capacity, need,
                    sizeof *e->compaction_before) != 0 ||
         array_grow((void **)&e->compaction_after, &e->compaction_after_capacity, need,
                    sizeof *e->compaction_after) != 0))
        return -1;
    /* depth on the engine's side only where something reads it */
    if (!persson && sim_model_needs_depth(e->params.model) &&
        array_grow((void **)&e->bottom, &e->bottom_capacity, need, sizeof *e->bottom) != 0)
        return -1;
    if (!persson && sim_model_needs_base(&e->params) &&
        array_grow((void **)&e->base, &e->base_capacity, need, sizeof *e->base) != 0)
        return -1;
    if (e->params.model == SIM_MODEL_BEKKER &&
        (array_grow((void **)&e->soil_state, &e->soil_state_capacity, need * SIM_SOIL_STATE_FIELDS,
                    sizeof *e->soil_state) != 0 ||
         array_grow((void **)&e->soil_before, &e->soil_before_capacity,
                    need * SIM_SOIL_STATE_FIELDS, sizeof *e->soil_before) != 0 ||
         array_grow((void **)&e->window_collider_source, &e->window_collider_source_capacity,
                    e->batch.refs + 1, sizeof *e->window_collider_source) != 0 ||
         array_grow((void **)&e->job_contacts, &e->job_contacts_capacity, e->batch.refs + 1,
                    sizeof *e->job_contacts) != 0 ||
         array_grow((void **)&e->contacts, &e->contacts_capacity, collider_count + 1,
                    sizeof *e->contacts) != 0))
        return -1;
    return array_grow((void **)&e->window_colliders, &e->window_collider_capacity,
                      e->batch.refs + 1, sizeof *e->window_colliders);
}

/* subtract: whole units of refill this tick, the fraction carried to the next. */
static int32_t tick_refill_units(sim_engine *e)
{
    e->refill_q16_accumulated += e->params.refill_q16_per_tick;
    int64_t units = e->refill_q16_accumulated >> 16;
    e->refill_q16_accumulated &= 0xffff;
    return units > WORLD_HEIGHT_MAX ? WORLD_HEIGHT_MAX : (int32_t)units;
}

/* The ground's layers of one window, packed like its heights. */
static void gather_ground(sim_engine *e, sim_window_job *job, int64_t offset)
{
    if (!e->ground)
        return;
    job->materials = &e->ground->table;
    if (!e->ground->uniform) {
        job->material_ids = e->material_ids + offset;
        ground_gather_ids(e->ground, job->rect, e->material_ids + offset);
    }
    if (e->ground->uses_compaction) {
        int32_t *before = e->compaction_before + offset;
        int64_t n = (int64_t)job->rect.w * job->rect.h;
        job->compaction = e->compaction + offset;
        world_layer_gather(e->world, WORLD_LAYER_COMPACTION, job->rect, before);
        for (int64_t k = 0; k < n; k++) /* recovered memory is checked: [0, 65535] */
            job->compaction[k] = (uint16_t)before[k];
    }
}

/* The colliders over window r into job. */
static void gather_colliders(sim_engine *e, const sim_collider *colliders, int collider_count,
                             sim_window_job *job, int *ref)
{
    job->colliders = e->window_colliders + *ref;
    if (e->params.model == SIM_MODEL_BEKKER)
        job->contacts = e->job_contacts + *ref;
    for (int c = 0; c < collider_count; c++) {
        if (e->footprints[c].w == 0 || !world_rects_overlap(e->footprints[c], job->rect))
            continue;
        if (e->params.model == SIM_MODEL_BEKKER)
            e->window_collider_source[*ref] = c;
        e->window_colliders[(*ref)++] = colliders[c];
        job->collider_count++;
    }
}

/* A job per window: heights (and their copy), ground layers, colliders and
 * base heights. */
static void tick_gather(sim_engine *e, const sim_collider *colliders, int collider_count,
                        int32_t refill_units, int needs_base)
{
    world *w = e->world;
    engine_batch *b = &e->batch;
    int64_t offset = 0;
    int ref = 0;
    for (int i = 0; i < b->count; i++) {
        world_rect r = b->windows[i];
        sim_window_job *job = &b->jobs[i];
        memset(job, 0, sizeof *job);
        b->offsets[i] = offset;
        job->rect = r;
        job->cell_size_m = w->cell_size_m;
        job->units_per_m = w->units_per_m;
        job->heights = e->heights + offset;
        job->world = w;
        world_gather_window(w, r, job->heights);
        gather_ground(e, job, offset);
        if (e->params.model == SIM_MODEL_BEKKER) {
            job->soil_state = e->soil_state + offset * SIM_SOIL_STATE_FIELDS;
            world_layer_gather(w, WORLD_LAYER_SOIL, r, job->soil_state);
            memcpy(e->soil_before + offset * SIM_SOIL_STATE_FIELDS, job->soil_state,
                   (size_t)r.w * r.h * SIM_SOIL_STATE_FIELDS * sizeof(int32_t));
        }
        memcpy(e->before + offset, job->heights, (size_t)r.w * r.h * sizeof(int32_t));
        gather_colliders(e, colliders, collider_count, job, &ref);
        if (needs_base && world_base_fill_rect(w, r, e->base + offset) == 0)
            job->base_heights = e->base + offset;
        job->refill_units = refill_units;
        offset += (int64_t)r.w * r.h;
    }
}

/* ---- depth ---- */

/* The depth the engine casts on the CPU for the models that read it
 * (timed as the depth stage); the persson models get theirs from the
 * backend, which computes the same fixed-point depth on either backend. */
static void tick_depth(sim_engine *e, int persson, sim_tick_report *report)
{
    if (persson || !sim_model_needs_depth(e->params.model))
        return;
    double t0 = time_now_ms();
    engine_batch *b = &e->batch;
    for (int i = 0; i < b->count; i++) {
        sim_window_job *job = &b->jobs[i];
        int32_t *bottom = e->bottom + b->offsets[i];
        sim_window_depth(job, bottom);
        job->bottom_override = bottom;
    }
    report->times.depth += time_now_ms() - t0;
}

/* ---- model ---- */

/* bekker: each load-driven collider of window i at the height where the soil
 * carries its load, in the window's collider order, before the window deforms. */
static void carry_loads(sim_engine *e, int i)
{
    sim_window_job *job = &e->batch.jobs[i];
    sim_collider *cols = e->window_colliders + (job->colliders - e->window_colliders);
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    int32_t top = job->heights[0];
    for (int64_t k = 1; k < n; k++)
        top = job->heights[k] > top ? job->heights[k] : top;
    for (int k = 0; k < job->collider_count; k++) {
        if (!(cols[k].load_n > 0.0))
            continue;
        /* the pose z at which the collider's lowest point is at the floor, and
         * one at which it is above every cell (carrying nothing) */
        int32_t reach = sim_units_clamped(collider_reach(cols[k].geometry), job->units_per_m) + 2;
        int64_t lo = (int64_t)e->params.floor + reach, hi = (int64_t)top + reach + 1;
        if (lo > WORLD_HEIGHT_MAX || hi > WORLD_HEIGHT_MAX)
            continue; /* out of range: left as posed (the window refuses it) */
        sim_bekker_carry(&e->params, job, &cols[k], cols[k].load_n, (int32_t)lo, (int32_t)hi,
                         e->model_scratch, e->carry_copy, e->carry_copy + n);
    }
}

/* The tick's windows through a non-persson model on the CPU. */
static int run_model_windows(sim_engine *e, sim_tick_report *report, error_text *err)
{
    const sim_params *p = &e->params;
    engine_batch *b = &e->batch;
    int64_t largest = 0;
    for (int i = 0; i < b->count; i++) {
        int64_t n = (int64_t)b->windows[i].w * b->windows[i].h;
        if (n > largest)
            largest = n;
    }
    int64_t need = sim_model_scratch_cells(p->model, largest);
    if (array_grow((void **)&e->model_scratch, &e->model_scratch_capacity, need + 1,
                   sizeof *e->model_scratch) != 0 ||
        (p->model == SIM_MODEL_DECALS &&
         array_grow((void **)&e->footprints_out, &e->footprint_out_capacity, b->refs + 1,
                    sizeof *e->footprints_out) != 0) ||
        (p->model == SIM_MODEL_BEKKER &&
         array_grow((void **)&e->carry_copy, &e->carry_copy_capacity,
                    largest * (1 + SIM_SOIL_STATE_FIELDS) + 1, sizeof *e->carry_copy) != 0)) {
        error_set(err, "sim: out of memory for the %s model's scratch", sim_model_name(p->model));
        return -1;
    }
    for (int i = 0; i < b->count; i++) {
        sim_window_job *job = &b->jobs[i];
        double t0 = time_now_ms();
        if (p->model == SIM_MODEL_DECALS) {
            b->status[i] = SIM_WINDOW_OK;
            report->footprint_count += sim_decals_window(
                p, job, e->model_scratch, e->footprints_out + report->footprint_count,
                (int)e->footprint_out_capacity - report->footprint_count);
        } else {
            if (p->model == SIM_MODEL_BEKKER)
                carry_loads(e, i);
            b->status[i] = sim_model_window(p, job, e->model_scratch);
        }
        report->model_ms += time_now_ms() - t0;
    }
    report->footprints = e->footprints_out;
    return 0;
}

/* The persson models on the backend as one batch, the others on the CPU. */
static int tick_model(sim_engine *e, int persson, sim_tick_report *report, error_text *err)
{
    engine_batch *b = &e->batch;
    if (b->count == 0)
        return 0;
    if (persson)
        return e->backend->run_windows(e->backend, &e->params, b->jobs, b->count, b->status,
                                       &report->times, err);
    if (!e->warned_cpu_model && strcmp(e->backend->name, "cpu") != 0) {
        log_info("sim: model %s has no %s version; it runs on the CPU",
                 sim_model_name(e->params.model), e->backend->name);
        e->warned_cpu_model = 1;
    }
    return run_model_windows(e, report, err);
}

/* ---- scatter ---- */

/* Tight bounding box of the cells that differ (`fields` int32 per cell); w
 * == 0 when none does. */
static world_rect diff_rect(world_rect r, const int32_t *before, const int32_t *after, int fields)
{
    int x0 = r.w, y0 = r.h, x1 = -1, y1 = -1;
    size_t cell = (size_t)fields * sizeof *before;
    for (int y = 0; y < r.h; y++) {
        const int32_t *a = before + (int64_t)y * r.w * fields,
                      *b = after + (int64_t)y * r.w * fields;
        if (memcmp(a, b, (size_t)r.w * cell) == 0)
            continue;
        /* the row differs: its first and last differing cells, found from
         * each end (a memcmp a cell across the whole row was 2 % of a
         * driven world's tick, issue 32) */
        int first = 0, last = r.w - 1;
        while (memcmp(a + (int64_t)first * fields, b + (int64_t)first * fields, cell) == 0)
            first++;
        while (memcmp(a + (int64_t)last * fields, b + (int64_t)last * fields, cell) == 0)
            last--;
        if (first < x0)
            x0 = first;
        if (last > x1)
            x1 = last;
        if (y < y0)
            y0 = y;
        y1 = y;
    }
    if (x1 < 0)
        return (world_rect){0, 0, 0, 0};
    return (world_rect){r.x + x0, r.y + y0, x1 - x0 + 1, y1 - y0 + 1};
}

/* Window i's compaction memory back into the world where it changed; *c:
 * that rectangle (w 0: none). 0, or -1 out of memory. */
static int scatter_compaction(sim_engine *e, int i, world_rect *c, error_text *err)
{
    engine_batch *b = &e->batch;
    world_rect r = b->windows[i];
    int64_t offset = b->offsets[i], n = (int64_t)r.w * r.h;
    int32_t *after = e->compaction_after + offset;
    for (int64_t k = 0; k < n; k++)
        after[k] = b->jobs[i].compaction[k];
    *c = diff_rect(r, e->compaction_before + offset, after, 1);
    if (c->w > 0 && world_layer_scatter(e->world, WORLD_LAYER_COMPACTION, r, after) != 0) {
        error_set(err, "sim: out of memory for the compaction memory");
        return -1;
    }
    return 0;
}

/* Accepted windows back into the world, with their per-cell state; the
 * report's dirty rectangles. */
static int tick_scatter(sim_engine *e, sim_tick_report *report, error_text *err)
{
    engine_batch *b = &e->batch;
    report->dirty = b->dirty;
    report->dirty_window = b->dirty_window;
    report->state_dirty = b->state_dirty;
    for (int i = 0; i < b->count; i++) {
        world_rect r = b->windows[i];
        int64_t offset = b->offsets[i];
        if (b->status[i] != SIM_WINDOW_OK) {
            report->refused_windows++;
            continue;
        }
        world_rect c = {0, 0, 0, 0}, s = {0, 0, 0, 0};
        if (b->jobs[i].compaction && scatter_compaction(e, i, &c, err) != 0)
            return -1;
        if (b->jobs[i].soil_state) {
            s = diff_rect(r, e->soil_before + offset * SIM_SOIL_STATE_FIELDS, b->jobs[i].soil_state,
                          SIM_SOIL_STATE_FIELDS);
            if (s.w > 0 &&
                world_layer_scatter(e->world, WORLD_LAYER_SOIL, r, b->jobs[i].soil_state) != 0) {
                error_set(err, "sim: out of memory for the soil state");
                return -1;
            }
        }
        /* one rectangle a window at most: state_dirty has room for one each */
        if (c.w > 0 || s.w > 0)
            b->state_dirty[report->state_dirty_count++] = world_rect_union(c, s);
        world_rect d = diff_rect(r, e->before + offset, e->heights + offset, 1);
        if (d.w > 0) {
            world_scatter_window(e->world, r, e->heights + offset);
            if (e->backend->window_scattered)
                e->backend->window_scattered(e->backend, i, e->world, r);
            b->dirty_window[report->dirty_count] = i;
            b->dirty[report->dirty_count++] = d;
        }
    }
    return 0;
}

/* ---- contacts (bekker) ---- */

/* A wheel's (cylinder's) slip: its axis is the local Y axis, it rolls along
 * axis x up; 1 - v/(wR) while driving (wR >= v), wR/v - 1 while skidding. */
static double contact_slip(const sim_contact *c, const sim_collider *col)
{
    if (col->geometry->shape != COLLIDER_CYLINDER)
        return 0.0;
    vec3d axis = quat_rotate(col->pose.orientation, (vec3d){0.0, 1.0, 0.0});
    double fx = axis.y, fy = -axis.x, len = sqrt(fx * fx + fy * fy);
    if (!(len > 1e-9))
        return 0.0; /* axis upright: not rolling */
    double v = (c->velocity[0] * fx + c->velocity[1] * fy) / len;
    double wr = (c->angular[0] * axis.x + c->angular[1] * axis.y + c->angular[2] * axis.z) *
                col->geometry->radius;
    if (wr == 0.0 && v == 0.0)
        return 0.0;
    return fabs(wr) >= fabs(v) ? 1.0 - v / wr : wr / v - 1.0;
}

/* The soil's push per collider: the accepted windows' contacts added in plan
 * order — a fixed order, so identical run to run and for any thread count. */
static void tick_contacts(sim_engine *e, const sim_collider *colliders, int collider_count,
                          sim_tick_report *report)
{
    if (e->params.model != SIM_MODEL_BEKKER)
        return;
    engine_batch *b = &e->batch;
    for (int c = 0; c < collider_count; c++) {
        memset(&e->contacts[c], 0, sizeof e->contacts[c]);
        e->contacts[c].collider_id = colliders[c].id;
        e->contacts[c].pose_z_m = colliders[c].pose.position.z;
    }
    for (int i = 0; i < b->count; i++) {
        const sim_window_job *job = &b->jobs[i];
        if (b->status[i] != SIM_WINDOW_OK)
            continue;
        int64_t ref = job->colliders - e->window_colliders;
        for (int k = 0; k < job->collider_count; k++) {
            sim_contact *to = &e->contacts[e->window_collider_source[ref + k]];
            sim_bekker_contact_merge(to, &job->contacts[k]);
            to->pose_z_m = job->colliders[k].pose.position.z; /* a load-driven one's: found */
        }
    }
    for (int c = 0; c < collider_count; c++)
        e->contacts[c].slip = contact_slip(&e->contacts[c], &colliders[c]);
    report->contacts = e->contacts;
    report->contact_count = collider_count;
}

/* ---- commit ---- */

/* subtract: the windows that still hold cells below base refill next tick. */
static int keep_refilling(sim_engine *e)
{
    engine_batch *b = &e->batch;
    e->refilling_count = 0;
    for (int i = 0; i < b->count; i++) {
        world_rect r = b->windows[i];
        int64_t n = (int64_t)r.w * r.h, offset = b->offsets[i];
        const int32_t *now =
            b->status[i] == SIM_WINDOW_OK ? e->heights + offset : e->before + offset;
        int below = 0;
        for (int64_t k = 0; k < n && !below; k++)
            below = now[k] < e->base[offset + k];
        if (!below)
            continue;
        if (array_grow((void **)&e->refilling, &e->refilling_capacity, e->refilling_count + 1,
                       sizeof *e->refilling) != 0)
            return -1;
        e->refilling[e->refilling_count++] = r;
    }
    return 0;
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
        (uint64_t)e->batch.capacity * (sizeof(world_rect) * 2 + sizeof(sim_window_job) +
                                       sizeof(int) + sizeof(int64_t) + sizeof(int)) +
        (uint64_t)e->footprint_capacity * sizeof(world_rect) +
        (uint64_t)e->window_collider_capacity * sizeof(sim_collider);
    m->depth += (uint64_t)e->bottom_capacity * sizeof(int32_t);
    m->model = (uint64_t)e->model_scratch_capacity * sizeof(int32_t) +
               (uint64_t)e->base_capacity * sizeof(int32_t) +
               (uint64_t)e->refilling_capacity * sizeof(world_rect) +
               (uint64_t)e->footprint_out_capacity * sizeof(sim_footprint) +
               (uint64_t)(e->soil_state_capacity + e->soil_before_capacity) * sizeof(int32_t) +
               (uint64_t)e->job_contacts_capacity * sizeof(sim_contact) +
               (uint64_t)e->contacts_capacity * sizeof(sim_contact) +
               (uint64_t)e->window_collider_source_capacity * sizeof(int);
}

static void memory_peak(sim_stage_memory *peak, const sim_stage_memory *now)
{
#define SIM_STAGE_MEMORY_PEAK(name)                                                                \
    if (now->name > peak->name)                                                                    \
        peak->name = now->name;
    SIM_MEMORY_STAGE_LIST(SIM_STAGE_MEMORY_PEAK)
#undef SIM_STAGE_MEMORY_PEAK
}

/* Peaks, subtract's refilling windows and the memory held, by stage. */
static int tick_commit(sim_engine *e, int refilling, sim_tick_report *report)
{
    sim_engine_stats *s = &e->stats;
    report->window_count = e->batch.count;
    report->active_cells = e->batch.cells;
    if (e->batch.cells > s->peak_active_cells)
        s->peak_active_cells = e->batch.cells;
    if (refilling && keep_refilling(e) != 0)
        return -1;
    engine_memory(e, &s->memory);
    memory_peak(&s->peak_memory, &s->memory);
    uint64_t scratch = sim_stage_memory_total(&s->memory);
    if (scratch > s->peak_scratch_bytes)
        s->peak_scratch_bytes = scratch;
    return 0;
}

/* ---- the tick ---- */

int sim_engine_tick(sim_engine *e, const sim_collider *colliders, int collider_count,
                    sim_tick_report *report, error_text *err)
{
    if (!e->owner.tid)
        thread_owner_claim(&e->owner, "sim");
    THREAD_OWNED(&e->owner);
    memset(report, 0, sizeof *report);
    double t_start = time_now_ms();
    int persson = sim_model_is_persson(e->params.model);
    int refilling = e->params.model == SIM_MODEL_SUBTRACT && e->params.refill_q16_per_tick > 0;
    if (tick_plan(e, colliders, collider_count, refilling) != 0 ||
        tick_reserve_cells(e, persson, collider_count) != 0)
        goto oom;
    int32_t refill_units = refilling ? tick_refill_units(e) : 0;
    tick_gather(e, colliders, collider_count, refill_units,
                !persson && sim_model_needs_base(&e->params));
    report->gather_scatter_ms += time_now_ms() - t_start;

    tick_depth(e, persson, report);
    if (tick_model(e, persson, report, err) != 0)
        return -1;

    double t_scatter = time_now_ms();
    if (tick_scatter(e, report, err) != 0)
        return -1;
    tick_contacts(e, colliders, collider_count, report);
    report->gather_scatter_ms += time_now_ms() - t_scatter;
    if (tick_commit(e, refilling, report) != 0)
        goto oom;
    return 0;
oom:
    error_set(err, "sim: out of memory planning %d colliders", collider_count);
    return -1;
}
