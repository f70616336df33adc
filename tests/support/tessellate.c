/*
 * tessellate.c: triangles of a collider in its local frame. The GL backend
 * drew these for its depth until issue 12 (the depth is one fixed-point rule
 * now, server/collider/depth_fixed.c), so they live with the tests: test_collider
 * turns a primitive into a mesh to check the mesh rule against the primitive's.
 * Every vertex lies on the analytic surface, so each facet is a chord inside
 * the solid: seen from below, a tessellated shape is never lower than the
 * exact one, only higher by the sagitta (0.7 mm for a 0.33 m wheel at 48
 * segments).
 */
#include "tessellate.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define TESS_SEGMENTS 48
#define TESS_RINGS                                                                                 \
    24 /* latitude bands of a full sphere; even, so a capsule splits at the equator */

typedef struct mesh_builder {
    float *v;
    uint32_t *i;
    int vn, in, vcap, icap;
} mesh_builder;

static uint32_t add_vertex(mesh_builder *b, double x, double y, double z)
{
    float *p = b->v + 3 * (size_t)b->vn;
    p[0] = (float)x;
    p[1] = (float)y;
    p[2] = (float)z;
    return (uint32_t)b->vn++;
}

static void add_triangle(mesh_builder *b, uint32_t a, uint32_t c, uint32_t d)
{
    uint32_t *p = b->i + b->in;
    p[0] = a;
    p[1] = c;
    p[2] = d;
    b->in += 3;
}

static int builder_init(mesh_builder *b, int vertices, int indices)
{
    b->v = malloc(sizeof(float) * 3 * (size_t)vertices);
    b->i = malloc(sizeof(uint32_t) * (size_t)indices);
    b->vn = b->in = 0;
    b->vcap = vertices;
    b->icap = indices;
    if (!b->v || !b->i) {
        free(b->v);
        free(b->i);
        return -1;
    }
    return 0;
}

/* Sphere or capsule about local Y: latitude rows from the +Y pole to the -Y
 * pole; with L > 0 the equator row is doubled, the upper copy at y = +L and
 * the lower at y = -L, and the band between them is the capsule's side. */
static void build_capsule(mesh_builder *b, double r, double L)
{
    const int S = TESS_SEGMENTS, R = TESS_RINGS;
    uint32_t top = add_vertex(b, 0, r + L, 0);
    uint32_t rows[TESS_RINGS + 2]; /* first vertex of each ring row */
    int row_count = 0;
    for (int k = 1; k < R; k++) {
        double theta = M_PI * k / R;
        double y = r * cos(theta), rho = r * sin(theta);
        int copies = (k == R / 2 && L > 0.0) ? 2 : 1;
        for (int c = 0; c < copies; c++) {
            double offset = (k < R / 2 || (k == R / 2 && c == 0)) ? L : -L;
            rows[row_count++] = (uint32_t)b->vn;
            for (int s = 0; s < S; s++) {
                double phi = 2.0 * M_PI * s / S;
                add_vertex(b, rho * cos(phi), y + offset, rho * sin(phi));
            }
        }
    }
    uint32_t bottom = add_vertex(b, 0, -r - L, 0);
    /* winding: counter-clockwise seen from outside */
    for (int s = 0; s < S; s++) {
        int n = (s + 1) % S;
        add_triangle(b, top, rows[0] + n, rows[0] + s);
    }
    for (int k = 0; k + 1 < row_count; k++)
        for (int s = 0; s < S; s++) {
            int n = (s + 1) % S;
            uint32_t a0 = rows[k] + s, a1 = rows[k] + n;
            uint32_t b0 = rows[k + 1] + s, b1 = rows[k + 1] + n;
            add_triangle(b, a0, a1, b1);
            add_triangle(b, a0, b1, b0);
        }
    uint32_t last = rows[row_count - 1];
    for (int s = 0; s < S; s++) {
        int n = (s + 1) % S;
        add_triangle(b, bottom, last + s, last + n);
    }
}

static void build_cylinder(mesh_builder *b, double r, double L)
{
    const int S = TESS_SEGMENTS;
    uint32_t top_centre = add_vertex(b, 0, L, 0);
    uint32_t bottom_centre = add_vertex(b, 0, -L, 0);
    uint32_t top = (uint32_t)b->vn;
    for (int s = 0; s < S; s++) {
        double phi = 2.0 * M_PI * s / S;
        add_vertex(b, r * cos(phi), L, r * sin(phi));
    }
    uint32_t bot = (uint32_t)b->vn;
    for (int s = 0; s < S; s++) {
        double phi = 2.0 * M_PI * s / S;
        add_vertex(b, r * cos(phi), -L, r * sin(phi));
    }
    for (int s = 0; s < S; s++) {
        int n = (s + 1) % S;
        add_triangle(b, top_centre, top + n, top + s);
        add_triangle(b, bottom_centre, bot + s, bot + n);
        add_triangle(b, top + s, top + n, bot + n);
        add_triangle(b, top + s, bot + n, bot + s);
    }
}

static void build_box(mesh_builder *b, vec3d h)
{
    for (int k = 0; k < 8; k++)
        add_vertex(b, (k & 1) ? h.x : -h.x, (k & 2) ? h.y : -h.y, (k & 4) ? h.z : -h.z);
    /* two triangles per face, outward counter-clockwise */
    static const uint32_t faces[6][4] = {
        {0, 4, 6, 2}, /* -x */
        {1, 3, 7, 5}, /* +x */
        {0, 1, 5, 4}, /* -y */
        {2, 6, 7, 3}, /* +y */
        {0, 2, 3, 1}, /* -z */
        {4, 5, 7, 6}, /* +z */
    };
    for (int f = 0; f < 6; f++) {
        add_triangle(b, faces[f][0], faces[f][1], faces[f][2]);
        add_triangle(b, faces[f][0], faces[f][2], faces[f][3]);
    }
}

int collider_tessellate(const collider_geometry *g, float **vertices, int *vertex_count,
                        uint32_t **indices, int *index_count)
{
    *vertices = NULL;
    *indices = NULL;
    *vertex_count = *index_count = 0;
    const int S = TESS_SEGMENTS, R = TESS_RINGS;
    mesh_builder b;
    switch (g->shape) {
    case COLLIDER_SPHERE:
    case COLLIDER_CAPSULE: {
        double L = g->shape == COLLIDER_CAPSULE ? g->half_length : 0.0;
        int rows = (R - 1) + (L > 0.0 ? 1 : 0);
        if (builder_init(&b, rows * S + 2, 3 * (2 * S + 2 * S * (rows - 1))) != 0)
            return -1;
        build_capsule(&b, g->radius, L);
        break;
    }
    case COLLIDER_CYLINDER:
        if (builder_init(&b, 2 * S + 2, 3 * 4 * S) != 0)
            return -1;
        build_cylinder(&b, g->radius, g->half_length);
        break;
    case COLLIDER_BOX:
        if (builder_init(&b, 8, 36) != 0)
            return -1;
        build_box(&b, g->half_extents);
        break;
    case COLLIDER_MESH: {
        const collider_mesh *m = g->mesh;
        if (!m || m->vertex_count < 1 || m->triangle_count < 1)
            return -1;
        if (builder_init(&b, m->vertex_count, 3 * m->triangle_count) != 0)
            return -1;
        memcpy(b.v, m->vertices, sizeof(float) * 3 * (size_t)m->vertex_count);
        memcpy(b.i, m->indices, sizeof(uint32_t) * 3 * (size_t)m->triangle_count);
        b.vn = m->vertex_count;
        b.in = 3 * m->triangle_count;
        break;
    }
    default:
        return -1;
    }
    *vertices = b.v;
    *indices = b.i;
    *vertex_count = b.vn;
    *index_count = b.in;
    return 0;
}
