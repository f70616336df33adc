#version 430 core
/*
 * depth.frag: the depth stage writes only depth (see depth.vert); the
 * framebuffer has no colour attachment, so there is nothing to output.
 */

void main()
{
}
