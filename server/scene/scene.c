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
 *     "clock": "wall" | "client",                 optional, default "wall"
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

#include "scene/scene_internal.h"

/* ---- world and terrain ---- */

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
    /* 0.1 mm .. 1 km per cell, and at least one height unit per cell: below
     * that the repose thresholds (rise per cell, in units) and the depth of
     * a cell under a collider lose all resolution, and at 1e-300 m a world
     * of 65,536 cells spans 1e-295 m */
    if (cell < SCENE_CELL_SIZE_MIN_M) {
        error_set(err, "world.cell_size_m: must be in [%g, 1000] m (got %g)", SCENE_CELL_SIZE_MIN_M,
                  cell);
        return -1;
    }
    if (cell * upm < 1.0) {
        error_set(err,
                  "world.cell_size_m: %g m at units_per_m %.0f is %.3g height units per cell, "
                  "under one: slope thresholds would be meaningless (use larger cells or more "
                  "units_per_m)",
                  cell, upm, cell * upm);
        return -1;
    }
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

int scene_resolve_path(const char *base_dir, const char *rel, char *out, size_t size,
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
        scene_resolve_path(ps->base_dir, rel, b->path, sizeof b->path, "terrain.path", err))
        return -1;
    return 0;
}

/* ---- entry points ---- */

static const char *const top_keys[] = {"name",
                                       "description",
                                       "world",
                                       "terrain",
                                       "material",
                                       "tick_hz",
                                       "active_margin_cells",
                                       "colliders",
                                       "materials",
                                       "material_map",
                                       "clock",
                                       NULL};

/* "clock": "wall" (the default) or "client" (ticks made due by STEP messages). */
static int parse_clock(const cJSON *root, scene *s, error_text *err)
{
    char clock[16] = "wall";
    if (json_get_string(root, "", "clock", clock, sizeof clock, err) < 0)
        return -1;
    if (strcmp(clock, "wall") != 0 && strcmp(clock, "client") != 0) {
        error_set(err, "clock: \"%s\" is not \"wall\" or \"client\"", clock);
        return -1;
    }
    s->client_clock = strcmp(clock, "client") == 0;
    return 0;
}

/* Each "materials" entry's own "soil" (the bekker model's), over the
 * scene's: the ground keeps it but leaves its rules to the sim. */
static int ground_soils(const scene *s, const cJSON *materials, ground *g, error_text *err)
{
    int index = 0;
    for (const cJSON *e = materials ? materials->child : NULL; e; e = e->next, index++) {
        const cJSON *o = cJSON_GetObjectItemCaseSensitive(e, "soil");
        if (!o)
            continue;
        char path[GROUND_NAME_MAX + 24], parent[GROUND_NAME_MAX + 16];
        snprintf(path, sizeof path, "materials.%s.soil", e->string);
        snprintf(parent, sizeof parent, "materials.%s", e->string);
        sim_soil soil = s->material.soil;
        if (scene_parse_soil(o, path, parent, &soil, err) != 0)
            return -1;
        ground_set_soil(g, index, &soil);
    }
    return 0;
}

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
    const cJSON *materials = cJSON_GetObjectItemCaseSensitive(root, "materials");
    int rc = ground_init_json(g, x, &base, materials,
                              cJSON_GetObjectItemCaseSensitive(root, "material_map"), err);
    if (rc == 0 && ground_soils(s, materials, g, err) != 0) {
        ground_free(g);
        rc = -1;
    }
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
    if ((materials && !cJSON_AddItemToObject(both, "materials", cJSON_Duplicate(materials, 1))) ||
        (map && !cJSON_AddItemToObject(both, "material_map", cJSON_Duplicate(map, 1)))) {
        cJSON_Delete(both);
        both = NULL;
    }
    if (!(s->ground_json = json_print_delete(both))) {
        error_set(err, "materials: out of memory");
        return -1;
    }
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

/*
 * NaN and Infinity are not JSON (RFC 8259 has no such literals; cJSON
 * refuses them as a syntax error), but other JSON writers (Python's json,
 * JavaScript's number printing) produce them. After a failed parse, look for
 * one outside strings, so the error says what it is, at which byte, and after
 * which key. Returns 1 when found (err set).
 */
static int non_finite_literal(const char *text, error_text *err)
{
    static const char *const literals[] = {"-Infinity", "+Infinity", "Infinity",
                                           "-NaN",      "+NaN",      "NaN"};
    char key[64] = "";
    const char *str = NULL; /* start of the last string outside strings */
    size_t str_len = 0;
    for (const char *c = text; *c; c++) {
        if (*c == '"') {
            const char *start = ++c;
            while (*c && *c != '"')
                c += (*c == '\\' && c[1]) ? 2 : 1;
            if (!*c)
                return 0;
            str = start;
            str_len = (size_t)(c - start);
            continue;
        }
        if (*c == ':' && str) {
            snprintf(key, sizeof key, "%.*s", (int)(str_len < 63 ? str_len : 63), str);
            continue;
        }
        for (size_t i = 0; i < sizeof literals / sizeof literals[0]; i++) {
            size_t n = strlen(literals[i]);
            if (strncmp(c, literals[i], n) == 0) {
                error_set(err,
                          "scene: %s at byte %zu%s%s%s is not JSON (JSON has no NaN or Infinity; "
                          "write a finite number)",
                          literals[i], (size_t)(c - text), key[0] ? " (after key \"" : "", key,
                          key[0] ? "\")" : "");
                return 1;
            }
        }
    }
    return 0;
}

int scene_load_json(const char *text, const char *base_dir, scene *s, error_text *err)
{
    memset(s, 0, sizeof *s);
    const char *end = NULL;
    cJSON *root = cJSON_ParseWithOpts(text, &end, 1);
    if (!root) {
        size_t at = end && end >= text ? (size_t)(end - text) : 0;
        if (!non_finite_literal(text, err))
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
        json_get_positive(root, "", "tick_hz", 10000, 0, &tick_hz, err) < 0 ||
        parse_clock(root, s, err) != 0)
        goto done;
    s->tick_hz = tick_hz; /* the material's rates are per second */
    if (parse_world(root, s, err) || parse_terrain(root, &ps, s, err) ||
        scene_parse_material(root, s, err) || parse_ground(root, s, err) ||
        json_get_integer(root, "", "active_margin_cells", 0, 4096, 0, &margin, err) < 0 ||
        scene_parse_colliders(root, &ps, s, err))
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
    uint8_t *data = NULL;
    size_t size = 0;
    if (file_read_all(path, SCENE_FILE_BYTES_MAX, &data, &size, err) != 0)
        return -1;
    const char *text = (const char *)data;
    char dir[1024];
    const char *slash = strrchr(path, '/');
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else if (slash == path)
        snprintf(dir, sizeof dir, "/");
    else
        snprintf(dir, sizeof dir, "%.*s", (int)(slash - path), path);
    int rc = scene_load_json(text, dir, s, err);
    free(data);
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
