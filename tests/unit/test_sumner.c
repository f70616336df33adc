/*
 * test_sumner.c: the Sumner 1999 model (server/sim/model_sumner.c) on single
 * windows: exact volume over many ticks of a moving collider, material lands
 * on the first ring with the remainder placed deterministically, erosion
 * reaches the angle of repose and stops, and the extremes the issue names
 * (repose 0 and 89.9, roughness and compression 0 and 1, one-cell and
 * window-sized colliders, heights at the ±2^29 limits).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/sim_internal.h"
#include "check.h"
#include "test_params.h"

#define CELL_M 0.05
#define UNITS 10000

static sim_params params_with(double repose, double roughness, double compression, int slope_it)
{
    sim_material m = sim_material_default();
    m.repose_deg = repose;
    m.roughness = roughness;
    m.compression = compression;
    m.slope_iterations = slope_it;
    return test_params_from_material(&m, WORLD_HEIGHT_MIN);
}

static int32_t *scratch_for(int w, int h)
{
    return malloc((size_t)sim_sumner_scratch_cells(w, h) * sizeof(int32_t));
}

/* A window job over heights with an explicit depth (bottom) array. */
static sim_window_job job_with_bottom(int w, int h, int32_t *heights, const int32_t *bottom)
{
    sim_window_job job;
    memset(&job, 0, sizeof job);
    job.rect = (world_rect){0, 0, w, h};
    job.cell_size_m = CELL_M;
    job.units_per_m = UNITS;
    job.heights = heights;
    job.bottom_override = bottom;
    return job;
}

/* A sphere rolling across a bumpy window for 300 ticks: Σh never changes. */
static void test_volume_exact_moving_sphere(void)
{
    enum { W = 64, H = 48 };
    static int32_t heights[W * H];
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        heights[i] = 50000 + (int32_t)(800.0 * sin(x * 0.3) * cos(y * 0.2)) + (x * 7 + y * 13) % 97;
    }
    int64_t before = test_sum(heights, W * H);
    collider_geometry sphere = {.shape = COLLIDER_SPHERE, .radius = 0.4};
    sim_collider col = {.id = 1, .geometry = &sphere};
    col.pose.orientation = (quatd){1, 0, 0, 0};
    sim_params p = params_with(30.0, 0.5, 0.0, 10);
    int32_t *scratch = scratch_for(W, H);
    int bad = 0, ok = 0;
    for (int t = 0; t < 300; t++) {
        col.pose.position = (vec3d){0.4 + 2.4 * (t % 100) / 100.0, 1.2 + 0.3 * sin(t * 0.1),
                                    5.0 + 0.4 - 0.12 - 0.0005 * t};
        sim_window_job job = job_with_bottom(W, H, heights, NULL);
        job.colliders = &col;
        job.collider_count = 1;
        if (sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK)
            ok++;
        if (test_sum(heights, W * H) != before)
            bad++;
    }
    CHECK(ok == 300, "every tick accepted (%d)", ok);
    CHECK(bad == 0, "sum of heights changed on %d of 300 ticks (now %lld, was %lld)", bad,
          (long long)test_sum(heights, W * H), (long long)before);
    /* the sphere dug: the lowest column is well below the start */
    int32_t lowest = INT32_MAX;
    for (int i = 0; i < W * H; i++)
        lowest = heights[i] < lowest ? heights[i] : lowest;
    CHECK(lowest < 50000 - 800 - 500, "sphere dug a trail (lowest %d)", lowest);
    free(scratch);
}

/* A 3x3 block pressed 5 units into flat ground: 45 units over the 16 cells of
 * the first ring, 2 each and one more for the first 13 in row-major order. */
static void test_first_ring(void)
{
    enum { W = 9, H = 9 };
    int32_t heights[W * H], bottom[W * H];
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        heights[i] = 1000;
        bottom[i] = (x >= 3 && x <= 5 && y >= 3 && y <= 5) ? 995 : COLLIDER_BOTTOM_NONE;
    }
    sim_params p = params_with(30.0, 0.5, 0.0, 0);
    int32_t *scratch = scratch_for(W, H);
    sim_window_job job = job_with_bottom(W, H, heights, bottom);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
    int ring_seen = 0, wrong = 0;
    for (int i = 0; i < W * H; i++) {
        int x = i % W, y = i / W;
        int inside = x >= 3 && x <= 5 && y >= 3 && y <= 5;
        int ring = !inside && x >= 2 && x <= 6 && y >= 2 && y <= 6;
        int32_t expect = 1000;
        if (inside)
            expect = 995;
        else if (ring)
            expect = 1000 + 2 + (ring_seen++ < 13 ? 1 : 0);
        if (heights[i] != expect) {
            wrong++;
            printf("  (%d,%d) = %d, expected %d\n", x, y, heights[i], expect);
        }
    }
    CHECK(ring_seen == 16, "16 first-ring cells (%d)", ring_seen);
    CHECK(wrong == 0, "%d cells differ from the first-ring rule", wrong);
    CHECK(test_sum(heights, W * H) == 1000LL * W * H, "volume kept");
    free(scratch);
}

/* Two separate footprints: each one's material goes to its own ring. */
static void test_two_components(void)
{
    enum { W = 12, H = 5 };
    int32_t heights[W * H], bottom[W * H];
    for (int i = 0; i < W * H; i++) {
        heights[i] = 0;
        bottom[i] = COLLIDER_BOTTOM_NONE;
    }
    bottom[2 * W + 2] = -80; /* 80 units over 8 ring cells: 10 each */
    bottom[2 * W + 9] = -16; /* 16 units over 8 ring cells: 2 each */
    sim_params p = params_with(30.0, 0.5, 0.0, 0);
    int32_t *scratch = scratch_for(W, H);
    sim_window_job job = job_with_bottom(W, H, heights, bottom);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
    CHECK(heights[2 * W + 2] == -80 && heights[2 * W + 9] == -16, "both columns lowered");
    CHECK(heights[1 * W + 1] == 10 && heights[3 * W + 3] == 10, "left ring gets 10 each (%d, %d)",
          heights[1 * W + 1], heights[3 * W + 3]);
    CHECK(heights[1 * W + 8] == 2 && heights[3 * W + 10] == 2, "right ring gets 2 each (%d, %d)",
          heights[1 * W + 8], heights[3 * W + 10]);
    CHECK(heights[2 * W + 5] == 0 && heights[2 * W + 6] == 0, "between the rings nothing lands");
    CHECK(test_sum(heights, W * H) == 0, "volume kept");
    free(scratch);
}

/* A spike with no collider relaxes to within the rounding bound of the
 * repose threshold, then stays put (no oscillation). */
static void check_erosion_reaches_repose(double repose, double roughness)
{
    enum { W = 33, H = 33 };
    static int32_t heights[W * H], previous[W * H];
    for (int i = 0; i < W * H; i++)
        heights[i] = 0;
    heights[16 * W + 16] = 400000; /* 40 m spike on 5 cm cells */
    sim_params p = params_with(repose, roughness, 0.0, 50);
    int32_t *scratch = scratch_for(W, H);
    int64_t before = test_sum(heights, W * H);
    int settled_at = -1;
    for (int call = 0; call < 400 && settled_at < 0; call++) {
        memcpy(previous, heights, sizeof heights);
        sim_window_job job = job_with_bottom(W, H, heights, NULL);
        CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
        if (memcmp(previous, heights, sizeof heights) == 0)
            settled_at = call;
    }
    int64_t bound = roughness > 0 ? (int64_t)ceil(8.0 * 65536.0 / p.roughness_q16) : 0;
    int64_t excess = sim_max_slope_excess(&p, W, H, heights);
    CHECK(settled_at >= 0, "repose %g roughness %g: erosion settles (no oscillation)", repose,
          roughness);
    CHECK(excess <= bound, "repose %g roughness %g: slope excess %lld above bound %lld", repose,
          roughness, (long long)excess, (long long)bound);
    CHECK(test_sum(heights, W * H) == before, "repose %g: volume kept by erosion", repose);
    free(scratch);
}

static void test_repose_extremes(void)
{
    check_erosion_reaches_repose(30.0, 0.5);
    check_erosion_reaches_repose(0.0, 1.0);
    check_erosion_reaches_repose(0.0, 0.3);
    /* 89.9 degrees: the threshold saturates; the spike is steep but within it */
    enum { W = 5, H = 5 };
    int32_t heights[W * H];
    for (int i = 0; i < W * H; i++)
        heights[i] = 0;
    heights[12] = 200000;
    sim_params p = params_with(89.9, 1.0, 0.0, 100);
    CHECK(p.slope_threshold_axial > 200000, "89.9 deg threshold %d", p.slope_threshold_axial);
    int32_t *scratch = scratch_for(W, H);
    sim_window_job job = job_with_bottom(W, H, heights, NULL);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
    CHECK(heights[12] == 200000, "89.9 deg: the spike stands (%d)", heights[12]);
    free(scratch);
    /* roughness 0: nothing erodes */
    int32_t flat[W * H];
    for (int i = 0; i < W * H; i++)
        flat[i] = 0;
    flat[12] = 100000;
    p = params_with(0.0, 0.0, 0.0, 100);
    scratch = scratch_for(W, H);
    job = job_with_bottom(W, H, flat, NULL);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
    CHECK(flat[12] == 100000, "roughness 0: no erosion");
    free(scratch);
}

/* Compression 1 removes the penetration; compression 0.5 displaces half. */
static void test_compression_extremes(void)
{
    enum { W = 7, H = 7 };
    int32_t heights[W * H], bottom[W * H];
    for (int c = 0; c <= 2; c++) {
        double compression = c * 0.5;
        for (int i = 0; i < W * H; i++) {
            heights[i] = 5000;
            bottom[i] = i == 24 ? 5000 - 1001 : COLLIDER_BOTTOM_NONE;
        }
        sim_params p = params_with(30.0, 1.0, compression, 20);
        int32_t *scratch = scratch_for(W, H);
        sim_window_job job = job_with_bottom(W, H, heights, bottom);
        CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
        int64_t compacted = 1001 - (1001 - ((1001LL * p.compression_q16) >> 16));
        CHECK(test_sum(heights, W * H) == 5000LL * W * H - compacted,
              "compression %g: volume %lld, expected %lld", compression,
              (long long)test_sum(heights, W * H), (long long)(5000LL * W * H - compacted));
        CHECK(heights[24] == 5000 - 1001, "compression %g: column pressed to the collider",
              compression);
        free(scratch);
    }
}

/* One-cell collider: a sphere smaller than a cell, centred on a cell centre. */
static void test_one_cell_collider(void)
{
    enum { W = 7, H = 7 };
    int32_t heights[W * H];
    for (int i = 0; i < W * H; i++)
        heights[i] = 10000;
    collider_geometry sphere = {.shape = COLLIDER_SPHERE, .radius = 0.02};
    sim_collider col = {.id = 1, .geometry = &sphere};
    col.pose.orientation = (quatd){1, 0, 0, 0};
    col.pose.position = (vec3d){3.5 * CELL_M, 3.5 * CELL_M, 1.0 + 0.02 - 0.01};
    sim_params p = params_with(30.0, 0.5, 0.0, 0);
    int32_t *scratch = scratch_for(W, H);
    int32_t bottom_used[W * H];
    sim_window_job job = job_with_bottom(W, H, heights, NULL);
    job.colliders = &col;
    job.collider_count = 1;
    job.bottom_out = bottom_used;
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
    int hit = 0;
    for (int i = 0; i < W * H; i++)
        hit += bottom_used[i] != COLLIDER_BOTTOM_NONE;
    CHECK(hit == 1, "one ray-cast column hit (%d)", hit);
    CHECK(heights[24] == 9900, "the column is pressed to 9900 (%d)", heights[24]);
    int ring_ok = 1;
    for (int j = 0; j < W * H; j++) {
        int dx = j % W - 3, dy = j / W - 3;
        if (j != 24 && abs(dx) <= 1 && abs(dy) <= 1)
            ring_ok &= heights[j] == 10000 + 100 / 8 + ((dy == -1 || (dy == 0 && dx < 0)) ? 1 : 0);
    }
    CHECK(ring_ok, "100 units over 8 ring cells: 12 each, 4 more to the first four");
    CHECK(test_sum(heights, W * H) == 10000LL * W * H, "volume kept");
    free(scratch);
}

/* A collider covering the whole window: no ring, the material stays home
 * (compression 0) or is compacted (compression 1); nothing overflows. */
static void test_window_sized_collider(void)
{
    enum { W = 16, H = 16 };
    int32_t heights[W * H], bottom[W * H];
    for (int c = 0; c <= 1; c++) {
        for (int i = 0; i < W * H; i++) {
            heights[i] = 2000 + i;
            bottom[i] = 1000;
        }
        sim_params p = params_with(0.0, 1.0, (double)c, 30);
        int32_t *scratch = scratch_for(W, H);
        sim_window_job job = job_with_bottom(W, H, heights, bottom);
        CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "window accepted");
        int same = 1;
        for (int i = 0; i < W * H; i++)
            same &= heights[i] == (c == 0 ? 2000 + i : 1000);
        CHECK(same, "compression %d: window-sized collider %s", c,
              c == 0 ? "keeps the material home" : "compacts to the collider");
        free(scratch);
    }
}

/* Heights at the limits: a rise past WORLD_HEIGHT_MAX is refused with the
 * heights untouched; a full-range drop is exact. */
static void test_height_limits(void)
{
    enum { W = 5, H = 5 };
    int32_t heights[W * H], bottom[W * H], copy[W * H];
    for (int i = 0; i < W * H; i++) {
        heights[i] = WORLD_HEIGHT_MAX - 3;
        bottom[i] = i == 12 ? WORLD_HEIGHT_MAX - 1000 : COLLIDER_BOTTOM_NONE;
    }
    memcpy(copy, heights, sizeof heights);
    sim_params p = params_with(0.0, 1.0, 0.0, 10);
    int32_t *scratch = scratch_for(W, H);
    sim_window_job job = job_with_bottom(W, H, heights, bottom);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_HEIGHT_LIMIT,
          "a ring rising past the limit is refused");
    CHECK(memcmp(copy, heights, sizeof heights) == 0, "refused window left unchanged");

    /* a column at the top pressed to the floor at the bottom: 2^30 units move */
    for (int i = 0; i < W * H; i++) {
        heights[i] = WORLD_HEIGHT_MIN;
        bottom[i] = COLLIDER_BOTTOM_NONE;
    }
    heights[12] = WORLD_HEIGHT_MAX;
    bottom[12] = WORLD_HEIGHT_MIN - 1;
    int64_t before = test_sum(heights, W * H);
    job = job_with_bottom(W, H, heights, bottom);
    CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "full-range drop accepted");
    CHECK(heights[12] == WORLD_HEIGHT_MIN, "column at the floor (%d)", heights[12]);
    CHECK(test_sum(heights, W * H) == before, "volume kept at the limits");
    int in_range = 1;
    for (int i = 0; i < W * H; i++)
        in_range &= heights[i] >= WORLD_HEIGHT_MIN && heights[i] <= WORLD_HEIGHT_MAX;
    CHECK(in_range, "every column inside the height range");
    free(scratch);
}

/* With per-cell materials and compaction memory (job->materials): a block
 * pressed into a compacting row and a plain row keeps Σh + Σmemory exact,
 * the compacting cells remember, and a second press yields less. */
static void test_materials_and_compaction(void)
{
    enum { W = 12, H = 8, N = W * H };
    int32_t heights[N], bottom[N];
    uint8_t ids[N];
    uint16_t memory[N];
    sim_params p = params_with(30.0, 0.5, 0.0, 5);
    ground_material_table t = {.count = 2};
    t.rows[0] = sim_material_row_from_params(&p, 0);
    t.rows[1] = t.rows[0];
    t.rows[1].compression_q16 = 49152; /* 0.75 */
    t.rows[1].max_compaction = 400;
    for (int i = 0; i < N; i++) {
        heights[i] = 3000;
        ids[i] = (uint8_t)(i / W >= 4);
        memory[i] = 0;
    }
    int32_t *scratch = scratch_for(W, H);
    int32_t yield_first = 0, yield_second = 0;
    for (int pass = 0; pass < 2; pass++) {
        int32_t before_cell = heights[5 * W + 5];
        for (int i = 0; i < N; i++) {
            int x = i % W, y = i / W;
            bottom[i] =
                (x >= 4 && x <= 6 && y >= 2 && y <= 5) ? before_cell - 300 : COLLIDER_BOTTOM_NONE;
        }
        int64_t h_before = test_sum(heights, N), m_before = 0, m_after = 0;
        for (int i = 0; i < N; i++)
            m_before += memory[i];
        sim_window_job job = job_with_bottom(W, H, heights, bottom);
        job.materials = &t;
        job.material_ids = ids;
        job.compaction = memory;
        CHECK(sim_sumner_window(&p, &job, scratch) == SIM_WINDOW_OK, "pass %d accepted", pass);
        for (int i = 0; i < N; i++)
            m_after += memory[i];
        CHECK(test_sum(heights, N) + m_after == h_before + m_before,
              "pass %d: Σh + Σmemory exact (%lld + %lld vs %lld + %lld)", pass,
              (long long)test_sum(heights, N), (long long)m_after, (long long)h_before,
              (long long)m_before);
        int32_t yielded = before_cell - heights[5 * W + 5];
        if (pass == 0)
            yield_first = yielded;
        else
            yield_second = yielded;
        CHECK(memory[2 * W + 5] == 0, "the plain row remembers nothing");
    }
    CHECK(memory[5 * W + 5] > 0 && memory[5 * W + 5] <= 400, "compacting cell remembers %u",
          memory[5 * W + 5]);
    CHECK(yield_first == 300 && yield_second < yield_first,
          "a second press yields less (%d then %d)", yield_first, yield_second);
    free(scratch);
}

int main(void)
{
    test_volume_exact_moving_sphere();
    test_first_ring();
    test_two_components();
    test_repose_extremes();
    test_compression_extremes();
    test_one_cell_collider();
    test_window_sized_collider();
    test_height_limits();
    test_materials_and_compaction();
    return check_report();
}
