/*
 * sim: the deformation pipeline of Persson's thesis, ch. 4, in integers — the
 * subsystem's whole public face: materials and their integer params, the
 * backend interface (a function table, like Redis's ae), the per-window job a
 * backend runs, and the engine that runs one tick over a world.
 *
 * One tick (docs/design.md, "One tick"): colliders' footprints, swept from
 * their last pose to this one plus a margin, become rectangles, merged until
 * disjoint: the windows. Each window is gathered from the world, handed to a
 * backend (GL compute or the CPU twin), and scattered back. A backend runs,
 * per window, the stages of SIM_STAGE_LIST (base.h):
 *
 *   depth        lowest collider point above each cell (collider/)
 *   classify     penetration, compression, seed / obstacle / penetrating
 *   jump_flood   nearest seed of every cell (Euclidean, Manhattan, Chebyshev)
 *   displace     iterative, SSBO single target, or SSBO multiple targets
 *   even_slopes  interleaved passes or SSBO, towards the angle of repose
 *
 * Everything after depth is integer-only and exactly specified by the CPU
 * twin (sim_stages.c, declared in sim_internal.h with the models' window
 * functions); the GLSL in shaders/ mirrors it line for line, so the two
 * backends give identical heights for identical depth input.
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
 * models run on the backends (GL or CPU twin) through the stages of
 * SIM_STAGE_LIST; the others are CPU window functions in
 * server/sim/model_<name>.c that the engine calls per window, taking the
 * model from the window's params, so a per-cell material layer can route
 * each window (or cell) by its material.
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
    SIM_MODEL_BEKKER,    /* Bekker-Wong pressure-sinkage, Janosi-Hanamoto shear: soil forces */
} sim_model;

#define SIM_MODEL_COUNT 9

/* Diffusion's sub-stepping: automatic (stable for any dt) or a fixed count. */
#define SIM_DIFFUSION_SUBSTEPS_AUTO 0
/* Automatic sub-stepping never runs more than this many per tick; beyond it
 * each substep is at the stability bound and the tick is saturated. */
#define SIM_DIFFUSION_SUBSTEPS_MAX 64

/* A soil's terramechanics parameters (the bekker model, docs/models.md):
 * ground.h's ground_soil, so each material of the ground's table carries one. */
typedef ground_soil sim_soil;

/* Soils of docs/models.md's table (Wong; Ding et al. 2011): "dry-sand",
 * "sandy-loam", "clayey-soil", "heavy-clay", "lete-sand", "snow-us",
 * "snow-sweden", "lunar", "ding2011". Returns 0, or -1 for an unknown name. */
int sim_soil_preset(const char *name, sim_soil *out);
/* The names sim_soil_preset knows, for errors. */
#define SIM_SOIL_PRESET_LIST                                                                       \
    "dry-sand | sandy-loam | clayey-soil | heavy-clay | lete-sand | snow-us | snow-sweden | "      \
    "lunar | ding2011"
/* Every field in its physical range; errors name "<path>.<field>". */
int sim_soil_validate(const sim_soil *s, const char *path, error_text *err);
/* Bekker's pressure (Pa) at sinkage z (m) under a patch of width b (m). */
double sim_soil_bekker_pa(const sim_soil *s, double b_m, double z_m);

/*
 * The single-wheel testbed (sim_testbed.c): a rigid wheel under a vertical
 * load, load-driven each tick, driven at a slip across a flat bin of the
 * bekker model; its drawbar pull, sinkage and driving torque are the means
 * over the second half of the distance. Deterministic.
 */
typedef struct sim_wheel_run {
    double radius_m, width_m, load_n;
    double slip;                /* [0, 1): the wheel turns at v / (R (1 - slip)) */
    double cell_m;              /* the bin's cells (default 0.005) */
    double distance_m;          /* default 0.5 */
    double speed_m_s;           /* default 0.05 */
    double tick_s;              /* default 0.05 (2.5 mm of travel a tick, as the tests) */
    double compression;         /* the material's share compacted, default 0.5 */
    collider_grousers grousers; /* the rim's lugs (zero: smooth); sinkage is then the tips' */
} sim_wheel_run;
typedef struct sim_wheel_result {
    double drawbar_pull_n; /* Fx on the wheel: > 0 pulls forward */
    double sinkage_m;      /* below the undisturbed surface, at the wheel's lowest point */
    double torque_nm;      /* the driving torque (minus the soil's about the axle) */
    long ticks;
} sim_wheel_result;
/* Zero wheel, the defaults above. */
void sim_wheel_run_defaults(sim_wheel_run *r);
/* 0, or -1 with err (a soil or run field out of range, or out of memory). */
int sim_wheel_testbed(const sim_soil *soil, const sim_wheel_run *run, sim_wheel_result *out,
                      error_text *err);
/* Ding et al. 2011 (J. Terramechanics 48(1):27-45, HIT testbed): the smooth
 * wheel of their Fig. 9 on their soil (preset "ding2011"), values read off
 * the plots (about +-0.5 mm, +-1 N; tests/validation/single-wheel-ding2011.csv),
 * for the validation test and the trade's physical axis. */
typedef struct sim_wheel_measured {
    double slip, drawbar_pull_n, sinkage_m, torque_nm;
} sim_wheel_measured;
#define SIM_WHEEL_DING2011_ROWS 6
#define SIM_WHEEL_DING2011_RADIUS_M 0.15735
#define SIM_WHEEL_DING2011_WIDTH_M 0.165
#define SIM_WHEEL_DING2011_LOAD_N 80.0
extern const sim_wheel_measured sim_wheel_ding2011[SIM_WHEEL_DING2011_ROWS];
/* Ding et al. 2011's lugged wheel (the same rim, soil and load; the CSV's
 * wheel=lugged rows): 30 lugs 10 mm tall. The lug thickness is not in the
 * data; 4 mm (a sheet-metal lug) stands in, and the bekker model's forces do
 * not depend on it (model_lugs.c: the lugs' envelope and their faces). */
#define SIM_WHEEL_DING2011_LUG_COUNT 30
#define SIM_WHEEL_DING2011_LUG_HEIGHT_M 0.010
#define SIM_WHEEL_DING2011_LUG_THICKNESS_M 0.004
extern const sim_wheel_measured sim_wheel_ding2011_lugged[SIM_WHEEL_DING2011_ROWS];

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
    /* bekker: the soil (compression: the share of a plastic sinkage compacted) */
    sim_soil soil;
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
    sim_soil soil;              /* bekker */
    double tick_s;              /* bekker: velocities from consecutive poses */
} sim_params;

int sim_params_from_material(const sim_material *m, double cell_size_m, int32_t units_per_m,
                             int32_t floor, sim_params *p, error_text *err);

const char *sim_model_name(sim_model m);
/* Every model a scene may name. */
int sim_model_parse(const char *name, sim_model *out);
/* Every model's name, for --help and errors, in sim_model order
 * (test_models checks it against sim_model_name). */
#define SIM_MODEL_LIST                                                                             \
    "persson-iterative | persson-ssbo | persson-multi | subtract | deferred | diffusion | "        \
    "sumner | decals | bekker"
/* 1 for the persson-* models (the backends' stages), 0 otherwise. */
int sim_model_is_persson(sim_model m);
/* The persson model of a method, and back. */
sim_model sim_model_from_method(sim_method m);

const char *sim_metric_name(sim_metric m);
const char *sim_method_name(sim_method m);
int sim_metric_parse(const char *name, sim_metric *out);
int sim_method_parse(const char *name, sim_method *out);

/* ---- Materials per cell (the table is ground/'s) ---- */

/* A row from a material's integer params and its max compaction (units). */
ground_material_row sim_material_row_from_params(const sim_params *p, int32_t max_compaction);
/* The per-cell part of a material (compression, roughness, repose) as the
 * ground's base material, named "default", with no compaction memory. */
ground_material sim_material_ground(const sim_material *m);

/* Outcome of a window. */
typedef enum sim_window_status {
    SIM_WINDOW_OK = 0,
    SIM_WINDOW_HEIGHT_LIMIT = 1, /* a column would leave the height range: refused */
} sim_window_status;

/* Measurements of a result (the simulate report, tests): the largest height
 * difference above the repose threshold between neighbours — with one
 * material, or with the threshold of the higher column's material. */
int64_t sim_max_slope_excess(const sim_params *p, int w, int h, const int32_t *heights);
int64_t sim_max_slope_excess_materials(const ground_material_table *t, const uint8_t *ids, int w,
                                       int h, const int32_t *heights);

/* ---- Backends ---- */

/* Scratch bytes held per stage (what an allocation is for, not when it runs):
 * depth .. even_slopes for the persson backends, backend_other for a
 * backend's scratch it does not split by stage (GL), model for the
 * non-persson models' scratch (and base heights), gather_scatter for the
 * engine's packed windows and bookkeeping. */
typedef struct sim_stage_memory {
#define SIM_STAGE_MEMORY_FIELD(name) uint64_t name;
    SIM_MEMORY_STAGE_LIST(SIM_STAGE_MEMORY_FIELD)
#undef SIM_STAGE_MEMORY_FIELD
} sim_stage_memory;

uint64_t sim_stage_memory_total(const sim_stage_memory *m);

/* Milliseconds per stage of SIM_STAGE_LIST. */
typedef struct sim_stage_times {
#define SIM_STAGE_TIME_FIELD(name) double name;
    SIM_STAGE_LIST(SIM_STAGE_TIME_FIELD)
#undef SIM_STAGE_TIME_FIELD
} sim_stage_times;

/* A collider as the backends see it in one tick. */
typedef struct sim_collider {
    int id;
    const collider_geometry *geometry;
    collider_pose pose;
    collider_pose previous_pose;
    int has_previous; /* 0 on the first tick it exists: footprint is the pose alone */
    /* bekker: > 0 load-driven, the vertical load (N) the soil must carry: the
     * engine sets the pose height each tick (sim_bekker_carry, before the
     * window deforms) and reports it in the contact's pose_z_m. 0: as posed. */
    double load_n;
    /* bekker, set by sim_bekker_carry: the found height's part above a whole
     * height unit, in units (0 <= lift < 1; 0 for any other collider). The
     * depth is cast at the whole unit below the pose and every contact
     * cell's penetration is lift less, so the carried force is continuous in
     * the height and the search can meet the load finer than one unit. */
    double lift_units;
} sim_collider;

/* The bekker model's state per cell, int32 each, in this order: plastic
 * sinkage (height units below the undisturbed level: what the cell has been
 * pressed to), Janosi shear displacement (micrometres, this pass), compacted
 * volume (height units taken out of the height by compaction). */
enum { SIM_SOIL_SINK, SIM_SOIL_SHEAR_UM, SIM_SOIL_COMPACTED, SIM_SOIL_STATE_FIELDS };

/* The soil's push on one collider over one tick (bekker): what a simulator
 * applies to the body. Summed over cells in row-major order within a window
 * and over windows in plan order, so bit-identical run to run and for any
 * thread count. */
typedef struct sim_contact {
    int collider_id;
    double force_n[3];   /* on the collider, world frame */
    double torque_nm[3]; /* about the collider's pose position */
    /* below the undisturbed surface at its lowest point in contact: the total
     * sinkage (plastic so far + penetration) of the contact cells where its
     * bottom is lowest, the least of them (a rut's edge cell was also pressed
     * under soil spread onto it) */
    double sinkage_m;
    double area_m2;       /* cells in contact times the cell area */
    double patch_width_m; /* Bekker's b of its largest contact patch: 2 A / L */
    int64_t patch_cells;  /* that patch's size (the tie rule of the merge) */
    double slip;          /* cylinders: 1 - v/(wR) driving, wR/v - 1 skidding; else 0 */
    int64_t cells;        /* cells in contact */
    double velocity[3];   /* m/s, from this tick's two poses */
    double angular[3];    /* rad/s, likewise */
    double pose_z_m;      /* the pose height it deformed at (load-driven: the engine's) */
    /* PROTOCOL.md CONTACT's fields at that pose against the heights before
     * the deformation (a load-driven collider's CONTACT is these): Σ
     * penetration (units), the deepest cell's penetration, centre and bottom,
     * the terrain normals' sum (central differences inside the window) */
    int64_t volume;
    int64_t deepest_units;
    double deepest[3];
    double normal_sum[3];
    int32_t lowest_bottom; /* the sinkage cell's bottom (units); merge ties */
} sim_contact;

typedef struct sim_window_job {
    world_rect rect;               /* world cells */
    double cell_size_m;            /* for the depth stage */
    int32_t units_per_m;           /* for the depth stage */
    int32_t *heights;              /* in: gathered heights; out: new heights (w*h) */
    const sim_collider *colliders; /* those whose footprint meets the window */
    int collider_count;
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
    /* bekker (NULL otherwise): SIM_SOIL_STATE_FIELDS int32 per cell (in/out,
     * kept only for accepted windows), and one contact per job collider (out). */
    int32_t *soil_state;
    sim_contact *contacts;
} sim_window_job;

/* A posed collider as one tick's engine takes it: a load-driven one (load_n
 * > 0) starts from the height it was found at last tick (previous_pose's,
 * which the caller kept from the contact's pose_z_m), not the posed one —
 * the engine's search goes on from there. The service and the twin both make
 * their tick's colliders with it, so a prediction starts where the server does. */
sim_collider sim_collider_for_tick(int id, const collider_geometry *geometry, collider_pose pose,
                                   collider_pose previous_pose, int has_previous, double load_n);

/* The swept collider of a tick (collider_sweep_*): 1 pose (this one) on the
 * tick a collider appears; else sub-steps k = 1..steps from previous_pose to
 * pose. Both backends' depth stages and the plan use these. */
int sim_collider_sweep_steps(const sim_collider *c, double cell_size_m);
collider_pose sim_collider_sweep_pose(const sim_collider *c, int k, int steps);
void sim_collider_sweep_bounds(const sim_collider *c, double cell_size_m, vec3d *lo, vec3d *hi);

/* The CPU depth stage of a job's window (the one "fill with no collider,
 * rasterise each collider" routine): bottom (w*h) becomes
 * COLLIDER_BOTTOM_NONE, lowered by collider_depth_cpu for each sub-step pose
 * of each of the job's colliders (the swept collider). Only rect, cell_size_m, units_per_m and the
 * colliders are read. */
void sim_window_depth(const sim_window_job *job, int32_t *bottom);

/* A footprint event of the decals model: where a collider touches the ground. */
typedef struct sim_footprint {
    int collider_id;
    double x_m, y_m;   /* centre of the touched cells, metres */
    double yaw_rad;    /* heading of the collider about z */
    double size_m;     /* side of a square with the touched area */
    double strength_m; /* deepest penetration */
} sim_footprint;

/* A GPU tile cache's statistics (zeros for a backend without one). */
typedef struct sim_tile_cache_stats {
    uint64_t texture_bytes; /* the array texture (its capacity) */
    int resident_tiles;     /* layers holding a tile */
    int tile_cells;         /* side of the tiles held, 0 while off */
    uint64_t uploads;       /* tiles uploaded, since creation */
    uint64_t upload_bytes;
    uint64_t evictions;      /* resident tiles replaced by others */
    uint64_t windows_cached; /* windows gathered from the cache */
    uint64_t windows_direct; /* windows uploaded from the CPU copy */
} sim_tile_cache_stats;

/* A GPU backend's synchronisation work, counted since creation (zeros for
 * the CPU): compute dispatches, draws, memory barriers, GPU→CPU readbacks
 * (glGetBufferSubData calls and their bytes) and full waits (glFinish). */
typedef struct sim_gpu_sync_stats {
    uint64_t dispatches, draws, barriers, readbacks, readback_bytes, finishes;
    /* of the dispatches, those over a compacted list whose size the GPU
     * wrote (glDispatchComputeIndirect: jump flooding's listed tiles) */
    uint64_t indirect;
} sim_gpu_sync_stats;

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
    /* Optional (NULL: no tile cache): the tile cache's statistics. */
    void (*tile_cache_stats)(const sim_backend *b, sim_tile_cache_stats *out);
    /* Optional (NULL: no GPU): its synchronisation counters. */
    void (*gpu_sync_stats)(const sim_backend *b, sim_gpu_sync_stats *out);
    /* Optional (NULL: times are always real): with timing on, wait for the
     * device after every stage so per-stage times are real. */
    void (*set_stage_timing)(sim_backend *b, int on);
    void (*destroy)(sim_backend *b);
};

sim_backend *sim_backend_cpu_create(error_text *err);
/* Threads of the CPU twin's stages (sim_threads.c): n < 1 means the
 * machine's cores (the default), at most SIM_THREADS_MAX. Heights do not
 * depend on it. sim_threads() is the count in use (sim_threads.c: a pool
 * of worker threads that sleep between loops). */
#define SIM_THREADS_MAX 64
void sim_set_threads(int n);
int sim_threads(void);
int sim_default_threads(void);
/* On: every parallel loop this thread meets runs on it alone (heights are
 * the same). A pool ticking several worlds (host/host_ticker.c) has its
 * parallelism across the worlds already; a tick that waited for a chunk a
 * descheduled helper had claimed would hold up the worlds behind it. */
void sim_thread_serial(int on);

/* Through the optional entries: zeros / nothing where a backend has none. */
void sim_backend_tile_cache_stats(const sim_backend *b, sim_tile_cache_stats *out);
void sim_backend_set_stage_timing(sim_backend *b, int on);
void sim_backend_gpu_sync_stats(const sim_backend *b, sim_gpu_sync_stats *out);

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
    /* tight rectangles where the per-cell state (world_soil.c: bekker's soil
     * state, the compaction memory) changed, heights or not; the store logs
     * them with the dirty ones */
    const world_rect *state_dirty;
    int state_dirty_count;
    double model_ms;                 /* the non-persson models' window functions */
    const sim_footprint *footprints; /* decals: this tick's events (engine-owned) */
    int footprint_count;
    const sim_contact *contacts; /* bekker: one per collider of the tick, in its order */
    int contact_count;
} sim_tick_report;

/* The engine: opaque; the sim thread's alone once it has ticked (its first
 * tick claims it; THREAD_OWNED checks every later one). */
typedef struct sim_engine sim_engine;

/* What the engine has held and done so far (simulate's report, metrics). */
typedef struct sim_engine_stats {
    uint64_t peak_scratch_bytes;  /* engine's own plus the backend's, high-water mark */
    int64_t peak_active_cells;    /* most cells in one tick's windows */
    sim_stage_memory memory;      /* held after the last tick */
    sim_stage_memory peak_memory; /* per stage high-water mark */
    int per_cell_materials;       /* 1: the ground's layers are read (not the uniform path) */
    int refilling_windows;        /* subtract: windows kept for the next tick's refill */
} sim_engine_stats;

/* Returns NULL with err set (margin outside [0, 4096], out of memory). The
 * world and the backend are not owned. */
sim_engine *sim_engine_create(world *w, const sim_params *p, sim_backend *backend, int margin_cells,
                              error_text *err);
void sim_engine_destroy(sim_engine *e);
/* This thread ticks e from now on (a world handed between sim workers). */
void sim_engine_claim(sim_engine *e);
/* The ground's per-cell layers (not owned; NULL: none). A ground with one
 * material equal to the params and no compaction memory changes nothing: the
 * uniform path runs. */
void sim_engine_set_ground(sim_engine *e, ground *g);
/* Returns 0, or -1 with err set if the backend failed (the world is unchanged then). */
int sim_engine_tick(sim_engine *e, const sim_collider *colliders, int collider_count,
                    sim_tick_report *report, error_text *err);
/* After a tick: window i of the last tick, its heights before and after. */
world_rect sim_engine_window(const sim_engine *e, int i, const int32_t **before,
                             const int32_t **after);
/* After a tick the store could not log: the per-cell state (soil state,
 * compaction memory) of its windows back as it was gathered (the caller puts
 * the heights back, sim_engine_window). */
void sim_engine_undo_state(sim_engine *e);
void sim_engine_get_stats(const sim_engine *e, sim_engine_stats *out);
/* bekker: Σ compacted volume over the world (height units): Σh + this is
 * constant. 0 for the other models. */
int64_t sim_engine_soil_compacted(const sim_engine *e);
/* Σ of what compaction has taken from Σh in w, for every model: bekker's
 * compacted volume plus the persson models' and sumner's compaction memory
 * (0 where nothing remembers it). /v1/stats `compacted`. */
int64_t sim_world_compacted(const world *w);
/* bekker: one cell's soil state (SIM_SOIL_STATE_FIELDS values; zeros where
 * nothing was ever pressed). */
void sim_engine_soil_cell(const sim_engine *e, int x, int y, int32_t *out);
world *sim_engine_world(const sim_engine *e);
sim_backend *sim_engine_backend(const sim_engine *e);

#endif
