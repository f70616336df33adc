#version 430 core
/*
 * classify.comp: the first integer stage of a tick, right after depth
 * (sim_classify in sim_stages.c). Per cell: the penetration of the lowest
 * collider into the column, the part of it that is displaced (the rest is
 * compacted away), and the class (seed / obstacle / penetrating). Each
 * cell's material row and compaction memory decide how far the column
 * yields and how much is compacted (sim_classify_materials); the uniform
 * path is row 0 of a one-row table of the params, as on the CPU.
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
/* id | compaction memory << 8 per cell; only bound (and read) when
 * u_materials_on; otherwise every cell is row 0 with no memory. The
 * memory is updated in place (sim_compaction_commit); the host reads it
 * back for accepted windows only. */
layout(std430, binding = 6) buffer material_buf { int material_word[]; };

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
    int word = u_materials_on != 0 ? material_word[c] : 0;
    int id = material_id(word);
    int max_m = u_material_max_compaction[id];
    int raw = pen, compacted;
    if (max_m > 0) { /* only with a material buffer: the params' row has none */
        int m = min(word >> 8, max_m);
        int hardness_q16 = int((uint(m) << 16u) / uint(max_m));
        raw = pen - mul_q16_shift(pen, hardness_q16, 16);
        compacted = min(mul_q16_shift(raw, u_material_rows[id].x, 16), max_m - m);
        material_word[c] = (word & 255) | ((m + compacted) << 8);
    } else {
        compacted = mul_q16_shift(pen, u_material_rows[id].x, 16);
    }
    moved[c] = raw - compacted;
    cls[c] = cl;
    heights[c] = h - raw;
    seed[c] = cl == CELL_SEED ? seed_pack(x, y) : -1;
}
