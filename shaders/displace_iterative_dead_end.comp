#version 430 core
/*
 * displace_iterative_dead_end.comp: between the last pass of iterative
 * displacement and displace_iterative_finish.comp, the dead ends of
 * displace_iterative in sim_stages.c. A column that is not a seed, has a seed
 * and has no receiving neighbour (count 0: every neighbour closer to a seed
 * is an obstacle) hands its transit to its nearest seed; left in place it
 * would gather a collider's whole displaced volume tick after tick.
 *
 * Representation (displace_iterative_init.comp): with count 0 the share word
 * is the whole transit and the remainder 0, and a seed's share word is its
 * deposit, so a dead end atomically adds its share word into its seed's and
 * zeroes its own. Only seeds are added to and only dead ends zeroed, never
 * the same word. Integer addition commutes, so the sum is the C's whatever
 * the order; the C refuses the window when the deposit passes INT32_MAX, and
 * as every transit is >= 0 that happens exactly when some atomicAdd sees
 * old + transit > INT32_MAX (64-bit, emulated): that invocation refuses it.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_seed;
layout(binding = 3) uniform isamplerBuffer u_mask;
layout(std430, binding = 2) coherent buffer share_buf { int share[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    if (window_refused(win.index))
        return; /* the C has stopped already; the window is discarded */
    int s = fetch(u_seed, c);
    if (fetch(u_cls, c) == CELL_SEED || s < 0 || ((fetch(u_mask, c) >> 8) & 15) != 0)
        return;
    int transit = share[c];
    if (transit == 0)
        return;
    int old = atomicAdd(share[win.offset + seed_y(s) * win.w + seed_x(s)], transit);
    if (i64_gt(i64_add(i64(old), i64(transit)), i64(INT32_MAX_V)))
        refuse_window(win.index);
    share[c] = 0;
}
