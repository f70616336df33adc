/*
 * scene: a JSON scene file (cJSON) — the world, its base terrain, the material
 * and, for offline runs and the demo, colliders with scripted motion. The
 * daemon starts from the embedded default scene (server/scene/default.json)
 * unless told otherwise. Every refused value gets a message naming its field,
 * e.g. "colliders[2].motion.velocity[0]: must be a finite number".
 */
#ifndef TERRAD_SCENE_H
#define TERRAD_SCENE_H

#include "base/base.h"
#include "collider/collider.h"
#include "ground/ground.h"
#include "sim/sim.h"
#include "world/world.h"

/* The smallest cell a scene may ask for (0.1 mm); the largest is 1000 m, and a
 * cell must hold at least one height unit (cell_size_m * units_per_m >= 1). */
#define SCENE_CELL_SIZE_MIN_M 1e-4

typedef struct scene_collider {
    char name[64];
    collider_geometry geometry;
    collider_motion motion;
} scene_collider;

typedef struct scene {
    char name[128];
    int width, height; /* cells */
    double cell_size_m;
    int32_t units_per_m;
    int32_t floor_units;
    int tile_cells; /* 0 = WORLD_TILE_CELLS_DEFAULT */
    world_base_spec base;
    sim_material material;
    double tick_hz; /* default 60 */
    /* who makes a tick due: 0 the server's wall clock at tick_hz ("wall", the
     * default), 1 the world's driver's STEP messages ("client"; PROTOCOL.md
     * "STEP") — tick_hz is then only the tick's length for rates and speeds */
    int client_clock;
    int active_margin_cells; /* default 4 */
    scene_collider *colliders;
    int collider_count;
    collider_mesh *meshes; /* owned; geometry.mesh points in here */
    int mesh_count;
    /* "materials" and "material_map" as validated JSON text, or NULL: one
     * material everywhere (the "material" key). Owned. */
    char *ground_json;
} scene;

/* base_dir resolves relative file paths (heightmaps, OBJ meshes). */
int scene_load_json(const char *text, const char *base_dir, scene *s, error_text *err);
int scene_load_file(const char *path, scene *s, error_text *err);
int scene_load_default(scene *s, error_text *err);
void scene_free(scene *s);

/* A material on its own in a JSON file (a scene's "material" object: what
 * `terrad calibrate --out` writes), read with every check a scene's gets for
 * a world of these cells; errors say "PATH: material.<field>: ...". */
int scene_material_load_file(const char *path, double cell_size_m, int32_t units_per_m,
                             sim_material *m, error_text *err);

/* The per-cell ground layers the scene describes (scene_create_world's world). */
int scene_create_ground(const scene *s, const world *w, ground *g, error_text *err);

/* Make the world the scene describes (allocation + base terrain). */
int scene_create_world(const scene *s, world *w, error_text *err);

/* The scene's parameters as the twin library's config keys (terrad_twin.h),
 * one call of fn per key: a number, or a name (name != NULL). -1 with err for
 * a scene the twin does not take (per-cell materials, a file base). */
typedef void (*scene_twin_key_fn)(void *ctx, const char *key, double number, const char *name);
int scene_twin_config(const scene *s, scene_twin_key_fn fn, void *ctx, error_text *err);
/* The same keys as a JSON object (malloc'd text; GET /v1/twin), or NULL with err. */
char *scene_twin_config_json(const scene *s, error_text *err);

#endif
