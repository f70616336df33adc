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

static int64_t max_slope_excess(const sim_params *p, const world *w, const char **scope)
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
    if (!rows)
        return -1;
    int64_t worst = 0;
    for (int y = r.y; y < r.y + r.h; y += band) {
        int h = y + band + 1 <= r.y + r.h ? band + 1 : r.y + r.h - y;
        world_gather_window(w, (world_rect){r.x, y, r.w, h}, rows);
        int64_t e = sim_max_slope_excess(p, r.w, h, rows);
        if (e > worst)
            worst = e;
    }
    free(rows);
    return worst;
}

typedef struct stage_series {
    const char *name;
    stat_series series;
} stage_series;

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
    sim_collider *colliders = calloc((size_t)sc.collider_count + 1, sizeof *colliders);
    if (!colliders) {
        fprintf(stderr, "terrad simulate: out of memory\n");
        goto done_engine;
    }
    int64_t volume_before = world_volume(&w);
    double active_sum = 0.0;
    long refused = 0;
    double dt = 1.0 / sc.tick_hz;
    for (long t = 0; t < o.ticks; t++) {
        for (int c = 0; c < sc.collider_count; c++) {
            colliders[c].id = c;
            colliders[c].geometry = &sc.colliders[c].geometry;
            colliders[c].pose = collider_motion_pose(&sc.colliders[c].motion, (double)t * dt);
            colliders[c].previous_pose =
                collider_motion_pose(&sc.colliders[c].motion, (double)(t - 1) * dt);
            colliders[c].has_previous = t > 0;
        }
        sim_tick_report report;
        double t0 = time_now_ms();
        if (sim_engine_tick(&engine, colliders, sc.collider_count, &report, &err) != 0) {
            fprintf(stderr, "terrad simulate: tick %ld: %s\n", t, err.message);
            goto done_colliders;
        }
        double elapsed = time_now_ms() - t0;
        double values[] = {report.times.depth,       report.times.classify,
                           report.times.jump_flood,  report.times.displace,
                           report.times.even_slopes, report.times.transfer,
                           report.gather_scatter_ms, elapsed};
        for (int s = 0; s < stage_count; s++)
            stat_series_add(&stages[s].series, values[s]);
        active_sum += (double)report.active_cells;
        refused += report.refused_windows;
    }
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
    const char *slope_scope;
    snprintf(num, sizeof num, "%lld", (long long)max_slope_excess(&params, &w, &slope_scope));
    cJSON_AddItemToObject(root, "max_slope_excess", cJSON_CreateRaw(num));
    cJSON_AddStringToObject(root, "max_slope_excess_scope", slope_scope);
    cJSON_AddNumberToObject(root, "world_resident_bytes", (double)world_resident_bytes(&w));
    cJSON_AddNumberToObject(root, "world_stored_tiles", (double)world_stored_tiles(&w));
    cJSON_AddNumberToObject(root, "world_tile_cells", w.tile_cells);
    gl_tile_cache_stats cache;
    sim_backend_gl_tile_cache_stats(backend, &cache);
    cJSON_AddNumberToObject(root, "gpu_tile_cache_bytes", (double)cache.texture_bytes);
    cJSON_AddNumberToObject(root, "gpu_tiles_resident", cache.resident_tiles);
    cJSON_AddNumberToObject(root, "gpu_tile_uploads", (double)cache.uploads);
    cJSON_AddNumberToObject(root, "gpu_tile_upload_bytes", (double)cache.upload_bytes);
    cJSON_AddNumberToObject(root, "gpu_tile_evictions", (double)cache.evictions);
    cJSON_AddNumberToObject(root, "gpu_windows_cached", (double)cache.windows_cached);
    cJSON_AddNumberToObject(root, "gpu_windows_direct", (double)cache.windows_direct);
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
    free(colliders);
    for (int s = 0; s < stage_count; s++)
        stat_series_free(&stages[s].series);
done_engine:
    sim_engine_free(&engine);
done_world:
    if (backend)
        backend->destroy(backend);
    world_free(&w);
    scene_free(&sc);
    return rc;
}
