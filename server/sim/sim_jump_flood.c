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
 * only on a tie of distances (the comparison is seed_better's, unchanged).
 */
#define JFA_PACK_MAX 32768

static int32_t jfa_pick(sim_metric metric, int origin_x, int origin_y, int x, int y, int k, int w,
                        int h, const int32_t *restrict in)
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

/* One step of sparse jump flooding over the listed cells. */
typedef struct jfa_loop {
    sim_metric metric;
    int origin_x, origin_y, w, h, k;
    const int32_t *list;
    const int32_t *in;
    int32_t *out;
} jfa_loop;

static void jfa_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    (void)thread;
    const jfa_loop *l = ctx;
    for (int64_t c = begin; c < end; c++) {
        int i = l->list[c], y = i / l->w, x = i - y * l->w;
        l->out[i] = jfa_pick(l->metric, l->origin_x, l->origin_y, x, y, l->k, l->w, l->h, l->in);
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
                list[count++] = i;
        }
    }
    if (count > 0) {
        memcpy(other, seed, (size_t)n * sizeof *seed);
        int32_t *in = seed, *out = other;
        jfa_loop l = {p->metric, origin_x, origin_y, w, h, 0, list, NULL, NULL};
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
            for (int c = 0; c < count; c++)
                seed[list[c]] = in[list[c]];
    }
    /* packed → window-local index; free cells are their own seed */
    for (int y = 0, i = 0; y < h; y++)
        for (int x = 0; x < w; x++, i++)
            seed[i] = seed[i] < 0 ? -1 : (seed[i] >> 16) * w + (seed[i] & 0xffff);
}
