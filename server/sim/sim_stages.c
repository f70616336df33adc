/*
 * sim_stages.c: the CPU twin of the integer stages (thesis ch. 4.1.3-4.1.5).
 *
 * This file is the specification of everything after the depth stage. The
 * compute shaders in shaders/ mirror it line for line; tests check that both
 * give identical heights for identical depth. Rules that keep it exact:
 *
 *  - Heights stay in [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX] = ±2^29, so a
 *    difference of two heights fits in int32 and products with a Q16 ratio
 *    fit in 64 bits (GLSL: umulExtended).
 *  - Material is only ever moved by integer amounts, and every division keeps
 *    its remainder somewhere explicit: Σh changes only by compression.
 *  - Sums that can grow without bound (material converging on one column)
 *    are checked; a window that would leave the height range is refused as a
 *    whole (SIM_WINDOW_HEIGHT_LIMIT) and the caller keeps the old heights.
 *    The GPU detects the same condition with carries on 32-bit sums.
 *  - Slope evening is Jacobi style (read old heights, write new ones), not
 *    the original's read-modify-write of one buffer, so the result does not
 *    depend on thread order.
 *
 * Classify and slope evening read a material row per cell (docs/materials.md):
 * one implementation serves per-cell materials and the uniform path, which is
 * a one-row table of the params with ids == NULL (uniform_table).
 *
 * Compaction memory, in integers per penetrated column with penetration pen,
 * memory m and its material's max M > 0:
 *     hardness  = (m << 16) / M        (Q16, integer division)
 *     resisted  = pen * hardness >> 16 (compacted ground carries the collider)
 *     yield     = pen - resisted       (the column is lowered by this)
 *     compacted = min(yield * c, M - m) (c the material's compression, Q16)
 *     moved     = yield - compacted    (displaced like any other material)
 * so repeated passes over one track lower it less each time, the memory
 * never passes M, and Σh falls by exactly the compacted units.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* 8-neighbourhood; the first four are axial, the last four diagonal. */
const int sim_neighbour_dx[8] = {1, -1, 0, 0, 1, -1, 1, -1};
const int sim_neighbour_dy[8] = {0, 0, 1, -1, 1, 1, -1, -1};

uint32_t sim_cell_hash(int32_t world_x, int32_t world_y)
{
    return hash_lowbias32((uint32_t)world_x * SIM_CELL_HASH_X ^
                          (uint32_t)world_y * SIM_CELL_HASH_Y);
}

/* (a * q16) >> shift for a >= 0, q16 in [0, 65536]: exact in 64 bits. */
static int32_t mul_q16_shift(int32_t a, int32_t q16, int shift)
{
    return (int32_t)(((uint64_t)(uint32_t)a * (uint32_t)q16) >> shift);
}

ground_material_row sim_material_row_from_params(const sim_params *p, int32_t max_compaction)
{
    ground_material_row r = {
        .compression_q16 = p->compression_q16,
        .roughness_q16 = p->roughness_q16,
        .slope_threshold_axial = p->slope_threshold_axial,
        .slope_threshold_diagonal = p->slope_threshold_diagonal,
        .max_compaction = max_compaction < 0       ? 0
                          : max_compaction > 65535 ? 65535
                                                   : max_compaction,
    };
    return r;
}

/* The uniform path's table: one row, the params' own, no compaction memory
 * (with ids == NULL every cell reads it). The stages below then compute what
 * a single material computes: there is one implementation for both. */
static ground_material_table uniform_table(const sim_params *p)
{
    ground_material_table t = {.count = 1};
    t.rows[0] = sim_material_row_from_params(p, 0);
    return t;
}

static const ground_material_row *row_of(const ground_material_table *t, const uint8_t *ids, int i)
{
    int id = ids ? ids[i] : 0;
    return &t->rows[id < t->count ? id : 0];
}

void sim_classify_materials(const sim_params *p, const ground_material_table *t, const uint8_t *ids,
                            const uint16_t *memory, int cell_count, const int32_t *heights,
                            const int32_t *bottom, int32_t *raw, int32_t *moved, int32_t *cls)
{
    for (int i = 0; i < cell_count; i++) {
        int32_t h = heights[i], b = bottom[i];
        int32_t pen = 0, c = SIM_CELL_SEED;
        if (b != COLLIDER_BOTTOM_NONE) {
            int32_t effective = b > p->floor ? b : p->floor;
            if (h > effective) {
                c = SIM_CELL_PENETRATING;
                pen = h - effective;
            } else if (b - h <= p->obstacle_gap) {
                c = SIM_CELL_OBSTACLE;
            }
        }
        const ground_material_row *row = row_of(t, ids, i);
        int32_t yield = pen, compacted;
        if (row->max_compaction > 0) {
            int32_t m = memory ? memory[i] : 0;
            if (m > row->max_compaction)
                m = row->max_compaction;
            /* hardness m/M in Q16 (<= 65536), so the GPU needs no 64-bit division */
            int32_t hardness_q16 = (int32_t)(((uint32_t)m << 16) / (uint32_t)row->max_compaction);
            yield = pen - mul_q16_shift(pen, hardness_q16, 16);
            compacted = mul_q16_shift(yield, row->compression_q16, 16);
            if (compacted > row->max_compaction - m)
                compacted = row->max_compaction - m;
        } else {
            compacted = mul_q16_shift(pen, row->compression_q16, 16);
        }
        raw[i] = yield;
        moved[i] = yield - compacted;
        cls[i] = c;
    }
}

void sim_classify(const sim_params *p, int cell_count, const int32_t *heights,
                  const int32_t *bottom, int32_t *raw, int32_t *moved, int32_t *cls)
{
    ground_material_table t = uniform_table(p);
    sim_classify_materials(p, &t, NULL, NULL, cell_count, heights, bottom, raw, moved, cls);
}

void sim_compaction_commit(const ground_material_table *t, const uint8_t *ids, int cell_count,
                           const int32_t *raw, const int32_t *moved, uint16_t *memory)
{
    for (int i = 0; i < cell_count; i++) {
        const ground_material_row *row = row_of(t, ids, i);
        if (row->max_compaction <= 0)
            continue;
        int32_t m = memory[i] + (raw[i] - moved[i]);
        memory[i] = (uint16_t)(m > row->max_compaction ? row->max_compaction : m);
    }
}

/* Add the received material to each column; refuse the window if any column
 * would rise above the height limit. `received` is exact (int64). */
static sim_window_status land_received(int n, int32_t *heights, const int64_t *received)
{
    for (int i = 0; i < n; i++)
        if (received[i] > (int64_t)WORLD_HEIGHT_MAX - heights[i])
            return SIM_WINDOW_HEIGHT_LIMIT;
    for (int i = 0; i < n; i++)
        heights[i] += (int32_t)received[i];
    return SIM_WINDOW_OK;
}

/* Single target (thesis method 2): all of a column's material to its seed. */
static void displace_single(int n, const int32_t *cls, const int32_t *seed, const int32_t *moved,
                            int64_t *received)
{
    for (int i = 0; i < n; i++) {
        if (cls[i] != SIM_CELL_PENETRATING || moved[i] == 0)
            continue;
        /* No seed in the window: nowhere to go, the material stays home. */
        int32_t target = seed[i] >= 0 ? seed[i] : i;
        received[target] += moved[i];
    }
}

/*
 * Multiple targets (thesis method 3): march from the seed away from the
 * column, one target per multi_target_step units (at most multi_target_max),
 * stopping at the window edge or at the first column that is not a seed.
 * Each placed target gets moved / n; what the missing targets and the
 * division leave over goes to the last valid target.
 */
static void displace_multi(const sim_params *p, int w, int h, const int32_t *cls,
                           const int32_t *seed, const int32_t *moved, int64_t *received)
{
    int n = w * h;
    for (int i = 0; i < n; i++) {
        if (cls[i] != SIM_CELL_PENETRATING || moved[i] == 0)
            continue;
        int32_t s = seed[i];
        if (s < 0) {
            received[i] += moved[i];
            continue;
        }
        int32_t amount = moved[i];
        int32_t targets = (amount - 1) / p->multi_target_step + 1;
        if (targets > p->multi_target_max)
            targets = p->multi_target_max;
        int32_t share = amount / targets;
        int px = i % w, py = i / w, sx = s % w, sy = s / w;
        int32_t dx = sx - px, dy = sy - py;
        int32_t adx = dx < 0 ? -dx : dx, ady = dy < 0 ? -dy : dy;
        int32_t len = adx > ady ? adx : ady; /* >= 1: a seed is never penetrating */
        int32_t sgx = dx < 0 ? -1 : 1, sgy = dy < 0 ? -1 : 1;
        int32_t last = s, placed = 0;
        for (int32_t t = 0; t < targets; t++) {
            int32_t tx = sx + sgx * (adx * t / len);
            int32_t ty = sy + sgy * (ady * t / len);
            if (tx < 0 || ty < 0 || tx >= w || ty >= h)
                break;
            int32_t ti = ty * w + tx;
            if (cls[ti] != SIM_CELL_SEED)
                break;
            received[ti] += share;
            placed += share;
            last = ti;
        }
        received[last] += amount - placed;
    }
}

/*
 * Iterative (thesis method 1, Listing 4.2): material flows one cell per pass
 * from each column to its neighbours closer to a seed (obstacles excluded),
 * split evenly; the remainder of the split stays. Seeds deposit what they
 * receive. After the last pass, a dead end (no receiving neighbour) hands its
 * transit to its nearest seed; any other material still in transit stays in
 * the column it reached (the next tick moves it on).
 */
static sim_window_status displace_iterative(const sim_params *p, int w, int h, const int32_t *cls,
                                            const int32_t *seed, const int32_t *moved,
                                            int32_t *heights, int32_t *scratch)
{
    int n = w * h;
    int32_t *dist = scratch;
    int32_t *mask = scratch + n; /* bit j: neighbour j receives; bits 8..11: count */
    int32_t *transit = scratch + 2 * n;
    int32_t *next = scratch + 3 * n;
    int32_t *deposit = scratch + 4 * n;
    for (int i = 0; i < n; i++) {
        int32_t s = seed[i];
        dist[i] = s >= 0 ? sim_metric_distance(p->metric, s % w - i % w, s / w - i / w) : INT32_MAX;
        transit[i] = cls[i] == SIM_CELL_PENETRATING ? moved[i] : 0;
        deposit[i] = 0;
    }
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x, bits = 0, count = 0;
            for (int j = 0; j < 8; j++) {
                int qx = x + sim_neighbour_dx[j], qy = y + sim_neighbour_dy[j];
                if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                    continue;
                int q = qy * w + qx;
                if (dist[q] < dist[i] && cls[q] != SIM_CELL_OBSTACLE) {
                    bits |= 1 << j;
                    count++;
                }
            }
            mask[i] = bits | count << 8;
        }
    }
    for (int32_t pass = 0; pass < p->displace_iterations; pass++) {
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++) {
                int i = y * w + x;
                int32_t count = mask[i] >> 8;
                int64_t total = count > 0 ? transit[i] % count : transit[i];
                int64_t inflow = 0;
                for (int j = 0; j < 8; j++) {
                    int qx = x + sim_neighbour_dx[j], qy = y + sim_neighbour_dy[j];
                    if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                        continue;
                    int q = qy * w + qx;
                    /* does q send to i? i is q's neighbour in the opposite direction */
                    int back = j ^ 1; /* pairs (0,1) (2,3) (4,5) (6,7) are opposite */
                    if (j >= 4)
                        back = 11 - j; /* (4,7) (5,6): diagonals are opposite across */
                    if (mask[q] & (1 << back))
                        inflow += transit[q] / (mask[q] >> 8);
                }
                if (cls[i] == SIM_CELL_SEED) {
                    int64_t d = (int64_t)deposit[i] + inflow;
                    if (d > INT32_MAX)
                        return SIM_WINDOW_HEIGHT_LIMIT;
                    deposit[i] = (int32_t)d;
                    next[i] = 0;
                } else {
                    total += inflow;
                    if (total > INT32_MAX)
                        return SIM_WINDOW_HEIGHT_LIMIT;
                    next[i] = (int32_t)total;
                }
            }
        }
        memcpy(transit, next, (size_t)n * sizeof *transit);
    }
    /* Dead ends: a column whose every neighbour closer to a seed is an
     * obstacle (count 0) can pass nothing on, yet its neighbours keep sending
     * to it; left in place, the whole displaced volume of a collider piles
     * into it tick after tick (issue 12: a 4.96 m spike on a flank). It hands
     * its transit to its nearest seed, as single-target displacement does. */
    for (int i = 0; i < n; i++) {
        int32_t s = seed[i];
        if (cls[i] == SIM_CELL_SEED || s < 0 || (mask[i] >> 8) != 0 || transit[i] == 0)
            continue;
        int64_t d = (int64_t)deposit[s] + transit[i];
        if (d > INT32_MAX)
            return SIM_WINDOW_HEIGHT_LIMIT;
        deposit[s] = (int32_t)d;
        transit[i] = 0;
    }
    for (int i = 0; i < n; i++) {
        int64_t add = (int64_t)deposit[i] + transit[i];
        if (add > (int64_t)WORLD_HEIGHT_MAX - heights[i])
            return SIM_WINDOW_HEIGHT_LIMIT;
    }
    for (int i = 0; i < n; i++)
        heights[i] += deposit[i] + transit[i];
    return SIM_WINDOW_OK;
}

sim_window_status sim_displace(const sim_params *p, int w, int h, const int32_t *cls,
                               const int32_t *seed, const int32_t *raw, const int32_t *moved,
                               int32_t *heights, int32_t *scratch)
{
    int n = w * h;
    for (int i = 0; i < n; i++)
        heights[i] -= raw[i];
    if (p->method == SIM_METHOD_ITERATIVE)
        return displace_iterative(p, w, h, cls, seed, moved, heights, scratch);
    /* 2*n+1 int32 of scratch, rounded up to int64 alignment */
    int64_t *received = (int64_t *)(void *)(((uintptr_t)scratch + 7) & ~(uintptr_t)7);
    memset(received, 0, (size_t)n * sizeof *received);
    if (p->method == SIM_METHOD_MULTI)
        displace_multi(p, w, h, cls, seed, moved, received);
    else
        displace_single(n, cls, seed, moved, received);
    return land_received(n, heights, received);
}

/* Flux out of a column of material `row` towards a lower neighbour. */
static int32_t slope_flux_row(const ground_material_row *row, int32_t hc, int32_t hk, int diagonal)
{
    int32_t threshold = diagonal ? row->slope_threshold_diagonal : row->slope_threshold_axial;
    int32_t excess = hc - hk - threshold;
    if (excess <= 0)
        return 0;
    return mul_q16_shift(excess, row->roughness_q16, 19);
}

/* One cell's Jacobi update of slope evening: its height after one iteration
 * given the heights before it (the formula of sim_even_slopes_materials_dense). */
int32_t sim_slope_next(const ground_material_table *t, const uint8_t *ids, int w, int h,
                       const int32_t *restrict cls, const int32_t *restrict heights, int x, int y)
{
    int i = y * w + x;
    int32_t hi = heights[i];
    const ground_material_row *ri = row_of(t, ids, i);
    int32_t out = 0, in = 0;
    for (int j = 0; j < 8; j++) {
        int qx = x + sim_neighbour_dx[j], qy = y + sim_neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= w || qy >= h)
            continue;
        int q = qy * w + qx;
        if (cls[q] == SIM_CELL_SEED)
            out += slope_flux_row(ri, hi, heights[q], j >= 4);
        if (cls[i] == SIM_CELL_SEED)
            in += slope_flux_row(row_of(t, ids, q), heights[q], hi, j >= 4);
    }
    return hi - out + in;
}

void sim_even_slopes_materials_dense(const sim_params *p, const ground_material_table *t,
                                     const uint8_t *ids, int w, int h, const int32_t *cls,
                                     int32_t *heights, int32_t *scratch)
{
    int n = w * h;
    int32_t *next = scratch;
    for (int32_t iter = 0; iter < p->slope_iterations; iter++) {
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++)
                next[y * w + x] = sim_slope_next(t, ids, w, h, cls, heights, x, y);
        }
        memcpy(heights, next, (size_t)n * sizeof *heights);
    }
}

/* Can slope_next change cell (x, y)? Only if some flux of its formula has a
 * positive excess: out of it towards a free neighbour, or into it (when it
 * is free) from a neighbour. Cells where this is 0 keep their height. */
int sim_slope_may_move(const ground_material_table *t, const uint8_t *ids, int w, int h,
                       const int32_t *restrict cls, const int32_t *restrict heights, int x, int y)
{
    int i = y * w + x;
    int32_t hi = heights[i];
    const ground_material_row *ri = row_of(t, ids, i);
    for (int j = 0; j < 8; j++) {
        int qx = x + sim_neighbour_dx[j], qy = y + sim_neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= w || qy >= h)
            continue;
        int q = qy * w + qx;
        int32_t hq = heights[q];
        int diagonal = j >= 4;
        if (cls[q] == SIM_CELL_SEED &&
            hi - hq > (diagonal ? ri->slope_threshold_diagonal : ri->slope_threshold_axial))
            return 1;
        if (cls[i] == SIM_CELL_SEED) {
            const ground_material_row *rq = row_of(t, ids, q);
            if (hq - hi > (diagonal ? rq->slope_threshold_diagonal : rq->slope_threshold_axial))
                return 1;
        }
    }
    return 0;
}

/* The first work list: every cell of the window that sim_slope_may_move
 * (per-cell materials; a one-material window takes the blocks of
 * sim_slope_blocks.c, whose first pass filters 16 cells at a time). */
static int slope_first_list(const ground_material_table *t, const uint8_t *ids, int w, int h,
                            const int32_t *restrict cls, const int32_t *restrict heights,
                            int32_t *restrict list)
{
    int count = 0;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++)
            if (sim_slope_may_move(t, ids, w, h, cls, heights, x, y))
                list[count++] = sim_slope_pack(x, y);
    return count;
}

/* One iteration's new heights of the listed cells into value[]. */
typedef struct slope_loop {
    const ground_material_table *t;
    const uint8_t *ids;
    int w, h;
    const int32_t *cls, *heights, *list;
    int32_t *value;
} slope_loop;

static void slope_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    (void)thread;
    const slope_loop *l = ctx;
    const int w = l->w, h = l->h;
    const int32_t *restrict list = l->list;
    int32_t *restrict value = l->value;
    for (int64_t c = begin; c < end; c++) {
        int x = sim_slope_x(list[c]), y = sim_slope_y(list[c]);
        value[c] = sim_slope_next(l->t, l->ids, w, h, l->cls, l->heights, x, y);
    }
}

/*
 * The sparse slope evening the engine runs; sim_even_slopes_materials_dense
 * is its reference. Iteration 1 visits the cells that slope_may_move; a
 * cell's next height depends only on itself and its 8 neighbours, so a cell
 * none of which changed in an iteration keeps its height in the next, and
 * the work list after an iteration is the changed cells and their
 * neighbours. It grows along a spreading slope and shrinks to nothing when
 * the window is at rest. scratch holds 4*w*h int32: two lists, the new
 * heights of the listed cells and a mark per cell.
 */
void sim_even_slopes_materials(const sim_params *p, const ground_material_table *t,
                               const uint8_t *ids, int w, int h, const int32_t *cls,
                               int32_t *heights, int32_t *scratch)
{
    if (ids == NULL) {
        sim_even_slopes_blocks(p, t, w, h, cls, heights, scratch);
        return;
    }
    int n = w * h;
    int32_t *restrict list = scratch, *restrict next_list = scratch + n;
    int32_t *restrict value = scratch + 2 * n, *restrict mark = scratch + 3 * n;
    int count = slope_first_list(t, ids, w, h, cls, heights, list);
    if (count == 0)
        return;
    for (int i = 0; i < n; i++)
        mark[i] = -1;
    for (int32_t iter = 0; iter < p->slope_iterations && count > 0; iter++) {
        /* Jacobi: every listed cell reads the old heights; bands are exact */
        slope_loop l = {t, ids, w, h, cls, heights, list, value};
        int bands = sim_band_threads(count);
        sim_parallel_for(count, sim_band_chunk(count, bands), bands, slope_range, &l);
        int next_count = 0;
        for (int c = 0; c < count; c++) {
            int x = sim_slope_x(list[c]), y = sim_slope_y(list[c]), i = y * w + x;
            if (value[c] == heights[i])
                continue;
            heights[i] = value[c];
            /* the changed cell and its neighbours inside the window, once each */
            int x0 = x > 0 ? x - 1 : 0, x1 = x < w - 1 ? x + 1 : w - 1;
            int y0 = y > 0 ? y - 1 : 0, y1 = y < h - 1 ? y + 1 : h - 1;
            for (int qy = y0; qy <= y1; qy++) {
                for (int qx = x0, q = qy * w + x0; qx <= x1; qx++, q++) {
                    if (mark[q] == iter)
                        continue;
                    mark[q] = iter;
                    next_list[next_count++] = sim_slope_pack(qx, qy);
                }
            }
        }
        int32_t *tmp = list;
        list = next_list;
        next_list = tmp;
        count = next_count;
    }
}

void sim_even_slopes(const sim_params *p, int w, int h, const int32_t *cls, int32_t *heights,
                     int32_t *scratch)
{
    ground_material_table t = uniform_table(p);
    sim_even_slopes_materials(p, &t, NULL, w, h, cls, heights, scratch);
}

int64_t sim_max_slope_excess_materials(const ground_material_table *t, const uint8_t *ids, int w,
                                       int h, const int32_t *heights)
{
    int64_t worst = 0;
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            for (int j = 0; j < 8; j++) {
                int qx = x + sim_neighbour_dx[j], qy = y + sim_neighbour_dy[j];
                if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                    continue;
                int64_t d = (int64_t)heights[i] - heights[qy * w + qx];
                const ground_material_row *r = row_of(t, ids, i);
                int64_t th = j >= 4 ? r->slope_threshold_diagonal : r->slope_threshold_axial;
                if (d - th > worst)
                    worst = d - th;
            }
        }
    }
    return worst;
}

int64_t sim_max_slope_excess(const sim_params *p, int w, int h, const int32_t *heights)
{
    ground_material_table t = uniform_table(p);
    return sim_max_slope_excess_materials(&t, NULL, w, h, heights);
}
