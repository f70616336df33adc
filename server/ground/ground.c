/*
 * ground.c: the scene's material table and material map, and the sparse
 * compaction memory (see ground.h). Material ids are evaluated from the map
 * whenever a window is gathered (a few comparisons per cell and paint), so
 * nothing per cell is stored for them; compaction memory lives in 64x64
 * uint16 tiles allocated the first time a cell in them is compacted.
 */
#include "ground/ground.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/*
 * Presets. Sources (docs/materials.md has the discussion):
 *  - sand, mud, pebbles: Gilardi et al., Fig. 4 — angle of repose α and the
 *    diffusion weight D (read as roughness, the share of excess slope moved
 *    per iteration): sand α = π/4, D = 1; mud α = 2π/5, D = 0.25; pebbles
 *    α = π/3, D = 0.9.
 *  - snow: Persson Fig. 5.12 (right), compression 0.9, roughness 0.5.
 *  - mud's compression and both max_compaction values, the snow repose
 *    angle and the densities are terrad's choices (no source gives them).
 */
static const ground_material presets[] = {
    {"snow", 0.9, 0.5, 35.0, 0.30, 300.0},
    {"sand", 0.0, 1.0, 45.0, 0.0, 1600.0},
    {"mud", 0.5, 0.25, 72.0, 0.10, 1800.0},
    {"pebbles", 0.0, 0.9, 60.0, 0.0, 1700.0},
};

int ground_material_preset(const char *name, ground_material *out)
{
    for (size_t i = 0; i < sizeof presets / sizeof presets[0]; i++)
        if (name && strcmp(name, presets[i].name) == 0) {
            *out = presets[i];
            return 0;
        }
    return -1;
}

int ground_material_index(const ground *g, const char *name)
{
    for (int i = 0; i < g->material_count; i++)
        if (strcmp(g->materials[i].name, name) == 0)
            return i;
    return -1;
}

int32_t ground_units_saturated(double units)
{
    if (!(units > 0.0))
        return 0;
    if (units >= (double)(1 << 30))
        return 1 << 30;
    return (int32_t)floor(units);
}

static int in_unit_range(double v)
{
    return isfinite(v) && v >= 0.0 && v <= 1.0;
}

int ground_material_row_from(const ground_material *m, double cell_size_m, int32_t units_per_m,
                             const char *path, ground_material_row *row, error_text *err)
{
    if (!in_unit_range(m->compression)) {
        error_set(err, "%s.compression: must be a number in [0, 1] (got %g)", path, m->compression);
        return -1;
    }
    if (!in_unit_range(m->roughness)) {
        error_set(err, "%s.roughness: must be a number in [0, 1] (got %g)", path, m->roughness);
        return -1;
    }
    if (!isfinite(m->repose_deg) || m->repose_deg < 0.0 || m->repose_deg >= 90.0) {
        error_set(err, "%s.repose_deg: must be a number in [0, 90) (got %g)", path, m->repose_deg);
        return -1;
    }
    memset(row, 0, sizeof *row);
    row->compression_q16 = (int32_t)lround(m->compression * 65536.0);
    row->roughness_q16 = (int32_t)lround(m->roughness * 65536.0);
    double rise_per_m = tan(m->repose_deg * M_PI / 180.0);
    double axial = rise_per_m * cell_size_m * units_per_m;
    row->slope_threshold_axial = ground_units_saturated(axial);
    row->slope_threshold_diagonal = ground_units_saturated(axial * M_SQRT2);
    return 0;
}

/* The integer row of one material with its compaction memory; `path` names
 * it in errors. */
static int material_row(const ground *g, const ground_material *m, const char *path,
                        ground_material_row *row, error_text *err)
{
    if (ground_material_row_from(m, g->cell_size_m, g->units_per_m, path, row, err) != 0)
        return -1;
    if (!isfinite(m->max_compaction_m) || m->max_compaction_m < 0.0) {
        error_set(err, "%s.max_compaction_m: must be a number >= 0 (got %g)", path,
                  m->max_compaction_m);
        return -1;
    }
    double units = m->max_compaction_m * g->units_per_m;
    if (units > GROUND_COMPACTION_MAX) {
        error_set(err, "%s.max_compaction_m: at most %g m at %d units per metre (got %g)", path,
                  GROUND_COMPACTION_MAX / (double)g->units_per_m, (int)g->units_per_m,
                  m->max_compaction_m);
        return -1;
    }
    /* memory only where something is compacted: compression 0 needs none */
    row->max_compaction = row->compression_q16 > 0 ? (int32_t)floor(units) : 0;
    return 0;
}

ground_extent ground_extent_of_world(const world *w)
{
    ground_extent x = {w->width, w->height, w->cell_size_m, w->units_per_m, w->floor};
    return x;
}

static void ground_base(ground *g, ground_extent w)
{
    memset(g, 0, sizeof *g);
    g->width = w.width;
    g->height = w.height;
    g->cell_size_m = w.cell_size_m;
    g->units_per_m = w.units_per_m;
    g->tiles_x = (w.width + GROUND_TILE_SIDE - 1) / GROUND_TILE_SIDE;
    g->tiles_y = (w.height + GROUND_TILE_SIDE - 1) / GROUND_TILE_SIDE;
}

/* Finish: uniform flag, compaction flag and its tile directory. */
static int ground_finish(ground *g, error_text *err)
{
    g->table.count = g->material_count;
    g->uniform = g->material_count == 1;
    g->uses_compaction = 0;
    for (int i = 0; i < g->material_count; i++)
        if (g->table.rows[i].max_compaction > 0)
            g->uses_compaction = 1;
    if (g->uses_compaction) {
        g->compaction_tiles = calloc((size_t)g->tiles_x * g->tiles_y, sizeof *g->compaction_tiles);
        if (!g->compaction_tiles) {
            error_set(err, "ground: out of memory for the compaction tile directory");
            return -1;
        }
    }
    return 0;
}

int ground_init_uniform(ground *g, ground_extent w, const ground_material *base, error_text *err)
{
    ground_base(g, w);
    ground_material *m = &g->materials[0];
    snprintf(m->name, sizeof m->name, "default");
    m->compression = base->compression;
    m->roughness = base->roughness;
    m->repose_deg = base->repose_deg;
    g->material_count = 1;
    if (material_row(g, m, "material", &g->table.rows[0], err) != 0)
        return -1;
    return ground_finish(g, err);
}

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
    static const char *const keys[] = {"preset",     "compression",      "roughness",
                                       "repose_deg", "max_compaction_m", "density_kg_m3",
                                       NULL};
    for (const cJSON *k = entry->child; k; k = k->next) {
        int known = 0;
        for (int i = 0; keys[i]; i++)
            known |= strcmp(k->string, keys[i]) == 0;
        if (!known) {
            error_set(err,
                      "%s.%s: unknown key (allowed: preset, compression, roughness, "
                      "repose_deg, max_compaction_m, density_kg_m3)",
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
    if (read_number(entry, path, "compression", 0, 1, 0, &m->compression, err) ||
        read_number(entry, path, "roughness", 0, 1, 0, &m->roughness, err) ||
        read_number(entry, path, "repose_deg", 0, 90, 1, &m->repose_deg, err) ||
        read_number(entry, path, "max_compaction_m", 0, GROUND_COMPACTION_MAX, 0,
                    &m->max_compaction_m, err) ||
        read_number(entry, path, "density_kg_m3", 0, 1e5, 0, &m->density_kg_m3, err))
        return -1;
    return material_row(g, m, path, &g->table.rows[index], err);
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

void ground_free(ground *g)
{
    if (g->compaction_tiles) {
        for (int i = 0; i < g->tiles_x * g->tiles_y; i++)
            free(g->compaction_tiles[i]);
        free(g->compaction_tiles);
    }
    free(g->paints);
    memset(g, 0, sizeof *g);
}

static uint8_t material_at(const ground *g, int x, int y)
{
    double cx = (x + 0.5) * g->cell_size_m, cy = (y + 0.5) * g->cell_size_m;
    uint8_t id = g->default_material;
    for (int i = 0; i < g->paint_count; i++) {
        const ground_paint *p = &g->paints[i];
        if (p->kind == GROUND_PAINT_RECT) {
            if (cx >= p->a && cx < p->c && cy >= p->b && cy < p->d)
                id = p->material;
        } else {
            double dx = cx - p->a, dy = cy - p->b;
            if (dx * dx + dy * dy <= p->c * p->c)
                id = p->material;
        }
    }
    return id;
}

void ground_gather_ids(const ground *g, world_rect r, uint8_t *dst)
{
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++)
            dst[(int64_t)y * r.w + x] = material_at(g, r.x + x, r.y + y);
}

void ground_gather_compaction(const ground *g, world_rect r, uint16_t *dst)
{
    for (int y = 0; y < r.h; y++) {
        int wy = r.y + y;
        for (int x = 0; x < r.w; x++) {
            int wx = r.x + x;
            const uint16_t *tile = g->compaction_tiles
                                       ? g->compaction_tiles[(wy / GROUND_TILE_SIDE) * g->tiles_x +
                                                             wx / GROUND_TILE_SIDE]
                                       : NULL;
            dst[(int64_t)y * r.w + x] =
                tile ? tile[(wy % GROUND_TILE_SIDE) * GROUND_TILE_SIDE + wx % GROUND_TILE_SIDE] : 0;
        }
    }
}

int ground_scatter_compaction(ground *g, world_rect r, const uint16_t *src, error_text *err)
{
    if (!g->compaction_tiles)
        return 0;
    for (int y = 0; y < r.h; y++) {
        int wy = r.y + y;
        for (int x = 0; x < r.w; x++) {
            int wx = r.x + x;
            uint16_t v = src[(int64_t)y * r.w + x];
            uint16_t **slot =
                &g->compaction_tiles[(wy / GROUND_TILE_SIDE) * g->tiles_x + wx / GROUND_TILE_SIDE];
            if (!*slot) {
                if (v == 0)
                    continue; /* an absent tile already reads as zero */
                *slot = calloc(GROUND_TILE_SIDE * GROUND_TILE_SIDE, sizeof **slot);
                if (!*slot) {
                    error_set(err, "ground: out of memory for a compaction tile");
                    return -1;
                }
                g->compaction_tiles_allocated++;
            }
            (*slot)[(wy % GROUND_TILE_SIDE) * GROUND_TILE_SIDE + wx % GROUND_TILE_SIDE] = v;
        }
    }
    return 0;
}

int64_t ground_compaction_total(const ground *g)
{
    int64_t total = 0;
    if (!g->compaction_tiles)
        return 0;
    for (int t = 0; t < g->tiles_x * g->tiles_y; t++)
        if (g->compaction_tiles[t])
            for (int i = 0; i < GROUND_TILE_SIDE * GROUND_TILE_SIDE; i++)
                total += g->compaction_tiles[t][i];
    return total;
}

uint64_t ground_compaction_bytes(const ground *g)
{
    if (!g->compaction_tiles)
        return 0;
    return (uint64_t)g->tiles_x * g->tiles_y * sizeof *g->compaction_tiles +
           (uint64_t)g->compaction_tiles_allocated * GROUND_TILE_SIDE * GROUND_TILE_SIDE *
               sizeof(uint16_t);
}
