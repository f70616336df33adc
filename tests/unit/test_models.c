/*
 * test_models.c: the deformation models other than Persson's core (subtract,
 * deferred, diffusion, decals), each through its window function and through
 * the engine's tick on a small world, checked against the promise
 * docs/models.md makes for it: subtract's exact min and refill that stops at
 * the base; deferred's order independence and profile; diffusion's exact Σh
 * for any Δt, its maximum principle and its limits; decals' untouched
 * heights. Plus the extremes the issue names for every model: a thin
 * collider moving several cells per tick, heights near ±2^29, and the
 * memory a subtract scene holds against a persson-ssbo one.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "sim/sim_internal.h"
#include "test_params.h"

/* One cell of a world by its row-major index (the world is tiled: no dense array). */
#define HEIGHT_AT(w, i) world_height_at(&(w), (int)((i) % (w).width), (int)((i) / (w).width))

#define CELL 0.05
#define UPM 10000

static sim_params params_for(sim_model model, void (*tune)(sim_material *))
{
    sim_material m = sim_material_default();
    m.model = model;
    if (model == SIM_MODEL_PERSSON_ITERATIVE)
        m.method = SIM_METHOD_ITERATIVE;
    if (model == SIM_MODEL_PERSSON_MULTI)
        m.method = SIM_METHOD_MULTI;
    if (tune)
        tune(&m);
    return test_params_from_material(&m, 0);
}

/* A flat world with a base, a CPU backend and an engine for one model. */
typedef struct rig {
    world w;
    sim_backend *backend;
    sim_engine *engine;
} rig;

static void rig_init(rig *r, int side, double height_m, const sim_params *p)
{
    error_text err;
    world_base_spec base = {.kind = WORLD_BASE_FLAT, .height_m = height_m};
    if (world_init(&r->w, side, side, CELL, UPM, 0, &err) != 0 ||
        world_generate_base(&r->w, &base, &err) != 0 ||
        !(r->backend = sim_backend_cpu_create(&err)) ||
        !(r->engine = sim_engine_create(&r->w, p, r->backend, 2, &err))) {
        printf("rig: %s\n", err.message);
        abort();
    }
}

static void rig_free(rig *r)
{
    sim_engine_destroy(r->engine);
    r->backend->destroy(r->backend);
    world_free(&r->w);
}

static void rig_tick(rig *r, const sim_collider *c, int count, sim_tick_report *report)
{
    error_text err;
    if (sim_engine_tick(r->engine, c, count, report, &err) != 0) {
        printf("tick: %s\n", err.message);
        abort();
    }
}

static sim_collider collider_at(const collider_geometry *g, double x, double y, double z, double px,
                                double py, double pz, int has_previous)
{
    sim_collider c = {.id = 1, .geometry = g, .has_previous = has_previous};
    c.pose.position = (vec3d){x, y, z};
    c.pose.orientation = (quatd){1, 0, 0, 0};
    c.previous_pose.position = (vec3d){px, py, pz};
    c.previous_pose.orientation = (quatd){1, 0, 0, 0};
    return c;
}

/* ---- names and parameters ---- */

static void test_model_names(void)
{
    const char *names[] = {"persson-iterative", "persson-ssbo", "persson-multi", "subtract",
                           "deferred",          "diffusion",    "sumner",        "decals"};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++) {
        sim_model m;
        CHECK(sim_model_parse(names[i], &m) == 0 && strcmp(sim_model_name(m), names[i]) == 0,
              "model %s round trip", names[i]);
    }
    sim_model m;
    CHECK(sim_model_scratch_cells(SIM_MODEL_SUMNER, 64 * 48) == sim_sumner_scratch_cells(64, 48),
          "the dispatch gives sumner the scratch it asks for");
    CHECK(sim_model_parse("persson", &m) != 0, "unknown model refused");
    CHECK(sim_model_parse(NULL, &m) != 0, "NULL refused");

    sim_material mat = sim_material_default();
    sim_params p;
    error_text err;
    mat.model = SIM_MODEL_DIFFUSION;
    mat.diffusion_d = NAN;
    CHECK(sim_params_from_material(&mat, CELL, UPM, 0, &p, &err) != 0 &&
              strstr(err.message, "material.D"),
          "NaN D refused naming the field: %s", err.message);
    mat = sim_material_default();
    mat.refill_m_per_s = -1;
    CHECK(sim_params_from_material(&mat, CELL, UPM, 0, &p, &err) != 0 &&
              strstr(err.message, "refill_m_per_s"),
          "negative refill refused: %s", err.message);
    mat = sim_material_default();
    mat.method = SIM_METHOD_MULTI; /* model still persson-ssbo: the method picks the variant */
    CHECK(sim_params_from_material(&mat, CELL, UPM, 0, &p, &err) == 0 &&
              p.model == SIM_MODEL_PERSSON_MULTI,
          "the method picks the persson variant");
    mat = sim_material_default();
    CHECK(sim_material_diffusion_preset(&mat, "sand") == 0 && mat.diffusion_d == 1.0 &&
              mat.diffusion_zeta_inv == 4e-4 && mat.repose_deg == 45.0,
          "Gilardi's sand preset");
    CHECK(sim_material_diffusion_preset(&mat, "gravel") != 0, "unknown preset refused");
}

static void test_base_fill_rect(void)
{
    error_text err;
    world w;
    world_base_spec dunes = {.kind = WORLD_BASE_DUNES,
                             .min_height_m = 0.2,
                             .max_height_m = 0.9,
                             .wavelength_m = 3,
                             .octaves = 3,
                             .seed = 11};
    world_init(&w, 70, 50, CELL, UPM, 0, &err);
    CHECK(world_generate_base(&w, &dunes, &err) == 0, "dunes");
    world_rect r = {13, 7, 40, 30};
    int32_t *a = malloc(sizeof(int32_t) * 40 * 30), *b = malloc(sizeof(int32_t) * 40 * 30);
    world_gather_window(&w, r, a);
    {
        int32_t changed = world_height_at(&w, 20, 10) + 999; /* changed since: the base is not */
        world_scatter_window(&w, (world_rect){20, 10, 1, 1}, &changed);
    }
    CHECK(world_base_fill_rect(&w, r, b) == 0 && memcmp(a, b, sizeof(int32_t) * 40 * 30) == 0,
          "dune base rect equals the generated heights");
    world_free(&w);
    world_init(&w, 8, 8, CELL, UPM, 0, &err);
    b[0] = b[1] = b[2] = b[3] = -1;
    CHECK(world_base_fill_rect(&w, (world_rect){0, 0, 2, 2}, b) == 0 && b[0] == 0 && b[3] == 0,
          "a world never given a base has the flat base 0 it starts with");
    world_free(&w);
    free(a);
    free(b);
}

/* ---- subtract ---- */

static void test_subtract_exact_min(void)
{
    enum { W = 9, H = 7, N = W * H };
    sim_params p = params_for(SIM_MODEL_SUBTRACT, NULL);
    p.floor = 100;
    int32_t heights[N], bottom[N], expect[N];
    uint32_t s = 12345;
    for (int i = 0; i < N; i++) {
        s = s * 1664525u + 1013904223u;
        heights[i] = 100 + (int32_t)(s >> 20);
        s = s * 1664525u + 1013904223u;
        bottom[i] = (s >> 31) ? COLLIDER_BOTTOM_NONE : (int32_t)(s >> 20) - 500;
        int32_t m = bottom[i] < heights[i] ? bottom[i] : heights[i];
        expect[i] = m < p.floor ? p.floor : m;
    }
    sim_window_job job = {.rect = {0, 0, W, H}, .heights = heights, .bottom_override = bottom};
    CHECK(sim_subtract_window(&p, &job, NULL) == SIM_WINDOW_OK, "subtract ok");
    CHECK(memcmp(heights, expect, sizeof heights) == 0, "heights == max(min(h, bottom), floor)");

    /* the in-place cast gives the same as the cast into a depth buffer */
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.2};
    sim_collider c = collider_at(&ball, 0.45, 0.35, 0.5 + 0.15, 0, 0, 0, 0);
    int32_t a[N], b[N];
    for (int i = 0; i < N; i++) {
        a[i] = b[i] = 5000 + 7 * i;
        bottom[i] = COLLIDER_BOTTOM_NONE;
    }
    collider_depth_cpu(&ball, c.pose, (world_rect){0, 0, W, H}, CELL, UPM, bottom);
    sim_window_job in_place = {.rect = {0, 0, W, H},
                               .cell_size_m = CELL,
                               .units_per_m = UPM,
                               .heights = a,
                               .colliders = &c,
                               .collider_count = 1};
    sim_window_job given = in_place;
    given.heights = b;
    given.bottom_override = bottom;
    sim_subtract_window(&p, &in_place, NULL);
    sim_subtract_window(&p, &given, NULL);
    CHECK(memcmp(a, b, sizeof a) == 0, "in-place cast == cast through a depth buffer");
    CHECK(test_sum(a, N) < 5000LL * N + 7LL * N * (N - 1) / 2, "the ball cut something");
}

static void refill_tune(sim_material *m)
{
    m->refill_m_per_s = 0.3; /* 3000 units/s: 50 per tick at 60 Hz */
}

static void test_subtract_refill(void)
{
    sim_params p = params_for(SIM_MODEL_SUBTRACT, refill_tune);
    rig r;
    rig_init(&r, 64, 0.5, &p);
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    /* press 10 cm into the snow for one tick */
    sim_collider c = collider_at(&ball, 1.6, 1.6, 0.5 + 0.3 - 0.1, 0, 0, 0, 0);
    sim_tick_report report;
    rig_tick(&r, &c, 1, &report);
    int32_t lowest = HEIGHT_AT(r.w, 32 * 64 + 32);
    CHECK(lowest <= 5000 - 900, "the ball cut about 10 cm (centre %d)", lowest);
    int64_t base_volume = 5000LL * 64 * 64;
    CHECK(world_volume(&r.w) < base_volume, "volume lost");
    int32_t *previous = malloc(sizeof(int32_t) * 64 * 64);
    int overshoot = 0, went_down = 0, ticks = 0;
    for (; ticks < 400 && world_volume(&r.w) != base_volume; ticks++) {
        world_gather_window(&r.w, (world_rect){0, 0, 64, 64}, previous);
        rig_tick(&r, NULL, 0, &report); /* the ball is gone: only refill */
        for (int i = 0; i < 64 * 64; i++) {
            overshoot |= HEIGHT_AT(r.w, i) > 5000;
            went_down |= HEIGHT_AT(r.w, i) < previous[i];
        }
    }
    CHECK(world_volume(&r.w) == base_volume, "refill converges to the base (after %d ticks)",
          ticks);
    CHECK(ticks >= 15 && ticks <= 25, "at 50 units/tick ~1000 units take ~20 ticks (took %d)",
          ticks);
    CHECK(!overshoot, "refill never passes the base");
    CHECK(!went_down, "refill only raises");
    rig_tick(&r, NULL, 0, &report);
    sim_engine_stats es;
    sim_engine_get_stats(r.engine, &es);
    CHECK(es.refilling_windows == 0 && report.window_count == 0,
          "nothing left to refill: no windows");
    free(previous);
    rig_free(&r);
}

/* ---- deferred ---- */

static void deferred_tune(sim_material *m)
{
    m->trail_scale_per_m = 4.0;
    m->trail_range_m = 0.6;
    m->edge_height = 0.5;
    m->edge_width = 0.6;
}

static void test_deferred_profile_and_order(void)
{
    sim_params p = params_for(SIM_MODEL_DEFERRED, deferred_tune);
    enum { W = 48, H = 48, N = W * H };
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.2};
    sim_collider cs[3] = {
        collider_at(&ball, 1.2, 1.2, 0.5 + 0.2 - 0.08, 1.0, 1.2, 0.5 + 0.2 - 0.08, 1),
        collider_at(&ball, 1.3, 0.9, 0.5 + 0.2 - 0.05, 1.3, 0.9, 0.5 + 0.2 - 0.05, 0),
        collider_at(&ball, 0.7, 1.5, 0.5 + 0.2 - 0.02, 0.9, 1.4, 0.5 + 0.2 - 0.02, 1)};
    sim_collider reversed[3] = {cs[2], cs[1], cs[0]};
    int32_t base[N], a[N], b[N];
    int32_t *scratch = malloc(sizeof(int32_t) * (size_t)sim_model_scratch_cells(p.model, N));
    for (int i = 0; i < N; i++)
        base[i] = a[i] = b[i] = 5000;
    sim_window_job job = {.rect = {0, 0, W, H},
                          .cell_size_m = CELL,
                          .units_per_m = UPM,
                          .heights = a,
                          .colliders = cs,
                          .collider_count = 3,
                          .base_heights = base};
    CHECK(sim_deferred_window(&p, &job, scratch) == SIM_WINDOW_OK, "deferred ok");
    job.heights = b;
    job.colliders = reversed;
    sim_deferred_window(&p, &job, scratch);
    CHECK(memcmp(a, b, sizeof a) == 0, "order-independent (colliders reversed)");

    /* one still point: the profile */
    int32_t h[N];
    for (int i = 0; i < N; i++)
        h[i] = 5000;
    sim_collider one = collider_at(&ball, 1.225, 1.225, 0.5 + 0.2 - 0.1, 0, 0, 0, 0);
    job.heights = h;
    job.colliders = &one;
    job.collider_count = 1;
    sim_deferred_window(&p, &job, scratch);
    int centre = 24 * W + 24;
    int32_t lowest = h[0], highest = h[0];
    for (int i = 0; i < N; i++) {
        lowest = h[i] < lowest ? h[i] : lowest;
        highest = h[i] > highest ? h[i] : highest;
    }
    CHECK(h[centre] == lowest && lowest >= 3999 && lowest <= 4000,
          "centre is lowest, at the foot (%d)", h[centre]);
    CHECK(highest > 5000, "raised edges above base (max %d)", highest);
    /* along a row: falls to the centre, the rim outside the depression */
    int rim_at = -1;
    for (int x = 24; x < W; x++)
        if (h[24 * W + x] > 5000 && rim_at < 0)
            rim_at = x;
    CHECK(rim_at > 24, "rim outside the depression (at x=%d)", rim_at);
    for (int x = 25; x < rim_at; x++)
        CHECK(h[24 * W + x] >= h[24 * W + x - 1], "depression rises monotonically to the rim");
    /* standing still does not pile rims on rims */
    int32_t again[N];
    memcpy(again, h, sizeof h);
    job.heights = again;
    sim_deferred_window(&p, &job, scratch);
    CHECK(memcmp(again, h, sizeof h) == 0, "a second tick at the same pose changes nothing");
    free(scratch);
}

/* ---- diffusion ---- */

static double tune_dt;
static double tune_d, tune_z;
static int tune_conservative = 1, tune_substeps = SIM_DIFFUSION_SUBSTEPS_AUTO;

static void diffusion_tune(sim_material *m)
{
    m->diffusion_dt = tune_dt;
    m->diffusion_d = tune_d;
    m->diffusion_zeta_inv = tune_z;
    m->diffusion_conservative = tune_conservative;
    m->diffusion_substeps = tune_substeps;
    m->repose_deg = 30.0;
}

static sim_params diffusion_params(double d, double z, double dt)
{
    tune_d = d;
    tune_z = z;
    tune_dt = dt;
    return params_for(SIM_MODEL_DIFFUSION, diffusion_tune);
}

/* 1000 ticks of a collider ploughing through a window: Σh exact for any Δt. */
static void test_diffusion_conservative_sum(void)
{
    const double dts[] = {0.1, 10, 1e6};
    for (size_t k = 0; k < sizeof dts / sizeof dts[0]; k++) {
        sim_params p = diffusion_params(1.0, 4e-4, dts[k]);
        rig r;
        rig_init(&r, 64, 0.5, &p);
        int64_t before = world_volume(&r.w);
        collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.15};
        int bad = 0, refused = 0;
        for (int t = 0; t < 1000; t++) {
            double x = 0.5 + 2.2 * (t % 100) / 100.0, px = 0.5 + 2.2 * ((t + 99) % 100) / 100.0;
            sim_collider c =
                collider_at(&ball, x, 1.6, 0.5 + 0.15 - 0.06, px, 1.6, 0.5 + 0.15 - 0.06, t > 0);
            sim_tick_report report;
            rig_tick(&r, &c, 1, &report);
            refused += report.refused_windows;
            bad |= world_volume(&r.w) != before;
        }
        CHECK(!bad && refused == 0, "dt=%g: Σh exact every tick of 1000 (refused %d)", dts[k],
              refused);
        int below = 0;
        for (int i = 0; i < 64 * 64; i++)
            below |= HEIGHT_AT(r.w, i) < r.w.floor;
        CHECK(!below, "dt=%g: nothing below the floor", dts[k]);
        rig_free(&r);
    }
}

/* A bump relaxing: with no collider the maximum principle holds exactly. */
static void run_bump(double d, double dt, int conservative, int substeps, int ticks,
                     int *max_principle, int *refused_any, int64_t *drift)
{
    enum { W = 20, H = 20, N = W * H };
    tune_conservative = conservative;
    tune_substeps = substeps;
    sim_params p = diffusion_params(d, 0.0, dt);
    tune_conservative = 1;
    tune_substeps = SIM_DIFFUSION_SUBSTEPS_AUTO;
    int32_t h[N], bottom[N];
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int dx = x - 10, dy = y - 10;
            h[y * W + x] = 5000 + (dx * dx + dy * dy < 12 ? 4000 : 0) + ((x + y) & 1) * 300;
            bottom[y * W + x] = COLLIDER_BOTTOM_NONE;
        }
    int32_t lo = 5000, hi = 9300;
    int64_t before = test_sum(h, N);
    int32_t *scratch = malloc(sizeof(int32_t) * (size_t)sim_model_scratch_cells(p.model, N));
    sim_window_job job = {.rect = {0, 0, W, H},
                          .cell_size_m = CELL,
                          .units_per_m = UPM,
                          .heights = h,
                          .bottom_override = bottom};
    *max_principle = 1;
    *refused_any = 0;
    for (int t = 0; t < ticks; t++) {
        if (sim_diffusion_window(&p, &job, scratch) != SIM_WINDOW_OK) {
            *refused_any = 1;
            break;
        }
        for (int i = 0; i < N; i++)
            if (h[i] < lo || h[i] > hi)
                *max_principle = 0;
    }
    *drift = test_sum(h, N) - before;
    free(scratch);
}

static void test_diffusion_extremes(void)
{
    int mp, refused;
    int64_t drift;
    run_bump(0.0, 0.2, 1, SIM_DIFFUSION_SUBSTEPS_AUTO, 50, &mp, &refused, &drift);
    {
        /* D = 0 (and no collider) moves nothing at all */
        enum { N = 16 };
        sim_params p = diffusion_params(0.0, 0.0, 0.2);
        int32_t h[N], bottom[N], copy[N], scratch[9 * N + 2];
        for (int i = 0; i < N; i++) {
            h[i] = copy[i] = 5000 + 1000 * (i % 3);
            bottom[i] = COLLIDER_BOTTOM_NONE;
        }
        sim_window_job job = {.rect = {0, 0, 4, 4}, .heights = h, .bottom_override = bottom};
        sim_diffusion_window(&p, &job, scratch);
        CHECK(memcmp(h, copy, sizeof h) == 0, "D = 0 does nothing");
    }
    const double ds[] = {0.25, 1.0, 1e6, 1e12};
    const double dts[] = {0.1, 10, 1e6};
    for (size_t i = 0; i < sizeof ds / sizeof ds[0]; i++) {
        for (size_t j = 0; j < sizeof dts / sizeof dts[0]; j++) {
            run_bump(ds[i], dts[j], 1, SIM_DIFFUSION_SUBSTEPS_AUTO, 60, &mp, &refused, &drift);
            CHECK(mp && !refused && drift == 0,
                  "conservative D=%g dt=%g: max principle %d, refused %d, drift %lld", ds[i],
                  dts[j], mp, refused, (long long)drift);
            run_bump(ds[i], dts[j], 0, SIM_DIFFUSION_SUBSTEPS_AUTO, 30, &mp, &refused, &drift);
            CHECK(!refused, "Gilardi's scheme under auto substeps D=%g dt=%g stays finite", ds[i],
                  dts[j]);
        }
    }
    /* Gilardi's scheme as published, one step of Δt = 2 with D = 1: past
     * their limit it oscillates and grows until the window is refused. */
    run_bump(1.0, 2.0, 0, 1, 200, &mp, &refused, &drift);
    CHECK(!mp, "Gilardi's scheme with dt=2 and one substep leaves the initial range (unstable)");
    run_bump(1.0, 0.2, 0, 1, 200, &mp, &refused, &drift);
    CHECK(mp && !refused, "Gilardi's scheme with dt=0.2 stays in range");

    /* ζ⁻¹ huge with a collider: bounded, exact, never below the floor */
    sim_params p = diffusion_params(1.0, 1e12, 1e6);
    rig r;
    rig_init(&r, 48, 0.5, &p);
    int64_t before = world_volume(&r.w);
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    int ok = 1;
    for (int t = 0; t < 100; t++) {
        sim_collider c = collider_at(&ball, 1.2, 1.2, 0.5 + 0.3 - 0.2, 1.2, 1.2, 0.6, 1);
        sim_tick_report report;
        rig_tick(&r, &c, 1, &report);
        for (int i = 0; i < 48 * 48; i++)
            ok &= HEIGHT_AT(r.w, i) >= 0 && HEIGHT_AT(r.w, i) < 5000 + 20000;
    }
    CHECK(ok, "huge zeta_inv: bounded");
    CHECK(world_volume(&r.w) == before, "huge zeta_inv: exact");
    rig_free(&r);
}

/* ---- a thin collider moving 5 cells per tick ---- */

static void test_thin_fast_collider(void)
{
    const sim_model models[] = {SIM_MODEL_PERSSON_ITERATIVE, SIM_MODEL_PERSSON_SSBO,
                                SIM_MODEL_PERSSON_MULTI, SIM_MODEL_DIFFUSION};
    collider_geometry blade = {.shape = COLLIDER_BOX, .half_extents = {0.03, 0.3, 0.2}};
    for (size_t k = 0; k < sizeof models / sizeof models[0]; k++) {
        tune_d = 0.25;
        tune_z = 6e-4;
        tune_dt = 1.0;
        sim_params p = models[k] == SIM_MODEL_DIFFUSION
                           ? params_for(SIM_MODEL_DIFFUSION, diffusion_tune)
                           : params_for(models[k], NULL);
        rig r;
        rig_init(&r, 96, 0.5, &p);
        int64_t before = world_volume(&r.w);
        double x = 0.6, step = 5 * CELL, z = 0.5 + 0.2 - 0.05;
        int ahead_grew = 1;
        for (int t = 0; t < 8; t++) {
            /* Σ over the cells ahead of the blade, before and after its tick */
            double nx = x + step;
            int ahead_from = (int)floor((nx + 0.03) / CELL) + 1;
            int64_t ahead_before = 0, ahead_after = 0;
            for (int y = 0; y < 96; y++)
                for (int xx = ahead_from; xx < ahead_from + 4; xx++)
                    ahead_before += HEIGHT_AT(r.w, y * 96 + xx);
            sim_collider c = collider_at(&blade, nx, 2.4, z, x, 2.4, z, t > 0);
            sim_tick_report report;
            rig_tick(&r, &c, 1, &report);
            for (int y = 0; y < 96; y++)
                for (int xx = ahead_from; xx < ahead_from + 4; xx++)
                    ahead_after += HEIGHT_AT(r.w, y * 96 + xx);
            ahead_grew &= ahead_after > ahead_before;
            x = nx;
        }
        CHECK(ahead_grew, "%s: a thin collider at 5 cells/tick pushes material ahead every tick",
              sim_model_name(models[k]));
        CHECK(world_volume(&r.w) == before, "%s: volume kept", sim_model_name(models[k]));
        rig_free(&r);
    }
}

/* ---- heights near the limits ---- */

static void test_height_limits(void)
{
    const sim_model models[] = {SIM_MODEL_SUBTRACT, SIM_MODEL_DEFERRED, SIM_MODEL_DIFFUSION,
                                SIM_MODEL_DECALS,   SIM_MODEL_SUMNER,   SIM_MODEL_PERSSON_SSBO};
    const double heights_m[] = {(WORLD_HEIGHT_MAX - 50) / (double)UPM,
                                (WORLD_HEIGHT_MIN + 50) / (double)UPM};
    for (size_t k = 0; k < sizeof models / sizeof models[0]; k++) {
        for (int s = 0; s < 2; s++) {
            tune_d = 1e6;
            tune_z = 1e6;
            tune_dt = 10;
            sim_material m = sim_material_default();
            m.model = models[k];
            m.edge_height = 100; /* a rim far above the limit */
            if (models[k] == SIM_MODEL_DIFFUSION)
                diffusion_tune(&m);
            sim_params p;
            error_text err;
            sim_params_from_material(&m, CELL, UPM, WORLD_HEIGHT_MIN, &p, &err);
            world w;
            world_base_spec base = {.kind = WORLD_BASE_FLAT, .height_m = heights_m[s]};
            sim_backend *b = sim_backend_cpu_create(&err);
            sim_engine *e;
            world_init(&w, 40, 40, CELL, UPM, WORLD_HEIGHT_MIN, &err);
            CHECK(world_generate_base(&w, &base, &err) == 0, "base near the limit: %s",
                  err.message);
            e = sim_engine_create(&w, &p, b, 2, &err);
            collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.3};
            int in_range = 1;
            for (int t = 0; t < 5; t++) {
                sim_collider c = collider_at(&ball, 1.0, 1.0, heights_m[s] + 0.3 - 0.2, 0.9, 1.0,
                                             heights_m[s] + 0.3 - 0.2, t > 0);
                sim_tick_report report;
                CHECK(sim_engine_tick(e, &c, 1, &report, &err) == 0, "tick");
                for (int i = 0; i < 40 * 40; i++)
                    in_range &=
                        HEIGHT_AT(w, i) >= WORLD_HEIGHT_MIN && HEIGHT_AT(w, i) <= WORLD_HEIGHT_MAX;
            }
            CHECK(in_range, "%s at %s: heights stay in range", sim_model_name(models[k]),
                  s ? "-2^29" : "+2^29");
            sim_engine_destroy(e);
            b->destroy(b);
            world_free(&w);
        }
    }
}

/* ---- one-cell and world-sized colliders ---- */

static void test_collider_sizes(void)
{
    const sim_model models[] = {SIM_MODEL_PERSSON_SSBO, SIM_MODEL_SUBTRACT, SIM_MODEL_DEFERRED,
                                SIM_MODEL_DIFFUSION,    SIM_MODEL_SUMNER,   SIM_MODEL_DECALS};
    collider_geometry speck = {.shape = COLLIDER_SPHERE, .radius = 0.01};
    collider_geometry slab = {.shape = COLLIDER_BOX, .half_extents = {5, 5, 0.2}};
    for (size_t k = 0; k < sizeof models / sizeof models[0]; k++) {
        for (int big = 0; big < 2; big++) {
            tune_d = 1.0;
            tune_z = 4e-4;
            tune_dt = 0.2;
            sim_params p = models[k] == SIM_MODEL_DIFFUSION
                               ? params_for(SIM_MODEL_DIFFUSION, diffusion_tune)
                               : params_for(models[k], NULL);
            rig r;
            rig_init(&r, 40, 0.5, &p);
            int64_t before = world_volume(&r.w);
            /* the speck sits on one cell's centre; the slab covers the world */
            sim_collider c =
                big ? collider_at(&slab, 1.0, 1.0, 0.5 + 0.2 - 0.05, 1.0, 1.0, 0.9, 1)
                    : collider_at(&speck, 0.525, 0.525, 0.5 + 0.01 - 0.005, 0.525, 0.525, 0.6, 1);
            int changed = 0;
            for (int t = 0; t < 3; t++) {
                sim_tick_report report;
                rig_tick(&r, &c, 1, &report);
                changed |= report.dirty_count > 0;
            }
            int64_t after = world_volume(&r.w);
            const char *name = sim_model_name(models[k]);
            if (models[k] == SIM_MODEL_SUBTRACT)
                CHECK(after < before, "%s %s: cut something", name,
                      big ? "world-sized" : "one-cell");
            else if (models[k] != SIM_MODEL_DEFERRED)
                CHECK(after == before, "%s %s: volume exact", name,
                      big ? "world-sized" : "one-cell");
            /* a slab over the whole world leaves Persson, Sumner and diffusion nowhere to
             * push (no free cell, no difference of penetration): the heights stay */
            int nowhere =
                big && (models[k] == SIM_MODEL_PERSSON_SSBO || models[k] == SIM_MODEL_DIFFUSION ||
                        models[k] == SIM_MODEL_SUMNER);
            if (models[k] != SIM_MODEL_DECALS)
                CHECK(changed == !nowhere, "%s %s: %s", name, big ? "world-sized" : "one-cell",
                      nowhere ? "nowhere to push, unchanged" : "deformed");
            rig_free(&r);
        }
    }
}

/* ---- decals ---- */

static void test_decals(void)
{
    sim_params p = params_for(SIM_MODEL_DECALS, NULL);
    rig r;
    rig_init(&r, 64, 0.5, &p);
    int64_t before = world_volume(&r.w);
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    sim_collider cs[2] = {collider_at(&ball, 1.0, 1.0, 0.5 + 0.3 - 0.05, 0, 0, 0, 0),
                          collider_at(&ball, 2.5, 2.5, 0.5 + 0.3 + 0.05, 0, 0, 0, 0)};
    cs[0].pose.orientation = quat_from_axis_angle((vec3d){0, 0, 1}, 0.5);
    cs[1].id = 2;
    sim_tick_report report;
    rig_tick(&r, cs, 2, &report);
    CHECK(world_volume(&r.w) == before && report.dirty_count == 0, "decals change no height");
    CHECK(report.footprint_count == 1, "one footprint: the second ball floats (%d)",
          report.footprint_count);
    if (report.footprint_count == 1) {
        const sim_footprint *f = &report.footprints[0];
        CHECK(f->collider_id == 1 && fabs(f->x_m - 1.0) < CELL && fabs(f->y_m - 1.0) < CELL,
              "footprint centre (%g, %g)", f->x_m, f->y_m);
        CHECK(fabs(f->yaw_rad - 0.5) < 1e-9, "yaw %g", f->yaw_rad);
        CHECK(fabs(f->strength_m - 0.05) < 0.004, "strength %g", f->strength_m);
        /* a 5 cm cap of a 30 cm ball: radius sqrt(0.3^2 - 0.25^2) = 0.166 m */
        CHECK(fabs(f->size_m - sqrt(M_PI) * 0.166) < 0.03, "size %g", f->size_m);
    }
    rig_free(&r);
}

/* ---- memory: only what the model needs ---- */

static void test_memory_by_model(void)
{
    collider_geometry slab = {.shape = COLLIDER_BOX, .half_extents = {1.5, 1.5, 0.2}};
    uint64_t peak[2];
    sim_model models[2] = {SIM_MODEL_PERSSON_SSBO, SIM_MODEL_SUBTRACT};
    for (int k = 0; k < 2; k++) {
        sim_params p = params_for(models[k], NULL);
        rig r;
        rig_init(&r, 128, 0.5, &p);
        sim_collider c = collider_at(&slab, 3.2, 3.2, 0.5 + 0.2 - 0.05, 3.2, 3.2, 0.65, 1);
        sim_tick_report report;
        rig_tick(&r, &c, 1, &report);
        sim_engine_stats es;
        sim_engine_get_stats(r.engine, &es);
        peak[k] = es.peak_scratch_bytes;
        const sim_stage_memory *m = &es.peak_memory;
        if (models[k] == SIM_MODEL_SUBTRACT)
            CHECK(m->jump_flood == 0 && m->displace == 0 && m->classify == 0 && m->depth == 0,
                  "subtract holds no persson stage buffers");
        else
            CHECK(m->jump_flood > 0 && m->displace > 0, "persson-ssbo holds its stages");
        CHECK(sim_stage_memory_total(m) == peak[k], "stages add up to the peak");
        rig_free(&r);
    }
    CHECK(peak[1] * 4 < peak[0], "subtract's scratch %llu < 25%% of persson-ssbo's %llu",
          (unsigned long long)peak[1], (unsigned long long)peak[0]);
}

static void timed(const char *name, void (*f)(void))
{
    double t0 = time_now_ms();
    f();
    printf("%s: %.0f ms\n", name, time_now_ms() - t0);
}

int main(void)
{
    log_set_quiet(1);
    timed("test_model_names", test_model_names);
    timed("test_base_fill_rect", test_base_fill_rect);
    timed("test_subtract_exact_min", test_subtract_exact_min);
    timed("test_subtract_refill", test_subtract_refill);
    timed("test_deferred_profile_and_order", test_deferred_profile_and_order);
    timed("test_diffusion_conservative_sum", test_diffusion_conservative_sum);
    timed("test_diffusion_extremes", test_diffusion_extremes);
    timed("test_thin_fast_collider", test_thin_fast_collider);
    timed("test_height_limits", test_height_limits);
    timed("test_collider_sizes", test_collider_sizes);
    timed("test_decals", test_decals);
    timed("test_memory_by_model", test_memory_by_model);
    return check_report();
}
