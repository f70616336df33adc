/*
 * test_trade_scenes.c: the pieces `terrad bench --trade` measures with — the
 * standard scenes at several cell sizes and headings (same physical world,
 * colliders turned about its centre), the cross-section sampler (bilinear at
 * physical positions), its trail rectangle, and the model list.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "app/trade_internal.h"
#include "check.h"

static double distance_xy(vec3d a, vec3d b)
{
    return hypot(a.x - b.x, a.y - b.y);
}

static void test_models(void)
{
    sim_material m = sim_material_default();
    error_text err = {{0}};
    CHECK(trade_model_count == SIM_MODEL_COUNT, "every model is in the sweep (%d of %d)",
          trade_model_count, SIM_MODEL_COUNT);
    for (int i = 0; i < trade_model_count; i++) {
        CHECK(trade_model_index(trade_model_names[i]) == i, "index of %s", trade_model_names[i]);
        CHECK(trade_model_configure(trade_model_names[i], &m, &err) == 0, "configure %s: %s",
              trade_model_names[i], err.message);
    }
    CHECK(trade_model_configure("persson-iterative", &m, &err) == 0 &&
              m.method == SIM_METHOD_ITERATIVE,
          "persson-iterative selects the iterative method");
    CHECK(trade_model_configure("persson-multi", &m, &err) == 0 && m.method == SIM_METHOD_MULTI,
          "persson-multi selects the multi-target method");
    CHECK(trade_model_configure("sumnerish", &m, &err) != 0 && strstr(err.message, "sumnerish"),
          "an unknown model is refused by name (%s)", err.message);
    CHECK(trade_model_index("nope") == -1, "unknown model index");
    CHECK(trade_model_configure("diffusion", &m, &err) == 0 && m.model == SIM_MODEL_DIFFUSION,
          "diffusion selects the diffusion model");
}

/* Every scene: the same physical world at every cell size; a heading turns
 * the colliders about the world's centre and keeps their distances. */
static void test_scenes(void)
{
    sim_material m = sim_material_default();
    const double cells[3] = {0.1, 0.05, 0.025};
    for (int s = 0; s < trade_scene_count; s++) {
        const char *name = trade_scene_names[s];
        CHECK(trade_scene_index(name) == s && strlen(trade_scene_about(s)) > 10, "scene %s", name);
        double side_m = 0;
        for (int c = 0; c < 3; c++) {
            scene sc;
            long ticks = 0;
            trade_profile_spec p;
            error_text err = {{0}};
            CHECK(trade_scene_build(s, cells[c], 0, &m, &sc, &ticks, &p, &err) == 0, "%s: %s", name,
                  err.message);
            double side = sc.width * sc.cell_size_m;
            if (c == 0)
                side_m = side;
            CHECK(fabs(side - side_m) < 1e-9 && sc.width == sc.height,
                  "%s at %g m: a square world of the same size (%g vs %g m)", name, cells[c], side,
                  side_m);
            CHECK(fabs(sc.cell_size_m - cells[c]) < 1e-12, "%s: cell size %g", name,
                  sc.cell_size_m);
            CHECK(ticks >= 60 && sc.collider_count >= 1, "%s: %ld ticks, %d colliders", name, ticks,
                  sc.collider_count);
            CHECK(trade_profile_length(&p) > 10, "%s: profile samples", name);
            scene_free(&sc);
        }
        scene straight, turned;
        long t0 = 0, t1 = 0;
        trade_profile_spec p0, p1;
        error_text err = {{0}};
        CHECK(trade_scene_build(s, 0.05, 0, &m, &straight, &t0, &p0, &err) == 0 &&
                  trade_scene_build(s, 0.05, 30, &m, &turned, &t1, &p1, &err) == 0,
              "%s: build at 0 and 30 deg: %s", name, err.message);
        CHECK(t0 == t1 && straight.collider_count == turned.collider_count,
              "%s: same run at any heading", name);
        vec3d centre = {0.5 * straight.width * straight.cell_size_m,
                        0.5 * straight.height * straight.cell_size_m, 0};
        double worst = 0, worst_angle = 0;
        for (int c = 0; c < straight.collider_count; c++)
            for (long t = 0; t <= t0; t += t0 / 4) {
                double time_s = (double)t / 60.0;
                vec3d a = collider_motion_pose(&straight.colliders[c].motion, time_s).position;
                vec3d b = collider_motion_pose(&turned.colliders[c].motion, time_s).position;
                worst = fmax(worst, fabs(distance_xy(a, centre) - distance_xy(b, centre)));
                worst = fmax(worst, fabs(a.z - b.z));
                /* the angle between centre→a and centre→b is the heading */
                double angle =
                    atan2(b.y - centre.y, b.x - centre.x) - atan2(a.y - centre.y, a.x - centre.x);
                angle = remainder(angle, 2 * M_PI);
                if (distance_xy(a, centre) > 0.2)
                    worst_angle = fmax(worst_angle, fabs(angle - M_PI / 6));
                /* inside the world at every heading */
                CHECK(b.x > 0 && b.y > 0 && b.x < 2 * centre.x && b.y < 2 * centre.y,
                      "%s: collider %d inside the world at 30 deg", name, c);
            }
        CHECK(worst < 1e-9, "%s: turning keeps distances to the centre and heights (%g)", name,
              worst);
        CHECK(worst_angle < 1e-9, "%s: colliders turned by exactly 30 deg (%g rad off)", name,
              worst_angle);
        scene_free(&straight);
        scene_free(&turned);
    }
    scene sc;
    long ticks;
    trade_profile_spec p;
    error_text err = {{0}};
    CHECK(trade_scene_build(0, 0.0, 0, &m, &sc, &ticks, &p, &err) != 0 && err.message[0],
          "cell size 0 refused: %s", err.message);
    CHECK(trade_scene_build(0, 1e-5, 0, &m, &sc, &ticks, &p, &err) != 0 &&
              strstr(err.message, "cells a side"),
          "an absurdly fine cell refused: %s", err.message);
}

/* On a linear ramp bilinear sampling is exact, at any heading. */
static void test_profile(void)
{
    world w;
    error_text err = {{0}};
    CHECK(world_init(&w, 64, 64, 0.05, 10000, -100000, &err) == 0, "world: %s", err.message);
    /* h = 0.4 m + 0.1 x + 0.2 y (metres at cell centres) */
    static int32_t ramp[64 * 64];
    for (int y = 0; y < 64; y++)
        for (int x = 0; x < 64; x++)
            ramp[y * 64 + x] =
                (int32_t)lround((0.4 + 0.1 * (x + 0.5) * 0.05 + 0.2 * (y + 0.5) * 0.05) * 10000);
    world_scatter_window(&w, (world_rect){0, 0, 64, 64}, ramp);
    trade_profile_spec p = {.stations = {0.3, 0.7},
                            .station_count = 2,
                            .across_lo_m = -0.5,
                            .across_hi_m = 0.5,
                            .step_m = 0.01,
                            .origin_x = 1.2,
                            .origin_y = 1.4,
                            .cos_heading = cos(M_PI / 6),
                            .sin_heading = sin(M_PI / 6),
                            .base_m = 0.4};
    int n = trade_profile_length(&p);
    CHECK(n == 2 * 101, "two lines of 101 samples (%d)", n);
    double *got = malloc((size_t)n * sizeof *got);
    trade_profile_sample(&p, &w, got);
    double worst = 0;
    for (int st = 0, k = 0; st < 2; st++)
        for (int i = 0; i < 101; i++, k++) {
            double along = p.stations[st], across = -0.5 + 0.01 * i;
            double x = 1.2 + p.cos_heading * along - p.sin_heading * across;
            double y = 1.4 + p.sin_heading * along + p.cos_heading * across;
            worst = fmax(worst, fabs(got[k] - (0.1 * x + 0.2 * y)));
        }
    CHECK(worst < 1e-4, "bilinear on a ramp is exact to the unit (%g m)", worst);
    world_rect r = trade_profile_rect(&p, &w);
    CHECK(r.w > 0 && r.h > 0 && r.x >= 0 && r.y >= 0 && r.x + r.w <= 64 && r.y + r.h <= 64,
          "trail rectangle inside the world");
    double line_ends[4][2] = {{0.3, -0.5}, {0.3, 0.5}, {0.7, -0.5}, {0.7, 0.5}};
    for (int k = 0; k < 4; k++) {
        double x = 1.2 + p.cos_heading * line_ends[k][0] - p.sin_heading * line_ends[k][1];
        double y = 1.4 + p.sin_heading * line_ends[k][0] + p.cos_heading * line_ends[k][1];
        int cx = (int)floor(x / 0.05), cy = (int)floor(y / 0.05);
        CHECK(cx >= r.x && cx < r.x + r.w && cy >= r.y && cy < r.y + r.h,
              "sample end %d in the trail rectangle", k);
    }
    double a[3] = {1, 2, 3}, b[3] = {1, 2, 7};
    CHECK(fabs(trade_rms_difference(a, b, 3) - sqrt(16.0 / 3)) < 1e-12, "rms");
    CHECK(trade_rms_difference(a, a, 3) == 0 && trade_rms_difference(a, b, 0) == 0, "rms 0");
    free(got);
    world_free(&w);
}

int main(void)
{
    test_models();
    test_scenes();
    test_profile();
    return check_report();
}
