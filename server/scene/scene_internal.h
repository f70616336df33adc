/*
 * scene_internal.h: what scene.c (entry points, world, terrain, ground),
 * scene_material.c and scene_colliders.c share inside server/scene/. Never
 * included from outside it.
 */
#ifndef TERRAD_SCENE_INTERNAL_H
#define TERRAD_SCENE_INTERNAL_H

#include <cjson/cJSON.h>

#include "scene/scene.h"

#define SCENE_COLLIDERS_MAX 4096
#define SCENE_KEYFRAMES_MAX 100000
#define SCENE_FILE_BYTES_MAX ((size_t)64 << 20)
#define SCENE_SPEED_MAX 1e4    /* m/s */
#define SCENE_SPIN_MAX_DEG 1e6 /* deg/s */
#define SCENE_TIME_MAX_S 1e9

typedef struct scene_parser {
    const char *base_dir;
    error_text *err;
} scene_parser;

/* base_dir resolves relative paths ("heightmap.png", "wheel.obj"). */
int scene_resolve_path(const char *base_dir, const char *rel, char *out, size_t size,
                       const char *field, error_text *err);
/* "material": the sim's material, checked by the sim's own conversion. */
int scene_parse_material(const cJSON *root, scene *s, error_text *err);
/* A "soil" object at `path` (inside `parent`) over *soil: a preset first,
 * then each number, then the sim's ranges (errors name "<path>.<field>"). */
int scene_parse_soil(const cJSON *s, const char *path, const char *parent, sim_soil *soil,
                     error_text *err);
/* "colliders": shapes, meshes and scripted motion. */
int scene_parse_colliders(const cJSON *root, const scene_parser *ps, scene *s, error_text *err);

#endif
