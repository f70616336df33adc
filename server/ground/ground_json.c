/*
 * ground_json.c: the scene's "materials" table and "material_map" (paints of
 * rectangles and circles) read from cJSON into a ground (ground.h). Kept apart
 * from ground.c so that the deformation core builds without cJSON: the twin
 * library (server/twin/, docs/engines.md) compiles ground.c alone, natively
 * and for WebAssembly.
 */
#include "ground/ground_internal.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* An optional number field of a material entry. */
static int read_number(const cJSON *o, const char *path, const char *key, double lo, double hi,
                       int hi_open, double *out, error_text *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    if (!v)
        return 0;
    if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble) || v->valuedouble < lo ||
        (hi_open ? v->valuedouble >= hi : v->valuedouble > hi)) {
        error_set(err, "%s.%s: must be a number in [%g, %g%s", path, key, lo, hi,
                  hi_open ? ")" : "]");
        return -1;
    }
    *out = v->valuedouble;
    return 0;
}

static int parse_material_entry(ground *g, const ground_material *base, const cJSON *entry,
                                int index, error_text *err)
{
    char path[GROUND_NAME_MAX + 16];
    snprintf(path, sizeof path, "materials.%s", entry->string);
    if (!cJSON_IsObject(entry)) {
        error_set(err, "%s: must be an object", path);
        return -1;
    }
    static const char *const keys[] = {
        "preset",           "compression",   "roughness", "repose_deg",
        "max_compaction_m", "density_kg_m3", "soil",      NULL};
    for (const cJSON *k = entry->child; k; k = k->next) {
        int known = 0;
        for (int i = 0; keys[i]; i++)
            known |= strcmp(k->string, keys[i]) == 0;
        if (!known) {
            error_set(err,
                      "%s.%s: unknown key (allowed: preset, compression, roughness, "
                      "repose_deg, max_compaction_m, density_kg_m3, soil)",
                      path, k->string);
            return -1;
        }
    }
    ground_material *m = &g->materials[index];
    memset(m, 0, sizeof *m);
    m->compression = base->compression;
    m->roughness = base->roughness;
    m->repose_deg = base->repose_deg;
    const cJSON *preset = cJSON_GetObjectItemCaseSensitive(entry, "preset");
    if (preset) {
        if (!cJSON_IsString(preset) || ground_material_preset(preset->valuestring, m) != 0) {
            error_set(err, "%s.preset: must be snow, sand, mud or pebbles", path);
            return -1;
        }
    }
    snprintf(m->name, sizeof m->name, "%s", entry->string);
    m->soil = base->soil; /* an entry's own "soil" is the scene's to read */
    if (read_number(entry, path, "compression", 0, 1, 0, &m->compression, err) ||
        read_number(entry, path, "roughness", 0, 1, 0, &m->roughness, err) ||
        read_number(entry, path, "repose_deg", 0, 90, 1, &m->repose_deg, err) ||
        read_number(entry, path, "max_compaction_m", 0, GROUND_COMPACTION_MAX, 0,
                    &m->max_compaction_m, err) ||
        read_number(entry, path, "density_kg_m3", 0, 1e5, 0, &m->density_kg_m3, err))
        return -1;
    return ground_row_checked(g, m, path, &g->table.rows[index], err);
}

static int paint_material(const ground *g, const cJSON *o, const char *path, uint8_t *out,
                          error_text *err)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, "material");
    int id = cJSON_IsString(v) ? ground_material_index(g, v->valuestring) : -1;
    if (id < 0) {
        error_set(err, "%s.material: must name an entry of \"materials\"", path);
        return -1;
    }
    *out = (uint8_t)id;
    return 0;
}

static int read_numbers(const cJSON *arr, const char *path, const char *key, int n, double *v,
                        error_text *err)
{
    if (!cJSON_IsArray(arr) || cJSON_GetArraySize(arr) != n) {
        error_set(err, "%s.%s: must be an array of %d numbers (metres)", path, key, n);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        const cJSON *e = cJSON_GetArrayItem(arr, i);
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble) || fabs(e->valuedouble) > 1e9) {
            error_set(err, "%s.%s[%d]: must be a finite number within ±1e9", path, key, i);
            return -1;
        }
        v[i] = e->valuedouble;
    }
    return 0;
}

static int parse_map(ground *g, const cJSON *map, error_text *err)
{
    if (!cJSON_IsObject(map)) {
        error_set(err, "material_map: must be an object {\"default\", \"paint\"}");
        return -1;
    }
    for (const cJSON *k = map->child; k; k = k->next)
        if (strcmp(k->string, "default") != 0 && strcmp(k->string, "paint") != 0) {
            error_set(err, "material_map.%s: unknown key (allowed: default, paint)", k->string);
            return -1;
        }
    const cJSON *def = cJSON_GetObjectItemCaseSensitive(map, "default");
    if (def) {
        int id = cJSON_IsString(def) ? ground_material_index(g, def->valuestring) : -1;
        if (id < 0) {
            error_set(err, "material_map.default: must name an entry of \"materials\"");
            return -1;
        }
        g->default_material = (uint8_t)id;
    }
    const cJSON *paint = cJSON_GetObjectItemCaseSensitive(map, "paint");
    if (!paint)
        return 0;
    if (!cJSON_IsArray(paint) || cJSON_GetArraySize(paint) > GROUND_PAINTS_MAX) {
        error_set(err, "material_map.paint: must be an array of at most %d paints",
                  GROUND_PAINTS_MAX);
        return -1;
    }
    int count = cJSON_GetArraySize(paint);
    g->paints = calloc(count ? (size_t)count : 1, sizeof *g->paints);
    if (!g->paints) {
        error_set(err, "material_map.paint: out of memory");
        return -1;
    }
    for (int i = 0; i < count; i++) {
        const cJSON *o = cJSON_GetArrayItem(paint, i);
        char path[64];
        snprintf(path, sizeof path, "material_map.paint[%d]", i);
        ground_paint *p = &g->paints[i];
        if (!cJSON_IsObject(o)) {
            error_set(err, "%s: must be an object", path);
            return -1;
        }
        const cJSON *rect = cJSON_GetObjectItemCaseSensitive(o, "rect");
        const cJSON *circle = cJSON_GetObjectItemCaseSensitive(o, "circle");
        if (cJSON_GetArraySize(o) != 2 || !!rect == !!circle) {
            error_set(err,
                      "%s: must have \"material\" and exactly one of \"rect\" [x0, y0, x1, "
                      "y1] or \"circle\" [cx, cy, r]",
                      path);
            return -1;
        }
        if (paint_material(g, o, path, &p->material, err))
            return -1;
        double v[4] = {0, 0, 0, 0};
        if (rect) {
            if (read_numbers(rect, path, "rect", 4, v, err))
                return -1;
            if (!(v[2] > v[0] && v[3] > v[1])) {
                error_set(err, "%s.rect: must have x1 > x0 and y1 > y0", path);
                return -1;
            }
            p->kind = GROUND_PAINT_RECT;
        } else {
            if (read_numbers(circle, path, "circle", 3, v, err))
                return -1;
            if (!(v[2] > 0)) {
                error_set(err, "%s.circle: radius must be > 0", path);
                return -1;
            }
            p->kind = GROUND_PAINT_CIRCLE;
        }
        p->a = v[0];
        p->b = v[1];
        p->c = v[2];
        p->d = v[3];
        g->paint_count++;
    }
    return 0;
}

int ground_init_json(ground *g, ground_extent w, const ground_material *base,
                     const void *materials_v, const void *map_v, error_text *err)
{
    const cJSON *materials = materials_v, *map = map_v;
    if (!materials) {
        if (map) {
            error_set(err, "material_map: needs a \"materials\" table");
            return -1;
        }
        return ground_init_uniform(g, w, base, err);
    }
    ground_base(g, w);
    if (!cJSON_IsObject(materials) || cJSON_GetArraySize(materials) < 1 ||
        cJSON_GetArraySize(materials) > GROUND_MATERIALS_MAX) {
        error_set(err, "materials: must be an object with 1 to %d entries", GROUND_MATERIALS_MAX);
        return -1;
    }
    int index = 0;
    for (const cJSON *e = materials->child; e; e = e->next, index++) {
        if (!e->string || !e->string[0] || strlen(e->string) >= GROUND_NAME_MAX) {
            error_set(err, "materials: entry names must be 1 to %d bytes", GROUND_NAME_MAX - 1);
            goto fail;
        }
        if (ground_material_index(g, e->string) >= 0) {
            error_set(err, "materials.%s: named twice", e->string);
            goto fail;
        }
        g->material_count = index; /* names so far, for the duplicate check */
        if (parse_material_entry(g, base, e, index, err))
            goto fail;
        g->material_count = index + 1;
    }
    if (g->material_count > 1 && !map) {
        error_set(err, "material_map: required when \"materials\" has more than one entry");
        goto fail;
    }
    if (map && parse_map(g, map, err))
        goto fail;
    /* A single material painted everywhere by default: nothing per cell. */
    if (ground_finish(g, err))
        goto fail;
    return 0;
fail:
    ground_free(g);
    return -1;
}
