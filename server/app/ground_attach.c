/*
 * ground_attach.c: gives the engine the scene's per-cell ground (materials
 * and compaction memory) before the first tick, and refuses a backend that
 * cannot run it, so a GL run never computes something the CPU twin would not.
 */
#include "app/app.h"

#include <string.h>

int app_ground_attach(const scene *sc, const world *w, sim_backend *backend, sim_engine *engine,
                      ground *g, error_text *err)
{
    if (scene_create_ground(sc, w, g, err) != 0)
        return -1;
    int per_cell = !g->uniform || g->uses_compaction;
    if (per_cell && strcmp(backend->name, "cpu") != 0) {
        error_set(err,
                  "materials: per-cell materials and compaction memory (%d materials%s) run only "
                  "on the cpu backend; start with --backend cpu",
                  g->material_count, g->uses_compaction ? ", compaction" : "");
        ground_free(g);
        return -1;
    }
    sim_engine_set_ground(engine, g);
    return 0;
}
