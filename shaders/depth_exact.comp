#version 430 core
#extension GL_ARB_gpu_shader_int64 : require
/*
 * depth_exact.comp: the depth stage's fixed-point shapes (issue 12, item 4),
 * run after depth_clear.comp has set the bottoms to "none". The GLSL
 * twin of server/collider/depth_fixed.c, the specification: each workgroup
 * row (gl_WorkGroupID.y) is one instance — a shape at one sub-step pose over
 * one window, prepared on the CPU as int64 words — and every invocation
 * evaluates the same integer rule as collider_fixed_cell on the cells of
 * the instance, lowering the window's bottom by atomicMin (a minimum does
 * not depend on the order instances run in). No floating point at all.
 */
#include "common.glsl"

layout(local_size_x = 64) in;

layout(std430, binding = 2) coherent buffer bottom_buf { int bottom[]; };
layout(std430, binding = 3) readonly buffer instance_buf { int64_t inst[]; };

uniform int u_step; /* first instance of this dispatch */

#define WORDS 28
#define SHAPE_SPHERE 0
#define SHAPE_BOX 1
#define SHAPE_CAPSULE 2
#define SHAPE_CYLINDER 3
#define SHAPE_MESH 4
#define CF_SHAPE 0
#define CF_WINDOW 1
#define CF_X0 2
#define CF_Y0 3
#define CF_W 4
#define CF_H 5
#define CF_SHIFT 6
#define CF_CX0 7
#define CF_CY0 8
#define CF_STEP 9
#define CF_CZ 10
#define CF_R 11
#define CF_H0 12
#define CF_H1 13
#define CF_H2 14
#define CF_ROT 15
#define CF_END 24
#define TAU_LIMIT (1L << 60)

uint64_t isqrt64(uint64_t v)
{
    uint64_t r = 0UL, bit = 1UL << 62;
    while (bit > v)
        bit >>= 2;
    while (bit != 0UL) {
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

int64_t floor_shift(int64_t v, int s)
{
    if (v >= 0L)
        return v >> s;
    return -int64_t((uint64_t(-v) + ((1UL << s) - 1UL)) >> s);
}

int64_t floor_div(int64_t a, int64_t b)
{
    bool neg = (a < 0L) != (b < 0L);
    uint64_t ua = a < 0L ? 0UL - uint64_t(a) : uint64_t(a);
    uint64_t ub = b < 0L ? 0UL - uint64_t(b) : uint64_t(b);
    uint64_t q = ua / ub, r = ua % ub;
    if (neg)
        return -int64_t(q + (r != 0UL ? 1UL : 0UL));
    return int64_t(q);
}

int64_t ceil_div(int64_t a, int64_t b)
{
    return -floor_div(-a, b);
}

bool slab_fixed(int64_t u, int64_t c, int64_t h, inout int64_t lo, inout int64_t hi)
{
    if (c == 0L)
        return u >= -h && u <= h;
    int64_t a = (-h - u) * (1L << 30), b = (h - u) * (1L << 30);
    int64_t t0 = c > 0L ? ceil_div(a, c) : ceil_div(b, c);
    int64_t t1 = c > 0L ? floor_div(b, c) : floor_div(a, c);
    if (t0 > lo)
        lo = t0;
    if (t1 < hi)
        hi = t1;
    return lo <= hi;
}

bool sphere_fixed(int64_t dx, int64_t dy, int64_t r, out int64_t tau)
{
    tau = 0L;
    if (dx < -r || dx > r || dy < -r || dy > r)
        return false;
    int64_t s = r * r - dx * dx;
    if (s < dy * dy)
        return false;
    s -= dy * dy;
    tau = -int64_t(isqrt64(uint64_t(s)));
    return true;
}

bool disc_fixed(int64_t u0, int64_t u2, int64_t c0, int64_t c2, int64_t r, inout int64_t lo,
                inout int64_t hi)
{
    int64_t a = (c0 * c0 + c2 * c2) >> 30;
    if (a == 0L)
        return u0 * u0 + u2 * u2 <= r * r;
    int64_t cn = int64_t(isqrt64(uint64_t(a) << 30));
    int64_t dot = u0 * c0 + u2 * c2, cross = u0 * c2 - u2 * c0;
    int64_t t0 = floor_div(-dot, a);
    int64_t dperp = floor_div(cross < 0L ? -cross : cross, cn);
    if (dperp > r)
        return false;
    int64_t chord = int64_t(isqrt64(uint64_t(r * r - dperp * dperp)));
    int64_t half_tau = floor_div(chord * (1L << 30), cn);
    if (t0 - half_tau > lo)
        lo = t0 - half_tau;
    if (t0 + half_tau < hi)
        hi = t0 + half_tau;
    return lo <= hi;
}

bool triangle_fixed(int t, int64_t px, int64_t py, out int64_t z)
{
    z = 0L;
    int64_t x0 = inst[t], y0 = inst[t + 1], z0 = inst[t + 2];
    int64_t x1 = inst[t + 3], y1 = inst[t + 4], z1 = inst[t + 5];
    int64_t x2 = inst[t + 6], y2 = inst[t + 7], z2 = inst[t + 8];
    int64_t e0 = (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1);
    int64_t e1 = (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2);
    int64_t e2 = (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0);
    int64_t area = e0 + e1 + e2;
    if (area == 0L)
        return false;
    if (area < 0L) {
        e0 = -e0;
        e1 = -e1;
        e2 = -e2;
        area = -area;
    }
    if (e0 < 0L || e1 < 0L || e2 < 0L)
        return false;
    z = z0 + floor_div(e1 * (z1 - z0) + e2 * (z2 - z0), area);
    return true;
}

/* collider_fixed_cell */
bool fixed_cell(int base, int64_t lx, int64_t ly, out int value)
{
    value = 0;
    int shape = int(inst[base + CF_SHAPE]);
    int64_t r = inst[base + CF_R];
    int64_t dx = inst[base + CF_CX0] + lx * inst[base + CF_STEP];
    int64_t dy = inst[base + CF_CY0] + ly * inst[base + CF_STEP];
    int64_t tau = 0L;
    bool hit = false;
    if (shape == SHAPE_SPHERE) {
        hit = sphere_fixed(dx, dy, r, tau);
    } else if (shape == SHAPE_MESH) {
        hit = triangle_fixed(base + CF_ROT, dx, dy, tau);
    } else {
        int64_t u[3], cz[3];
        for (int j = 0; j < 3; j++) {
            int m = base + CF_ROT + 3 * j;
            u[j] = floor_div(inst[m] * dx + inst[m + 1] * dy, 1L << 30);
            cz[j] = inst[m + 2];
        }
        int64_t lo = -TAU_LIMIT, hi = TAU_LIMIT;
        if (shape == SHAPE_BOX) {
            hit = slab_fixed(u[0], cz[0], inst[base + CF_H0], lo, hi) &&
                  slab_fixed(u[1], cz[1], inst[base + CF_H1], lo, hi) &&
                  slab_fixed(u[2], cz[2], inst[base + CF_H2], lo, hi);
        } else {
            hit = slab_fixed(u[1], cz[1], inst[base + CF_H1], lo, hi) &&
                  disc_fixed(u[0], u[2], cz[0], cz[2], r, lo, hi);
        }
        tau = lo;
        if (shape == SHAPE_CAPSULE) {
            for (int e = -1; e <= 1; e += 2) {
                int64_t t;
                int64_t ee = int64_t(e);
                if (sphere_fixed(dx - ee * inst[base + CF_END], dy - ee * inst[base + CF_END + 1],
                                 r, t)) {
                    t += ee * inst[base + CF_END + 2];
                    if (!hit || t < tau)
                        tau = t;
                    hit = true;
                }
            }
        }
    }
    if (!hit)
        return false;
    if (tau < -TAU_LIMIT)
        tau = -TAU_LIMIT;
    int64_t u = floor_shift(inst[base + CF_CZ] + tau, int(inst[base + CF_SHIFT]));
    /* no clamp() on int64: it crashed llvmpipe (Mesa 22.3) */
    if (u < int64_t(HEIGHT_MIN - 1))
        u = int64_t(HEIGHT_MIN - 1);
    if (u > int64_t(HEIGHT_MAX + 1))
        u = int64_t(HEIGHT_MAX + 1);
    value = int(u);
    return true;
}

void main()
{
    int base = (u_step + int(gl_WorkGroupID.y)) * WORDS;
    window_entry e = window_at(int(inst[base + CF_WINDOW]));
    int x0 = int(inst[base + CF_X0]), y0 = int(inst[base + CF_Y0]);
    int w = int(inst[base + CF_W]), h = int(inst[base + CF_H]);
    int stride = int(gl_NumWorkGroups.x) * 64;
    for (int c = int(gl_GlobalInvocationID.x); c < w * h; c += stride) {
        int lx = c % w, ly = c / w;
        int value;
        if (fixed_cell(base, int64_t(lx), int64_t(ly), value))
            atomicMin(bottom[e.offset + (y0 + ly) * e.w + x0 + lx], value);
    }
}
