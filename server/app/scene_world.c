/*
 * scene_world.c: the offline commands' start (export, fsck): the scene a
 * data directory was made with (a file, or the embedded default) and its
 * world over the base terrain, before any log or snapshot is read
 * (app_open_scene_world), and the frame that opens, runs and frees them
 * (app_offline_world).
 */
#include "app/app.h"

int app_open_scene_world(const char *scene_path, scene *sc, world *w, error_text *err)
{
    if ((scene_path ? scene_load_file(scene_path, sc, err) : scene_load_default(sc, err)) != 0)
        return -1;
    if (scene_create_world(sc, w, err) != 0) {
        scene_free(sc);
        return -1;
    }
    return 0;
}

int app_offline_world(const char *scene_path, app_world_run run, void *ctx)
{
    error_text err = {{0}};
    scene sc;
    world w;
    if (app_open_scene_world(scene_path, &sc, &w, &err) != 0) {
        log_error("%s", err.message);
        return 1;
    }
    int rc = run(ctx, &w);
    world_free(&w);
    scene_free(&sc);
    return rc;
}
