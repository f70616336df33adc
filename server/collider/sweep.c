/*
 * sweep.c: the swept collider of one tick (issue 12, item 2). The depth a
 * tick sees is the collider swept from its previous pose to this one, so a
 * fast collider leaves a continuous trench instead of a row of dents. The
 * sweep is a set of sub-step poses along the motion — position lerped,
 * orientation slerped — spaced so that no point of the collider moves more
 * than half a cell between two of them; the depth is the minimum over those
 * poses. The poses are a pure function of (geometry, previous pose, pose,
 * cell size) computed here on the CPU in double precision, so the CPU twin
 * (sim_window_depth) and the GL depth pass (gl/depth.c) see the very same poses.
 *
 * The previous pose itself is not a sub-step: its depth was applied on the
 * tick before, so a collider at rest, or one that moves at most half a cell,
 * costs one pose — this one — exactly as before the sweep.
 */
#include "collider/collider.h"

#include <math.h>

int collider_sweep_steps(const collider_geometry *g, collider_pose from, collider_pose to,
                         double cell_size_m)
{
    if (!(cell_size_m > 0.0))
        return 1;
    double dx = to.position.x - from.position.x, dy = to.position.y - from.position.y,
           dz = to.position.z - from.position.z;
    quatd a = quat_normalize(from.orientation), b = quat_normalize(to.orientation);
    double dot = fabs(a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z);
    double angle = dot >= 1.0 ? 0.0 : 2.0 * acos(dot); /* rotation from a to b, radians */
    /* a point at distance R from the position travels at most |Δp| + R θ */
    double travel = sqrt(dx * dx + dy * dy + dz * dz) + collider_reach(g) * angle;
    double steps = ceil(travel / (0.5 * cell_size_m));
    if (!(steps >= 1.0)) /* also NaN */
        return 1;
    if (steps > COLLIDER_SWEEP_STEPS_MAX)
        return COLLIDER_SWEEP_STEPS_MAX;
    return (int)steps;
}

collider_pose collider_sweep_pose(collider_pose from, collider_pose to, int k, int steps)
{
    if (k >= steps || steps <= 1)
        return to; /* the last sub-step is the pose itself, bit for bit */
    double t = (double)k / (double)steps;
    collider_pose p;
    p.position = (vec3d){from.position.x + (to.position.x - from.position.x) * t,
                         from.position.y + (to.position.y - from.position.y) * t,
                         from.position.z + (to.position.z - from.position.z) * t};
    p.orientation = quat_slerp(from.orientation, to.orientation, t);
    return p;
}

void collider_sweep_bounds(const collider_geometry *g, collider_pose from, collider_pose to,
                           int steps, vec3d *lo, vec3d *hi)
{
    collider_bounds(g, to, lo, hi);
    for (int k = 0; k < steps; k++) { /* k = 0: the previous pose, so the footprint covers it */
        vec3d l, h;
        collider_bounds(g, collider_sweep_pose(from, to, k, steps), &l, &h);
        lo->x = fmin(lo->x, l.x);
        lo->y = fmin(lo->y, l.y);
        lo->z = fmin(lo->z, l.z);
        hi->x = fmax(hi->x, h.x);
        hi->y = fmax(hi->y, h.y);
        hi->z = fmax(hi->z, h.z);
    }
}
