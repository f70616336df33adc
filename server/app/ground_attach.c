/*
 * ground_attach.c: gives the engine the scene's per-cell ground (materials
 * and compaction memory) before the first tick. Both backends run it: the
 * CPU twin (sim_stages.c) and the GL shaders that mirror it.
 */
#include "app/app.h"

int app_ground_attach(const scene *sc, const world *w, sim_engine *engine, ground *g,
                      error_text *err)
{
    if (scene_create_ground(sc, w, g, err) != 0)
        return -1;
    sim_engine_set_ground(engine, g);
    return 0;
}
