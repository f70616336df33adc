#version 430 core
#extension GL_ARB_gpu_shader_int64 : require
/*
 * depth_exact.comp: the depth stage's fixed-point shapes (issue 12, item 4),
 * run after depth_to_bottom.comp has written the raster's bottoms. The GLSL
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

#define WORDS 24
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

/* collider_fixed_cell: the sphere */
bool fixed_cell(int base, int64_t lx, int64_t ly, out int value)
{
    int64_t r = inst[base + CF_R];
    int64_t dx = inst[base + CF_CX0] + lx * inst[base + CF_STEP];
    int64_t dy = inst[base + CF_CY0] + ly * inst[base + CF_STEP];
    value = 0;
    if (dx < -r || dx > r || dy < -r || dy > r)
        return false;
    int64_t s = r * r - dx * dx;
    if (s < dy * dy)
        return false;
    s -= dy * dy;
    int64_t z = inst[base + CF_CZ] - int64_t(isqrt64(uint64_t(s)));
    int64_t u = floor_shift(z, int(inst[base + CF_SHIFT]));
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
