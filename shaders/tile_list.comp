#version 430 core
/*
 * tile_list.comp: a compacted list of the tiles a sparse stage must visit,
 * one workgroup per 8x8 tile of the batch; a tile any of whose cells needs
 * it appends its index to the list.
 *
 * u_list_kind 0, jump flooding (after classify; sim_jump_flood on the CPU
 * visits only the cells that are not free): a tile holding a penetrated or
 * obstacle cell. A tile of free cells only is left out: a free cell is its
 * own nearest seed at distance 0, which no candidate beats, so jump flooding
 * never changes it.
 *
 * u_list_kind 1, slope evening's first iteration (the CPU's first work
 * list): a tile with a cell that differs from a neighbour by more than the
 * smallest repose threshold of any material. Elsewhere no flux of the
 * formula has a positive excess, so no height changes (a superset of the
 * CPU's list: a listed tile computes the exact update). The order of
 * the list depends on the GPU's scheduling; the result does not (each listed
 * tile writes only its own cells). Each append also raises the rows of the
 * jump-flood steps' indirect dispatch (rows of u_list_row groups; the host
 * starts the list at count 0, 0 rows).
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls; /* kind 1: the heights */
layout(std430, binding = 3) buffer tile_list_buf {
    uint tl_count;
    uint tl_groups[3]; /* glDispatchComputeIndirect's x (u_list_row), y (rows), z */
    int tl_tile[];
};

uniform int u_list_row;
uniform int u_list_kind;

/* Kind 1: can a flux leave or enter cell (x, y)? */
bool slope_may_move(cell_window win, int x, int y, int c)
{
    int th = 0x7fffffff;
    for (int m = 0; m < u_material_count; m++)
        th = min(th, min(u_material_rows[m].z, u_material_rows[m].w));
    int hc = fetch(u_cls, c);
    for (int j = 0; j < 8; j++) {
        int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= win.w || qy >= win.h)
            continue;
        int d = hc - fetch(u_cls, win.offset + qy * win.w + qx);
        if (d > th || -d > th)
            return true;
    }
    return false;
}

shared uint busy;

void main()
{
    if (gl_LocalInvocationIndex == 0u)
        busy = 0u;
    barrier();
    int x, y, c;
    cell_window win;
    if (locate_cell(win, x, y, c) &&
        (u_list_kind == 0 ? fetch(u_cls, c) != CELL_SEED : slope_may_move(win, x, y, c)))
        atomicOr(busy, 1u);
    barrier();
    if (gl_LocalInvocationIndex == 0u && busy != 0u) {
        uint slot = atomicAdd(tl_count, 1u);
        tl_tile[slot] = int(gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x);
        atomicMax(tl_groups[1], slot / uint(u_list_row) + 1u);
    }
}
