/*
 * test_demo_edges.c: the demo world's edges (issue 12, "Also": "the demo
 * world grows tall thin fins along its edges after a few minutes of
 * `make run`"). It runs what `terrad serve` runs without clients — the
 * embedded default scene, the CPU twin and the six built-in demo actors
 * (host_demo.c), stepped and ticked exactly as step_demo does
 * (tests/support/demo_rig.c) — for 3,600 ticks (one minute of the demo at
 * 60 Hz), without the daemon's clock.
 *
 * The fins came from the actors: they bounced off the world's edge with
 * their centre, so a sphere spent its bounce half outside the world. The
 * material of the half inside has no ring on the edge side: every pressed
 * cell along the edge gave it to the two ends of the footprint on the edge
 * column, which rose to 9.3 m in a tick and could only relax along that
 * column (slope evening never moves material into a footprint), and left a
 * fin when the actor moved on. Actors then bounced with their rim; now they
 * run laps inside their own cell of the world (issue 20, test_demo_readable),
 * so a sphere still never leaves the world. Checked here:
 *   - no actor's sphere ever reaches past the world's edge;
 *   - no column of the border (the outermost 3 cells) ends higher than the
 *     highest column of the interior: before, the border held the world's
 *     tallest columns (5.4 m transient, 2.0 m left standing after three
 *     minutes, against 1.9 m inside).
 */
#include <stdio.h>
#include <stdlib.h>

#include "check.h"
#include "demo_rig.h"

#ifndef DEMO_TICKS
#define DEMO_TICKS 3600
#endif
#define BORDER 3

int main(void)
{
    error_text err = {{0}};
    demo_rig r;
    CHECK(demo_rig_open(&r, &err) == 0, "the demo world: %s", err.message);
    if (!r.engine) {
        demo_rig_close(&r);
        return check_report();
    }
    world *w = &r.w;
    double size_x = w->width * w->cell_size_m, size_y = w->height * w->cell_size_m;
    int outside = 0, failed_ticks = 0;
    for (long tick = 0; tick < DEMO_TICKS; tick++) {
        if (demo_rig_tick(&r, tick, &err) != 0)
            failed_ticks++;
        for (int a = 0; a < DEMO_RIG_ACTORS; a++) {
            const sim_collider *c = &r.colliders[a];
            double rad = r.actors[a].geometry.radius, x = c->pose.position.x,
                   y = c->pose.position.y;
            if (x - rad < 0.0 || x + rad > size_x || y - rad < 0.0 || y + rad > size_y)
                outside++;
        }
    }
    CHECK(failed_ticks == 0, "every tick ran (%d failed: %s)", failed_ticks, err.message);
    CHECK(outside == 0, "no actor's sphere reaches past the world's edge (%d poses did)", outside);

    int32_t border_max = INT32_MIN, interior_max = INT32_MIN;
    int bx = 0, by = 0;
    for (int y = 0; y < w->height; y++) {
        for (int x = 0; x < w->width; x++) {
            int32_t h = world_height_at(w, x, y);
            int border =
                x < BORDER || y < BORDER || x >= w->width - BORDER || y >= w->height - BORDER;
            if (border && h > border_max) {
                border_max = h;
                bx = x;
                by = y;
            }
            if (!border && h > interior_max)
                interior_max = h;
        }
    }
    printf("after %d ticks: highest border column %d at (%d, %d), highest interior column %d\n",
           DEMO_TICKS, border_max, bx, by, interior_max);
    CHECK(border_max <= interior_max,
          "no fin on the border: its highest column %d (at %d, %d) <= the interior's %d",
          border_max, bx, by, interior_max);

    demo_rig_close(&r);
    return check_report();
}
