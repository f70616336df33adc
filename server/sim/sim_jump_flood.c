/*
 * sim_jump_flood.c: the CPU twin's jump flooding (thesis ch. 4.1.4), the
 * stage of a tick between classify and displacement: every penetrated or
 * obstacle cell learns its nearest free cell, to which displacement sends
 * its material. sim_jump_flood (sparse, what the engine runs) and
 * sim_jump_flood_dense (its reference) give the same seeds bit for bit, and
 * shaders/jump_flood.comp mirrors them (sim_stages.c states the rules).
 */
#include "sim/sim_internal.h"

#include <string.h>

/* Is seed candidate a (index, distance) better than b for this cell? */
static int seed_better(int32_t da, uint32_t ha, int32_t a, int32_t db, uint32_t hb, int32_t b)
{
    if (da != db)
        return da < db;
    if (ha != hb)
        return ha < hb;
    return a < b;
}

/*
 * Step sizes: K = the largest power of two below max(w, h) (1 for a 1-cell
 * side), then K/2, ..., 1. A batch may run the largest window's sequence for
 * every window: steps >= max(w, h) only look outside the window and change
 * nothing.
 */
static int jump_flood_first_step(int w, int h)
{
    int side = w > h ? w : h;
    int k = 1;
    while (k * 2 < side)
        k *= 2;
    return k;
}

void sim_jump_flood_dense(const sim_params *p, int w, int h, int origin_x, int origin_y,
                          const int32_t *cls, int32_t *seed, int32_t *scratch)
{
    int n = w * h;
    for (int i = 0; i < n; i++)
        seed[i] = cls[i] == SIM_CELL_SEED ? i : -1;
    int32_t *in = seed, *out = scratch;
    for (int k = jump_flood_first_step(w, h); k >= 1; k /= 2) {
        for (int y = 0; y < h; y++) {
            for (int x = 0; x < w; x++) {
                int32_t best = in[y * w + x];
                int32_t best_d = 0;
                uint32_t best_h = 0;
                if (best >= 0) {
                    int bx = best % w, by = best / w;
                    best_d = sim_metric_distance(p->metric, bx - x, by - y);
                    best_h = sim_cell_hash(origin_x + bx, origin_y + by);
                }
                for (int j = 0; j < 8; j++) {
                    int qx = x + sim_neighbour_dx[j] * k, qy = y + sim_neighbour_dy[j] * k;
                    if (qx < 0 || qy < 0 || qx >= w || qy >= h)
                        continue;
                    int32_t s = in[qy * w + qx];
                    if (s < 0)
                        continue;
                    int sx = s % w, sy = s / w;
                    int32_t d = sim_metric_distance(p->metric, sx - x, sy - y);
                    uint32_t hs = sim_cell_hash(origin_x + sx, origin_y + sy);
                    if (best < 0 || seed_better(d, hs, s, best_d, best_h, best)) {
                        best = s;
                        best_d = d;
                        best_h = hs;
                    }
                }
                out[y * w + x] = best;
            }
        }
        int32_t *t = in;
        in = out;
        out = t;
    }
    if (in != seed)
        memcpy(seed, in, (size_t)n * sizeof *seed);
}

/*
 * The sparse jump flooding the engine runs; sim_jump_flood_dense is its
 * reference (test_sim_stages compares them on random windows). A free cell
 * is its own nearest seed at distance 0, which no candidate can beat, so
 * only the cells that are not free are visited: the work is 8 candidates
 * per step per penetrated or obstacle cell, not per window cell. Seeds are
 * carried packed as (y << 16 | x) — packed order is index order — so a
 * candidate costs no division, and the hash that breaks ties is computed
 * only on a tie of distances.
 *
 * What a cell keeps is the least of {its seed, its 8 candidates} in the
 * order (distance, sim_cell_hash, index): a strict total order, so the
 * answer does not depend on the order the candidates are looked at
 * (jfa_pick looks at them one at a time). That lets runs of listed cells
 * along a row go 8 at a time (jfa_block), and each loop is compiled once
 * per metric (jfa_range), so the distance is inline and branch-free. In
 * AVX2 a run shorter than 8 is one block too, with the hash in the vector
 * for ties (jfa_blocks_avx2): a wheel's footprint is a few cells across,
 * and its cells went one by one through jfa_pick, 11 % of a driven world's
 * tick in the daemon (issue 32).
 */
#define JFA_PACK_MAX 32768
#define JFA_LANES 8
#define JFA_ALWAYS_INLINE SIM_ALWAYS_INLINE

static JFA_ALWAYS_INLINE int32_t jfa_pick(sim_metric metric, int origin_x, int origin_y, int x,
                                          int y, int k, int w, int h, const int32_t *restrict in)
{
    int32_t best = in[y * w + x];
    int32_t best_d = 0;
    uint32_t best_h = 0;
    int have_h = 0;
    if (best >= 0)
        best_d = sim_metric_distance(metric, (best & 0xffff) - x, (best >> 16) - y);
    for (int j = 0; j < 8; j++) {
        int qx = x + sim_neighbour_dx[j] * k, qy = y + sim_neighbour_dy[j] * k;
        if (qx < 0 || qy < 0 || qx >= w || qy >= h)
            continue;
        int32_t s = in[qy * w + qx];
        if (s < 0 || s == best)
            continue;
        int sx = s & 0xffff, sy = s >> 16;
        int32_t d = sim_metric_distance(metric, sx - x, sy - y);
        if (best >= 0 && d > best_d)
            continue;
        if (best >= 0 && d == best_d) {
            if (!have_h)
                best_h = sim_cell_hash(origin_x + (best & 0xffff), origin_y + (best >> 16));
            have_h = 1;
            uint32_t hs = sim_cell_hash(origin_x + sx, origin_y + sy);
            if (hs > best_h || (hs == best_h && s > best))
                continue;
            best_h = hs;
        } else {
            have_h = 0;
        }
        best = s;
        best_d = d;
    }
    return best;
}

/* One step of sparse jump flooding over the listed cells (packed). */
typedef struct jfa_loop {
    sim_metric metric;
    int origin_x, origin_y, w, h, k;
    int avx2; /* jfa_blocks_avx2 runs the blocks (sim_cpu_avx2) */
    const int32_t *list;
    const int32_t *in;
    int32_t *out;
} jfa_loop;

/* Where a block's 8 candidates are: for candidate j of the cell at x,
 * in[off[j] + x] | mask[j]. A candidate outside the window (the same for
 * every cell of a block) reads the cell itself, masked to -1. */
typedef struct jfa_block_at {
    int32_t off[8];
    int32_t mask[8];
} jfa_block_at;

/*
 * Cells x .. x + 7 of row y, in SSE2 (the x86-64 baseline): the candidates
 * of consecutive cells are consecutive cells of rows y - k, y and y + k, so
 * each candidate is one contiguous load per 4 lanes and nothing branches.
 * A seed minus the cell, both packed (y << 16 | x), is (dy, dx) as two
 * int16 (|dx|, |dy| < JFA_PACK_MAX), so pmaddwd gives dx² + dy² (or, of
 * |dx| and |dy|, their sum) in one instruction: sim_metric_distance's
 * integers exactly. No seed (-1) is INT32_MAX, above every distance. Each
 * lane keeps the nearest seed and a flag for a second, different seed at
 * that same distance; without one, the nearest is the least element and
 * jfa_pick's answer. The flagged lanes (a tie the hash must break: rare)
 * come back as bits for jfa_pick to redo. Elsewhere every cell takes
 * jfa_pick (JFA_BLOCKS 0).
 */
#if defined(__SSE2__)
#include <emmintrin.h>
#define JFA_BLOCKS 1

static JFA_ALWAYS_INLINE __m128i jfa_distance4(sim_metric metric, __m128i s, __m128i cell)
{
    const __m128i none = _mm_set1_epi32(INT32_MAX), v = _mm_sub_epi16(s, cell);
    __m128i d;
    if (metric == SIM_METRIC_EUCLIDEAN) {
        d = _mm_madd_epi16(v, v);
    } else {
        __m128i a = _mm_max_epi16(v, _mm_sub_epi16(_mm_setzero_si128(), v));
        if (metric == SIM_METRIC_MANHATTAN)
            d = _mm_madd_epi16(a, _mm_set1_epi16(1));
        else
            d = _mm_and_si128(_mm_max_epi16(a, _mm_srli_epi32(a, 16)), _mm_set1_epi32(0xffff));
    }
    __m128i missing = _mm_srai_epi32(s, 31);
    return _mm_or_si128(_mm_andnot_si128(missing, d), _mm_and_si128(missing, none));
}

static JFA_ALWAYS_INLINE int jfa_block(sim_metric metric, const jfa_block_at *restrict at, int x,
                                       int y, int row, const int32_t *restrict in,
                                       int32_t *restrict out)
{
    int ties = 0;
    for (int half = 0; half < 2; half++) {
        int cx = x + 4 * half;
        const __m128i cell =
            _mm_add_epi32(_mm_set1_epi32(y << 16 | cx), _mm_setr_epi32(0, 1, 2, 3));
        __m128i best = _mm_loadu_si128((const __m128i *)(in + row + cx));
        __m128i best_d = jfa_distance4(metric, best, cell), tie = _mm_setzero_si128();
        for (int j = 0; j < 8; j++) {
            __m128i s = _mm_or_si128(_mm_loadu_si128((const __m128i *)(in + at->off[j] + cx)),
                                     _mm_set1_epi32(at->mask[j]));
            __m128i d = jfa_distance4(metric, s, cell);
            __m128i nearer = _mm_cmplt_epi32(d, best_d);
            __m128i same = _mm_andnot_si128(_mm_cmpeq_epi32(s, best), _mm_cmpeq_epi32(d, best_d));
            tie = _mm_andnot_si128(nearer, _mm_or_si128(tie, same));
            best = _mm_or_si128(_mm_and_si128(nearer, s), _mm_andnot_si128(nearer, best));
            best_d = _mm_or_si128(_mm_and_si128(nearer, d), _mm_andnot_si128(nearer, best_d));
        }
        _mm_storeu_si128((__m128i *)(out + row + cx), best);
        ties |= _mm_movemask_ps(_mm_castsi128_ps(tie)) << (4 * half);
    }
    return ties;
}

#if SIM_AVX2_CLONE
#include <immintrin.h>

/* jfa_distance4 on 8 lanes (AVX2): the same integers */
static SIM_TARGET_AVX2 JFA_ALWAYS_INLINE __m256i jfa_distance8(sim_metric metric, __m256i s,
                                                               __m256i cell)
{
    const __m256i none = _mm256_set1_epi32(INT32_MAX), v = _mm256_sub_epi16(s, cell);
    __m256i d;
    if (metric == SIM_METRIC_EUCLIDEAN) {
        d = _mm256_madd_epi16(v, v);
    } else {
        __m256i a = _mm256_max_epi16(v, _mm256_sub_epi16(_mm256_setzero_si256(), v));
        if (metric == SIM_METRIC_MANHATTAN)
            d = _mm256_madd_epi16(a, _mm256_set1_epi16(1));
        else
            d = _mm256_and_si256(_mm256_max_epi16(a, _mm256_srli_epi32(a, 16)),
                                 _mm256_set1_epi32(0xffff));
    }
    __m256i missing = _mm256_srai_epi32(s, 31);
    return _mm256_blendv_epi8(d, none, missing);
}

/* jfa_block with the 8 lanes in one AVX2 register: the nearest seed of
 * cells x .. x + 7 of row y, and in *tie the lanes where a second, different
 * seed is as near (the hash must break the tie: jfa_exact8). */
static SIM_TARGET_AVX2 JFA_ALWAYS_INLINE __m256i jfa_near8(sim_metric metric,
                                                           const jfa_block_at *restrict at, int x,
                                                           int y, int row,
                                                           const int32_t *restrict in, int *tie)
{
    const __m256i cell =
        _mm256_add_epi32(_mm256_set1_epi32(y << 16 | x), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
    __m256i best = _mm256_loadu_si256((const __m256i *)(in + row + x));
    __m256i best_d = jfa_distance8(metric, best, cell), ties = _mm256_setzero_si256();
    for (int j = 0; j < 8; j++) {
        __m256i s = _mm256_or_si256(_mm256_loadu_si256((const __m256i *)(in + at->off[j] + x)),
                                    _mm256_set1_epi32(at->mask[j]));
        __m256i d = jfa_distance8(metric, s, cell);
        __m256i nearer = _mm256_cmpgt_epi32(best_d, d);
        __m256i same =
            _mm256_andnot_si256(_mm256_cmpeq_epi32(s, best), _mm256_cmpeq_epi32(d, best_d));
        ties = _mm256_andnot_si256(nearer, _mm256_or_si256(ties, same));
        best = _mm256_blendv_epi8(best, s, nearer);
        best_d = _mm256_blendv_epi8(best_d, d, nearer);
    }
    *tie = _mm256_movemask_ps(_mm256_castsi256_ps(ties));
    return best;
}

/* sim_cell_hash of 8 packed seeds, plus INT32_MIN so that a signed compare
 * orders them as the unsigned hashes (AVX2): the same integers. */
static SIM_TARGET_AVX2 JFA_ALWAYS_INLINE __m256i jfa_hash8(__m256i s, __m256i origin_x,
                                                           __m256i origin_y)
{
    __m256i x = _mm256_add_epi32(_mm256_and_si256(s, _mm256_set1_epi32(0xffff)), origin_x);
    __m256i y = _mm256_add_epi32(_mm256_srli_epi32(s, 16), origin_y);
    __m256i v =
        _mm256_xor_si256(_mm256_mullo_epi32(x, _mm256_set1_epi32((int32_t)SIM_CELL_HASH_X)),
                         _mm256_mullo_epi32(y, _mm256_set1_epi32((int32_t)SIM_CELL_HASH_Y)));
    /* hash_lowbias32 */
    v = _mm256_xor_si256(v, _mm256_srli_epi32(v, 16));
    v = _mm256_mullo_epi32(v, _mm256_set1_epi32((int32_t)HASH_LOWBIAS32_M1));
    v = _mm256_xor_si256(v, _mm256_srli_epi32(v, 15));
    v = _mm256_mullo_epi32(v, _mm256_set1_epi32((int32_t)HASH_LOWBIAS32_M2));
    v = _mm256_xor_si256(v, _mm256_srli_epi32(v, 16));
    return _mm256_xor_si256(v, _mm256_set1_epi32(INT32_MIN));
}

/* jfa_pick for 8 lanes: the least of {the cell's seed, its 8 candidates} in
 * the order (distance, sim_cell_hash, index), every lane at once. For the
 * blocks with a tie (on a wheel's footprint, a few cells wide, most blocks
 * have one: the cells along its middle are as near to either side), where
 * jfa_pick would redo each tied lane. No seed (-1) is at INT32_MAX, above
 * every seed; two of them are the same -1, whichever is kept. */
static SIM_TARGET_AVX2 JFA_ALWAYS_INLINE __m256i jfa_exact8(sim_metric metric,
                                                            const jfa_block_at *restrict at, int x,
                                                            int y, int row,
                                                            const int32_t *restrict in,
                                                            __m256i origin_x, __m256i origin_y)
{
    const __m256i cell =
        _mm256_add_epi32(_mm256_set1_epi32(y << 16 | x), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
    __m256i best = _mm256_loadu_si256((const __m256i *)(in + row + x));
    __m256i best_d = jfa_distance8(metric, best, cell),
            best_h = jfa_hash8(best, origin_x, origin_y);
    for (int j = 0; j < 8; j++) {
        __m256i s = _mm256_or_si256(_mm256_loadu_si256((const __m256i *)(in + at->off[j] + x)),
                                    _mm256_set1_epi32(at->mask[j]));
        __m256i d = jfa_distance8(metric, s, cell), hs = jfa_hash8(s, origin_x, origin_y);
        /* (d, hs, s) < (best_d, best_h, best) */
        __m256i lower = _mm256_or_si256(
            _mm256_cmpgt_epi32(best_h, hs),
            _mm256_and_si256(_mm256_cmpeq_epi32(hs, best_h), _mm256_cmpgt_epi32(best, s)));
        __m256i better = _mm256_or_si256(_mm256_cmpgt_epi32(best_d, d),
                                         _mm256_and_si256(_mm256_cmpeq_epi32(d, best_d), lower));
        best = _mm256_blendv_epi8(best, s, better);
        best_d = _mm256_blendv_epi8(best_d, d, better);
        best_h = _mm256_blendv_epi8(best_h, hs, better);
    }
    return best;
}

/* Cells x .. b - 1 of row y in AVX2 blocks; the cells [e0, e1) of the row
 * around them all have the same candidates inside the window (at), e1 - e0
 * >= JFA_LANES. What is left after the whole blocks (and a run shorter than
 * a block: a wheel's footprint is a few cells across) is one more block
 * placed over it within [e0, e1), keeping only its lanes: the lanes beside
 * it are other cells of the row, free ones or listed ones, read but not
 * written. A block with a tie among its kept lanes is computed again with
 * the hash (jfa_exact8). */
static SIM_TARGET_AVX2 void jfa_blocks_avx2(const jfa_loop *l, sim_metric metric,
                                            const jfa_block_at *at, int x, int b, int y, int e1)
{
    const int row = y * l->w;
    const __m256i origin_x = _mm256_set1_epi32(l->origin_x),
                  origin_y = _mm256_set1_epi32(l->origin_y);
    const __m256i bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    while (x < b) {
        int at_x = x, n = b - x < JFA_LANES ? b - x : JFA_LANES;
        if (at_x + JFA_LANES > e1)
            at_x = e1 - JFA_LANES;
        unsigned keep = ((1u << n) - 1u) << (x - at_x);
        int tie;
        __m256i best = jfa_near8(metric, at, at_x, y, row, l->in, &tie);
        if (tie & (int)keep)
            best = jfa_exact8(metric, at, at_x, y, row, l->in, origin_x, origin_y);
        if (keep == 0xffu) {
            _mm256_storeu_si256((__m256i *)(l->out + row + at_x), best);
        } else {
            /* only the kept lanes are written: the others may be another
             * band's cells, which that band writes */
            __m256i kept = _mm256_and_si256(_mm256_set1_epi32((int32_t)keep), bit);
            _mm256_maskstore_epi32(l->out + row + at_x, _mm256_cmpeq_epi32(kept, bit), best);
        }
        x += n;
    }
}
#endif
#else
#define JFA_BLOCKS 0
#endif

/* Listed cells x0 .. x1 - 1 of row y at step k. A block needs the same
 * candidates inside the window for all its cells, so the run is cut where
 * x - k or x + k crosses the window's edge; short pieces go one by one. */
static JFA_ALWAYS_INLINE void jfa_run(const jfa_loop *l, sim_metric metric, int x0, int x1, int y)
{
    const int w = l->w, h = l->h, k = l->k, row = y * w;
    /* x >= k: left candidates inside; x < w - k: right ones inside */
    int e0 = k < w - k ? k : w - k, e1 = k < w - k ? w - k : k;
    int lo = e0 < x0 ? x0 : e0 > x1 ? x1 : e0, hi = e1 < lo ? lo : e1 > x1 ? x1 : e1;
    const int cut[4] = {x0, lo, hi, x1};
#if JFA_BLOCKS
    /* e0 < 0 and e1 > w where k > w (a window taller than wide) */
    const int edge[4] = {0, e0 > 0 ? e0 : 0, e1 < w ? e1 : w, w};
#endif
    for (int part = 0; part < 3; part++) {
        int x = cut[part], b = cut[part + 1];
#if JFA_BLOCKS
        /* cells [edge[part], edge[part + 1]) share which candidates are inside */
        int wide = edge[part + 1] - edge[part] >= JFA_LANES;
        if (x < b && (b - x >= JFA_LANES || (l->avx2 && wide))) {
            jfa_block_at at;
            for (int j = 0; j < 8; j++) {
                int dx = sim_neighbour_dx[j] * k, qy = y + sim_neighbour_dy[j] * k;
                int inside = x + dx >= 0 && b - 1 + dx < w && qy >= 0 && qy < h;
                at.off[j] = inside ? qy * w + dx : row;
                at.mask[j] = inside ? 0 : -1;
            }
#if SIM_AVX2_CLONE
            if (l->avx2 && wide) {
                jfa_blocks_avx2(l, metric, &at, x, b, y, edge[part + 1]);
                continue;
            }
#endif
            for (; x + JFA_LANES <= b; x += JFA_LANES) {
                int tie = jfa_block(metric, &at, x, y, row, l->in, l->out);
                for (int t = 0; tie; t++, tie >>= 1)
                    if (tie & 1)
                        l->out[row + x + t] =
                            jfa_pick(metric, l->origin_x, l->origin_y, x + t, y, k, w, h, l->in);
            }
        }
#endif
        for (; x < b; x++)
            l->out[row + x] = jfa_pick(metric, l->origin_x, l->origin_y, x, y, k, w, h, l->in);
    }
}

/* The listed cells [begin, end) of one step, as runs of consecutive cells
 * of a row (consecutive packed values). */
static JFA_ALWAYS_INLINE void jfa_cells(const jfa_loop *l, int64_t begin, int64_t end,
                                        sim_metric metric)
{
    const int32_t *restrict list = l->list;
    for (int64_t c = begin; c < end;) {
        int64_t e = c + 1;
        while (e < end && list[e] == list[e - 1] + 1)
            e++;
        int x0 = list[c] & 0xffff;
        jfa_run(l, metric, x0, x0 + (int)(e - c), list[c] >> 16);
        c = e;
    }
}

static void jfa_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    (void)thread;
    const jfa_loop *l = ctx;
    switch (l->metric) {
    case SIM_METRIC_MANHATTAN:
        jfa_cells(l, begin, end, SIM_METRIC_MANHATTAN);
        break;
    case SIM_METRIC_CHEBYSHEV:
        jfa_cells(l, begin, end, SIM_METRIC_CHEBYSHEV);
        break;
    case SIM_METRIC_EUCLIDEAN:
    default:
        jfa_cells(l, begin, end, SIM_METRIC_EUCLIDEAN);
        break;
    }
}

void sim_jump_flood(const sim_params *p, int w, int h, int origin_x, int origin_y,
                    const int32_t *cls, int32_t *seed, int32_t *scratch)
{
    if (w > JFA_PACK_MAX || h > JFA_PACK_MAX) {
        sim_jump_flood_dense(p, w, h, origin_x, origin_y, cls, seed, scratch);
        return;
    }
    int n = w * h;
    int32_t *restrict other = scratch, *restrict list = scratch + n;
    int count = 0;
    for (int y = 0, i = 0; y < h; y++) {
        for (int x = 0; x < w; x++, i++) {
            int free_cell = cls[i] == SIM_CELL_SEED;
            seed[i] = free_cell ? (y << 16 | x) : -1;
            if (!free_cell)
                list[count++] = y << 16 | x;
        }
    }
    if (count > 0) {
        memcpy(other, seed, (size_t)n * sizeof *seed);
        int32_t *in = seed, *out = other;
        jfa_loop l = {p->metric, origin_x, origin_y, w, h, 0, sim_cpu_avx2(), list, NULL, NULL};
        int bands = sim_band_threads(count);
        for (l.k = jump_flood_first_step(w, h); l.k >= 1; l.k /= 2) {
            /* each listed cell reads `in`, writes its own `out`: bands are exact */
            l.in = in;
            l.out = out;
            sim_parallel_for(count, sim_band_chunk(count, bands), bands, jfa_range, &l);
            int32_t *t = in;
            in = out;
            out = t;
        }
        if (in != seed)
            for (int c = 0; c < count; c++) {
                int i = (list[c] >> 16) * w + (list[c] & 0xffff);
                seed[i] = in[i];
            }
    }
    /* packed → window-local index; free cells are their own seed */
    for (int y = 0, i = 0; y < h; y++)
        for (int x = 0; x < w; x++, i++)
            seed[i] = seed[i] < 0 ? -1 : (seed[i] >> 16) * w + (seed[i] & 0xffff);
}
