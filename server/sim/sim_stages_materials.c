/*
 * sim_stages_materials.c: the classify and slope-evening stages of the CPU
 * twin with a material per cell and compaction memory (docs/materials.md).
 * They run in place of sim_classify / sim_even_slopes when a scene has more
 * than one material or a material that remembers compaction; with a single
 * row equal to the params and no memory they compute exactly what those do
 * (test_materials checks it), so the uniform path is unchanged.
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

#include <stdint.h>
#include <string.h>

static const int neighbour_dx[8] = {1, -1, 0, 0, 1, -1, 1, -1};
static const int neighbour_dy[8] = {0, 0, 1, -1, 1, 1, -1, -1};

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

/* Flux out of a column of material `row` towards a lower neighbour. */
static int32_t slope_flux_row(const ground_material_row *row, int32_t hc, int32_t hk, int diagonal)
{
    int32_t threshold = diagonal ? row->slope_threshold_diagonal : row->slope_threshold_axial;
    int32_t excess = hc - hk - threshold;
    if (excess <= 0)
        return 0;
    return mul_q16_shift(excess, row->roughness_q16, 19);
}

void sim_even_slopes_materials(const sim_params *p, const ground_material_table *t,
                               const uint8_t *ids, int w, int h, const int32_t *cls,
                               int32_t *heights, int32_t *scratch)
{
    int n = w * h;
    int32_t *next = scratch;
    for (int32_t iter = 0; iter < p->slope_iterations; iter++) {
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++) {
                int i = y * w + x;
                int32_t hi = heights[i];
                const ground_material_row *ri = row_of(t, ids, i);
                int32_t out = 0, in = 0;
                for (int j = 0; j < 8; j++) {
                    int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
                    if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                        continue;
                    int q = qy * w + qx;
                    if (cls[q] == SIM_CELL_SEED)
                        out += slope_flux_row(ri, hi, heights[q], j >= 4);
                    if (cls[i] == SIM_CELL_SEED)
                        in += slope_flux_row(row_of(t, ids, q), heights[q], hi, j >= 4);
                }
                next[i] = hi - out + in;
            }
        }
        memcpy(heights, next, (size_t)n * sizeof *heights);
    }
}

int64_t sim_max_slope_excess_materials(const ground_material_table *t, const uint8_t *ids, int w,
                                       int h, const int32_t *heights)
{
    int64_t worst = 0;
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            for (int j = 0; j < 8; j++) {
                int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
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
