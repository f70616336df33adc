/*
 * test_gl.c: the GL backend against the CPU twin. It checks the headless
 * context (EGL, no window, GL >= 4.3), the GL depth stage (depth_exact.comp)
 * against the CPU twin's depth, cell for cell, and then the promise that makes
 * the twin an oracle: for identical depth input, the GL compute stages give
 * bit-identical heights and identical window status (including refusals at
 * the height limit) for every method and metric, on random batches of
 * windows of awkward shapes (1x1, 1xN, non-powers of two, several per batch).
 *
 * Exits 77 (skipped) when no GL 4.3 context can be made on this machine.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "gl/gl.h"
#include "sim/sim.h"
#include "check.h"
#include "test_params.h"

/* A small deterministic generator (xorshift64*), so failures reproduce. */
/* Every displacement method and distance metric: each case runs them all. */
static const sim_method methods[3] = {SIM_METHOD_ITERATIVE, SIM_METHOD_SSBO, SIM_METHOD_MULTI};
static const sim_metric metrics[3] = {SIM_METRIC_EUCLIDEAN, SIM_METRIC_MANHATTAN,
                                      SIM_METRIC_CHEBYSHEV};

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;

static uint32_t rnd(void)
{
    rng_state ^= rng_state >> 12;
    rng_state ^= rng_state << 25;
    rng_state ^= rng_state >> 27;
    return (uint32_t)((rng_state * 0x2545f4914f6cdd1dull) >> 32);
}

/* Uniform in [lo, hi]. */
static int32_t rnd_range(int32_t lo, int32_t hi)
{
    return lo + (int32_t)(rnd() % (uint32_t)((int64_t)hi - lo + 1));
}

/* ---- context ---- */

static int test_context(void)
{
    error_text err = {{0}};
    gl_context *c = gl_context_create(&err);
    if (!c) {
        printf("skip: no OpenGL 4.3 context on this machine: %s\n", err.message);
        return -1;
    }
    int major = 0, minor = 0;
    const char *v = gl_context_version(c);
    /* "4.5 (Core Profile) Mesa 22.3.6" */
    int parsed = sscanf(v, "%d.%d", &major, &minor) == 2;
    CHECK(parsed && (major > 4 || (major == 4 && minor >= 3)), "context: GL %s on %s (>= 4.3)", v,
          gl_context_renderer(c));
    gl_context_destroy(c);
    return 0;
}

/* `--backend auto` takes these for software rasterisers (real GL_RENDERER
 * strings), the rest for GPUs; needs no context. */
static void test_renderer_is_software(void)
{
    static const struct {
        const char *renderer;
        int software;
    } cases[] = {
        {"llvmpipe (LLVM 15.0.6, 256 bits)", 1},
        {"softpipe", 1},
        {"Google SwiftShader", 1},
        {"ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero)), SwiftShader driver)", 1},
        {"Mesa X11 Software Rasterizer", 1},
        {"NVIDIA H100 80GB HBM3/PCIe/SSE2", 0},
        {"AMD Radeon RX 7900 XTX (radeonsi, navi31, LLVM 15.0.6, DRM 3.54)", 0},
        {"Mesa Intel(R) UHD Graphics 630 (CFL GT2)", 0},
        {"", 0},
    };
    for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++)
        CHECK(gl_renderer_is_software(cases[i].renderer) == cases[i].software,
              "renderer \"%s\" is %s", cases[i].renderer,
              cases[i].software ? "software" : "hardware");
}

/* ---- GL depth vs CPU depth ---- */

typedef struct depth_case {
    const char *name;
    collider_geometry geometry;
    collider_pose pose;
} depth_case;

static quatd axis_angle(double x, double y, double z, double degrees)
{
    return quat_from_axis_angle((vec3d){x, y, z}, degrees * M_PI / 180.0);
}

/* again == 0: one batch. again == 1: the same batch once more, after
 * sim_backend_gl_set_limits has made it run in several chunks. Both times
 * every cell's GL bottom must be the CPU twin's (one fixed-point rule,
 * collider/depth_fixed.c; issue 12, item 4). */
static void test_depth_exact(sim_backend *gl, int again)
{
    const double cell = 0.02;
    const int32_t upm = 10000;
    depth_case cases[] = {
        {"sphere r=0.3",
         {.shape = COLLIDER_SPHERE, .radius = 0.3},
         {{1.01, 1.03, 0.45}, {1, 0, 0, 0}}},
        {"wheel r=0.33 yawed 30 deg",
         {.shape = COLLIDER_CYLINDER, .radius = 0.33, .half_length = 0.12},
         {{3.0, 1.0, 0.40}, axis_angle(0, 0, 1, 30)}},
        {"box tilted",
         {.shape = COLLIDER_BOX, .half_extents = {0.25, 0.15, 0.1}},
         {{5.0, 1.0, 0.5}, quat_multiply(axis_angle(0, 0, 1, 35), axis_angle(1, 0, 0, 20))}},
        {"lugged wheel r=0.3 8 lugs, yawed and spun",
         {.shape = COLLIDER_CYLINDER,
          .radius = 0.3,
          .half_length = 0.1,
          .grousers = {8, 0.06, 0.03}},
         {{9.0, 1.0, 0.40}, quat_multiply(axis_angle(0, 0, 1, 20), axis_angle(0, 1, 0, 7))}},
        {"capsule lying",
         {.shape = COLLIDER_CAPSULE, .radius = 0.2, .half_length = 0.2},
         {{7.0, 1.0, 0.42}, axis_angle(0, 0, 1, -60)}},
    };
    enum { CASES = sizeof cases / sizeof cases[0] };
    sim_window_job jobs[CASES];
    sim_collider colliders[CASES];
    int32_t *heights[CASES], *bottom_gl[CASES], *bottom_cpu[CASES];
    int status[CASES];
    for (int k = 0; k < CASES; k++) {
        /* windows of different odd sizes */
        int side = 41 + 4 * k;
        world_rect r = {(int)(cases[k].pose.position.x / cell) - side / 2,
                        (int)(cases[k].pose.position.y / cell) - side / 2 + k, side, side - 3};
        int n = r.w * r.h;
        heights[k] = calloc((size_t)n, sizeof(int32_t));
        bottom_gl[k] = calloc((size_t)n, sizeof(int32_t));
        bottom_cpu[k] = calloc((size_t)n, sizeof(int32_t));
        for (int i = 0; i < n; i++) {
            heights[k][i] = -20000; /* far below: nothing moves, only depth matters */
            bottom_cpu[k][i] = COLLIDER_BOTTOM_NONE;
        }
        colliders[k] =
            (sim_collider){.id = k, .geometry = &cases[k].geometry, .pose = cases[k].pose};
        collider_depth_cpu(&cases[k].geometry, cases[k].pose, r, cell, upm, bottom_cpu[k]);
        jobs[k] = (sim_window_job){
            .rect = r,
            .cell_size_m = cell,
            .units_per_m = upm,
            .heights = heights[k],
            .colliders = &colliders[k],
            .collider_count = 1,
            .bottom_out = bottom_gl[k],
        };
    }
    sim_material m = sim_material_default();
    sim_params p;
    error_text err = {{0}};
    sim_params_from_material(&m, cell, upm, -100000, &p, &err);
    int rc = gl->run_windows(gl, &p, jobs, CASES, status, &(sim_stage_times){0}, &err);
    for (int k = 0; k < CASES; k++)
        gl->forget_geometry(gl, &cases[k].geometry);
    CHECK(rc == 0, "depth batch of %d windows runs%s (%s)", CASES, again ? " in chunks" : "",
          rc ? err.message : "ok");
    for (int k = 0; k < CASES; k++) {
        int n = jobs[k].rect.w * jobs[k].rect.h, covered = 0, differ = 0;
        for (int i = 0; i < n; i++) {
            covered += bottom_cpu[k][i] != COLLIDER_BOTTOM_NONE;
            differ += bottom_cpu[k][i] != bottom_gl[k][i];
        }
        CHECK(rc == 0 && covered > 100 && differ == 0,
              "depth %s%s: GL bottoms == CPU bottoms (%d cells covered, %d differ)", cases[k].name,
              again ? " in chunks" : "", covered, differ);
        free(heights[k]);
        free(bottom_gl[k]);
        free(bottom_cpu[k]);
    }
}

/* ---- bit-exact integer stages ---- */

typedef struct batch {
    int count;
    sim_window_job jobs[8];
    int32_t *heights[8], *heights_cpu[8], *bottom[8];
} batch;

static void batch_free(batch *b)
{
    for (int i = 0; i < b->count; i++) {
        free(b->heights[i]);
        free(b->heights_cpu[i]);
        free(b->bottom[i]);
    }
    b->count = 0;
}

static const int awkward_sizes[][2] = {
    {1, 1},   {1, 7},  {9, 1},   {2, 2},  {3, 5},  {13, 11},
    {16, 16}, {17, 9}, {31, 33}, {64, 5}, {6, 40}, {47, 29},
};

/*
 * A random window: terrain with slopes and noise around `base`, and a bottom
 * made of colliders (discs pressing in), obstacles (tiny gaps above the
 * surface), uncovered cells, colliders deep below the floor, and per-cell
 * noise in the "mixed" style.
 */
static void random_window(batch *b, int k, int w, int h, int32_t base, int32_t amplitude, int style)
{
    int n = w * h;
    b->heights[k] = malloc((size_t)n * sizeof(int32_t));
    b->heights_cpu[k] = malloc((size_t)n * sizeof(int32_t));
    b->bottom[k] = malloc((size_t)n * sizeof(int32_t));
    int32_t sx = rnd_range(-amplitude / 8, amplitude / 8),
            sy = rnd_range(-amplitude / 8, amplitude / 8);
    int discs = 1 + (int)(rnd() % 3);
    int cx[3], cy[3], rad[3];
    int32_t press[3];
    for (int d = 0; d < discs; d++) {
        cx[d] = rnd_range(0, w - 1);
        cy[d] = rnd_range(0, h - 1);
        rad[d] = rnd_range(0, (w > h ? w : h) / 2 + 1);
        press[d] = rnd_range(0, amplitude);
    }
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            int64_t hv = (int64_t)base + (int64_t)sx * x / (w > 1 ? w : 1) +
                         (int64_t)sy * y / (h > 1 ? h : 1) + rnd_range(0, amplitude / 16 + 1);
            if (hv > WORLD_HEIGHT_MAX)
                hv = WORLD_HEIGHT_MAX;
            if (hv < WORLD_HEIGHT_MIN)
                hv = WORLD_HEIGHT_MIN;
            int32_t hh = (int32_t)hv;
            int32_t bt = COLLIDER_BOTTOM_NONE;
            if (style == 0) {
                for (int d = 0; d < discs; d++) {
                    int dx = x - cx[d], dy = y - cy[d];
                    if (dx * dx + dy * dy <= rad[d] * rad[d]) {
                        int64_t v = (int64_t)base - press[d] + (dx * dx + dy * dy) * 7;
                        if (v < bt)
                            bt = (int32_t)(v < WORLD_HEIGHT_MIN - 1 ? WORLD_HEIGHT_MIN - 1 : v);
                    }
                }
            } else {
                switch (rnd() % 6) {
                case 0:
                case 1:
                    break; /* uncovered */
                case 2:    /* obstacle: a tiny gap above */
                    bt = (int32_t)((int64_t)hh + rnd_range(0, 1200) > WORLD_HEIGHT_MAX + 1
                                       ? WORLD_HEIGHT_MAX + 1
                                       : hh + rnd_range(0, 1200));
                    break;
                case 3: /* deep below the floor */
                    bt = WORLD_HEIGHT_MIN - 1 + rnd_range(0, 1000);
                    break;
                default: /* pressing in */
                    bt = (int32_t)((int64_t)hh - rnd_range(0, amplitude) < WORLD_HEIGHT_MIN - 1
                                       ? WORLD_HEIGHT_MIN - 1
                                       : hh - rnd_range(0, amplitude));
                    break;
                }
            }
            b->heights[k][i] = hh;
            b->heights_cpu[k][i] = hh;
            b->bottom[k][i] = bt;
        }
    }
    b->jobs[k] = (sim_window_job){
        .rect = {rnd_range(-5000, 5000), rnd_range(-5000, 5000), w, h},
        .cell_size_m = 0.05,
        .units_per_m = 10000,
        .heights = b->heights[k],
        .bottom_override = b->bottom[k],
    };
}

/* Run a batch on both backends; compare status and (accepted) heights. */
static int compare_batch(sim_backend *gl, sim_backend *cpu, const sim_params *p, batch *b,
                         const char *label, int *limit_windows)
{
    sim_window_job cpu_jobs[8];
    int st_gl[8], st_cpu[8];
    for (int k = 0; k < b->count; k++) {
        cpu_jobs[k] = b->jobs[k];
        cpu_jobs[k].heights = b->heights_cpu[k];
    }
    error_text err = {{0}};
    sim_stage_times t = {0};
    if (gl->run_windows(gl, p, b->jobs, b->count, st_gl, &t, &err) != 0) {
        printf("FAIL %s: gl run_windows: %s\n", label, err.message);
        return -1;
    }
    if (cpu->run_windows(cpu, p, cpu_jobs, b->count, st_cpu, &t, &err) != 0) {
        printf("FAIL %s: cpu run_windows: %s\n", label, err.message);
        return -1;
    }
    for (int k = 0; k < b->count; k++) {
        if (st_gl[k] != st_cpu[k]) {
            printf("FAIL %s: window %d (%dx%d) status gl %d cpu %d\n", label, k, b->jobs[k].rect.w,
                   b->jobs[k].rect.h, st_gl[k], st_cpu[k]);
            return -1;
        }
        if (st_cpu[k] != SIM_WINDOW_OK) {
            (*limit_windows)++;
            continue;
        }
        int n = b->jobs[k].rect.w * b->jobs[k].rect.h;
        for (int i = 0; i < n; i++) {
            if (b->heights[k][i] != b->heights_cpu[k][i]) {
                printf("FAIL %s: window %d (%dx%d) cell (%d,%d): gl %d cpu %d\n", label, k,
                       b->jobs[k].rect.w, b->jobs[k].rect.h, i % b->jobs[k].rect.w,
                       i / b->jobs[k].rect.w, b->heights[k][i], b->heights_cpu[k][i]);
                return -1;
            }
        }
    }
    return 0;
}

static sim_params random_params(sim_method method, sim_metric metric, int32_t floor_units)
{
    sim_material m = sim_material_default();
    m.method = method;
    m.metric = metric;
    m.compression = (rnd() % 3 == 0) ? (rnd() % 1000) / 1000.0 : 0.0;
    m.roughness = (rnd() % 1001) / 1000.0;
    m.repose_deg = (rnd() % 8900) / 100.0;
    if (m.repose_deg < 0.2)
        m.repose_deg = 0.0; /* under one unit per cell: refused (ground.c) */
    m.obstacle_gap_m = (rnd() % 1000) / 10000.0;
    m.multi_target_m = 0.001 + (rnd() % 500) / 1000.0;
    m.multi_target_max = 1 + (int)(rnd() % 24);
    m.displace_iterations = (int)(rnd() % 14);
    m.slope_iterations = (int)(rnd() % 14);
    return test_params_from_material(&m, floor_units);
}

static void test_bit_exact(sim_backend *gl, sim_backend *cpu, int rounds, int big_first)
{
    for (int mi = 0; mi < 3; mi++) {
        for (int di = 0; di < 3; di++) {
            int batches = 0, windows = 0, limits = 0, ok = 1;
            for (int round = 0; round < rounds && ok; round++) {
                batch b = {0};
                b.count = 1 + (int)(rnd() % 6);
                int extreme = round % 4 == 3;
                int32_t floor_units = extreme ? WORLD_HEIGHT_MIN : rnd_range(-2000, 40000);
                for (int k = 0; k < b.count; k++) {
                    static const int big[2] = {150, 97}; /* long jump-flood steps */
                    const int *sz = big_first && round == 0 && k == 0
                                        ? big
                                        : awkward_sizes[rnd() % (sizeof awkward_sizes /
                                                                 sizeof awkward_sizes[0])];
                    int32_t base = extreme ? WORLD_HEIGHT_MAX - rnd_range(0, 5000) : 50000;
                    int32_t amp = extreme ? (1 << 30) : rnd_range(10, 20000);
                    random_window(&b, k, sz[0], sz[1], base, amp, (int)(rnd() % 2));
                }
                sim_params p = random_params(methods[mi], metrics[di], floor_units);
                char label[96];
                snprintf(label, sizeof label, "%s/%s batch %d", sim_method_name(methods[mi]),
                         sim_metric_name(metrics[di]), round);
                if (compare_batch(gl, cpu, &p, &b, label, &limits) != 0)
                    ok = 0;
                batches++;
                windows += b.count;
                batch_free(&b);
            }
            CHECK(ok, "bit-exact %s/%s: %d batches, %d windows, %d refused at the height limit",
                  sim_method_name(methods[mi]), sim_metric_name(metrics[di]), batches, windows,
                  limits);
        }
    }
}

/* Hand-made refusals: each method's overflow rule, next to a normal window
 * in the same batch (a refusal must not touch its neighbours). */
static void test_height_limit(sim_backend *gl, sim_backend *cpu)
{
    for (int mi = 0; mi < 3; mi++) {
        for (int variant = 0; variant < 2; variant++) {
            batch b = {0};
            b.count = 2;
            for (int k = 0; k < 2; k++) {
                int w = 9, h = 7, n = w * h;
                b.heights[k] = malloc((size_t)n * sizeof(int32_t));
                b.heights_cpu[k] = malloc((size_t)n * sizeof(int32_t));
                b.bottom[k] = malloc((size_t)n * sizeof(int32_t));
                for (int i = 0; i < n; i++) {
                    int32_t hh, bt;
                    if (k == 1) { /* an ordinary window */
                        hh = 50000;
                        bt = (i % w >= 3 && i % w <= 5) ? 49000 : COLLIDER_BOTTOM_NONE;
                    } else if (variant == 0) {
                        /* near the top: everything but one column is pressed
                         * down 1000 units, and it all lands on that column */
                        hh = WORLD_HEIGHT_MAX - 10;
                        bt = i == n - 1 ? COLLIDER_BOTTOM_NONE : WORLD_HEIGHT_MAX - 1010;
                    } else {
                        /* full range: columns at the top pushed to a floor at
                         * the bottom; sums pass INT32_MAX on the way */
                        hh = WORLD_HEIGHT_MAX;
                        bt = i == 0 ? COLLIDER_BOTTOM_NONE : WORLD_HEIGHT_MIN - 1;
                    }
                    b.heights[k][i] = b.heights_cpu[k][i] = hh;
                    b.bottom[k][i] = bt;
                }
                b.jobs[k] = (sim_window_job){
                    .rect = {k * 100, 0, w, h},
                    .cell_size_m = 0.05,
                    .units_per_m = 10000,
                    .heights = b.heights[k],
                    .bottom_override = b.bottom[k],
                };
            }
            sim_material m = sim_material_default();
            m.method = methods[mi];
            m.displace_iterations = 20;
            sim_params p;
            error_text err;
            sim_params_from_material(&m, 0.05, 10000, WORLD_HEIGHT_MIN, &p, &err);
            int limits = 0;
            char label[64];
            snprintf(label, sizeof label, "height limit %s variant %d", sim_method_name(m.method),
                     variant);
            int rc = compare_batch(gl, cpu, &p, &b, label, &limits);
            CHECK(rc == 0 && limits == 1, "%s: same status and heights, %d window refused", label,
                  limits);
            batch_free(&b);
        }
    }
}

/*
 * Dead ends of iterative displacement (issue 12): column x = 0 uncovered
 * (seeds), x = 1 obstacles, x >= 2 pressed in. Every column at x = 2 has
 * only obstacles closer to a seed, so it can pass nothing on while the
 * columns behind it keep sending: it must hand what it holds to its seed,
 * or the whole displaced volume would pile on it. Checked on both backends
 * (same heights) and on the CPU's numbers: after enough passes nothing but
 * the remainders of the even split (< 8 units) is left beyond the
 * obstacles, and Σh is kept. Variant 1 starts at the top of
 * the range, so the seeds' deposits pass INT32_MAX only through the dead
 * ends' hand-over: both backends must refuse the window there.
 */
static void test_dead_ends(sim_backend *gl, sim_backend *cpu)
{
    for (int mi = 0; mi < 3; mi++) {
        for (int variant = 0; variant < 2; variant++) {
            batch b = {0};
            b.count = 2;
            int w = 12, h = 7, n = w * h;
            int64_t before = 0;
            for (int k = 0; k < 2; k++) {
                b.heights[k] = malloc((size_t)n * sizeof(int32_t));
                b.heights_cpu[k] = malloc((size_t)n * sizeof(int32_t));
                b.bottom[k] = malloc((size_t)n * sizeof(int32_t));
                for (int i = 0; i < n; i++) {
                    int x = i % w;
                    int32_t hh = variant == 1 && k == 0 ? WORLD_HEIGHT_MAX : 50000;
                    int32_t press = variant == 1 && k == 0 ? 1 << 27 : 3000;
                    int32_t bt = x == 0 ? COLLIDER_BOTTOM_NONE : x == 1 ? hh + 50 : hh - press;
                    if (k == 1 && x > 6)
                        bt = COLLIDER_BOTTOM_NONE; /* an ordinary window beside it */
                    b.heights[k][i] = b.heights_cpu[k][i] = hh;
                    b.bottom[k][i] = bt;
                    if (k == 0)
                        before += hh;
                }
                b.jobs[k] = (sim_window_job){
                    .rect = {k * 100, 0, w, h},
                    .cell_size_m = 0.05,
                    .units_per_m = 10000,
                    .heights = b.heights[k],
                    .bottom_override = b.bottom[k],
                };
            }
            sim_material m = sim_material_default();
            m.method = SIM_METHOD_ITERATIVE;
            m.metric = metrics[mi];
            m.compression = 0.0;
            m.obstacle_gap_m = 0.01;
            m.displace_iterations = 2 * w;
            m.slope_iterations = 0;
            sim_params p;
            error_text err;
            sim_params_from_material(&m, 0.05, 10000, WORLD_HEIGHT_MIN, &p, &err);
            int limits = 0;
            char label[64];
            snprintf(label, sizeof label, "dead ends %s variant %d", sim_metric_name(m.metric),
                     variant);
            int rc = compare_batch(gl, cpu, &p, &b, label, &limits);
            CHECK(rc == 0 && limits == variant, "%s: same status and heights, %d window refused",
                  label, limits);
            if (variant == 0) {
                int64_t after = 0;
                int piled = 0;
                for (int i = 0; i < n; i++) {
                    after += b.heights_cpu[0][i];
                    if (i % w >= 2 && b.heights_cpu[0][i] > 50000 - 3000 + 7)
                        piled++;
                }
                CHECK(after == before && piled == 0,
                      "%s: no column past the obstacles keeps more than a remainder (%d do), sum "
                      "%lld -> %lld",
                      label, piled, (long long)before, (long long)after);
            }
            batch_free(&b);
        }
    }
}

/*
 * Sparse jump flooding and slope evening on the GL backend (compacted tile
 * lists, indirect dispatch over the listed tiles; slope evening's list after
 * each iteration is the tiles around a change): windows where most 8x8 tiles
 * hold free cells only and are left out of the list — one small press in a large
 * window, presses at opposite corners (seeds read across unlisted tiles at
 * every step size), a window nothing penetrates (an empty list), a window
 * pressed everywhere (every tile listed, no seed at all) — against the CPU's
 * sparse stages, every method x metric, with slope evening on.
 */
static void sparse_window(batch *b, int k, int w, int h, int presses, const int (*at)[3])
{
    int n = w * h;
    b->heights[k] = malloc((size_t)n * sizeof(int32_t));
    b->heights_cpu[k] = malloc((size_t)n * sizeof(int32_t));
    b->bottom[k] = malloc((size_t)n * sizeof(int32_t));
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            int32_t hh = 50000 + 37 * x - 23 * y + rnd_range(0, 400);
            int32_t bt = COLLIDER_BOTTOM_NONE;
            for (int d = 0; d < presses; d++) {
                int dx = x - at[d][0], dy = y - at[d][1], r = at[d][2];
                if (r < 0 || dx * dx + dy * dy <= r * r)
                    bt = hh - 2000 - 40 * (dx * dx + dy * dy); /* r < 0: the whole window */
                else if (dx * dx + dy * dy <= (r + 1) * (r + 1) && bt == COLLIDER_BOTTOM_NONE)
                    bt = hh + 30; /* a ring of obstacles around the press */
            }
            b->heights[k][i] = b->heights_cpu[k][i] = hh;
            b->bottom[k][i] = bt;
        }
    }
    b->jobs[k] = (sim_window_job){
        .rect = {k * 1000, 500 - k * 300, w, h},
        .cell_size_m = 0.05,
        .units_per_m = 10000,
        .heights = b->heights[k],
        .bottom_override = b->bottom[k],
    };
}

static void test_sparse_tiles(sim_backend *gl, sim_backend *cpu, int chunked)
{
    static const int one[1][3] = {{113, 71, 3}}, one_small[1][3] = {{47, 41, 3}};
    static const int corners[2][3] = {{2, 2, 2}, {67, 17, 1}};
    static const int everywhere[1][3] = {{0, 0, -1}};
    for (int mi = 0; mi < 3; mi++) {
        for (int di = 0; di < 3; di++) {
            batch b = {0};
            b.count = 4;
            /* with 3400-cell chunks the first window must fit one: 60 x 50 */
            if (chunked)
                sparse_window(&b, 0, 60, 50, 1, one_small);
            else
                sparse_window(&b, 0, 150, 97, 1, one);
            sparse_window(&b, 1, 70, 20, 2, corners);
            sparse_window(&b, 2, 40, 40, 0, NULL);
            sparse_window(&b, 3, 9, 9, 1, everywhere);
            sim_material m = sim_material_default();
            m.method = methods[mi];
            m.metric = metrics[di];
            m.displace_iterations = 6;
            m.slope_iterations = 5;
            sim_params p;
            error_text err;
            sim_params_from_material(&m, 0.05, 10000, WORLD_HEIGHT_MIN, &p, &err);
            int limits = 0;
            char label[64];
            snprintf(label, sizeof label, "sparse tiles %s/%s", sim_method_name(m.method),
                     sim_metric_name(m.metric));
            int rc = compare_batch(gl, cpu, &p, &b, label, &limits);
            CHECK(rc == 0 && limits == 0, "%s: GL and CPU heights equal", label);
            batch_free(&b);
        }
    }
}

/* The same batch twice gives the same heights (atomics commute, ties hash). */
static void test_repeatable(sim_backend *gl)
{
    batch b = {0}, c = {0};
    uint64_t saved = rng_state;
    b.count = c.count = 4;
    for (int k = 0; k < 4; k++)
        random_window(&b, k, 37, 23, 50000, 8000, 0);
    rng_state = saved;
    for (int k = 0; k < 4; k++)
        random_window(&c, k, 37, 23, 50000, 8000, 0);
    sim_material m = sim_material_default();
    m.method = SIM_METHOD_MULTI;
    sim_params p;
    error_text err;
    sim_params_from_material(&m, 0.05, 10000, 0, &p, &err);
    int st[4];
    sim_stage_times t = {0};
    gl->run_windows(gl, &p, b.jobs, 4, st, &t, &err);
    gl->run_windows(gl, &p, c.jobs, 4, st, &t, &err);
    int same = 1;
    for (int k = 0; k < 4; k++)
        same &= memcmp(b.heights[k], c.heights[k], 37 * 23 * sizeof(int32_t)) == 0;
    CHECK(same, "repeatable: the same batch twice gives the same heights");
    batch_free(&b);
    batch_free(&c);
}

/* Scratch memory follows the batch, and the timing of a 4-window batch. */
static void test_scratch_and_timing(sim_backend *gl)
{
    uint64_t before = gl->scratch_bytes(gl);
    enum { N = 4, W = 128, H = 96 };
    static collider_geometry sphere = {.shape = COLLIDER_SPHERE, .radius = 0.4};
    sim_collider colliders[N];
    sim_window_job jobs[N];
    int32_t *heights[N];
    int status[N];
    for (int k = 0; k < N; k++) {
        heights[k] = malloc(W * H * sizeof(int32_t));
        for (int i = 0; i < W * H; i++)
            heights[k][i] = 50000;
        world_rect r = {k * 200, 0, W, H};
        colliders[k] = (sim_collider){
            .id = k,
            .geometry = &sphere,
            .pose = {{(r.x + W / 2) * 0.05, (H / 2) * 0.05, 4.6 + 0.05 * k}, {1, 0, 0, 0}}};
        jobs[k] = (sim_window_job){.rect = r,
                                   .cell_size_m = 0.05,
                                   .units_per_m = 10000,
                                   .heights = heights[k],
                                   .colliders = &colliders[k],
                                   .collider_count = 1};
    }
    sim_backend_set_stage_timing(gl, 1);
    for (int mi = 0; mi < 3; mi++) {
        sim_material m = sim_material_default();
        m.method = methods[mi];
        sim_params p;
        error_text err;
        sim_params_from_material(&m, 0.05, 10000, 0, &p, &err);
        sim_stage_times t = {0};
        const int reps = 5;
        for (int rep = 0; rep <= reps; rep++) {
            for (int k = 0; k < N; k++)
                for (int i = 0; i < W * H; i++)
                    heights[k][i] = 50000;
            if (rep == 0) /* warm-up: first use compiles and allocates */
                gl->run_windows(gl, &p, jobs, N, status, &(sim_stage_times){0}, &err);
            else
                gl->run_windows(gl, &p, jobs, N, status, &t, &err);
        }
        printf("info timing %s, %d windows of %dx%d on %s (ms per batch): depth %.3f classify "
               "%.3f jump_flood %.3f displace %.3f even_slopes %.3f transfer %.3f\n",
               sim_method_name(m.method), N, W, H, gl->renderer, t.depth / reps, t.classify / reps,
               t.jump_flood / reps, t.displace / reps, t.even_slopes / reps, t.transfer / reps);
    }
    sim_backend_set_stage_timing(gl, 0);
    uint64_t after = gl->scratch_bytes(gl);
    CHECK(after >= (uint64_t)N * W * H * 10 * sizeof(int32_t) && after < (uint64_t)64 << 20,
          "scratch: %llu bytes before, %llu after a %d-cell batch (grows with the batch)",
          (unsigned long long)before, (unsigned long long)after, N * W * H);
    gl->forget_geometry(gl, &sphere);
    for (int k = 0; k < N; k++)
        free(heights[k]);
}

/* ---- per-cell materials and compaction memory (sim_stages.c) ---- */

/* Random material tables, ids and compaction memory on random windows: heights,
 * statuses and the compaction written back agree bit for bit. */
static void test_materials_bit_exact(sim_backend *gl, sim_backend *cpu, int rounds)
{
    int ok = 1, windows = 0, compacting = 0;
    for (int round = 0; round < rounds && ok; round++) {
        batch b = {0};
        b.count = 1 + (int)(rnd() % 5);
        sim_params p = random_params(methods[round % 3], (sim_metric)(rnd() % 3), 0);
        ground_material_table t = {.count = 1 + (int)(rnd() % GROUND_MATERIALS_MAX)};
        for (int r = 0; r < t.count; r++) {
            sim_params q = random_params(methods[round % 3], SIM_METRIC_EUCLIDEAN, 0);
            int32_t max_c = rnd() % 2 ? (int32_t)(rnd() % 65536) : 0;
            t.rows[r] = sim_material_row_from_params(&q, max_c);
            if (rnd() % 4 == 0)
                t.rows[r].compression_q16 = (int32_t)(rnd() % 65537);
        }
        uint8_t *ids[8];
        uint16_t *mem_gl[8], *mem_cpu[8];
        int with_ids = round % 4 != 3; /* every fourth: one material, ids NULL */
        for (int k = 0; k < b.count; k++) {
            const int *sz = awkward_sizes[rnd() % (sizeof awkward_sizes / sizeof awkward_sizes[0])];
            random_window(&b, k, sz[0], sz[1], 50000, rnd_range(10, 20000), (int)(rnd() % 2));
            int n = sz[0] * sz[1];
            ids[k] = malloc((size_t)n);
            mem_gl[k] = malloc((size_t)n * 2);
            mem_cpu[k] = malloc((size_t)n * 2);
            for (int i = 0; i < n; i++) {
                ids[k][i] = (uint8_t)(rnd() % (uint32_t)t.count);
                int32_t max_c = t.rows[with_ids ? ids[k][i] : 0].max_compaction;
                mem_gl[k][i] = mem_cpu[k][i] =
                    (uint16_t)(max_c > 0 ? rnd() % (uint32_t)(max_c + 2) : rnd() % 65536);
            }
            b.jobs[k].materials = &t;
            b.jobs[k].material_ids = with_ids ? ids[k] : NULL;
            b.jobs[k].compaction = mem_gl[k];
        }
        /* compare_batch copies the jobs for the CPU: give its copy its own memory */
        sim_window_job cpu_jobs[8];
        int st_gl[8], st_cpu[8];
        for (int k = 0; k < b.count; k++) {
            cpu_jobs[k] = b.jobs[k];
            cpu_jobs[k].heights = b.heights_cpu[k];
            cpu_jobs[k].compaction = mem_cpu[k];
        }
        error_text err = {{0}};
        sim_stage_times tm = {0};
        if (gl->run_windows(gl, &p, b.jobs, b.count, st_gl, &tm, &err) != 0 ||
            cpu->run_windows(cpu, &p, cpu_jobs, b.count, st_cpu, &tm, &err) != 0) {
            printf("FAIL materials round %d: run_windows: %s\n", round, err.message);
            ok = 0;
        }
        for (int k = 0; ok && k < b.count; k++) {
            int n = b.jobs[k].rect.w * b.jobs[k].rect.h;
            if (st_gl[k] != st_cpu[k]) {
                printf("FAIL materials round %d window %d: status gl %d cpu %d\n", round, k,
                       st_gl[k], st_cpu[k]);
                ok = 0;
                break;
            }
            if (st_cpu[k] != SIM_WINDOW_OK)
                continue;
            for (int i = 0; i < n && ok; i++) {
                if (b.heights[k][i] != b.heights_cpu[k][i] || mem_gl[k][i] != mem_cpu[k][i]) {
                    printf("FAIL materials round %d window %d (%dx%d) cell %d: heights gl %d cpu "
                           "%d, compaction gl %u cpu %u\n",
                           round, k, b.jobs[k].rect.w, b.jobs[k].rect.h, i, b.heights[k][i],
                           b.heights_cpu[k][i], mem_gl[k][i], mem_cpu[k][i]);
                    ok = 0;
                }
                if (mem_cpu[k][i] != 0)
                    compacting++;
            }
            windows++;
        }
        for (int k = 0; k < b.count; k++) {
            free(ids[k]);
            free(mem_gl[k]);
            free(mem_cpu[k]);
        }
        batch_free(&b);
    }
    CHECK(ok, "materials bit-exact: %d rounds, %d accepted windows, %d cells with memory", rounds,
          windows, compacting);
}

/* The GPU tile cache through the engine: a tiled dune world ticked on GL
 * with a tiny cache (evictions, fallbacks, re-uploads) and on the CPU twin
 * with the same depth stays identical, including after a write into a
 * cached tile that does not go through a tick (the cache must notice it by
 * the tile's generation). */
static void test_tile_cache(sim_backend *gl, sim_backend *cpu)
{
    error_text err = {{0}};
    world wg, wc;
    world_base_spec dunes = {.kind = WORLD_BASE_DUNES,
                             .min_height_m = 0.3,
                             .max_height_m = 0.6,
                             .wavelength_m = 2.0,
                             .octaves = 3,
                             .seed = 9};
    int ok = world_init_tiled(&wg, 200, 150, 0.05, 10000, 0, 16, &err) == 0 &&
             world_init_tiled(&wc, 200, 150, 0.05, 10000, 0, 16, &err) == 0 &&
             world_generate_base(&wg, &dunes, &err) == 0 &&
             world_generate_base(&wc, &dunes, &err) == 0;
    CHECK(ok, "tile cache: worlds (%s)", err.message);
    if (!ok)
        return;
    sim_material m = sim_material_default();
    sim_params p;
    CHECK(sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) == 0, "params");
    sim_backend_gl_set_tile_cache(gl, 10, 8 * 16 * 16 * 4);
    sim_tile_cache_stats before;
    sim_backend_tile_cache_stats(gl, &before);
    sim_engine *eg = sim_engine_create(&wg, &p, gl, 2, &err);
    sim_engine *ec = sim_engine_create(&wc, &p, cpu, 2, &err);
    CHECK(eg && ec, "engines");
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.35};
    collider_geometry small = {.shape = COLLIDER_SPHERE, .radius = 0.15};
    /* pressed in only for ticks 20..39: its window covers more tiles than
     * the cache has layers, so it goes direct and the cached copies of those
     * tiles go stale; the first ball drives over them afterwards */
    collider_geometry big = {.shape = COLLIDER_SPHERE, .radius = 1.3};
    int same = 1, tick_ok = 1;
    for (int t = 0; t < 90 && tick_ok; t++) {
        sim_collider c[4];
        memset(c, 0, sizeof c);
        /* across the corners of 16-cell (0.8 m) tiles, one slow, one fast */
        double xs[3] = {0.8 + 0.02 * t, 3.2 + 0.05 * t, 6.4};
        double ys[3] = {0.8 + 0.015 * t, 2.4, 1.6 + 0.04 * t};
        for (int i = 0; i < 3; i++) {
            c[i].id = i;
            c[i].geometry = i == 1 ? &small : &ball;
            c[i].pose.orientation.w = 1.0;
            c[i].pose.position = (vec3d){xs[i], ys[i], 0.5 + (i == 1 ? 0.0 : 0.2)};
            c[i].previous_pose = c[i].pose;
            c[i].has_previous = 0;
        }
        c[3] = c[0];
        c[3].id = 3;
        c[3].geometry = &big;
        c[3].pose.position = (vec3d){2.2, 1.9, t >= 20 && t < 40 ? 1.55 : 5.0};
        c[3].previous_pose = c[3].pose;
        if (t == 45) {
            /* a write between ticks into a tile the GL cache holds */
            world_set_height(&wg, 30, 25, 9000);
            world_set_height(&wc, 30, 25, 9000);
        }
        sim_tick_report rg, rc;
        memset(&rg, 0, sizeof rg);
        memset(&rc, 0, sizeof rc);
        tick_ok =
            sim_engine_tick(eg, c, 4, &rg, &err) == 0 && sim_engine_tick(ec, c, 4, &rc, &err) == 0;
        int32_t *a = malloc(200 * 150 * 4), *b = malloc(200 * 150 * 4);
        world_gather_window(&wg, (world_rect){0, 0, 200, 150}, a);
        world_gather_window(&wc, (world_rect){0, 0, 200, 150}, b);
        same &= memcmp(a, b, 200 * 150 * 4) == 0;
        free(a);
        free(b);
    }
    CHECK(tick_ok, "tile cache: 90 ticks run (%s)", err.message);
    CHECK(same, "tile cache: GL through a 10-layer cache == CPU twin after every tick");
    CHECK(world_volume(&wg) == world_volume(&wc), "tile cache: same volume");
    sim_tile_cache_stats after;
    sim_backend_tile_cache_stats(gl, &after);
    CHECK(after.windows_cached > before.windows_cached &&
              after.windows_direct > before.windows_direct && after.evictions > before.evictions,
          "tile cache: windows from the cache (%llu), direct (%llu), evictions (%llu)",
          (unsigned long long)(after.windows_cached - before.windows_cached),
          (unsigned long long)(after.windows_direct - before.windows_direct),
          (unsigned long long)(after.evictions - before.evictions));
    CHECK(after.texture_bytes == 10 * 16 * 16 * 4 && after.resident_tiles <= 10,
          "tile cache: texture of 10 layers, %d resident", after.resident_tiles);
    sim_engine_destroy(eg);
    sim_engine_destroy(ec);
    world_free(&wg);
    world_free(&wc);
    sim_backend_gl_set_tile_cache(gl, 64, (int64_t)4 << 20);
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    test_renderer_is_software();
    if (test_context() != 0)
        return failed ? 1 : 77;
    error_text err = {{0}};
    sim_backend *gl = sim_backend_gl_create(&err);
    CHECK(gl != NULL, "gl backend: created (%s)", gl ? gl->renderer : err.message);
    sim_backend *cpu = sim_backend_cpu_create(&err);
    if (!gl || !cpu) {
        printf("%d passed, %d failed\n", passed, failed + 1);
        return 1;
    }
    test_depth_exact(gl, 0);
    test_bit_exact(gl, cpu, 12, 1);
    test_materials_bit_exact(gl, cpu, 24);
    test_height_limit(gl, cpu);
    test_dead_ends(gl, cpu);
    test_sparse_tiles(gl, cpu, 0);
    test_repeatable(gl);
    test_scratch_and_timing(gl);
    test_tile_cache(gl, cpu);
    /* last: the path of batches too big for one storage block, forced with a
     * small limit (which stays for the rest of the backend's life) */
    sim_backend_gl_set_limits(gl, 3400);
    test_depth_exact(gl, 1);
    printf("info with 3400-cell chunks:\n");
    test_bit_exact(gl, cpu, 4, 0);
    test_sparse_tiles(gl, cpu, 1);
    gl->destroy(gl);
    cpu->destroy(cpu);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
