/*
 * ground.c: the scene's material table and material map (see ground.h).
 * Material ids are evaluated from the map whenever a window is gathered (a
 * few comparisons per cell and paint), so nothing per cell is stored for
 * them; the compaction memory is the world's (world/world_soil.c), so the
 * store keeps it. The table and map read from a scene's JSON are
 * ground_json.c's.
 */
#include "ground/ground_internal.h"

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
/* (no soil: an entry takes the scene's unless it has its own "soil") */
static const ground_material presets[] = {
    {.name = "snow",
     .compression = 0.9,
     .roughness = 0.5,
     .repose_deg = 35.0,
     .max_compaction_m = 0.30,
     .density_kg_m3 = 300.0},
    {.name = "sand",
     .compression = 0.0,
     .roughness = 1.0,
     .repose_deg = 45.0,
     .max_compaction_m = 0.0,
     .density_kg_m3 = 1600.0},
    {.name = "mud",
     .compression = 0.5,
     .roughness = 0.25,
     .repose_deg = 72.0,
     .max_compaction_m = 0.10,
     .density_kg_m3 = 1800.0},
    {.name = "pebbles",
     .compression = 0.0,
     .roughness = 0.9,
     .repose_deg = 60.0,
     .max_compaction_m = 0.0,
     .density_kg_m3 = 1700.0},
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

/*
 * Repose thresholds: the rise of the angle of repose over one cell, in whole
 * units, rounded down so that a slope at the threshold is at rest and one
 * unit steeper flows; except that a value within a relative 1e-9 below a
 * whole number is that number. tan() and the products carry a relative error
 * of a few 1e-16, so a rise that is exactly whole (tan 45 deg = 1 at 5 cm and
 * 10,000 units per metre: 500) may come out as 499.99999999999994, which a
 * plain floor turns into 499 and leaves a 45 deg slope flowing. 1e-9 is far
 * above that error and far below any angle a scene can tell apart (1e-9 of
 * the rise is a millionth of a unit at any threshold the world can hold).
 */
int32_t ground_repose_units(double units)
{
    if (!(units > 0.0))
        return 0;
    double slack = 1e-9 * (units > 1.0 ? units : 1.0);
    return ground_units_saturated(floor(units + slack));
}

/* An angle the scale cannot hold is refused, naming the field: above 0 deg
 * it must rise at least one unit per cell (else it would act as 0 deg), and
 * its diagonal rise must stay below 2^30 units (else it saturates: "never"). */
static int repose_representable(double deg, double axial, double cell_size_m, int32_t units_per_m,
                                const char *path, error_text *err)
{
    double scale = cell_size_m * units_per_m; /* units of rise per cell at 45 deg */
    if (deg > 0.0 && ground_repose_units(axial) < 1) {
        error_set(err,
                  "%s.repose_deg: %g deg rises %.3g units per cell at cell_size_m %g and "
                  "units_per_m %d, under one unit, so it would act as 0 deg; at this scale "
                  "the smallest angle above 0 is %.3g deg (or raise units_per_m)",
                  path, deg, axial, cell_size_m, (int)units_per_m,
                  atan(1.0 / scale) * 180.0 / M_PI);
        return -1;
    }
    if (axial * M_SQRT2 >= (double)(1 << 30)) {
        error_set(err,
                  "%s.repose_deg: %g deg rises %.3g units per cell at cell_size_m %g and "
                  "units_per_m %d, past the 2^30 units a threshold can hold; at this scale "
                  "the largest angle is %.6g deg",
                  path, deg, axial, cell_size_m, (int)units_per_m,
                  atan((double)(1 << 30) / M_SQRT2 / scale) * 180.0 / M_PI);
        return -1;
    }
    return 0;
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
    double axial = tan(m->repose_deg * M_PI / 180.0) * cell_size_m * units_per_m;
    if (repose_representable(m->repose_deg, axial, cell_size_m, units_per_m, path, err) != 0)
        return -1;
    row->slope_threshold_axial = ground_repose_units(axial);
    row->slope_threshold_diagonal = ground_repose_units(axial * M_SQRT2);
    return 0;
}

/* The integer row of one material with its compaction memory; `path` names
 * it in errors. */
int ground_row_checked(const ground *g, const ground_material *m, const char *path,
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

void ground_base(ground *g, ground_extent w)
{
    memset(g, 0, sizeof *g);
    g->width = w.width;
    g->height = w.height;
    g->cell_size_m = w.cell_size_m;
    g->units_per_m = w.units_per_m;
}

/* Finish: uniform flag and compaction flag (nothing can fail today). */
int ground_finish(ground *g, error_text *err)
{
    g->table.count = g->material_count;
    g->uniform = g->material_count == 1;
    g->uses_compaction = 0;
    for (int i = 0; i < g->material_count; i++) {
        g->table.soils[i] = g->materials[i].soil;
        if (g->table.rows[i].max_compaction > 0)
            g->uses_compaction = 1;
    }
    (void)err;
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
    m->soil = base->soil;
    g->material_count = 1;
    if (ground_row_checked(g, m, "material", &g->table.rows[0], err) != 0)
        return -1;
    return ground_finish(g, err);
}

void ground_set_soil(ground *g, int index, const ground_soil *soil)
{
    if (index < 0 || index >= g->material_count)
        return;
    g->materials[index].soil = *soil;
    g->table.soils[index] = *soil;
}

void ground_free(ground *g)
{
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
