#version 430 core
/*
 * classify.comp: the first integer stage of a tick, right after depth
 * (sim_classify in sim_stages.c). Per cell: the penetration of the lowest
 * collider into the column, the part of it that is displaced (the rest is
 * compacted away), and the class (seed / obstacle / penetrating).
 *
 * Two trivial per-cell steps of later stages are folded in to save passes,
 * with identical results: sim_displace's first step (heights -= raw; the raw
 * penetration is needed nowhere else) and sim_jump_flood's initialisation
 * (seed = own coordinates for seed cells, -1 otherwise).
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_bottom;
layout(std430, binding = 2) buffer heights_buf { int heights[]; };
layout(std430, binding = 3) writeonly buffer moved_buf { int moved[]; };
layout(std430, binding = 4) writeonly buffer cls_buf { int cls[]; };
layout(std430, binding = 5) writeonly buffer seed_buf { int seed[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    int h = heights[c], b = fetch(u_bottom, c);
    int pen = 0, cl = CELL_SEED;
    if (b != BOTTOM_NONE) {
        /* A collider below the floor pushes the column to the floor only. */
        int effective = b > u_floor ? b : u_floor;
        if (h > effective) {
            cl = CELL_PENETRATING;
            pen = h - effective;
        } else if (b - h <= u_obstacle_gap) {
            cl = CELL_OBSTACLE;
        }
    }
    moved[c] = pen - mul_q16_shift(pen, u_compression_q16, 16);
    cls[c] = cl;
    heights[c] = h - pen;
    seed[c] = cl == CELL_SEED ? seed_pack(x, y) : -1;
}
