/*
 * test_sim_stages.c: hand-checked cases for each integer stage of the CPU
 * twin (the specification the GL backend is checked against), the window
 * planner, and the volume promise on random windows for every method and
 * metric, including the extremes the issue names.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/sim_internal.h"
#include "check.h"
#include "test_params.h"

static sim_params params_for(sim_method method, sim_metric metric)
{
    sim_material m = sim_material_default();
    m.method = method;
    m.metric = metric;
    return test_params_from_material(&m, 0);
}

/* Thesis Fig. 4.3: a 6x6 penetrating block in a 10x10 area; the Manhattan
 * distance of each cell to the nearest free cell is 1, 2, 3 from the rim in. */
static void test_fig_4_3_manhattan(void)
{
    enum { W = 10, H = 10 };
    int32_t heights[W * H], bottom[W * H], raw[W * H], moved[W * H], cls[W * H];
    int32_t seed[W * H], scratch[W * H];
    sim_params p = params_for(SIM_METHOD_SSBO, SIM_METRIC_MANHATTAN);
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        heights[i] = 50000;
        bottom[i] = (x >= 2 && x <= 7 && y >= 2 && y <= 7) ? 49995 : COLLIDER_BOTTOM_NONE;
    }
    sim_classify(&p, W * H, heights, bottom, raw, moved, cls);
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        int inside = x >= 2 && x <= 7 && y >= 2 && y <= 7;
        CHECK(cls[i] == (inside ? SIM_CELL_PENETRATING : SIM_CELL_SEED), "class of (%d,%d)", x, y);
        CHECK(raw[i] == (inside ? 5 : 0), "penetration of (%d,%d) is %d", x, y, raw[i]);
    }
    sim_jump_flood(&p, W, H, 0, 0, cls, seed, scratch);
    static const int expected[10][10] = {
        {0, 0, 0, 0, 0, 0, 0, 0, 0, 0}, {0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
        {0, 0, 1, 1, 1, 1, 1, 1, 0, 0}, {0, 0, 1, 2, 2, 2, 2, 1, 0, 0},
        {0, 0, 1, 2, 3, 3, 2, 1, 0, 0}, {0, 0, 1, 2, 3, 3, 2, 1, 0, 0},
        {0, 0, 1, 2, 2, 2, 2, 1, 0, 0}, {0, 0, 1, 1, 1, 1, 1, 1, 0, 0},
        {0, 0, 0, 0, 0, 0, 0, 0, 0, 0}, {0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
    };
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        CHECK(seed[i] >= 0 && cls[seed[i]] == SIM_CELL_SEED, "(%d,%d) has a seed", x, y);
        int d = sim_metric_distance(SIM_METRIC_MANHATTAN, seed[i] % W - x, seed[i] / W - y);
        CHECK(d == expected[y][x], "manhattan distance at (%d,%d) is %d, want %d", x, y, d,
              expected[y][x]);
    }
}

static void test_classify_extremes(void)
{
    sim_material m = sim_material_default();
    sim_params p;
    error_text err;
    m.compression = 0.5;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 1000, &p, &err) == 0, "params");
    /* seed, obstacle (within the 0.1 m gap), penetrating, below the floor, at the floor */
    int32_t h[5] = {5000, 5000, 5000, 5000, 1000};
    int32_t b[5] = {COLLIDER_BOTTOM_NONE, 5900, 4001, -90000, -90000};
    int32_t raw[5], moved[5], cls[5];
    sim_classify(&p, 5, h, b, raw, moved, cls);
    CHECK(cls[0] == SIM_CELL_SEED && raw[0] == 0, "free column is a seed");
    CHECK(cls[1] == SIM_CELL_OBSTACLE && raw[1] == 0, "collider 0.09 m above: obstacle");
    CHECK(cls[2] == SIM_CELL_PENETRATING && raw[2] == 999 && moved[2] == 500,
          "penetration 999 with compression 0.5 moves 500 (got %d, %d)", raw[2], moved[2]);
    CHECK(cls[3] == SIM_CELL_PENETRATING && raw[3] == 4000,
          "collider below the floor pushes down to the floor only (raw %d)", raw[3]);
    CHECK(cls[4] == SIM_CELL_OBSTACLE && raw[4] == 0, "column at the floor cannot be pushed");
    m.compression = 1.0;
    sim_params_from_material(&m, 0.05, 10000, 0, &p, &err);
    sim_classify(&p, 5, h, b, raw, moved, cls);
    CHECK(moved[2] == 0 && raw[2] == 999, "compression 1 compacts everything");
}

static void test_params(void)
{
    sim_material m = sim_material_default();
    sim_params p;
    error_text err = {{0}};
    m.repose_deg = 0;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) == 0 &&
              p.slope_threshold_axial == 0 && p.slope_threshold_diagonal == 0,
          "repose 0: zero thresholds");
    m.repose_deg = 45;
    sim_params_from_material(&m, 0.05, 10000, 0, &p, &err);
    CHECK(p.slope_threshold_axial == 499 || p.slope_threshold_axial == 500,
          "repose 45 on 5 cm cells: axial threshold %d ~ 500", p.slope_threshold_axial);
    CHECK(p.slope_threshold_diagonal == 707, "diagonal threshold %d = 707",
          p.slope_threshold_diagonal);
    m.repose_deg = 89;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) == 0 &&
              p.slope_threshold_axial > 28000,
          "repose 89 accepted (threshold %d)", p.slope_threshold_axial);
    m.repose_deg = 90;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) != 0 &&
              strstr(err.message, "material.repose_deg"),
          "repose 90 refused naming the field: %s", err.message);
    m = sim_material_default();
    m.roughness = NAN;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) != 0 &&
              strstr(err.message, "material.roughness"),
          "NaN roughness refused naming the field: %s", err.message);
    m = sim_material_default();
    m.compression = 1.5;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) != 0 &&
              strstr(err.message, "material.compression"),
          "compression 1.5 refused: %s", err.message);
}

/* 1x5 strip, column 2 penetrated by 300: single target puts it on a nearest
 * free neighbour; multi marches outwards; iterative splits 150/150. */
static void test_displacement_small(void)
{
    for (int method = 0; method < 3; method++) {
        sim_params p = params_for((sim_method)method, SIM_METRIC_EUCLIDEAN);
        p.multi_target_step = 100;
        int32_t h[5] = {1000, 1000, 1300, 1000, 1000};
        int32_t b[5] = {COLLIDER_BOTTOM_NONE, COLLIDER_BOTTOM_NONE, 1000, COLLIDER_BOTTOM_NONE,
                        COLLIDER_BOTTOM_NONE};
        int32_t raw[5], moved[5], cls[5], seed[5], scratch[5 * 5];
        sim_classify(&p, 5, h, b, raw, moved, cls);
        sim_jump_flood(&p, 5, 1, 0, 0, cls, seed, scratch);
        CHECK(seed[2] == 1 || seed[2] == 3, "nearest seed of the middle is a neighbour");
        sim_window_status st = sim_displace(&p, 5, 1, cls, seed, raw, moved, h, scratch);
        CHECK(st == SIM_WINDOW_OK, "displacement ok");
        CHECK(test_sum(h, 5) == 5300, "%s keeps volume (%lld)", sim_method_name(p.method),
              (long long)test_sum(h, 5));
        CHECK(h[2] == 1000, "%s leaves the column at the collider (%d)", sim_method_name(p.method),
              h[2]);
        if (p.method == SIM_METHOD_SSBO)
            CHECK(h[seed[2]] == 1300, "single target: all 300 on the seed");
        if (p.method == SIM_METHOD_ITERATIVE)
            CHECK(h[1] == 1150 && h[3] == 1150, "iterative splits evenly (%d, %d)", h[1], h[3]);
        if (p.method == SIM_METHOD_MULTI) {
            int side = seed[2];
            int next = side == 1 ? 0 : 4;
            /* 3 targets of 100 planned, 2 fit before the window edge: the last
             * valid one takes the rest */
            CHECK(h[side] == 1100 && h[next] == 1200,
                  "multi: 100 on the seed, the rest on the last valid target (%d, %d)", h[side],
                  h[next]);
        }
    }
}

/* No free cell anywhere (a collider covering the whole window): material
 * stays where it is, for every method. */
static void test_no_seed(void)
{
    for (int method = 0; method < 3; method++) {
        sim_params p = params_for((sim_method)method, SIM_METRIC_CHEBYSHEV);
        int32_t h[9], b[9], raw[9], moved[9], cls[9], seed[9], scratch[9 * 5];
        for (int i = 0; i < 9; i++) {
            h[i] = 4000 + 100 * i;
            b[i] = 1000;
        }
        sim_classify(&p, 9, h, b, raw, moved, cls);
        sim_jump_flood(&p, 3, 3, 7, 7, cls, seed, scratch);
        for (int i = 0; i < 9; i++)
            CHECK(seed[i] == -1, "no seed anywhere");
        CHECK(sim_displace(&p, 3, 3, cls, seed, raw, moved, h, scratch) == SIM_WINDOW_OK, "ok");
        for (int i = 0; i < 9; i++)
            CHECK(h[i] == 4000 + 100 * i, "%s: column %d unchanged (%d)", sim_method_name(p.method),
                  i, h[i]);
    }
}

static void test_height_limit(void)
{
    /* 15 columns near the top of the range pour into one free column */
    sim_params p = params_for(SIM_METHOD_SSBO, SIM_METRIC_EUCLIDEAN);
    enum { W = 4, H = 4 };
    int32_t h[W * H], b[W * H], raw[W * H], moved[W * H], cls[W * H], seed[W * H];
    int32_t scratch[W * H * 5];
    for (int i = 0; i < W * H; i++) {
        h[i] = WORLD_HEIGHT_MAX - 10;
        b[i] = i == 0 ? COLLIDER_BOTTOM_NONE : 0;
    }
    sim_classify(&p, W * H, h, b, raw, moved, cls);
    sim_jump_flood(&p, W, H, 0, 0, cls, seed, scratch);
    CHECK(sim_displace(&p, W, H, cls, seed, raw, moved, h, scratch) == SIM_WINDOW_HEIGHT_LIMIT,
          "a column pushed beyond the height limit refuses the window");
    for (int method = 0; method < 3; method++) {
        p = params_for((sim_method)method, SIM_METRIC_EUCLIDEAN);
        for (int i = 0; i < W * H; i++)
            h[i] = WORLD_HEIGHT_MAX - 10;
        sim_classify(&p, W * H, h, b, raw, moved, cls);
        sim_jump_flood(&p, W, H, 0, 0, cls, seed, scratch);
        CHECK(sim_displace(&p, W, H, cls, seed, raw, moved, h, scratch) == SIM_WINDOW_HEIGHT_LIMIT,
              "%s refuses at the limit", sim_method_name(p.method));
    }
}

static void test_slopes(void)
{
    enum { W = 9, H = 9 };
    sim_params p = params_for(SIM_METHOD_SSBO, SIM_METRIC_EUCLIDEAN);
    int32_t h[W * H], cls[W * H], scratch[W * H * 2];
    for (int i = 0; i < W * H; i++) {
        h[i] = 1000;
        cls[i] = SIM_CELL_SEED;
    }
    h[4 * W + 4] = 101000; /* a 10 m spike */
    int64_t before = test_sum(h, W * H);
    int64_t excess_before = sim_max_slope_excess(&p, W, H, h);
    sim_even_slopes(&p, W, H, cls, h, scratch);
    CHECK(test_sum(h, W * H) == before, "slope evening keeps volume");
    CHECK(sim_max_slope_excess(&p, W, H, h) < excess_before, "slope excess shrinks");
    int32_t lo = INT32_MAX, hi = INT32_MIN;
    for (int i = 0; i < W * H; i++) {
        lo = h[i] < lo ? h[i] : lo;
        hi = h[i] > hi ? h[i] : hi;
    }
    CHECK(lo >= 1000 && hi <= 101000, "no new extremes (max principle): [%d, %d]", lo, hi);
    /* many iterations converge to the angle of repose without oscillating */
    p.slope_iterations = 1000;
    sim_even_slopes(&p, W, H, cls, h, scratch);
    CHECK(test_sum(h, W * H) == before, "volume after 1000 iterations");
    /* flux rounds down, so at rest an excess below 8/roughness units may remain */
    int64_t rest = (int64_t)8 * 65536 / p.roughness_q16 + 1;
    CHECK(sim_max_slope_excess(&p, W, H, h) <= rest, "converged to repose (excess %lld <= %lld)",
          (long long)sim_max_slope_excess(&p, W, H, h), (long long)rest);
    /* roughness 0: nothing moves */
    int32_t copy[W * H];
    memcpy(copy, h, sizeof copy);
    h[0] = 90000;
    copy[0] = 90000;
    p.roughness_q16 = 0;
    sim_even_slopes(&p, W, H, cls, h, scratch);
    CHECK(memcmp(copy, h, sizeof copy) == 0, "roughness 0 moves nothing");
    /* material never flows under a collider (non-seed receivers) */
    p = params_for(SIM_METHOD_SSBO, SIM_METRIC_EUCLIDEAN);
    for (int i = 0; i < W * H; i++) {
        h[i] = 1000;
        cls[i] = SIM_CELL_OBSTACLE;
    }
    h[40] = 50000;
    sim_even_slopes(&p, W, H, cls, h, scratch);
    CHECK(h[40] == 50000, "no flow towards obstacles");
}

/* Σh is exact for every method and metric on random windows, compression 0,
 * and two runs agree bit for bit. */
static void test_random_volume(void)
{
    uint32_t state = 99;
    for (int round = 0; round < 60; round++) {
        state = state * 1664525u + 1013904223u;
        int w = 1 + (int)(state >> 24) % 40;
        state = state * 1664525u + 1013904223u;
        int h = 1 + (int)(state >> 24) % 40;
        int n = w * h;
        int32_t *heights = malloc(sizeof(int32_t) * n), *bottom = malloc(sizeof(int32_t) * n);
        int32_t *raw = malloc(sizeof(int32_t) * n), *moved = malloc(sizeof(int32_t) * n);
        int32_t *cls = malloc(sizeof(int32_t) * n), *seed = malloc(sizeof(int32_t) * n);
        int32_t *scratch = malloc(sizeof(int32_t) * n * 5), *first = malloc(sizeof(int32_t) * n);
        for (int method = 0; method < 3; method++) {
            for (int metric = 0; metric < 3; metric++) {
                sim_params p = params_for((sim_method)method, (sim_metric)metric);
                for (int rep = 0; rep < 2; rep++) {
                    uint32_t s = state;
                    for (int i = 0; i < n; i++) {
                        s = s * 1664525u + 1013904223u;
                        heights[i] = (int32_t)(s >> 12) % 20000;
                        s = s * 1664525u + 1013904223u;
                        int kind = (int)(s >> 28);
                        bottom[i] = kind < 6   ? COLLIDER_BOTTOM_NONE
                                    : kind < 8 ? heights[i] + (int32_t)(s >> 20) % 2000
                                               : (int32_t)(s >> 14) % 30000 - 5000;
                    }
                    int64_t before = test_sum(heights, n);
                    sim_classify(&p, n, heights, bottom, raw, moved, cls);
                    sim_jump_flood(&p, w, h, round, 3 * round, cls, seed, scratch);
                    sim_window_status st =
                        sim_displace(&p, w, h, cls, seed, raw, moved, heights, scratch);
                    sim_even_slopes(&p, w, h, cls, heights, scratch);
                    CHECK(st == SIM_WINDOW_OK && test_sum(heights, n) == before,
                          "%dx%d %s/%s: volume %lld -> %lld", w, h, sim_method_name(p.method),
                          sim_metric_name(p.metric), (long long)before,
                          (long long)test_sum(heights, n));
                    if (rep == 0)
                        memcpy(first, heights, sizeof(int32_t) * n);
                    else
                        CHECK(memcmp(first, heights, sizeof(int32_t) * n) == 0,
                              "two runs identical");
                }
            }
        }
        free(heights);
        free(bottom);
        free(raw);
        free(moved);
        free(cls);
        free(seed);
        free(scratch);
        free(first);
    }
}

static void test_plan_windows(void)
{
    world w;
    error_text err;
    CHECK(world_init(&w, 200, 100, 0.1, 10000, 0, &err) == 0, "world");
    world_base_spec flat = {.kind = WORLD_BASE_FLAT, .height_m = 0.5};
    CHECK(world_generate_base(&w, &flat, &err) == 0, "flat base at 5000 units");
    sim_params p = params_for(SIM_METHOD_SSBO, SIM_METRIC_EUCLIDEAN);
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.5};
    sim_collider c[4];
    memset(c, 0, sizeof c);
    double xs[4] = {2.0, 2.6, 15.0, 19.9};
    for (int i = 0; i < 4; i++) {
        c[i].id = i;
        c[i].geometry = &ball;
        c[i].pose = (collider_pose){{xs[i], 5.0, 0.9}, {1, 0, 0, 0}};
    }
    /* the fourth flies far above the terrain */
    c[3].pose.position.z = 50.0;
    world_rect fp[4], *win = NULL;
    int count = 0;
    CHECK(sim_plan_windows(&w, &p, c, 4, 2, NULL, 0, fp, &win, &count) == 0, "plan");
    CHECK(count == 2,
          "two overlapping footprints merge, one far away stays, one flying is "
          "skipped: %d windows",
          count);
    CHECK(fp[3].w == 0, "flying collider has no footprint");
    if (count == 2) {
        CHECK(win[0].x <= 13 && win[0].x + win[0].w >= 32, "merged window covers both");
        CHECK(!world_rects_overlap(win[0], win[1]), "windows disjoint");
    }
    free(win);
    /* a collider crossing the world edge is clipped */
    c[0].pose.position.x = 0.1;
    CHECK(sim_plan_windows(&w, &p, c, 1, 2, NULL, 0, fp, &win, &count) == 0 && count == 1 &&
              win[0].x == 0,
          "clipped at the edge");
    free(win);
    world_free(&w);
}

int main(void)
{
    test_fig_4_3_manhattan();
    test_classify_extremes();
    test_params();
    test_displacement_small();
    test_no_seed();
    test_height_limit();
    test_slopes();
    test_random_volume();
    test_plan_windows();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
