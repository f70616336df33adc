#version 430 core
/*
 * displace_iterative_init.comp: set-up of iterative displacement (thesis
 * method 1, Listing 4.2; displace_iterative in sim_stages.c), after jump
 * flooding. Per cell: the material in transit (the displaced material of a
 * penetrating column, 0 elsewhere), an empty deposit, and the mask of
 * neighbours that receive from it: those strictly closer to a seed that are
 * not obstacles (bit j for neighbour j, the count in bits 8..11).
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
layout(std430, binding = 3) writeonly buffer transit_buf { int transit[]; };
layout(std430, binding = 4) writeonly buffer deposit_buf { int deposit[]; };

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
    mask[c] = bits | count << 8;
    transit[c] = fetch(u_cls, c) == CELL_PENETRATING ? fetch(u_moved, c) : 0;
    deposit[c] = 0;
}
