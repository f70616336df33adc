/*
 * test_sweep.c: the swept collider of a tick (collider/sweep.c, issue 12
 * item 2). Sub-step counts: one pose at rest and for a move of at most half
 * a cell, enough that no point moves more than half a cell between poses
 * (translation and rotation), capped at COLLIDER_SWEEP_STEPS_MAX, NaN-safe;
 * the last sub-step is the pose itself bit for bit; the depth of a sphere
 * swept 40 cells has no gap along its path; the swept bounds hold a box
 * half way through a quarter turn.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "collider/collider.h"

#define CELL 0.05

static collider_pose at(double x, double y, double z)
{
    return (collider_pose){{x, y, z}, {1, 0, 0, 0}};
}

static void test_steps(void)
{
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    CHECK(collider_sweep_steps(&ball, at(1, 1, 1), at(1, 1, 1), CELL) == 1, "at rest: one pose");
    CHECK(collider_sweep_steps(&ball, at(1, 1, 1), at(1.02, 1, 1), CELL) == 1,
          "0.4 cell: one pose");
    CHECK(collider_sweep_steps(&ball, at(1, 1, 1), at(1.03, 1, 1), CELL) == 2,
          "0.6 cell: two poses");
    CHECK(collider_sweep_steps(&ball, at(0, 0, 1), at(2, 0, 1), CELL) == 80,
          "40 cells: 80 poses, half a cell apart");
    CHECK(collider_sweep_steps(&ball, at(0, 0, 1), at(1e6, 0, 1), CELL) == COLLIDER_SWEEP_STEPS_MAX,
          "capped");
    CHECK(collider_sweep_steps(&ball, at(0, 0, 1), at(NAN, 0, 1), CELL) == 1, "NaN: one pose");
    CHECK(collider_sweep_steps(&ball, at(0, 0, 1), at(1, 0, 1), 0.0) == 1, "no cell size: one");

    /* a quarter turn of a 1 m cube in place: its corners travel reach * pi/2 */
    collider_geometry box = {.shape = COLLIDER_BOX, .half_extents = {0.5, 0.5, 0.5}};
    collider_pose a = at(1, 1, 1), b = a;
    b.orientation = quat_from_axis_angle((vec3d){0, 0, 1}, M_PI / 2);
    int n = collider_sweep_steps(&box, a, b, CELL);
    CHECK(n == (int)ceil(sqrt(0.75) * M_PI / 2 / (CELL / 2)), "rotation counted (%d)", n);
    for (int k = 1; k < n; k++) {
        vec3d c0 =
            quat_rotate(collider_sweep_pose(a, b, k - 1, n).orientation, (vec3d){.5, .5, .5});
        vec3d c1 = quat_rotate(collider_sweep_pose(a, b, k, n).orientation, (vec3d){.5, .5, .5});
        double d = sqrt((c1.x - c0.x) * (c1.x - c0.x) + (c1.y - c0.y) * (c1.y - c0.y));
        if (d > CELL / 2 + 1e-12) {
            CHECK(0, "corner moves %.4f m between sub-steps %d, %d", d, k - 1, k);
            break;
        }
    }
    vec3d lo, hi;
    collider_sweep_bounds(&box, a, b, n, &lo, &hi);
    CHECK(hi.x >= 1 + sqrt(0.5) - CELL / 2 && lo.y <= 1 - sqrt(0.5) + CELL / 2,
          "swept bounds hold the 45-degree pose to half a cell (%.3f %.3f)", hi.x, lo.y);

    collider_pose last = collider_sweep_pose(a, b, n, n);
    CHECK(memcmp(&last, &b, sizeof last) == 0, "last sub-step is the pose, bit for bit");
    collider_pose first = collider_sweep_pose(at(0, 0, 0), at(1, 2, 3), 1, 4);
    CHECK(first.position.x == 0.25 && first.position.y == 0.5 && first.position.z == 0.75,
          "positions lerped");
}

static void test_swept_depth(void)
{
    /* a small sphere (r 0.1 m, 2 cells) swept 40 cells along row 5 */
    collider_geometry ball = {.shape = COLLIDER_SPHERE, .radius = 0.1};
    world_rect win = {0, 0, 60, 10};
    collider_pose from = at(5.5 * CELL, 5.5 * CELL, 0.1), to = at(45.5 * CELL, 5.5 * CELL, 0.1);
    int32_t *one = malloc(sizeof *one * 600), *swept = malloc(sizeof *swept * 600);
    for (int i = 0; i < 600; i++)
        one[i] = swept[i] = COLLIDER_BOTTOM_NONE;
    collider_depth_cpu(&ball, to, win, CELL, 10000, one);
    int n = collider_sweep_steps(&ball, from, to, CELL);
    for (int k = 1; k <= n; k++)
        collider_depth_cpu(&ball, collider_sweep_pose(from, to, k, n), win, CELL, 10000, swept);
    int gaps = 0, pose_cells = 0;
    for (int x = 6; x <= 45; x++) {
        gaps += swept[5 * 60 + x] > 5; /* within 0.5 mm of the lowest point, 0 m */
        pose_cells += one[5 * 60 + x] != COLLIDER_BOTTOM_NONE;
    }
    CHECK(gaps == 0, "swept sphere: the path's centre line at its lowest point (%d gaps)", gaps);
    CHECK(pose_cells < 6, "one pose alone covers only its own cells (%d)", pose_cells);
    CHECK(swept[5 * 60 + 5] == COLLIDER_BOTTOM_NONE || swept[5 * 60 + 5] > 0,
          "the previous pose is not pressed again at its lowest point");
    free(one);
    free(swept);
}

/* collider_isqrt64 against the digit-by-digit loop depth_exact.comp runs */
static uint64_t isqrt_digits(uint64_t v)
{
    uint64_t r = 0, bit = (uint64_t)1 << 62;
    while (bit > v)
        bit >>= 2;
    while (bit != 0) {
        if (v >= r + bit) {
            v -= r + bit;
            r = (r >> 1) + bit;
        } else {
            r >>= 1;
        }
        bit >>= 2;
    }
    return r;
}

static void test_isqrt(void)
{
    int bad = 0;
    uint64_t x = 88172645463325252ull;
    for (int i = 0; i < 200000; i++) {
        x ^= x << 13;
        x ^= x >> 7;
        x ^= x << 17;
        uint64_t v = x >> (2 + i % 62); /* every magnitude below 2^62 */
        bad += collider_isqrt64(v) != isqrt_digits(v);
    }
    for (uint64_t k = 1; k < 3037000499ull; k = k * 3 + 1) /* squares and their neighbours */
        for (int d = -1; d <= 1; d++)
            bad += collider_isqrt64(k * k + d) != isqrt_digits(k * k + d);
    CHECK(bad == 0, "isqrt64: the C estimate equals the GLSL digit loop (%d differ)", bad);
}

int main(void)
{
    test_isqrt();
    test_steps();
    test_swept_depth();
    return check_report();
}
