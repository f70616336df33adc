#version 430 core
/*
 * tile_scatter.comp: the GPU tile cache's half of the readback stage. The
 * final heights of an accepted window that was gathered from the cache are
 * written back into the resident tiles, so next tick the window can be
 * gathered again without an upload (the engine scatters the same ints into
 * the CPU world, which stays authoritative). Same layout and uniforms as
 * tile_gather.comp; a window uploaded from the CPU copy is written into
 * those of its tiles that were current (layer >= 0) and skips the others.
 */
layout(local_size_x = 8, local_size_y = 8) in;

layout(std430, binding = 2) readonly buffer heights_buf { int heights[]; };
layout(std430, binding = 6) readonly buffer layer_buf { int layers[]; };

layout(binding = 0, r32i) writeonly uniform iimage2DArray u_tile_image;
uniform ivec2 u_origin;
uniform ivec2 u_size;
uniform int u_offset;
uniform int u_shift;
uniform ivec2 u_first_tile;
uniform int u_tiles_x;
uniform int u_layer_base;

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
    if (layer < 0)
        return;
    imageStore(u_tile_image, ivec3(local, layer), ivec4(heights[u_offset + p.y * u_size.x + p.x]));
}
