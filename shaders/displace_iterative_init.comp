#version 430 core
/*
 * displace_iterative_init.comp: set-up of iterative displacement (thesis
 * method 1, Listing 4.2; displace_iterative in sim_stages.c), after jump
 * flooding. Per cell: the mask of neighbours that receive from it — those
 * strictly closer to a seed that are not obstacles (bit j for neighbour j,
 * the count in bits 8..11) — and the material in transit (the displaced
 * material of a penetrating column, 0 elsewhere).
 *
 * The C keeps transit T and divides it by the count once per receiving
 * neighbour per pass. Here a cell stores T already split (see
 * displace_iterative_pass.comp): share = T / count in the share buffer and
 * the remainder T % count in bits 12..14 of the mask word, or share = T and
 * remainder 0 when count is 0. A seed's count is always 0 (nothing is closer
 * to a seed than distance 0) and its transit always 0, so a seed's share
 * word holds its deposit instead. Both are exact rewrites of the C's values,
 * and the pass then needs one division per cell instead of nine.
 *
 * The C computes a distance array first and the mask from it; here each
 * invocation recomputes its neighbours' distances from their seeds, which
 * gives the same numbers without another pass and buffer.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_seed;
layout(binding = 3) uniform isamplerBuffer u_moved;
layout(std430, binding = 2) writeonly buffer mask_buf { int mask[]; };
layout(std430, binding = 3) writeonly buffer share_buf { int share[]; };

/* Distance from window-local cell (x, y) to its seed, INT32_MAX without one. */
int seed_distance(cell_window win, int x, int y)
{
    int s = fetch(u_seed, win.offset + y * win.w + x);
    if (s < 0)
        return INT32_MAX_V;
    return metric_distance(seed_x(s) - x, seed_y(s) - y);
}

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int dist = seed_distance(win, x, y);
    int bits = 0, count = 0;
    for (int j = 0; j < 8; j++) {
        int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= win.w || qy >= win.h)
            continue;
        if (seed_distance(win, qx, qy) < dist &&
            fetch(u_cls, win.offset + qy * win.w + qx) != CELL_OBSTACLE) {
            bits |= 1 << j;
            count++;
        }
    }
    int transit = fetch(u_cls, c) == CELL_PENETRATING ? fetch(u_moved, c) : 0;
    int part = count > 0 ? transit / count : transit;
    int rest = transit - part * max(count, 1);
    mask[c] = bits | count << 8 | rest << 12;
    share[c] = part;
}
