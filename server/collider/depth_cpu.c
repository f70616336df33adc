/*
 * depth_cpu.c: the CPU twin's depth stage (rows 4c and 4d.1 of the tick
 * table in docs/design.md). For every
 * cell of a window it finds the lowest point of a collider on the vertical
 * line through the cell centre and lowers the window's "bottom" array to it,
 * by the one fixed-point rule both backends share (depth_fixed.c; the GL
 * backend runs its GLSL twin, depth_exact.comp): a primitive is one instance,
 * a mesh one instance per triangle, a lugged wheel its rim and a box per lug
 * (lugs.c). Only the cells under the shape's bounds
 * are visited, so the cost follows the collider's footprint, not the window.
 * (The analytic double-precision intersections that were the reference
 * before issue 12 are gone: no shape reached them any more.)
 */
#include "collider/collider.h"

#include <stdlib.h>

void collider_depth_cpu(const collider_geometry *g, collider_pose pose, world_rect window,
                        double cell_size_m, int32_t units_per_m, int32_t *bottom)
{
    if (window.w <= 0 || window.h <= 0 || !(cell_size_m > 0.0) || !collider_fixed_supported(g))
        return; /* a mesh without triangles presses nothing */
    if (g->shape == COLLIDER_MESH || (g->shape == COLLIDER_CYLINDER && g->grousers.count > 0)) {
        collider_fixed *inst = NULL;
        int64_t n = 0, cap = 0;
        if (collider_fixed_instances(g, pose, window, cell_size_m, units_per_m, &inst, &n, &cap) >=
            0)
            for (int64_t i = 0; i < n; i++)
                collider_fixed_apply(&inst[i], bottom, window.w);
        free(inst);
        return;
    }
    collider_fixed f;
    if (collider_fixed_prepare(g, pose, window, cell_size_m, units_per_m, &f))
        collider_fixed_apply(&f, bottom, window.w);
}
