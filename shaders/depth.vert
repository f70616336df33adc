#version 430 core
/*
 * depth.vert: the depth stage of a tick (thesis Fig. 4.1), first thing the
 * GL backend does for a batch. Each collider's triangles (its local frame,
 * uploaded once per geometry) are drawn into its window's slot of a depth
 * atlas by an orthographic camera under the window. u_mvp is built on the
 * CPU in double precision: the collider's pose, then the window's world
 * rectangle to NDC x, y (pixel centres = cell centres) and the height range
 * [depth_low, depth_high] to NDC z, lower = nearer, so a depth test LESS
 * keeps the lowest collider point above each cell centre.
 */

layout(location = 0) in vec3 a_position;

uniform mat4 u_mvp;

void main()
{
    gl_Position = u_mvp * vec4(a_position, 1.0);
}
