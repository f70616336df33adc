/*
 * sim: the deformation pipeline of Persson's thesis, ch. 4, in integers.
 *
 * One tick (DESIGN.md steps 3-7): colliders' footprints, swept from their last
 * pose to this one plus a margin, become rectangles, merged until disjoint:
 * the windows. Each window is gathered from the world, handed to a backend
 * (GL compute or the CPU twin), and scattered back. A backend runs, per
 * window:
 *
 *   depth        lowest collider point above each cell (collider/)
 *   classify     penetration, compression, seed / obstacle / penetrating
 *   jump_flood   nearest seed of every cell (Euclidean, Manhattan, Chebyshev)
 *   displace     iterative, SSBO single target, or SSBO multiple targets
 *   even_slopes  interleaved passes or SSBO, towards the angle of repose
 *
 * Everything after depth is integer-only and exactly specified by the CPU
 * twin below (sim_stages.c); the GLSL in shaders/ mirrors it line for line,
 * so the two backends give identical heights for identical depth input.
 * Volume: with compression 0 every unit taken from a column lands in exactly
 * one other column of the same window, so Σh over the world is unchanged.
 */
#ifndef TERRAD_SIM_H
#define TERRAD_SIM_H

#include <stdint.h>

#include "base/base.h"
#include "collider/collider.h"
#include "world/world.h"

/* Windows are at most this many cells on a side, so squared Euclidean
 * distances inside one fit in int32. */
#define SIM_WINDOW_SIDE_MAX 16384

typedef enum sim_metric {
    SIM_METRIC_EUCLIDEAN,
    SIM_METRIC_MANHATTAN,
    SIM_METRIC_CHEBYSHEV,
} sim_metric;

/* The thesis's Table 5.1 combinations. */
typedef enum sim_method {
    SIM_METHOD_ITERATIVE, /* iterative displacement + interleaved slope passes */
    SIM_METHOD_SSBO,      /* single-target SSBO displacement + SSBO slopes */
    SIM_METHOD_MULTI,     /* multiple-target SSBO displacement + SSBO slopes */
} sim_method;

typedef enum sim_cell_class {
    SIM_CELL_SEED = 0,        /* free: can receive material */
    SIM_CELL_OBSTACLE = 1,    /* a collider rests just above: receives nothing */
    SIM_CELL_PENETRATING = 2, /* a collider is inside the column */
} sim_cell_class;

/* The material as a person writes it (scene files, the wire). */
typedef struct sim_material {
    double compression;      /* [0,1]: share of the penetration that is compacted away */
    double roughness;        /* [0,1]: share of the excess slope moved per slope iteration */
    double repose_deg;       /* [0,90): angle of repose */
    double obstacle_gap_m;   /* a collider this close above a column makes it an obstacle */
    double multi_target_m;   /* multi: material per target column */
    int multi_target_max;    /* multi: at most this many targets per column */
    int displace_iterations; /* iterative displacement passes per tick */
    int slope_iterations;    /* slope-evening iterations per tick */
    sim_metric metric;
    sim_method method;
} sim_material;

/* The defaults: the thesis's Table 5.3 (10 and 10 iterations), compression 0. */
sim_material sim_material_default(void);

/* The integer form of a material, computed once on the CPU. */
typedef struct sim_params {
    sim_metric metric;
    sim_method method;
    int32_t compression_q16;          /* 0..65536 */
    int32_t roughness_q16;            /* 0..65536 */
    int32_t slope_threshold_axial;    /* units of height difference */
    int32_t slope_threshold_diagonal; /* units of height difference */
    int32_t obstacle_gap;             /* units */
    int32_t multi_target_step;        /* units per target, >= 1 */
    int32_t multi_target_max;         /* >= 1 */
    int32_t displace_iterations;
    int32_t slope_iterations;
    int32_t floor; /* units */
} sim_params;

int sim_params_from_material(const sim_material *m, double cell_size_m, int32_t units_per_m,
                             int32_t floor, sim_params *p, error_text *err);

const char *sim_metric_name(sim_metric m);
const char *sim_method_name(sim_method m);
int sim_metric_parse(const char *name, sim_metric *out);
int sim_method_parse(const char *name, sim_method *out);

/* ---- The CPU twin's integer stages, on window-local row-major arrays ---- */

/* Hash of a world cell, used to break jump-flooding ties (same in GLSL). */
uint32_t sim_cell_hash(int32_t world_x, int32_t world_y);
/* Distance under a metric; Euclidean is squared (order is all that matters). */
int32_t sim_metric_distance(sim_metric m, int32_t dx, int32_t dy);

/*
 * classify: raw[i] = penetration (units the column must lose), moved[i] =
 * the part of it that is displaced (raw minus compression), cls[i] = class.
 */
void sim_classify(const sim_params *p, int cell_count, const int32_t *heights,
                  const int32_t *bottom, int32_t *raw, int32_t *moved, int32_t *cls);

/*
 * jump_flood: seed[i] = window-local index of the nearest seed cell, or -1 if
 * the window has none. scratch holds w*h int32. Ties go to the lower
 * (sim_cell_hash, index) of the candidate seed, so the answer does not
 * depend on evaluation order.
 */
void sim_jump_flood(const sim_params *p, int w, int h, int origin_x, int origin_y,
                    const int32_t *cls, int32_t *seed, int32_t *scratch);

/* Outcome of a window. */
typedef enum sim_window_status {
    SIM_WINDOW_OK = 0,
    SIM_WINDOW_HEIGHT_LIMIT = 1, /* a column would leave the height range: refused */
} sim_window_status;

/*
 * displace: heights[i] -= raw[i], and the moved material lands by the
 * params' method. `scratch` holds 5*w*h int32. Returns SIM_WINDOW_HEIGHT_LIMIT
 * (heights then unspecified; the caller discards the window) if a column
 * would leave [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX].
 */
sim_window_status sim_displace(const sim_params *p, int w, int h, const int32_t *cls,
                               const int32_t *seed, const int32_t *raw, const int32_t *moved,
                               int32_t *heights, int32_t *scratch);

/* even_slopes: params.slope_iterations Jacobi iterations; scratch holds 2*w*h int32. */
void sim_even_slopes(const sim_params *p, int w, int h, const int32_t *cls, int32_t *heights,
                     int32_t *scratch);

/* Largest height difference above the repose threshold between neighbours. */
int64_t sim_max_slope_excess(const sim_params *p, int w, int h, const int32_t *heights);

/* ---- Backends ---- */

typedef struct sim_stage_times {
    double depth, classify, jump_flood, displace, even_slopes, transfer; /* ms */
} sim_stage_times;

/* A collider as the backends see it in one tick. */
typedef struct sim_collider {
    int id;
    const collider_geometry *geometry;
    collider_pose pose;
    collider_pose previous_pose;
    int has_previous; /* 0 on the first tick it exists: footprint is the pose alone */
} sim_collider;

typedef struct sim_window_job {
    world_rect rect;               /* world cells */
    double cell_size_m;            /* for the depth stage */
    int32_t units_per_m;           /* for the depth stage */
    int32_t *heights;              /* in: gathered heights; out: new heights (w*h) */
    const sim_collider *colliders; /* those whose footprint meets the window */
    int collider_count;
    int32_t depth_low, depth_high;  /* height range the depth stage must resolve (units) */
    const int32_t *bottom_override; /* non-NULL: use this depth, skip the depth stage */
    int32_t *bottom_out;            /* non-NULL: receives the depth that was used */
    const world *world; /* where the window was gathered from (a backend's tile cache) */
} sim_window_job;

typedef struct sim_backend sim_backend;
struct sim_backend {
    const char *name;   /* "gl" or "cpu" */
    char renderer[256]; /* GL_RENDERER, or a description of the CPU */
    char version[256];  /* GL_VERSION, or "C twin" */
    /*
     * Run every window of one tick (disjoint rectangles) as one batch, so a GL
     * backend issues one dispatch per stage for all of them. Sets status[i]
     * (a sim_window_status) per window; times accumulate per stage. Returns 0,
     * or -1 with err set on a backend failure.
     */
    int (*run_windows)(sim_backend *b, const sim_params *p, sim_window_job *jobs, int job_count,
                       int *status, sim_stage_times *times, error_text *err);
    /* Drop anything cached for a geometry that is about to be freed. */
    void (*forget_geometry)(sim_backend *b, const collider_geometry *g);
    uint64_t (*scratch_bytes)(const sim_backend *b); /* scratch memory held now */
    /* Optional (NULL if none): the engine has scattered window `window` of the
     * batch just run into w, so a backend that caches tiles can tell its
     * copy of them is current (or not). */
    void (*window_scattered)(sim_backend *b, int window, const world *w, world_rect r);
    void (*destroy)(sim_backend *b);
    void *impl;
};

sim_backend *sim_backend_cpu_create(error_text *err);

/* ---- The tick over a world ---- */

typedef struct sim_tick_report {
    int window_count;
    int64_t active_cells;
    int refused_windows; /* windows refused at the height limit */
    sim_stage_times times;
    double gather_scatter_ms;
    world_rect *dirty; /* tight rectangles of changed cells, one per changed window */
    int *dirty_window; /* the window each dirty rectangle came from */
    int dirty_count;
} sim_tick_report;

typedef struct sim_engine {
    world *world;
    sim_params params;
    sim_backend *backend;
    int margin_cells;
    int depth_from_cpu; /* feed the CPU twin's depth to the backend (GL ≡ CPU tests) */
    /* reusable scratch, grown to the largest tick seen */
    world_rect *windows;
    sim_window_job *jobs;
    int *status;
    world_rect *dirty;
    int *dirty_window;
    int64_t *window_offsets; /* where each window starts in the packed arrays */
    int window_capacity;
    world_rect *footprints; /* per collider */
    int footprint_capacity;
    sim_collider *window_colliders;
    int window_collider_capacity;
    int32_t *heights, *before, *bottom; /* all windows of a tick, packed */
    int64_t cell_capacity;
    uint64_t peak_scratch_bytes; /* engine's own plus the backend's, high-water mark */
    int64_t peak_active_cells;
} sim_engine;

int sim_engine_init(sim_engine *e, world *w, const sim_params *p, sim_backend *backend,
                    int margin_cells, error_text *err);
/* Returns 0, or -1 with err set if the backend failed (the world is unchanged then). */
int sim_engine_tick(sim_engine *e, const sim_collider *colliders, int collider_count,
                    sim_tick_report *report, error_text *err);
void sim_engine_free(sim_engine *e);
/* After a tick: window i of the last tick, its heights before and after. */
world_rect sim_engine_window(const sim_engine *e, int i, const int32_t **before,
                             const int32_t **after);

/*
 * Footprints → disjoint windows (exposed for tests). footprints[i] receives
 * collider i's footprint (w == 0 when it cannot touch the terrain). Windows
 * are sorted by (y, x). Caller frees *out.
 */
int sim_plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                     int collider_count, int margin_cells, world_rect *footprints, world_rect **out,
                     int *out_count);

#endif
