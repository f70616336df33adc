/*
 * bench_trade.c: `terrad bench --trade` — the measured speed/accuracy trade.
 *
 * For every standard scene (trade_scenes.c) it first runs the reference:
 * persson-iterative at the finest cell size with 50 displacement and 50
 * slope iterations (20/20 with --quick), and shows that it is converged by
 * running twice as many and printing how far the trail moved. Then every model × backend × cell
 * size × iteration count of the sweep runs the same scene at headings 0°, 30° and 45° through the
 * offline tick loop `simulate` uses (app_run_scene_ticks). The 0° run gives the cost (ms per tick,
 * peak scratch, bytes per world cell) and the errors (volume drift, trail cross-section RMS against
 * the reference, largest slope excess over the angle of repose on the finished trail); the three
 * headings give the anisotropy (largest RMS difference between their
 * cross-sections, sampled along the turned trail).
 *
 * Out: DIR/trade.csv (one row per run configuration) and DIR/trade.txt (the
 * table and the summary also printed). With the bekker model in the sweep,
 * its physical axis too (trade_physical.c): DIR/trade-physical.csv, each
 * configuration's cost and error against Ding 2011's measured single wheel,
 * smooth and lugged. The plot (cost against error with each scene's Pareto
 * front) is drawn from the CSV by scripts/trade-plot (matplotlib); `make
 * bench` runs it.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "app/app.h"
#include "host/host.h"
#include "app/trade_internal.h"

#define HEADING_COUNT 3
static const double headings_deg[HEADING_COUNT] = {0.0, 30.0, 45.0};

static const double full_cells_m[] = {0.1, 0.05, 0.025};
static const int full_iterations[] = {1, 5, 10, 20};
/* The reference: persson-iterative at the finest cell size, this many
 * displacement and slope iterations; "converged" is checked against twice as
 * many. --quick (a smoke test in seconds) uses coarser cells and 20/40. */
static const int full_reference_iterations = 50;
static const double quick_cells_m[] = {0.2, 0.1};
static const int quick_iterations[] = {1, 10};
static const int quick_reference_iterations = 20;

typedef struct trade_options {
    const char *out_dir;
    int quick;
    int cpu_all, gl_all, gl_one; /* which backends run which cell sizes */
    int models[16];
    int model_count;
    int scenes[16];
    int scene_count;
} trade_options;

typedef struct bench_args {
    trade_options o;
    int trade;
    const char *models, *scenes;
} bench_args;

static int backend_option(void *ctx, const char *v, error_text *err)
{
    trade_options *o = &((bench_args *)ctx)->o;
    o->cpu_all = strcmp(v, "cpu") == 0 || strcmp(v, "both") == 0;
    o->gl_all = strcmp(v, "gl") == 0 || strcmp(v, "both") == 0;
    o->gl_one = 0;
    if (!o->cpu_all && !o->gl_all) {
        error_set(err, "must be cpu, gl or both (got \"%s\")", v);
        return -1;
    }
    return 0;
}

static const cli_option bench_table[] = {
    {"trade", NULL, "the speed/accuracy sweep (the one bench so far; required)",
     CLI_AT_FLAG(bench_args, trade)},
    {"quick", NULL,
     "a reduced sweep in seconds: cells 0.2 and 0.1 m, 1 and 10\n"
     "iterations, reference 20/20 (full: 0.1, 0.05, 0.025 m; 1, 5,\n"
     "10, 20; reference 50/50 checked against 100/100)",
     CLI_AT_FLAG(bench_args, o.quick)},
    {"out", "DIR", "where trade.csv and trade.txt go (default docs/trade)",
     CLI_AT_STRING(bench_args, o.out_dir)},
    {"backend", "cpu|gl|both",
     "cpu: every run on the CPU twin; gl: every run on GL; both: both;\n"
     "default: the CPU twin for the sweep plus GL at one cell size",
     CLI_CALLS(backend_option)},
    {"models", "LIST", "comma-separated; default: all the models below",
     CLI_AT_STRING(bench_args, models)},
    {"scenes", "LIST", "comma-separated; default: all the scenes below",
     CLI_AT_STRING(bench_args, scenes)},
    {0},
};

static const char bench_usage[] = "--trade [options]";

/* The models and scenes --models and --scenes take. */
static void bench_print_lists(FILE *f)
{
    fprintf(f, "\nmodels:");
    for (int i = 0; i < trade_model_count; i++)
        fprintf(f, " %s", trade_model_names[i]);
    fprintf(f, "\nscenes:\n");
    for (int i = 0; i < trade_scene_count; i++)
        fprintf(f, "  %-10s %s\n", trade_scene_names[i], trade_scene_about(i));
}

void app_bench_usage(FILE *f)
{
    cli_print_help(f, "bench", bench_usage, bench_table);
    bench_print_lists(f);
}

/* Split a comma list into indices by `lookup`; names the unknown entry. */
static int parse_list(const char *option, const char *list, int (*lookup)(const char *),
                      const char *const *known, int known_count, int *out, int *count)
{
    *count = 0;
    char buf[512];
    if (strlen(list) >= sizeof buf || list[0] == '\0') {
        fprintf(stderr, "terrad bench: %s: expected a comma-separated list\n", option);
        return -1;
    }
    strcpy(buf, list);
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        int index = lookup(tok);
        if (index < 0) {
            fprintf(stderr, "terrad bench: %s: unknown name \"%s\" (known:", option, tok);
            for (int i = 0; i < known_count; i++)
                fprintf(stderr, " %s", known[i]);
            fprintf(stderr, ")\n");
            return -1;
        }
        int seen = 0;
        for (int i = 0; i < *count; i++)
            seen |= out[i] == index;
        if (!seen && *count < 16)
            out[(*count)++] = index;
    }
    return 0;
}

static cli_result parse_options(int argc, char **argv, trade_options *o)
{
    bench_args a = {.o = {.out_dir = "docs/trade", .cpu_all = 1, .gl_one = 1}};
    cli_result r = cli_parse("bench", bench_usage, bench_table, argc, argv, &a, NULL);
    *o = a.o;
    if (r == CLI_HELP) /* the lists --models and --scenes take */
        bench_print_lists(stdout);
    if (r != CLI_OK)
        return r;
    if (!a.trade) {
        fprintf(stderr, "terrad bench: say which bench: --trade (see terrad bench --help)\n");
        return CLI_ERROR;
    }
    if (a.models) {
        if (parse_list("--models", a.models, trade_model_index, trade_model_names,
                       trade_model_count, o->models, &o->model_count) != 0)
            return CLI_ERROR;
    } else {
        for (int i = 0; i < trade_model_count && i < 16; i++)
            o->models[o->model_count++] = i;
    }
    if (a.scenes) {
        if (parse_list("--scenes", a.scenes, trade_scene_index, trade_scene_names,
                       trade_scene_count, o->scenes, &o->scene_count) != 0)
            return CLI_ERROR;
    } else {
        for (int i = 0; i < trade_scene_count; i++)
            o->scenes[o->scene_count++] = i;
    }
    return CLI_OK;
}

/* mkdir -p */
static int make_dirs(const char *path)
{
    char buf[1024];
    if (strlen(path) >= sizeof buf) {
        errno = ENAMETOOLONG;
        return -1;
    }
    strcpy(buf, path);
    for (char *p = buf + 1; *p; p++) {
        if (*p != '/')
            continue;
        *p = '\0';
        if (mkdir(buf, 0777) != 0 && errno != EEXIST)
            return -1;
        *p = '/';
    }
    return mkdir(buf, 0777) != 0 && errno != EEXIST ? -1 : 0;
}

/* ---- One run ---- */

typedef struct run_result {
    long ticks;
    int64_t world_cells;
    double tick_ms_mean, tick_ms_p95;
    uint64_t scratch_bytes_peak;
    double bytes_per_world_cell;
    double volume_drift;
    double max_slope_excess_m;
    long refused_windows;
    double *profile;
    int profile_length;
} run_result;

typedef struct tick_log {
    stat_series tick_ms;
    long refused;
} tick_log;

static void log_tick(void *ctx, long tick, const sim_tick_report *report, double tick_ms)
{
    (void)tick;
    tick_log *log = ctx;
    stat_series_add(&log->tick_ms, tick_ms);
    log->refused += report->refused_windows;
}

/* The renderer strings of the backends used, for the CSV and the plot. */
static char cpu_renderer[256] = "", gl_renderer[256] = "";

static int run_scene(int scene_index, const char *model, const char *backend_name, double cell_m,
                     int iterations, double heading_deg, run_result *r, error_text *err)
{
    memset(r, 0, sizeof *r);
    sim_material material = sim_material_default();
    if (trade_model_configure(model, &material, err) != 0)
        return -1;
    material.displace_iterations = iterations;
    material.slope_iterations = iterations;
    scene sc;
    trade_profile_spec spec;
    if (trade_scene_build(scene_index, cell_m, heading_deg, &material, &sc, &r->ticks, &spec,
                          err) != 0)
        return -1;
    world w;
    if (scene_create_world(&sc, &w, err) != 0) {
        scene_free(&sc);
        return -1;
    }
    int rc = -1;
    size_t cells = (size_t)w.width * w.height;
    int32_t *before = malloc(cells * sizeof *before);
    int32_t *after = malloc(cells * sizeof *after);
    sim_params params;
    sim_backend *backend = NULL;
    sim_engine *engine = NULL;
    tick_log log = {{0}, 0};
    if (!before || !after) {
        error_set(err, "out of memory");
        goto done;
    }
    world_rect whole = {0, 0, w.width, w.height};
    world_gather_window(&w, whole, before);
    if (sim_params_from_material(&sc.material, w.cell_size_m, w.units_per_m, w.floor, &params,
                                 err) != 0 ||
        !(backend = host_backend_create(backend_name, NULL, 0, err)) ||
        !(engine = sim_engine_create(&w, &params, backend, sc.active_margin_cells, err)))
        goto done;
    char *renderer = strcmp(backend->name, "gl") == 0 ? gl_renderer : cpu_renderer;
    snprintf(renderer, sizeof cpu_renderer, "%s", backend->renderer);
    if (app_run_scene_ticks(&sc, engine, r->ticks, log_tick, &log, err) != 0)
        goto done;

    world_gather_window(&w, whole, after);
    int64_t volume_before = 0, volume_after = 0, displaced = 0;
    for (size_t i = 0; i < cells; i++) {
        volume_before += before[i];
        volume_after += after[i];
        if (after[i] < before[i])
            displaced += before[i] - after[i];
    }
    int64_t drift = volume_after - volume_before;
    r->volume_drift = displaced ? (double)llabs(drift) / (double)displaced : 0.0;
    /* Slopes over the finished trail only: where a collider still rests at
     * the end, the rut's wall is held up by it, not left over by the model. */
    world_rect trail = trade_profile_rect(&spec, &w);
    if (trail.w > 0) {
        int32_t *patch = malloc((size_t)trail.w * trail.h * sizeof *patch);
        if (!patch) {
            error_set(err, "out of memory");
            goto done;
        }
        world_gather_window(&w, trail, patch);
        r->max_slope_excess_m =
            (double)sim_max_slope_excess(&params, trail.w, trail.h, patch) / (double)w.units_per_m;
        free(patch);
    }
    r->world_cells = (int64_t)cells;
    r->tick_ms_mean = stat_series_mean(&log.tick_ms);
    r->tick_ms_p95 = stat_series_percentile(&log.tick_ms, 95);
    sim_engine_stats es;
    sim_engine_get_stats(engine, &es);
    r->scratch_bytes_peak = es.peak_scratch_bytes;
    r->bytes_per_world_cell =
        ((double)cells * sizeof(int32_t) + (double)es.peak_scratch_bytes) / (double)cells;
    r->refused_windows = log.refused;
    r->profile_length = trade_profile_length(&spec);
    r->profile = malloc((size_t)r->profile_length * sizeof *r->profile);
    if (!r->profile) {
        error_set(err, "out of memory");
        goto done;
    }
    trade_profile_sample(&spec, &w, r->profile);
    rc = 0;
done:
    stat_series_free(&log.tick_ms);
    sim_engine_destroy(engine);
    if (backend)
        backend->destroy(backend);
    free(before);
    free(after);
    world_free(&w);
    scene_free(&sc);
    return rc;
}

/*
 * One row: the configuration at every heading. Cost, drift and slope come
 * from the 0° run; the cross-section error compares the 0° trail with the
 * reference; the anisotropy is the largest difference between headings.
 */
static int measure_row(int scene_index, const char *model, const char *backend, double cell_m,
                       int iterations, const double *reference, int reference_length,
                       trade_row *row, error_text *err)
{
    run_result runs[HEADING_COUNT];
    int done = 0, rc = -1;
    for (; done < HEADING_COUNT; done++) {
        error_text run_err = {{0}};
        if (run_scene(scene_index, model, backend, cell_m, iterations, headings_deg[done],
                      &runs[done], &run_err) != 0) {
            error_set(err, "%s %s %s cell %g m, %d iterations, %g deg: %s",
                      trade_scene_names[scene_index], model, backend, cell_m, iterations,
                      headings_deg[done], run_err.message);
            goto out;
        }
    }
    if (runs[0].profile_length != reference_length) {
        error_set(err, "%s: profile has %d samples, reference %d", trade_scene_names[scene_index],
                  runs[0].profile_length, reference_length);
        goto out;
    }
    memset(row, 0, sizeof *row);
    row->model = model;
    row->scene = trade_scene_names[scene_index];
    row->backend = backend;
    row->renderer = strcmp(backend, "gl") == 0 ? gl_renderer : cpu_renderer;
    row->role = "sweep";
    row->cell_m = cell_m;
    row->iterations = iterations;
    row->world_cells = runs[0].world_cells;
    row->ticks = runs[0].ticks;
    row->tick_ms_mean = runs[0].tick_ms_mean;
    row->tick_ms_p95 = runs[0].tick_ms_p95;
    row->scratch_bytes_peak = runs[0].scratch_bytes_peak;
    row->bytes_per_world_cell = runs[0].bytes_per_world_cell;
    row->volume_drift = runs[0].volume_drift;
    row->max_slope_excess_m = runs[0].max_slope_excess_m;
    row->cross_section_rms_m = trade_rms_difference(runs[0].profile, reference, reference_length);
    for (int a = 0; a < HEADING_COUNT; a++) {
        row->refused_windows += runs[a].refused_windows;
        for (int b = a + 1; b < HEADING_COUNT; b++) {
            double d = trade_rms_difference(runs[a].profile, runs[b].profile, reference_length);
            row->anisotropy_rms_m = fmax(row->anisotropy_rms_m, d);
        }
    }
    rc = 0;
out:
    for (int i = 0; i < done; i++)
        free(runs[i].profile);
    return rc;
}

/* ---- Output ---- */

static void csv_text(FILE *f, const char *s)
{
    fputc('"', f);
    for (; *s; s++) {
        if (*s == '"')
            fputc('"', f);
        fputc(*s, f);
    }
    fputc('"', f);
}

static int write_csv(const char *path, const trade_row *rows, int count)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return -1;
    fprintf(f, "model,scene,backend,role,cell_m,iterations,world_cells,ticks,tick_ms_mean,"
               "tick_ms_p95,scratch_bytes_peak,bytes_per_world_cell,volume_drift,"
               "cross_section_rms_m,max_slope_excess_m,anisotropy_rms_m,refused_windows,"
               "renderer\n");
    for (int i = 0; i < count; i++) {
        const trade_row *r = &rows[i];
        fprintf(f, "%s,%s,%s,%s,%g,%d,%lld,%ld,%.4f,%.4f,%llu,%.3f,%.6g,%.6g,%.6g,%.6g,%ld,",
                r->model, r->scene, r->backend, r->role, r->cell_m, r->iterations,
                (long long)r->world_cells, r->ticks, r->tick_ms_mean, r->tick_ms_p95,
                (unsigned long long)r->scratch_bytes_peak, r->bytes_per_world_cell, r->volume_drift,
                r->cross_section_rms_m, r->max_slope_excess_m, r->anisotropy_rms_m,
                r->refused_windows);
        csv_text(f, r->renderer);
        fputc('\n', f);
    }
    return fclose(f) != 0 ? -1 : 0;
}

static void print_row_line(FILE *f, const trade_row *r)
{
    fprintf(f, "%-10s %-18s %-4s %-11s %6.4f %4d %9.3f %9.3f %8.1f %8.2g %9.3f %9.2f %9.3f\n",
            r->scene, r->model, r->backend, r->role, r->cell_m, r->iterations, r->tick_ms_mean,
            r->tick_ms_p95, r->bytes_per_world_cell, r->volume_drift, r->cross_section_rms_m * 1e3,
            r->max_slope_excess_m * 1e3, r->anisotropy_rms_m * 1e3);
}

static void print_header(FILE *f)
{
    fprintf(f, "%-10s %-18s %-4s %-11s %6s %4s %9s %9s %8s %8s %9s %9s %9s\n", "scene", "model",
            "back", "role", "cell_m", "iter", "ms_mean", "ms_p95", "B/cell", "drift", "xsect_mm",
            "slope_mm", "aniso_mm");
}

/*
 * The compact table (the reference rows and every run at the thesis's 10
 * iterations, or the nearest count of the sweep) and the summary: per scene,
 * the reference beside each model's fastest configuration.
 */
static void print_report(FILE *f, const trade_row *rows, int count, int table_iterations,
                         int reference_iterations, const double *convergence_m,
                         const trade_options *o)
{
    fprintf(f, "runs at %d iterations, and the reference (cross-section error against it):\n",
            table_iterations);
    print_header(f);
    for (int i = 0; i < count; i++)
        if (strcmp(rows[i].role, "sweep") != 0 || rows[i].iterations == table_iterations)
            print_row_line(f, &rows[i]);
    fprintf(f, "\nsummary: the reference against each model's fastest run (cpu and gl)\n");
    print_header(f);
    for (int s = 0; s < o->scene_count; s++) {
        const char *scene_name = trade_scene_names[o->scenes[s]];
        for (int i = 0; i < count; i++)
            if (strcmp(rows[i].scene, scene_name) == 0 && strcmp(rows[i].role, "reference") == 0)
                print_row_line(f, &rows[i]);
        const char *backends[2] = {"cpu", "gl"};
        for (int m = 0; m < o->model_count; m++)
            for (int b = 0; b < 2; b++) {
                const trade_row *best = NULL;
                for (int i = 0; i < count; i++) {
                    const trade_row *r = &rows[i];
                    if (strcmp(r->scene, scene_name) == 0 && strcmp(r->role, "sweep") == 0 &&
                        strcmp(r->model, trade_model_names[o->models[m]]) == 0 &&
                        strcmp(r->backend, backends[b]) == 0 &&
                        (!best || r->tick_ms_mean < best->tick_ms_mean))
                        best = r;
                }
                if (best)
                    print_row_line(f, best);
            }
        fprintf(f, "  %s reference converged: %d/%d vs %d/%d iterations differ by %.4f mm RMS\n",
                scene_name, reference_iterations, reference_iterations, 2 * reference_iterations,
                2 * reference_iterations, convergence_m[s] * 1e3);
    }
}

/* The sweep's plan and what it has measured so far. */
typedef struct bench_sweep {
    trade_options o;
    const double *cells_m;
    int cell_count;
    const int *iterations;
    int iteration_count;
    double finest_m, gl_one_m;
    const char *reference_model;
    int reference_iterations;
    trade_row *rows;
    int row_count;
    double convergence_m[16];
    double started;
    trade_physical_row physical[TRADE_PHYSICAL_MAX]; /* bekker against Ding 2011 */
    int physical_count;
} bench_sweep;

static void bench_plan(bench_sweep *b)
{
    int quick = b->o.quick;
    b->cells_m = quick ? quick_cells_m : full_cells_m;
    b->cell_count = quick ? 2 : 3;
    b->iterations = quick ? quick_iterations : full_iterations;
    b->iteration_count = quick ? 2 : 4;
    b->finest_m = b->cells_m[b->cell_count - 1];
    b->gl_one_m = b->cells_m[b->cell_count - 2]; /* GL's single cell size by default */
    b->reference_model = "persson-iterative";
    b->reference_iterations = quick ? quick_reference_iterations : full_reference_iterations;
}

/* One model's rows of one scene: every backend, cell size and iteration count. */
static int bench_sweep_model(bench_sweep *b, int scene_index, const char *model,
                             const run_result *ref, error_text *err)
{
    for (int k = 0; k < 2; k++) {
        const char *backend = k == 0 ? "cpu" : "gl";
        for (int c = 0; c < b->cell_count; c++) {
            int wanted = k == 0 ? b->o.cpu_all
                                : b->o.gl_all || (b->o.gl_one && b->cells_m[c] == b->gl_one_m);
            if (!wanted)
                continue;
            for (int it = 0; it < b->iteration_count; it++) {
                if (measure_row(scene_index, model, backend, b->cells_m[c], b->iterations[it],
                                ref->profile, ref->profile_length, &b->rows[b->row_count],
                                err) != 0)
                    return -1;
                b->row_count++;
            }
        }
    }
    return 0;
}

/* One scene: the reference, its convergence check, then every model. */
static int bench_sweep_scene(bench_sweep *b, int s, error_text *err)
{
    int scene_index = b->o.scenes[s];
    const char *scene_name = trade_scene_names[scene_index];
    run_result ref;
    if (run_scene(scene_index, b->reference_model, "cpu", b->finest_m, b->reference_iterations, 0.0,
                  &ref, err) != 0) {
        error_prefix(err, scene_name, " reference: ");
        return -1;
    }
    int rc = -1;
    /* the reference and its convergence check, measured like any row */
    const int ref_iterations[2] = {b->reference_iterations, 2 * b->reference_iterations};
    const char *roles[2] = {"reference", "convergence"};
    for (int k = 0; k < 2; k++) {
        trade_row *row = &b->rows[b->row_count];
        if (measure_row(scene_index, b->reference_model, "cpu", b->finest_m, ref_iterations[k],
                        ref.profile, ref.profile_length, row, err) != 0)
            goto out;
        row->role = roles[k];
        b->row_count++;
    }
    b->convergence_m[s] = b->rows[b->row_count - 1].cross_section_rms_m;
    fprintf(stderr, "trade: %s: reference %s %g m %d/%d; %d/%d differs by %.4f mm RMS (%.0f s)\n",
            scene_name, b->reference_model, b->finest_m, b->reference_iterations,
            b->reference_iterations, 2 * b->reference_iterations, 2 * b->reference_iterations,
            b->convergence_m[s] * 1e3, (time_now_ms() - b->started) / 1e3);
    for (int m = 0; m < b->o.model_count; m++) {
        const char *model = trade_model_names[b->o.models[m]];
        if (bench_sweep_model(b, scene_index, model, &ref, err) != 0)
            goto out;
        fprintf(stderr, "trade: %s %s done (%.0f s)\n", scene_name, model,
                (time_now_ms() - b->started) / 1e3);
    }
    rc = 0;
out:
    free(ref.profile);
    return rc;
}

/* trade.csv and trade.txt, and the report on stdout. */
static int bench_write(bench_sweep *b, const char *csv_path, const char *txt_path,
                       const char *physical_path)
{
    if (write_csv(csv_path, b->rows, b->row_count) != 0) {
        fprintf(stderr, "terrad bench: cannot write %s: %s\n", csv_path, strerror(errno));
        return -1;
    }
    if (b->physical_count == 0)
        remove(physical_path); /* not measured this time: no stale file beside the CSV */
    else if (trade_physical_write_csv(physical_path, b->physical, b->physical_count) != 0) {
        fprintf(stderr, "terrad bench: cannot write %s: %s\n", physical_path, strerror(errno));
        return -1;
    }
    char subtitle[700];
    snprintf(subtitle, sizeof subtitle, "%s%s%s; %s sweep, %d rows", cpu_renderer,
             gl_renderer[0] ? " / gl: " : "", gl_renderer, b->o.quick ? "quick" : "full",
             b->row_count);
    int table_iterations = b->iterations[b->iteration_count - 1] >= 10 ? 10 : b->iterations[0];
    FILE *txt = fopen(txt_path, "w");
    if (!txt) {
        fprintf(stderr, "terrad bench: cannot write %s: %s\n", txt_path, strerror(errno));
        return -1;
    }
    fprintf(txt, "terrad bench --trade (%s sweep): %s\n", b->o.quick ? "quick" : "full", subtitle);
    fprintf(txt, "lengths in mm; drift = |dSum h| / material displaced; %.0f s\n\n",
            (time_now_ms() - b->started) / 1e3);
    print_report(txt, b->rows, b->row_count, table_iterations, b->reference_iterations,
                 b->convergence_m, &b->o);
    if (b->physical_count)
        trade_physical_report(txt, b->physical, b->physical_count);
    if (fclose(txt) != 0) {
        fprintf(stderr, "terrad bench: cannot write %s\n", txt_path);
        return -1;
    }
    print_report(stdout, b->rows, b->row_count, table_iterations, b->reference_iterations,
                 b->convergence_m, &b->o);
    if (b->physical_count)
        trade_physical_report(stdout, b->physical, b->physical_count);
    printf("\nwrote %s, %s (%d rows, %.0f s); plot it with scripts/trade-plot %s OUT.svg\n",
           csv_path, txt_path, b->row_count, (time_now_ms() - b->started) / 1e3, csv_path);
    return 0;
}

int app_bench(int argc, char **argv)
{
    bench_sweep b = {0};
    cli_result parsed = parse_options(argc, argv, &b.o);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    trade_options *o = &b.o;
    log_set_quiet(1);
    char csv_path[1200], txt_path[1200], physical_path[1200];
    snprintf(csv_path, sizeof csv_path, "%s/trade.csv", o->out_dir);
    snprintf(physical_path, sizeof physical_path, "%s/trade-physical.csv", o->out_dir);
    snprintf(txt_path, sizeof txt_path, "%s/trade.txt", o->out_dir);
    /* Refuse an unusable --out before spending minutes on the sweep. */
    FILE *probe = NULL;
    if (make_dirs(o->out_dir) != 0 || !(probe = fopen(csv_path, "w"))) {
        fprintf(stderr, "terrad bench: --out %s: cannot write %s: %s\n", o->out_dir, csv_path,
                strerror(errno));
        return 1;
    }
    fclose(probe);
    bench_plan(&b);
    int row_capacity = o->scene_count * (2 + o->model_count * 2 * b.cell_count * b.iteration_count);
    b.rows = calloc((size_t)row_capacity, sizeof *b.rows);
    if (!b.rows) {
        fprintf(stderr, "terrad bench: out of memory\n");
        return 1;
    }
    if (o->gl_one) {
        /* GL is only asked for by default here: without a context, say so and go on. */
        error_text gl_err = {{0}};
        sim_backend *gl = host_backend_create("gl", NULL, 0, &gl_err);
        if (gl) {
            gl->destroy(gl);
        } else {
            fprintf(stderr, "trade: GL backend unavailable, GL rows skipped: %s\n", gl_err.message);
            o->gl_one = 0;
        }
    }
    b.started = time_now_ms();
    int rc = 1;
    error_text err = {{0}};
    for (int s = 0; s < o->scene_count; s++)
        if (bench_sweep_scene(&b, s, &err) != 0) {
            fprintf(stderr, "terrad bench: %s\n", err.message);
            goto done;
        }
    /* the physical axis: the model with forces against measured data */
    for (int m = 0; m < o->model_count; m++)
        if (strcmp(trade_model_names[o->models[m]], "bekker") == 0) {
            if (trade_physical_run(o->quick, b.physical, &b.physical_count, &err) != 0) {
                fprintf(stderr, "terrad bench: physical axis: %s\n", err.message);
                goto done;
            }
            fprintf(stderr, "trade: bekker against Ding 2011 done (%.0f s)\n",
                    (time_now_ms() - b.started) / 1e3);
        }
    if (bench_write(&b, csv_path, txt_path, physical_path) == 0)
        rc = 0;
done:
    free(b.rows);
    return rc;
}
