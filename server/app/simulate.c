/*
 * simulate.c: `terrad simulate` — runs a scene's scripted colliders for N
 * ticks on one backend, offline, and prints one JSON object: volume before
 * and after (Σh, int64), per-stage mean and p99 milliseconds, mean active
 * cells, the largest slope excess left over the angle of repose, memory per
 * world cell and per active cell, and peak RSS. The tests and `make bench`
 * are built on it. `--model M` runs the scene's colliders through another
 * deformation model (docs/models.md); the output then says which model ran,
 * whether it ran on the CPU for want of a GL version, the scratch memory
 * held per stage, and for decals the number of footprint events.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "host/host.h"
#include "scene/scene.h"

typedef struct simulate_options {
    const char *scene_path;
    long ticks;
    const char *backend;
    const char *method;
    const char *model;
    const char *metric;
    const char *out_path;
    long threads;
} simulate_options;

static const cli_option simulate_table[] = {
    {"scene", "FILE", "scene JSON with scripted colliders (default: embedded scene)",
     CLI_AT_STRING(simulate_options, scene_path)},
    {"ticks", "N", "number of ticks to run (required)",
     CLI_AT_LONG(simulate_options, ticks, 0, 100000000)},
    {"backend", "auto|gl|cpu",
     "default auto: gl on a hardware GPU, cpu where GL is software\n"
     "(llvmpipe) or missing",
     CLI_AT_STRING(simulate_options, backend)},
    {"method", "M", "iterative | ssbo | multi (overrides the scene's material)",
     CLI_AT_STRING(simulate_options, method)},
    {"model", "M",
     "persson-iterative | persson-ssbo | persson-multi | subtract |\n"
     "deferred | diffusion | sumner | decals | bekker (overrides the scene's model)",
     CLI_AT_STRING(simulate_options, model)},
    {"metric", "K", "euclidean | manhattan | chebyshev (overrides the scene's)",
     CLI_AT_STRING(simulate_options, metric)},
    {"out", "FILE", "write the final heights: little-endian int32, row-major",
     CLI_AT_STRING(simulate_options, out_path)},
    {"threads", "N",
     "threads of the CPU twin (default: the machine's cores);\n"
     "heights do not depend on it",
     CLI_AT_LONG(simulate_options, threads, 1, SIM_THREADS_MAX)},
    {0},
};

static const char simulate_usage[] = "--ticks N [options]";

void app_simulate_usage(FILE *out)
{
    cli_print_help(out, "simulate", simulate_usage, simulate_table);
}

static cli_result parse_options(int argc, char **argv, simulate_options *o)
{
    memset(o, 0, sizeof *o);
    o->ticks = -1;
    o->backend = "auto";
    cli_result r = cli_parse("simulate", simulate_usage, simulate_table, argc, argv, o, NULL);
    if (r == CLI_OK && o->ticks < 0) {
        fprintf(stderr, "terrad simulate: --ticks N is required\n");
        return CLI_ERROR;
    }
    if (r == CLI_OK)
        sim_set_threads((int)o->threads); /* 0 (not given): the machine's cores */
    return r;
}

/* Heights as little-endian int32, row-major: the format `--out` promises.
 * Written a band of rows at a time, so a tiled world is never made dense. */
static int write_heights(const char *path, const world *w)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    int band = 64;
    int32_t *rows = malloc((size_t)w->width * band * sizeof *rows);
    int bad = !rows;
    for (int y = 0; !bad && y < w->height; y += band) {
        world_rect r = {0, y, w->width, y + band <= w->height ? band : w->height - y};
        world_gather_window(w, r, rows);
        size_t n = (size_t)r.w * r.h;
        bad = fwrite(rows, sizeof(int32_t), n, f) != n;
    }
    free(rows);
    bad |= fclose(f) != 0;
    return bad ? -1 : 0;
}

/* The steepest slope's excess over the repose threshold, in bands of rows
 * that overlap by one row so every neighbour pair is seen. A world above
 * SLOPE_SCAN_CELLS_MAX cells is scanned tile by tile over the stored
 * (written) tiles only, each with a ring of one cell so the pairs across its
 * edges are seen: the base beyond was never touched by a tick. (Their
 * bounding box is not enough: two colliders at opposite corners of a 65,536²
 * world made it 2.7e9 cells, issue 12.) */
#define SLOPE_SCAN_CELLS_MAX ((int64_t)1 << 26)

typedef struct slope_scan {
    const sim_params *p;
    const world *w;
    const ground *g;
    int32_t *rows;
    uint8_t *ids;
    size_t capacity; /* cells in rows (and ids) */
    int64_t worst;
    int64_t cells; /* scanned, reported: the tiles' cells, not their box */
    int failed;
} slope_scan;

/* The excess over rect r, in bands of 64 rows (+1 overlapping). */
static void scan_rect(slope_scan *sc, world_rect r)
{
    int band = 64;
    size_t need = (size_t)r.w * (size_t)(band + 1);
    if (need > sc->capacity) {
        int32_t *rows = realloc(sc->rows, need * sizeof *rows);
        if (rows)
            sc->rows = rows;
        uint8_t *ids = sc->g && !sc->g->uniform ? realloc(sc->ids, need) : sc->ids;
        if (ids)
            sc->ids = ids;
        if (!rows || (sc->g && !sc->g->uniform && !ids)) {
            sc->failed = 1;
            return;
        }
        sc->capacity = need;
    }
    sc->cells += (int64_t)r.w * r.h;
    for (int y = r.y; y < r.y + r.h; y += band) {
        int h = y + band + 1 <= r.y + r.h ? band + 1 : r.y + r.h - y;
        world_rect band_rect = {r.x, y, r.w, h};
        world_gather_window(sc->w, band_rect, sc->rows);
        int64_t e;
        if (sc->g) {
            if (!sc->g->uniform)
                ground_gather_ids(sc->g, band_rect, sc->ids);
            e = sim_max_slope_excess_materials(&sc->g->table, sc->g->uniform ? NULL : sc->ids, r.w,
                                               h, sc->rows);
        } else {
            e = sim_max_slope_excess(sc->p, r.w, h, sc->rows);
        }
        if (e > sc->worst)
            sc->worst = e;
    }
}

static void scan_tile(void *ctx, int tx, int ty, world_rect cells, uint64_t generation)
{
    (void)tx, (void)ty, (void)generation;
    slope_scan *sc = ctx;
    world_rect r = {cells.x - 1, cells.y - 1, cells.w + 2, cells.h + 2};
    world_clip_rect(sc->w, &r);
    if (!sc->failed && r.w > 0 && r.h > 0)
        scan_rect(sc, r);
}

/* With per-cell materials (g non-NULL) each column is held to its own material's repose. */
static int64_t max_slope_excess(const sim_params *p, const world *w, const ground *g,
                                const char **scope, int64_t *cells)
{
    slope_scan sc = {.p = p, .w = w, .g = g};
    if ((int64_t)w->width * w->height > SLOPE_SCAN_CELLS_MAX) {
        *scope = "stored_tiles";
        world_for_each_stored_tile(w, scan_tile, &sc);
    } else {
        *scope = "world";
        scan_rect(&sc, (world_rect){0, 0, w->width, w->height});
    }
    free(sc.rows);
    free(sc.ids);
    *cells = sc.cells;
    return sc.failed ? -1 : sc.worst;
}

typedef struct stage_series {
    const char *name;
    stat_series series;
} stage_series;

typedef struct simulate_totals {
    stage_series *stages;
    int stage_count;
    double active_sum;
    long refused;
    long footprint_events; /* decals */
} simulate_totals;

static void record_tick(void *ctx, long tick, const sim_tick_report *report, double tick_ms)
{
    (void)tick;
    simulate_totals *t = ctx;
#define STAGE_VALUE(name) report->times.name,
    double values[] = {SIM_STAGE_LIST(STAGE_VALUE) report->model_ms, report->gather_scatter_ms,
                       tick_ms};
#undef STAGE_VALUE
    for (int s = 0; s < t->stage_count; s++)
        stat_series_add(&t->stages[s].series, values[s]);
    t->active_sum += (double)report->active_cells;
    t->refused += report->refused_windows;
    t->footprint_events += report->footprint_count;
}

int app_run_scene_ticks(const scene *sc, sim_engine *engine, long ticks, app_tick_observer observe,
                        void *ctx, error_text *err)
{
    sim_collider *colliders = calloc((size_t)sc->collider_count + 1, sizeof *colliders);
    if (!colliders) {
        error_set(err, "out of memory");
        return -1;
    }
    double dt = 1.0 / sc->tick_hz;
    int rc = 0;
    for (long t = 0; t < ticks; t++) {
        for (int c = 0; c < sc->collider_count; c++) {
            colliders[c].id = c;
            colliders[c].geometry = &sc->colliders[c].geometry;
            colliders[c].pose = collider_motion_pose(&sc->colliders[c].motion, (double)t * dt);
            colliders[c].previous_pose =
                collider_motion_pose(&sc->colliders[c].motion, (double)(t - 1) * dt);
            colliders[c].has_previous = t > 0;
        }
        sim_tick_report report;
        error_text tick_err = {{0}};
        double t0 = time_now_ms();
        if (sim_engine_tick(engine, colliders, sc->collider_count, &report, &tick_err) != 0) {
            error_set(err, "tick %ld: %s", t, tick_err.message);
            rc = -1;
            break;
        }
        double elapsed = time_now_ms() - t0;
        if (observe)
            observe(ctx, t, &report, elapsed);
    }
    free(colliders);
    return rc;
}

/* --method, --model and --metric over the scene's material. 0, or -1 (printed). */
static int apply_overrides(const simulate_options *o, scene *sc)
{
    if (o->method && sim_method_parse(o->method, &sc->material.method) != 0) {
        fprintf(stderr, "terrad simulate: --method must be iterative, ssbo or multi\n");
        return -1;
    }
    if (o->method) /* the persson model of that method */
        sc->material.model = sim_model_from_method(sc->material.method);
    if (o->model) {
        if (sim_model_parse(o->model, &sc->material.model) != 0) {
            fprintf(stderr,
                    "terrad simulate: --model must be one of " SIM_MODEL_LIST " (got \"%s\")\n",
                    o->model);
            return -1;
        }
        if (sc->material.model == SIM_MODEL_PERSSON_ITERATIVE)
            sc->material.method = SIM_METHOD_ITERATIVE;
        else if (sc->material.model == SIM_MODEL_PERSSON_MULTI)
            sc->material.method = SIM_METHOD_MULTI;
        else if (sc->material.model == SIM_MODEL_PERSSON_SSBO)
            sc->material.method = SIM_METHOD_SSBO;
    }
    if (o->metric && sim_metric_parse(o->metric, &sc->material.metric) != 0) {
        fprintf(stderr, "terrad simulate: --metric must be euclidean, manhattan or chebyshev\n");
        return -1;
    }
    return 0;
}

/* One offline run: what the report is made of. */
typedef struct simulate_run {
    simulate_options o;
    scene sc;
    world w;
    sim_params params;
    sim_backend *backend;
    char backend_reason[HOST_BACKEND_REASON_MAX];
    sim_engine *engine;
    ground grd;
    simulate_totals totals;
    int64_t volume_before, volume_after;
} simulate_run;

static void add_int64(cJSON *obj, const char *key, int64_t value)
{
    /* int64 printed as a JSON integer exactly, not through a double */
    char num[32];
    snprintf(num, sizeof num, "%lld", (long long)value);
    cJSON_AddItemToObject(obj, key, cJSON_CreateRaw(num));
}

/* What ran, the volumes and the per-stage times. */
static void report_add_run(cJSON *root, simulate_run *r)
{
    const sim_backend *backend = r->backend;
    const world *w = &r->w;
    cJSON_AddStringToObject(root, "scene", r->sc.name);
    cJSON_AddStringToObject(root, "backend", backend->name);
    cJSON_AddStringToObject(root, "backend_reason", r->backend_reason);
    cJSON_AddStringToObject(root, "renderer", backend->renderer);
    cJSON_AddStringToObject(root, "version", backend->version);
    cJSON_AddStringToObject(root, "model", sim_model_name(r->params.model));
    /* a model without a GL version ran on the CPU: say so */
    cJSON_AddBoolToObject(root, "model_on_cpu",
                          !sim_model_is_persson(r->params.model) ||
                              strcmp(backend->name, "cpu") == 0);
    cJSON_AddStringToObject(root, "method", sim_method_name(r->params.method));
    cJSON_AddStringToObject(root, "metric", sim_metric_name(r->params.metric));
    cJSON_AddNumberToObject(root, "threads", sim_threads());
    cJSON_AddNumberToObject(root, "ticks", (double)r->o.ticks);
    cJSON_AddNumberToObject(root, "world_width", w->width);
    cJSON_AddNumberToObject(root, "world_height", w->height);
    add_int64(root, "volume_before", r->volume_before);
    add_int64(root, "volume_after", r->volume_after);
    /* volume_after + compacted == volume_before; bekker's soil keeps its own
     * (it never writes the materials' compaction memory, even where one is on) */
    if (r->params.model == SIM_MODEL_BEKKER || r->grd.uses_compaction)
        add_int64(root, "compacted", sim_world_compacted(w));
    cJSON *st = cJSON_AddObjectToObject(root, "stages");
    const simulate_totals *t = &r->totals;
    for (int s = 0; s < t->stage_count; s++) {
        cJSON *one = cJSON_AddObjectToObject(st, t->stages[s].name);
        cJSON_AddNumberToObject(one, "mean_ms",
                                round(stat_series_mean(&t->stages[s].series) * 1e4) / 1e4);
        cJSON_AddNumberToObject(
            one, "p99_ms", round(stat_series_percentile(&t->stages[s].series, 99) * 1e4) / 1e4);
    }
}

/* Active cells, slopes, the world's and the GPU cache's memory. */
static void report_add_cells(cJSON *root, simulate_run *r)
{
    sim_engine_stats es;
    sim_engine_get_stats(r->engine, &es);
    world *w = &r->w;
    cJSON_AddNumberToObject(root, "active_cells_mean",
                            r->o.ticks ? r->totals.active_sum / r->o.ticks : 0.0);
    cJSON_AddNumberToObject(root, "peak_active_cells", (double)es.peak_active_cells);
    cJSON_AddNumberToObject(root, "refused_windows", (double)r->totals.refused);
    const char *slope_scope;
    int64_t slope_cells = 0;
    add_int64(root, "max_slope_excess",
              max_slope_excess(&r->params, w, es.per_cell_materials ? &r->grd : NULL, &slope_scope,
                               &slope_cells));
    cJSON_AddStringToObject(root, "max_slope_excess_scope", slope_scope);
    cJSON_AddNumberToObject(root, "max_slope_excess_cells", (double)slope_cells);
    cJSON_AddNumberToObject(root, "world_resident_bytes", (double)world_resident_bytes(w));
    cJSON_AddNumberToObject(root, "world_stored_tiles", (double)world_stored_tiles(w));
    cJSON_AddNumberToObject(root, "world_tile_cells", w->tile_cells);
    sim_tile_cache_stats cache;
    sim_backend_tile_cache_stats(r->backend, &cache);
    cJSON_AddNumberToObject(root, "gpu_tile_cache_bytes", (double)cache.texture_bytes);
    cJSON_AddNumberToObject(root, "gpu_tiles_resident", cache.resident_tiles);
    cJSON_AddNumberToObject(root, "gpu_tile_uploads", (double)cache.uploads);
    cJSON_AddNumberToObject(root, "gpu_tile_upload_bytes", (double)cache.upload_bytes);
    cJSON_AddNumberToObject(root, "gpu_tile_evictions", (double)cache.evictions);
    cJSON_AddNumberToObject(root, "gpu_windows_cached", (double)cache.windows_cached);
    cJSON_AddNumberToObject(root, "gpu_windows_direct", (double)cache.windows_direct);
}

/* The GPU's synchronisation points per tick (zeros on the CPU backend):
 * compute dispatches, draws, memory barriers, GPU→CPU readbacks and their
 * bytes, full waits (glFinish, only with stage timing on). */
static void report_add_gpu_sync(cJSON *root, simulate_run *r)
{
    sim_gpu_sync_stats g;
    sim_backend_gpu_sync_stats(r->backend, &g);
    double ticks = r->o.ticks > 0 ? (double)r->o.ticks : 1.0;
    cJSON *o = cJSON_AddObjectToObject(root, "gpu_sync_per_tick");
    cJSON_AddNumberToObject(o, "dispatches", round((double)g.dispatches / ticks * 100) / 100);
    cJSON_AddNumberToObject(o, "indirect", round((double)g.indirect / ticks * 100) / 100);
    cJSON_AddNumberToObject(o, "draws", round((double)g.draws / ticks * 100) / 100);
    cJSON_AddNumberToObject(o, "barriers", round((double)g.barriers / ticks * 100) / 100);
    cJSON_AddNumberToObject(o, "readbacks", round((double)g.readbacks / ticks * 100) / 100);
    cJSON_AddNumberToObject(o, "readback_bytes", round((double)g.readback_bytes / ticks));
    cJSON_AddNumberToObject(o, "finishes", round((double)g.finishes / ticks * 100) / 100);
}

/* Scratch memory by stage and per cell, and the process's peak. */
static void report_add_memory(cJSON *root, simulate_run *r)
{
    sim_engine_stats es;
    sim_engine_get_stats(r->engine, &es);
    double world_cells = (double)r->w.width * r->w.height;
    double world_bytes = (double)world_resident_bytes(&r->w);
    cJSON_AddNumberToObject(root, "scratch_bytes_peak", (double)es.peak_scratch_bytes);
    cJSON *by_stage = cJSON_AddObjectToObject(root, "scratch_bytes_by_stage");
#define ADD_STAGE_BYTES(name) cJSON_AddNumberToObject(by_stage, #name, (double)es.peak_memory.name);
    SIM_MEMORY_STAGE_LIST(ADD_STAGE_BYTES)
#undef ADD_STAGE_BYTES
    if (r->params.model == SIM_MODEL_DECALS)
        cJSON_AddNumberToObject(root, "footprint_events", (double)r->totals.footprint_events);
    cJSON_AddNumberToObject(
        root, "bytes_per_world_cell",
        round((world_bytes + (double)es.peak_scratch_bytes) / world_cells * 1e4) / 1e4);
    cJSON_AddNumberToObject(
        root, "bytes_per_active_cell",
        es.peak_active_cells
            ? round((double)es.peak_scratch_bytes / (double)es.peak_active_cells * 1e2) / 1e2
            : 0.0);
    cJSON_AddNumberToObject(root, "peak_rss_bytes", (double)proc_peak_rss_bytes());
}

/* The report on stdout. 0, or -1 when it could not be made. */
static int report_print(simulate_run *r)
{
    cJSON *root = cJSON_CreateObject();
    report_add_run(root, r);
    report_add_cells(root, r);
    report_add_gpu_sync(root, r);
    report_add_memory(root, r);
    char *text = cJSON_Print(root);
    cJSON_Delete(root);
    if (!text)
        return -1;
    printf("%s\n", text);
    free(text);
    return 0;
}

/* The engine on its backend with the scene's ground; the ticks; the report.
 * Returns the exit status. */
static int simulate_engine_run(simulate_run *r)
{
    error_text err = {{0}};
    world *w = &r->w;
    if (sim_params_from_material(&r->sc.material, w->cell_size_m, w->units_per_m, w->floor,
                                 &r->params, &err) != 0 ||
        !(r->backend = host_backend_create(r->o.backend, r->backend_reason,
                                           sizeof r->backend_reason, &err)) ||
        !(r->engine =
              sim_engine_create(w, &r->params, r->backend, r->sc.active_margin_cells, &err))) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        return 1;
    }
    if (host_ground_attach(&r->sc, w, r->engine, &r->grd, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        sim_engine_destroy(r->engine);
        return 1;
    }
    sim_backend_set_stage_timing(r->backend, 1);

#define STAGE_SERIES(name) {#name, {0}},
    stage_series stages[] = {
        SIM_STAGE_LIST(STAGE_SERIES){"model", {0}}, {"gather_scatter", {0}}, {"tick", {0}}};
#undef STAGE_SERIES
    const int stage_count = (int)(sizeof stages / sizeof stages[0]);
    r->volume_before = world_volume(w);
    r->totals = (simulate_totals){stages, stage_count, 0.0, 0, 0};
    int rc = 1;
    if (app_run_scene_ticks(&r->sc, r->engine, r->o.ticks, record_tick, &r->totals, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
    } else {
        r->volume_after = world_volume(w);
        if (r->o.out_path && write_heights(r->o.out_path, w) != 0)
            fprintf(stderr, "terrad simulate: cannot write %s\n", r->o.out_path);
        else if (report_print(r) == 0)
            rc = 0;
    }
    for (int s = 0; s < stage_count; s++)
        stat_series_free(&stages[s].series);
    sim_engine_destroy(r->engine);
    return rc;
}

int app_simulate(int argc, char **argv)
{
    simulate_run *r = calloc(1, sizeof *r);
    if (!r) {
        fprintf(stderr, "terrad simulate: out of memory\n");
        return 1;
    }
    cli_result parsed = parse_options(argc, argv, &r->o);
    int rc = parsed == CLI_HELP ? 0 : 2;
    if (parsed != CLI_OK)
        goto done;
    log_set_quiet(1);
    error_text err = {{0}};
    rc = 1;
    if ((r->o.scene_path ? scene_load_file(r->o.scene_path, &r->sc, &err)
                         : scene_load_default(&r->sc, &err)) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done;
    }
    if (apply_overrides(&r->o, &r->sc) != 0) {
        rc = 2;
        goto done;
    }
    if (scene_create_world(&r->sc, &r->w, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done;
    }
    rc = simulate_engine_run(r);
done:
    ground_free(&r->grd);
    if (r->backend)
        r->backend->destroy(r->backend);
    world_free(&r->w);
    scene_free(&r->sc);
    free(r);
    return rc;
}
