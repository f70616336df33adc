/*
 * serve_demo.c: `terrad serve`'s built-in demo actors — spheres sliding and
 * bouncing over the terrain, after Wasmut's stress test — so that a daemon
 * without clients still deforms its terrain and a newcomer sees it work.
 * Each tick the sim thread steps them and hands them to the service as
 * colliders beside the clients' (--no-demo turns them off).
 */
#include <math.h>

#include "app/serve_internal.h"

void demo_actors_init(demo_actor *a, int count, const world *w)
{
    double size_x = w->width * w->cell_size_m, size_y = w->height * w->cell_size_m;
    uint32_t state = 12345u;
    for (int i = 0; i < count; i++) {
        /* a fixed LCG: the demo is the same every run */
        double r[5];
        for (int k = 0; k < 5; k++) {
            state = state * 1664525u + 1013904223u;
            r[k] = (state >> 8) / 16777216.0;
        }
        a[i].geometry = (collider_geometry){.shape = COLLIDER_SPHERE, .radius = 0.25 + 0.35 * r[0]};
        a[i].x = size_x * (0.1 + 0.8 * r[1]);
        a[i].y = size_y * (0.1 + 0.8 * r[2]);
        double speed = 0.6 + 1.4 * r[3], heading = 2.0 * M_PI * r[4];
        a[i].vx = speed * cos(heading);
        a[i].vy = speed * sin(heading);
        a[i].phase = r[4] * 6.0;
    }
}

static double terrain_height_m(const world *w, double x, double y)
{
    int cx = (int)floor(x / w->cell_size_m), cy = (int)floor(y / w->cell_size_m);
    if (cx < 0)
        cx = 0;
    if (cy < 0)
        cy = 0;
    if (cx >= w->width)
        cx = w->width - 1;
    if (cy >= w->height)
        cy = w->height - 1;
    return (double)world_height_at(w, cx, cy) / w->units_per_m;
}

collider_pose demo_actor_step(demo_actor *a, const world *w, double dt, double time_s)
{
    /* The sphere bounces off the edge with its rim, so it stays inside the
     * world. Bouncing with its centre put half of it outside: the half inside
     * had no ring of free cells on the edge side, every pressed cell along the
     * edge sent its material to the two ends of the footprint on the border
     * column (metres high within a tick), and the demo world grew fins along
     * its edges (issue 12; test_demo_edges). */
    double r = a->geometry.radius;
    double lo = r, hi_x = w->width * w->cell_size_m - r, hi_y = w->height * w->cell_size_m - r;
    a->x += a->vx * dt;
    a->y += a->vy * dt;
    if (hi_x > lo && (a->x < lo || a->x > hi_x)) {
        a->vx = -a->vx;
        a->x = a->x < lo ? 2 * lo - a->x : 2 * hi_x - a->x;
    }
    if (hi_y > lo && (a->y < lo || a->y > hi_y)) {
        a->vy = -a->vy;
        a->y = a->y < lo ? 2 * lo - a->y : 2 * hi_y - a->y;
    }
    double ground = terrain_height_m(w, a->x, a->y);
    double bob = fabs(sin(1.3 * time_s + a->phase));
    double z = ground + a->geometry.radius * (0.6 + 1.2 * bob);
    return (collider_pose){{a->x, a->y, z}, {1, 0, 0, 0}};
}
