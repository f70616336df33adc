/*
 * store_record.c: the one codec of a log record's payload (store.h), shared
 * by every backend — the data directory's log (store_dir.c writes it,
 * store_log.c replays it) and the cluster's JetStream log and tile snapshots
 * (server/cluster/cluster_store.c). A tick's commit encodes the rectangles
 * it changed after the deformation; recovery decodes and applies them before
 * the first tick. One copy, so a world's per-cell state — bekker's soil state
 * (bit 31 of the rectangle count), the compaction memory (bit 30) — travels
 * the same way whichever store holds it.
 *
 *   u32 count | layer bits, count × (x, y, w, h) u32, u32 raw bytes,
 *   zstd(heights of every rectangle in order, then with the soil bit their
 *   soil state, WORLD_SOIL_FIELDS i32 per cell in the same order, then with
 *   the compaction bit their compaction memory, one i32 per cell)
 */
#include "store/store_internal.h"

#include <stdlib.h>
#include <string.h>

#define RECORD_RECTS_MAX (1u << 20)

void store_record_free(store_record *c)
{
    free(c->values);
    free(c->buf);
    free(c->part);
    memset(c, 0, sizeof *c);
}

/* Each world layer's STORE_LAYER_* bit. Their values follow the heights in
 * WORLD_LAYER_* order (soil, then compaction): the order on disk, so a new
 * layer goes last. */
static const unsigned layer_bit[WORLD_LAYERS] = {
    [WORLD_LAYER_SOIL] = STORE_LAYER_SOIL,
    [WORLD_LAYER_COMPACTION] = STORE_LAYER_COMPACTION,
};

unsigned store_world_layers(const world *w)
{
    unsigned layers = 0;
    for (world_layer_id i = 0; w && i < WORLD_LAYERS; i++)
        if (world_layer_enabled(w, i))
            layers |= layer_bit[i];
    return layers;
}

unsigned store_rect_layers(const world *w, world_rect r)
{
    unsigned layers = 0;
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
        if (world_layer_enabled(w, i) && !world_layer_rect_empty(w, i, r))
            layers |= layer_bit[i];
    return layers;
}

int store_layers_ints(unsigned layers)
{
    int ints = 1;
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
        if (layers & layer_bit[i])
            ints += world_layer_fields(i);
    return ints;
}

static uint32_t layer_bits(unsigned layers)
{
    return (layers & STORE_LAYER_SOIL ? STORE_RECORD_SOIL : 0) |
           (layers & STORE_LAYER_COMPACTION ? STORE_RECORD_COMPACTION : 0);
}

static size_t rects_cells(const world_rect *rects, int n)
{
    size_t cells = 0;
    for (int i = 0; i < n; i++)
        cells += (size_t)rects[i].w * rects[i].h;
    return cells;
}

/* Where each part of `cells` cells' values starts (ints from the start):
 * the heights at 0, each layer carried at at[layer], ints in all. */
typedef struct layout {
    size_t at[WORLD_LAYERS], ints;
} layout;

static layout layout_of(size_t cells, unsigned layers)
{
    layout l = {.ints = cells};
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++) {
        l.at[i] = l.ints;
        if (layers & layer_bit[i])
            l.ints += cells * (size_t)world_layer_fields(i);
    }
    return l;
}

/* Rectangle r's values at `off` cells into a record of `cells` cells. */
static void gather_at(const world *w, world_rect r, unsigned layers, layout l, size_t off,
                      int32_t *values)
{
    world_gather_window(w, r, values + off);
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
        if (layers & layer_bit[i])
            world_layer_gather(w, i, r, values + l.at[i] + off * (size_t)world_layer_fields(i));
}

/* The inverse of gather_at. 0, or -1 out of memory. */
static int scatter_at(world *w, world_rect r, unsigned layers, layout l, size_t off,
                      const int32_t *values)
{
    world_scatter_window(w, r, values + off);
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++) {
        if (!(layers & layer_bit[i]))
            continue;
        size_t at = l.at[i] + off * (size_t)world_layer_fields(i);
        if (world_layer_scatter(w, i, r, values + at) != 0)
            return -1;
    }
    return 0;
}

/* Rectangle q (inside r) of one part of r's values, f ints per cell, into dst. */
static void copy_part(int32_t *dst, const int32_t *src, world_rect r, world_rect q, int f)
{
    for (int y = 0; y < q.h; y++)
        memcpy(dst + (size_t)y * q.w * f, src + ((size_t)(q.y - r.y + y) * r.w + (q.x - r.x)) * f,
               (size_t)q.w * f * sizeof *dst);
}

/* scatter_at, only where r meets clip (clip.w 0: all of r): a rebuild of one
 * rectangle never stores the tiles beside it. *part is scratch for the met
 * cells' values. 0, or -1 out of memory. */
static int scatter_clipped(world *w, world_rect r, world_rect clip, unsigned layers, layout l,
                           size_t off, const int32_t *values, int32_t **part, int64_t *part_cap)
{
    world_rect q = clip.w ? world_rect_meet(r, clip) : r;
    if (q.w <= 0 || q.h <= 0)
        return 0;
    if (q.w == r.w && q.h == r.h)
        return scatter_at(w, r, layers, l, off, values);
    layout ql = layout_of((size_t)q.w * q.h, layers);
    if (array_grow((void **)part, part_cap, (int64_t)ql.ints + 1, sizeof **part) != 0)
        return -1;
    copy_part(*part, values + off, r, q, 1);
    for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
        if (layers & layer_bit[i]) {
            int f = world_layer_fields(i);
            copy_part(*part + ql.at[i], values + l.at[i] + off * (size_t)f, r, q, f);
        }
    return scatter_at(w, q, layers, ql, 0, *part);
}

void store_layers_gather(const world *w, world_rect r, unsigned layers, int32_t *dst)
{
    gather_at(w, r, layers, layout_of((size_t)r.w * r.h, layers), 0, dst);
}

int store_layers_scatter(world *w, world_rect r, unsigned layers, const int32_t *src,
                         const world_rect *clip)
{
    int32_t *part = NULL;
    int64_t part_cap = 0;
    int rc = scatter_clipped(w, r, clip ? *clip : (world_rect){0, 0, 0, 0}, layers,
                             layout_of((size_t)r.w * r.h, layers), 0, src, &part, &part_cap);
    free(part);
    return rc;
}

int store_record_gather(store_record *c, const world *w, const world_rect *rects, int n,
                        unsigned layers)
{
    layout l = layout_of(rects_cells(rects, n), layers);
    if (array_grow((void **)&c->values, &c->values_cap, (int64_t)l.ints + 1, sizeof *c->values) !=
        0)
        return -1;
    size_t off = 0;
    for (int i = 0; i < n; i++) {
        gather_at(w, rects[i], layers, l, off, c->values);
        off += (size_t)rects[i].w * rects[i].h;
    }
    return 0;
}

size_t store_record_encode(store_record *c, struct ZSTD_CCtx_s *cctx, int level,
                           const world_rect *rects, int n, unsigned layers, const int32_t *values,
                           size_t head, error_text *err)
{
    size_t raw = layout_of(rects_cells(rects, n), layers).ints * 4;
    size_t table = 4 + (size_t)n * 16 + 4;
    size_t bound = ZSTD_compressBound(raw);
    if (n < 0 || (uint32_t)n > RECORD_RECTS_MAX || raw > REC_MAX_PAYLOAD) {
        error_set(err, "store: a record of %d rectangles and %zu bytes is too large", n, raw);
        return 0;
    }
    if (array_grow((void **)&c->buf, &c->buf_cap, (int64_t)(head + table + bound), 1) != 0) {
        error_set(err, "store: out of memory for a log record");
        return 0;
    }
    uint8_t *p = c->buf + head;
    put32(p, (uint32_t)n | layer_bits(layers));
    for (int i = 0; i < n; i++) {
        put32(p + 4 + 16 * i, (uint32_t)rects[i].x);
        put32(p + 8 + 16 * i, (uint32_t)rects[i].y);
        put32(p + 12 + 16 * i, (uint32_t)rects[i].w);
        put32(p + 16 + 16 * i, (uint32_t)rects[i].h);
    }
    put32(p + table - 4, (uint32_t)raw);
    size_t packed = ZSTD_compressCCtx(cctx, p + table, bound, values, raw, level);
    if (ZSTD_isError(packed)) {
        error_set(err, "store: zstd: %s", ZSTD_getErrorName(packed));
        return 0;
    }
    return table + packed;
}

unsigned store_record_layers(const uint8_t *p, size_t len)
{
    uint32_t word = len >= 4 ? get32(p) : 0;
    return (word & STORE_RECORD_SOIL ? STORE_LAYER_SOIL : 0) |
           (word & STORE_RECORD_COMPACTION ? STORE_LAYER_COMPACTION : 0);
}

static world_rect rect_at(const uint8_t *p, uint32_t i)
{
    return (world_rect){(int32_t)get32(p + 4 + 16 * i), (int32_t)get32(p + 8 + 16 * i),
                        (int32_t)get32(p + 12 + 16 * i), (int32_t)get32(p + 16 + 16 * i)};
}

int store_record_apply(store_record *c, world *w, const uint8_t *p, size_t len,
                       int (*check)(void *ctx, world_rect r), void *ctx)
{
    /* everything is checked before anything is applied */
    uint32_t word = len >= 4 ? get32(p) : 0, nrect = word & ~STORE_RECORD_LAYER_BITS;
    unsigned layers = store_record_layers(p, len);
    size_t table = 4 + (size_t)nrect * 16 + 4;
    int ok = len >= 4 && nrect <= RECORD_RECTS_MAX && table <= len;
    uint64_t cells = 0;
    for (uint32_t i = 0; ok && i < nrect; i++) {
        world_rect r = rect_at(p, i), clipped = r;
        ok = r.w > 0 && r.h > 0 && world_clip_rect(w, &clipped) && clipped.x == r.x &&
             clipped.y == r.y && clipped.w == r.w && clipped.h == r.h &&
             (!check || check(ctx, r) == 0);
        cells += (uint64_t)r.w * r.h;
    }
    if (!ok || cells > REC_MAX_PAYLOAD)
        return 1;
    layout l = layout_of((size_t)cells, layers);
    uint64_t raw = (uint64_t)l.ints * 4;
    if (raw != get32(p + table - 4) || raw > REC_MAX_PAYLOAD)
        return 1;
    if (array_grow((void **)&c->values, &c->values_cap, (int64_t)(raw / 4 + 1),
                   sizeof *c->values) != 0)
        return -1;
    if (ZSTD_decompress(c->values, raw, p + table, len - table) != raw)
        return 1;
    for (size_t k = 0; (layers & STORE_LAYER_COMPACTION) && k < cells; k++)
        if (c->values[l.at[WORLD_LAYER_COMPACTION] + k] < 0 ||
            c->values[l.at[WORLD_LAYER_COMPACTION] + k] > WORLD_COMPACTION_MAX)
            return 1;
    size_t off = 0;
    for (uint32_t i = 0; i < nrect; i++) {
        world_rect r = rect_at(p, i);
        if (scatter_clipped(w, r, c->clip, layers, l, off, c->values, &c->part, &c->part_cap) != 0)
            return -1;
        off += (size_t)r.w * r.h;
    }
    return 0;
}
