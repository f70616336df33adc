#version 430 core
/*
 * displace_multi.comp: multiple-target displacement (thesis method 3;
 * displace_multi in sim_stages.c), after jump flooding. From its seed, each
 * penetrating column marches away from itself, one target per
 * multi_target_step units of material (at most multi_target_max), stopping
 * at the window edge or at the first column that is not a seed. Each placed
 * target gets amount / targets; what the missing targets and the division
 * leave over goes to the last valid target, so every unit lands somewhere.
 * Sums are exact 64-bit atomics as in displace_ssbo.comp; displace_land.comp
 * adds them to the heights.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_seed;
layout(binding = 3) uniform isamplerBuffer u_moved;
layout(std430, binding = 2) coherent buffer received_lo_buf { uint received_lo[]; };
layout(std430, binding = 3) coherent buffer received_hi_buf { uint received_hi[]; };

/* received[c] += v for 0 <= v < 2^31, exactly. */
void receive(int c, int v)
{
    uint old = atomicAdd(received_lo[c], uint(v));
    if (old + uint(v) < old)
        atomicAdd(received_hi[c], 1u);
}

void main()
{
    int px, py, c;
    cell_window win;
    if (!locate_cell(win, px, py, c))
        return;
    int amount = fetch(u_moved, c);
    if (fetch(u_cls, c) != CELL_PENETRATING || amount == 0)
        return;
    int s = fetch(u_seed, c);
    if (s < 0) {
        receive(c, amount);
        return;
    }
    int w = win.w, h = win.h;
    int targets = (amount - 1) / u_multi_target_step + 1;
    if (targets > u_multi_target_max)
        targets = u_multi_target_max;
    int share = amount / targets;
    int sx = seed_x(s), sy = seed_y(s);
    int dx = sx - px, dy = sy - py;
    int adx = abs(dx), ady = abs(dy);
    int len = max(adx, ady); /* >= 1: a seed is never penetrating */
    int sgx = dx < 0 ? -1 : 1, sgy = dy < 0 ? -1 : 1;
    int last = sy * w + sx, placed = 0;
    for (int t = 0; t < targets; t++) {
        int tx = sx + sgx * (adx * t / len);
        int ty = sy + sgy * (ady * t / len);
        if (tx < 0 || ty < 0 || tx >= w || ty >= h)
            break;
        int ti = ty * w + tx;
        if (fetch(u_cls, win.offset + ti) != CELL_SEED)
            break;
        receive(win.offset + ti, share);
        placed += share;
        last = ti;
    }
    receive(win.offset + last, amount - placed);
}
