/*
 * world_soil.c: the per-cell soil state a world carries beside its heights
 * (issue 21) — WORLD_SOIL_FIELDS int32 per cell whose meaning belongs to the
 * model that writes them (sim's bekker: plastic sinkage, shear displacement,
 * compacted volume). It lives in the world, not in the engine, so that the
 * store logs and snapshots it with the heights of the same rectangles and
 * recovery puts it back before the first tick (docs/storage.md).
 *
 * Sparse 64x64 tiles, allocated the first time a cell in them holds anything
 * but zeros: a world nobody pressed costs a table of NULLs. The engine
 * gathers a window's state with its heights (row 4b of the tick) and
 * scatters it back for accepted windows only (row 4e).
 */
#include "world/world.h"

#include <stdlib.h>
#include <string.h>

#define SOIL_TILE 64
#define SOIL_TILE_INTS ((int64_t)SOIL_TILE * SOIL_TILE * WORLD_SOIL_FIELDS)

struct world_soil {
    int tiles_x, tiles_y;
    int32_t **tiles; /* NULL entries: never pressed */
    int64_t allocated;
    int64_t sums[WORLD_SOIL_FIELDS]; /* kept by every scatter, so a sum costs nothing */
};

int world_soil_enable(world *w)
{
    if (w->soil)
        return 0;
    struct world_soil *s = calloc(1, sizeof *s);
    if (!s)
        return -1;
    s->tiles_x = (w->width + SOIL_TILE - 1) / SOIL_TILE;
    s->tiles_y = (w->height + SOIL_TILE - 1) / SOIL_TILE;
    s->tiles = calloc((size_t)s->tiles_x * (size_t)s->tiles_y + 1, sizeof *s->tiles);
    if (!s->tiles) {
        free(s);
        return -1;
    }
    w->soil = s;
    return 0;
}

int world_soil_enabled(const world *w)
{
    return w->soil != NULL;
}

void world_soil_free(world *w)
{
    struct world_soil *s = w->soil;
    if (!s)
        return;
    for (int64_t i = 0; i < (int64_t)s->tiles_x * s->tiles_y; i++)
        free(s->tiles[i]);
    free(s->tiles);
    free(s);
    w->soil = NULL;
}

/* The state of world cell (x, y), or NULL where its tile was never pressed. */
static int32_t *soil_cell(const struct world_soil *s, int x, int y)
{
    if (!s)
        return NULL;
    int32_t *t = s->tiles[(int64_t)(y / SOIL_TILE) * s->tiles_x + x / SOIL_TILE];
    if (!t)
        return NULL;
    return t + ((int64_t)(y % SOIL_TILE) * SOIL_TILE + x % SOIL_TILE) * WORLD_SOIL_FIELDS;
}

void world_soil_gather(const world *w, world_rect r, int32_t *dst)
{
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++) {
            int32_t *d = dst + ((int64_t)y * r.w + x) * WORLD_SOIL_FIELDS;
            const int32_t *s = soil_cell(w->soil, r.x + x, r.y + y);
            for (int f = 0; f < WORLD_SOIL_FIELDS; f++)
                d[f] = s ? s[f] : 0;
        }
}

static int all_zero(const int32_t *v)
{
    for (int f = 0; f < WORLD_SOIL_FIELDS; f++)
        if (v[f])
            return 0;
    return 1;
}

int world_soil_scatter(world *w, world_rect r, const int32_t *src)
{
    if (world_soil_enable(w) != 0)
        return -1;
    struct world_soil *l = w->soil;
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++) {
            const int32_t *s = src + ((int64_t)y * r.w + x) * WORLD_SOIL_FIELDS;
            int wx = r.x + x, wy = r.y + y;
            int32_t *d = soil_cell(l, wx, wy);
            if (!d) {
                if (all_zero(s))
                    continue; /* nothing to remember: no tile */
                int64_t t = (int64_t)(wy / SOIL_TILE) * l->tiles_x + wx / SOIL_TILE;
                l->tiles[t] = calloc((size_t)SOIL_TILE_INTS, sizeof(int32_t));
                if (!l->tiles[t])
                    return -1;
                l->allocated++;
                d = soil_cell(l, wx, wy);
            }
            for (int f = 0; f < WORLD_SOIL_FIELDS; f++)
                l->sums[f] += (int64_t)s[f] - d[f];
            memcpy(d, s, WORLD_SOIL_FIELDS * sizeof *d);
        }
    return 0;
}

int world_soil_rect_empty(const world *w, world_rect r)
{
    const struct world_soil *s = w->soil;
    if (!s)
        return 1;
    for (int ty = r.y / SOIL_TILE; ty <= (r.y + r.h - 1) / SOIL_TILE; ty++)
        for (int tx = r.x / SOIL_TILE; tx <= (r.x + r.w - 1) / SOIL_TILE; tx++)
            if (s->tiles[(int64_t)ty * s->tiles_x + tx])
                return 0;
    return 1;
}

int64_t world_soil_sum(const world *w, int field)
{
    return w->soil && field >= 0 && field < WORLD_SOIL_FIELDS ? w->soil->sums[field] : 0;
}

void world_soil_cell(const world *w, int x, int y, int32_t *out)
{
    const int32_t *s = NULL;
    if (x >= 0 && y >= 0 && x < w->width && y < w->height)
        s = soil_cell(w->soil, x, y);
    for (int f = 0; f < WORLD_SOIL_FIELDS; f++)
        out[f] = s ? s[f] : 0;
}
