#version 430 core
/*
 * displace_land.comp: the end of single- and multiple-target displacement
 * (land_received in sim_stages.c). Adds each column's exact 64-bit received
 * sum to its height; if any column of a window would rise above
 * WORLD_HEIGHT_MAX, the window is refused as a whole (SIM_WINDOW_HEIGHT_LIMIT)
 * and the host keeps its old heights, so what this pass wrote there does not
 * matter.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_received_lo;
layout(binding = 2) uniform isamplerBuffer u_received_hi;
layout(std430, binding = 2) buffer heights_buf { int heights[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int h = heights[c];
    uvec2 received = uvec2(uint(fetch(u_received_lo, c)), uint(fetch(u_received_hi, c)));
    /* received > (int64)WORLD_HEIGHT_MAX - h */
    if (i64_gt(received, i64_sub(i64(HEIGHT_MAX), i64(h)))) {
        refuse_window(win.index);
        return;
    }
    heights[c] = h + int(received.x);
}
