#version 430 core
/*
 * tile_list.comp: the compacted list of jump flooding's work (sim_jump_flood
 * on the CPU visits only the cells that are not free). After classify, one
 * workgroup per 8x8 tile of the batch looks at its cells; a tile holding a
 * penetrated or obstacle cell appends its index to the list. A tile of free
 * cells only is left out: a free cell is its own nearest seed at distance 0,
 * which no candidate beats, so jump flooding never changes it. The order of
 * the list depends on the GPU's scheduling; the result does not (each listed
 * tile writes only its own cells). Each append also raises the rows of the
 * jump-flood steps' indirect dispatch (rows of u_list_row groups; the host
 * starts the list at count 0, 0 rows).
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(std430, binding = 3) buffer tile_list_buf {
    uint tl_count;
    uint tl_groups[3]; /* glDispatchComputeIndirect's x (u_list_row), y (rows), z */
    int tl_tile[];
};

uniform int u_list_row;

shared uint busy;

void main()
{
    if (gl_LocalInvocationIndex == 0u)
        busy = 0u;
    barrier();
    int x, y, c;
    cell_window win;
    if (locate_cell(win, x, y, c) && fetch(u_cls, c) != CELL_SEED)
        atomicOr(busy, 1u);
    barrier();
    if (gl_LocalInvocationIndex == 0u && busy != 0u) {
        uint slot = atomicAdd(tl_count, 1u);
        tl_tile[slot] = int(gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x);
        atomicMax(tl_groups[1], slot / uint(u_list_row) + 1u);
    }
}
