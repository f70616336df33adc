/*
 * trade_internal.h: the pieces of `terrad bench --trade` (bench_trade.c)
 * shared by its files — the standard scenes built in code at any cell size
 * and heading (trade_scenes.c), the trail cross-section sampler, the model
 * list. The plot is drawn from trade.csv by scripts/trade-plot
 * (matplotlib). Nothing outside server/app/
 * uses these.
 */
#ifndef TERRAD_TRADE_INTERNAL_H
#define TERRAD_TRADE_INTERNAL_H

#include <stdint.h>
#include <stdio.h>

#include "base/base.h"
#include "scene/scene.h"
#include "sim/sim.h"
#include "world/world.h"

/* ---- Models ---- */

/* Every model the trade knows, in plotting order (index = colour/marker). */
extern const char *const trade_model_names[];
extern const int trade_model_count;
/* Index of a model name in trade_model_names, or -1. */
int trade_model_index(const char *name);
/*
 * The one place that says what a model name means for a material: sets the
 * fields that select the model, leaves the rest (snow, iterations) alone.
 * Returns 0, or -1 with err naming the model if it is unknown.
 */
int trade_model_configure(const char *name, sim_material *m, error_text *err);

/* ---- Scenes and the trail cross-section ---- */

#define TRADE_STATION_MAX 8

/*
 * Where a run's trail is sampled: lines across the trail at `stations`
 * (metres along it, in the scene's own frame: x along the trail, y across)
 * from across_lo to across_hi every step_m, mapped to world coordinates by
 * the heading the scene was built at. Samples are physical positions, so
 * runs at different cell sizes and headings give comparable profiles.
 */
typedef struct trade_profile_spec {
    double stations[TRADE_STATION_MAX];
    int station_count;
    double across_lo_m, across_hi_m, step_m;
    double origin_x, origin_y; /* world metres of the scene frame's origin */
    double cos_heading, sin_heading;
    double base_m; /* untouched snow surface: profiles are heights above it */
} trade_profile_spec;

extern const char *const trade_scene_names[];
extern const int trade_scene_count;
int trade_scene_index(const char *name);
/* One line on what the scene is (for the docs and --help). */
const char *trade_scene_about(int index);

/*
 * Build standard scene `index` with cells of cell_m metres, its trail
 * heading heading_deg from the world's x axis, the thesis's snow and
 * `material` (model and iterations already set). The world is a square big
 * enough for every heading, the same physical size at every cell size.
 * *ticks receives the run length. The caller scene_free()s *out.
 */
int trade_scene_build(int index, double cell_m, double heading_deg, const sim_material *material,
                      scene *out, long *ticks, trade_profile_spec *profile, error_text *err);

/* Number of samples trade_profile_sample writes. */
int trade_profile_length(const trade_profile_spec *p);
/* Bilinear heights (metres above base) at the profile's sample points. */
void trade_profile_sample(const trade_profile_spec *p, const world *w, double *out);
/*
 * The world cells under the cross-sections (their bounding rectangle, one
 * cell wider): the finished trail, away from where colliders rest at the end.
 */
world_rect trade_profile_rect(const trade_profile_spec *p, const world *w);
/* Root mean square of a - b over n samples. */
double trade_rms_difference(const double *a, const double *b, int n);

/* ---- Rows and the plot ---- */

typedef struct trade_row {
    const char *model;
    const char *scene;
    const char *backend;
    const char *renderer;
    const char *role; /* "reference", "convergence" or "sweep" */
    double cell_m;
    int iterations;
    int64_t world_cells;
    long ticks;
    double tick_ms_mean, tick_ms_p95;
    uint64_t scratch_bytes_peak;
    double bytes_per_world_cell;
    double volume_drift;        /* |ΔΣh| / material displaced */
    double cross_section_rms_m; /* against the reference */
    double max_slope_excess_m;  /* over trade_profile_rect */
    double anisotropy_rms_m;    /* max over heading pairs */
    long refused_windows;
} trade_row;

/* ---- The physical axis (trade_physical.c) ---- */

/* One configuration of the bekker model on one of Ding 2011's wheels. */
typedef struct trade_physical_row {
    int lugged; /* 0: the smooth wheel, 1: the lugged (30 lugs, 10 mm) */
    double cell_m, tick_mm;
    long ticks;
    double tick_ms_mean; /* wall, mean over the slips */
    double pull_n[SIM_WHEEL_DING2011_ROWS], sinkage_m[SIM_WHEEL_DING2011_ROWS],
        torque_nm[SIM_WHEEL_DING2011_ROWS];
    double pull_error, sinkage_error, torque_error; /* median relative, against Ding */
    double pull_rms_vs_finest_n, sinkage_rms_vs_finest_m;
} trade_physical_row;
#define TRADE_PHYSICAL_MAX 18
/* Every configuration (quick: two) of the smooth wheel, then the same of the
 * lugged, each wheel's finest last; 0 or -1 with err. */
int trade_physical_run(int quick, trade_physical_row *rows, int *count, error_text *err);
/* DIR/trade-physical.csv: 0, or -1 (errno) */
int trade_physical_write_csv(const char *path, const trade_physical_row *rows, int count);
/* The table for trade.txt and stdout. */
void trade_physical_report(FILE *f, const trade_physical_row *rows, int count);

#endif
