/*
 * world.c: the authoritative height field and the rectangle helpers the tick
 * uses around it. The sim engine plans windows with world_clip_rect,
 * world_rects_overlap and world_rect_union, gathers each window's heights out
 * of the world (row 4b of the tick table in docs/design.md), and scatters
 * the new heights back (row 4e). Volumes are summed in int64 so that "Σh is unchanged" can be
 * checked exactly.
 *
 * The heights live in tiles of tile_cells² cells. A tile is stored only once
 * something has been scattered into it; until then every read of it is served
 * from the base terrain (world_base_fill), so memory follows the tiles the
 * colliders have touched, not the world. Dunes are costly to evaluate (four
 * octaves of noise per cell) and a collider's window re-reads the same
 * untouched tiles every tick, so generated dune tiles are kept in a small LRU
 * bounded by WORLD_CLEAN_CACHE_BYTES; flat and file bases are read directly.
 *
 * Σh is the base's Σh plus change_sum, the exact sum of (new - old) over every
 * cell every scatter wrote, so world_volume never walks the world.
 */
#include "world/world_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The tile table (a pointer and a generation per tile) stays below 16 MiB. */
#define WORLD_TILES_MAX ((int64_t)1 << 20)
/* Generated (unwritten) dune tiles kept for reuse: at most this many bytes
 * and WORLD_CLEAN_SLOTS tiles, at least one tile. */
#define WORLD_CLEAN_CACHE_BYTES ((size_t)16 << 20)
#define WORLD_CLEAN_SLOTS 64

typedef struct clean_slot {
    int64_t tile;      /* tile index, -1 when empty */
    uint64_t last_use; /* LRU clock */
    int32_t *cells;    /* tile width * tile height, allocated for the largest tile */
} clean_slot;

struct world_store {
    world_base base;
    int32_t **tiles;       /* tiles_x * tiles_y, NULL while the tile is not stored */
    uint64_t *generations; /* per tile: scatters into it */
    size_t stored;         /* tiles stored */
    uint64_t stored_bytes; /* their cells */
    int64_t change_sum;    /* Σ(new - old) of every cell written since the base was set */
    int32_t *flat_row;     /* tile_cells copies of the flat height, read with stride 0 */
    clean_slot clean[WORLD_CLEAN_SLOTS];
    int clean_slots; /* slots in use for this tile size */
    uint64_t clean_clock;
    uint64_t base_serial; /* world_base_serial */
};

/* Process-wide source of base serials (worlds live on several threads). */
static _Atomic uint64_t next_base_serial = 1;

static int is_power_of_two(int v)
{
    return v > 0 && (v & (v - 1)) == 0;
}

int world_init_tiled(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
                     int32_t floor, int tile_cells, error_text *err)
{
    memset(w, 0, sizeof *w);
    if (width < 1 || width > WORLD_SIDE_MAX) {
        error_set(err, "world.width: must be an integer in [1, %d] (got %d)", WORLD_SIDE_MAX,
                  width);
        return -1;
    }
    if (height < 1 || height > WORLD_SIDE_MAX) {
        error_set(err, "world.height: must be an integer in [1, %d] (got %d)", WORLD_SIDE_MAX,
                  height);
        return -1;
    }
    if (!isfinite(cell_size_m) || cell_size_m <= 0.0 || cell_size_m > 1000.0) {
        error_set(err, "world.cell_size_m: must be a finite number > 0 and <= 1000 (got %g)",
                  cell_size_m);
        return -1;
    }
    if (units_per_m < 1 || units_per_m > 1000000) {
        error_set(err, "world.units_per_m: must be an integer in [1, 1000000] (got %d)",
                  (int)units_per_m);
        return -1;
    }
    if (floor < WORLD_HEIGHT_MIN || floor > WORLD_HEIGHT_MAX) {
        error_set(err, "world.floor: must lie in [%d, %d] units (got %d)", WORLD_HEIGHT_MIN,
                  WORLD_HEIGHT_MAX, (int)floor);
        return -1;
    }
    if (tile_cells == 0)
        tile_cells = WORLD_TILE_CELLS_DEFAULT;
    if (!is_power_of_two(tile_cells) || tile_cells < WORLD_TILE_CELLS_MIN ||
        tile_cells > WORLD_SIDE_MAX) {
        error_set(err,
                  "world.tile_cells: must be 0 (default %d) or a power of two in [%d, %d] "
                  "(got %d)",
                  WORLD_TILE_CELLS_DEFAULT, WORLD_TILE_CELLS_MIN, WORLD_SIDE_MAX, tile_cells);
        return -1;
    }
    int tiles_x = (width + tile_cells - 1) / tile_cells;
    int tiles_y = (height + tile_cells - 1) / tile_cells;
    if ((int64_t)tiles_x * tiles_y > WORLD_TILES_MAX) {
        error_set(err,
                  "world.tile_cells: %d makes %d x %d tiles, more than the %lld the tile table "
                  "may hold; use larger tiles",
                  tile_cells, tiles_x, tiles_y, (long long)WORLD_TILES_MAX);
        return -1;
    }
    struct world_store *st = calloc(1, sizeof *st);
    size_t n = (size_t)tiles_x * (size_t)tiles_y;
    if (st) {
        st->tiles = calloc(n, sizeof *st->tiles);
        st->generations = calloc(n, sizeof *st->generations);
        st->flat_row = calloc((size_t)tile_cells, sizeof *st->flat_row);
    }
    if (!st || !st->tiles || !st->generations || !st->flat_row) {
        if (st) {
            free(st->tiles);
            free(st->generations);
            free(st->flat_row);
        }
        free(st);
        error_set(err, "world: out of memory for the tile table of %d x %d tiles", tiles_x,
                  tiles_y);
        return -1;
    }
    w->width = width;
    w->height = height;
    w->cell_size_m = cell_size_m;
    w->units_per_m = units_per_m;
    w->floor = floor;
    w->tile_cells = tile_cells;
    w->tiles_x = tiles_x;
    w->tiles_y = tiles_y;
    w->store = st;
    /* heights start at 0: a flat base at 0 units (volume 0) */
    st->base.kind = WORLD_BASE_FLAT;
    st->base.volume_known = 1;
    st->base_serial = next_base_serial++;
    size_t tile_max = (size_t)(width < tile_cells ? width : tile_cells) *
                      (size_t)(height < tile_cells ? height : tile_cells);
    size_t slots = WORLD_CLEAN_CACHE_BYTES / (tile_max * sizeof(int32_t));
    st->clean_slots = slots < 1 ? 1 : slots > WORLD_CLEAN_SLOTS ? WORLD_CLEAN_SLOTS : (int)slots;
    for (int i = 0; i < WORLD_CLEAN_SLOTS; i++)
        st->clean[i].tile = -1;
    return 0;
}

int world_init(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
               int32_t floor, error_text *err)
{
    return world_init_tiled(w, width, height, cell_size_m, units_per_m, floor, 0, err);
}

static void drop_tiles(struct world_store *st, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        free(st->tiles[i]);
        st->tiles[i] = NULL;
        st->generations[i] = 0;
    }
    st->stored = 0;
    st->stored_bytes = 0;
    st->change_sum = 0;
    for (int i = 0; i < WORLD_CLEAN_SLOTS; i++)
        st->clean[i].tile = -1;
}

void world_free(world *w)
{
    if (!w)
        return;
    struct world_store *st = w->store;
    if (st) {
        drop_tiles(st, (size_t)w->tiles_x * w->tiles_y);
        for (int i = 0; i < WORLD_CLEAN_SLOTS; i++)
            free(st->clean[i].cells);
        world_base_free(&st->base);
        free(st->tiles);
        free(st->generations);
        free(st->flat_row);
        free(st);
    }
    world_layers_free(w);
    memset(w, 0, sizeof *w);
}

int world_generate_base(world *w, const world_base_spec *spec, error_text *err)
{
    struct world_store *st = w->store;
    world_base b;
    if (world_base_build(w, spec, &b, err) != 0)
        return -1;
    drop_tiles(st, (size_t)w->tiles_x * w->tiles_y);
    world_base_free(&st->base);
    st->base = b;
    st->base_serial = next_base_serial++;
    for (int i = 0; i < w->tile_cells; i++)
        st->flat_row[i] = b.flat_units;
    return 0;
}

world_rect world_tile_rect(const world *w, int tx, int ty)
{
    world_rect r = {tx * w->tile_cells, ty * w->tile_cells, w->tile_cells, w->tile_cells};
    world_clip_rect(w, &r);
    return r;
}

/* The dune heights of an unwritten tile, from the LRU (generating them on a
 * miss). The pointer stays valid until the next call. */
static const int32_t *clean_tile(const world *w, int64_t tile, world_rect tr)
{
    struct world_store *st = w->store;
    clean_slot *victim = &st->clean[0];
    for (int i = 0; i < st->clean_slots; i++) {
        clean_slot *s = &st->clean[i];
        if (s->tile == tile) {
            s->last_use = ++st->clean_clock;
            return s->cells;
        }
        if (s->tile < 0 ? victim->tile >= 0 || s->last_use < victim->last_use
                        : victim->tile >= 0 && s->last_use < victim->last_use)
            victim = s;
    }
    if (!victim->cells) {
        size_t side_x = (size_t)(w->width < w->tile_cells ? w->width : w->tile_cells);
        size_t side_y = (size_t)(w->height < w->tile_cells ? w->height : w->tile_cells);
        victim->cells = malloc(side_x * side_y * sizeof *victim->cells);
        if (!victim->cells)
            return NULL;
    }
    world_base_fill(w, &st->base, tr, victim->cells, (size_t)tr.w);
    victim->tile = tile;
    victim->last_use = ++st->clean_clock;
    return victim->cells;
}

/* Where tile (tx, ty)'s heights can be read now: its first cell and the row
 * stride in cells (0 for a flat base: every row is the same row). NULL only
 * when a dune tile cannot be generated for want of memory; callers then fill
 * from the base directly. */
static const int32_t *tile_source(const world *w, int tx, int ty, world_rect tr, size_t *stride)
{
    struct world_store *st = w->store;
    int64_t t = (int64_t)ty * w->tiles_x + tx;
    if (st->tiles[t]) {
        *stride = (size_t)tr.w;
        return st->tiles[t];
    }
    switch (st->base.kind) {
    case WORLD_BASE_FLAT:
        *stride = 0;
        return st->flat_row;
    case WORLD_BASE_DUNES:
        *stride = (size_t)tr.w;
        return clean_tile(w, t, tr);
    case WORLD_BASE_PNG16:
    case WORLD_BASE_RAW_INT16:
    case WORLD_BASE_RAW_INT32:
        *stride = (size_t)w->width;
        return st->base.cells + (size_t)tr.y * w->width + tr.x;
    }
    return NULL;
}

/* One tile's share of a rectangle: part is r ∩ tile, in world cells. */
typedef struct tile_part {
    int tx, ty;
    world_rect tile; /* the tile's cells */
    world_rect part; /* r ∩ tile */
} tile_part;

/* Iterate the tiles a (clipped, non-empty) rectangle covers, row-major. */
typedef struct tile_walk {
    world_rect r;
    int tx0, tx1, ty1, tx, ty;
} tile_walk;

static tile_walk tile_walk_begin(const world *w, world_rect r)
{
    int shift = 0;
    while ((1 << shift) < w->tile_cells)
        shift++;
    tile_walk k = {
        r,           r.x >> shift, (r.x + r.w - 1) >> shift, (r.y + r.h - 1) >> shift, r.x >> shift,
        r.y >> shift};
    return k;
}

static int tile_walk_next(const world *w, tile_walk *k, tile_part *p)
{
    if (k->r.w <= 0 || k->r.h <= 0 || k->ty > k->ty1)
        return 0;
    p->tx = k->tx;
    p->ty = k->ty;
    p->tile = world_tile_rect(w, k->tx, k->ty);
    int x0 = k->r.x > p->tile.x ? k->r.x : p->tile.x;
    int y0 = k->r.y > p->tile.y ? k->r.y : p->tile.y;
    int x1 = k->r.x + k->r.w < p->tile.x + p->tile.w ? k->r.x + k->r.w : p->tile.x + p->tile.w;
    int y1 = k->r.y + k->r.h < p->tile.y + p->tile.h ? k->r.y + k->r.h : p->tile.y + p->tile.h;
    p->part = (world_rect){x0, y0, x1 - x0, y1 - y0};
    if (++k->tx > k->tx1) {
        k->tx = k->tx0;
        k->ty++;
    }
    return 1;
}

/* Copy part (inside tile p) into dst with row stride dst_stride. */
static void read_part(const world *w, const tile_part *p, int32_t *dst, size_t dst_stride)
{
    size_t stride;
    const int32_t *src = tile_source(w, p->tx, p->ty, p->tile, &stride);
    if (!src) {
        world_base_fill(w, &w->store->base, p->part, dst, dst_stride);
        return;
    }
    src += (size_t)(p->part.x - p->tile.x);
    for (int y = 0; y < p->part.h; y++)
        memcpy(dst + (size_t)y * dst_stride, src + (size_t)(p->part.y - p->tile.y + y) * stride,
               (size_t)p->part.w * sizeof *dst);
}

int64_t world_volume(const world *w)
{
    struct world_store *st = w->store;
    if (!st->base.volume_known) {
        /* dunes: one pass over the noise, row by row, the first time */
        int32_t *row = malloc((size_t)w->width * sizeof *row);
        int64_t sum = 0;
        for (int y = 0; row && y < w->height; y++) {
            world_base_fill(w, &st->base, (world_rect){0, y, w->width, 1}, row, (size_t)w->width);
            for (int x = 0; x < w->width; x++)
                sum += row[x];
        }
        if (row) {
            free(row);
            st->base.volume = sum;
            st->base.volume_known = 1;
        } else {
            /* no memory for one row: sum the world the slow way, uncached */
            return world_rect_volume(w, (world_rect){0, 0, w->width, w->height});
        }
    }
    return st->base.volume + st->change_sum;
}

/* Cell (x, y) of part p: from its tile's heights (src, from tile_source) or,
 * for a tile never written (src NULL), the base terrain's value. */
static inline int32_t part_height(const world *w, const tile_part *p, const int32_t *src,
                                  size_t stride, int x, int y)
{
    if (src)
        return src[(size_t)(y - p->tile.y) * stride + (size_t)(x - p->tile.x)];
    int32_t one;
    world_base_fill(w, &w->store->base, (world_rect){x, y, 1, 1}, &one, 1);
    return one;
}

/* The sum, least and greatest of the heights of r, in one walk of its tiles
 * (world_rect_volume and world_rect_height_range); an empty r leaves 0,
 * INT32_MAX and INT32_MIN. */
static void rect_heights(const world *w, world_rect r, int64_t *sum, int32_t *lo, int32_t *hi)
{
    int64_t s = 0;
    int32_t mn = INT32_MAX, mx = INT32_MIN;
    tile_walk k = tile_walk_begin(w, r);
    tile_part p;
    while (tile_walk_next(w, &k, &p)) {
        size_t stride;
        const int32_t *src = tile_source(w, p.tx, p.ty, p.tile, &stride);
        if (src) {
            /* row by row from the tile's cells: the engine plans every
             * collider's window with this (sim_plan.c), every tick, and a
             * cell at a time through part_height cost 3 % of a driven
             * world's tick (issue 32) */
            for (int y = p.part.y; y < p.part.y + p.part.h; y++) {
                const int32_t *row = src + (size_t)(y - p.tile.y) * stride + (p.part.x - p.tile.x);
                for (int x = 0; x < p.part.w; x++) {
                    int32_t v = row[x];
                    s += v;
                    mn = v < mn ? v : mn;
                    mx = v > mx ? v : mx;
                }
            }
            continue;
        }
        for (int y = p.part.y; y < p.part.y + p.part.h; y++)
            for (int x = p.part.x; x < p.part.x + p.part.w; x++) {
                int32_t v = part_height(w, &p, src, stride, x, y);
                s += v;
                if (v < mn)
                    mn = v;
                if (v > mx)
                    mx = v;
            }
    }
    *sum = s;
    *lo = mn;
    *hi = mx;
}

int64_t world_rect_volume(const world *w, world_rect r)
{
    if (!world_clip_rect(w, &r))
        return 0;
    int64_t sum;
    int32_t lo, hi;
    rect_heights(w, r, &sum, &lo, &hi);
    return sum;
}

int world_clip_rect(const world *w, world_rect *r)
{
    if (r->w <= 0 || r->h <= 0) {
        *r = (world_rect){0, 0, 0, 0};
        return 0;
    }
    /* int64 so a rectangle near INT_MAX does not wrap while being clipped */
    int64_t x0 = r->x, y0 = r->y;
    int64_t x1 = x0 + r->w, y1 = y0 + r->h;
    if (x0 < 0)
        x0 = 0;
    if (y0 < 0)
        y0 = 0;
    if (x1 > w->width)
        x1 = w->width;
    if (y1 > w->height)
        y1 = w->height;
    if (x1 <= x0 || y1 <= y0) {
        *r = (world_rect){0, 0, 0, 0};
        return 0;
    }
    *r = (world_rect){(int)x0, (int)y0, (int)(x1 - x0), (int)(y1 - y0)};
    return 1;
}

void world_gather_window(const world *w, world_rect r, int32_t *dst)
{
    tile_walk k = tile_walk_begin(w, r);
    tile_part p;
    while (tile_walk_next(w, &k, &p))
        read_part(w, &p, dst + (size_t)(p.part.y - r.y) * r.w + (size_t)(p.part.x - r.x),
                  (size_t)r.w);
}

/* Make tile p stored (a copy of its current heights); 0 on success. */
static int store_tile(world *w, const tile_part *p)
{
    struct world_store *st = w->store;
    int64_t t = (int64_t)p->ty * w->tiles_x + p->tx;
    if (st->tiles[t])
        return 0;
    int32_t *cells = malloc((size_t)p->tile.w * p->tile.h * sizeof *cells);
    if (!cells)
        return -1;
    tile_part whole = *p;
    whole.part = p->tile;
    read_part(w, &whole, cells, (size_t)p->tile.w);
    for (int i = 0; i < WORLD_CLEAN_SLOTS; i++)
        if (st->clean[i].tile == t)
            st->clean[i].tile = -1; /* the stored copy is read from now on */
    st->tiles[t] = cells;
    st->stored++;
    st->stored_bytes += (uint64_t)p->tile.w * p->tile.h * sizeof *cells;
    return 0;
}

void world_scatter_window(world *w, world_rect r, const int32_t *src)
{
    struct world_store *st = w->store;
    tile_walk k = tile_walk_begin(w, r);
    tile_part p;
    while (tile_walk_next(w, &k, &p)) {
        if (store_tile(w, &p) != 0) {
            /* Out of memory for one tile: the write is lost, which the
             * volume check of the tick reports; nothing is left half done. */
            log_error("world: out of memory storing tile (%d, %d); a scatter into it is lost", p.tx,
                      p.ty);
            continue;
        }
        int64_t t = (int64_t)p.ty * w->tiles_x + p.tx;
        int32_t *tile = st->tiles[t];
        int64_t change = 0;
        for (int y = 0; y < p.part.h; y++) {
            int32_t *dst =
                tile + (size_t)(p.part.y - p.tile.y + y) * p.tile.w + (size_t)(p.part.x - p.tile.x);
            const int32_t *from =
                src + (size_t)(p.part.y - r.y + y) * r.w + (size_t)(p.part.x - r.x);
            for (int x = 0; x < p.part.w; x++)
                change += (int64_t)from[x] - dst[x];
            memcpy(dst, from, (size_t)p.part.w * sizeof *dst);
        }
        st->change_sum += change;
        st->generations[t]++;
    }
}

int world_rect_reaches(const world *w, world_rect r, int64_t level)
{
    if (r.w <= 0 || r.h <= 0)
        return 0;
    tile_walk k = tile_walk_begin(w, r);
    tile_part p;
    while (tile_walk_next(w, &k, &p)) {
        size_t stride;
        const int32_t *src = tile_source(w, p.tx, p.ty, p.tile, &stride);
        for (int y = p.part.y; y < p.part.y + p.part.h; y++) {
            if (src) {
                const int32_t *row = src + (size_t)(y - p.tile.y) * stride + (p.part.x - p.tile.x);
                for (int x = 0; x < p.part.w; x++)
                    if (row[x] >= level)
                        return 1;
                continue;
            }
            for (int x = p.part.x; x < p.part.x + p.part.w; x++)
                if (part_height(w, &p, src, stride, x, y) >= level)
                    return 1;
        }
    }
    return 0;
}

void world_rect_height_range(const world *w, world_rect r, int32_t *lo, int32_t *hi)
{
    int64_t sum;
    rect_heights(w, r, &sum, lo, hi);
    if (r.w <= 0 || r.h <= 0)
        *lo = *hi = 0; /* an empty rectangle has no heights; 0 keeps callers' arithmetic sane */
}

int32_t world_height_at(const world *w, int x, int y)
{
    int32_t h;
    world_gather_window(w, (world_rect){x, y, 1, 1}, &h);
    return h;
}

void world_set_height(world *w, int x, int y, int32_t h)
{
    world_scatter_window(w, (world_rect){x, y, 1, 1}, &h);
}

uint64_t world_tile_generation(const world *w, int tx, int ty)
{
    if (tx < 0 || ty < 0 || tx >= w->tiles_x || ty >= w->tiles_y)
        return 0;
    return w->store->generations[(int64_t)ty * w->tiles_x + tx];
}

void world_for_each_stored_tile(const world *w, world_tile_fn fn, void *ctx)
{
    const struct world_store *st = w->store;
    for (int ty = 0; ty < w->tiles_y; ty++)
        for (int tx = 0; tx < w->tiles_x; tx++) {
            int64_t t = (int64_t)ty * w->tiles_x + tx;
            if (st->tiles[t])
                fn(ctx, tx, ty, world_tile_rect(w, tx, ty), st->generations[t]);
        }
}

uint64_t world_base_serial(const world *w)
{
    return w->store ? w->store->base_serial : 0;
}

size_t world_stored_tiles(const world *w)
{
    return w->store ? w->store->stored : 0;
}

uint64_t world_resident_bytes(const world *w)
{
    const struct world_store *st = w->store;
    if (!st)
        return 0;
    size_t n = (size_t)w->tiles_x * w->tiles_y;
    uint64_t bytes = sizeof *st + n * (sizeof *st->tiles + sizeof *st->generations) +
                     (uint64_t)w->tile_cells * sizeof *st->flat_row + st->stored_bytes;
    size_t side_x = (size_t)(w->width < w->tile_cells ? w->width : w->tile_cells);
    size_t side_y = (size_t)(w->height < w->tile_cells ? w->height : w->tile_cells);
    for (int i = 0; i < WORLD_CLEAN_SLOTS; i++)
        if (st->clean[i].cells)
            bytes += side_x * side_y * sizeof(int32_t);
    if (st->base.cells)
        bytes += (uint64_t)w->width * w->height * sizeof(int32_t);
    return bytes;
}

int world_rects_overlap(world_rect a, world_rect b)
{
    if (a.w <= 0 || a.h <= 0 || b.w <= 0 || b.h <= 0)
        return 0;
    return (int64_t)a.x < (int64_t)b.x + b.w && (int64_t)b.x < (int64_t)a.x + a.w &&
           (int64_t)a.y < (int64_t)b.y + b.h && (int64_t)b.y < (int64_t)a.y + a.h;
}

world_rect world_rect_meet(world_rect a, world_rect b)
{
    int64_t x0 = a.x > b.x ? a.x : b.x, y0 = a.y > b.y ? a.y : b.y;
    int64_t x1 = (int64_t)a.x + a.w < (int64_t)b.x + b.w ? (int64_t)a.x + a.w : (int64_t)b.x + b.w;
    int64_t y1 = (int64_t)a.y + a.h < (int64_t)b.y + b.h ? (int64_t)a.y + a.h : (int64_t)b.y + b.h;
    if (x1 <= x0 || y1 <= y0)
        return (world_rect){(int)x0, (int)y0, 0, 0};
    return (world_rect){(int)x0, (int)y0, (int)(x1 - x0), (int)(y1 - y0)};
}

world_rect world_rect_union(world_rect a, world_rect b)
{
    if (a.w <= 0 || a.h <= 0)
        return b;
    if (b.w <= 0 || b.h <= 0)
        return a;
    int64_t x0 = a.x < b.x ? a.x : b.x;
    int64_t y0 = a.y < b.y ? a.y : b.y;
    int64_t x1 = (int64_t)a.x + a.w > (int64_t)b.x + b.w ? (int64_t)a.x + a.w : (int64_t)b.x + b.w;
    int64_t y1 = (int64_t)a.y + a.h > (int64_t)b.y + b.h ? (int64_t)a.y + a.h : (int64_t)b.y + b.h;
    return (world_rect){(int)x0, (int)y0, (int)(x1 - x0), (int)(y1 - y0)};
}

int world_base_fill_rect(const world *w, world_rect r, int32_t *dst)
{
    world_base_fill(w, &w->store->base, r, dst, (size_t)r.w);
    return 0;
}
