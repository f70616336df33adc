/*
 * tessellate.h: triangles of a collider primitive in its local frame, for
 * test_collider's check of the mesh depth rule against the primitive's.
 * Primitives are tessellated to within a few millimetres of the exact surface
 * for wheel-sized shapes; meshes are copied. The caller frees both arrays.
 */
#ifndef TERRAD_TEST_TESSELLATE_H
#define TERRAD_TEST_TESSELLATE_H

#include "collider/collider.h"

int collider_tessellate(const collider_geometry *g, float **vertices, int *vertex_count,
                        uint32_t **indices, int *index_count);

#endif
