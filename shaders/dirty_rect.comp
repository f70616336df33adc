#version 430 core
/*
 * dirty_rect.comp: the last pass of a tick on the GPU, after slope evening.
 * Each window's dirty rectangle — the bounding box of the cells whose final
 * height differs from the height uploaded at the start of the tick — goes
 * into the status buffer after the status flags (STATUS_WORDS in
 * gl_internal.h): the host reads flags and rectangles back in one transfer,
 * then only the rows of each rectangle (chunk_readback); every other cell of
 * the window already holds its height on the host. One workgroup per tile
 * reduces its cells in shared memory first, so a tile costs at most four
 * global atomics.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_heights_final;
layout(binding = 2) uniform isamplerBuffer u_heights_uploaded;

shared uint min_x, min_y, max_x, max_y;

void main()
{
    if (gl_LocalInvocationIndex == 0u) {
        min_x = 0xffffffffu;
        min_y = 0xffffffffu;
        max_x = 0u;
        max_y = 0u;
    }
    barrier();
    int x, y, c;
    cell_window win;
    bool inside = locate_cell(win, x, y, c);
    if (inside && fetch(u_heights_final, c) != fetch(u_heights_uploaded, c)) {
        atomicMin(min_x, uint(x));
        atomicMin(min_y, uint(y));
        atomicMax(max_x, uint(x));
        atomicMax(max_y, uint(y));
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && inside && min_x <= max_x) {
        int base = u_window_count + 4 * win.index;
        atomicMin(status[base], min_x);
        atomicMin(status[base + 1], min_y);
        atomicMax(status[base + 2], max_x);
        atomicMax(status[base + 3], max_y);
    }
}
