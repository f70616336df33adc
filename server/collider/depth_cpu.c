/*
 * depth_cpu.c: the CPU twin's depth stage (step 5 of the tick). For every
 * cell of a window it finds the lowest point of a collider on the vertical
 * line through the cell centre and lowers the window's "bottom" array to it.
 * Primitives are intersected analytically in the collider's local frame, so
 * the twin is the exact reference the GL raster of tessellated triangles is
 * measured against; meshes are rasterised triangle by triangle, as GL does.
 *
 * Only the cells under the collider's bounds are visited: the cost follows
 * the collider's footprint, not the window. Lines that run parallel to a
 * face or to the axis (a standing cylinder, an upright box) are handled as
 * inside/outside tests, never by dividing by zero.
 */
#include "collider/collider.h"

#include <math.h>
#include <stdlib.h>

/* An entry point z (metres) → bottom units, with the clamp the stages expect. */
static int32_t bottom_units(double z, int32_t units_per_m)
{
    double u = floor(z * (double)units_per_m);
    if (!(u > (double)WORLD_HEIGHT_MIN - 1.0)) /* also NaN: nothing sensible, keep it low */
        return WORLD_HEIGHT_MIN - 1;
    if (u > (double)WORLD_HEIGHT_MAX + 1.0)
        return WORLD_HEIGHT_MAX + 1;
    return (int32_t)u;
}

static void lower(int32_t *cell, double z, int32_t units_per_m)
{
    int32_t v = bottom_units(z, units_per_m);
    if (v < *cell)
        *cell = v;
}

/* Cell index range whose centres (i + 0.5) * cell lie in [lo, hi], clipped to
 * [first, first + count). Returns 0 when empty. */
static int cell_span(double lo, double hi, double cell, int first, int count, int *i0, int *i1)
{
    double a = ceil(lo / cell - 0.5), b = floor(hi / cell - 0.5);
    double f = first, l = (double)first + count - 1;
    if (!(a <= b) || b < f || a > l) /* also rejects NaN */
        return 0;
    *i0 = (int)(a < f ? f : a);
    *i1 = (int)(b > l ? l : b);
    return 1;
}

/* Interval of line parameters t inside the slab |o + t d| <= h on one axis.
 * Returns 0 when the line misses the slab. */
static int slab(double o, double d, double h, double *tmin, double *tmax)
{
    if (fabs(d) < 1e-12) /* parallel to the slab's faces: all or nothing */
        return fabs(o) <= h;
    double t1 = (-h - o) / d, t2 = (h - o) / d;
    if (t1 > t2) {
        double s = t1;
        t1 = t2;
        t2 = s;
    }
    if (t1 > *tmin)
        *tmin = t1;
    if (t2 < *tmax)
        *tmax = t2;
    return *tmin <= *tmax;
}

/* Entry parameter of the line into a sphere of radius r centred at c. */
static int sphere_entry(vec3d o, vec3d d, vec3d c, double r, double *t)
{
    double ox = o.x - c.x, oy = o.y - c.y, oz = o.z - c.z;
    double b = ox * d.x + oy * d.y + oz * d.z; /* d is unit length */
    double cc = ox * ox + oy * oy + oz * oz - r * r;
    double disc = b * b - cc;
    if (disc < 0.0)
        return 0;
    *t = -b - sqrt(disc);
    return 1;
}

/* Entry parameter into a solid cylinder about local Y: the infinite
 * cylinder's chord clipped by the slab |y| <= L (this is what makes the caps). */
static int cylinder_entry(vec3d o, vec3d d, double r, double L, double *t)
{
    double tmin = -INFINITY, tmax = INFINITY;
    double a = d.x * d.x + d.z * d.z;
    double b = o.x * d.x + o.z * d.z;
    double c = o.x * o.x + o.z * o.z - r * r;
    if (a < 1e-18) { /* line along the axis: inside the disc or not */
        if (c > 0.0)
            return 0;
    } else {
        double disc = b * b - a * c;
        if (disc < 0.0)
            return 0;
        double s = sqrt(disc);
        tmin = (-b - s) / a;
        tmax = (-b + s) / a;
    }
    if (!slab(o.y, d.y, L, &tmin, &tmax))
        return 0;
    if (!isfinite(tmin)) /* cannot happen for a bounded solid; guard anyway */
        return 0;
    *t = tmin;
    return 1;
}

static int box_entry(vec3d o, vec3d d, vec3d h, double *t)
{
    double tmin = -INFINITY, tmax = INFINITY;
    if (!slab(o.x, d.x, h.x, &tmin, &tmax) || !slab(o.y, d.y, h.y, &tmin, &tmax) ||
        !slab(o.z, d.z, h.z, &tmin, &tmax))
        return 0;
    if (!isfinite(tmin))
        return 0;
    *t = tmin;
    return 1;
}

static void depth_mesh(const collider_mesh *m, collider_pose pose, quatd q, world_rect win,
                       double cell, int32_t units_per_m, int32_t *bottom)
{
    for (int k = 0; k < m->triangle_count; k++) {
        vec3d v[3];
        for (int j = 0; j < 3; j++) {
            const float *s = m->vertices + 3 * (size_t)m->indices[3 * (size_t)k + j];
            vec3d r = quat_rotate(q, (vec3d){s[0], s[1], s[2]});
            v[j] = (vec3d){r.x + pose.position.x, r.y + pose.position.y, r.z + pose.position.z};
        }
        /* twice the signed area of the xy projection; 0 for a vertical face,
         * which the line can only graze: its neighbours give the same bottom */
        double area = (v[1].x - v[0].x) * (v[2].y - v[0].y) - (v[2].x - v[0].x) * (v[1].y - v[0].y);
        if (!(fabs(area) > 1e-18))
            continue;
        double minx = fmin(v[0].x, fmin(v[1].x, v[2].x)), maxx = fmax(v[0].x, fmax(v[1].x, v[2].x));
        double miny = fmin(v[0].y, fmin(v[1].y, v[2].y)), maxy = fmax(v[0].y, fmax(v[1].y, v[2].y));
        double minz = fmin(v[0].z, fmin(v[1].z, v[2].z)), maxz = fmax(v[0].z, fmax(v[1].z, v[2].z));
        int x0, x1, y0, y1;
        if (!cell_span(minx, maxx, cell, win.x, win.w, &x0, &x1) ||
            !cell_span(miny, maxy, cell, win.y, win.h, &y0, &y1))
            continue;
        double inv = 1.0 / area;
        for (int y = y0; y <= y1; y++) {
            double py = ((double)y + 0.5) * cell;
            for (int x = x0; x <= x1; x++) {
                double px = ((double)x + 0.5) * cell;
                /* barycentric weights; inclusive edges so shared edges leave no gaps */
                double l0 = ((v[1].x - px) * (v[2].y - py) - (v[2].x - px) * (v[1].y - py)) * inv;
                double l1 = ((v[2].x - px) * (v[0].y - py) - (v[0].x - px) * (v[2].y - py)) * inv;
                double l2 = 1.0 - l0 - l1;
                if (l0 < 0.0 || l1 < 0.0 || l2 < 0.0)
                    continue;
                double z = l0 * v[0].z + l1 * v[1].z + l2 * v[2].z;
                z = fmin(fmax(z, minz), maxz); /* rounding must not leave the triangle */
                lower(&bottom[(size_t)(y - win.y) * win.w + (x - win.x)], z, units_per_m);
            }
        }
    }
}

void collider_depth_cpu(const collider_geometry *g, collider_pose pose, world_rect window,
                        double cell_size_m, int32_t units_per_m, int32_t *bottom)
{
    if (window.w <= 0 || window.h <= 0 || !(cell_size_m > 0.0))
        return;
    collider_fixed f;
    if (g->shape == COLLIDER_MESH && g->mesh) { /* the fixed-point specification, as GL */
        collider_fixed *tri = NULL;
        int64_t n = 0, cap = 0;
        if (collider_fixed_mesh_prepare(g, pose, window, cell_size_m, units_per_m, &tri, &n,
                                        &cap) >= 0)
            for (int64_t i = 0; i < n; i++)
                collider_fixed_apply(&tri[i], bottom, window.w);
        free(tri);
        return;
    }
    if (collider_fixed_supported(g)) { /* the fixed-point specification, as GL computes it */
        if (collider_fixed_prepare(g, pose, window, cell_size_m, units_per_m, &f))
            collider_fixed_apply(&f, bottom, window.w);
        return;
    }
    quatd q = quat_normalize(pose.orientation);
    if (g->shape == COLLIDER_MESH) {
        if (g->mesh)
            depth_mesh(g->mesh, pose, q, window, cell_size_m, units_per_m, bottom);
        return;
    }
    vec3d lo, hi;
    collider_bounds(g, pose, &lo, &hi);
    int x0, x1, y0, y1;
    if (!cell_span(lo.x, hi.x, cell_size_m, window.x, window.w, &x0, &x1) ||
        !cell_span(lo.y, hi.y, cell_size_m, window.y, window.h, &y0, &y1))
        return;
    quatd qi = {q.w, -q.x, -q.y, -q.z};
    vec3d d = quat_rotate(qi, (vec3d){0, 0, 1}); /* the vertical, in the local frame */
    vec3d p = pose.position;
    double r = g->radius, L = g->half_length;
    for (int y = y0; y <= y1; y++) {
        double cy = ((double)y + 0.5) * cell_size_m;
        int32_t *row = bottom + (size_t)(y - window.y) * window.w;
        for (int x = x0; x <= x1; x++) {
            double cx = ((double)x + 0.5) * cell_size_m;
            double t = 0.0;
            int hit = 0;
            if (g->shape == COLLIDER_SPHERE) {
                /* rotation-free: the chord's lower end, straight from the centre */
                double dx = cx - p.x, dy = cy - p.y, s = r * r - dx * dx - dy * dy;
                if (s >= 0.0) {
                    t = p.z - sqrt(s);
                    hit = 1;
                }
            } else {
                /* world line (cx, cy, 0) + t (0, 0, 1): t is the world z */
                vec3d o = quat_rotate(qi, (vec3d){cx - p.x, cy - p.y, -p.z});
                switch (g->shape) {
                case COLLIDER_BOX:
                    hit = box_entry(o, d, g->half_extents, &t);
                    break;
                case COLLIDER_CYLINDER:
                    hit = cylinder_entry(o, d, r, L, &t);
                    break;
                case COLLIDER_CAPSULE: {
                    double tc;
                    if (L > 0.0 && cylinder_entry(o, d, r, L, &tc)) {
                        t = tc;
                        hit = 1;
                    }
                    for (int e = -1; e <= 1; e += 2)
                        if (sphere_entry(o, d, (vec3d){0, e * L, 0}, r, &tc) && (!hit || tc < t)) {
                            t = tc;
                            hit = 1;
                        }
                    break;
                }
                default:
                    break;
                }
            }
            if (hit)
                lower(&row[x - window.x], t, units_per_m);
        }
    }
}
