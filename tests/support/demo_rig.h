/*
 * demo_rig.h: what `terrad serve` runs without clients — the embedded
 * default scene, the CPU twin and the built-in demo actors (host_demo.c),
 * stepped and ticked exactly as step_demo (host_sim.c) does, without the
 * daemon's clock — for the tests of the demo world (test_demo_edges,
 * test_demo_readable).
 */
#ifndef TERRAD_DEMO_RIG_H
#define TERRAD_DEMO_RIG_H

#include "app/app.h"
#include "app/serve_internal.h"

#define DEMO_RIG_ACTORS 6 /* serve's default --demo-actors */

typedef struct demo_rig {
    scene sc;
    world w;
    sim_params p;
    sim_backend *cpu;
    sim_engine *engine;
    demo_actor actors[DEMO_RIG_ACTORS];
    sim_collider colliders[DEMO_RIG_ACTORS];
} demo_rig;

/* The default scene's world and a CPU engine over it, the actors placed.
 * Returns 0, or -1 with err set (then demo_rig_close still frees it all). */
int demo_rig_open(demo_rig *r, error_text *err);
/* Tick `tick` (from 0): each actor's pose as step_demo sets it, then the
 * engine's tick. Returns sim_engine_tick's result. */
int demo_rig_tick(demo_rig *r, long tick, error_text *err);
void demo_rig_close(demo_rig *r);

#endif
