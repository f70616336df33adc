/*
 * sim_internal.h: the sim subsystem's parts that only sim/ (and its tests)
 * use — the CPU twin's integer stages on window-local row-major arrays, their
 * per-cell-material forms, the non-persson models' window functions and the
 * window planner. The backends and the engine are built from these; the
 * public face is sim.h.
 */
#ifndef TERRAD_SIM_INTERNAL_H
#define TERRAD_SIM_INTERNAL_H

#include "sim/sim.h"

/* A parallel loop over items [0, items) in chunks (sim_threads.c): fn runs
 * each chunk [begin, end) on some thread; `thread` is its slot, 0 (the
 * caller) .. threads - 1, for per-thread scratch. A loop nested in another,
 * or one begun while another thread's loop holds the pool, runs serially on
 * the calling thread. Every caller writes only each item's own cells from
 * values read before the loop, so the result does not depend on the split. */
typedef void (*sim_range_fn)(void *ctx, int64_t begin, int64_t end, int thread);
void sim_parallel_for(int64_t items, int64_t chunk, int threads, sim_range_fn fn, void *ctx);

/* How many threads a loop of `items` independent items should use: 1 inside
 * another parallel loop or for a small loop. */
#define SIM_BAND_MIN_ITEMS 4096
int sim_band_threads(int64_t items);
/* Chunk size for a banded loop of `items` on `bands` threads: a few chunks
 * per thread, so a thread that starts late leaves its share to the others. */
int64_t sim_band_chunk(int64_t items, int bands);

/* The hot integer loops (slope evening's blocks, jump flooding's runs) are
 * compiled twice on x86-64 with gcc or clang: for the SSE2 baseline and,
 * with SIM_TARGET_AVX2, for AVX2, chosen at run time by sim_cpu_avx2().
 * Both are the same integer operations on the same integers: the heights
 * do not depend on which runs (test_sparse_stages runs both where the CPU
 * has AVX2; TERRAD_NO_AVX2=1 in the environment forces the baseline). */
#define SIM_ALWAYS_INLINE inline __attribute__((always_inline))
#if defined(__x86_64__) && defined(__GNUC__) && !defined(TERRAD_TWIN_LIB)
#define SIM_AVX2_CLONE 1
#define SIM_TARGET_AVX2 __attribute__((target("avx2")))
#else
#define SIM_AVX2_CLONE 0
#endif
/* 1 when the AVX2 forms may run: the CPU has AVX2, TERRAD_NO_AVX2 is unset
 * (read once) and sim_cpu_avx2_allow(0) was not called (sim_threads.c). */
int sim_cpu_avx2(void);
/* Tests: 0 forces the SSE2 forms from now on, 1 lets AVX2 run again. */
void sim_cpu_avx2_allow(int allow);

/* The 8-neighbourhood in the order every stage visits it (sums and tie
 * rules follow it); the first four are axial, the last four diagonal. */
extern const int sim_neighbour_dx[8];
extern const int sim_neighbour_dy[8];

typedef enum sim_cell_class {
    SIM_CELL_SEED = 0,        /* free: can receive material */
    SIM_CELL_OBSTACLE = 1,    /* a collider rests just above: receives nothing */
    SIM_CELL_PENETRATING = 2, /* a collider is inside the column */
} sim_cell_class;

/* ---- The CPU twin's integer stages, on window-local row-major arrays ---- */

/* Hash of a world cell, used to break jump-flooding ties (same in GLSL). */
uint32_t sim_cell_hash(int32_t world_x, int32_t world_y);
/* its multipliers of x and y (the AVX2 jump flooding computes it 8 at a time) */
#define SIM_CELL_HASH_X 0x8da6b343u
#define SIM_CELL_HASH_Y 0xd8163841u
/* Distance under a metric; Euclidean is squared (order is all that matters).
 * Inline: jump flooding calls it for every candidate of every step. */
static inline int32_t sim_metric_distance(sim_metric m, int32_t dx, int32_t dy)
{
    int32_t ax = dx < 0 ? -dx : dx;
    int32_t ay = dy < 0 ? -dy : dy;
    switch (m) {
    case SIM_METRIC_MANHATTAN:
        return ax + ay;
    case SIM_METRIC_CHEBYSHEV:
        return ax > ay ? ax : ay;
    case SIM_METRIC_EUCLIDEAN:
    default:
        return ax * ax + ay * ay;
    }
}

/*
 * classify: raw[i] = penetration (units the column must lose), moved[i] =
 * the part of it that is displaced (raw minus compression), cls[i] = class.
 */
void sim_classify(const sim_params *p, int cell_count, const int32_t *heights,
                  const int32_t *bottom, int32_t *raw, int32_t *moved, int32_t *cls);

/*
 * jump_flood: seed[i] = window-local index of the nearest seed cell, or -1 if
 * the window has none. scratch holds 2*w*h int32. Ties go to the lower
 * (sim_cell_hash, index) of the candidate seed, so the answer does not
 * depend on evaluation order. It visits only the cells that are not free;
 * sim_jump_flood_dense (scratch w*h) visits every cell and is its reference:
 * both give identical seeds (test_sim_stages).
 */
void sim_jump_flood(const sim_params *p, int w, int h, int origin_x, int origin_y,
                    const int32_t *cls, int32_t *seed, int32_t *scratch);
void sim_jump_flood_dense(const sim_params *p, int w, int h, int origin_x, int origin_y,
                          const int32_t *cls, int32_t *seed, int32_t *scratch);

/* ---- Per-cell materials and compaction memory (sim_stages.c) ----
 * Classify and slope evening with a material id per cell (an index into a
 * small table of integer rows, ground/'s) and, where some material remembers
 * compaction, a uint16 compaction memory per cell. With ids == NULL every
 * cell is row 0. These are the one implementation: sim_classify and
 * sim_even_slopes run them with a one-row table of the params. */

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
/* even_slopes where each flux uses the material of the column it leaves.
 * Sparse (a work list of the cells that can move); scratch holds 4*w*h int32.
 * The _dense form visits every cell (scratch 2*w*h) and is the reference the
 * sparse one is tested against: identical heights. */
void sim_even_slopes_materials(const sim_params *p, const ground_material_table *t,
                               const uint8_t *ids, int w, int h, const int32_t *cls,
                               int32_t *heights, int32_t *scratch);
void sim_even_slopes_materials_dense(const sim_params *p, const ground_material_table *t,
                                     const uint8_t *ids, int w, int h, const int32_t *cls,
                                     int32_t *heights, int32_t *scratch);
/* The one-material form (ids == NULL) sim_even_slopes_materials runs: by
 * blocks of 16 cells along a row (sim_slope_blocks.c); scratch 4*w*h int32. */
void sim_even_slopes_blocks(const sim_params *p, const ground_material_table *t, int w, int h,
                            const int32_t *cls, int32_t *heights, int32_t *scratch);
/* One cell's Jacobi update of slope evening (the specification, any cell of
 * the window), and whether it can change the cell at all. */
int32_t sim_slope_next(const ground_material_table *t, const uint8_t *ids, int w, int h,
                       const int32_t *restrict cls, const int32_t *restrict heights, int x, int y);
int sim_slope_may_move(const ground_material_table *t, const uint8_t *ids, int w, int h,
                       const int32_t *restrict cls, const int32_t *restrict heights, int x, int y);
/* Slope evening's work lists hold cells packed as (y << 16 | x), unsigned
 * (a side is at most WORLD_SIDE_MAX = 65536 cells): a listed cell's x and y
 * cost a mask and a shift, not a division. */
static inline int32_t sim_slope_pack(int x, int y)
{
    return (int32_t)((uint32_t)y << 16 | (uint32_t)x);
}

static inline int sim_slope_x(int32_t packed)
{
    return (int)((uint32_t)packed & 0xffffu);
}

static inline int sim_slope_y(int32_t packed)
{
    return (int)((uint32_t)packed >> 16);
}
/*
 * displace: heights[i] -= raw[i], and the moved material lands by the
 * params' method. `scratch` holds 5*w*h int32. Returns SIM_WINDOW_HEIGHT_LIMIT
 * (heights then unspecified; the caller discards the window) if a column
 * would leave [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX].
 */
sim_window_status sim_displace(const sim_params *p, int w, int h, const int32_t *cls,
                               const int32_t *seed, const int32_t *raw, const int32_t *moved,
                               int32_t *heights, int32_t *scratch);

/* even_slopes: params.slope_iterations Jacobi iterations; scratch holds 4*w*h int32. */
void sim_even_slopes(const sim_params *p, int w, int h, const int32_t *cls, int32_t *heights,
                     int32_t *scratch);

/* ---- Sumner, O'Brien and Hodgins 1999 on the CPU (model_sumner.c) ----
 * The accuracy reference: ray-cast columns, first-ring displacement, erosion
 * by the slope-evening iterations. Σh exact with compression 0. Returns
 * SIM_WINDOW_HEIGHT_LIMIT with job->heights unchanged if a column would leave
 * the height range. `scratch` holds sim_sumner_scratch_cells(w, h) int32. */
int64_t sim_sumner_scratch_cells(int w, int h);
sim_window_status sim_sumner_window(const sim_params *p, sim_window_job *job, int32_t *scratch);

/*
 * The displacement half of Sumner's model, shared with bekker: the footprint
 * (cls != SEED) split into 8-connected components, each component's
 * displaced material spread evenly over its first ring (row-major remainder),
 * then the slope evening; heights[i] -= raw[i] first. The caller puts raw and
 * moved at SIM_SETTLE_RAW / SIM_SETTLE_MOVED of `scratch`
 * (sim_settle_scratch_cells(w, h) int32). Σh changes by -Σ(raw - moved)
 * exactly; SIM_WINDOW_HEIGHT_LIMIT leaves job->heights as they were.
 */
int64_t sim_settle_scratch_cells(int w, int h);
#define SIM_SETTLE_MOVED(scratch, n) ((scratch) + 4 * (int64_t)(n))
#define SIM_SETTLE_RAW(scratch, n) ((scratch) + 5 * (int64_t)(n))
sim_window_status sim_sumner_settle(const sim_params *p, sim_window_job *job, const int32_t *cls,
                                    int32_t *scratch);

/* ---- bekker: soil forces (model_bekker.c, sim_soil.c) ----
 * The window needs job->soil_state and job->contacts (one per job collider);
 * scratch of sim_bekker_scratch_cells(w, h) int32. */
int64_t sim_bekker_scratch_cells(int w, int h);
sim_window_status sim_bekker_window(const sim_params *p, sim_window_job *job, int32_t *scratch);
/* A lugged wheel in the bekker model (model_lugs.c): sim_lugged says whether g has
 * grousers; sim_lug_envelope is the smooth cylinder of its lugs' tips the press uses (g
 * itself for any other shape); sim_lug_thrust adds the lugs' bulldozing (passive earth
 * pressure, Irani et al. 2011) to the contact c the press measured at pose (lowest_m: the
 * height of its sinkage cell's bottom). */
int sim_lugged(const collider_geometry *g);
collider_geometry sim_lug_envelope(const collider_geometry *g);
void sim_lug_thrust(const sim_soil *s, const sim_collider *col, collider_pose pose, double lowest_m,
                    sim_contact *c);
/* One window's contact of a collider into the collider's (the engine adds
 * windows in plan order): sums, and the sinkage and deepest point kept by the
 * press's own rules. */
void sim_bekker_contact_merge(sim_contact *to, const sim_contact *from);
/*
 * Load-driven: the highest pose height z (whole units, in [lo, hi)) at which
 * the soil's vertical force on c (one of job->colliders, which the caller owns)
 * reaches load_n, by bisection — lo when even lo does not carry it (the
 * collider stands as low as it may go). c's pose height is left at z; the
 * job's heights and state are as they were (copies: n and
 * SIM_SOIL_STATE_FIELDS * n int32); job->contacts hold the last trial's.
 */
int32_t sim_bekker_carry(const sim_params *p, sim_window_job *job, sim_collider *c, double load_n,
                         int32_t lo, int32_t hi, int32_t *scratch, int32_t *heights_copy,
                         int32_t *state_copy);

/*
 * A soil bin (sim_testbed.c): one flat window of bekker soil (10,000 units
 * per metre) and one collider, driven the way the engine drives the model
 * (sim_bekker_window on a job with its soil state and contacts). The
 * single-wheel testbed runs on it, and the tests press plates and roll
 * wheels in it (tests/support/soil_rig.h). The caller sets the geometry and
 * p.tick_s; slope evening is off.
 */
typedef struct sim_soil_bin {
    sim_params p;
    collider_geometry geometry;
    sim_collider collider;
    sim_contact contact;
    sim_window_job job;
    int32_t *heights, *state, *scratch, *heights_copy, *state_copy;
    int64_t cells;
} sim_soil_bin;
int sim_soil_bin_init(sim_soil_bin *b, const sim_soil *soil, double compression, double cell_m,
                      int w, int h, double height_m, error_text *err);
void sim_soil_bin_free(sim_soil_bin *b);
/* The collider's pose; its previous pose the current one (has_previous 1) or none. */
void sim_soil_bin_place(sim_soil_bin *b, double x, double y, double z, quatd q, int has_previous);
/* Load-driven: the collider left at the highest height carrying load_n (sim_bekker_carry). */
int32_t sim_soil_bin_carry(sim_soil_bin *b, double load_n);
/* One tick of the model at the collider's pose. */
sim_window_status sim_soil_bin_step(sim_soil_bin *b);

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

/*
 * A fast collider's tick in one-cell slices (sim_slices.c; diffusion and
 * bekker). sim_sweep_slices: how many the window's tick needs (1 when no
 * collider moves more than 1.5 cells); sim_travel_slices: likewise, counting
 * only how far each collider's pose position travels (bekker, which presses
 * at the pose). sim_slice_end: the sub-step of a
 * collider swept in `steps` where slice j (1..slices) ends (the last ends at
 * the pose itself); sim_slice_pose: the pose there. sim_slice_rect: the part
 * of the window slice j runs over (its colliders' poses in the slice + the
 * default active margin; empty w/h 0). sim_slice_copy: a per-cell array of
 * cell_bytes per cell between the window (in = 1 packs part out of it) and a
 * packed part (in = 0 writes it back).
 */
int sim_sweep_slices(const sim_window_job *job);
int sim_travel_slices(const sim_window_job *job);
int sim_slice_end(int j, int slices, int steps);
collider_pose sim_slice_pose(const sim_collider *c, double cell_size_m, int j, int slices);
world_rect sim_slice_rect(const sim_window_job *job, int j, int slices);
void sim_slice_copy(world_rect window, world_rect part, void *cells, void *packed,
                    size_t cell_bytes, int in);
/* The CPU depth stage over a sub-step range (backend_cpu.c, beside
 * sim_window_depth, which is slice 1 of 1): sim_window_cast lowers target
 * (w*h, not filled first) by each collider's sub-step poses of slice j of
 * `slices` (the pose it stands at when it does not move within the slice);
 * sim_window_depth_slice fills bottom with COLLIDER_BOTTOM_NONE first. Slices
 * 1..n together cast every sub-step of the tick once. */
void sim_window_cast(const sim_window_job *job, int j, int slices, int32_t *target);
void sim_window_depth_slice(const sim_window_job *job, int j, int slices, int32_t *bottom);

/* decals: one window's events (at most out_capacity); returns how many. */
int sim_decals_window(const sim_params *p, const sim_window_job *job, int32_t *scratch,
                      sim_footprint *out, int out_capacity);

/* A height in metres as units, clamped to one past the height range. */
int32_t sim_units_clamped(double metres, int32_t units_per_m);

/*
 * Footprints → disjoint windows. footprints[i] receives collider i's
 * footprint (w == 0 when it cannot touch the terrain); extra rectangles
 * (subtract's refilling windows) join the footprints. Windows are sorted by
 * (y, x). Caller frees *out.
 */
int sim_plan_windows(const world *w, const sim_params *p, const sim_collider *colliders,
                     int collider_count, int margin_cells, const world_rect *extra, int extra_count,
                     world_rect *footprints, world_rect **out, int *out_count);

#endif
