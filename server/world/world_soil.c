/*
 * world_soil.c: the per-cell state a world carries beside its heights, in
 * two layers whose meaning belongs to the models that write them:
 *
 *   soil        WORLD_SOIL_FIELDS int32 per cell (issue 21; sim's bekker:
 *               plastic sinkage, shear displacement, compacted volume)
 *   compaction  one int32 per cell in [0, 65535] (issue 28; the persson
 *               models' and sumner's compaction memory: height units the
 *               column has been compacted by, docs/materials.md)
 *
 * They live in the world, not in the engine or the ground, so that the store
 * logs and snapshots them with the heights of the same rectangles and
 * recovery puts them back before the first tick (docs/storage.md).
 *
 * One family of functions serves both (world_layer_*, world.h), indexed by
 * WORLD_LAYER_*: a layer differs from another only in its int32 per cell.
 * Each layer is sparse 64x64 tiles, allocated the first time a cell in them
 * holds anything but zeros: a world nobody pressed costs a table of NULLs.
 * The engine gathers a window's state with its heights (row 4b of the tick)
 * and scatters it back for accepted windows only (row 4e).
 */
#include "world/world_internal.h"

#include <stdlib.h>
#include <string.h>

#define LAYER_TILE 64
#define LAYER_FIELDS_MAX WORLD_SOIL_FIELDS

struct world_layer {
    int fields; /* int32 per cell */
    int tiles_x, tiles_y;
    int32_t **tiles; /* NULL entries: never written with anything but zeros */
    int64_t allocated;
    int64_t sums[LAYER_FIELDS_MAX]; /* kept by every scatter, so a sum costs nothing */
};

static int64_t tile_ints(const struct world_layer *l)
{
    return (int64_t)LAYER_TILE * LAYER_TILE * l->fields;
}

static int layer_enable(const world *w, struct world_layer **slot, int fields)
{
    if (*slot)
        return 0;
    struct world_layer *l = calloc(1, sizeof *l);
    if (!l)
        return -1;
    l->fields = fields;
    l->tiles_x = (w->width + LAYER_TILE - 1) / LAYER_TILE;
    l->tiles_y = (w->height + LAYER_TILE - 1) / LAYER_TILE;
    l->tiles = calloc((size_t)l->tiles_x * (size_t)l->tiles_y + 1, sizeof *l->tiles);
    if (!l->tiles) {
        free(l);
        return -1;
    }
    *slot = l;
    return 0;
}

static void layer_free(struct world_layer **slot)
{
    struct world_layer *l = *slot;
    if (!l)
        return;
    for (int64_t i = 0; i < (int64_t)l->tiles_x * l->tiles_y; i++)
        free(l->tiles[i]);
    free(l->tiles);
    free(l);
    *slot = NULL;
}

/* The state of world cell (x, y), or NULL where its tile was never written. */
static int32_t *layer_cell(const struct world_layer *l, int x, int y)
{
    if (!l)
        return NULL;
    int32_t *t = l->tiles[(int64_t)(y / LAYER_TILE) * l->tiles_x + x / LAYER_TILE];
    if (!t)
        return NULL;
    return t + ((int64_t)(y % LAYER_TILE) * LAYER_TILE + x % LAYER_TILE) * l->fields;
}

/* r into dst, `fields` per cell; zeros where nothing was written (l may be NULL). */
static void layer_gather(const struct world_layer *l, int fields, world_rect r, int32_t *dst)
{
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++) {
            int32_t *d = dst + ((int64_t)y * r.w + x) * fields;
            const int32_t *s = layer_cell(l, r.x + x, r.y + y);
            for (int f = 0; f < fields; f++)
                d[f] = s ? s[f] : 0;
        }
}

static int all_zero(const int32_t *v, int fields)
{
    for (int f = 0; f < fields; f++)
        if (v[f])
            return 0;
    return 1;
}

static int layer_scatter(struct world_layer *l, world_rect r, const int32_t *src)
{
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++) {
            const int32_t *s = src + ((int64_t)y * r.w + x) * l->fields;
            int wx = r.x + x, wy = r.y + y;
            int32_t *d = layer_cell(l, wx, wy);
            if (!d) {
                if (all_zero(s, l->fields))
                    continue; /* nothing to remember: no tile */
                int64_t t = (int64_t)(wy / LAYER_TILE) * l->tiles_x + wx / LAYER_TILE;
                l->tiles[t] = calloc((size_t)tile_ints(l), sizeof(int32_t));
                if (!l->tiles[t])
                    return -1;
                l->allocated++;
                d = layer_cell(l, wx, wy);
            }
            for (int f = 0; f < l->fields; f++)
                l->sums[f] += (int64_t)s[f] - d[f];
            memcpy(d, s, (size_t)l->fields * sizeof *d);
        }
    return 0;
}

static int layer_rect_empty(const struct world_layer *l, world_rect r)
{
    if (!l)
        return 1;
    for (int ty = r.y / LAYER_TILE; ty <= (r.y + r.h - 1) / LAYER_TILE; ty++)
        for (int tx = r.x / LAYER_TILE; tx <= (r.x + r.w - 1) / LAYER_TILE; tx++)
            if (l->tiles[(int64_t)ty * l->tiles_x + tx])
                return 0;
    return 1;
}

static void layer_cell_copy(const world *w, const struct world_layer *l, int fields, int x, int y,
                            int32_t *out)
{
    const int32_t *s = NULL;
    if (x >= 0 && y >= 0 && x < w->width && y < w->height)
        s = layer_cell(l, x, y);
    for (int f = 0; f < fields; f++)
        out[f] = s ? s[f] : 0;
}

static uint64_t layer_bytes(const struct world_layer *l)
{
    if (!l)
        return 0;
    return (uint64_t)l->allocated * (uint64_t)tile_ints(l) * sizeof(int32_t) +
           (uint64_t)l->tiles_x * (uint64_t)l->tiles_y * sizeof(int32_t *);
}

/* ---- the world_layer_* family ---- */

static const int layer_fields[WORLD_LAYERS] = {
    [WORLD_LAYER_SOIL] = WORLD_SOIL_FIELDS,
    [WORLD_LAYER_COMPACTION] = 1,
};

int world_layer_fields(world_layer_id layer)
{
    return layer_fields[layer];
}

int world_layer_enable(world *w, world_layer_id layer)
{
    return layer_enable(w, &w->layers[layer], layer_fields[layer]);
}

int world_layer_enabled(const world *w, world_layer_id layer)
{
    return w->layers[layer] != NULL;
}

void world_layers_free(world *w)
{
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
        layer_free(&w->layers[i]);
}

void world_layer_gather(const world *w, world_layer_id layer, world_rect r, int32_t *dst)
{
    layer_gather(w->layers[layer], layer_fields[layer], r, dst);
}

int world_layer_scatter(world *w, world_layer_id layer, world_rect r, const int32_t *src)
{
    if (world_layer_enable(w, layer) != 0)
        return -1;
    return layer_scatter(w->layers[layer], r, src);
}

int world_layer_rect_empty(const world *w, world_layer_id layer, world_rect r)
{
    return layer_rect_empty(w->layers[layer], r);
}

int64_t world_layer_sum(const world *w, world_layer_id layer, int field)
{
    const struct world_layer *l = w->layers[layer];
    return l && field >= 0 && field < l->fields ? l->sums[field] : 0;
}

void world_layer_cell(const world *w, world_layer_id layer, int x, int y, int32_t *out)
{
    layer_cell_copy(w, w->layers[layer], layer_fields[layer], x, y, out);
}

uint64_t world_layer_bytes(const world *w, world_layer_id layer)
{
    return layer_bytes(w->layers[layer]);
}
