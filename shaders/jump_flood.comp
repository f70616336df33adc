#version 430 core
/*
 * jump_flood.comp: one step of jump flooding (sim_jump_flood), after
 * classify and before displacement. Every cell looks at its 8 neighbours
 * u_step cells away and keeps the nearest seed any of them knows; ties go to
 * the lower (cell hash, index) of the seed, so the result does not depend on
 * evaluation order. The host runs steps K, K/2, ..., 1, ping-ponging two
 * buffers, with K from the largest window of the batch: in a smaller window
 * the extra large steps only look outside it and change nothing.
 *
 * Only the tiles tile_list.comp listed run (an indirect dispatch): the
 * others hold free cells only, whose seeds never change.
 *
 * Seeds are window-local coordinates x | y << 16 (-1: no seed known yet),
 * which order like the C's indices, so ties break identically.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(binding = 1) uniform isamplerBuffer u_seed_in;
layout(std430, binding = 2) writeonly buffer seed_out_buf { int seed_out[]; };

uniform int u_step;

/* The tiles to visit (tile_list.comp): a tile of free cells only keeps its
 * seeds, so the steps are dispatched indirectly over the listed tiles. Both
 * seed buffers hold classify's seeds for the other tiles (the host copies
 * one into the other before the first step). */
layout(std430, binding = 3) readonly buffer tile_list_buf {
    uint tl_count;
    uint tl_groups[3];
    int tl_tile[];
};

/* seed_better: is candidate a (distance, hash, index) better than b? */
bool seed_better(int da, uint ha, int a, int db, uint hb, int b)
{
    if (da != db)
        return da < db;
    if (ha != hb)
        return ha < hb;
    return a < b;
}

void main()
{
    uint listed = gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x;
    if (listed >= tl_count)
        return; /* the last row of groups overhangs the list */
    int x, y, c;
    cell_window win;
    if (!locate_tile_cell(uint(tl_tile[listed]), win, x, y, c))
        return;
    /* the window's world corner, for the tie-breaking hash */
    ivec2 corner = texelFetch(u_table, 2 * win.index).yz;
    int ox = corner.x, oy = corner.y;
    int best = fetch(u_seed_in, c);
    int best_d = 0;
    uint best_h = 0u;
    if (best >= 0) {
        int bx = seed_x(best), by = seed_y(best);
        best_d = metric_distance(bx - x, by - y);
        best_h = cell_hash(ox + bx, oy + by);
    }
    for (int j = 0; j < 8; j++) {
        int qx = x + neighbour_dx[j] * u_step, qy = y + neighbour_dy[j] * u_step;
        if (qx < 0 || qy < 0 || qx >= win.w || qy >= win.h)
            continue;
        int s = fetch(u_seed_in, win.offset + qy * win.w + qx);
        /* no seed known there, or the one we hold already (never better
         * than itself): the common case, skipped before any arithmetic */
        if (s < 0 || s == best)
            continue;
        int sx = seed_x(s), sy = seed_y(s);
        int d = metric_distance(sx - x, sy - y);
        uint hs = cell_hash(ox + sx, oy + sy);
        if (best < 0 || seed_better(d, hs, s, best_d, best_h, best)) {
            best = s;
            best_d = d;
            best_h = hs;
        }
    }
    seed_out[c] = best;
}
