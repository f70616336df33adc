/*
 * simulate.c: `terrad simulate` — runs a scene's scripted colliders for N
 * ticks on one backend, offline, and prints one JSON object: volume before
 * and after (Σh, int64), per-stage mean and p99 milliseconds, mean active
 * cells, the largest slope excess left over the angle of repose, memory per
 * world cell and per active cell, and peak RSS. The tests and `make bench`
 * are built on it.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "gl/gl.h"
#include "scene/scene.h"

typedef struct simulate_options {
    const char *scene_path;
    long ticks;
    const char *backend;
    const char *method;
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

/* Heights as little-endian int32, row-major: the format `--out` promises. */
static int write_heights(const char *path, const world *w)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    size_t n = (size_t)w->width * w->height;
    size_t done = fwrite(w->heights, sizeof(int32_t), n, f);
    int bad = fclose(f) != 0 || done != n;
    return bad ? -1 : 0;
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
} simulate_totals;

static void record_tick(void *ctx, long tick, const sim_tick_report *report, double tick_ms)
{
    (void)tick;
    simulate_totals *t = ctx;
    double values[] = {report->times.depth,       report->times.classify,
                       report->times.jump_flood,  report->times.displace,
                       report->times.even_slopes, report->times.transfer,
                       report->gather_scatter_ms, tick_ms};
    for (int s = 0; s < t->stage_count; s++)
        stat_series_add(&t->stages[s].series, values[s]);
    t->active_sum += (double)report->active_cells;
    t->refused += report->refused_windows;
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
    if (o.metric && sim_metric_parse(o.metric, &sc.material.metric) != 0) {
        fprintf(stderr, "terrad simulate: --metric must be euclidean, manhattan or chebyshev\n");
        scene_free(&sc);
        return 2;
    }
    world w;
    sim_params params;
    sim_backend *backend = NULL;
    sim_engine engine;
    int rc = 1;
    if (scene_create_world(&sc, &w, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        scene_free(&sc);
        return 1;
    }
    if (sim_params_from_material(&sc.material, w.cell_size_m, w.units_per_m, w.floor, &params,
                                 &err) != 0 ||
        !(backend = app_backend_create(o.backend, &err)) ||
        sim_engine_init(&engine, &w, &params, backend, sc.active_margin_cells, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done_world;
    }
    if (strcmp(backend->name, "gl") == 0)
        sim_backend_gl_set_stage_timing(backend, 1);
    engine.depth_from_cpu = o.depth_from_cpu;

    stage_series stages[] = {{"depth", {0}},          {"classify", {0}},    {"jump_flood", {0}},
                             {"displace", {0}},       {"even_slopes", {0}}, {"transfer", {0}},
                             {"gather_scatter", {0}}, {"tick", {0}}};
    const int stage_count = (int)(sizeof stages / sizeof stages[0]);
    int64_t volume_before = world_volume(&w);
    simulate_totals totals = {stages, stage_count, 0.0, 0};
    if (app_run_scene_ticks(&sc, &engine, o.ticks, record_tick, &totals, &err) != 0) {
        fprintf(stderr, "terrad simulate: %s\n", err.message);
        goto done_colliders;
    }
    double active_sum = totals.active_sum;
    long refused = totals.refused;
    int64_t volume_after = world_volume(&w);
    if (o.out_path && write_heights(o.out_path, &w) != 0) {
        fprintf(stderr, "terrad simulate: cannot write %s\n", o.out_path);
        goto done_colliders;
    }
    double world_cells = (double)w.width * w.height;
    double world_bytes = world_cells * sizeof(int32_t);

    cJSON *root = cJSON_CreateObject();
    cJSON_AddStringToObject(root, "scene", sc.name);
    cJSON_AddStringToObject(root, "backend", backend->name);
    cJSON_AddStringToObject(root, "renderer", backend->renderer);
    cJSON_AddStringToObject(root, "version", backend->version);
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
    cJSON *st = cJSON_AddObjectToObject(root, "stages");
    for (int s = 0; s < stage_count; s++) {
        cJSON *one = cJSON_AddObjectToObject(st, stages[s].name);
        cJSON_AddNumberToObject(one, "mean_ms",
                                round(stat_series_mean(&stages[s].series) * 1e4) / 1e4);
        cJSON_AddNumberToObject(one, "p99_ms",
                                round(stat_series_percentile(&stages[s].series, 99) * 1e4) / 1e4);
    }
    cJSON_AddNumberToObject(root, "active_cells_mean", o.ticks ? active_sum / o.ticks : 0.0);
    cJSON_AddNumberToObject(root, "peak_active_cells", (double)engine.peak_active_cells);
    cJSON_AddNumberToObject(root, "refused_windows", (double)refused);
    snprintf(num, sizeof num, "%lld",
             (long long)sim_max_slope_excess(&params, w.width, w.height, w.heights));
    cJSON_AddItemToObject(root, "max_slope_excess", cJSON_CreateRaw(num));
    cJSON_AddNumberToObject(root, "scratch_bytes_peak", (double)engine.peak_scratch_bytes);
    cJSON_AddNumberToObject(
        root, "bytes_per_world_cell",
        round((world_bytes + (double)engine.peak_scratch_bytes) / world_cells * 1e4) / 1e4);
    cJSON_AddNumberToObject(
        root, "bytes_per_active_cell",
        engine.peak_active_cells
            ? round((double)engine.peak_scratch_bytes / (double)engine.peak_active_cells * 1e2) /
                  1e2
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
    sim_engine_free(&engine);
done_world:
    if (backend)
        backend->destroy(backend);
    world_free(&w);
    scene_free(&sc);
    return rc;
}
