/*
 * sim_slope_blocks.c: slope evening of a one-material window by blocks of
 * 16 cells along a row — the form of row 4d.5 of the tick (docs/design.md)
 * the daemon runs for every uniform window, after displacement and before
 * the scatter. sim_stages.c states the rule (sim_slope_next, per cell) and
 * keeps the per-cell work list for per-cell materials; this file computes
 * the same heights, bit for bit, with contiguous loads that vectorise, and
 * on x86-64 an AVX2 form of its two hot loops (sim_internal.h,
 * SIM_AVX2_CLONE): 8-lane units with 32-bit products where they are exact.
 * test_sparse_stages compares it with the dense reference in both forms.
 */
#include "sim/sim_internal.h"

#include <string.h>

/*
 * The same argument as the work list's (sim_even_slopes_materials), with a
 * block of SLOPE_SEG cells for a cell: iteration 1 visits the blocks holding
 * a cell that may move (slope_first_range), and after an iteration the blocks
 * holding a changed cell or one of its neighbours. Any block visited gives
 * its cells' exact next heights, so visiting a superset of the listed cells
 * changes nothing; in exchange the 16 cells of a block go through
 * slope_block_body (or, in AVX2, two slope_unit8) with contiguous loads and
 * no branch, and the marks are one byte per block, not a list entry per
 * cell. Only the cells of the window's two sides go one by one.
 */
#define SLOPE_SEG 16

/* The neighbours a block of row 0 or row h - 1 lacks (bits of slope_next's
 * order: E, W, S, N, SE, SW, NE, NW). The rule skips a neighbour outside
 * the window, which is adding 0: a block of the top or bottom row runs the
 * block form without those directions (and reads nothing outside). */
#define SLOPE_DIRS_ALL 0xffu
#define SLOPE_DIRS_NO_NORTH (1u << 3 | 1u << 6 | 1u << 7)
#define SLOPE_DIRS_NO_SOUTH (1u << 2 | 1u << 4 | 1u << 5)

/* Next heights of cells i0 .. i0 + 15, one cell or more inside the window's
 * sides (and above/below it, for the directions in dirs): slope_next's sum
 * with the lanes along the row. dirs is a constant where it is inlined, so
 * each form is compiled without a branch per neighbour. The baseline form
 * (SSE2: no 32-bit multiply, so the products are 64-bit). */
static SIM_ALWAYS_INLINE void slope_block_body(const ground_material_row *restrict r, int w,
                                               const int32_t *restrict cls,
                                               const int32_t *restrict heights, int i0,
                                               int32_t *restrict dst, unsigned dirs)
{
    const int32_t ax = r->slope_threshold_axial, dg = r->slope_threshold_diagonal;
    const uint32_t rough = (uint32_t)r->roughness_q16;
    /* the neighbours in slope_next's order: E, W, S, N, SE, SW, NE, NW */
    const int off[8] = {1, -1, w, -w, w + 1, w - 1, -w + 1, -w - 1};
    const int32_t *restrict hm = heights + i0;
    int32_t out[SLOPE_SEG] = {0}, in[SLOPE_SEG] = {0};
    /* With thresholds >= 0 at most one of the two excesses below is positive
     * (they sum to -2 th): one product per neighbour, of max(|d| - th, 0), is
     * the flux out of the cell when d > 0 and into it when d < 0 (0 either
     * way otherwise). Half the 64-bit products; the same integers. */
    const int one_product = ax >= 0 && dg >= 0;
    for (int j = 0; j < 8; j++) {
        if (!(dirs & 1u << j))
            continue;
        const int32_t th = j < 4 ? ax : dg;
        const int32_t *restrict hq = heights + i0 + off[j], *restrict cq = cls + i0 + off[j];
        if (one_product) {
            for (int l = 0; l < SLOPE_SEG; l++) {
                int32_t d = hm[l] - hq[l], sign = d >> 31;
                int32_t e = ((d ^ sign) - sign) - th;
                uint32_t pe = (uint32_t)(e & ~(e >> 31));
                int32_t f = (int32_t)(((uint64_t)pe * rough) >> 19);
                out[l] += f & ~sign & -(int32_t)(cq[l] == SIM_CELL_SEED);
                in[l] += f & sign;
            }
        } else {
            for (int l = 0; l < SLOPE_SEG; l++) {
                /* max(e, 0) and the class test as masks: no control flow to vectorise */
                int32_t eo = hm[l] - hq[l] - th, ei = hq[l] - hm[l] - th;
                uint32_t po = (uint32_t)(eo & ~(eo >> 31)), pi = (uint32_t)(ei & ~(ei >> 31));
                int32_t fo = (int32_t)(((uint64_t)po * rough) >> 19);
                int32_t fi = (int32_t)(((uint64_t)pi * rough) >> 19);
                out[l] += fo & -(int32_t)(cq[l] == SIM_CELL_SEED);
                in[l] += fi;
            }
        }
    }
    for (int l = 0; l < SLOPE_SEG; l++)
        dst[l] = hm[l] - out[l] + (cls[i0 + l] == SIM_CELL_SEED ? in[l] : 0);
}

/* One iteration's next heights of the listed blocks (packed y << 16 | s). */
typedef struct slope_blocks_loop {
    const ground_material_table *t;
    int w, h;
    const int32_t *cls, *heights, *blocks;
    int32_t *value;
} slope_blocks_loop;

/* The cells of a listed block outside the range [lo, hi) a vector form
 * computed: the specification, cell by cell (sim_slope_next; ids NULL, as
 * every cell of the window is of the table's one row). */
static void slope_rest(const slope_blocks_loop *l, int y, int x0, int x1, int lo, int hi)
{
    for (int x = x0; x < x1; x++)
        if (x < lo || x >= hi)
            l->value[y * l->w + x] =
                sim_slope_next(l->t, NULL, l->w, l->h, l->cls, l->heights, x, y);
}

/* The baseline: a block of 16 lanes placed over the block's cells off the
 * window's sides (a block at a side starts early; only its own cells are
 * kept); the sides and narrow windows cell by cell. */
static void slope_blocks_range_base(const slope_blocks_loop *l, int64_t begin, int64_t end)
{
    const int w = l->w, h = l->h;
    const ground_material_row *r = &l->t->rows[0];
    for (int64_t c = begin; c < end; c++) {
        int y = sim_slope_y(l->blocks[c]), x0 = sim_slope_x(l->blocks[c]) * SLOPE_SEG;
        int x1 = x0 + SLOPE_SEG < w ? x0 + SLOPE_SEG : w, row = y * w;
        int lo = x0 > 0 ? x0 : 1, hi = x1 < w ? x1 : w - 1;
        if (w - 2 >= SLOPE_SEG && lo < hi) {
            int b = lo < w - 1 - SLOPE_SEG ? lo : w - 1 - SLOPE_SEG;
            int32_t next[SLOPE_SEG];
            unsigned dirs =
                (y == 0 ? SLOPE_DIRS_NO_NORTH : 0) | (y == h - 1 ? SLOPE_DIRS_NO_SOUTH : 0);
            if (dirs == 0)
                slope_block_body(r, w, l->cls, l->heights, row + b, next, SLOPE_DIRS_ALL);
            else if (dirs == SLOPE_DIRS_NO_NORTH)
                slope_block_body(r, w, l->cls, l->heights, row + b, next,
                                 SLOPE_DIRS_ALL & ~SLOPE_DIRS_NO_NORTH);
            else if (dirs == SLOPE_DIRS_NO_SOUTH)
                slope_block_body(r, w, l->cls, l->heights, row + b, next,
                                 SLOPE_DIRS_ALL & ~SLOPE_DIRS_NO_SOUTH);
            else /* a one-row window: E and W only */
                slope_block_body(r, w, l->cls, l->heights, row + b, next, 3u);
            for (int x = lo; x < hi; x++)
                l->value[row + x] = next[x - b];
        } else {
            lo = hi = x0;
        }
        slope_rest(l, y, x0, x1, lo, hi);
    }
}

#if SIM_AVX2_CLONE
#include <immintrin.h>

/* One neighbour direction's flux for 8 lanes (AVX2), thresholds >= 0 (the
 * one-product form above). narrow: max(|d| - th, 0) * roughness in 32 bits
 * (one vpmulld for 8 lanes), exact while the product fits: peak keeps the
 * largest factor for the caller to check. Otherwise the 64-bit products of
 * the baseline, vpmuludq on the even and the odd lanes. */
static SIM_TARGET_AVX2 SIM_ALWAYS_INLINE void
slope_dir8(__m256i hm, const int32_t *hq, const int32_t *cq, int32_t th, __m256i rough, int narrow,
           int masked, __m256i lanes, __m256i *out, __m256i *in, __m256i *peak)
{
    const __m256i seed = _mm256_set1_epi32(SIM_CELL_SEED);
    /* masked: the lanes off `lanes` have this neighbour outside the window
     * (slope_next skips it: no flux); they read nothing and add 0 */
    __m256i hqv =
        masked ? _mm256_maskload_epi32(hq, lanes) : _mm256_loadu_si256((const __m256i *)hq);
    __m256i cqv =
        masked ? _mm256_maskload_epi32(cq, lanes) : _mm256_loadu_si256((const __m256i *)cq);
    __m256i d = _mm256_sub_epi32(hm, hqv);
    __m256i sign = _mm256_srai_epi32(d, 31);
    __m256i pe = _mm256_max_epi32(_mm256_sub_epi32(_mm256_abs_epi32(d), _mm256_set1_epi32(th)),
                                  _mm256_setzero_si256());
    if (masked)
        pe = _mm256_and_si256(pe, lanes);
    __m256i f;
    if (narrow) {
        *peak = _mm256_max_epu32(*peak, pe);
        f = _mm256_srli_epi32(_mm256_mullo_epi32(pe, rough), 19);
    } else {
        /* the low 32 bits of (pe * rough) >> 19 of each lane, as the baseline */
        __m256i even = _mm256_srli_epi64(_mm256_mul_epu32(pe, rough), 19);
        __m256i odd = _mm256_srli_epi64(_mm256_mul_epu32(_mm256_srli_epi64(pe, 32), rough), 19);
        f = _mm256_blend_epi32(even, _mm256_slli_epi64(odd, 32), 0xaa);
    }
    __m256i to_seed = _mm256_cmpeq_epi32(cqv, seed);
    *out = _mm256_add_epi32(*out, _mm256_andnot_si256(sign, _mm256_and_si256(f, to_seed)));
    *in = _mm256_add_epi32(*in, _mm256_and_si256(f, sign));
}

/* Next heights of the 8 cells i0 .. i0 + 7 (dirs as for slope_block_body),
 * thresholds >= 0. sides: bit 0, lane 0 is the window's west side (x = 0:
 * no W, SW, NW neighbours); bit 1, lane 7 its east side (no E, SE, NE); the
 * lanes are otherwise inside the window's sides. narrow: with 32-bit products;
 * returns 0 and writes nothing when some factor exceeds lim = UINT32_MAX /
 * roughness, where the 32-bit product would differ from the 64-bit one (at
 * roughness 0.3 a step of 21.8 m at 10^4 units per m: the deep box's bow
 * wave reaches it), and the caller redoes the unit with narrow = 0. */
static SIM_TARGET_AVX2 SIM_ALWAYS_INLINE int slope_unit8(const ground_material_row *r, int w,
                                                         const int32_t *restrict cls,
                                                         const int32_t *restrict heights, int i0,
                                                         int32_t *restrict dst, unsigned dirs,
                                                         unsigned sides, int narrow, uint32_t lim)
{
    const int32_t ax = r->slope_threshold_axial, dg = r->slope_threshold_diagonal;
    const __m256i rough = _mm256_set1_epi32(r->roughness_q16);
    const __m256i hm = _mm256_loadu_si256((const __m256i *)(heights + i0));
    const __m256i west = _mm256_setr_epi32(0, -1, -1, -1, -1, -1, -1, -1);
    const __m256i east = _mm256_setr_epi32(-1, -1, -1, -1, -1, -1, -1, 0);
    __m256i out = _mm256_setzero_si256(), in = out, peak = out;
    /* slope_next's order, E, W, S, N, SE, SW, NE, NW, written out: gcc does
     * not unroll the loop over the directions itself; side: 1 west, 2 east */
#define SLOPE_DIR8(j, o, th, side)                                                                 \
    do {                                                                                           \
        if (dirs & 1u << (j))                                                                      \
            slope_dir8(hm, heights + i0 + (o), cls + i0 + (o), th, rough, narrow,                  \
                       (sides & (side)) != 0, (side) == 1 ? west : east, &out, &in, &peak);        \
    } while (0)
    SLOPE_DIR8(0, 1, ax, 2);
    SLOPE_DIR8(1, -1, ax, 1);
    SLOPE_DIR8(2, w, ax, 0);
    SLOPE_DIR8(3, -w, ax, 0);
    SLOPE_DIR8(4, w + 1, dg, 2);
    SLOPE_DIR8(5, w - 1, dg, 1);
    SLOPE_DIR8(6, -w + 1, dg, 2);
    SLOPE_DIR8(7, -w - 1, dg, 1);
#undef SLOPE_DIR8
    const __m256i limv = _mm256_set1_epi32((int32_t)lim);
    if (narrow &&
        _mm256_movemask_epi8(_mm256_cmpeq_epi32(_mm256_max_epu32(peak, limv), limv)) != -1)
        return 0;
    __m256i own_seed = _mm256_cmpeq_epi32(_mm256_loadu_si256((const __m256i *)(cls + i0)),
                                          _mm256_set1_epi32(SIM_CELL_SEED));
    __m256i next = _mm256_add_epi32(_mm256_sub_epi32(hm, out), _mm256_and_si256(in, own_seed));
    _mm256_storeu_si256((__m256i *)dst, next);
    return 1;
}

/* slope_unit8 for a unit of row y of h, dirs a constant in each call:
 * first with 32-bit products, again with 64-bit ones if they overflow */
static SIM_TARGET_AVX2 SIM_ALWAYS_INLINE void
slope_unit8_dirs(const ground_material_row *r, int w, const int32_t *cls, const int32_t *heights,
                 int i0, int32_t *dst, unsigned dirs, unsigned sides, uint32_t lim)
{
    if (!slope_unit8(r, w, cls, heights, i0, dst, dirs, sides, 1, lim))
        slope_unit8(r, w, cls, heights, i0, dst, dirs, sides, 0, 0);
}

static SIM_TARGET_AVX2 SIM_ALWAYS_INLINE void slope_unit8_row(const ground_material_row *r, int w,
                                                              int h, const int32_t *cls,
                                                              const int32_t *heights, int y, int i0,
                                                              int32_t *dst, uint32_t lim)
{
    if (y > 0 && y < h - 1)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL, 0, lim);
    else if (h == 1)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, 3u, 0, lim);
    else if (y == 0)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL & ~SLOPE_DIRS_NO_NORTH, 0,
                         lim);
    else
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL & ~SLOPE_DIRS_NO_SOUTH, 0,
                         lim);
}

/* A unit of an inner row (0 < y < h - 1) over cells b .. b + 7 of a window
 * 8 or more wide, the window's sides included (sides as for slope_unit8). */
static SIM_TARGET_AVX2 SIM_ALWAYS_INLINE void slope_unit8_inner(const ground_material_row *r, int w,
                                                                const int32_t *cls,
                                                                const int32_t *heights, int b,
                                                                int i0, int32_t *dst, uint32_t lim)
{
    unsigned sides = (b == 0 ? 1u : 0u) | (b + 8 == w ? 2u : 0u);
    if (sides == 0)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL, 0, lim);
    else if (sides == 1)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL, 1, lim);
    else if (sides == 2)
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL, 2, lim);
    else
        slope_unit8_dirs(r, w, cls, heights, i0, dst, SLOPE_DIRS_ALL, 3, lim);
}

/* The AVX2 form: a block's cells in units of 8 lanes, each placed over as
 * many of them as it can (the last one of a row ends at the side, starting
 * early; only the block's own cells are kept), so a window 10 or more cells
 * wide takes vectors and a narrow block's remainder costs one unit, not a
 * whole block. In an inner row the units take the window's two side cells
 * too, with the neighbours off the window masked (slope_unit8's sides): a
 * wheel's window is ~25 cells wide, so nearly every block it visits holds a
 * side cell, and those went one by one through sim_slope_next, a sixth of
 * the engine's tick (issue 32); the top and bottom rows keep them so. */
static SIM_TARGET_AVX2 void slope_blocks_range_avx2(const slope_blocks_loop *l, int64_t begin,
                                                    int64_t end)
{
    const int w = l->w, h = l->h;
    const ground_material_row *r = &l->t->rows[0];
    const uint32_t lim =
        r->roughness_q16 > 0 ? UINT32_MAX / (uint32_t)r->roughness_q16 : UINT32_MAX;
    for (int64_t c = begin; c < end; c++) {
        int y = sim_slope_y(l->blocks[c]), x0 = sim_slope_x(l->blocks[c]) * SLOPE_SEG;
        int x1 = x0 + SLOPE_SEG < w ? x0 + SLOPE_SEG : w, row = y * w;
        int lo = x0 > 0 ? x0 : 1, hi = x1 < w ? x1 : w - 1;
        if (w - 2 < 8 || lo >= hi) {
            slope_rest(l, y, x0, x1, x0, x0);
            continue;
        }
        if (y > 0 && y < h - 1) {
            for (int u = x0; u < x1; u += 8) {
                int b = u < w - 8 ? u : w - 8, e = u + 8 < x1 ? u + 8 : x1;
                if (b == u && e == u + 8) { /* all 8 lanes are the block's: in place */
                    slope_unit8_inner(r, w, l->cls, l->heights, b, row + b, l->value + row + b,
                                      lim);
                    continue;
                }
                int32_t next[8];
                slope_unit8_inner(r, w, l->cls, l->heights, b, row + b, next, lim);
                for (int x = u; x < e; x++)
                    l->value[row + x] = next[x - b];
            }
            continue;
        }
        for (int u = lo; u < hi; u += 8) {
            int b = u < w - 9 ? u : w - 9, e = u + 8 < hi ? u + 8 : hi;
            int32_t next[8];
            slope_unit8_row(r, w, h, l->cls, l->heights, y, row + b, next, lim);
            for (int x = u; x < e; x++)
                l->value[row + x] = next[x - b];
        }
        slope_rest(l, y, x0, x1, lo, hi);
    }
}
#endif

static void slope_blocks_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    (void)thread;
    const slope_blocks_loop *l = ctx;
#if SIM_AVX2_CLONE
    const ground_material_row *r = &l->t->rows[0];
    if (sim_cpu_avx2() && r->slope_threshold_axial >= 0 && r->slope_threshold_diagonal >= 0) {
        slope_blocks_range_avx2(l, begin, end);
        return;
    }
#endif
    slope_blocks_range_base(l, begin, end);
}

/* Is some cell of i0 .. i0 + lanes - 1 (all one cell or more inside the
 * window) steeper than th towards some neighbour? The filter of the first
 * blocks: sim_slope_may_move needs a neighbour beyond its direction's
 * threshold (>= th, the smaller) and a class besides, so every cell that may
 * move passes it. Max and min over the 8 neighbours, so it vectorises. */
static SIM_ALWAYS_INLINE int slope_steep_body(int w, const int32_t *restrict heights, int i0,
                                              int32_t th, int lanes)
{
    const int off[8] = {1, -1, w, -w, w + 1, w - 1, -w + 1, -w - 1};
    const int32_t *restrict hm = heights + i0;
    int32_t hi[SLOPE_SEG], lo[SLOPE_SEG];
    for (int l = 0; l < lanes; l++)
        hi[l] = lo[l] = hm[l];
    for (int j = 0; j < 8; j++)
        for (int l = 0; l < lanes; l++) {
            int32_t v = hm[l + off[j]];
            hi[l] = v > hi[l] ? v : hi[l];
            lo[l] = v < lo[l] ? v : lo[l];
        }
    int steep = 0;
    for (int l = 0; l < lanes; l++)
        steep |= (hi[l] - hm[l] > th) | (hm[l] - lo[l] > th);
    return steep;
}

/* The first blocks of rows [begin, end): mark[y * segs + s] = 1 for a block
 * holding a cell that may move — an inner cell that passes the filter
 * above, a cell of the window's border that sim_slope_may_move. A superset
 * of the cells that may move, which changes nothing (above); it replaces a
 * per-cell list whose inner cells each took the filter and then
 * sim_slope_may_move one at a time. */
typedef struct slope_first_loop {
    const ground_material_table *t;
    int w, h, segs;
    const int32_t *cls, *heights;
    uint8_t *mark;
} slope_first_loop;

static SIM_ALWAYS_INLINE void slope_first_body(const slope_first_loop *l, int64_t begin,
                                               int64_t end)
{
    const int w = l->w, h = l->h, segs = l->segs;
    const ground_material_row *r = &l->t->rows[0];
    const int32_t th = r->slope_threshold_axial < r->slope_threshold_diagonal
                           ? r->slope_threshold_axial
                           : r->slope_threshold_diagonal;
    for (int y = (int)begin; y < (int)end; y++) {
        uint8_t *mark = l->mark + (size_t)y * segs;
        int inner_row = y > 0 && y < h - 1;
        for (int s = 0; s < segs; s++) {
            int x0 = s * SLOPE_SEG, x1 = x0 + SLOPE_SEG < w ? x0 + SLOPE_SEG : w;
            int lo = inner_row ? (x0 > 0 ? x0 : 1) : x1, hi = inner_row && x1 > w - 1 ? w - 1 : x1;
            int steep = 0;
            if (lo + SLOPE_SEG == hi)
                steep = slope_steep_body(w, l->heights, y * w + lo, th, SLOPE_SEG);
            else
                for (int x = lo; x < hi && !steep; x++)
                    steep = slope_steep_body(w, l->heights, y * w + x, th, 1);
            for (int x = x0; x < x1 && !steep; x++) /* the border: the rule itself */
                if (x < lo || x >= hi)
                    steep = sim_slope_may_move(l->t, NULL, w, h, l->cls, l->heights, x, y);
            mark[s] = (uint8_t)steep;
        }
    }
}

#if SIM_AVX2_CLONE
SIM_TARGET_AVX2 static void slope_first_range_avx2(const slope_first_loop *l, int64_t begin,
                                                   int64_t end)
{
    slope_first_body(l, begin, end);
}
#endif

static void slope_first_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    (void)thread;
#if SIM_AVX2_CLONE
    if (sim_cpu_avx2()) {
        slope_first_range_avx2(ctx, begin, end);
        return;
    }
#endif
    slope_first_body(ctx, begin, end);
}

/* Write block (y, s)'s next heights; mark for the next iteration the blocks
 * of rows y - 1 .. y + 1 that hold a changed cell or a neighbour of one. */
static void slope_block_commit(int w, int h, int segs, int y, int s, const int32_t *value,
                               int32_t *heights, uint8_t *next)
{
    int x0 = s * SLOPE_SEG, x1 = x0 + SLOPE_SEG < w ? x0 + SLOPE_SEG : w, i0 = y * w + x0;
    /* whether any cell changed, and whether the first and the last did (the
     * neighbouring blocks then hold neighbours of a changed cell): a compare
     * over the block and a copy, no branch per cell */
    int changed = 0;
    if (x1 - x0 == SLOPE_SEG)
        for (int l = 0; l < SLOPE_SEG; l++)
            changed |= value[i0 + l] != heights[i0 + l];
    else
        for (int l = 0; l < x1 - x0; l++)
            changed |= value[i0 + l] != heights[i0 + l];
    if (!changed)
        return;
    int first_changed = value[i0] != heights[i0];
    int last_changed = value[i0 + x1 - x0 - 1] != heights[i0 + x1 - x0 - 1];
    memcpy(heights + i0, value + i0, (size_t)(x1 - x0) * sizeof *heights);
    int s0 = first_changed && s > 0 ? s - 1 : s;
    int s1 = last_changed && s + 1 < segs ? s + 1 : s;
    for (int qy = y > 0 ? y - 1 : 0; qy <= (y < h - 1 ? y + 1 : h - 1); qy++)
        for (int qs = s0; qs <= s1; qs++)
            next[qy * segs + qs] = 1;
}

/* scratch: 4 * w * h int32 (value, the block list, marks). */
void sim_even_slopes_blocks(const sim_params *p, const ground_material_table *t, int w, int h,
                            const int32_t *cls, int32_t *heights, int32_t *scratch)
{
    int n = w * h, segs = (w + SLOPE_SEG - 1) / SLOPE_SEG;
    int32_t *restrict value = scratch, *restrict blocks = scratch + 2 * n;
    uint8_t *restrict mark = (uint8_t *)(scratch + 3 * n), *restrict next = mark + h * segs;
    if (p->slope_iterations <= 0)
        return;
    /* rows write only their own marks: bands are exact */
    slope_first_loop f = {t, w, h, segs, cls, heights, mark};
    int rows_bands = sim_band_threads(n);
    sim_parallel_for(h, sim_band_chunk(h, rows_bands), rows_bands, slope_first_range, &f);
    for (int32_t iter = 0; iter < p->slope_iterations; iter++) {
        int nb = 0;
        for (int y = 0; y < h; y++)
            for (int s = 0; s < segs; s++)
                if (mark[y * segs + s])
                    blocks[nb++] = sim_slope_pack(s, y);
        if (nb == 0)
            break;
        /* Jacobi: every block reads the old heights; bands are exact */
        slope_blocks_loop l = {t, w, h, cls, heights, blocks, value};
        int bands = sim_band_threads((int64_t)nb * SLOPE_SEG);
        sim_parallel_for(nb, sim_band_chunk(nb, bands), bands, slope_blocks_range, &l);
        memset(next, 0, (size_t)h * segs);
        for (int c = 0; c < nb; c++)
            slope_block_commit(w, h, segs, sim_slope_y(blocks[c]), sim_slope_x(blocks[c]), value,
                               heights, next);
        uint8_t *tmp = mark;
        mark = next;
        next = tmp;
    }
}
