#version 430 core
/*
 * displace_iterative_finish.comp: the end of iterative displacement
 * (displace_iterative in sim_stages.c). Each column adds its deposit and the
 * material still in transit (the next tick moves it on); a column that would
 * rise above WORLD_HEIGHT_MAX refuses the whole window. With the split
 * representation of displace_iterative_init.comp, a seed's share word is its
 * deposit (its transit is 0) and any other column's transit is
 * share * count + remainder (its deposit is 0): the C's deposit + transit.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_mask;
layout(binding = 2) uniform isamplerBuffer u_share;
layout(std430, binding = 2) buffer heights_buf { int heights[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int h = heights[c];
    int mask = fetch(u_mask, c);
    int count = (mask >> 8) & 15;
    int add = fetch(u_share, c) * max(count, 1) + (mask >> 12);
    /* add > (int64)WORLD_HEIGHT_MAX - h */
    if (i64_gt(i64(add), i64_sub(i64(HEIGHT_MAX), i64(h)))) {
        refuse_window(win.index);
        return;
    }
    heights[c] = h + add;
}
