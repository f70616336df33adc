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
#include "scene/scene.h"

typedef struct simulate_options {
    const char *scene_path;
    long ticks;
    const char *backend;
    const char *method;
    const char *model;
    const char *metric;
    const char *out_path;
    int depth_from_cpu;
} simulate_options;

static int parse_options(int argc, char **argv, simulate_options *o)
{
    memset(o, 0, sizeof *o);
    o->ticks = -1;
    o->backend = "gl";
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--depth-from-cpu") == 0) {
            o->depth_from_cpu = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "terrad simulate: %s needs a value\n", a);
            return -1;
        }
        i++;
        if (strcmp(a, "--scene") == 0) {
            o->scene_path = v;
        } else if (strcmp(a, "--ticks") == 0) {
            char *end;
            o->ticks = strtol(v, &end, 10);
            if (*end || o->ticks < 0 || o->ticks > 100000000) {
                fprintf(stderr, "terrad simulate: --ticks must be an integer in [0, 1e8]\n");
                return -1;
            }
        } else if (strcmp(a, "--backend") == 0) {
            o->backend = v;
        } else if (strcmp(a, "--method") == 0) {
            o->method = v;
        } else if (strcmp(a, "--model") == 0) {
            o->model = v;
        } else if (strcmp(a, "--metric") == 0) {
            o->metric = v;
        } else if (strcmp(a, "--out") == 0) {
            o->out_path = v;
        } else {
            fprintf(stderr, "terrad simulate: unknown option %s (see terrad --help)\n", a);
            return -1;
        }
    }
    if (o->ticks < 0) {
        fprintf(stderr, "terrad simulate: --ticks N is required\n");
        return -1;
    }
    return 0;
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
 * SLOPE_SCAN_CELLS_MAX cells is scanned only over the stored (written) tiles
 * and one cell around them: the base beyond was never touched by a tick. */
#define SLOPE_SCAN_CELLS_MAX ((int64_t)1 << 26)

typedef struct touched_bounds {
    world_rect r;
} touched_bounds;

static void add_touched(void *ctx, int tx, int ty, world_rect cells, uint64_t generation)
{
    (void)tx, (void)ty, (void)generation;
    touched_bounds *b = ctx;
    b->r = world_rect_union(b->r, cells);
}

/* With per-cell materials (g non-NULL) each column is held to its own material's repose. */
static int64_t max_slope_excess(const sim_params *p, const world *w, const ground *g,
                                const char **scope)
{
    world_rect r = {0, 0, w->width, w->height};
    *scope = "world";
    if ((int64_t)w->width * w->height > SLOPE_SCAN_CELLS_MAX) {
        touched_bounds b = {{0, 0, 0, 0}};
        world_for_each_stored_tile(w, add_touched, &b);
        *scope = "stored_tiles";
        if (b.r.w <= 0)
            return 0;
        r = (world_rect){b.r.x - 1, b.r.y - 1, b.r.w + 2, b.r.h + 2};
        world_clip_rect(w, &r);
    }
    int band = 64;
    int32_t *rows = malloc((size_t)r.w * (band + 1) * sizeof *rows);
    uint8_t *ids = g && !g->uniform ? malloc((size_t)r.w * (band + 1)) : NULL;
    if (!rows || (g && !g->uniform && !ids)) {
        free(rows);
        free(ids);
        return -1;
    }
    int64_t worst = 0;
    for (int y = r.y; y < r.y + r.h; y += band) {
        int h = y + band + 1 <= r.y + r.h ? band + 1 : r.y + r.h - y;
        world_rect band_rect = {r.x, y, r.w, h};
        world_gather_window(w, band_rect, rows);
        int64_t e;
        if (g) {
            if (ids)
                ground_gather_ids(g, band_rect, ids);
            e = sim_max_slope_excess_materials(&g->table, ids, r.w, h, rows);
        } else {
            e = sim_max_slope_excess(p, r.w, h, rows);
        }
        if (e > worst)
            worst = e;
    }
    free(rows);
    free(ids);
    return worst;
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

int app_simulate(int argc, char **argv)
{
    simulate_options o;
    if (parse_options(argc, argv, &o) != 0)
        return 2;
    log_set_quiet(1);
    error_text err = {{0}};
    scene sc;
    int loaded =
        o.scene_path ? scene_load_file(o.scene_path, &sc, &err) : scene_load_default(&sc, &err);
    if (loaded != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        return 1;
    }
    if (o.method && sim_method_parse(o.method, &sc.material.method) != 0) {
        fprintf(stderr, "terrad simulate: --method must be iterative, ssbo or multi\n");
        scene_free(&sc);
        return 2;
    }
    if (o.method) /* the persson model of that method */
        sc.material.model = sim_model_from_method(sc.material.method);
    if (o.model) {
        if (sim_model_parse(o.model, &sc.material.model) != 0) {
            fprintf(stderr, "terrad simulate: --model must be persson-iterative, persson-ssbo, "
                            "persson-multi, subtract, deferred, diffusion or decals\n");
            scene_free(&sc);
            return 2;
        }
        if (sc.material.model == SIM_MODEL_PERSSON_ITERATIVE)
            sc.material.method = SIM_METHOD_ITERATIVE;
        else if (sc.material.model == SIM_MODEL_PERSSON_MULTI)
            sc.material.method = SIM_METHOD_MULTI;
        else if (sc.material.model == SIM_MODEL_PERSSON_SSBO)
            sc.material.method = SIM_METHOD_SSBO;
    }
    if (o.metric && sim_metric_parse(o.metric, &sc.material.metric) != 0) {
        fprintf(stderr, "terrad simulate: --metric must be euclidean, manhattan or chebyshev\n");
        scene_free(&sc);
        return 2;
    }
    world w;
    sim_params params;
    sim_backend *backend = NULL;
    sim_engine *engine = NULL;
    ground grd;
    memset(&grd, 0, sizeof grd);
    int rc = 1;
    if (scene_create_world(&sc, &w, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        scene_free(&sc);
        return 1;
    }
    if (sim_params_from_material(&sc.material, w.cell_size_m, w.units_per_m, w.floor, &params,
                                 &err) != 0 ||
        !(backend = app_backend_create(o.backend, &err)) ||
        !(engine = sim_engine_create(&w, &params, backend, sc.active_margin_cells, &err))) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done_world;
    }
    if (app_ground_attach(&sc, &w, engine, &grd, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        sim_engine_destroy(engine);
        goto done_world;
    }
    sim_backend_set_stage_timing(backend, 1);
    sim_engine_set_depth_from_cpu(engine, o.depth_from_cpu);

#define STAGE_SERIES(name) {#name, {0}},
    stage_series stages[] = {
        SIM_STAGE_LIST(STAGE_SERIES){"model", {0}}, {"gather_scatter", {0}}, {"tick", {0}}};
#undef STAGE_SERIES
    const int stage_count = (int)(sizeof stages / sizeof stages[0]);
    int64_t volume_before = world_volume(&w);
    simulate_totals totals = {stages, stage_count, 0.0, 0, 0};
    if (app_run_scene_ticks(&sc, engine, o.ticks, record_tick, &totals, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done_colliders;
    }
    double active_sum = totals.active_sum;
    long refused = totals.refused, footprint_events = totals.footprint_events;
    int64_t volume_after = world_volume(&w);
    if (o.out_path && write_heights(o.out_path, &w) != 0) {
        fprintf(stderr, "terrad simulate: cannot write %s\n", o.out_path);
        goto done_colliders;
    }
    double world_cells = (double)w.width * w.height;
    double world_bytes = (double)world_resident_bytes(&w);

    cJSON *root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "scene", sc.name);
    cJSON_AddStringToObject(root, "backend", backend->name);
    cJSON_AddStringToObject(root, "renderer", backend->renderer);
    cJSON_AddStringToObject(root, "version", backend->version);
    cJSON_AddStringToObject(root, "model", sim_model_name(params.model));
    /* a model without a GL version ran on the CPU: say so */
    cJSON_AddBoolToObject(root, "model_on_cpu",
                          !sim_model_is_persson(params.model) || strcmp(backend->name, "cpu") == 0);
    cJSON_AddStringToObject(root, "method", sim_method_name(params.method));
    cJSON_AddStringToObject(root, "metric", sim_metric_name(params.metric));
    cJSON_AddNumberToObject(root, "ticks", (double)o.ticks);
    cJSON_AddNumberToObject(root, "world_width", w.width);
    cJSON_AddNumberToObject(root, "world_height", w.height);
    /* int64 volumes printed as JSON integers exactly, not through a double */
    char num[32];
    snprintf(num, sizeof num, "%lld", (long long)volume_before);
    cJSON_AddItemToObject(root, "volume_before", cJSON_CreateRaw(num));
    snprintf(num, sizeof num, "%lld", (long long)volume_after);
    cJSON_AddItemToObject(root, "volume_after", cJSON_CreateRaw(num));
    if (grd.uses_compaction) { /* volume_after + compacted == volume_before */
        snprintf(num, sizeof num, "%lld", (long long)ground_compaction_total(&grd));
        cJSON_AddItemToObject(root, "compacted", cJSON_CreateRaw(num));
    }
    cJSON *st = cJSON_AddObjectToObject(root, "stages");
    for (int s = 0; s < stage_count; s++) {
        cJSON *one = cJSON_AddObjectToObject(st, stages[s].name);
        cJSON_AddNumberToObject(one, "mean_ms",
                                round(stat_series_mean(&stages[s].series) * 1e4) / 1e4);
        cJSON_AddNumberToObject(one, "p99_ms",
                                round(stat_series_percentile(&stages[s].series, 99) * 1e4) / 1e4);
    }
    cJSON_AddNumberToObject(root, "active_cells_mean", o.ticks ? active_sum / o.ticks : 0.0);
    sim_engine_stats es;
    sim_engine_get_stats(engine, &es);
    cJSON_AddNumberToObject(root, "peak_active_cells", (double)es.peak_active_cells);
    cJSON_AddNumberToObject(root, "refused_windows", (double)refused);
    const char *slope_scope;
    snprintf(num, sizeof num, "%lld",
             (long long)max_slope_excess(&params, &w, es.per_cell_materials ? &grd : NULL,
                                         &slope_scope));
    cJSON_AddItemToObject(root, "max_slope_excess", cJSON_CreateRaw(num));
    cJSON_AddStringToObject(root, "max_slope_excess_scope", slope_scope);
    cJSON_AddNumberToObject(root, "world_resident_bytes", (double)world_resident_bytes(&w));
    cJSON_AddNumberToObject(root, "world_stored_tiles", (double)world_stored_tiles(&w));
    cJSON_AddNumberToObject(root, "world_tile_cells", w.tile_cells);
    sim_tile_cache_stats cache;
    sim_backend_tile_cache_stats(backend, &cache);
    cJSON_AddNumberToObject(root, "gpu_tile_cache_bytes", (double)cache.texture_bytes);
    cJSON_AddNumberToObject(root, "gpu_tiles_resident", cache.resident_tiles);
    cJSON_AddNumberToObject(root, "gpu_tile_uploads", (double)cache.uploads);
    cJSON_AddNumberToObject(root, "gpu_tile_upload_bytes", (double)cache.upload_bytes);
    cJSON_AddNumberToObject(root, "gpu_tile_evictions", (double)cache.evictions);
    cJSON_AddNumberToObject(root, "gpu_windows_cached", (double)cache.windows_cached);
    cJSON_AddNumberToObject(root, "gpu_windows_direct", (double)cache.windows_direct);
    cJSON_AddNumberToObject(root, "scratch_bytes_peak", (double)es.peak_scratch_bytes);
    cJSON *by_stage = cJSON_AddObjectToObject(root, "scratch_bytes_by_stage");
#define ADD_STAGE_BYTES(name) cJSON_AddNumberToObject(by_stage, #name, (double)es.peak_memory.name);
    SIM_MEMORY_STAGE_LIST(ADD_STAGE_BYTES)
#undef ADD_STAGE_BYTES
    if (params.model == SIM_MODEL_DECALS)
        cJSON_AddNumberToObject(root, "footprint_events", (double)footprint_events);
    cJSON_AddNumberToObject(
        root, "bytes_per_world_cell",
        round((world_bytes + (double)es.peak_scratch_bytes) / world_cells * 1e4) / 1e4);
    cJSON_AddNumberToObject(
        root, "bytes_per_active_cell",
        es.peak_active_cells
            ? round((double)es.peak_scratch_bytes / (double)es.peak_active_cells * 1e2) / 1e2
            : 0.0);
    cJSON_AddNumberToObject(root, "peak_rss_bytes", (double)proc_peak_rss_bytes());
    char *text = cJSON_Print(root);
    if (text) {
        printf("%s\n", text);
        free(text);
        rc = 0;
    }
    cJSON_Delete(root);
done_colliders:
    for (int s = 0; s < stage_count; s++)
        stat_series_free(&stages[s].series);
    sim_engine_destroy(engine);
done_world:
    ground_free(&grd);
    if (backend)
        backend->destroy(backend);
    world_free(&w);
    scene_free(&sc);
    return rc;
}
