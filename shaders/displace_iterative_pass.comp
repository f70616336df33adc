#version 430 core
/*
 * displace_iterative_pass.comp: one pass of iterative displacement
 * (displace_iterative in sim_stages.c); the host runs displace_iterations
 * of them, ping-ponging the transit buffers. Material moves one cell per
 * pass from each column to the neighbours in its mask, split evenly; the
 * remainder of the split stays. Seeds deposit what they receive. A deposit
 * or a column's transit beyond INT32_MAX refuses the window, exactly where
 * the C returns SIM_WINDOW_HEIGHT_LIMIT (sums are exact 64-bit, emulated).
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_mask;
layout(binding = 3) uniform isamplerBuffer u_transit_in;
layout(std430, binding = 2) writeonly buffer transit_out_buf { int transit_out[]; };
layout(std430, binding = 3) buffer deposit_buf { int deposit[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    if (window_refused(win.index))
        return; /* the C has stopped here already; the window is discarded */
    int count = fetch(u_mask, c) >> 8;
    int own = fetch(u_transit_in, c);
    uvec2 total = i64(count > 0 ? own % count : own);
    uvec2 inflow = uvec2(0u);
    for (int j = 0; j < 8; j++) {
        int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= win.w || qy >= win.h)
            continue;
        int q = win.offset + qy * win.w + qx;
        /* does q send to i? i is q's neighbour in the opposite direction */
        int back = j ^ 1; /* pairs (0,1) (2,3) (4,5) (6,7) are opposite */
        if (j >= 4)
            back = 11 - j; /* (4,7) (5,6): diagonals are opposite across */
        int mask_q = fetch(u_mask, q);
        if ((mask_q & (1 << back)) != 0)
            inflow = i64_add(inflow, i64(fetch(u_transit_in, q) / (mask_q >> 8)));
    }
    if (fetch(u_cls, c) == CELL_SEED) {
        uvec2 d = i64_add(i64(deposit[c]), inflow);
        if (i64_gt(d, i64(INT32_MAX_V))) {
            refuse_window(win.index);
            return;
        }
        deposit[c] = int(d.x);
        transit_out[c] = 0;
    } else {
        total = i64_add(total, inflow);
        if (i64_gt(total, i64(INT32_MAX_V))) {
            refuse_window(win.index);
            return;
        }
        transit_out[c] = int(total.x);
    }
}
