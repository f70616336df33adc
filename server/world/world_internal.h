/*
 * world_internal.h: what world.c (tiles, caches, volumes), terrain_base.c
 * (base terrain) and world_soil.c (per-cell layers) share and nobody else
 * sees. A tile that has never been written is not stored; its cells come from
 * the base, described here.
 */
#ifndef TERRAD_WORLD_INTERNAL_H
#define TERRAD_WORLD_INTERNAL_H

#include "world/world.h"

/* The base terrain in the form reads need it. */
typedef struct world_base {
    world_base_kind kind;
    int32_t flat_units;   /* flat: the one height */
    world_base_spec spec; /* dunes: validated parameters */
    int32_t *cells;       /* png16 / raw: dense, row-major, width * height */
    int volume_known;     /* 0 until volume below is computed (dunes: lazily) */
    int64_t volume;       /* Σh of the base over the whole world */
} world_base;

/* Fill dst (row stride dst_stride cells) with the base heights of rectangle r
 * (inside the world). Dunes values are bit-identical to what a dense world
 * generated cell by cell, whatever the rectangle. */
void world_base_fill(const world *w, const world_base *b, world_rect r, int32_t *dst,
                     size_t dst_stride);

/* Validate spec and build b (reads the file for png16 / raw). On error b is
 * left empty and err names the file or the field. */
int world_base_build(const world *w, const world_base_spec *spec, world_base *b, error_text *err);
void world_base_free(world_base *b);

/* Free every per-cell layer (world_soil.c), for world_free. */
void world_layers_free(world *w);

#endif
