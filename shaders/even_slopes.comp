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

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    if (window_refused(win.index))
        return; /* refused windows skip slope evening, as in the C */
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
    heights_out[c] = hi - outflow + inflow;
}
