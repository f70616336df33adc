#version 430 core
/*
 * displace_ssbo.comp: single-target displacement (thesis method 2;
 * displace_single in sim_stages.c), after jump flooding. Each penetrating
 * column sends all of its displaced material to its nearest seed, or keeps
 * it when the window has no seed. The received amounts are exact 64-bit
 * sums: atomic adds on the low word, and a carry into the high word when the
 * low word wraps (atomic adds commute, so the sum is deterministic).
 * displace_land.comp then adds them to the heights.
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
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int amount = fetch(u_moved, c);
    if (fetch(u_cls, c) != CELL_PENETRATING || amount == 0)
        return;
    int s = fetch(u_seed, c);
    /* No seed in the window: nowhere to go, the material stays home. */
    int target = s >= 0 ? win.offset + seed_y(s) * win.w + seed_x(s) : c;
    receive(target, amount);
}
