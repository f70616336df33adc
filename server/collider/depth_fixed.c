/*
 * depth_fixed.c: the depth stage's fixed-point specification (issue 12,
 * item 4), step 5 of the tick on both backends. A GL raster of tessellated
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
 *
 * Shapes not listed here (boxes, cylinders, capsules, meshes) still take
 * the analytic double path on the CPU and the raster on GL: see
 * docs/core.md for what is exact.
 */
#include "collider/collider.h"

#include <math.h>

uint64_t collider_isqrt64(uint64_t v)
{
    /* digit by digit, two bits a step: the same loop as depth_exact.comp */
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

/* floor(v / 2^s) without relying on the sign behaviour of >> */
static int64_t floor_shift(int64_t v, int64_t s)
{
    if (v >= 0)
        return v >> s;
    return -(int64_t)(((uint64_t)(-v) + (((uint64_t)1 << s) - 1)) >> s);
}

/* metres → fixed units (1/2^s of a height unit), rounded, kept far from overflow */
static int64_t to_fixed(double metres, int32_t units_per_m, int s)
{
    double v = nearbyint(metres * (double)units_per_m * ldexp(1.0, s));
    const double lim = ldexp(1.0, 60);
    if (!(v > -lim)) /* also NaN */
        return -((int64_t)1 << 60);
    if (v > lim)
        return (int64_t)1 << 60;
    return (int64_t)v;
}

int collider_fixed_supported(const collider_geometry *g)
{
    return g->shape == COLLIDER_SPHERE;
}

int collider_fixed_prepare(const collider_geometry *g, collider_pose pose, world_rect window,
                           double cell_size_m, int32_t units_per_m, collider_fixed *out)
{
    if (!collider_fixed_supported(g) || window.w <= 0 || window.h <= 0 || !(cell_size_m > 0.0))
        return 0;
    vec3d lo, hi;
    collider_bounds(g, pose, &lo, &hi);
    /* the cells whose centres may be inside, one cell wider each way: the
     * integer test below decides, the span only has to hold it */
    double a = ceil(lo.x / cell_size_m - 0.5) - 1, b = floor(hi.x / cell_size_m - 0.5) + 1;
    double c = ceil(lo.y / cell_size_m - 0.5) - 1, d = floor(hi.y / cell_size_m - 0.5) + 1;
    double wx0 = window.x, wx1 = (double)window.x + window.w - 1;
    double wy0 = window.y, wy1 = (double)window.y + window.h - 1;
    if (!(a <= b && c <= d) || b < wx0 || a > wx1 || d < wy0 || c > wy1)
        return 0;
    int x0 = (int)(a < wx0 ? wx0 : a), x1 = (int)(b > wx1 ? wx1 : b);
    int y0 = (int)(c < wy0 ? wy0 : c), y1 = (int)(d > wy1 ? wy1 : d);
    /* S: as fine as 1/65536 unit while r stays under 2^31 fixed units */
    double r_units = g->radius * (double)units_per_m;
    int s = 16;
    while (s > 0 && r_units * ldexp(1.0, s) >= ldexp(1.0, 31))
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
    return 1;
}

int collider_fixed_cell(const collider_fixed *f, int64_t lx, int64_t ly, int32_t *bottom)
{
    const int64_t *v = f->v;
    int64_t r = v[CF_R];
    int64_t dx = v[CF_CX0] + lx * v[CF_STEP], dy = v[CF_CY0] + ly * v[CF_STEP];
    if (dx < -r || dx > r || dy < -r || dy > r)
        return 0;
    int64_t s = r * r - dx * dx; /* >= 0, < 2^62 */
    if (s < dy * dy)
        return 0;
    s -= dy * dy;
    int64_t z = v[CF_CZ] - (int64_t)collider_isqrt64((uint64_t)s);
    int64_t u = floor_shift(z, v[CF_SHIFT]);
    if (u < (int64_t)WORLD_HEIGHT_MIN - 1)
        u = (int64_t)WORLD_HEIGHT_MIN - 1;
    if (u > (int64_t)WORLD_HEIGHT_MAX + 1)
        u = (int64_t)WORLD_HEIGHT_MAX + 1;
    *bottom = (int32_t)u;
    return 1;
}

void collider_fixed_apply(const collider_fixed *f, int32_t *bottom, int window_w)
{
    for (int64_t ly = 0; ly < f->v[CF_H]; ly++) {
        int32_t *row = bottom + (size_t)(f->v[CF_Y0] + ly) * (size_t)window_w + f->v[CF_X0];
        for (int64_t lx = 0; lx < f->v[CF_W]; lx++) {
            int32_t u;
            if (collider_fixed_cell(f, lx, ly, &u) && u < row[lx])
                row[lx] = u;
        }
    }
}
