/*
 * world: the terrain itself — an extent in cells, a cell size in metres and
 * int32 heights in fixed units (default 10,000 per metre), held on the CPU as
 * the authoritative copy. Each tick gathers small windows out of it for the
 * deformation backends and scatters the results back (the gather and
 * scatter steps of the tick in docs/design.md); nothing outside a window is
 * touched.
 *
 * The heights are held in square tiles (WORLD_TILE_CELLS_DEFAULT cells a side,
 * a power of two) and the world is sparse: a tile nobody has written is not
 * stored at all, its heights are produced from the base terrain whenever they
 * are read (see terrain_base.c), so a 65,536² world costs only its tile table
 * until something presses into it. Only the functions below see tiles; every
 * caller reads and writes rectangles and cells in world coordinates.
 *
 * Heights are kept inside [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX] (about ±53 km at
 * the default scale) so that every difference of two heights, and every sum
 * the integer stages form, fits in 32 bits. Base terrain outside that range is
 * refused when it is loaded, never wrapped.
 */
#ifndef TERRAD_WORLD_H
#define TERRAD_WORLD_H

#include <stddef.h>
#include <stdint.h>

#include "base/base.h"

#define WORLD_HEIGHT_MAX (1 << 29)
#define WORLD_HEIGHT_MIN (-(1 << 29))
#define WORLD_SIDE_MAX 65536 /* cells per side */
#define WORLD_TILE_CELLS_DEFAULT 256
#define WORLD_TILE_CELLS_MIN 16

typedef struct world_rect {
    int x, y, w, h; /* cells; w and h > 0 for a non-empty rectangle */
} world_rect;

/* The per-cell layers a world carries beside its heights (world_soil.c, and
 * the world_layer_* family below). */
typedef enum world_layer_id {
    WORLD_LAYER_SOIL,       /* WORLD_SOIL_FIELDS int32 per cell */
    WORLD_LAYER_COMPACTION, /* one int32 per cell in [0, WORLD_COMPACTION_MAX] */
    WORLD_LAYERS
} world_layer_id;

typedef struct world {
    int width, height;         /* cells */
    double cell_size_m;        /* metres per cell, both axes */
    int32_t units_per_m;       /* height units per metre */
    int32_t floor;             /* material is never pushed below this height (units) */
    int tile_cells;            /* side of a tile in cells, a power of two */
    int tiles_x, tiles_y;      /* tiles per row / column (the last ones may be partial) */
    struct world_store *store; /* tiles, base terrain, caches: world.c only */
    /* per-cell state beside the heights, NULL while none: world_soil.c only */
    struct world_layer *layers[WORLD_LAYERS];
} world;

/* How the base terrain is made. */
typedef enum world_base_kind {
    WORLD_BASE_FLAT,
    WORLD_BASE_DUNES,     /* seeded gradient noise between min and max height */
    WORLD_BASE_PNG16,     /* 16-bit greyscale PNG, value * scale + offset */
    WORLD_BASE_RAW_INT16, /* little-endian int16, row-major, width * height */
    WORLD_BASE_RAW_INT32, /* little-endian int32, row-major, width * height */
} world_base_kind;

typedef struct world_base_spec {
    world_base_kind kind;
    double height_m;           /* flat */
    double min_height_m;       /* dunes */
    double max_height_m;       /* dunes */
    double wavelength_m;       /* dunes: size of the largest feature */
    int octaves;               /* dunes: 1..8 */
    uint32_t seed;             /* dunes */
    char path[1024];           /* png16 / raw: resolved file path */
    double value_scale_units;  /* png16 / raw: units per file value */
    double value_offset_units; /* png16 / raw: added after scaling */
} world_base_spec;

/* Set up a world; heights start at 0 (a flat base). Nothing proportional to
 * the world's area is allocated, only a table of tile slots. Refuses absurd
 * sizes with a reason. world_init uses WORLD_TILE_CELLS_DEFAULT;
 * world_init_tiled takes tile_cells (0 = default, else a power of two in
 * [WORLD_TILE_CELLS_MIN, WORLD_SIDE_MAX]; a tile as large as the world makes
 * it one dense array, which tests compare tilings against). */
int world_init(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
               int32_t floor, error_text *err);
int world_init_tiled(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
                     int32_t floor, int tile_cells, error_text *err);
void world_free(world *w);

/* Set the base terrain from a spec, dropping every stored tile (the world is
 * then the base everywhere). Flat and dunes are functions of (x, y) and are
 * computed on demand; png16 / raw files are read once into a dense base
 * array. Errors name the file or the field. */
int world_generate_base(world *w, const world_base_spec *spec, error_text *err);

/*
 * Fill dst (r.w * r.h, row-major) with the base terrain's heights over r (already
 * clipped): what the world was before anything pressed into it, whatever happened
 * since. Models that relax towards the untouched ground (subtract's refill) read it.
 * Returns 0 (every world has a base: flat 0 until world_generate_base).
 */
int world_base_fill_rect(const world *w, world_rect r, int32_t *dst);

/* Σh over the whole world, exactly: the base's Σh (closed form for flat, the
 * sum of the file for png16 / raw, one pass over the noise for dunes, done the
 * first time it is asked for and kept) plus the exact sum of every change
 * written since. */
int64_t world_volume(const world *w);
/* Σh over a rectangle, exactly. */
int64_t world_rect_volume(const world *w, world_rect r);

/* Clip r to the world; returns 0 when nothing is left. */
int world_clip_rect(const world *w, world_rect *r);
/* Copy a rectangle (already clipped) out of / back into the world. */
void world_gather_window(const world *w, world_rect r, int32_t *dst);
void world_scatter_window(world *w, world_rect r, const int32_t *src);
/* Highest and lowest height inside a clipped rectangle. */
void world_rect_height_range(const world *w, world_rect r, int32_t *lo, int32_t *hi);
/* Does some cell of a clipped rectangle stand at level or higher? Stops at
 * the first that does: the plan's test whether a collider can touch the
 * ground under it (sim_plan.c) usually ends at the rectangle's first cell,
 * where the greatest height would read all of them. 0 for an empty r. */
int world_rect_reaches(const world *w, world_rect r, int64_t level);

/* One cell's height; (x, y) must lie inside the world. */
int32_t world_height_at(const world *w, int x, int y);
/* Write one cell (a 1 x 1 scatter). */
void world_set_height(world *w, int x, int y, int32_t h);

/* Tiles. A tile's generation is 0 while it has never been written and goes up
 * by one with every scatter that writes into it, so a cache (the GL tile
 * cache, the storage engine) can tell whether its copy is current. */
uint64_t world_tile_generation(const world *w, int tx, int ty);
/* The cells tile (tx, ty) covers (clipped to the world). */
world_rect world_tile_rect(const world *w, int tx, int ty);
/* A number no other base of any world in this process had: it changes with
 * every world_init and world_generate_base, so a cache keyed by it and the
 * tile generations never mistakes an old base's tile for the current one. */
uint64_t world_base_serial(const world *w);
/* Calls fn for every stored (written) tile, in row-major tile order. */
typedef void (*world_tile_fn)(void *ctx, int tx, int ty, world_rect cells, uint64_t generation);
void world_for_each_stored_tile(const world *w, world_tile_fn fn, void *ctx);
/* Tiles stored now, and bytes held for the world: tile table, stored tiles,
 * the cache of generated base tiles and a file base's dense array. */
size_t world_stored_tiles(const world *w);
uint64_t world_resident_bytes(const world *w);

/* 1 if two rectangles share at least one cell. */
int world_rects_overlap(world_rect a, world_rect b);
world_rect world_rect_union(world_rect a, world_rect b);
/* The cells a and b share (w or h 0 when none): a tile's part of a subscription. */
world_rect world_rect_meet(world_rect a, world_rect b);

/* ---- terrain edits from game logic (world_edit.c; PROTOCOL.md "edit") ---- */

#define WORLD_EDIT_RADIUS_MAX 1024 /* a crater's radius, cells */
#define WORLD_EDIT_MAX_CELLS_DEFAULT 4194304

typedef enum world_edit_op {
    WORLD_EDIT_CRATER,
    WORLD_EDIT_STAMP,
    WORLD_EDIT_RESET,
    WORLD_EDIT_ADD,
    WORLD_EDIT_REMOVE,
} world_edit_op;

typedef enum world_stamp_mode {
    WORLD_STAMP_SET,
    WORLD_STAMP_ADD,
    WORLD_STAMP_MIN,
    WORLD_STAMP_MAX,
} world_stamp_mode;

typedef struct world_edit {
    world_edit_op op;
    world_rect rect;         /* the cells it may change (inside the world) */
    int cx, cy, radius, rim; /* crater: centre and radius (cells); rim keeps Σh */
    int64_t depth;           /* crater: units at the centre */
    int32_t amount;          /* add / remove: units per cell */
    world_stamp_mode mode;   /* stamp */
    int32_t *values;         /* stamp: rect.w * rect.h heights or offsets (owned) */
    uint8_t *mask;           /* stamp: NULL, or nonzero where the stamp applies (owned) */
} world_edit;

/* (An `edit` message is parsed into a world_edit by hub_edit_parse, hub/hub_edit.c.) */
void world_edit_free(world_edit *e);
const char *world_edit_op_name(world_edit_op op);
/* Apply e to w whole: *rect the cells it could change, *diff (malloc'd,
 * rect's cells) new minus old, *volume their exact sum. -1 with err when a
 * cell would leave the height range: w is then unchanged. */
int world_edit_apply(world *w, const world_edit *e, world_rect *rect, int32_t **diff,
                     int64_t *volume, error_text *err);
/* Take an applied edit back (the store could not log its tick). */
void world_edit_undo(world *w, world_rect r, const int32_t *diff);

/* ---- per-cell layers (world_soil.c) ----
 * State a world carries beside its heights, int32 per cell, zeros until
 * written; what the values mean is the model's that writes them. The store
 * logs and snapshots each layer with the heights of the same rectangles.
 * WORLD_LAYER_SOIL holds bekker's soil state (sim.h: SIM_SOIL_*);
 * WORLD_LAYER_COMPACTION the height units each column has been compacted by
 * so far (the persson models' and sumner's memory, docs/materials.md),
 * enabled by the engine when some material remembers compaction
 * (sim_engine_set_ground) or by a record that carries it. */

#define WORLD_SOIL_FIELDS 3
#define WORLD_COMPACTION_MAX 65535

/* int32 per cell of the layer: WORLD_SOIL_FIELDS or 1. */
int world_layer_fields(world_layer_id layer);
/* Allocate the (empty) layer; idempotent. 0, or -1 out of memory. */
int world_layer_enable(world *w, world_layer_id layer);
int world_layer_enabled(const world *w, world_layer_id layer);
/* r (clipped) into dst, world_layer_fields per cell, row-major; zeros where
 * nothing was written. */
void world_layer_gather(const world *w, world_layer_id layer, world_rect r, int32_t *dst);
/* src over r (enabling the layer). 0, or -1 out of memory. */
int world_layer_scatter(world *w, world_layer_id layer, world_rect r, const int32_t *src);
/* 1 when no cell of r (clipped) was ever written with anything but zeros. */
int world_layer_rect_empty(const world *w, world_layer_id layer, world_rect r);
/* Σ of one field over the world, exactly (kept as cells are written); for
 * the compaction memory (field 0) what compression has taken from Σh. */
int64_t world_layer_sum(const world *w, world_layer_id layer, int field);
/* Cell (x, y)'s world_layer_fields values into out; zeros outside the world
 * or where nothing was written. */
void world_layer_cell(const world *w, world_layer_id layer, int x, int y, int32_t *out);
/* Bytes the layer holds: its tile table and the tiles written. */
uint64_t world_layer_bytes(const world *w, world_layer_id layer);

/* Write / read a 16-bit greyscale PNG (used by base terrain and exports). */
int png16_read(const char *path, int *width, int *height, uint16_t **pixels, error_text *err);
/* The same from bytes in memory; name is what errors call them. */
int png16_decode(const uint8_t *data, size_t len, const char *name, int *width, int *height,
                 uint16_t **pixels, error_text *err);
int png16_write(const char *path, int width, int height, const uint16_t *pixels, error_text *err);
/* The one PNG writer: a width x height 16-bit greyscale PNG into out (its
 * data malloc'd), row y's samples from row_of(arg, y, samples), at zlib level
 * (0-9; -1: libpng's default). 0, or -1 with err set (name names the image)
 * and out zeroed (data NULL, len and cap 0: nothing held). */
typedef struct png16_memory {
    unsigned char *data;
    size_t len;
    int64_t cap;
} png16_memory;
typedef void png16_row_fn(void *arg, int y, uint16_t *samples);
int png16_encode(int width, int height, int level, png16_row_fn *row_of, void *arg,
                 const char *name, png16_memory *out, error_text *err);

#endif
