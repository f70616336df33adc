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
#include "ground/ground.h"
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

/*
 * The deformation model of a material (docs/models.md). The three persson-*
 * models run on the backends (GL or CPU twin) through the stages above; the
 * others are CPU window functions in server/sim/model_<name>.c that the
 * engine calls per window, taking the model from the window's params, so a
 * per-cell material layer can route each window (or cell) by its material.
 */
typedef enum sim_model {
    SIM_MODEL_PERSSON_ITERATIVE,
    SIM_MODEL_PERSSON_SSBO,
    SIM_MODEL_PERSSON_MULTI,
    SIM_MODEL_SUBTRACT,  /* depth-buffer subtraction, optional refill (loses volume) */
    SIM_MODEL_DEFERRED,  /* quadratic trail with raised edges, point-based (loses volume) */
    SIM_MODEL_DIFFUSION, /* Gilardi's drift-diffusion: integer flux form or their float scheme */
    SIM_MODEL_SUMNER,    /* Sumner, O'Brien and Hodgins 1999 on the CPU: the accuracy reference */
    SIM_MODEL_DECALS,    /* no deformation: footprint events only */
} sim_model;

#define SIM_MODEL_COUNT 8

/* Diffusion's sub-stepping: automatic (stable for any dt) or a fixed count. */
#define SIM_DIFFUSION_SUBSTEPS_AUTO 0
/* Automatic sub-stepping never runs more than this many per tick; beyond it
 * each substep is at the stability bound and the tick is saturated. */
#define SIM_DIFFUSION_SUBSTEPS_MAX 64

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
    sim_method method; /* the persson variant; kept in step with model */
    sim_model model;
    double tick_s; /* seconds per tick (the scene's 1/tick_hz): refill is per second */
    /* subtract */
    double refill_m_per_s; /* >= 0: cells below the base terrain rise back at this rate */
    /* deferred (Wasmut ch. 4.2.2) */
    double trail_scale_per_m; /* artist's scale: trail height rises by d^2 * scale (d in m) */
    double trail_range_m;     /* half side of the square each contact point writes */
    double edge_height;       /* rim height as a share of the trail's depth, >= 0 */
    double edge_width;        /* rim width as a share of the trail's radius, > 0 */
    /* diffusion (Gilardi eq. 1-8) */
    double diffusion_d;           /* D, cells^2 per unit of Gilardi time */
    double diffusion_zeta_inv;    /* ζ⁻¹, the inverse friction */
    double diffusion_force_scale; /* force per cell of penetration (F = scale * p) */
    double diffusion_dt;          /* Δt per tick in Gilardi's time */
    int diffusion_substeps;       /* SIM_DIFFUSION_SUBSTEPS_AUTO or a fixed count >= 1 */
    int diffusion_conservative;   /* 1: integer flux form (Σh exact); 0: their float scheme */
    /* decals */
    double decal_min_strength_m; /* a footprint shallower than this sends no event */
} sim_material;

/* Gilardi's material presets (their Fig. 4): "mud", "pebbles", "sand". Sets D,
 * ζ⁻¹ and the angle of repose; returns -1 for an unknown name. */
int sim_material_diffusion_preset(sim_material *m, const char *name);

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
    sim_model model;
    int64_t refill_q16_per_tick; /* subtract: units per tick, Q16 */
    int32_t trail_scale_q16;     /* deferred: units per cell^2, Q16 */
    int32_t trail_range_cells;   /* deferred */
    int32_t edge_height_q16;     /* deferred: share of depth, Q16 */
    int32_t edge_width_q16;      /* deferred: share of radius, Q16 */
    double diffusion_d, diffusion_zeta_inv, diffusion_force_scale, diffusion_dt;
    int32_t diffusion_substeps;
    int32_t diffusion_conservative;
    double repose_rad;          /* diffusion's float scheme: α of eq. 4 */
    double cell_size_m;         /* the float scheme measures heights in cells */
    int32_t units_per_m;        /* ditto */
    int32_t decal_min_strength; /* units */
} sim_params;

int sim_params_from_material(const sim_material *m, double cell_size_m, int32_t units_per_m,
                             int32_t floor, sim_params *p, error_text *err);

const char *sim_model_name(sim_model m);
/* Every model a scene may name. */
int sim_model_parse(const char *name, sim_model *out);
/* 1 for the persson-* models (the backends' stages), 0 otherwise. */
int sim_model_is_persson(sim_model m);
/* The persson model of a method, and back. */
sim_model sim_model_from_method(sim_method m);

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

/* ---- Per-cell materials and compaction memory (sim_stages_materials.c) ----
 * The same stages with a material id per cell (an index into a small table of
 * integer rows) and, where some material remembers compaction, a uint16
 * compaction memory per cell (the table is ground/'s). With ids == NULL every
 * cell is row 0; with one row equal to the params and max_compaction 0 the
 * results are those of sim_classify / sim_even_slopes, bit for bit. */
/* A row from a material's integer params and its max compaction (units). */
ground_material_row sim_material_row_from_params(const sim_params *p, int32_t max_compaction);
/* The per-cell part of a material (compression, roughness, repose) as the
 * ground's base material, named "default", with no compaction memory. */
ground_material sim_material_ground(const sim_material *m);

/*
 * classify with per-cell materials. A penetrated column with compaction
 * memory m of its material's max M yields only pen - pen*m/M (compacted
 * ground resists; the collider rests in it), of which the material's
 * compression share (at most M - m) is compacted and the rest displaced:
 * raw[i] = yield, moved[i] = yield - compacted. memory may be NULL (m = 0).
 */
void sim_classify_materials(const sim_params *p, const ground_material_table *t, const uint8_t *ids,
                            const uint16_t *memory, int cell_count, const int32_t *heights,
                            const int32_t *bottom, int32_t *raw, int32_t *moved, int32_t *cls);
/* After a window is accepted: memory[i] += raw[i] - moved[i] where the
 * cell's material remembers compaction. */
void sim_compaction_commit(const ground_material_table *t, const uint8_t *ids, int cell_count,
                           const int32_t *raw, const int32_t *moved, uint16_t *memory);
/* even_slopes where each flux uses the material of the column it leaves. */
void sim_even_slopes_materials(const sim_params *p, const ground_material_table *t,
                               const uint8_t *ids, int w, int h, const int32_t *cls,
                               int32_t *heights, int32_t *scratch);
/* Largest excess above the threshold of the higher column's material. */
int64_t sim_max_slope_excess_materials(const ground_material_table *t, const uint8_t *ids, int w,
                                       int h, const int32_t *heights);

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

/* Scratch bytes held per stage (what an allocation is for, not when it runs). */
typedef struct sim_stage_memory {
    uint64_t depth, classify, jump_flood, displace, even_slopes; /* persson backends */
    uint64_t backend_other;  /* a backend's scratch it does not split by stage (GL) */
    uint64_t model;          /* the non-persson models' scratch (and base heights) */
    uint64_t gather_scatter; /* the engine's packed windows and bookkeeping */
} sim_stage_memory;

uint64_t sim_stage_memory_total(const sim_stage_memory *m);

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
    /* For the models that need them (NULL otherwise): */
    const int32_t *base_heights; /* the base terrain over rect (subtract refill, deferred) */
    int32_t refill_units;        /* subtract: how far a cell below base rises this tick */

    /* Per-cell materials (ground/): NULL for the uniform path (params only).
     * material_ids NULL: every cell is row 0. compaction (in/out) NULL when no
     * material remembers compaction; written only for accepted windows. */
    const ground_material_table *materials;
    const uint8_t *material_ids;
    uint16_t *compaction;
    const world *world; /* where the window was gathered from (a backend's tile cache) */
} sim_window_job;

/* ---- Sumner, O'Brien and Hodgins 1999 on the CPU (model_sumner.c) ----
 * The accuracy reference: ray-cast columns, first-ring displacement, erosion
 * by the slope-evening iterations. Σh exact with compression 0. Returns
 * SIM_WINDOW_HEIGHT_LIMIT with job->heights unchanged if a column would leave
 * the height range. `scratch` holds sim_sumner_scratch_cells(w, h) int32. */
int64_t sim_sumner_scratch_cells(int w, int h);
sim_window_status sim_sumner_window(const sim_params *p, sim_window_job *job, int32_t *scratch);

/* ---- The non-persson models: CPU window functions (model_<name>.c) ----
 *
 * Each takes the window's params (their model field picks the function in
 * sim_model_window), the job — with bottom_override holding the depth the
 * engine computed — and scratch of sim_model_scratch_cells(model, w*h) int32.
 * They change job->heights in place and return SIM_WINDOW_HEIGHT_LIMIT (the
 * engine then keeps the world's heights) when a column would leave the range.
 */
int64_t sim_model_scratch_cells(sim_model m, int64_t cells);
/* 1 when the model needs job->base_heights / the depth in bottom_override. */
int sim_model_needs_base(const sim_params *p);
int sim_model_needs_depth(sim_model m);
sim_window_status sim_model_window(const sim_params *p, sim_window_job *job, int32_t *scratch);

/* heights = max(min(heights, bottom), floor) after rising toward base by refill_units. */
sim_window_status sim_subtract_window(const sim_params *p, sim_window_job *job, int32_t *scratch);
/* Contact points → quadratic trail and rim in an integer image (min), then applied. */
sim_window_status sim_deferred_window(const sim_params *p, sim_window_job *job, int32_t *scratch);
/* Drift-diffusion, conservative integer flux form or Gilardi's float scheme. */
sim_window_status sim_diffusion_window(const sim_params *p, sim_window_job *job, int32_t *scratch);
/* Substeps the diffusion model runs for one tick (1 <= n <= SIM_DIFFUSION_SUBSTEPS_MAX
 * under auto), and the coefficients per substep (the bound is explained there). */
int sim_diffusion_substeps(const sim_params *p, double *c_diffusion, double *c_drift);

/* A footprint event of the decals model: where a collider touches the ground. */
typedef struct sim_footprint {
    int collider_id;
    double x_m, y_m;   /* centre of the touched cells, metres */
    double yaw_rad;    /* heading of the collider about z */
    double size_m;     /* side of a square with the touched area */
    double strength_m; /* deepest penetration */
} sim_footprint;

/* decals: one window's events (at most out_capacity); returns how many. */
int sim_decals_window(const sim_params *p, const sim_window_job *job, int32_t *scratch,
                      sim_footprint *out, int out_capacity);

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
    /* Optional (NULL: all of scratch_bytes counts as backend_other). */
    void (*stage_bytes)(const sim_backend *b, sim_stage_memory *out);
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
    double model_ms;                 /* the non-persson models' window functions */
    const sim_footprint *footprints; /* decals: this tick's events (engine-owned) */
    int footprint_count;
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
    int64_t bottom_capacity;     /* bottom is allocated only when the engine casts depth */
    uint64_t peak_scratch_bytes; /* engine's own plus the backend's, high-water mark */
    int64_t peak_active_cells;
    /* the non-persson models */
    int32_t *model_scratch;
    int64_t model_scratch_capacity; /* int32 */
    int32_t *base;                  /* base heights of the packed windows (models that need them) */
    int64_t base_capacity;
    int64_t refill_q16_accumulated; /* subtract: refill's fraction carried over */
    world_rect *refilling;          /* subtract: windows with cells still below base */
    int refilling_count, refilling_capacity;
    sim_footprint *footprints_out; /* decals: the last tick's events */
    int footprint_out_capacity;
    sim_stage_memory memory;      /* held after the last tick */
    sim_stage_memory peak_memory; /* per stage high-water mark */
    int warned_cpu_model;         /* "runs on the CPU" said once */
    /* Per-cell materials and compaction memory (sim_engine_set_ground). */
    struct ground *ground; /* not owned; NULL: one material, the params */
    uint8_t *material_ids; /* all windows of a tick, packed; only if not uniform */
    uint16_t *compaction;  /* likewise; only if some material compacts */
    int64_t ground_capacity;
} sim_engine;

int sim_engine_init(sim_engine *e, world *w, const sim_params *p, sim_backend *backend,
                    int margin_cells, error_text *err);
/* Returns 0, or -1 with err set if the backend failed (the world is unchanged then). */
int sim_engine_tick(sim_engine *e, const sim_collider *colliders, int collider_count,
                    sim_tick_report *report, error_text *err);
void sim_engine_free(sim_engine *e);
/* After sim_engine_init: the ground's per-cell layers (not owned; NULL: none). A
 * ground with one material equal to the params and no compaction memory
 * changes nothing: the uniform path runs. */
void sim_engine_set_ground(sim_engine *e, struct ground *g);
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
