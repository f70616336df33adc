/*
 * depth_fixed.c: the depth stage's fixed-point specification (issue 12,
 * item 4), row 4d.1 of the tick table (docs/design.md) on both backends. A GL raster of tessellated
 * triangles in float and an analytic intersection in double never agree
 * bit for bit, so the shapes done here are computed by ONE integer
 * specification: this file, and its GLSL twin shaders/depth_exact.comp,
 * which runs the same integer operations on the same integers.
 *
 * Everything that needs floating point happens once, here on the CPU, when
 * an instance (a shape at one sub-step pose over one window) is prepared:
 * lengths become int64 in 1/2^S of a height unit (S = 16, lowered for huge
 * shapes so that every square fits in int64), the cell grid becomes the
 * first cell centre relative to the shape and the cell pitch in those
 * units. Both backends receive these integers (collider_fixed) and nothing
 * else; from there on it is integer arithmetic only.
 *
 * The rule, per cell: bottom = floor(z / 2^S) for the LOWEST fixed-point
 * height z (an integer in 1/2^S units) inside the shape on the vertical line
 * through the cell centre, clamped to [WORLD_HEIGHT_MIN - 1,
 * WORLD_HEIGHT_MAX + 1]; no such z: the cell is left alone.
 *
 *   sphere: (dx² + dy² + (z - cz)² <= r²) → z = cz - isqrt(r² - dx² - dy²)
 *   box, cylinder, capsule: the line in the local frame is u + c τ / 2^30
 *     (τ = z - cz; u = the cell's offset rotated by Rᵀ rounded to Q30 on the
 *     CPU, floored to fixed units; c = Rᵀ's third column in Q30); each slab
 *     |u_j + c_j τ / 2^30| <= h_j gives an integer τ interval (ceil of the
 *     lower bound, floor of the upper); a cylinder's disc gives
 *     τ0 ± half_τ from the closest approach (floor divisions, isqrt), a
 *     capsule adds two spheres whose centres the CPU rotated and rounded;
 *     the lowest τ in the intersection is the entry.
 *
 * The divisions round on magnitudes (floor_div, ceil_div), never on the
 * sign rules of a language.
 *
 *   mesh: an instance per triangle; vertices rotated in double and rounded
 *     once per vertex (so shared edges agree), cell centres on the exact
 *     grid X step + step / 2; integer edge functions, inclusive; the plane's
 *     height floor(z0 + (E1 (z1 - z0) + E2 (z2 - z0)) / A).
 */
#include "collider/collider.h"

#include <math.h>
#include <stdlib.h>

uint64_t collider_isqrt64(uint64_t v)
{
    /* floor(sqrt(v)) is one integer whatever computes it: here a double
     * estimate corrected both ways (every v here is below 2^62, so the
     * squares cannot wrap); depth_exact.comp takes it digit by digit */
    uint64_t r = (uint64_t)sqrt((double)v);
    while (r > 0 && r * r > v)
        r--;
    while ((r + 1) * (r + 1) <= v)
        r++;
    return r;
}

/* floor(v / 2^s) without relying on the sign behaviour of >> */
static int64_t floor_shift(int64_t v, int64_t s)
{
    if (v >= 0)
        return v >> s;
    return -(int64_t)(((uint64_t)(-v) + (((uint64_t)1 << s) - 1)) >> s);
}

/* metres → fixed units, scale = units_per_m 2^s (exact: a power of two times
 * an int32), rounded, kept far from overflow. Scaling by a power of two
 * commutes with rounding, so metres * scale is metres * units_per_m * 2^s. */
static int64_t to_fixed_scaled(double metres, double scale)
{
    double v = nearbyint(metres * scale);
    const double lim = ldexp(1.0, 60);
    if (!(v > -lim)) /* also NaN */
        return -((int64_t)1 << 60);
    if (v > lim)
        return (int64_t)1 << 60;
    return (int64_t)v;
}

/* metres → fixed units (1/2^s of a height unit) */
static int64_t to_fixed(double metres, int32_t units_per_m, int s)
{
    return to_fixed_scaled(metres, (double)units_per_m * ldexp(1.0, s));
}

/* floor(a / b) and ceil(a / b), b != 0, on magnitudes (depth_exact.comp: the same) */
static int64_t floor_div(int64_t a, int64_t b)
{
    int neg = (a < 0) != (b < 0);
    uint64_t ua = a < 0 ? (uint64_t)0 - (uint64_t)a : (uint64_t)a;
    uint64_t ub = b < 0 ? (uint64_t)0 - (uint64_t)b : (uint64_t)b;
    uint64_t q = ua / ub, r = ua % ub;
    if (neg)
        return -(int64_t)(q + (r != 0));
    return (int64_t)q;
}

static int64_t ceil_div(int64_t a, int64_t b)
{
    return -floor_div(-a, b);
}

#define TAU_LIMIT ((int64_t)1 << 60)

/* Inlined into the per-shape loops of collider_fixed_apply: a call per cell
 * and per slab was most of the box's depth stage. */
#define FIXED_INLINE inline __attribute__((always_inline))

/* Narrow [lo, hi] to the τ with |u + c τ / 2^30| <= h; 0 when empty. */
static FIXED_INLINE int slab_fixed(int64_t u, int64_t c, int64_t h, int64_t *lo, int64_t *hi)
{
    if (c == 0)
        return u >= -h && u <= h;
    int64_t t0, t1;
    if (c == ((int64_t)1 << 30) || c == -((int64_t)1 << 30)) {
        /* a local axis along world z (every unrotated box): the quotients
         * below are exact, (±h - u) 2^30 / ±2^30, so no division is needed
         * (two 64-bit divisions per slab per cell were most of the deep
         * box's depth stage); the same integers as the general case */
        t0 = c > 0 ? -h - u : u - h;
        t1 = c > 0 ? h - u : u + h;
    } else {
        int64_t a = (-h - u) * ((int64_t)1 << 30), b = (h - u) * ((int64_t)1 << 30);
        t0 = c > 0 ? ceil_div(a, c) : ceil_div(b, c);
        t1 = c > 0 ? floor_div(b, c) : floor_div(a, c);
    }
    if (t0 > *lo)
        *lo = t0;
    if (t1 < *hi)
        *hi = t1;
    return *lo <= *hi;
}

/* The lowest τ of the sphere of radius r at horizontal offset (dx, dy). */
static int sphere_fixed(int64_t dx, int64_t dy, int64_t r, int64_t *tau)
{
    if (dx < -r || dx > r || dy < -r || dy > r)
        return 0;
    int64_t s = r * r - dx * dx; /* >= 0, < 2^62 */
    if (s < dy * dy)
        return 0;
    s -= dy * dy;
    *tau = -(int64_t)collider_isqrt64((uint64_t)s);
    return 1;
}

/* The disc x² + z² <= r² of the local xz plane, crossed by u + c τ / 2^30. */
static int disc_fixed(int64_t u0, int64_t u2, int64_t c0, int64_t c2, int64_t r, int64_t *lo,
                      int64_t *hi)
{
    int64_t a = (c0 * c0 + c2 * c2) >> 30; /* |c_xz|², Q30 */
    if (a == 0)                            /* along the axis: inside the disc or not */
        return u0 * u0 + u2 * u2 <= r * r;
    int64_t cn = (int64_t)collider_isqrt64((uint64_t)a << 30); /* |c_xz|, Q30 */
    int64_t dot = u0 * c0 + u2 * c2, cross = u0 * c2 - u2 * c0;
    int64_t t0 = floor_div(-dot, a); /* closest approach */
    int64_t dperp = floor_div(cross < 0 ? -cross : cross, cn);
    if (dperp > r)
        return 0;
    int64_t chord = (int64_t)collider_isqrt64((uint64_t)(r * r - dperp * dperp));
    int64_t half_tau = floor_div(chord * ((int64_t)1 << 30), cn);
    if (t0 - half_tau > *lo)
        *lo = t0 - half_tau;
    if (t0 + half_tau < *hi)
        *hi = t0 + half_tau;
    return *lo <= *hi;
}

/*
 * A triangle (x, y relative to the instance's first cell centre, z
 * absolute; 9 words) at the cell offset (px, py): integer edge functions,
 * inclusive on every edge (a minimum does not mind a cell counted by two
 * triangles), and the plane's height floor(z0 + (E1 dz1 + E2 dz2) / A).
 * A vertical triangle (A = 0) covers nothing: its neighbours give the bottom.
 */
static int triangle_fixed(const int64_t *t, int64_t px, int64_t py, int64_t *z)
{
    int64_t x0 = t[0], y0 = t[1], z0 = t[2], x1 = t[3], y1 = t[4], z1 = t[5];
    int64_t x2 = t[6], y2 = t[7], z2 = t[8];
    int64_t e0 = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1);
    int64_t e1 = (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2);
    int64_t e2 = (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0);
    int64_t area = e0 + e1 + e2;
    if (area == 0)
        return 0;
    if (area < 0) {
        e0 = -e0;
        e1 = -e1;
        e2 = -e2;
        area = -area;
    }
    if (e0 < 0 || e1 < 0 || e2 < 0)
        return 0;
    *z = z0 + floor_div(e1 * (z1 - z0) + e2 * (z2 - z0), area);
    return 1;
}

int collider_fixed_supported(const collider_geometry *g)
{
    return g->shape != COLLIDER_MESH || g->mesh != NULL;
}

/*
 * The cells of the window whose centres lie in a triangle's bounding box, on
 * the fixed grid itself (cell X's centre is X step + step / 2): exactly the
 * cells its inclusive edge test can hit, so none is visited in vain and a
 * triangle between cell centres, or vertical (no area in plan, it covers
 * nothing), makes no instance at all (issue 20, item 3: at the default mesh
 * limits most triangles are smaller than a cell, and the span one cell wider
 * each way made each of them nine cells' work). The bottoms are the same:
 * only cells the test can never hit are left out. 0 when none.
 */
static int fixed_span(const int64_t *a, const int64_t *b, const int64_t *c, int64_t step,
                      world_rect window, int *x0, int *x1, int *y0, int *y1)
{
    int64_t area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if (area == 0)
        return 0;
    int64_t lo_x = a[0] < b[0] ? a[0] : b[0], hi_x = a[0] > b[0] ? a[0] : b[0];
    int64_t lo_y = a[1] < b[1] ? a[1] : b[1], hi_y = a[1] > b[1] ? a[1] : b[1];
    lo_x = c[0] < lo_x ? c[0] : lo_x;
    hi_x = c[0] > hi_x ? c[0] : hi_x;
    lo_y = c[1] < lo_y ? c[1] : lo_y;
    hi_y = c[1] > hi_y ? c[1] : hi_y;
    int64_t half = step / 2;
    int64_t cx0 = ceil_div(lo_x - half, step), cx1 = floor_div(hi_x - half, step);
    int64_t cy0 = ceil_div(lo_y - half, step), cy1 = floor_div(hi_y - half, step);
    int64_t wx0 = window.x, wx1 = (int64_t)window.x + window.w - 1;
    int64_t wy0 = window.y, wy1 = (int64_t)window.y + window.h - 1;
    if (cx0 > cx1 || cy0 > cy1 || cx1 < wx0 || cx0 > wx1 || cy1 < wy0 || cy0 > wy1)
        return 0;
    *x0 = (int)(cx0 < wx0 ? wx0 : cx0);
    *x1 = (int)(cx1 > wx1 ? wx1 : cx1);
    *y0 = (int)(cy0 < wy0 ? wy0 : cy0);
    *y1 = (int)(cy1 > wy1 ? wy1 : cy1);
    return 1;
}

int collider_fixed_mesh_prepare(const collider_geometry *g, collider_pose pose, world_rect window,
                                double cell_size_m, int32_t units_per_m, collider_fixed **out,
                                int64_t *count, int64_t *capacity)
{
    const collider_mesh *m = g->mesh;
    if (g->shape != COLLIDER_MESH || !m || window.w <= 0 || window.h <= 0 || !(cell_size_m > 0.0) ||
        m->vertex_count <= 0)
        return 0;
    vec3d *wv = malloc((size_t)m->vertex_count * sizeof *wv);
    int64_t *fv = malloc((size_t)m->vertex_count * 3 * sizeof *fv);
    if (!wv || !fv) {
        free(wv);
        free(fv);
        return -1;
    }
    quatd q = quat_normalize(pose.orientation);
    for (int i = 0; i < m->vertex_count; i++) {
        const float *s = m->vertices + 3 * (size_t)i;
        vec3d r = quat_rotate(q, (vec3d){s[0], s[1], s[2]});
        wv[i] = (vec3d){r.x + pose.position.x, r.y + pose.position.y, r.z + pose.position.z};
    }
    /* S from the largest triangle (plus two cells): every edge-function
     * product and plane term then fits in int64 */
    double ext = 0.0;
    for (int k = 0; k < m->triangle_count; k++) {
        const uint32_t *ix = m->indices + 3 * (size_t)k;
        for (int j = 0; j < 3; j++) { /* finite: plain compares are fmax, and cheaper */
            vec3d a = wv[ix[j]], b = wv[ix[(j + 1) % 3]];
            double dx = fabs(a.x - b.x), dy = fabs(a.y - b.y), dz = fabs(a.z - b.z);
            double d = dx > dy ? dx : dy;
            d = dz > d ? dz : d;
            ext = d > ext ? d : ext;
        }
    }
    ext = (ext + 2.0 * cell_size_m) * (double)units_per_m;
    int s = 16;
    while (s > 0 && ext * ldexp(1.0, s) >= ldexp(1.0, 19))
        s--;
    double scale = (double)units_per_m * ldexp(1.0, s);
    for (int i = 0; i < m->vertex_count; i++) { /* once per vertex: shared edges agree */
        fv[3 * i + 0] = to_fixed_scaled(wv[i].x, scale);
        fv[3 * i + 1] = to_fixed_scaled(wv[i].y, scale);
        fv[3 * i + 2] = to_fixed_scaled(wv[i].z, scale);
    }
    int64_t step = to_fixed(cell_size_m, units_per_m, s);
    int added = 0;
    for (int k = 0; k < m->triangle_count; k++) {
        const uint32_t *ix = m->indices + 3 * (size_t)k;
        int x0, x1, y0, y1;
        if (!fixed_span(fv + 3 * (size_t)ix[0], fv + 3 * (size_t)ix[1], fv + 3 * (size_t)ix[2],
                        step, window, &x0, &x1, &y0, &y1))
            continue;
        if (array_grow((void **)out, capacity, *count + 1, sizeof **out) != 0) {
            free(wv);
            free(fv);
            return -1;
        }
        collider_fixed *f = &(*out)[(*count)++];
        for (int i = 0; i < COLLIDER_FIXED_WORDS; i++)
            f->v[i] = 0;
        f->v[CF_SHAPE] = COLLIDER_MESH;
        f->v[CF_X0] = x0 - window.x;
        f->v[CF_Y0] = y0 - window.y;
        f->v[CF_W] = x1 - x0 + 1;
        f->v[CF_H] = y1 - y0 + 1;
        f->v[CF_SHIFT] = s;
        f->v[CF_STEP] = step;
        /* cell X's centre is X step + step / 2 on this grid, exactly */
        int64_t ox = (int64_t)x0 * step + step / 2, oy = (int64_t)y0 * step + step / 2;
        for (int j = 0; j < 3; j++) {
            f->v[CF_ROT + 3 * j + 0] = fv[3 * (size_t)ix[j] + 0] - ox;
            f->v[CF_ROT + 3 * j + 1] = fv[3 * (size_t)ix[j] + 1] - oy;
            f->v[CF_ROT + 3 * j + 2] = fv[3 * (size_t)ix[j] + 2];
        }
        added++;
    }
    free(wv);
    free(fv);
    return added;
}

int collider_fixed_prepare(const collider_geometry *g, collider_pose pose, world_rect window,
                           double cell_size_m, int32_t units_per_m, collider_fixed *out)
{
    if (g->shape == COLLIDER_MESH || window.w <= 0 || window.h <= 0 || !(cell_size_m > 0.0))
        return 0; /* meshes: collider_fixed_mesh_prepare, an instance per triangle */
    vec3d lo, hi;
    collider_bounds(g, pose, &lo, &hi);
    /* the cells whose centres may be inside, one cell wider each way: the
     * integer test decides, the span only has to hold it */
    double a = ceil(lo.x / cell_size_m - 0.5) - 1, b = floor(hi.x / cell_size_m - 0.5) + 1;
    double c = ceil(lo.y / cell_size_m - 0.5) - 1, d = floor(hi.y / cell_size_m - 0.5) + 1;
    double wx0 = window.x, wx1 = (double)window.x + window.w - 1;
    double wy0 = window.y, wy1 = (double)window.y + window.h - 1;
    if (!(a <= b && c <= d) || b < wx0 || a > wx1 || d < wy0 || c > wy1)
        return 0;
    int x0 = (int)(a < wx0 ? wx0 : a), x1 = (int)(b > wx1 ? wx1 : b);
    int y0 = (int)(c < wy0 ? wy0 : c), y1 = (int)(d > wy1 ? wy1 : d);
    /* S: as fine as 1/65536 unit while every offset the rule meets (the
     * shape's reach and two cells) stays under 2^29 fixed units, so every
     * product and square below fits in int64 */
    double extent = (collider_reach(g) + 2.0 * cell_size_m) * (double)units_per_m;
    int s = 16;
    while (s > 0 && extent * ldexp(1.0, s) >= ldexp(1.0, 29))
        s--;
    for (int i = 0; i < COLLIDER_FIXED_WORDS; i++)
        out->v[i] = 0;
    out->v[CF_SHAPE] = g->shape;
    out->v[CF_X0] = x0 - window.x;
    out->v[CF_Y0] = y0 - window.y;
    out->v[CF_W] = x1 - x0 + 1;
    out->v[CF_H] = y1 - y0 + 1;
    out->v[CF_SHIFT] = s;
    out->v[CF_CX0] = to_fixed(((double)x0 + 0.5) * cell_size_m - pose.position.x, units_per_m, s);
    out->v[CF_CY0] = to_fixed(((double)y0 + 0.5) * cell_size_m - pose.position.y, units_per_m, s);
    out->v[CF_STEP] = to_fixed(cell_size_m, units_per_m, s);
    out->v[CF_CZ] = to_fixed(pose.position.z, units_per_m, s);
    out->v[CF_R] = to_fixed(g->radius, units_per_m, s);
    out->v[CF_H0] = to_fixed(g->shape == COLLIDER_BOX ? g->half_extents.x : 0.0, units_per_m, s);
    out->v[CF_H1] =
        to_fixed(g->shape == COLLIDER_BOX ? g->half_extents.y : g->half_length, units_per_m, s);
    out->v[CF_H2] = to_fixed(g->shape == COLLIDER_BOX ? g->half_extents.z : 0.0, units_per_m, s);
    /* Rᵀ in Q30, row j = local axis j in world coordinates */
    quatd q = quat_normalize(pose.orientation);
    vec3d axes[3] = {quat_rotate(q, (vec3d){1, 0, 0}), quat_rotate(q, (vec3d){0, 1, 0}),
                     quat_rotate(q, (vec3d){0, 0, 1})};
    for (int j = 0; j < 3; j++) {
        out->v[CF_ROT + 3 * j + 0] = (int64_t)nearbyint(axes[j].x * 1073741824.0);
        out->v[CF_ROT + 3 * j + 1] = (int64_t)nearbyint(axes[j].y * 1073741824.0);
        out->v[CF_ROT + 3 * j + 2] = (int64_t)nearbyint(axes[j].z * 1073741824.0);
    }
    /* a capsule's end centres, ± half_length along local y, rotated here */
    out->v[CF_END + 0] = to_fixed(axes[1].x * g->half_length, units_per_m, s);
    out->v[CF_END + 1] = to_fixed(axes[1].y * g->half_length, units_per_m, s);
    out->v[CF_END + 2] = to_fixed(axes[1].z * g->half_length, units_per_m, s);
    return 1;
}

/* The rule at cell (x0 + lx, y0 + ly): 1 and *bottom set where the shape
 * covers it. The shape is given: a constant where it is inlined, so each
 * shape's loop keeps only its own branch. */
static FIXED_INLINE int fixed_cell(const collider_fixed *f, int64_t shape, int64_t lx, int64_t ly,
                                   int32_t *bottom)
{
    const int64_t *v = f->v;
    int64_t r = v[CF_R];
    int64_t dx = v[CF_CX0] + lx * v[CF_STEP], dy = v[CF_CY0] + ly * v[CF_STEP];
    int64_t tau = 0;
    int hit = 0;
    if (shape == COLLIDER_SPHERE) {
        hit = sphere_fixed(dx, dy, r, &tau);
    } else if (shape == COLLIDER_MESH) {
        hit = triangle_fixed(v + CF_ROT, dx, dy, &tau);
    } else if (shape == COLLIDER_BOX) {
        /* the general branch's slabs, each offset computed only when the
         * slab before it holds (no side effects: the same τ) */
        const int64_t *m = v + CF_ROT;
        int64_t lo = -TAU_LIMIT, hi = TAU_LIMIT;
        hit = slab_fixed(floor_shift(m[0] * dx + m[1] * dy, 30), m[2], v[CF_H0], &lo, &hi) &&
              slab_fixed(floor_shift(m[3] * dx + m[4] * dy, 30), m[5], v[CF_H1], &lo, &hi) &&
              slab_fixed(floor_shift(m[6] * dx + m[7] * dy, 30), m[8], v[CF_H2], &lo, &hi);
        tau = lo;
    } else {
        int64_t u[3], cz[3];
        for (int j = 0; j < 3; j++) {
            const int64_t *m = v + CF_ROT + 3 * j;
            u[j] = floor_shift(m[0] * dx + m[1] * dy, 30); /* = floor_div by 2^30, no divide */
            cz[j] = m[2];
        }
        int64_t lo = -TAU_LIMIT, hi = TAU_LIMIT;
        /* cylinder, and the capsule's middle */
        hit = slab_fixed(u[1], cz[1], v[CF_H1], &lo, &hi) &&
              disc_fixed(u[0], u[2], cz[0], cz[2], r, &lo, &hi);
        tau = lo;
        if (shape == COLLIDER_CAPSULE) {
            for (int e = -1; e <= 1; e += 2) {
                int64_t t;
                if (sphere_fixed(dx - e * v[CF_END + 0], dy - e * v[CF_END + 1], r, &t)) {
                    t += e * v[CF_END + 2];
                    if (!hit || t < tau)
                        tau = t;
                    hit = 1;
                }
            }
        }
    }
    if (!hit)
        return 0;
    if (tau < -TAU_LIMIT)
        tau = -TAU_LIMIT;
    int64_t u = floor_shift(v[CF_CZ] + tau, v[CF_SHIFT]);
    if (u < (int64_t)WORLD_HEIGHT_MIN - 1)
        u = (int64_t)WORLD_HEIGHT_MIN - 1;
    if (u > (int64_t)WORLD_HEIGHT_MAX + 1)
        u = (int64_t)WORLD_HEIGHT_MAX + 1;
    *bottom = (int32_t)u;
    return 1;
}

/* The instance's cells for one shape (a constant after inlining). */
static FIXED_INLINE void fixed_apply_shape(const collider_fixed *f, int64_t shape, int32_t *bottom,
                                           int window_w)
{
    for (int64_t ly = 0; ly < f->v[CF_H]; ly++) {
        int32_t *row = bottom + (size_t)(f->v[CF_Y0] + ly) * (size_t)window_w + f->v[CF_X0];
        for (int64_t lx = 0; lx < f->v[CF_W]; lx++) {
            int32_t u;
            if (fixed_cell(f, shape, lx, ly, &u) && u < row[lx])
                row[lx] = u;
        }
    }
}

void collider_fixed_apply(const collider_fixed *f, int32_t *bottom, int window_w)
{
    switch (f->v[CF_SHAPE]) {
    case COLLIDER_SPHERE:
        fixed_apply_shape(f, COLLIDER_SPHERE, bottom, window_w);
        break;
    case COLLIDER_BOX:
        fixed_apply_shape(f, COLLIDER_BOX, bottom, window_w);
        break;
    case COLLIDER_MESH:
        fixed_apply_shape(f, COLLIDER_MESH, bottom, window_w);
        break;
    default:
        fixed_apply_shape(f, f->v[CF_SHAPE], bottom, window_w);
        break;
    }
}
