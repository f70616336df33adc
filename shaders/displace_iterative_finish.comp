#version 430 core
/*
 * displace_iterative_finish.comp: the end of iterative displacement
 * (displace_iterative in sim_stages.c). Each column adds its deposit and the
 * material still in transit (the next tick moves it on); a column that would
 * rise above WORLD_HEIGHT_MAX refuses the whole window.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_transit;
layout(binding = 2) uniform isamplerBuffer u_deposit;
layout(std430, binding = 2) buffer heights_buf { int heights[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int h = heights[c];
    int deposit = fetch(u_deposit, c), transit = fetch(u_transit, c);
    uvec2 add = i64_add(i64(deposit), i64(transit));
    /* add > (int64)WORLD_HEIGHT_MAX - h */
    if (i64_gt(add, i64_sub(i64(HEIGHT_MAX), i64(h)))) {
        refuse_window(win.index);
        return;
    }
    heights[c] = h + deposit + transit;
}
