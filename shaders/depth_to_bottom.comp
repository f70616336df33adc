#version 430 core
/*
 * depth_to_bottom.comp: the end of the depth stage, before classify. Turns
 * the atlas's depth (0 = depth_low, 1 = depth_high) into the int32 "bottom"
 * array the integer stages consume, as the CPU twin's collider_depth_cpu
 * writes it: floor of the height in units, clamped to
 * [WORLD_HEIGHT_MIN - 1, WORLD_HEIGHT_MAX + 1], and COLLIDER_BOTTOM_NONE
 * where nothing was drawn (depth still at the clear value 1.0). This is the
 * only float arithmetic after the raster; from here on it is integers.
 * Only windows rasterised in this atlas round (u_round) are written;
 * windows whose bottom was uploaded are left alone.
 */
#include "common.glsl"

layout(local_size_x = 8, local_size_y = 8) in;

layout(std430, binding = 2) writeonly buffer bottom_buf { int bottom[]; };

layout(binding = 1) uniform sampler2D u_depth;
uniform int u_round;

void main()
{
    int x, y, c;
    cell_window win;
    if (!locate_cell(win, x, y, c))
        return;
    window_entry e = window_at(win.index);
    if (e.raster_round != u_round + 1)
        return;
    float d = texelFetch(u_depth, ivec2(e.slot_x + x, e.slot_y + y), 0).r;
    if (d >= 1.0) {
        bottom[c] = BOTTOM_NONE;
        return;
    }
    /* depth_low is an integer, so floor(depth_low + f) = depth_low + floor(f):
     * only the fraction of the range is float, the offset stays exact. */
    float range = float(e.depth_high) - float(e.depth_low);
    float f = clamp(floor(max(d, 0.0) * range), 0.0, 2147483520.0);
    uvec2 z = i64_add(i64(e.depth_low), i64(int(f)));
    if (i64_gt(z, i64(HEIGHT_MAX + 1)))
        z = i64(HEIGHT_MAX + 1);
    if (i64_gt(i64(HEIGHT_MIN - 1), z))
        z = i64(HEIGHT_MIN - 1);
    bottom[c] = int(z.x);
}
