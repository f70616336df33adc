#version 430 core
/*
 * tile_args.comp: one invocation after tile_list.comp: the listed tiles as
 * the groups of an indirect dispatch, x at most the driver's limit
 * (u_groups_max) and y rows of them, as gl_dispatch lays out a dense pass.
 * No tile listed: zero groups, and the jump-flood steps do nothing.
 */
layout(local_size_x = 1) in;

layout(std430, binding = 3) buffer tile_list_buf {
    uint tl_count;
    uint tl_groups[3];
    int tl_tile[];
};

uniform int u_groups_max;

void main()
{
    uint n = tl_count;
    uint gx = min(n, uint(u_groups_max));
    tl_groups[0] = gx;
    tl_groups[1] = gx == 0u ? 0u : (n + gx - 1u) / gx;
    tl_groups[2] = 1u;
}
