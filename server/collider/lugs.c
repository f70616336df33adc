/*
 * lugs.c: a wheel's grousers in the depth stage (issue 31, item 1), row 4d.1
 * of the tick table in docs/design.md on both backends. A lugged cylinder is
 * its smooth rim plus one flat plate per lug, and every plate is a box: the
 * depth stage lowers the bottoms with a box instance per lug beside the rim's
 * cylinder instance, by the one fixed-point rule (depth_fixed.c and its GLSL
 * twin shaders/depth_exact.comp). So a lugged rim is exact and identical on
 * CPU and GL with no rule of its own: the lugs' poses are turned into
 * integers once on the CPU, like every other instance.
 *
 * Lug k points along the wheel's local -z turned 360° k / count about the
 * axle (local y). Its box spans the whole width, thickness along the rim, and
 * radially from r - max(height, thickness) (inside the rim, so the plate's
 * corners meet the rim without a gap) out to r + height.
 */
#include "collider/collider.h"

#include <math.h>

static const double lug_pi = 3.14159265358979323846;

/* The radial extent of a lug's box: inner and outer radius. */
static void lug_span(const collider_geometry *g, double *inner, double *outer)
{
    const collider_grousers *l = &g->grousers;
    double in = g->radius - fmax(l->height, l->thickness);
    *inner = in > 0.0 ? in : 0.0;
    *outer = g->radius + l->height;
}

collider_geometry collider_lug_box(const collider_geometry *g, collider_pose pose, int k,
                                   collider_pose *lug_pose)
{
    double inner, outer;
    lug_span(g, &inner, &outer);
    int n = g->grousers.count > 0 ? g->grousers.count : 1;
    quatd q = quat_normalize(pose.orientation);
    quatd turn = quat_from_axis_angle((vec3d){0, 1, 0}, 2.0 * lug_pi * (double)k / (double)n);
    quatd ql = quat_normalize(quat_multiply(q, turn));
    vec3d c = quat_rotate(ql, (vec3d){0, 0, -0.5 * (inner + outer)});
    lug_pose->position =
        (vec3d){pose.position.x + c.x, pose.position.y + c.y, pose.position.z + c.z};
    lug_pose->orientation = ql;
    return (collider_geometry){
        .shape = COLLIDER_BOX,
        .half_extents = {0.5 * g->grousers.thickness, g->half_length, 0.5 * (outer - inner)}};
}

int collider_fixed_instances(const collider_geometry *g, collider_pose pose, world_rect window,
                             double cell_size_m, int32_t units_per_m, collider_fixed **out,
                             int64_t *count, int64_t *capacity)
{
    if (g->shape == COLLIDER_MESH)
        return collider_fixed_mesh_prepare(g, pose, window, cell_size_m, units_per_m, out, count,
                                           capacity);
    /* the rim as a smooth cylinder (its own bounds, not the lugs'), then each lug */
    collider_geometry rim = *g;
    rim.grousers = (collider_grousers){0};
    int lugs = g->shape == COLLIDER_CYLINDER ? g->grousers.count : 0;
    int added = 0;
    for (int k = -1; k < lugs; k++) {
        if (array_grow((void **)out, capacity, *count + 1, sizeof **out) != 0)
            return -1;
        collider_pose p = pose;
        collider_geometry box;
        if (k >= 0)
            box = collider_lug_box(g, pose, k, &p);
        if (collider_fixed_prepare(k < 0 ? &rim : &box, p, window, cell_size_m, units_per_m,
                                   &(*out)[*count])) {
            (*count)++;
            added++;
        }
    }
    return added;
}
