/*
 * scene_world.c: the offline commands' start (export, fsck): the scene a
 * data directory was made with (a file, or the embedded default) and its
 * world over the base terrain, before any log or snapshot is read.
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
