/*
 * host_demo.c: `terrad serve`'s built-in demo actors — spheres that run
 * laps and bob in and out of the terrain — so that a daemon without clients
 * still deforms its terrain and a newcomer sees it work. Each tick the sim
 * thread steps them and hands them to the service as colliders beside the
 * clients' (--no-demo turns them off).
 *
 * Why laps: spheres that slid in straight lines and bounced off the edges
 * (after Wasmut's stress test) covered the whole map within ten minutes of
 * `make run`, and then no trail could be told from another. Each actor now
 * runs its own ellipse inside its own cell of a grid over the world, and its
 * depth follows the scene's base terrain rather than the current ground: a
 * lap presses the same trench to the same depth as the last one instead of
 * digging deeper, so the terrain it touches (trench, rims and what slides
 * off them) is bounded and the rest of the world stays as the scene made it,
 * however long the daemon runs (test_demo_readable). The terrain itself is
 * deformed by the ordinary tick: Σh, the log and GL ≡ CPU are untouched.
 */
#include <math.h>

#include "host/host.h"

void demo_actors_init(demo_actor *a, int count, const world *w)
{
    double size_x = w->width * w->cell_size_m, size_y = w->height * w->cell_size_m;
    int cols = 1;
    while (cols * cols < count)
        cols++;
    int rows = count > 0 ? (count + cols - 1) / cols : 1;
    double cell_x = size_x / cols, cell_y = size_y / rows;
    double cell_min = cell_x < cell_y ? cell_x : cell_y;
    uint32_t state = 12345u;
    for (int i = 0; i < count; i++) {
        /* a fixed LCG: the demo is the same every run */
        double r[4];
        for (int k = 0; k < 4; k++) {
            state = state * 1664525u + 1013904223u;
            r[k] = (state >> 8) / 16777216.0;
        }
        /* The sphere stays inside its cell: the lap's half-axis (0.32 of the
         * cell) plus the radius (at most 0.12 of it) is under half a cell, so
         * laps never cross and no sphere reaches past the world's edge. */
        double radius = 0.25 + 0.35 * r[0];
        if (radius > 0.12 * cell_min)
            radius = 0.12 * cell_min;
        a[i].geometry = (collider_geometry){.shape = COLLIDER_SPHERE, .radius = radius};
        a[i].cx = cell_x * (i % cols + 0.5);
        a[i].cy = cell_y * (i / cols + 0.5);
        a[i].ax = 0.32 * cell_x;
        a[i].ay = 0.32 * cell_y;
        double speed = 0.6 + 1.4 * r[1]; /* m/s along the lap, roughly */
        a[i].omega = (i % 2 ? -1.0 : 1.0) * speed / (0.5 * (a[i].ax + a[i].ay));
        a[i].angle0 = 2.0 * M_PI * r[2];
        a[i].phase = r[3] * 6.0;
    }
}

static double base_height_m(const world *w, double x, double y)
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
    int32_t h = 0;
    world_base_fill_rect(w, (world_rect){cx, cy, 1, 1}, &h);
    return (double)h / w->units_per_m;
}

collider_pose demo_actor_step(const demo_actor *a, const world *w, double time_s)
{
    /* A function of time alone: the same tick gives the same pose, whatever
     * ran before (a restart, a skipped tick). */
    double angle = a->angle0 + a->omega * time_s;
    double x = a->cx + a->ax * cos(angle), y = a->cy + a->ay * sin(angle);
    double ground = base_height_m(w, x, y);
    double bob = fabs(sin(1.3 * time_s + a->phase));
    double z = ground + a->geometry.radius * (0.6 + 1.2 * bob);
    return (collider_pose){{x, y, z}, {1, 0, 0, 0}};
}
