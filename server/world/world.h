/*
 * world: the terrain itself — an extent in cells, a cell size in metres and
 * int32 heights in fixed units (default 10,000 per metre), held on the CPU as
 * the authoritative copy. Each tick gathers small windows out of it for the
 * deformation backends and scatters the results back (steps 4 and 7 of the
 * tick in DESIGN.md); nothing outside a window is touched.
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

typedef struct world_rect {
    int x, y, w, h; /* cells; w and h > 0 for a non-empty rectangle */
} world_rect;

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

typedef struct world {
    int width, height;   /* cells */
    double cell_size_m;  /* metres per cell, both axes */
    int32_t units_per_m; /* height units per metre */
    int32_t floor;       /* material is never pushed below this height (units) */
    int32_t *heights;    /* row-major, width * height */
    /* The base the heights were generated from (world_generate_base), so a
     * rectangle of it can be made again (world_base_fill_rect). */
    int has_base;
    world_base_spec base;
    int32_t *base_copy; /* heightmap-file bases only: the file's heights, kept */
} world;

/* Allocate a world; heights start at 0. Refuses absurd sizes with a reason. */
int world_init(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
               int32_t floor, error_text *err);
void world_free(world *w);

/* Fill the heights from a base spec. Errors name the file or the field. */
int world_generate_base(world *w, const world_base_spec *spec, error_text *err);

/*
 * Base heights of a clipped rectangle into dst (r.w * r.h, row-major): what
 * world_generate_base put there, whatever happened since. Flat and dunes are
 * computed again (they depend only on the spec and the cell); heightmap files
 * come from the copy world_generate_base kept. Returns -1 if the world has
 * no base (heights set by hand).
 */
int world_base_fill_rect(const world *w, world_rect r, int32_t *dst);

/* Σh over the whole world, exactly. */
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

/* 1 if two rectangles share at least one cell. */
int world_rects_overlap(world_rect a, world_rect b);
world_rect world_rect_union(world_rect a, world_rect b);

/* Write / read a 16-bit greyscale PNG (used by base terrain and exports). */
int png16_read(const char *path, int *width, int *height, uint16_t **pixels, error_text *err);
int png16_write(const char *path, int width, int height, const uint16_t *pixels, error_text *err);

#endif
