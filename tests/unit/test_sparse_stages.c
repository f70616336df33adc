/*
 * test_sparse_stages.c: the sparse stages the engine runs (jump flooding over
 * the cells that are not free, slope evening over a work list) against their
 * dense references (sim_jump_flood_dense, sim_even_slopes_materials_dense),
 * stage for stage on random windows: identical seeds and identical heights,
 * for every metric, with one material and with per-cell materials, with
 * thresholds of 0, and with slope iteration counts from 0 to 40. The chain
 * classify → jump flood → displace → slopes runs once with each form and the
 * heights must agree bit for bit. All of it runs twice: with the AVX2 forms
 * of the hot loops (where the CPU has AVX2) and with the SSE2 baseline.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/sim_internal.h"
#include "check.h"
#include "test_params.h"

/* Heights: a smooth ramp with random bumps and cliffs, so some regions are at
 * rest and some are far over the thresholds. Bottom: blobs of penetration
 * and obstacles around a few centres. */
static void random_window(uint32_t *s, int w, int h, int32_t *heights, int32_t *bottom)
{
    int blobs = 1 + (int)(test_next_random(s) % 4);
    int bx[4], by[4], br[4];
    for (int b = 0; b < blobs; b++) {
        bx[b] = (int)(test_next_random(s) % (uint32_t)w);
        by[b] = (int)(test_next_random(s) % (uint32_t)h);
        br[b] = 1 + (int)(test_next_random(s) % 8);
    }
    int cliffs = (int)(test_next_random(s) % 3);
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            int32_t z = 20000 + 30 * x + 10 * y;
            if (test_next_random(s) % 8 == 0)
                z += (int32_t)(test_next_random(s) % 3000);
            if (cliffs > 0 && x > w / 2)
                z += 5000 * cliffs;
            heights[i] = z;
            bottom[i] = COLLIDER_BOTTOM_NONE;
            for (int b = 0; b < blobs; b++) {
                int dx = x - bx[b], dy = y - by[b];
                if (dx * dx + dy * dy > br[b] * br[b])
                    continue;
                bottom[i] = b % 2 == 0 ? z - 1 - (int32_t)(test_next_random(s) % 900)
                                       : z + (int32_t)(test_next_random(s) % 50);
            }
        }
    }
}

static void compare_on(const sim_params *p, const ground_material_table *t, const uint8_t *ids,
                       int w, int h, int origin_x, int origin_y, const int32_t *start,
                       const int32_t *bottom)
{
    int n = w * h;
    size_t bytes = sizeof(int32_t) * (size_t)n;
    int32_t *raw = malloc(bytes), *moved = malloc(bytes), *cls = malloc(bytes);
    int32_t *seed_sparse = malloc(bytes), *seed_dense = malloc(bytes);
    int32_t *h_sparse = malloc(bytes), *h_dense = malloc(bytes);
    int32_t *scratch = malloc(bytes * 5);

    memcpy(h_sparse, start, bytes);
    sim_classify_materials(p, t, ids, NULL, n, h_sparse, bottom, raw, moved, cls);
    sim_jump_flood(p, w, h, origin_x, origin_y, cls, seed_sparse, scratch);
    sim_jump_flood_dense(p, w, h, origin_x, origin_y, cls, seed_dense, scratch);
    CHECK(memcmp(seed_sparse, seed_dense, bytes) == 0, "%dx%d %s: sparse seeds equal dense", w, h,
          sim_metric_name(p->metric));

    /* slope evening alone, on the raw heights (many cells over threshold) */
    memcpy(h_sparse, start, bytes);
    memcpy(h_dense, start, bytes);
    sim_even_slopes_materials(p, t, ids, w, h, cls, h_sparse, scratch);
    sim_even_slopes_materials_dense(p, t, ids, w, h, cls, h_dense, scratch);
    CHECK(memcmp(h_sparse, h_dense, bytes) == 0, "%dx%d %s, %d iterations: slopes equal dense", w,
          h, ids ? "materials" : "uniform", p->slope_iterations);

    /* the whole chain after classify */
    memcpy(h_sparse, start, bytes);
    memcpy(h_dense, start, bytes);
    sim_displace(p, w, h, cls, seed_sparse, raw, moved, h_sparse, scratch);
    sim_even_slopes_materials(p, t, ids, w, h, cls, h_sparse, scratch);
    sim_displace(p, w, h, cls, seed_dense, raw, moved, h_dense, scratch);
    sim_even_slopes_materials_dense(p, t, ids, w, h, cls, h_dense, scratch);
    CHECK(memcmp(h_sparse, h_dense, bytes) == 0, "%dx%d %s/%s: chain equal dense", w, h,
          sim_method_name(p->method), sim_metric_name(p->metric));

    free(raw);
    free(moved);
    free(cls);
    free(seed_sparse);
    free(seed_dense);
    free(h_sparse);
    free(h_dense);
    free(scratch);
}

static void test_random_windows(void)
{
    static const int32_t iteration_counts[] = {0, 1, 3, 10, 40};
    uint32_t s = 12345;
    for (int round = 0; round < 80; round++) {
        int w = 1 + (int)(test_next_random(&s) % (round < 10 ? 3 : 70));
        int h = 1 + (int)(test_next_random(&s) % (round < 10 ? 3 : 70));
        int n = w * h;
        int32_t *start = malloc(sizeof(int32_t) * (size_t)n);
        int32_t *bottom = malloc(sizeof(int32_t) * (size_t)n);
        uint8_t *ids = malloc((size_t)n);
        random_window(&s, w, h, start, bottom);
        for (int i = 0; i < n; i++)
            ids[i] = (uint8_t)(test_next_random(&s) % 4); /* 3 rows: id 3 falls back to row 0 */
        sim_material m = sim_material_default();
        m.method = (sim_method)(round % 3);
        m.metric = (sim_metric)((round / 3) % 3);
        m.slope_iterations = iteration_counts[round % 5];
        if (round % 7 == 0)
            m.repose_deg = 0; /* thresholds 0: every difference is a slope */
        sim_params p = test_params_from_material(&m, 0);
        ground_material_table one = {.count = 1};
        one.rows[0] = sim_material_row_from_params(&p, 0);
        ground_material_table three = {.count = 3};
        for (int k = 0; k < 3; k++) {
            three.rows[k] = sim_material_row_from_params(&p, 0);
            three.rows[k].slope_threshold_axial = (int32_t)(test_next_random(&s) % 2000);
            three.rows[k].slope_threshold_diagonal = (int32_t)(test_next_random(&s) % 2800);
            three.rows[k].roughness_q16 = 1 + (int32_t)(test_next_random(&s) % 65536);
        }
        int ox = (int)(test_next_random(&s) % 5000), oy = (int)(test_next_random(&s) % 5000);
        compare_on(&p, &one, NULL, w, h, ox, oy, start, bottom);
        compare_on(&p, &three, ids, w, h, ox, oy, start, bottom);
        free(start);
        free(bottom);
        free(ids);
    }
}

/* Windows large enough that the work lists split into bands (more than
 * SIM_BAND_MIN_ITEMS cells move): 1, 2 and 7 threads equal the dense form. */
static void test_bands(void)
{
    enum { W = 300, H = 260, N = W * H };
    uint32_t s = 777;
    int32_t *start = malloc(sizeof(int32_t) * N), *bottom = malloc(sizeof(int32_t) * N);
    int32_t *cls = malloc(sizeof(int32_t) * N), *raw = malloc(sizeof(int32_t) * N);
    int32_t *moved = malloc(sizeof(int32_t) * N), *scratch = malloc(sizeof(int32_t) * N * 5);
    int32_t *seed_dense = malloc(sizeof(int32_t) * N), *seed = malloc(sizeof(int32_t) * N);
    int32_t *h_dense = malloc(sizeof(int32_t) * N), *h = malloc(sizeof(int32_t) * N);
    for (int i = 0; i < N; i++) {
        int x = i % W, y = i / W;
        start[i] = 20000 + (int32_t)(test_next_random(&s) % 4000) + (x > W / 2 ? 9000 : 0);
        int dx = x - W / 3, dy = y - H / 2;
        bottom[i] = dx * dx + dy * dy < 80 * 80 ? start[i] - 500 : COLLIDER_BOTTOM_NONE;
    }
    for (int metric = 0; metric < 3; metric++) {
        sim_material m = sim_material_default();
        m.metric = (sim_metric)metric;
        sim_params p = test_params_from_material(&m, 0);
        ground_material_table t = {.count = 1};
        t.rows[0] = sim_material_row_from_params(&p, 0);
        sim_classify(&p, N, start, bottom, raw, moved, cls);
        sim_jump_flood_dense(&p, W, H, 5, 9, cls, seed_dense, scratch);
        memcpy(h_dense, start, sizeof(int32_t) * N);
        sim_even_slopes_materials_dense(&p, &t, NULL, W, H, cls, h_dense, scratch);
        static const int threads[] = {1, 2, 7};
        for (int k = 0; k < 3; k++) {
            sim_set_threads(threads[k]);
            sim_jump_flood(&p, W, H, 5, 9, cls, seed, scratch);
            CHECK(memcmp(seed, seed_dense, sizeof(int32_t) * N) == 0,
                  "%s, %d threads: banded seeds equal dense", sim_metric_name(p.metric),
                  threads[k]);
            memcpy(h, start, sizeof(int32_t) * N);
            sim_even_slopes(&p, W, H, cls, h, scratch);
            CHECK(memcmp(h, h_dense, sizeof(int32_t) * N) == 0,
                  "%s, %d threads: banded slopes equal dense", sim_metric_name(p.metric),
                  threads[k]);
        }
        sim_set_threads(0);
    }
    free(start);
    free(bottom);
    free(cls);
    free(raw);
    free(moved);
    free(scratch);
    free(seed_dense);
    free(seed);
    free(h_dense);
    free(h);
}

/* Steep one-material windows: steps far beyond the 32-bit products' reach
 * (UINT32_MAX / roughness, 65,535 units at roughness 1.0), next to gentle
 * ones, so slope evening's AVX2 units take both the 32-bit products and the
 * 64-bit redo, in windows from 1 cell to wider than two blocks (the 8-lane
 * units begin at 10 cells wide, the 16-lane blocks at 18). */
static void test_steep_windows(void)
{
    static const int32_t roughness[] = {65536, 19661, 1, 40000};
    uint32_t s = 4242;
    for (int round = 0; round < 60; round++) {
        int w = 1 + (int)(test_next_random(&s) % 60), h = 1 + (int)(test_next_random(&s) % 30);
        int n = w * h;
        int32_t *start = malloc(sizeof(int32_t) * (size_t)n),
                *cls = malloc(sizeof(int32_t) * (size_t)n);
        int32_t *h_sparse = malloc(sizeof(int32_t) * (size_t)n);
        int32_t *h_dense = malloc(sizeof(int32_t) * (size_t)n);
        int32_t *scratch = malloc(sizeof(int32_t) * (size_t)n * 5);
        for (int i = 0; i < n; i++) {
            uint32_t r = test_next_random(&s);
            start[i] = 100000 + (int32_t)(r % 5000) + (r % 5 == 0 ? (int32_t)(r % 700000) : 0);
            cls[i] = r % 7 == 0    ? SIM_CELL_OBSTACLE
                     : r % 11 == 0 ? SIM_CELL_PENETRATING
                                   : SIM_CELL_SEED;
        }
        sim_material m = sim_material_default();
        m.slope_iterations = 1 + round % 12;
        if (round % 5 == 0)
            m.repose_deg = 0;
        sim_params p = test_params_from_material(&m, 0);
        ground_material_table t = {.count = 1};
        t.rows[0] = sim_material_row_from_params(&p, 0);
        t.rows[0].roughness_q16 = roughness[round % 4];
        memcpy(h_sparse, start, sizeof(int32_t) * (size_t)n);
        memcpy(h_dense, start, sizeof(int32_t) * (size_t)n);
        sim_even_slopes_materials(&p, &t, NULL, w, h, cls, h_sparse, scratch);
        sim_even_slopes_materials_dense(&p, &t, NULL, w, h, cls, h_dense, scratch);
        CHECK(memcmp(h_sparse, h_dense, sizeof(int32_t) * (size_t)n) == 0,
              "%dx%d steep, roughness %d, %d iterations: slopes equal dense", w, h,
              t.rows[0].roughness_q16, p.slope_iterations);
        free(start);
        free(cls);
        free(h_sparse);
        free(h_dense);
        free(scratch);
    }
}

int main(void)
{
    /* both compiled forms of the hot loops (sim_internal.h): AVX2 where the
     * CPU has it, then the SSE2 baseline; each must equal the dense form */
    printf("# AVX2 forms %s\n", sim_cpu_avx2() ? "run" : "absent (baseline only)");
    for (int allow = 1; allow >= 0; allow--) {
        sim_cpu_avx2_allow(allow);
        test_random_windows();
        test_steep_windows();
        test_bands();
    }
    sim_cpu_avx2_allow(1);
    return check_report();
}
