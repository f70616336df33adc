#version 430 core
/*
 * even_slopes.comp: one Jacobi iteration of slope evening (sim_even_slopes
 * in sim_stages.c), the last stage of a tick; the host runs
 * slope_iterations of them, ping-ponging two height buffers. Every method
 * uses this one scheme: the original's read-modify-write of a single buffer
 * depended on thread order and could not match a CPU twin.
 *
 * The flux from column c to neighbour k is roughness/8 of the height
 * difference above the repose threshold (integer thresholds computed once on
 * the CPU), rounded down, and only towards free columns (seeds). Each flux
 * uses the material row of the column it leaves (sim_even_slopes_materials);
 * the uniform path is row 0 of a one-row table of the params, as on the CPU.
 *
 * Sparse as the CPU's work list, at tile granularity: after the first
 * iteration only the tiles within one tile of a change run (main below).
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_cls;
layout(binding = 2) uniform isamplerBuffer u_heights_in;
layout(binding = 3) uniform isamplerBuffer u_material; /* only read when u_materials_on */
layout(std430, binding = 2) writeonly buffer heights_out_buf { int heights_out[]; };

/* The flux out of a column of material `id`, as sim_even_slopes_materials:
 * the leaving column's threshold and roughness. */
int slope_flux(int id, int hc, int hk, bool diagonal)
{
    ivec4 row = u_material_rows[id];
    int threshold = diagonal ? row.w : row.z;
    int excess = hc - hk - threshold;
    if (excess <= 0)
        return 0;
    return mul_q16_shift(excess, row.y, 19);
}

int cell_material(int c)
{
    return u_materials_on != 0 ? material_id(fetch(u_material, c)) : 0;
}

/* The tiles of this iteration and the next (gl_stage_even_slopes): with
 * u_sparse 0 every tile of the batch runs, otherwise the listed ones. A tile
 * where some cell changed lists itself and its 8 neighbouring tiles of the
 * same window for the next iteration, each once (tile_mark = u_stamp). */
uniform int u_sparse;
uniform int u_stamp;
uniform int u_list_row; /* indirect groups per row (tile_list.comp) */
layout(std430, binding = 3) readonly buffer tile_list_buf {
    uint tl_count;
    uint tl_groups[3];
    int tl_tile[];
};
layout(std430, binding = 4) buffer next_list_buf {
    uint nl_count;
    uint nl_groups[3];
    int nl_tile[];
};
layout(std430, binding = 5) buffer tile_mark_buf { int tile_mark[]; };

shared uint tile_changed;

/* Cell c's height after one Jacobi iteration. */
int even_slope(cell_window win, int x, int y, int c)
{
    int hi = fetch(u_heights_in, c);
    int outflow = 0, inflow = 0;
    bool self_seed = fetch(u_cls, c) == CELL_SEED;
    int id_self = cell_material(c);
    for (int j = 0; j < 8; j++) {
        int qx = x + neighbour_dx[j], qy = y + neighbour_dy[j];
        if (qx < 0 || qy < 0 || qx >= win.w || qy >= win.h)
            continue;
        int q = win.offset + qy * win.w + qx;
        int hq = fetch(u_heights_in, q);
        if (fetch(u_cls, q) == CELL_SEED)
            outflow += slope_flux(id_self, hi, hq, j >= 4);
        if (self_seed)
            inflow += slope_flux(cell_material(q), hq, hi, j >= 4);
    }
    return hi - outflow + inflow;
}

/* List tile (of a window tw x th tiles wide) and its neighbours for the next
 * iteration, each tile once. */
void list_neighbourhood(uint tile)
{
    ivec4 t = tile_entry(tile);
    int w = t.w & 0xffff, h = t.w >> 16;
    int tx = (t.y & 0xffff) >> 3, ty = (t.y >> 16) >> 3;
    int tw = (w + 7) >> 3, th = (h + 7) >> 3;
    int first = int(tile) - (ty * tw + tx); /* a window's tiles are row-major */
    for (int ny = max(ty - 1, 0); ny <= min(ty + 1, th - 1); ny++)
        for (int nx = max(tx - 1, 0); nx <= min(tx + 1, tw - 1); nx++) {
            int n = first + ny * tw + nx;
            if (atomicExchange(tile_mark[n], u_stamp) != u_stamp) {
                uint slot = atomicAdd(nl_count, 1u);
                nl_tile[slot] = n;
                atomicMax(nl_groups[1], slot / uint(u_list_row) + 1u);
            }
        }
}

void main()
{
    uint tile = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (u_sparse != 0) {
        if (tile >= tl_count)
            return; /* the whole group: the last row of groups overhangs the list */
        tile = uint(tl_tile[tile]);
    }
    if (gl_LocalInvocationIndex == 0u)
        tile_changed = 0u;
    barrier();
    int x, y, c;
    cell_window win;
    /* refused windows skip slope evening, as in the C */
    if (locate_tile_cell(tile, win, x, y, c) && !window_refused(win.index)) {
        int next = even_slope(win, x, y, c);
        heights_out[c] = next;
        if (next != fetch(u_heights_in, c))
            atomicOr(tile_changed, 1u);
    }
    barrier();
    if (gl_LocalInvocationIndex == 0u && tile_changed != 0u)
        list_neighbourhood(tile);
}
