#version 430 core
/*
 * displace_iterative_pass.comp: one pass of iterative displacement
 * (displace_iterative in sim_stages.c); the host runs displace_iterations
 * of them, ping-ponging the mask and share buffers. Material moves one cell
 * per pass from each column to the neighbours in its mask, split evenly; the
 * remainder of the split stays. Seeds deposit what they receive. A deposit
 * or a column's transit beyond INT32_MAX refuses the window, exactly where
 * the C returns SIM_WINDOW_HEIGHT_LIMIT (sums are exact 64-bit, emulated).
 *
 * Representation (displace_iterative_init.comp): the C's transit[q] /
 * count[q] is the neighbour's share word, transit % count the remainder in
 * bits 12..14 of the mask word, and a seed's share word is its deposit.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_mask_in;
layout(binding = 3) uniform isamplerBuffer u_share_in;
layout(std430, binding = 2) writeonly buffer mask_out_buf { int mask_out[]; };
layout(std430, binding = 3) writeonly buffer share_out_buf { int share_out[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    if (window_refused(win.index))
        return; /* the C has stopped here already; the window is discarded */
    int mask = fetch(u_mask_in, c);
    int count = (mask >> 8) & 15;
    int own = fetch(u_share_in, c);
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
        if ((fetch(u_mask_in, q) & (1 << back)) != 0)
            inflow = i64_add(inflow, i64(fetch(u_share_in, q))); /* transit[q] / count[q] */
    }
    if (fetch(u_cls, c) == CELL_SEED) {
        uvec2 d = i64_add(i64(own), inflow); /* own: the deposit so far */
        if (i64_gt(d, i64(INT32_MAX_V))) {
            refuse_window(win.index);
            return;
        }
        share_out[c] = int(d.x);
        mask_out[c] = mask;
    } else {
        /* the C's total: transit % count, or all of it without receivers */
        uvec2 total = i64(count > 0 ? mask >> 12 : own);
        total = i64_add(total, inflow);
        if (i64_gt(total, i64(INT32_MAX_V))) {
            refuse_window(win.index);
            return;
        }
        int next = int(total.x);
        int part = count > 0 ? next / count : next;
        share_out[c] = part;
        mask_out[c] = (mask & 0xfff) | (next - part * max(count, 1)) << 12;
    }
}
