/*
 * twin_trace.c: writes what the twin library needs to replay a scene the way
 * `terrad simulate` runs it (tests/integration/clients/test_twin.py): the world's
 * parameters as terrad_twin_config keys, the whole world as the window, the
 * colliders and, per tick, every collider's pose (app_run_scene_ticks's
 * poses). One line per item, numbers printed with %.17g so that C's strtod
 * and JavaScript's Number() read back the same doubles:
 *
 *   set KEY VALUE | name KEY VALUE | window X Y W H | heights H0 H1 ... | base
 *   collider ID SHAPE RADIUS HALF_LENGTH HX HY HZ
 *   wheel ID RADIUS HALF_LENGTH COUNT HEIGHT THICKNESS   (a cylinder with grousers)
 *   mesh ID NV NT X0 Y0 Z0 ... I0 I1 I2 ...
 *   pose ID X Y Z QW QX QY QZ | tick
 *
 * A world of more than 65,536 cells is sent as "base" (the twin makes the
 * untouched base terrain itself: terrad_twin_create with no heights), a
 * smaller one cell by cell, so both ways are replayed.
 *
 * Usage: twin_trace SCENE TICKS > TRACE. Exit 77 for a scene the twin library
 * does not take (per-cell materials or a file base), with the reason.
 */
#include <stdio.h>
#include <stdlib.h>

#include "scene/scene.h"

/* One config key: the scene's own list (scene_twin_config, also GET /v1/twin). */
static void print_key(void *ctx, const char *key, double number, const char *name)
{
    (void)ctx;
    if (name)
        printf("name %s %s\n", key, name);
    else
        printf("set %s %.17g\n", key, number);
}

static void print_collider(int id, const collider_geometry *g)
{
    static const char *const shapes[] = {"sphere", "box", "capsule", "cylinder"};
    if (g->shape == COLLIDER_CYLINDER && g->grousers.count > 0) {
        printf("wheel %d %.17g %.17g %d %.17g %.17g\n", id, g->radius, g->half_length,
               g->grousers.count, g->grousers.height, g->grousers.thickness);
        return;
    }
    if (g->shape != COLLIDER_MESH) {
        printf("collider %d %s %.17g %.17g %.17g %.17g %.17g\n", id, shapes[g->shape], g->radius,
               g->half_length, g->half_extents.x, g->half_extents.y, g->half_extents.z);
        return;
    }
    const collider_mesh *m = g->mesh;
    printf("mesh %d %d %d", id, m->vertex_count, m->triangle_count);
    for (int i = 0; i < m->vertex_count * 3; i++)
        printf(" %.9g", (double)m->vertices[i]);
    for (int i = 0; i < m->triangle_count * 3; i++)
        printf(" %u", m->indices[i]);
    printf("\n");
}

int main(int argc, char **argv)
{
    scene sc;
    world w;
    error_text err = {{0}};
    if (argc != 3) {
        fprintf(stderr, "usage: twin_trace SCENE TICKS\n");
        return 2;
    }
    if (scene_load_file(argv[1], &sc, &err) != 0 || scene_create_world(&sc, &w, &err) != 0) {
        fprintf(stderr, "twin_trace: %s\n", err.message);
        return 1;
    }
    if (scene_twin_config(&sc, print_key, NULL, &err) != 0) {
        printf("twin_trace: %s: %s\n", argv[1], err.message);
        return 77;
    }
    long ticks = atol(argv[2]);
    printf("window 0 0 %d %d\n", sc.width, sc.height);
    if ((int64_t)sc.width * sc.height > 65536) {
        printf("base\n");
    } else {
        printf("heights");
        for (int y = 0; y < sc.height; y++)
            for (int x = 0; x < sc.width; x++)
                printf(" %d", (int)world_height_at(&w, x, y));
        printf("\n");
    }
    for (int c = 0; c < sc.collider_count; c++)
        print_collider(c, &sc.colliders[c].geometry);
    double dt = 1.0 / sc.tick_hz;
    for (long t = 0; t < ticks; t++) {
        for (int c = 0; c < sc.collider_count; c++) {
            collider_pose p = collider_motion_pose(&sc.colliders[c].motion, (double)t * dt);
            printf("pose %d %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", c, p.position.x,
                   p.position.y, p.position.z, p.orientation.w, p.orientation.x, p.orientation.y,
                   p.orientation.z);
        }
        printf("tick\n");
    }
    world_free(&w);
    scene_free(&sc);
    return 0;
}
