/*
 * test_demo_readable.c: the demo world stays readable however long `make
 * run` goes (issue 20: "the demo fills the whole map with craters within ten
 * minutes, after which no trail can be told apart"). It runs what `terrad
 * serve` runs without clients — the embedded default scene, the CPU twin and
 * the six built-in demo actors (host_demo.c), stepped as step_demo does —
 * without the daemon's clock, and looks at the world twice: after LOOK_A and
 * after LOOK_B ticks.
 *
 * Each actor runs laps of its own ellipse and presses to a depth set by the
 * base terrain, so what the demo changes is its six lanes and nothing else:
 *   - every cell that differs from the base terrain lies within BAND_M of
 *     some actor's lap (the sphere's radius plus its rims and what slid off
 *     them), at both looks: the lanes do not widen with time;
 *   - at least 40% of the world is still the base terrain at both looks;
 *   - no cell lies deeper below the base than the deepest press (0.4 of the
 *     largest radius) plus one repose step: laps re-press the same trench
 *     instead of digging on;
 *   - every lane is dug: each actor's lap has cells below the base.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "check.h"
#include "demo_rig.h"

// ctest-timeout: 600
#ifndef LOOK_A
#define LOOK_A 3600 /* one minute of the demo at 60 Hz */
#endif
#ifndef LOOK_B
#define LOOK_B 14400 /* four minutes: laps of every actor (30 minutes: docs/core.md) */
#endif
#define ACTORS DEMO_RIG_ACTORS
#define BAND_M 0.75  /* beyond the sphere's radius, for the rims */
#define SAMPLES 1440 /* points per lap when drawing the lanes */

/* Mark, in lane[], every cell within the sphere's radius + BAND_M of the
 * actor's lap; owner[] gets the actor's index + 1. */
static void mark_lanes(const world *w, const demo_actor *a, int count, unsigned char *owner)
{
    double cell = w->cell_size_m;
    for (int i = 0; i < count; i++) {
        double reach = a[i].geometry.radius + BAND_M;
        int rc = (int)ceil(reach / cell);
        for (int s = 0; s < SAMPLES; s++) {
            double t = 2.0 * M_PI * s / SAMPLES;
            double x = a[i].cx + a[i].ax * cos(t), y = a[i].cy + a[i].ay * sin(t);
            int cx = (int)floor(x / cell), cy = (int)floor(y / cell);
            for (int dy = -rc; dy <= rc; dy++) {
                for (int dx = -rc; dx <= rc; dx++) {
                    int gx = cx + dx, gy = cy + dy;
                    if (gx < 0 || gy < 0 || gx >= w->width || gy >= w->height)
                        continue;
                    double px = (gx + 0.5) * cell - x, py = (gy + 0.5) * cell - y;
                    if (px * px + py * py <= reach * reach)
                        owner[(size_t)gy * w->width + gx] = (unsigned char)(i + 1);
                }
            }
        }
    }
}

static void look(const world *w, const demo_actor *a, const unsigned char *owner,
                 const int32_t *base, long tick)
{
    long changed = 0, outside = 0, ox = -1, oy = -1;
    int32_t deepest = 0, deepest_allowed = 0;
    int dug[ACTORS] = {0};
    for (int i = 0; i < ACTORS; i++) {
        int32_t press = (int32_t)ceil(0.4 * a[i].geometry.radius * w->units_per_m);
        if (press > deepest_allowed)
            deepest_allowed = press;
    }
    /* one repose step: tan(35°) of a cell (the default scene's material) */
    deepest_allowed += (int32_t)ceil(tan(35.0 * M_PI / 180.0) * w->cell_size_m * w->units_per_m);
    for (int y = 0; y < w->height; y++) {
        for (int x = 0; x < w->width; x++) {
            size_t k = (size_t)y * w->width + x;
            int32_t d = world_height_at(w, x, y) - base[k];
            if (d == 0)
                continue;
            changed++;
            if (!owner[k]) {
                outside++;
                ox = x;
                oy = y;
            } else if (d < 0) {
                dug[owner[k] - 1] = 1;
            }
            if (-d > deepest)
                deepest = -d;
        }
    }
    long cells = (long)w->width * w->height;
    printf("tick %ld: %ld of %ld cells changed (%.1f%%), %ld outside the lanes, deepest %d units "
           "below the base (allowed %d)\n",
           tick, changed, cells, 100.0 * changed / cells, outside, deepest, deepest_allowed);
    CHECK(outside == 0,
          "tick %ld: every changed cell lies in a lane (%ld do not, the last at %ld, %ld)", tick,
          outside, ox, oy);
    CHECK(changed * 10 <= cells * 6,
          "tick %ld: at least 40%% of the world is untouched (%.1f%% changed)", tick,
          100.0 * changed / cells);
    CHECK(deepest <= deepest_allowed, "tick %ld: deepest cell %d units below the base <= %d", tick,
          deepest, deepest_allowed);
    for (int i = 0; i < ACTORS; i++)
        CHECK(dug[i], "tick %ld: actor %d's lane is dug", tick, i);
}

int main(void)
{
    error_text err = {{0}};
    demo_rig r;
    CHECK(demo_rig_open(&r, &err) == 0, "the demo world: %s", err.message);
    const world *w = &r.w;
    size_t cells = (size_t)w->width * w->height;
    int32_t *base = malloc(cells * sizeof *base);
    unsigned char *owner = calloc(cells, 1);
    if (r.engine && base && owner) {
        world_base_fill_rect(w, (world_rect){0, 0, w->width, w->height}, base);
        mark_lanes(w, r.actors, ACTORS, owner);
        int failed_ticks = 0;
        for (long tick = 0; tick < LOOK_B; tick++) {
            if (demo_rig_tick(&r, tick, &err) != 0)
                failed_ticks++;
            if (tick + 1 == LOOK_A || tick + 1 == LOOK_B)
                look(w, r.actors, owner, base, tick + 1);
        }
        CHECK(failed_ticks == 0, "every tick ran (%d failed: %s)", failed_ticks, err.message);
    }
    free(owner);
    free(base);
    demo_rig_close(&r);
    return check_report();
}
