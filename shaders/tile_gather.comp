#version 430 core
/*
 * tile_gather.comp: the GPU tile cache's half of the upload stage. A window
 * whose world tiles are all resident in the cache's array texture (one
 * layer per tile) is copied from there into its cells of the heights buffer
 * instead of being uploaded from the CPU. u_layers lists, for each tile the
 * window covers (row-major from u_first_tile, u_tiles_x a row), the layer
 * that holds it — the cache's pointer table for this window. One dispatch
 * per window, an invocation per cell; a plain copy, so the result is the
 * same ints the CPU copy holds.
 */
layout(local_size_x = 8, local_size_y = 8) in;

layout(std430, binding = 2) writeonly buffer heights_buf { int heights[]; };
layout(std430, binding = 6) readonly buffer layer_buf { int layers[]; };

layout(binding = 7) uniform isampler2DArray u_tiles;
uniform ivec2 u_origin;    /* window corner, world cells */
uniform ivec2 u_size;      /* window size */
uniform int u_offset;      /* window's first cell in the heights buffer */
uniform int u_shift;       /* log2(tile side) */
uniform ivec2 u_first_tile;
uniform int u_tiles_x;
uniform int u_layer_base;  /* window's first entry in layers[] */

void main()
{
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (p.x >= u_size.x || p.y >= u_size.y)
        return;
    ivec2 g = u_origin + p;
    ivec2 t = g >> u_shift;
    ivec2 local = g - (t << u_shift);
    t -= u_first_tile;
    int layer = layers[u_layer_base + t.y * u_tiles_x + t.x];
    heights[u_offset + p.y * u_size.x + p.x] = texelFetch(u_tiles, ivec3(local, layer), 0).r;
}
