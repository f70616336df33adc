#version 430 core
/*
 * depth_clear.comp: the start of the depth stage. Sets the bottom of every
 * cell of the windows whose depth the stage computes (cast_depth) to
 * COLLIDER_BOTTOM_NONE, "no collider above"; depth_exact.comp then lowers
 * the cells under a collider with atomicMin. Windows whose bottom was
 * uploaded are left alone.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(std430, binding = 2) writeonly buffer bottom_buf { int bottom[]; };

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    if (window_at(win.index).cast_depth != 0)
        bottom[c] = BOTTOM_NONE;
}
