/*
 * demo_rig.c: the demo world without the daemon (demo_rig.h): the one copy
 * of the default-scene engine set-up and of step_demo's actor loop that the
 * demo tests share.
 */
#include "demo_rig.h"

#include <string.h>

int demo_rig_open(demo_rig *r, error_text *err)
{
    memset(r, 0, sizeof *r);
    if (app_open_scene_world(NULL, &r->sc, &r->w, err) != 0)
        return -1;
    if (sim_params_from_material(&r->sc.material, r->w.cell_size_m, r->w.units_per_m, r->w.floor,
                                 &r->p, err) != 0)
        return -1;
    r->cpu = sim_backend_cpu_create(err);
    if (!r->cpu)
        return -1;
    r->engine = sim_engine_create(&r->w, &r->p, r->cpu, r->sc.active_margin_cells, err);
    if (!r->engine)
        return -1;
    demo_actors_init(r->actors, DEMO_RIG_ACTORS, &r->w);
    return 0;
}

int demo_rig_tick(demo_rig *r, long tick, error_text *err)
{
    for (int a = 0; a < DEMO_RIG_ACTORS; a++) { /* as step_demo (host_sim.c) */
        sim_collider *c = &r->colliders[a];
        c->id = a + 1;
        c->geometry = &r->actors[a].geometry;
        c->previous_pose = c->pose;
        c->pose = demo_actor_step(&r->actors[a], &r->w, (double)tick / r->sc.tick_hz);
        c->has_previous = tick > 0;
    }
    sim_tick_report report;
    return sim_engine_tick(r->engine, r->colliders, DEMO_RIG_ACTORS, &report, err);
}

void demo_rig_close(demo_rig *r)
{
    if (r->engine)
        sim_engine_destroy(r->engine);
    if (r->cpu)
        r->cpu->destroy(r->cpu);
    world_free(&r->w);
    scene_free(&r->sc);
}
