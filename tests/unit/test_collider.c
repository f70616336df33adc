/*
 * test_collider.c: the colliders' checks, quaternions, bounds, scripted
 * motion, OBJ loading and — above all — the CPU twin's depth stage against
 * closed-form answers: a sphere at its centre and rim, a box at 45 degrees,
 * a wheel lying on its side, a standing cylinder (lines parallel to the
 * axis), a capsule's hemispheres, and the primitives tessellated into meshes
 * (tests/support/tessellate.c), whose depth must stay within millimetres above
 * the analytic bottom; and the mesh rule's instances against the rule
 * evaluated the long way at every cell.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "collider/collider.h"
#include "check.h"
#include "tessellate.h"

#define UPM 10000
#define NONE COLLIDER_BOTTOM_NONE

static int has(const error_text *e, const char *needle)
{
    return strstr(e->message, needle) != NULL;
}

static int near(double a, double b, double eps)
{
    return fabs(a - b) <= eps;
}

static int32_t units(double z)
{
    return (int32_t)floor(z * UPM);
}

static int32_t *bottom_new(world_rect r)
{
    int32_t *b = malloc(sizeof *b * (size_t)r.w * r.h);
    for (int i = 0; i < r.w * r.h; i++)
        b[i] = NONE;
    return b;
}

static collider_pose pose_at(double x, double y, double z, quatd q)
{
    collider_pose p = {{x, y, z}, q};
    return p;
}

static const quatd identity = {1, 0, 0, 0};

static void test_validate(void)
{
    error_text e = {{0}};
    collider_geometry g = {.shape = COLLIDER_SPHERE, .radius = NAN};
    CHECK(collider_geometry_validate(&g, &e) != 0 &&
              strcmp(e.message, "radius: must be a finite number > 0 and <= 1000 m (got nan)") == 0,
          "NaN radius: %s", e.message);
    g.radius = -1;
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "radius"), "negative radius: %s",
          e.message);
    g.radius = 0;
    CHECK(collider_geometry_validate(&g, &e) != 0, "zero radius refused");
    g.radius = INFINITY;
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "inf"), "infinite radius: %s",
          e.message);
    g.radius = 1000.5;
    CHECK(collider_geometry_validate(&g, &e) != 0, "radius > 1000 m refused");
    g.radius = 0.3;
    CHECK(collider_geometry_validate(&g, &e) == 0, "sphere 0.3 m accepted");
    g = (collider_geometry){.shape = COLLIDER_CYLINDER, .radius = 0.3, .half_length = 0};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "half_length"),
          "flat cylinder refused: %s", e.message);
    g.shape = COLLIDER_CAPSULE;
    CHECK(collider_geometry_validate(&g, &e) == 0, "capsule of length 0 (a sphere) accepted");
    g.half_length = NAN;
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "half_length"),
          "NaN half_length refused: %s", e.message);
    /* grousers (lugs.c): a wheel's only, no taller or thicker than the rim's radius */
    g = (collider_geometry){.shape = COLLIDER_CYLINDER,
                            .radius = 0.15,
                            .half_length = 0.08,
                            .grousers = {30, 0.01, 0.004}};
    CHECK(collider_geometry_validate(&g, &e) == 0, "lugged wheel accepted: %s", e.message);
    g.grousers.height = 0.2;
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers.height"),
          "lug taller than the radius refused: %s", e.message);
    g.grousers = (collider_grousers){30, 0.01, NAN};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers.thickness"),
          "NaN lug thickness refused: %s", e.message);
    /* COLLIDERS carries them as f32 > 0: one that rounds to 0 there is refused */
    g.grousers = (collider_grousers){30, 1e-46, 0.004};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers.height: 1e-46 m"),
          "a lug height f32 cannot carry refused: %s", e.message);
    g.grousers = (collider_grousers){30, 0.01, 1e-300};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers.thickness: 1e-300 m"),
          "a lug thickness f32 cannot carry refused: %s", e.message);
    g.grousers = (collider_grousers){30, 1e-44, 1e-44};
    CHECK(collider_geometry_validate(&g, &e) == 0, "the least f32 sizes accepted: %s", e.message);
    g.grousers = (collider_grousers){COLLIDER_GROUSERS_MAX + 1, 0.01, 0.004};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers.count"),
          "too many lugs refused: %s", e.message);
    g = (collider_geometry){.shape = COLLIDER_SPHERE, .radius = 0.3, .grousers = {4, 0.01, 0.01}};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "grousers: only a wheel"),
          "lugs on a sphere refused: %s", e.message);
    g = (collider_geometry){.shape = COLLIDER_BOX, .half_extents = {1, 0, 1}};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "half_extents[1]"),
          "zero box side refused: %s", e.message);
    g = (collider_geometry){.shape = COLLIDER_MESH};
    CHECK(collider_geometry_validate(&g, &e) != 0 && has(&e, "mesh"), "mesh without triangles: %s",
          e.message);

    collider_pose p = pose_at(1, 2, 3, identity);
    CHECK(collider_pose_validate(&p, &e) == 0, "ordinary pose accepted");
    p.position.y = INFINITY;
    CHECK(collider_pose_validate(&p, &e) != 0 && has(&e, "position[1]"), "infinite y: %s",
          e.message);
    p.position.y = 2e6;
    CHECK(collider_pose_validate(&p, &e) != 0 && has(&e, "position[1]"), "y beyond 1e6 m refused");
    p.position.y = 0;
    p.orientation = (quatd){0, 0, 0, 0};
    CHECK(collider_pose_validate(&p, &e) != 0 && has(&e, "orientation"), "zero quaternion: %s",
          e.message);
    p.orientation = (quatd){NAN, 0, 0, 1};
    CHECK(collider_pose_validate(&p, &e) != 0 && has(&e, "orientation[0]"), "NaN quaternion: %s",
          e.message);
    p.orientation = (quatd){2, 0, 0, 0};
    CHECK(collider_pose_validate(&p, &e) == 0,
          "unnormalised quaternion accepted (normalised later)");
}

static void test_quaternions(void)
{
    quatd q = quat_from_axis_angle((vec3d){0, 0, 2}, M_PI / 2);
    vec3d v = quat_rotate(q, (vec3d){1, 0, 0});
    CHECK(near(v.x, 0, 1e-12) && near(v.y, 1, 1e-12) && near(v.z, 0, 1e-12),
          "90 deg about z takes x to y (unnormalised axis)");
    quatd qq = quat_multiply(q, q);
    v = quat_rotate(qq, (vec3d){1, 0, 0});
    CHECK(near(v.x, -1, 1e-12) && near(v.y, 0, 1e-12), "q*q is 180 deg");
    quatd a = quat_from_axis_angle((vec3d){1, 0, 0}, M_PI / 2);
    v = quat_rotate(quat_multiply(a, q), (vec3d){1, 0, 0}); /* q first, then a */
    CHECK(near(v.x, 0, 1e-12) && near(v.y, 0, 1e-12) && near(v.z, 1, 1e-12),
          "multiply composes right to left");
    quatd n = quat_normalize((quatd){2, 0, 0, 0});
    CHECK(n.w == 1 && n.x == 0, "normalise");
    /* the wire's capsule axis is z, the engine's y: the wire's identity points it along z */
    v = quat_rotate(collider_wire_orientation((quatd){2, 0, 0, 0}, 1), (vec3d){0, 1, 0});
    CHECK(near(v.x, 0, 1e-12) && near(v.y, 0, 1e-12) && near(v.z, 1, 1e-12),
          "collider_wire_orientation turns an axis-z shape's y axis to the wire's z");
    n = collider_wire_orientation((quatd){0, 0, 0, 3}, 0);
    CHECK(n.w == 0 && n.z == 1, "collider_wire_orientation only normalises other shapes");
    n = quat_normalize((quatd){0, 0, 0, 0});
    CHECK(n.w == 1, "normalising zero gives the identity, not NaN");
    quatd h = quat_slerp(identity, q, 0.5);
    v = quat_rotate(h, (vec3d){1, 0, 0});
    CHECK(near(v.x, sqrt(0.5), 1e-12) && near(v.y, sqrt(0.5), 1e-12), "slerp halfway is 45 deg");
    quatd neg = {-q.w, -q.x, -q.y, -q.z};
    h = quat_slerp(identity, neg, 0.5);
    v = quat_rotate(h, (vec3d){1, 0, 0});
    CHECK(near(v.x, sqrt(0.5), 1e-12) && near(v.y, sqrt(0.5), 1e-12),
          "slerp takes the short way when the quaternions' signs differ");
    h = quat_slerp(q, q, 0.3);
    CHECK(near(h.w, q.w, 1e-12) && near(h.z, q.z, 1e-12), "slerp of equal quaternions");
    v = quat_rotate(quat_from_axis_angle((vec3d){0, 0, 0}, 1.0), (vec3d){1, 2, 3});
    CHECK(v.x == 1 && v.y == 2 && v.z == 3, "zero axis means no rotation");
}

/* Bounds against brute force: sample the surface densely. */
static void sampled_bounds(const collider_geometry *g, collider_pose p, vec3d *lo, vec3d *hi)
{
    quatd q = quat_normalize(p.orientation);
    *lo = (vec3d){INFINITY, INFINITY, INFINITY};
    *hi = (vec3d){-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i <= 200; i++)
        for (int j = 0; j < 400; j++) {
            double th = M_PI * i / 200, ph = 2 * M_PI * j / 400;
            vec3d s = {sin(th) * cos(ph), cos(th), sin(th) * sin(ph)}; /* pole on local Y */
            vec3d l;
            if (g->shape == COLLIDER_BOX) { /* the corners, whatever i and j */
                int c = (i * 400 + j) & 7;
                l = (vec3d){(c & 1) ? g->half_extents.x : -g->half_extents.x,
                            (c & 2) ? g->half_extents.y : -g->half_extents.y,
                            (c & 4) ? g->half_extents.z : -g->half_extents.z};
            } else if (g->shape == COLLIDER_CAPSULE) {
                l = (vec3d){g->radius * s.x, g->radius * s.y + (s.y >= 0 ? 1 : -1) * g->half_length,
                            g->radius * s.z};
            } else { /* cylinder: rim circles */
                l = (vec3d){g->radius * cos(ph), (i < 100 ? 1 : -1) * g->half_length,
                            g->radius * sin(ph)};
            }
            vec3d w = quat_rotate(q, l);
            w = (vec3d){w.x + p.position.x, w.y + p.position.y, w.z + p.position.z};
            lo->x = fmin(lo->x, w.x), lo->y = fmin(lo->y, w.y), lo->z = fmin(lo->z, w.z);
            hi->x = fmax(hi->x, w.x), hi->y = fmax(hi->y, w.y), hi->z = fmax(hi->z, w.z);
        }
}

static void test_bounds(void)
{
    vec3d lo, hi;
    collider_geometry s = {.shape = COLLIDER_SPHERE, .radius = 0.5};
    collider_bounds(&s, pose_at(1, 2, 3, quat_from_axis_angle((vec3d){1, 1, 0}, 1)), &lo, &hi);
    CHECK(near(lo.x, 0.5, 1e-12) && near(hi.z, 3.5, 1e-12), "sphere bounds ignore rotation");
    collider_geometry b = {.shape = COLLIDER_BOX, .half_extents = {0.5, 0.5, 0.25}};
    collider_bounds(&b, pose_at(0, 0, 0, quat_from_axis_angle((vec3d){0, 0, 1}, M_PI / 4)), &lo,
                    &hi);
    CHECK(near(hi.x, sqrt(0.5), 1e-12) && near(hi.y, sqrt(0.5), 1e-12) && near(hi.z, 0.25, 1e-12),
          "box at 45 deg: half-diagonal in x and y");
    collider_geometry w = {.shape = COLLIDER_CYLINDER, .radius = 0.33, .half_length = 0.1};
    collider_bounds(&w, pose_at(0, 0, 0, identity), &lo, &hi);
    CHECK(near(hi.x, 0.33, 1e-12) && near(hi.y, 0.1, 1e-12) && near(lo.z, -0.33, 1e-12),
          "wheel bounds: r in x and z, half_length in y");
    collider_bounds(&w, pose_at(0, 0, 0, quat_from_axis_angle((vec3d){1, 0, 0}, M_PI / 2)), &lo,
                    &hi);
    CHECK(near(hi.x, 0.33, 1e-12) && near(hi.y, 0.33, 1e-12) && near(hi.z, 0.1, 1e-12),
          "standing cylinder bounds");

    quatd odd = quat_normalize((quatd){0.9, 0.3, -0.2, 0.4});
    collider_geometry shapes[3] = {
        {.shape = COLLIDER_BOX, .half_extents = {0.4, 0.1, 0.7}},
        {.shape = COLLIDER_CYLINDER, .radius = 0.33, .half_length = 0.2},
        {.shape = COLLIDER_CAPSULE, .radius = 0.1, .half_length = 0.5},
    };
    const char *names[3] = {"box", "cylinder", "capsule"};
    for (int k = 0; k < 3; k++) {
        vec3d slo, shi;
        collider_pose p = pose_at(5, -3, 1, odd);
        collider_bounds(&shapes[k], p, &lo, &hi);
        sampled_bounds(&shapes[k], p, &slo, &shi);
        int contains = lo.x <= slo.x + 1e-12 && lo.y <= slo.y + 1e-12 && lo.z <= slo.z + 1e-12 &&
                       hi.x >= shi.x - 1e-12 && hi.y >= shi.y - 1e-12 && hi.z >= shi.z - 1e-12;
        int tight = near(lo.x, slo.x, 2e-3) && near(lo.y, slo.y, 2e-3) && near(lo.z, slo.z, 2e-3) &&
                    near(hi.x, shi.x, 2e-3) && near(hi.y, shi.y, 2e-3) && near(hi.z, shi.z, 2e-3);
        CHECK(contains && tight, "%s bounds under an odd rotation are exact (contain and touch)",
              names[k]);
    }
}

static void test_depth_sphere(void)
{
    const double cell = 0.05;
    world_rect win = {0, 0, 40, 40};
    collider_geometry g = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    /* centre exactly over the centre of cell (20, 20) */
    double cx = 20.5 * cell, cy = 20.5 * cell, cz = 0.55;
    int32_t *b = bottom_new(win);
    collider_depth_cpu(&g, pose_at(cx, cy, cz, identity), win, cell, UPM, b);
    CHECK(b[20 * 40 + 20] == units(cz - 0.3), "sphere at its centre: z - r (%d)", b[20 * 40 + 20]);
    /* the fixed-point rule (depth_fixed.c): floor of the lowest 1/65536-unit
     * height inside, which is the closed form's floor */
    int ok = 1, covered = 0, off_by_one = 0;
    for (int y = 0; y < 40; y++)
        for (int x = 0; x < 40; x++) {
            double dx = (x + 0.5) * cell - cx, dy = (y + 0.5) * cell - cy, d2 = dx * dx + dy * dy;
            int32_t expect = d2 <= 0.09 ? units(cz - sqrt(0.09 - d2)) : NONE;
            int32_t got = b[y * 40 + x];
            if (got != expect) {
                /* where the exact answer is an integer (the rim at d = r, or
                 * (24, 24) at d² = 0.08), double rounding in the closed form
                 * falls on either side; the integer rule gives the exact one */
                double exact = (cz - sqrt(fmax(0.0, 0.09 - d2))) * UPM;
                ok &= fabs(exact - nearbyint(exact)) < 1e-6 && got == (int32_t)nearbyint(exact);
                off_by_one++;
            }
            covered += got != NONE;
        }
    CHECK(ok,
          "sphere: every cell matches z - sqrt(r^2 - d^2), rim included (%d cells, %d a unit "
          "above an integer-close exact value)",
          covered, off_by_one);
    /* near the rim: cell (25, 20) is 0.25 m from the centre, where the surface is steep */
    CHECK(b[20 * 40 + 25] == units(cz - sqrt(0.09 - 0.0625)), "sphere near the rim (%d vs %d)",
          b[20 * 40 + 25], units(cz - sqrt(0.09 - 0.0625)));
    CHECK(b[20 * 40 + 27] == NONE, "outside the rim: untouched");
    /* min with what is already there */
    for (int i = 0; i < 1600; i++)
        b[i] = 5000;
    collider_depth_cpu(&g, pose_at(cx, cy, cz, identity), win, cell, UPM, b);
    CHECK(b[20 * 40 + 20] == 2500 && b[0] == 5000 && b[20 * 40 + 26] == 5000,
          "bottom keeps the minimum of what was there and the collider");
    free(b);

    /* a window elsewhere: indices are window-local, nothing outside is written */
    world_rect off = {18, 17, 5, 4};
    int32_t guard[5 * 4 + 8];
    for (int i = 0; i < 28; i++)
        guard[i] = NONE;
    collider_depth_cpu(&g, pose_at(cx, cy, cz, identity), off, cell, UPM, guard);
    CHECK(guard[(20 - 17) * 5 + (20 - 18)] == units(cz - 0.3), "window-local indexing");
    int untouched = 1;
    for (int i = 20; i < 28; i++)
        untouched &= guard[i] == NONE;
    CHECK(untouched, "nothing written past the window");

    /* clamping of absurd heights */
    world_rect one = {0, 0, 1, 1};
    int32_t v = NONE;
    collider_depth_cpu(&g, pose_at(0.025, 0.025, -1e6, identity), one, cell, UPM, &v);
    CHECK(v == WORLD_HEIGHT_MIN - 1, "far below: clamped to WORLD_HEIGHT_MIN - 1");
    v = NONE;
    collider_depth_cpu(&g, pose_at(0.025, 0.025, 1e6, identity), one, cell, UPM, &v);
    CHECK(v == WORLD_HEIGHT_MAX + 1, "far above: clamped to WORLD_HEIGHT_MAX + 1");
}

static void test_depth_box(void)
{
    const double cell = 0.05;
    world_rect win = {0, 0, 128, 128};
    collider_geometry g = {.shape = COLLIDER_BOX, .half_extents = {0.5, 0.5, 0.25}};
    quatd q = quat_from_axis_angle((vec3d){0, 0, 1}, M_PI / 4);
    double px = 3.2, py = 3.2, pz = 0.5;
    int32_t *b = bottom_new(win);
    collider_depth_cpu(&g, pose_at(px, py, pz, q), win, cell, UPM, b);
    int ok = 1, covered = 0;
    for (int y = 0; y < 128; y++)
        for (int x = 0; x < 128; x++) {
            double dx = (x + 0.5) * cell - px, dy = (y + 0.5) * cell - py;
            double u = (dx + dy) * sqrt(0.5), v = (dy - dx) * sqrt(0.5); /* box frame */
            int inside = fabs(u) <= 0.5 + 1e-9 && fabs(v) <= 0.5 + 1e-9;
            int strictly = fabs(u) < 0.5 - 1e-9 && fabs(v) < 0.5 - 1e-9;
            int32_t got = b[y * 128 + x];
            if (strictly)
                ok &= got == units(0.25);
            else if (!inside)
                ok &= got == NONE;
            covered += got != NONE;
        }
    CHECK(ok, "box at 45 deg: flat bottom at z - h inside the diamond, nothing outside");
    CHECK(abs(covered - 400) <= 40, "box at 45 deg covers about 1 m^2 / cell^2 = 400 cells (%d)",
          covered);

    /* a box tilted 30 deg about y: the vertical through its centre meets the
     * bottom face h_z / cos 30 below the centre */
    free(b);
    b = bottom_new(win);
    quatd tilt = quat_from_axis_angle((vec3d){0, 1, 0}, M_PI / 6);
    double cx = 64.5 * cell, cy = 64.5 * cell;
    collider_depth_cpu(&g, pose_at(cx, cy, pz, tilt), win, cell, UPM, b);
    CHECK(abs(b[64 * 128 + 64] - units(pz - 0.25 / cos(M_PI / 6))) <= 1,
          "tilted box: bottom face along the vertical (%d vs %d)", b[64 * 128 + 64],
          units(pz - 0.25 / cos(M_PI / 6)));
    /* axis-aligned box: lines parallel to four faces, no NaN anywhere; a
     * quarter-cell offset keeps the faces off the cell centres */
    free(b);
    b = bottom_new(win);
    collider_depth_cpu(&g, pose_at(64.25 * cell, 64.25 * cell, pz, identity), win, cell, UPM, b);
    int sane = 1;
    covered = 0;
    for (int i = 0; i < 128 * 128; i++) {
        sane &= b[i] == NONE || abs(b[i] - units(0.25)) <= 1;
        covered += b[i] != NONE;
    }
    CHECK(sane && covered == 20 * 20, "axis-aligned box: 20 x 20 cells at z - h (%d)", covered);
    free(b);
}

static void test_depth_cylinder_capsule(void)
{
    const double cell = 0.05;
    world_rect win = {0, 0, 64, 64};
    collider_geometry wheel = {.shape = COLLIDER_CYLINDER, .radius = 0.33, .half_length = 0.1};
    double px = 1.6, py = 1.6, pz = 0.65;
    int32_t *b = bottom_new(win);
    /* spun about its own axis: the shape is the same */
    collider_depth_cpu(&wheel, pose_at(px, py, pz, quat_from_axis_angle((vec3d){0, 1, 0}, 0.7)),
                       win, cell, UPM, b);
    int ok = 1, covered = 0;
    for (int y = 0; y < 64; y++)
        for (int x = 0; x < 64; x++) {
            double dx = (x + 0.5) * cell - px, dy = (y + 0.5) * cell - py;
            int32_t expect = NONE;
            if (fabs(dy) <= 0.1 && fabs(dx) <= 0.33)
                expect = units(pz - sqrt(0.33 * 0.33 - dx * dx));
            if (fabs(fabs(dy) - 0.1) < 1e-9 || fabs(fabs(dx) - 0.33) < 1e-9)
                continue; /* exactly on an edge: either answer is right */
            ok &= b[y * 64 + x] == expect || abs(b[y * 64 + x] - expect) <= 1;
            covered += b[y * 64 + x] != NONE;
        }
    CHECK(ok, "wheel lying on its side: z - sqrt(r^2 - dx^2) under the tread (%d cells)", covered);
    CHECK(b[32 * 64 + 31] <= units(pz - 0.33) + 10, "wheel bottom near z - r");
    free(b);

    /* standing cylinder: the vertical is parallel to the axis */
    b = bottom_new(win);
    quatd up = quat_from_axis_angle((vec3d){1, 0, 0}, M_PI / 2);
    collider_depth_cpu(&wheel, pose_at(px, py, pz, up), win, cell, UPM, b);
    int flat = 1;
    covered = 0;
    for (int i = 0; i < 64 * 64; i++) {
        flat &= b[i] == NONE || abs(b[i] - units(pz - 0.1)) <= 1;
        covered += b[i] != NONE;
    }
    CHECK(flat && abs(covered - (int)(M_PI * 0.33 * 0.33 / (cell * cell))) < 20,
          "standing cylinder: flat cap at z - L over a disc (%d cells)", covered);
    free(b);

    /* tilted wheel (camber 20 deg about x): compare with a brute-force march */
    b = bottom_new(win);
    quatd camber = quat_from_axis_angle((vec3d){1, 0, 0}, 20 * M_PI / 180);
    collider_depth_cpu(&wheel, pose_at(px, py, pz, camber), win, cell, UPM, b);
    quatd inv = {camber.w, -camber.x, -camber.y, -camber.z};
    int worst = 0;
    for (int y = 20; y < 44; y++)
        for (int x = 20; x < 44; x++) {
            double lowest = INFINITY;
            for (double z = pz - 0.5; z < pz + 0.5; z += 2e-5) {
                vec3d l =
                    quat_rotate(inv, (vec3d){(x + 0.5) * cell - px, (y + 0.5) * cell - py, z - pz});
                if (l.x * l.x + l.z * l.z <= 0.33 * 0.33 && fabs(l.y) <= 0.1) {
                    lowest = z;
                    break;
                }
            }
            int32_t expect = isinf(lowest) ? NONE : units(lowest);
            int32_t got = b[y * 64 + x];
            if ((expect == NONE) != (got == NONE))
                worst = 1 << 30;
            else if (expect != NONE && abs(got - expect) > worst)
                worst = abs(got - expect);
        }
    CHECK(worst <= 1, "cambered wheel matches a brute-force march (worst %d units)", worst);
    free(b);

    /* capsule lying along y: hemispheres at the ends */
    collider_geometry cap = {.shape = COLLIDER_CAPSULE, .radius = 0.1, .half_length = 0.2};
    double cx = 32.5 * cell, cy = 32.5 * cell;
    b = bottom_new(win);
    collider_depth_cpu(&cap, pose_at(cx, cy, pz, identity), win, cell, UPM, b);
    ok = 1;
    for (int y = 0; y < 64; y++)
        for (int x = 0; x < 64; x++) {
            double dx = (x + 0.5) * cell - cx, dy = (y + 0.5) * cell - cy;
            double ay = fabs(dy) > 0.2 ? fabs(dy) - 0.2 : 0.0;
            double d2 = dx * dx + ay * ay;
            int32_t expect = d2 <= 0.01 ? units(pz - sqrt(0.01 - d2)) : NONE;
            if (fabs(d2 - 0.01) < 1e-9)
                continue;
            ok &= abs(b[y * 64 + x] - expect) <= 1 || b[y * 64 + x] == expect;
        }
    CHECK(ok, "capsule: cylinder body and hemispherical ends");
    CHECK(b[(32 + 5) * 64 + 32] == units(pz - sqrt(0.01 - 0.05 * 0.05)),
          "capsule end cap at 0.25 m along the axis: inside the hemisphere");
    free(b);
}

/* Depth of a tessellated shape (the mesh rule) against the analytic one. */
static void compare_tessellated(const char *name, collider_geometry g, collider_pose p,
                                int32_t max_above)
{
    const double cell = 0.02;
    world_rect win = {0, 0, 100, 100};
    collider_mesh m = {0};
    int ic = 0;
    CHECK(collider_tessellate(&g, &m.vertices, &m.vertex_count, &m.indices, &ic) == 0 &&
              ic % 3 == 0,
          "%s tessellates (%d vertices, %d triangles)", name, m.vertex_count, ic / 3);
    m.triangle_count = ic / 3;
    collider_geometry mg = {.shape = COLLIDER_MESH, .mesh = &m};
    int32_t *ba = bottom_new(win), *bm = bottom_new(win);
    collider_depth_cpu(&g, p, win, cell, UPM, ba);
    collider_depth_cpu(&mg, p, win, cell, UPM, bm);
    int32_t lowest = NONE;
    for (int i = 0; i < 100 * 100; i++)
        lowest = ba[i] < lowest ? ba[i] : lowest;
    /* Where the surface turns vertical (the silhouette) a sub-millimetre
     * horizontal error of the polygon becomes centimetres of height, for any
     * tessellation; what matters is the part that presses into the snow, so
     * the bound is checked over the lowest 10 cm and the rest only for sign. */
    int below = 0, worst = 0, worst_all = 0, only_analytic = 0, only_mesh = 0, both = 0;
    for (int i = 0; i < 100 * 100; i++) {
        if (ba[i] != NONE && bm[i] != NONE) {
            both++;
            if (bm[i] < ba[i] - 1)
                below++;
            if (ba[i] <= lowest + 1000 && bm[i] - ba[i] > worst)
                worst = bm[i] - ba[i];
            if (bm[i] - ba[i] > worst_all)
                worst_all = bm[i] - ba[i];
        } else if (ba[i] != NONE) {
            only_analytic++;
        } else if (bm[i] != NONE) {
            only_mesh++;
        }
    }
    CHECK(below == 0, "%s: raster never below the analytic bottom (%d cells below)", name, below);
    CHECK(worst <= max_above,
          "%s: raster within %.1f mm above over the lowest 10 cm (worst %.1f mm; %.1f mm at the "
          "silhouette; %d cells)",
          name, max_above / 10.0, worst / 10.0, worst_all / 10.0, both);
    CHECK(only_mesh == 0 && only_analytic <= both / 20,
          "%s: same footprint but for the rim (%d only analytic, %d only mesh)", name,
          only_analytic, only_mesh);
    free(ba);
    free(bm);
    free(m.vertices);
    free(m.indices);
}

static void test_tessellation(void)
{
    collider_geometry wheel = {.shape = COLLIDER_CYLINDER, .radius = 0.33, .half_length = 0.1};
    compare_tessellated("wheel", wheel, pose_at(1.0037, 0.9981, 0.65, identity), 50);
    compare_tessellated("wheel rolled and steered", wheel,
                        pose_at(1.0037, 0.9981, 0.65,
                                quat_multiply(quat_from_axis_angle((vec3d){0, 0, 1}, 0.5),
                                              quat_from_axis_angle((vec3d){0, 1, 0}, 0.3))),
                        50);
    collider_geometry sphere = {.shape = COLLIDER_SPHERE, .radius = 0.33};
    compare_tessellated("sphere", sphere, pose_at(1.0037, 0.9981, 0.5, identity), 50);
    collider_geometry cap = {.shape = COLLIDER_CAPSULE, .radius = 0.15, .half_length = 0.25};
    compare_tessellated("capsule", cap,
                        pose_at(1.0037, 0.9981, 0.5, quat_from_axis_angle((vec3d){0, 0, 1}, 0.8)),
                        50);
    collider_geometry box = {.shape = COLLIDER_BOX, .half_extents = {0.3, 0.2, 0.1}};
    compare_tessellated(
        "box", box, pose_at(1.0037, 0.9981, 0.5, quat_from_axis_angle((vec3d){1, 1, 0}, 0.4)), 1);

    float *v;
    uint32_t *idx;
    int vc, ic;
    collider_tessellate(&sphere, &v, &vc, &idx, &ic);
    int on_surface = 1;
    for (int i = 0; i < vc; i++) {
        double r = sqrt((double)v[3 * i] * v[3 * i] + (double)v[3 * i + 1] * v[3 * i + 1] +
                        (double)v[3 * i + 2] * v[3 * i + 2]);
        on_surface &= near(r, 0.33, 1e-6);
    }
    CHECK(on_surface && ic / 3 == 2 * 48 * 23, "UV sphere 48 x 24, vertices on the surface (%d)",
          ic / 3);
    free(v);
    free(idx);
    collider_tessellate(&box, &v, &vc, &idx, &ic);
    CHECK(vc == 8 && ic == 36, "box: 8 vertices, 12 triangles");
    free(v);
    free(idx);
}

/* The mesh rule the long way, from its definition (depth_fixed.c): vertices
 * rotated in double and rounded once to 1/2^S units, every triangle tested
 * at every cell centre of the window (inclusive edges, zero plan area hits
 * nothing), the plane's height floored, the lowest kept. */
static int64_t ref_floor_div(int64_t a, int64_t b)
{
    return a >= 0 ? a / b : -((-a + b - 1) / b);
}

static void mesh_depth_reference(const collider_mesh *m, collider_pose p, world_rect win,
                                 double cell, int32_t *bottom)
{
    int64_t *fv = malloc(sizeof *fv * 3 * (size_t)m->vertex_count);
    vec3d *wv = malloc(sizeof *wv * (size_t)m->vertex_count);
    quatd q = quat_normalize(p.orientation);
    for (int i = 0; i < m->vertex_count; i++) {
        const float *v = m->vertices + 3 * i;
        vec3d r = quat_rotate(q, (vec3d){v[0], v[1], v[2]});
        wv[i] = (vec3d){r.x + p.position.x, r.y + p.position.y, r.z + p.position.z};
    }
    double ext = 0;
    for (int k = 0; k < 3 * m->triangle_count; k++) {
        vec3d a = wv[m->indices[k]], b = wv[m->indices[k - k % 3 + (k + 1) % 3]];
        ext = fmax(ext, fmax(fabs(a.x - b.x), fmax(fabs(a.y - b.y), fabs(a.z - b.z))));
    }
    ext = (ext + 2 * cell) * UPM;
    int s = 16;
    while (s > 0 && ext * ldexp(1.0, s) >= ldexp(1.0, 19))
        s--;
    for (int i = 0; i < m->vertex_count; i++) {
        fv[3 * i] = (int64_t)nearbyint(wv[i].x * UPM * ldexp(1.0, s));
        fv[3 * i + 1] = (int64_t)nearbyint(wv[i].y * UPM * ldexp(1.0, s));
        fv[3 * i + 2] = (int64_t)nearbyint(wv[i].z * UPM * ldexp(1.0, s));
    }
    int64_t step = (int64_t)nearbyint(cell * UPM * ldexp(1.0, s));
    for (int y = 0; y < win.h; y++)
        for (int x = 0; x < win.w; x++) {
            int64_t px = (int64_t)(win.x + x) * step + step / 2;
            int64_t py = (int64_t)(win.y + y) * step + step / 2;
            for (int k = 0; k < m->triangle_count; k++) {
                const int64_t *a = fv + 3 * m->indices[3 * k], *b = fv + 3 * m->indices[3 * k + 1],
                              *c = fv + 3 * m->indices[3 * k + 2];
                int64_t e0 = (c[0] - b[0]) * (py - b[1]) - (c[1] - b[1]) * (px - b[0]);
                int64_t e1 = (a[0] - c[0]) * (py - c[1]) - (a[1] - c[1]) * (px - c[0]);
                int64_t e2 = (b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0]);
                int64_t area = e0 + e1 + e2, sg = area < 0 ? -1 : 1;
                if (area == 0 || sg * e0 < 0 || sg * e1 < 0 || sg * e2 < 0)
                    continue;
                int64_t z =
                    a[2] + ref_floor_div(sg * (e1 * (b[2] - a[2]) + e2 * (c[2] - a[2])), sg * area);
                int64_t u = ref_floor_div(z, (int64_t)1 << s);
                if (u < bottom[y * win.w + x])
                    bottom[y * win.w + x] = (int32_t)u;
            }
        }
    free(fv);
    free(wv);
}

/* Issue 20, item 3: the mesh's instances visit only the cells of a
 * triangle's bounding box on the fixed grid, and a triangle with none (or no
 * plan area) makes none. A bumpy sheet of triangles a quarter of a cell wide,
 * with vertical fins, tilted and off the grid: the same bottoms as the rule
 * the long way, and far fewer instances than triangles. */
static void test_mesh_exact_spans(void)
{
    enum { N = 80, FINS = 40 };
    collider_mesh m = {0};
    m.vertex_count = N * N + 4 * FINS;
    m.triangle_count = 2 * (N - 1) * (N - 1) + 2 * FINS;
    m.vertices = malloc(sizeof *m.vertices * 3 * (size_t)m.vertex_count);
    m.indices = malloc(sizeof *m.indices * 3 * (size_t)m.triangle_count);
    int t = 0;
    for (int j = 0; j < N; j++)
        for (int i = 0; i < N; i++) {
            float *v = m.vertices + 3 * (j * N + i);
            v[0] = (float)(i * 0.0125 - 0.5 + 0.003 * sin(7.0 * j));
            v[1] = (float)(j * 0.0125 - 0.5);
            v[2] = (float)(0.05 * sin(9.0 * i / N) * cos(5.0 * j / N));
            if (i && j) {
                uint32_t a = (uint32_t)((j - 1) * N + i - 1), b = a + 1, c = a + N, d = c + 1;
                uint32_t tri[6] = {a, b, d, a, d, c};
                memcpy(m.indices + 3 * t, tri, sizeof tri);
                t += 2;
            }
        }
    for (int f = 0; f < FINS; f++) { /* vertical quads: no plan area */
        uint32_t base = (uint32_t)(N * N + 4 * f);
        float x = (float)(-0.45 + 0.0223 * f), y = (float)(-0.4 + 0.017 * f);
        float q[12] = {x, y, -0.2f, x + 0.03f, y, -0.2f, x + 0.03f, y, 0.1f, x, y, 0.1f};
        memcpy(m.vertices + 3 * base, q, sizeof q);
        uint32_t tri[6] = {base, base + 1, base + 2, base, base + 2, base + 3};
        memcpy(m.indices + 3 * t, tri, sizeof tri);
        t += 2;
    }
    collider_geometry g = {.shape = COLLIDER_MESH, .mesh = &m};
    const double cell = 0.05;
    world_rect win = {3, 2, 30, 28};
    collider_pose poses[2] = {pose_at(0.9137, 0.8021, 0.3, identity),
                              pose_at(0.9137, 0.8021, 0.3,
                                      quat_multiply(quat_from_axis_angle((vec3d){0, 0, 1}, 0.7),
                                                    quat_from_axis_angle((vec3d){1, 0, 0}, 0.3)))};
    for (int k = 0; k < 2; k++) {
        int32_t *got = bottom_new(win), *want = bottom_new(win);
        collider_depth_cpu(&g, poses[k], win, cell, UPM, got);
        mesh_depth_reference(&m, poses[k], win, cell, want);
        int differ = 0, hit = 0;
        for (int i = 0; i < win.w * win.h; i++) {
            differ += got[i] != want[i];
            hit += want[i] != NONE;
        }
        collider_fixed *inst = NULL;
        int64_t n = 0, cap = 0;
        collider_fixed_mesh_prepare(&g, poses[k], win, cell, UPM, &inst, &n, &cap);
        CHECK(differ == 0 && hit >= 300,
              "mesh pose %d: the bottoms of the rule the long way (%d of %d cells differ, %d hit)",
              k, differ, win.w * win.h, hit);
        CHECK(n > 0 && n < m.triangle_count / 2,
              "mesh pose %d: %lld instances for %d triangles (sub-cell and vertical ones skipped)",
              k, (long long)n, m.triangle_count);
        free(inst);
        free(got);
        free(want);
    }
    free(m.vertices);
    free(m.indices);
}

static void write_file(const char *path, const char *text)
{
    FILE *f = fopen(path, "wb");
    fputs(text, f);
    fclose(f);
}

static void test_obj(void)
{
    char path[] = "/tmp/terrad_test_obj_XXXXXX";
    int fd = mkstemp(path);
    close(fd);
    error_text e = {{0}};
    collider_mesh m;
    write_file(path, "# a unit square and a triangle\r\n"
                     "o thing\n"
                     "v 0 0 0\n"
                     "v 1 0 0\n"
                     "v 1 1 0\n"
                     "v 0 1 0\n"
                     "vt 0 0\n"
                     "vn 0 0 1\n"
                     "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
                     "v 0 0 2\r\n"
                     "f -1 1//1 2/1\n"
                     "s off\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) == 0, "OBJ with quads, v/t/n and negatives: %s",
          e.message);
    CHECK(m.vertex_count == 5 && m.triangle_count == 3, "quad fanned: 5 vertices, 3 triangles");
    CHECK(m.indices[0] == 0 && m.indices[1] == 1 && m.indices[2] == 2 && m.indices[3] == 0 &&
              m.indices[4] == 2 && m.indices[5] == 3,
          "fan order 0 1 2, 0 2 3");
    CHECK(m.indices[6] == 4 && m.indices[7] == 0 && m.indices[8] == 1,
          "negative index -1 is the last vertex so far");
    CHECK(near(m.bounding_radius, 2.0, 1e-6), "bounding radius %g", m.bounding_radius);
    collider_mesh_free(&m);

    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2 4\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, path) && has(&e, ":5:") &&
              has(&e, "out of range"),
          "index out of range, with the line: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -4 1 2\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":4:"),
          "negative index before the first vertex: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":4:"), "index 0 refused: %s",
          e.message);
    write_file(path, "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":2:") && has(&e, "finite"),
          "NaN coordinate refused: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0\nf 1 2 1\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":2:"),
          "vertex with two numbers refused: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, "no triangles"),
          "no faces refused: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":4:") && has(&e, "at least 3"),
          "two-vertex face refused: %s", e.message);
    write_file(path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, ":4:"),
          "non-integer index refused: %s", e.message);
    write_file(path, "");
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0, "empty file refused: %s", e.message);
    unlink(path);
    CHECK(collider_mesh_load_obj(path, &m, &e) != 0 && has(&e, path), "missing file: %s",
          e.message);
}

static void test_motion(void)
{
    collider_motion m = {.kind = COLLIDER_MOTION_STATIC, .start = pose_at(1, 2, 3, identity)};
    collider_pose p = collider_motion_pose(&m, 100);
    CHECK(p.position.x == 1 && p.position.z == 3, "static stays put");

    m.kind = COLLIDER_MOTION_VELOCITY;
    m.velocity = (vec3d){0.5, -1, 0};
    m.spin_axis = (vec3d){0, 0, 1};
    m.spin_rad_per_s = M_PI / 2;
    p = collider_motion_pose(&m, 2);
    CHECK(near(p.position.x, 2, 1e-12) && near(p.position.y, 0, 1e-12), "velocity: start + v t");
    vec3d v = quat_rotate(p.orientation, (vec3d){1, 0, 0});
    CHECK(near(v.x, -1, 1e-12) && near(v.y, 0, 1e-12), "spin: 90 deg/s for 2 s is 180 deg");
    /* the spin applies after the start orientation */
    m.start.orientation = quat_from_axis_angle((vec3d){1, 0, 0}, M_PI / 2);
    p = collider_motion_pose(&m, 1);
    v = quat_rotate(p.orientation,
                    (vec3d){0, 1, 0}); /* start takes y to z; spin about z keeps it */
    CHECK(near(v.z, 1, 1e-12), "spin composes after the start orientation");

    collider_keyframe k[3] = {
        {1.0, pose_at(0, 0, 1, identity)},
        {2.0, pose_at(2, 0, 0, quat_from_axis_angle((vec3d){0, 0, 1}, M_PI / 2))},
        {4.0, pose_at(2, 4, 0, quat_from_axis_angle((vec3d){0, 0, 1}, M_PI / 2))},
    };
    collider_motion km = {
        .kind = COLLIDER_MOTION_KEYFRAMES, .keyframes = k, .keyframe_count = 3, .start = k[0].pose};
    p = collider_motion_pose(&km, -5);
    CHECK(p.position.x == 0 && p.position.z == 1, "before the first keyframe: held");
    p = collider_motion_pose(&km, 1.5);
    v = quat_rotate(p.orientation, (vec3d){1, 0, 0});
    CHECK(near(p.position.x, 1, 1e-12) && near(p.position.z, 0.5, 1e-12) &&
              near(v.x, sqrt(0.5), 1e-12) && near(v.y, sqrt(0.5), 1e-12),
          "halfway: linear position, slerped orientation");
    p = collider_motion_pose(&km, 3.0);
    CHECK(near(p.position.y, 2, 1e-12), "second segment");
    p = collider_motion_pose(&km, 2.0);
    CHECK(near(p.position.x, 2, 1e-12) && near(p.position.y, 0, 1e-12), "exactly on a keyframe");
    p = collider_motion_pose(&km, 99);
    CHECK(p.position.y == 4, "after the last keyframe: held");
    p = collider_motion_pose(&km, NAN);
    CHECK(p.position.x == 0, "NaN time: the first keyframe, not NaN");
}

/* The cost model's arithmetic (collider.c): a 0.3 m sphere at 0.05 m cells has
 * a window of (13 + 8)^2, a depth of ceil(169 / 32) per pose and a lane of 21;
 * 40 sub-steps charge the depth 40 times and 19 lanes, feedback one depth more. */
static void test_cost(void)
{
    collider_geometry g = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    collider_cost c = collider_cost_of(&g, 0.05);
    CHECK(c.window == 441 && c.step == 6 && c.lane == 21, "sphere cost %lld %lld %lld",
          (long long)c.window, (long long)c.step, (long long)c.lane);
    CHECK(collider_cost_cells(&c, 1, 0) == 447 && collider_cost_cells(&c, 1, 1) == 453 &&
              collider_cost_cells(&c, 40, 0) == 441 + 240 + 399 &&
              collider_cost_cells(&c, 0, 0) == 447,
          "cells at rest, with feedback, over 40 sub-steps, and steps < 1 taken as 1");
}

/* A lugged wheel (lugs.c: the rim and a box per lug, by the one fixed-point
 * rule) against a brute-force march through the solid it describes, at a
 * spin that puts no lug straight down and at one that does; and its reach
 * and bounds grown by the lugs. Without the lug instances every cell under a
 * lug is the rim's, up to a lug height (100 units) too high. */
static void test_depth_lugged(void)
{
    const double cell = 0.002, r = 0.15, hl = 0.02, h = 0.01, t = 0.004;
    const int n = 12;
    collider_geometry g = {
        .shape = COLLIDER_CYLINDER, .radius = r, .half_length = hl, .grousers = {n, h, t}};
    CHECK(near(collider_reach(&g), sqrt(hl * hl + (r + h) * (r + h) + t * t / 4), 1e-12),
          "lugged reach: the lugs' corners (%g)", collider_reach(&g));
    world_rect win = {0, 0, 200, 40};
    double px = 0.2, py = 0.04, pz = 0.5;
    for (int spin = 0; spin < 2; spin++) {
        double a = spin ? 0.0 : 0.11; /* lug 0 straight down, or turned off the vertical */
        quatd q = quat_from_axis_angle((vec3d){0, 1, 0}, a);
        vec3d lo, hi;
        collider_bounds(&g, pose_at(px, py, pz, q), &lo, &hi);
        CHECK(lo.z <= pz - r - h, "lugged bounds reach the lugs (%g)", lo.z);
        int32_t *b = bottom_new(win);
        collider_depth_cpu(&g, pose_at(px, py, pz, q), win, cell, UPM, b);
        quatd inv = {q.w, -q.x, -q.y, -q.z};
        int worst = 0, lug_cells = 0;
        for (int y = 0; y < win.h; y++)
            for (int x = 0; x < win.w; x++) {
                double lowest = INFINITY;
                for (double z = pz - r - h - 0.001; z < pz + r + h; z += 4e-5) {
                    vec3d l = quat_rotate(
                        inv, (vec3d){(x + 0.5) * cell - px, (y + 0.5) * cell - py, z - pz});
                    if (fabs(l.y) > hl)
                        break;
                    int in = l.x * l.x + l.z * l.z <= r * r;
                    for (int k = 0; k < n && !in; k++) { /* lug k: local -z turned by 2πk/n */
                        double th = 2 * M_PI * k / n, c = cos(th), s = sin(th);
                        double tx = c * l.x - s * l.z, rz = -(s * l.x + c * l.z);
                        in = fabs(tx) <= t / 2 && rz <= r + h && rz >= r - h;
                    }
                    if (in) {
                        lowest = z;
                        break;
                    }
                }
                int32_t expect = isinf(lowest) ? NONE : units(lowest);
                int32_t got = b[y * win.w + x];
                if ((expect == NONE) != (got == NONE))
                    worst = 1 << 30;
                else if (expect != NONE && abs(got - expect) > worst)
                    worst = abs(got - expect);
                lug_cells += got != NONE && expect != NONE && fabs((x + 0.5) * cell - px) < r &&
                             got < units(pz - sqrt(r * r - pow((x + 0.5) * cell - px, 2))) - 10;
            }
        CHECK(worst <= 1, "lugged wheel (spin %g rad) matches a brute-force march (worst %d units)",
              a, worst);
        CHECK(lug_cells > 0, "lugged wheel (spin %g rad): cells below the rim under lugs (%d)", a,
              lug_cells);
        if (spin)
            CHECK(abs(b[(int)(py / cell) * win.w + (int)(px / cell)] - units(pz - r - h)) <= 1,
                  "lug 0 straight down: the bottom is z - r - h");
        free(b);
    }
}

int main(void)
{
    test_validate();
    test_quaternions();
    test_bounds();
    test_depth_sphere();
    test_depth_box();
    test_depth_cylinder_capsule();
    test_depth_lugged();
    test_tessellation();
    test_mesh_exact_spans();
    test_obj();
    test_motion();
    test_cost();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
