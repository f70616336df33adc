/*
 * ground: what the terrain is made of, cell by cell, and what it remembers.
 *
 * Two per-cell layers beside the world's heights, kept out of world/ so the
 * height storage can change without them:
 *
 *   material ids  uint8 per cell, an index into the scene's material table
 *                 (at most GROUND_MATERIALS_MAX). They come from the scene's
 *                 material map — a default material and painted rectangles
 *                 and circles, later paints on top — evaluated on demand
 *                 when a window is gathered; nothing is stored per cell.
 *   compaction    flag only: when some material has max_compaction_m > 0
 *                 and compression > 0, each cell remembers the height units
 *                 it has been compacted by (Persson ch. 6.2, future work).
 *                 The memory itself is the world's (world_compaction_*,
 *                 world/world_soil.c), so the store logs and snapshots it
 *                 with the heights; the engine gathers it per window and
 *                 scatters back what the window compacted.
 *
 * The tick gathers the ids for each window (ground_gather_ids) and the stages
 * read them (sim_classify_materials, sim_even_slopes_materials).
 *
 * The material table — each material's integer row — is defined here, below
 * sim/, so the ground depends on the world alone and the sim on the ground.
 */
#ifndef TERRAD_GROUND_H
#define TERRAD_GROUND_H

#include <stdint.h>

#include "base/base.h"
#include "world/world.h"

#define GROUND_NAME_MAX 32
#define GROUND_PAINTS_MAX 256
/* Compaction memory is uint16 height units; a material's max_compaction_m
 * must fit (6.5 m at the default 10,000 units per metre). */
#define GROUND_COMPACTION_MAX WORLD_COMPACTION_MAX

/*
 * A soil's terramechanics parameters (the bekker model, docs/models.md), in
 * SI units as Wong's tables and Chrono's SCM give them: Bekker's
 * p = (kc/b + kphi) z^n, Mohr-Coulomb's c and phi with Janosi-Hanamoto's K,
 * the elastic unloading/reloading stiffness and a damping. The share of a
 * plastic sinkage that compacts (rather than being pushed aside) is the
 * material's `compression`. Defined here so each material of the table can
 * carry its own (the sim names it sim_soil; its presets and ranges are the
 * sim's, sim_soil.c, and the scene reads and checks each entry's).
 */
typedef struct ground_soil {
    double n;              /* sinkage exponent, (0, 3] */
    double kc;             /* N/m^(n+1), >= 0 */
    double kphi;           /* N/m^(n+2), > 0 */
    double cohesion_pa;    /* c, >= 0 */
    double friction_deg;   /* phi, [0, 60] */
    double shear_k_m;      /* Janosi-Hanamoto K, > 0 */
    double elastic_pa_m;   /* unloading/reloading stiffness, > 0 */
    double damping_pa_s_m; /* pressure per m/s of sinking, >= 0 */
    double slip_n;         /* slip-sinkage: n grows by slip_n x the cell's slip ratio, [0, 2] */
    double density_kg_m3;  /* bulk density: the unit weight in a lug's bulldozing, (0, 3000] */
} ground_soil;

typedef struct ground_material {
    char name[GROUND_NAME_MAX];
    double compression;      /* [0, 1] share of the yielded depth compacted away */
    double roughness;        /* [0, 1] share of excess slope moved per iteration */
    double repose_deg;       /* [0, 90) */
    double max_compaction_m; /* [0, ...] how far a column can be compacted in all; 0: no memory */
    double density_kg_m3;    /* informative (docs, clients); not used by the stages */
    ground_soil soil;        /* bekker: the base's unless the entry has "soil" (the scene's) */
} ground_material;

/* Presets: "snow", "sand", "mud", "pebbles" (numbers and sources in
 * docs/materials.md). Returns 0, or -1 for an unknown name. */
int ground_material_preset(const char *name, ground_material *out);

/* The integer form of a material's per-cell part, computed once on the CPU:
 * what the classify and slope stages read per cell (sim_material_row_from_params
 * gives the row of the uniform params). */
#define GROUND_MATERIALS_MAX 16

typedef struct ground_material_row {
    int32_t compression_q16;          /* 0..65536 */
    int32_t roughness_q16;            /* 0..65536 */
    int32_t slope_threshold_axial;    /* units */
    int32_t slope_threshold_diagonal; /* units */
    int32_t max_compaction;           /* units, 0..65535; 0: no compaction memory */
} ground_material_row;

typedef struct ground_material_table {
    int count; /* 1..GROUND_MATERIALS_MAX */
    ground_material_row rows[GROUND_MATERIALS_MAX];
    /* bekker: each material's soil, read per contact cell (model_bekker.c);
     * no GPU stage reads it */
    ground_soil soils[GROUND_MATERIALS_MAX];
} ground_material_table;

/* A non-negative length in units, saturated at 2^30 (any larger threshold
 * already means "never"). */
int32_t ground_units_saturated(double units);

/* A repose threshold in whole units: floor, except that a value within a
 * relative 1e-9 below a whole number is that number (ground.c says why), so
 * a slope exactly at the angle of repose is at rest. */
int32_t ground_repose_units(double units);

/*
 * compression, roughness and repose_deg of m into a row (max_compaction 0):
 * Q16 shares and the angle of repose as height-difference thresholds for
 * axial and diagonal neighbours, so no GPU evaluates atan or compares floats.
 * Errors name "<path>.<field>", e.g. "material.roughness: must be a number in
 * [0, 1] (got 2)". Returns 0 or -1.
 */
int ground_material_row_from(const ground_material *m, double cell_size_m, int32_t units_per_m,
                             const char *path, ground_material_row *row, error_text *err);

typedef enum ground_paint_kind {
    GROUND_PAINT_RECT,   /* cells whose centre is in [x0, x1) x [y0, y1) (metres) */
    GROUND_PAINT_CIRCLE, /* cells whose centre is within r of (cx, cy) (metres) */
} ground_paint_kind;

typedef struct ground_paint {
    ground_paint_kind kind;
    uint8_t material;
    double a, b, c, d; /* rect: x0 y0 x1 y1; circle: cx cy r (d unused) */
} ground_paint;

/* The world's shape and scale, all the ground needs of it (a scene has these
 * before any world exists). */
typedef struct ground_extent {
    int width, height; /* cells */
    double cell_size_m;
    int32_t units_per_m;
    int32_t floor; /* units */
} ground_extent;

ground_extent ground_extent_of_world(const world *w);

typedef struct ground {
    int width, height; /* world cells */
    double cell_size_m;
    int32_t units_per_m;
    int material_count;
    ground_material materials[GROUND_MATERIALS_MAX];
    ground_material_table table; /* the integer rows the stages use */
    uint8_t default_material;
    ground_paint *paints;
    int paint_count;
    int uniform;         /* every cell is material 0: no id buffer is needed */
    int uses_compaction; /* some material remembers compaction (in the world) */
} ground;

/*
 * One material everywhere: `base` (the per-cell part of the scene's
 * "material", sim_material_ground), no compaction memory. The world's
 * dimensions and scale give the integer rows.
 */
int ground_init_uniform(ground *g, ground_extent x, const ground_material *base, error_text *err);

/*
 * From the scene: `materials` is the JSON object {"name": {"preset": ...,
 * overrides...}, ...} and `map` the object {"default": "name", "paint": [
 * {"material": "name", "rect": [x0, y0, x1, y1]} | {"material": "name",
 * "circle": [cx, cy, r]}, ...]} (metres), either may be NULL (then one
 * material, `base`). `base` gives what an entry does not override
 * (compression, roughness, repose, soil). An entry's "soil" is accepted
 * but not read here: its presets and ranges are the sim's, so the scene
 * reads it (scene_material.c) and sets it with ground_set_soil. Errors name
 * the field, e.g.
 * "materials.snow.roughness: must be a number in [0, 1] (got 2)".
 * The JSON values are cJSON pointers, passed as void to keep cJSON out of
 * this header.
 */
int ground_init_json(ground *g, ground_extent x, const ground_material *base, const void *materials,
                     const void *map, error_text *err);
void ground_free(ground *g);

/* Material `index`'s soil (the scene's reading of its entry's "soil",
 * already checked by the sim's rules); an index out of the table is ignored. */
void ground_set_soil(ground *g, int index, const ground_soil *soil);

/* Index of a material by name, or -1. */
int ground_material_index(const ground *g, const char *name);

/* Material ids of a rectangle of world cells, row-major (r must be inside). */
void ground_gather_ids(const ground *g, world_rect r, uint8_t *dst);

#endif
