/*
 * collider.c: the collider geometry's checks, quaternion arithmetic,
 * world-space bounds and scripted motion. Each tick starts here: a collider's
 * pose (streamed or from collider_motion_pose) and its bounds decide its
 * footprint, the footprints become windows (row 4a of the tick table in docs/design.md), and the
 * depth stage (depth_fixed.c on either backend)
 * then works only inside them. Bounds are exact rather than bounding-sphere
 * wide, because every extra cell of footprint is work for every later stage.
 */
#include "collider/collider.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define COLLIDER_SIZE_MAX_M 1000.0
#define COLLIDER_POSITION_MAX_M 1e6

static int size_ok(double v)
{
    return isfinite(v) && v > 0.0 && v <= COLLIDER_SIZE_MAX_M;
}

/* A cylinder's grousers (lugs.c): a whole count, each lug no taller and no
 * thicker than the rim's radius (the plate then starts inside the rim). */
static int grousers_validate(const collider_geometry *g, error_text *err)
{
    const collider_grousers *l = &g->grousers;
    if (l->count == 0)
        return 0;
    if (g->shape != COLLIDER_CYLINDER) {
        error_set(err, "grousers: only a wheel (a cylinder) carries grousers");
        return -1;
    }
    if (l->count < 0 || l->count > COLLIDER_GROUSERS_MAX) {
        error_set(err, "grousers.count: must be an integer 0..%d (got %d)", COLLIDER_GROUSERS_MAX,
                  l->count);
        return -1;
    }
    if (!size_ok(l->height) || l->height > g->radius) {
        error_set(err,
                  "grousers.height: must be a finite number > 0 and <= the radius %g m (got %g)",
                  g->radius, l->height);
        return -1;
    }
    if (!size_ok(l->thickness) || l->thickness > g->radius) {
        error_set(err,
                  "grousers.thickness: must be a finite number > 0 and <= the radius %g m (got %g)",
                  g->radius, l->thickness);
        return -1;
    }
    /* COLLIDERS' grousers extension reports both as f32 > 0 (PROTOCOL.md): a
     * size that rounds to f32 0 could not be reported, and the frame holding
     * it would be refused whole, for every viewer that asked for grousers */
    if ((float)l->height == 0.0f || (float)l->thickness == 0.0f) {
        int h = (float)l->height == 0.0f;
        error_set(err, "grousers.%s: %g m is below the least size COLLIDERS frames carry (%g m)",
                  h ? "height" : "thickness", h ? l->height : l->thickness, (double)FLT_TRUE_MIN);
        return -1;
    }
    return 0;
}

int collider_geometry_validate(const collider_geometry *g, error_text *err)
{
    if (g->grousers.count != 0 && g->shape != COLLIDER_CYLINDER)
        return grousers_validate(g, err);
    switch (g->shape) {
    case COLLIDER_SPHERE:
        if (!size_ok(g->radius)) {
            error_set(err, "radius: must be a finite number > 0 and <= 1000 m (got %g)", g->radius);
            return -1;
        }
        return 0;
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER:
        if (!size_ok(g->radius)) {
            error_set(err, "radius: must be a finite number > 0 and <= 1000 m (got %g)", g->radius);
            return -1;
        }
        /* a capsule of length 0 is a sphere and harmless; a flat cylinder is not a solid */
        if (g->shape == COLLIDER_CAPSULE && g->half_length == 0.0)
            return 0;
        if (!size_ok(g->half_length)) {
            error_set(err, "half_length: must be a finite number > 0 and <= 1000 m (got %g)",
                      g->half_length);
            return -1;
        }
        return grousers_validate(g, err);
    case COLLIDER_BOX: {
        const double e[3] = {g->half_extents.x, g->half_extents.y, g->half_extents.z};
        for (int i = 0; i < 3; i++)
            if (!size_ok(e[i])) {
                error_set(err,
                          "half_extents[%d]: must be a finite number > 0 and <= 1000 m (got %g)", i,
                          e[i]);
                return -1;
            }
        return 0;
    }
    case COLLIDER_MESH:
        if (!g->mesh || g->mesh->triangle_count < 1 || !g->mesh->vertices || !g->mesh->indices) {
            error_set(err, "mesh: has no triangles");
            return -1;
        }
        if (!size_ok(g->mesh->bounding_radius)) {
            error_set(err,
                      "mesh: must reach a finite distance > 0 and <= 1000 m from its origin "
                      "(got %g)",
                      g->mesh->bounding_radius);
            return -1;
        }
        for (int i = 0; i < g->mesh->triangle_count * 3; i++)
            if (g->mesh->indices[i] >= (uint32_t)g->mesh->vertex_count) {
                error_set(err, "mesh: index %u out of range (%d vertices)", g->mesh->indices[i],
                          g->mesh->vertex_count);
                return -1;
            }
        return 0;
    }
    error_set(err, "shape: unknown shape %d", (int)g->shape);
    return -1;
}

int collider_pose_validate(const collider_pose *p, error_text *err)
{
    const double v[3] = {p->position.x, p->position.y, p->position.z};
    for (int i = 0; i < 3; i++)
        if (!isfinite(v[i]) || fabs(v[i]) > COLLIDER_POSITION_MAX_M) {
            error_set(err, "position[%d]: must be a finite number with |x| <= 1e6 m (got %g)", i,
                      v[i]);
            return -1;
        }
    const double q[4] = {p->orientation.w, p->orientation.x, p->orientation.y, p->orientation.z};
    for (int i = 0; i < 4; i++)
        if (!isfinite(q[i]) || fabs(q[i]) > 1e6) {
            error_set(err, "orientation[%d]: must be a finite number with |x| <= 1e6 (got %g)", i,
                      q[i]);
            return -1;
        }
    double n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3];
    if (!(n2 > 1e-12)) {
        error_set(err, "orientation: must be a non-zero quaternion [w, x, y, z] (norm %g)",
                  sqrt(n2));
        return -1;
    }
    return 0;
}

/* ---- Quaternions ---- */

quatd quat_normalize(quatd q)
{
    double n = sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    if (!(n > 1e-300) || !isfinite(n))
        return (quatd){1, 0, 0, 0}; /* no usable rotation: treat as none */
    return (quatd){q.w / n, q.x / n, q.y / n, q.z / n};
}

quatd quat_multiply(quatd a, quatd b)
{
    return (quatd){
        a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z,
        a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
        a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
        a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w,
    };
}

quatd collider_wire_orientation(quatd q, int axis_z)
{
    q = quat_normalize(q);
    if (axis_z) {
        const double h = 0.70710678118654752440; /* a quarter turn about x: y -> z */
        q = quat_normalize(quat_multiply(q, (quatd){h, h, 0, 0}));
    }
    return q;
}

quatd quat_from_axis_angle(vec3d axis, double radians)
{
    double n = sqrt(axis.x * axis.x + axis.y * axis.y + axis.z * axis.z);
    if (!(n > 1e-300) || !isfinite(n) || !isfinite(radians))
        return (quatd){1, 0, 0, 0};
    double s = sin(radians * 0.5) / n;
    return (quatd){cos(radians * 0.5), axis.x * s, axis.y * s, axis.z * s};
}

quatd quat_slerp(quatd a, quatd b, double t)
{
    a = quat_normalize(a);
    b = quat_normalize(b);
    double d = a.w * b.w + a.x * b.x + a.y * b.y + a.z * b.z;
    if (d < 0.0) { /* q and -q are the same rotation: take the short way round */
        b = (quatd){-b.w, -b.x, -b.y, -b.z};
        d = -d;
    }
    double wa, wb;
    if (d > 0.9995) { /* nearly equal: sin(θ) ≈ 0, lerp is exact enough */
        wa = 1.0 - t;
        wb = t;
    } else {
        double theta = acos(d), s = sin(theta);
        wa = sin((1.0 - t) * theta) / s;
        wb = sin(t * theta) / s;
    }
    return quat_normalize((quatd){wa * a.w + wb * b.w, wa * a.x + wb * b.x, wa * a.y + wb * b.y,
                                  wa * a.z + wb * b.z});
}

vec3d quat_rotate(quatd q, vec3d v)
{
    /* v' = v + 2w(u × v) + 2u × (u × v), u = (x, y, z) */
    double tx = 2.0 * (q.y * v.z - q.z * v.y);
    double ty = 2.0 * (q.z * v.x - q.x * v.z);
    double tz = 2.0 * (q.x * v.y - q.y * v.x);
    return (vec3d){
        v.x + q.w * tx + (q.y * tz - q.z * ty),
        v.y + q.w * ty + (q.z * tx - q.x * tz),
        v.z + q.w * tz + (q.x * ty - q.y * tx),
    };
}

/* ---- Bounds ---- */

double collider_rim_reach(const collider_geometry *g)
{
    if (g->shape != COLLIDER_CYLINDER || g->grousers.count <= 0)
        return g->radius;
    /* a lug's outer corners: r + height out, thickness / 2 aside */
    double o = g->radius + g->grousers.height, t = 0.5 * g->grousers.thickness;
    return sqrt(o * o + t * t);
}

void collider_bounds(const collider_geometry *g, collider_pose pose, vec3d *lo, vec3d *hi)
{
    quatd q = quat_normalize(pose.orientation);
    vec3d p = pose.position, e = {0, 0, 0};
    switch (g->shape) {
    case COLLIDER_SPHERE:
        e = (vec3d){g->radius, g->radius, g->radius};
        break;
    case COLLIDER_BOX: {
        /* the extent along each world axis is Σ_j |R_ij| h_j: the farthest corner */
        vec3d c0 = quat_rotate(q, (vec3d){1, 0, 0});
        vec3d c1 = quat_rotate(q, (vec3d){0, 1, 0});
        vec3d c2 = quat_rotate(q, (vec3d){0, 0, 1});
        vec3d h = g->half_extents;
        e.x = fabs(c0.x) * h.x + fabs(c1.x) * h.y + fabs(c2.x) * h.z;
        e.y = fabs(c0.y) * h.x + fabs(c1.y) * h.y + fabs(c2.y) * h.z;
        e.z = fabs(c0.z) * h.x + fabs(c1.z) * h.y + fabs(c2.z) * h.z;
        break;
    }
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER: {
        vec3d a = quat_rotate(q, (vec3d){0, 1, 0});
        double L = g->half_length, r = collider_rim_reach(g);
        if (g->shape == COLLIDER_CAPSULE) {
            e = (vec3d){fabs(a.x) * L + r, fabs(a.y) * L + r, fabs(a.z) * L + r};
        } else {
            /* a disc of radius r with unit normal a reaches r·sqrt(1 - a_i²) along axis i */
            e.x = fabs(a.x) * L + r * sqrt(fmax(0.0, 1.0 - a.x * a.x));
            e.y = fabs(a.y) * L + r * sqrt(fmax(0.0, 1.0 - a.y * a.y));
            e.z = fabs(a.z) * L + r * sqrt(fmax(0.0, 1.0 - a.z * a.z));
        }
        break;
    }
    case COLLIDER_MESH: {
        const collider_mesh *m = g->mesh;
        if (!m || m->vertex_count < 1)
            break;
        vec3d mn = {INFINITY, INFINITY, INFINITY}, mx = {-INFINITY, -INFINITY, -INFINITY};
        for (int i = 0; i < m->vertex_count; i++) {
            const float *v = m->vertices + 3 * (size_t)i;
            vec3d w = quat_rotate(q, (vec3d){v[0], v[1], v[2]});
            mn.x = fmin(mn.x, w.x);
            mn.y = fmin(mn.y, w.y);
            mn.z = fmin(mn.z, w.z);
            mx.x = fmax(mx.x, w.x);
            mx.y = fmax(mx.y, w.y);
            mx.z = fmax(mx.z, w.z);
        }
        *lo = (vec3d){p.x + mn.x, p.y + mn.y, p.z + mn.z};
        *hi = (vec3d){p.x + mx.x, p.y + mx.y, p.z + mx.z};
        return;
    }
    }
    *lo = (vec3d){p.x - e.x, p.y - e.y, p.z - e.z};
    *hi = (vec3d){p.x + e.x, p.y + e.y, p.z + e.z};
}

/* ---- Scripted motion ---- */

collider_pose collider_motion_pose(const collider_motion *m, double time_s)
{
    switch (m->kind) {
    case COLLIDER_MOTION_STATIC:
        break;
    case COLLIDER_MOTION_VELOCITY: {
        collider_pose p = m->start;
        p.position.x += m->velocity.x * time_s;
        p.position.y += m->velocity.y * time_s;
        p.position.z += m->velocity.z * time_s;
        quatd spin = quat_from_axis_angle(m->spin_axis, m->spin_rad_per_s * time_s);
        p.orientation = quat_normalize(quat_multiply(spin, quat_normalize(m->start.orientation)));
        return p;
    }
    case COLLIDER_MOTION_KEYFRAMES: {
        const collider_keyframe *k = m->keyframes;
        int n = m->keyframe_count;
        if (n < 1 || !k)
            break;
        if (!(time_s > k[0].time_s)) /* also catches NaN */
            return k[0].pose;
        if (time_s >= k[n - 1].time_s)
            return k[n - 1].pose;
        /* last keyframe with time <= t */
        int lo = 0, hi = n - 1;
        while (hi - lo > 1) {
            int mid = lo + (hi - lo) / 2;
            if (k[mid].time_s <= time_s)
                lo = mid;
            else
                hi = mid;
        }
        double span = k[hi].time_s - k[lo].time_s;
        double u = span > 0.0 ? (time_s - k[lo].time_s) / span : 0.0;
        const vec3d a = k[lo].pose.position, b = k[hi].pose.position;
        collider_pose p;
        p.position = (vec3d){a.x + (b.x - a.x) * u, a.y + (b.y - a.y) * u, a.z + (b.z - a.z) * u};
        p.orientation = quat_slerp(k[lo].pose.orientation, k[hi].pose.orientation, u);
        return p;
    }
    }
    return m->start;
}

void collider_motion_free(collider_motion *m)
{
    if (!m)
        return;
    free(m->keyframes);
    m->keyframes = NULL;
    m->keyframe_count = 0;
}

double collider_reach(const collider_geometry *g)
{
    switch (g->shape) {
    case COLLIDER_SPHERE:
        return g->radius;
    case COLLIDER_CAPSULE:
        return g->half_length + g->radius;
    case COLLIDER_CYLINDER: {
        double r = collider_rim_reach(g);
        return sqrt(g->half_length * g->half_length + r * r);
    }
    case COLLIDER_BOX: {
        vec3d h = g->half_extents;
        return sqrt(h.x * h.x + h.y * h.y + h.z * h.z);
    }
    case COLLIDER_MESH:
        return g->mesh ? g->mesh->bounding_radius : 0.0;
    }
    return 0.0;
}

/*
 * What a collider costs a tick (issue 20, item 3), in "cells": one cell is the
 * work of one cell of a window through the whole tick (depth, classify, jump
 * flood, displacement, commit). Calibrated with instruction counts, which the
 * machine's load does not change (callgrind, `terrad simulate --backend cpu
 * --threads 1` on the daemon's default dunes, a collider ploughing fresh
 * ground, per tick; docs/service.md has the table):
 *   - a primitive sphere of r 0.5 / 2 / 8 m: 3.5 M / 30 M / 449 M
 *     instructions, i.e. 4.1–4.4 k per cell of its window, which is the
 *     bounding square plus the sim's active margin (4 cells) on each side;
 *   - a mesh of 32,760 triangles (0.5 m): 17 M more than the sphere, 515
 *     instructions per triangle (prepared on every sub-step): 1/8 cell;
 *   - 40 sweep sub-steps of the 0.5 m sphere instead of 1: 3.8 M more, the
 *     window growing with the travel (a lane of window per cell moved) and
 *     under 100 instructions per cell of its square per sub-step: 1/32 cell.
 */
#define COST_MARGIN_CELLS 4  /* the default active margin (scene.h) */
#define COST_STEP_DIVISOR 32 /* cells of a depth pass per cell of window */
#define COST_TRIANGLE_DIVISOR 8

/* The cells a mesh's depth instances visit, summed over its triangles: per
 * triangle the square around its own bounding sphere (what its depth may
 * visit), whatever the orientation. */
static int64_t mesh_visit_cells(const collider_mesh *m, double cell)
{
    int64_t sum = 0;
    for (int k = 0; k < m->triangle_count; k++) {
        const uint32_t *ix = m->indices + 3 * (size_t)k;
        double c[3] = {0, 0, 0}, r2 = 0;
        for (int j = 0; j < 3; j++)
            for (int a = 0; a < 3; a++)
                c[a] += m->vertices[3 * (size_t)ix[j] + a] / 3.0;
        for (int j = 0; j < 3; j++) {
            double d2 = 0;
            for (int a = 0; a < 3; a++) {
                double d = m->vertices[3 * (size_t)ix[j] + a] - c[a];
                d2 += d * d;
            }
            r2 = d2 > r2 ? d2 : r2;
        }
        double side = floor(2 * sqrt(r2) / cell) + 1;
        sum += (int64_t)(side * side);
    }
    return sum;
}

static int64_t ceil_div(int64_t a, int64_t b)
{
    return (a + b - 1) / b;
}

collider_cost collider_cost_of(const collider_geometry *g, double cell_size_m)
{
    double cell = cell_size_m > 0 ? cell_size_m : 1;
    double side = ceil(2 * collider_reach(g) / cell) + 1;
    int64_t lane = (int64_t)side + 2 * COST_MARGIN_CELLS;
    collider_cost c = {.window = lane * lane, .lane = lane};
    if (g->shape == COLLIDER_MESH && g->mesh)
        c.step = ceil_div(g->mesh->triangle_count, COST_TRIANGLE_DIVISOR) +
                 ceil_div(mesh_visit_cells(g->mesh, cell), COST_STEP_DIVISOR);
    else
        c.step = ceil_div((int64_t)(side * side), COST_STEP_DIVISOR);
    if (g->shape == COLLIDER_CYLINDER && g->grousers.count > 0) {
        /* a lug is a box instance: its bounding square, prepared like a triangle */
        const collider_grousers *l = &g->grousers;
        double lug = ceil(2 *
                          sqrt(g->half_length * g->half_length +
                               (l->height + l->thickness) * (l->height + l->thickness)) /
                          cell) +
                     3;
        c.step += ceil_div(l->count, COST_TRIANGLE_DIVISOR) +
                  ceil_div((int64_t)l->count * (int64_t)(lug * lug), COST_STEP_DIVISOR);
    }
    return c;
}

int64_t collider_cost_cells(const collider_cost *c, int steps, int feedback)
{
    int64_t n = steps > 1 ? steps : 1;
    return c->window + (n + (feedback ? 1 : 0)) * c->step + (n - 1) / 2 * c->lane;
}
