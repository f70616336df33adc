/*
 * scene.c: scene files (JSON, read with cJSON) — the world's extent, its base
 * terrain, the material and scripted colliders. A scene is read once, before
 * the first tick: scene_create_world builds the world from it, the material
 * becomes the sim's integer parameters, and each tick asks every scene
 * collider for its pose with collider_motion_pose.
 *
 * Strictness is the point: every key is checked against the keys its object
 * may have (a typo such as "rougness" is refused, never silently replaced by
 * a default), every number must be finite and in range, and every message
 * names the JSON path of the offending value, e.g.
 * "colliders[2].motion.velocity[0]: must be a finite number".
 *
 * The format (docs/scene-format.md has a complete example):
 *
 *   {
 *     "name": "thesis-car",                       optional, < 128 bytes
 *     "description": "...",                       optional, ignored
 *     "world": {"width": 1024, "height": 1024,    cells, required
 *               "tile_cells": 256,                 optional, a power of two
 *               "cell_size_m": 0.048828125,       required
 *               "units_per_m": 10000,             optional, default 10000
 *               "floor_m": 0},                    optional, default 0
 *     "terrain": {"kind": "flat", "height_m": 0.4}
 *              | {"kind": "dunes", "min_height_m": 0.3, "max_height_m": 0.8,
 *                 "wavelength_m": 12, "octaves": 4, "seed": 7}
 *              | {"kind": "png16" | "raw_int16" | "raw_int32", "path": "file",
 *                 "scale_units": 1, "offset_units": 0},
 *                                                 optional, default flat 0 m
 *     "material": {"model": "persson-ssbo" | "persson-iterative" | "persson-multi" |
 *                           "subtract" | "deferred" | "diffusion" | "decals",
 *                  "compression", "roughness", "repose_deg", "obstacle_gap_m",
 *                  "multi_target_m", "multi_target_max", "displace_iterations",
 *                  "slope_iterations", "metric",
 *                  "method" (iterative|ssbo|multi: alias of the persson-* models),
 *                  subtract: "refill_m_per_s"; deferred: "trail_scale_per_m",
 *                  "trail_range_m", "edge_height", "edge_width"; diffusion: "preset"
 *                  (mud|pebbles|sand), "D", "zeta_inv", "force_scale", "dt",
 *                  "substeps" ("auto" | N), "conservative" (bool); decals:
 *                  "decal_min_strength_m"},
 *                                                 every key optional (sim_material_default)
 *     "tick_hz": 60, "active_margin_cells": 4,    optional
 *     "colliders": [{"name": "...", "shape": "sphere|box|capsule|cylinder|wheel|mesh",
 *                    "radius", "half_length", "half_extents": [x,y,z],
 *                    "obj": "file.obj", "scale": 1,
 *                    "position": [x,y,z], "orientation": [w,x,y,z],
 *                    "motion": {"velocity": [..], "spin_axis": [..], "spin_deg_per_s": ..}
 *                            | {"keyframes": [{"time_s", "position", "orientation"}, ...]}}]
 *   }
 *
 * Relative file paths resolve against the scene file's directory.
 */
#include "scene/scene.h"

#include <cjson/cJSON.h>
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "base/embedded.h"

#define SCENE_COLLIDERS_MAX 4096
#define SCENE_KEYFRAMES_MAX 100000
#define SCENE_FILE_BYTES_MAX ((long)64 << 20)
#define SCENE_SPEED_MAX 1e4    /* m/s */
#define SCENE_SPIN_MAX_DEG 1e6 /* deg/s */
#define SCENE_TIME_MAX_S 1e9

typedef struct scene_parser {
    const char *base_dir;
    error_text *err;
} scene_parser;

/* ---- world, terrain, material ---- */

static const char *const world_keys[] = {"width",   "height",     "cell_size_m", "units_per_m",
                                         "floor_m", "tile_cells", NULL};

static int parse_world(const cJSON *root, scene *s, error_text *err)
{
    const cJSON *w = cJSON_GetObjectItemCaseSensitive(root, "world");
    if (!w) {
        error_set(err, "world: missing (an object with width, height and cell_size_m)");
        return -1;
    }
    if (json_expect_object(w, "world", "scene", err) ||
        json_check_keys(w, "world", world_keys, NULL, err))
        return -1;
    double width, height, cell, upm = 10000, floor_m = 0, tile_cells = 0;
    if (json_get_integer(w, "world", "width", 1, WORLD_SIDE_MAX, 1, &width, err) < 0 ||
        json_get_integer(w, "world", "height", 1, WORLD_SIDE_MAX, 1, &height, err) < 0 ||
        json_get_positive(w, "world", "cell_size_m", 1000, 1, &cell, err) < 0 ||
        json_get_integer(w, "world", "units_per_m", 1, 1000000, 0, &upm, err) < 0 ||
        json_get_number(w, "world", "floor_m", -1e9, 1e9, &floor_m, err) < 0 ||
        json_get_integer(w, "world", "tile_cells", 0, WORLD_SIDE_MAX, 0, &tile_cells, err) < 0)
        return -1;
    int tc = (int)tile_cells;
    if (tc != 0 && (tc < WORLD_TILE_CELLS_MIN || (tc & (tc - 1)) != 0)) {
        error_set(err,
                  "world.tile_cells: must be 0 (default %d) or a power of two in [%d, %d] "
                  "(got %d)",
                  WORLD_TILE_CELLS_DEFAULT, WORLD_TILE_CELLS_MIN, WORLD_SIDE_MAX, tc);
        return -1;
    }
    double floor_units = floor_m * upm;
    if (floor_units < WORLD_HEIGHT_MIN - 0.5 || floor_units >= WORLD_HEIGHT_MAX + 0.5) {
        error_set(err, "world.floor_m: %g m is %.0f units, outside [%d, %d]", floor_m, floor_units,
                  WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX);
        return -1;
    }
    s->width = (int)width;
    s->height = (int)height;
    s->cell_size_m = cell;
    s->units_per_m = (int32_t)upm;
    s->floor_units = (int32_t)llround(floor_units);
    s->tile_cells = tc;
    return 0;
}

/* A height in metres that must land in [floor, WORLD_HEIGHT_MAX] units. */
static int check_height_m(const scene *s, const char *path, double metres, error_text *err)
{
    double units = metres * s->units_per_m;
    double lo = s->floor_units > WORLD_HEIGHT_MIN ? s->floor_units : WORLD_HEIGHT_MIN;
    if (units < lo - 0.5 || units >= WORLD_HEIGHT_MAX + 0.5) {
        error_set(err, "%s: %g m is %.0f units, outside [%.0f, %d] (floor to WORLD_HEIGHT_MAX)",
                  path, metres, units, lo, WORLD_HEIGHT_MAX);
        return -1;
    }
    return 0;
}

static int resolve_path(const char *base_dir, const char *rel, char *out, size_t size,
                        const char *field, error_text *err)
{
    int n;
    if (rel[0] == '/' || !base_dir || !base_dir[0])
        n = snprintf(out, size, "%s", rel);
    else
        n = snprintf(out, size, "%s/%s", base_dir, rel);
    if (n < 0 || (size_t)n >= size) {
        error_set(err, "%s: path too long", field);
        return -1;
    }
    return 0;
}

static int parse_terrain(const cJSON *root, const scene_parser *ps, scene *s, error_text *err)
{
    world_base_spec *b = &s->base;
    memset(b, 0, sizeof *b);
    b->kind = WORLD_BASE_FLAT;
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(root, "terrain");
    if (!t)
        return 0; /* flat at 0 m */
    if (json_expect_object(t, "terrain", "scene", err))
        return -1;
    char kind[32];
    int r = json_get_string(t, "terrain", "kind", kind, sizeof kind, err);
    if (r < 0)
        return -1;
    if (r == 0) {
        error_set(err, "terrain.kind: missing (flat, dunes, png16, raw_int16 or raw_int32)");
        return -1;
    }
    if (strcmp(kind, "flat") == 0) {
        static const char *const keys[] = {"kind", "height_m", NULL};
        if (json_check_keys(t, "terrain", keys, "terrain kind flat", err) ||
            json_require_number(t, "terrain", "height_m", -1e9, 1e9, &b->height_m, err) ||
            check_height_m(s, "terrain.height_m", b->height_m, err))
            return -1;
        return 0;
    }
    if (strcmp(kind, "dunes") == 0) {
        static const char *const keys[] = {
            "kind", "min_height_m", "max_height_m", "wavelength_m", "octaves", "seed", NULL};
        double octaves = 4, seed = 0;
        b->kind = WORLD_BASE_DUNES;
        b->wavelength_m = 10.0;
        if (json_check_keys(t, "terrain", keys, "terrain kind dunes", err) ||
            json_require_number(t, "terrain", "min_height_m", -1e9, 1e9, &b->min_height_m, err) ||
            json_require_number(t, "terrain", "max_height_m", -1e9, 1e9, &b->max_height_m, err) ||
            json_get_positive(t, "terrain", "wavelength_m", 1e6, 0, &b->wavelength_m, err) < 0 ||
            json_get_integer(t, "terrain", "octaves", 1, 8, 0, &octaves, err) < 0 ||
            json_get_integer(t, "terrain", "seed", 0, 4294967295.0, 0, &seed, err) < 0 ||
            check_height_m(s, "terrain.min_height_m", b->min_height_m, err) ||
            check_height_m(s, "terrain.max_height_m", b->max_height_m, err))
            return -1;
        if (b->max_height_m < b->min_height_m) {
            error_set(err, "terrain.max_height_m: must be >= min_height_m (got %g < %g)",
                      b->max_height_m, b->min_height_m);
            return -1;
        }
        b->octaves = (int)octaves;
        b->seed = (uint32_t)seed;
        return 0;
    }
    if (strcmp(kind, "png16") == 0)
        b->kind = WORLD_BASE_PNG16;
    else if (strcmp(kind, "raw_int16") == 0)
        b->kind = WORLD_BASE_RAW_INT16;
    else if (strcmp(kind, "raw_int32") == 0)
        b->kind = WORLD_BASE_RAW_INT32;
    else {
        error_set(err,
                  "terrain.kind: must be flat, dunes, png16, raw_int16 or raw_int32 (got \"%s\")",
                  kind);
        return -1;
    }
    static const char *const keys[] = {"kind", "path", "scale_units", "offset_units", NULL};
    char rel[1024];
    b->value_scale_units = 1.0;
    b->value_offset_units = 0.0;
    if (json_check_keys(t, "terrain", keys, "a heightmap terrain", err) ||
        (r = json_get_string(t, "terrain", "path", rel, sizeof rel, err)) < 0)
        return -1;
    if (r == 0 || !rel[0]) {
        error_set(err, "terrain.path: missing (the heightmap file)");
        return -1;
    }
    if (json_get_number(t, "terrain", "scale_units", -1e9, 1e9, &b->value_scale_units, err) < 0 ||
        json_get_number(t, "terrain", "offset_units", -1e10, 1e10, &b->value_offset_units, err) <
            0 ||
        resolve_path(ps->base_dir, rel, b->path, sizeof b->path, "terrain.path", err))
        return -1;
    return 0;
}

static int parse_material(const cJSON *root, scene *s, error_text *err)
{
    sim_material *m = &s->material;
    *m = sim_material_default();
    m->tick_s = 1.0 / s->tick_hz;
    const cJSON *o = cJSON_GetObjectItemCaseSensitive(root, "material");
    if (!o)
        return 0;
    static const char *const keys[] = {"compression",
                                       "roughness",
                                       "repose_deg",
                                       "obstacle_gap_m",
                                       "multi_target_m",
                                       "multi_target_max",
                                       "displace_iterations",
                                       "slope_iterations",
                                       "metric",
                                       "method",
                                       "model",
                                       "refill_m_per_s",
                                       "trail_scale_per_m",
                                       "trail_range_m",
                                       "edge_height",
                                       "edge_width",
                                       "preset",
                                       "D",
                                       "zeta_inv",
                                       "force_scale",
                                       "dt",
                                       "substeps",
                                       "conservative",
                                       "decal_min_strength_m",
                                       NULL};
    const char *P = "material";
    if (json_expect_object(o, P, "scene", err) || json_check_keys(o, P, keys, NULL, err))
        return -1;
    double v;
    int r;
    if (json_get_number(o, P, "compression", 0, 1, &m->compression, err) < 0 ||
        json_get_number(o, P, "roughness", 0, 1, &m->roughness, err) < 0 ||
        json_get_number(o, P, "obstacle_gap_m", 0, 1000, &m->obstacle_gap_m, err) < 0 ||
        json_get_positive(o, P, "multi_target_m", 1000, 0, &m->multi_target_m, err) < 0)
        return -1;
    if ((r = json_get_number(o, P, "repose_deg", 0, 90, &v, err)) < 0)
        return -1;
    if (r) {
        if (v >= 90.0) {
            error_set(err, "material.repose_deg: must be in [0, 90) (got %g)", v);
            return -1;
        }
        m->repose_deg = v;
    }
    if ((r = json_get_integer(o, P, "multi_target_max", 1, 1024, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->multi_target_max = (int)v;
    if ((r = json_get_integer(o, P, "displace_iterations", 0, 1000, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->displace_iterations = (int)v;
    if ((r = json_get_integer(o, P, "slope_iterations", 0, 1000, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->slope_iterations = (int)v;
    char name[32];
    if ((r = json_get_string(o, P, "metric", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_metric_parse(name, &m->metric) != 0) {
        error_set(err, "material.metric: must be euclidean, manhattan or chebyshev (got \"%s\")",
                  name);
        return -1;
    }
    if ((r = json_get_string(o, P, "method", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_method_parse(name, &m->method) != 0) {
        error_set(err, "material.method: must be iterative, ssbo or multi (got \"%s\")", name);
        return -1;
    }
    int has_method = r;
    m->model = sim_model_from_method(m->method);
    if ((r = json_get_string(o, P, "model", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_model_parse(name, &m->model) != 0) {
        error_set(err,
                  "material.model: must be persson-iterative, persson-ssbo, persson-multi, "
                  "subtract, deferred, diffusion or decals (got \"%s\")",
                  name);
        return -1;
    }
    if (r && sim_model_is_persson(m->model)) {
        sim_method implied = m->model == SIM_MODEL_PERSSON_ITERATIVE ? SIM_METHOD_ITERATIVE
                             : m->model == SIM_MODEL_PERSSON_MULTI   ? SIM_METHOD_MULTI
                                                                     : SIM_METHOD_SSBO;
        if (has_method && implied != m->method) {
            error_set(err, "material.method: \"%s\" contradicts material.model \"%s\"",
                      sim_method_name(m->method), name);
            return -1;
        }
        m->method = implied;
    }
    /* a preset first, so explicit D / zeta_inv / repose_deg override it */
    char preset[32];
    if ((r = json_get_string(o, P, "preset", preset, sizeof preset, err)) < 0)
        return -1;
    if (r) {
        double repose = m->repose_deg;
        const cJSON *rd = cJSON_GetObjectItemCaseSensitive(o, "repose_deg");
        if (sim_material_diffusion_preset(m, preset) != 0) {
            error_set(err, "material.preset: must be mud, pebbles or sand (got \"%s\")", preset);
            return -1;
        }
        if (rd)
            m->repose_deg = repose;
    }
    if (json_get_number(o, P, "refill_m_per_s", 0, 1000, &m->refill_m_per_s, err) < 0 ||
        json_get_number(o, P, "trail_scale_per_m", 0, 1e6, &m->trail_scale_per_m, err) < 0 ||
        json_get_number(o, P, "trail_range_m", 0, 1000, &m->trail_range_m, err) < 0 ||
        json_get_number(o, P, "edge_height", 0, 100, &m->edge_height, err) < 0 ||
        json_get_positive(o, P, "edge_width", 100, 0, &m->edge_width, err) < 0 ||
        json_get_number(o, P, "D", 0, 1e12, &m->diffusion_d, err) < 0 ||
        json_get_number(o, P, "zeta_inv", 0, 1e12, &m->diffusion_zeta_inv, err) < 0 ||
        json_get_number(o, P, "force_scale", 0, 1e12, &m->diffusion_force_scale, err) < 0 ||
        json_get_number(o, P, "dt", 0, 1e12, &m->diffusion_dt, err) < 0 ||
        json_get_number(o, P, "decal_min_strength_m", 0, 1000, &m->decal_min_strength_m, err) < 0)
        return -1;
    const cJSON *sub = cJSON_GetObjectItemCaseSensitive(o, "substeps");
    if (sub && cJSON_IsString(sub)) {
        if (strcmp(sub->valuestring, "auto") != 0) {
            error_set(err, "material.substeps: must be \"auto\" or an integer in [1, 100000]");
            return -1;
        }
        m->diffusion_substeps = SIM_DIFFUSION_SUBSTEPS_AUTO;
    } else {
        if ((r = json_get_integer(o, P, "substeps", 1, 100000, 0, &v, err)) < 0)
            return -1;
        if (r)
            m->diffusion_substeps = (int)v;
    }
    const cJSON *cons = cJSON_GetObjectItemCaseSensitive(o, "conservative");
    if (cons) {
        if (!cJSON_IsBool(cons)) {
            error_set(err, "material.conservative: must be true or false");
            return -1;
        }
        m->diffusion_conservative = cJSON_IsTrue(cons) ? 1 : 0;
    }
    /* the sim's own conversion has the last word on what it can run */
    sim_params p;
    if (sim_params_from_material(m, s->cell_size_m, s->units_per_m, s->floor_units, &p, err) != 0)
        return -1;
    return 0;
}

/* ---- colliders ---- */

static int parse_quat(const cJSON *obj, const char *path, quatd *q, error_text *err)
{
    double v[4];
    int r = json_get_vector(obj, path, "orientation", 4, 1e6, v, err);
    if (r <= 0) {
        *q = (quatd){1, 0, 0, 0};
        return r;
    }
    double n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3];
    if (!(n2 > 1e-12)) {
        char p[256];
        json_path_join(p, sizeof p, path, "orientation");
        error_set(err, "%s: must be a non-zero quaternion [w, x, y, z]", p);
        return -1;
    }
    *q = quat_normalize((quatd){v[0], v[1], v[2], v[3]});
    return 1;
}

static int parse_position(const cJSON *obj, const char *path, vec3d *p, error_text *err)
{
    double v[3];
    int r = json_get_vector(obj, path, "position", 3, 1e6, v, err);
    if (r > 0)
        *p = (vec3d){v[0], v[1], v[2]};
    return r;
}

static int parse_keyframes(const cJSON *arr, const char *path, collider_motion *m, error_text *err)
{
    int n = cJSON_IsArray(arr) ? cJSON_GetArraySize(arr) : 0;
    if (n < 1 || n > SCENE_KEYFRAMES_MAX) {
        error_set(err, "%s: must be an array of 1 to %d keyframes", path, SCENE_KEYFRAMES_MAX);
        return -1;
    }
    m->keyframes = calloc((size_t)n, sizeof *m->keyframes);
    if (!m->keyframes) {
        error_set(err, "%s: out of memory", path);
        return -1;
    }
    m->keyframe_count = n;
    static const char *const keys[] = {"time_s", "position", "orientation", NULL};
    int i = 0;
    for (const cJSON *k = arr->child; k; k = k->next, i++) {
        char p[256];
        json_path_index(p, sizeof p, path, i);
        collider_keyframe *f = &m->keyframes[i];
        if (json_expect_object(k, p, "scene", err) || json_check_keys(k, p, keys, NULL, err) ||
            json_require_number(k, p, "time_s", -SCENE_TIME_MAX_S, SCENE_TIME_MAX_S, &f->time_s,
                                err))
            return -1;
        if (i > 0 && !(f->time_s > m->keyframes[i - 1].time_s)) {
            error_set(err, "%s.time_s: must be greater than the previous keyframe's (%g <= %g)", p,
                      f->time_s, m->keyframes[i - 1].time_s);
            return -1;
        }
        int r = parse_position(k, p, &f->pose.position, err);
        if (r < 0)
            return -1;
        if (r == 0) {
            error_set(err, "%s.position: missing ([x, y, z] in metres)", p);
            return -1;
        }
        if (parse_quat(k, p, &f->pose.orientation, err) < 0)
            return -1;
    }
    return 0;
}

static int parse_motion(const cJSON *c, const char *path, collider_motion *m, int has_position,
                        error_text *err)
{
    const cJSON *o = cJSON_GetObjectItemCaseSensitive(c, "motion");
    char p[256];
    json_path_join(p, sizeof p, path, "motion");
    m->kind = COLLIDER_MOTION_STATIC;
    if (!o) {
        if (!has_position) {
            error_set(err, "%s.position: missing ([x, y, z] in metres)", path);
            return -1;
        }
        return 0;
    }
    if (json_expect_object(o, p, "scene", err))
        return -1;
    const cJSON *kf = cJSON_GetObjectItemCaseSensitive(o, "keyframes");
    if (kf) {
        static const char *const keys[] = {"keyframes", NULL};
        if (json_check_keys(o, p, keys, "keyframe motion (velocity and keyframes do not mix)", err))
            return -1;
        if (has_position) {
            error_set(err,
                      "%s.position: not allowed with motion.keyframes (the keyframes give "
                      "the pose)",
                      path);
            return -1;
        }
        char q[280];
        json_path_join(q, sizeof q, p, "keyframes");
        if (parse_keyframes(kf, q, m, err) != 0)
            return -1;
        m->kind = COLLIDER_MOTION_KEYFRAMES;
        m->start = m->keyframes[0].pose;
        return 0;
    }
    static const char *const keys[] = {"velocity", "spin_axis", "spin_deg_per_s", NULL};
    if (json_check_keys(o, p, keys, NULL, err))
        return -1;
    if (!has_position) {
        error_set(err, "%s.position: missing ([x, y, z] in metres)", path);
        return -1;
    }
    double v[3] = {0, 0, 0}, axis[3] = {0, 0, 1}, spin = 0;
    if (json_get_vector(o, p, "velocity", 3, SCENE_SPEED_MAX, v, err) < 0 ||
        json_get_vector(o, p, "spin_axis", 3, 1e6, axis, err) < 0 ||
        json_get_number(o, p, "spin_deg_per_s", -SCENE_SPIN_MAX_DEG, SCENE_SPIN_MAX_DEG, &spin,
                        err) < 0)
        return -1;
    if (spin != 0.0 && !(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2] > 1e-12)) {
        error_set(err, "%s.spin_axis: must be a non-zero vector when spin_deg_per_s is not 0", p);
        return -1;
    }
    m->kind = COLLIDER_MOTION_VELOCITY;
    m->velocity = (vec3d){v[0], v[1], v[2]};
    m->spin_axis = (vec3d){axis[0], axis[1], axis[2]};
    m->spin_rad_per_s = spin * (M_PI / 180.0);
    return 0;
}

static int load_mesh(const scene_parser *ps, const cJSON *c, const char *path, scene *s,
                     collider_geometry *g, error_text *err)
{
    char rel[1024], full[1024];
    int r = json_get_string(c, path, "obj", rel, sizeof rel, err);
    if (r < 0)
        return -1;
    if (r == 0 || !rel[0]) {
        error_set(err, "%s.obj: missing (the OBJ file of a mesh collider)", path);
        return -1;
    }
    double scale = 1.0;
    if (json_get_positive(c, path, "scale", 1e6, 0, &scale, err) < 0)
        return -1;
    char field[280];
    json_path_join(field, sizeof field, path, "obj");
    if (resolve_path(ps->base_dir, rel, full, sizeof full, field, err))
        return -1;
    collider_mesh *m = &s->meshes[s->mesh_count];
    if (collider_mesh_load_obj(full, m, err) != 0) {
        error_prefix(err, field, ": ");
        return -1;
    }
    s->mesh_count++;
    if (scale != 1.0) {
        for (int i = 0; i < 3 * m->vertex_count; i++)
            m->vertices[i] = (float)(m->vertices[i] * scale);
        m->bounding_radius *= scale;
    }
    g->mesh = m;
    return 0;
}

static int parse_collider(const scene_parser *ps, const cJSON *c, const char *path, int index,
                          scene *s, scene_collider *sc, error_text *err)
{
    if (json_expect_object(c, path, "scene", err))
        return -1;
    char shape[32];
    int r = json_get_string(c, path, "shape", shape, sizeof shape, err);
    if (r < 0)
        return -1;
    if (r == 0) {
        error_set(err, "%s.shape: missing (sphere, box, capsule, cylinder, wheel or mesh)", path);
        return -1;
    }
    collider_geometry *g = &sc->geometry;
    const char *context;
    static const char *const sphere_keys[] = {"name",   "shape",  "position", "orientation",
                                              "motion", "radius", NULL};
    static const char *const axial_keys[] = {"name",   "shape",  "position",    "orientation",
                                             "motion", "radius", "half_length", NULL};
    static const char *const box_keys[] = {"name",   "shape",        "position", "orientation",
                                           "motion", "half_extents", NULL};
    static const char *const mesh_keys[] = {"name",   "shape", "position", "orientation",
                                            "motion", "obj",   "scale",    NULL};
    const char *const *keys;
    if (strcmp(shape, "sphere") == 0) {
        g->shape = COLLIDER_SPHERE;
        keys = sphere_keys;
        context = "a sphere";
    } else if (strcmp(shape, "box") == 0) {
        g->shape = COLLIDER_BOX;
        keys = box_keys;
        context = "a box";
    } else if (strcmp(shape, "capsule") == 0) {
        g->shape = COLLIDER_CAPSULE;
        keys = axial_keys;
        context = "a capsule";
    } else if (strcmp(shape, "cylinder") == 0 || strcmp(shape, "wheel") == 0) {
        g->shape = COLLIDER_CYLINDER;
        keys = axial_keys;
        context = "a cylinder";
    } else if (strcmp(shape, "mesh") == 0) {
        g->shape = COLLIDER_MESH;
        keys = mesh_keys;
        context = "a mesh";
    } else {
        error_set(err,
                  "%s.shape: must be sphere, box, capsule, cylinder, wheel or mesh (got \"%s\")",
                  path, shape);
        return -1;
    }
    if (json_check_keys(c, path, keys, context, err))
        return -1;
    r = json_get_string(c, path, "name", sc->name, sizeof sc->name, err);
    if (r < 0)
        return -1;
    if (r == 0)
        snprintf(sc->name, sizeof sc->name, "collider-%d", index);

    switch (g->shape) {
    case COLLIDER_SPHERE:
        if (json_get_positive(c, path, "radius", 1000, 1, &g->radius, err) < 0)
            return -1;
        break;
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER:
        if (json_get_positive(c, path, "radius", 1000, 1, &g->radius, err) < 0)
            return -1;
        if (g->shape == COLLIDER_CAPSULE) {
            if (json_require_number(c, path, "half_length", 0, 1000, &g->half_length, err))
                return -1;
        } else if (json_get_positive(c, path, "half_length", 1000, 1, &g->half_length, err) < 0) {
            return -1;
        }
        break;
    case COLLIDER_BOX: {
        double e[3];
        r = json_get_vector(c, path, "half_extents", 3, 1000, e, err);
        if (r < 0)
            return -1;
        if (r == 0) {
            error_set(err, "%s.half_extents: missing ([x, y, z] half sizes in metres)", path);
            return -1;
        }
        g->half_extents = (vec3d){e[0], e[1], e[2]};
        break;
    }
    case COLLIDER_MESH:
        if (load_mesh(ps, c, path, s, g, err) != 0)
            return -1;
        break;
    }
    /* the collider module's own checks (sizes > 0, mesh extent) have the last word */
    if (collider_geometry_validate(g, err) != 0) {
        error_prefix(err, path, ".");
        return -1;
    }

    collider_motion *m = &sc->motion;
    int has_position = parse_position(c, path, &m->start.position, err);
    if (has_position < 0 || parse_quat(c, path, &m->start.orientation, err) < 0)
        return -1;
    if (parse_motion(c, path, m, has_position, err) != 0)
        return -1;
    if (cJSON_GetObjectItemCaseSensitive(c, "orientation") &&
        m->kind == COLLIDER_MOTION_KEYFRAMES) {
        error_set(err,
                  "%s.orientation: not allowed with motion.keyframes (the keyframes give "
                  "the pose)",
                  path);
        return -1;
    }
    if (collider_pose_validate(&m->start, err) != 0) {
        error_prefix(err, path, ".");
        return -1;
    }
    return 0;
}

static int parse_colliders(const cJSON *root, const scene_parser *ps, scene *s, error_text *err)
{
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "colliders");
    if (!arr)
        return 0;
    if (!cJSON_IsArray(arr)) {
        error_set(err, "colliders: must be an array (got %s)", json_type_name(arr));
        return -1;
    }
    int n = cJSON_GetArraySize(arr);
    if (n > SCENE_COLLIDERS_MAX) {
        error_set(err, "colliders: at most %d colliders (got %d)", SCENE_COLLIDERS_MAX, n);
        return -1;
    }
    if (n == 0)
        return 0;
    int meshes = 0;
    for (const cJSON *c = arr->child; c; c = c->next) {
        const cJSON *sh = cJSON_GetObjectItemCaseSensitive(c, "shape");
        if (cJSON_IsString(sh) && sh->valuestring && strcmp(sh->valuestring, "mesh") == 0)
            meshes++;
    }
    s->colliders = calloc((size_t)n, sizeof *s->colliders);
    /* sized up front: geometry.mesh points into this array, so it never moves */
    s->meshes = meshes ? calloc((size_t)meshes, sizeof *s->meshes) : NULL;
    if (!s->colliders || (meshes && !s->meshes)) {
        error_set(err, "colliders: out of memory");
        return -1;
    }
    int i = 0;
    for (const cJSON *c = arr->child; c; c = c->next, i++) {
        char p[64];
        json_path_index(p, sizeof p, "colliders", i);
        s->collider_count = i + 1; /* so scene_free releases a half-parsed one */
        if (parse_collider(ps, c, p, i, s, &s->colliders[i], err) != 0)
            return -1;
    }
    return 0;
}

/* ---- entry points ---- */

static const char *const top_keys[] = {
    "name",    "description",         "world",     "terrain",   "material",
    "tick_hz", "active_margin_cells", "colliders", "materials", "material_map",
    NULL};

/* Build the ground from JSON text {"materials", "material_map"}. */
static int ground_from_json_text(const scene *s, const char *text, ground *g, error_text *err)
{
    cJSON *root = cJSON_Parse(text);
    if (!root) {
        error_set(err, "materials: out of memory");
        return -1;
    }
    ground_extent x = {s->width, s->height, s->cell_size_m, s->units_per_m, s->floor_units};
    ground_material base = sim_material_ground(&s->material);
    int rc = ground_init_json(g, x, &base, cJSON_GetObjectItemCaseSensitive(root, "materials"),
                              cJSON_GetObjectItemCaseSensitive(root, "material_map"), err);
    cJSON_Delete(root);
    return rc;
}

/* "materials" and "material_map": validated now (errors name the field),
 * kept as text for scene_create_ground. */
static int parse_ground(const cJSON *root, scene *s, error_text *err)
{
    const cJSON *materials = cJSON_GetObjectItemCaseSensitive(root, "materials");
    const cJSON *map = cJSON_GetObjectItemCaseSensitive(root, "material_map");
    if (!materials && !map)
        return 0;
    cJSON *both = cJSON_CreateObject();
    if (!both ||
        (materials && !cJSON_AddItemToObject(both, "materials", cJSON_Duplicate(materials, 1))) ||
        (map && !cJSON_AddItemToObject(both, "material_map", cJSON_Duplicate(map, 1))) ||
        !(s->ground_json = cJSON_PrintUnformatted(both))) {
        cJSON_Delete(both);
        error_set(err, "materials: out of memory");
        return -1;
    }
    cJSON_Delete(both);
    ground g;
    if (ground_from_json_text(s, s->ground_json, &g, err) != 0)
        return -1;
    ground_free(&g);
    return 0;
}

int scene_create_ground(const scene *s, const world *w, ground *g, error_text *err)
{
    if (!s->ground_json) {
        ground_material base = sim_material_ground(&s->material);
        return ground_init_uniform(g, ground_extent_of_world(w), &base, err);
    }
    return ground_from_json_text(s, s->ground_json, g, err);
}

int scene_load_json(const char *text, const char *base_dir, scene *s, error_text *err)
{
    memset(s, 0, sizeof *s);
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithOpts(text, &end, 1);
    if (!root) {
        size_t at = end && end >= text ? (size_t)(end - text) : 0;
        error_set(err, "scene: JSON syntax error near byte %zu", at);
        return -1;
    }
    scene_parser ps = {base_dir ? base_dir : ".", err};
    int rc = -1;
    char description[4096];
    double tick_hz = 60, margin = 4;
    if (json_expect_object(root, "", "scene", err) ||
        json_check_keys(root, "", top_keys, NULL, err))
        goto done;
    snprintf(s->name, sizeof s->name, "unnamed");
    if (json_get_string(root, "", "name", s->name, sizeof s->name, err) < 0 ||
        json_get_string(root, "", "description", description, sizeof description, err) < 0 ||
        json_get_positive(root, "", "tick_hz", 10000, 0, &tick_hz, err) < 0)
        goto done;
    s->tick_hz = tick_hz; /* the material's rates are per second */
    if (parse_world(root, s, err) || parse_terrain(root, &ps, s, err) ||
        parse_material(root, s, err) || parse_ground(root, s, err) ||
        json_get_integer(root, "", "active_margin_cells", 0, 4096, 0, &margin, err) < 0 ||
        parse_colliders(root, &ps, s, err))
        goto done;
    s->tick_hz = tick_hz;
    s->active_margin_cells = (int)margin;
    rc = 0;
done:
    cJSON_Delete(root);
    if (rc != 0)
        scene_free(s);
    return rc;
}

int scene_load_file(const char *path, scene *s, error_text *err)
{
    memset(s, 0, sizeof *s);
    FILE *f = fopen(path, "rb");
    if (!f) {
        error_set(err, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    long size = -1;
    if (fseek(f, 0, SEEK_END) == 0)
        size = ftell(f);
    if (size < 0 || size > SCENE_FILE_BYTES_MAX) {
        error_set(err, "%s: %s", path,
                  size < 0 ? "cannot determine the file size" : "scene file larger than 64 MiB");
        fclose(f);
        return -1;
    }
    rewind(f);
    char *text = malloc((size_t)size + 1);
    if (!text || fread(text, 1, (size_t)size, f) != (size_t)size) {
        error_set(err, "%s: cannot read", path);
        free(text);
        fclose(f);
        return -1;
    }
    fclose(f);
    text[size] = '\0';
    char dir[1024];
    const char *slash = strrchr(path, '/');
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else if (slash == path)
        snprintf(dir, sizeof dir, "/");
    else
        snprintf(dir, sizeof dir, "%.*s", (int)(slash - path), path);
    int rc = scene_load_json(text, dir, s, err);
    free(text);
    if (rc != 0)
        error_prefix(err, path, ": ");
    return rc;
}

int scene_load_default(scene *s, error_text *err)
{
    memset(s, 0, sizeof *s);
    size_t size = 0;
    const char *data = embedded_file_find("server/scene/default.json", &size);
    if (!data) {
        error_set(err, "scene: the embedded default scene is missing from this build");
        return -1;
    }
    char *text = malloc(size + 1); /* embedded data need not be NUL-terminated */
    if (!text) {
        error_set(err, "scene: out of memory");
        return -1;
    }
    memcpy(text, data, size);
    text[size] = '\0';
    int rc = scene_load_json(text, ".", s, err);
    free(text);
    if (rc != 0)
        error_prefix(err, "default scene", ": ");
    return rc;
}

void scene_free(scene *s)
{
    if (!s)
        return;
    for (int i = 0; i < s->collider_count; i++)
        collider_motion_free(&s->colliders[i].motion);
    free(s->colliders);
    for (int i = 0; i < s->mesh_count; i++)
        collider_mesh_free(&s->meshes[i]);
    free(s->meshes);
    free(s->ground_json);
    memset(s, 0, sizeof *s);
}

int scene_create_world(const scene *s, world *w, error_text *err)
{
    if (world_init_tiled(w, s->width, s->height, s->cell_size_m, s->units_per_m, s->floor_units,
                         s->tile_cells, err) != 0)
        return -1;
    if (world_generate_base(w, &s->base, err) != 0) {
        world_free(w);
        return -1;
    }
    return 0;
}
