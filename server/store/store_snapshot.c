/*
 * store_snapshot.c: the data directory's manifest and tile snapshots. The
 * manifest, written once, names the world the directory belongs to; a tile
 * snapshot holds one 256² tile's heights (and its per-cell state) as of a tick boundary, zstd
 * compressed. Snapshots are written by the compaction thread (never in a
 * tick) and read at recovery, before the first tick.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>
#include <zstd.h>

#include "store/store_internal.h"

/* ---- manifest ---- */

/*
 * The manifest names the world by its base terrain. The world is sparse and may
 * be 65,536² cells, so the base is not summed whole: a lattice of up to 257²
 * cells spread evenly over it, corners included, is read from the base
 * (world_base_fill_rect, never the live heights) and checksummed. Another scene's
 * dunes seed, height or heightmap changes these samples.
 */
uint32_t store_base_identity(const world *w)
{
    enum { SAMPLES = 257 };
    uint32_t crc = 0;
    int nx = w->width < SAMPLES ? w->width : SAMPLES;
    int ny = w->height < SAMPLES ? w->height : SAMPLES;
    for (int j = 0; j < ny; j++) {
        int y = ny > 1 ? (int)((int64_t)j * (w->height - 1) / (ny - 1)) : 0;
        for (int i = 0; i < nx; i++) {
            int x = nx > 1 ? (int)((int64_t)i * (w->width - 1) / (nx - 1)) : 0;
            int32_t h;
            world_base_fill_rect(w, (world_rect){x, y, 1, 1}, &h);
            uint8_t le[4] = {(uint8_t)h, (uint8_t)(h >> 8), (uint8_t)(h >> 16),
                             (uint8_t)((uint32_t)h >> 24)};
            crc = store_crc32c(crc, le, sizeof le);
        }
    }
    return crc;
}

char *store_manifest_text(const world *w, uint32_t base_crc)
{
    char body[512];
    snprintf(body, sizeof body,
             "{\"format\":1,\"width\":%d,\"height\":%d,\"cell_size_m\":%.17g,"
             "\"units_per_m\":%d,\"base_crc32c\":\"%08x\",\"tile_size\":%d}\n",
             w->width, w->height, w->cell_size_m, (int)w->units_per_m, base_crc, STORE_TILE_SIZE);
    size_t n = strlen(body);
    char *out = malloc(n + 32);
    if (out)
        snprintf(out, n + 32, "%scrc32c %08x\n", body, store_crc32c(0, body, n));
    return out;
}

/* Compare the manifest with the world; errors name the file and the field. */
int store_manifest_check(const char *path, const world *w, uint32_t base_crc, error_text *err)
{
    uint8_t *data;
    size_t len;
    if (store_file_read(path, "", &data, &len, err) != 0)
        return -1;
    char *text = (char *)data;
    if (!store_text_crc_end(text, "}\n")) {
        error_set(err, "store: %s is corrupt (checksum mismatch or truncated)", path);
        free(data);
        return -1;
    }
    char *expect = store_manifest_text(w, base_crc);
    int same = expect && strcmp(expect, text) == 0;
    if (!same) {
        cJSON *doc = cJSON_Parse(text);
        const char *fields[] = {"format",      "width",       "height",
                                "cell_size_m", "units_per_m", "base_crc32c"};
        cJSON *want = expect ? cJSON_Parse(expect) : NULL;
        const char *bad = "contents";
        for (size_t i = 0; doc && want && i < sizeof fields / sizeof *fields; i++) {
            cJSON *a = cJSON_GetObjectItemCaseSensitive(doc, fields[i]);
            cJSON *b = cJSON_GetObjectItemCaseSensitive(want, fields[i]);
            if (!cJSON_Compare(a, b, 1)) {
                bad = fields[i];
                break;
            }
        }
        error_set(err,
                  "store: %s belongs to another world or scene (%s differs: the data directory "
                  "was made for a different scene; use another --data directory)",
                  path, bad);
        cJSON_Delete(doc);
        cJSON_Delete(want);
    }
    free(expect);
    free(data);
    return same ? 0 : -1;
}

/* ---- tile snapshots ---- */

world_rect store_tile_rect(int width, int height, int tx, int ty)
{
    world_rect r = {tx * STORE_TILE_SIZE, ty * STORE_TILE_SIZE, STORE_TILE_SIZE, STORE_TILE_SIZE};
    if (r.x + r.w > width)
        r.w = width - r.x;
    if (r.y + r.h > height)
        r.h = height - r.y;
    return r;
}

/* Read one tile snapshot into w; errors name the file. */
int store_tile_load(const char *path, world *w, uint64_t upto_tick, const world_rect *clip,
                    uint64_t *tick_out, error_text *err)
{
    uint8_t *data;
    size_t len;
    if (store_file_read(path, "tile snapshot ", &data, &len, err) != 0)
        return -1;
    int rc = -1;
    int32_t *values = NULL;
    if (len < TILE_HEADER || memcmp(data, TILE_MAGIC, 8) != 0 ||
        get32(data + 52) != store_crc32c(0, data, 52)) {
        error_set(err, "store: tile snapshot %s is corrupt (bad header or header checksum)", path);
        goto out;
    }
    uint32_t format = get32(data + 8), ww = get32(data + 12), wh = get32(data + 16),
             tx = get32(data + 20), ty = get32(data + 24), comp = get32(data + 44),
             crc = get32(data + 48);
    if (format < TILE_FORMAT_HEIGHTS || format > TILE_FORMAT_MAX) {
        error_set(err, "store: tile snapshot %s has format %u (this build reads 1 to %d)", path,
                  format, TILE_FORMAT_MAX);
        goto out;
    }
    unsigned layers = format - TILE_FORMAT_HEIGHTS;
    if (ww != (uint32_t)w->width || wh != (uint32_t)w->height) {
        error_set(err, "store: tile snapshot %s is for a %ux%u world, this one is %dx%d", path, ww,
                  wh, w->width, w->height);
        goto out;
    }
    if ((size_t)TILE_HEADER + comp != len || store_crc32c(0, data + TILE_HEADER, comp) != crc) {
        error_set(err, "store: tile snapshot %s is corrupt (truncated or payload checksum)", path);
        goto out;
    }
    if (tx >= (uint32_t)((w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE) ||
        ty >= (uint32_t)((w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE)) {
        error_set(err, "store: tile snapshot %s names tile (%u, %u) outside the world", path, tx,
                  ty);
        goto out;
    }
    if (upto_tick && get64(data + 36) > upto_tick) {
        error_set(err,
                  "store: tile snapshot %s is of tick %llu, after tick %llu: the log before it "
                  "was compacted away",
                  path, (unsigned long long)get64(data + 36), (unsigned long long)upto_tick);
        goto out;
    }
    *tick_out = get64(data + 36);
    world_rect r = store_tile_rect(w->width, w->height, (int)tx, (int)ty);
    if (clip && !world_rects_overlap(r, *clip)) {
        rc = 0; /* checked as any other (a newer tick refuses), but none of its cells is wanted */
        goto out;
    }
    size_t cells = (size_t)r.w * r.h;
    size_t raw = cells * 4 * (size_t)store_layers_ints(layers);
    values = malloc(raw);
    if (!values || ZSTD_decompress(values, raw, data + TILE_HEADER, comp) != raw) {
        error_set(err, "store: tile snapshot %s does not decompress to %dx%d cells", path, r.w,
                  r.h);
        goto out;
    }
    for (size_t i = 0; i < raw / 4; i++)
        values[i] = (int32_t)get32((uint8_t *)&values[i]);
    /* heights first; the compaction memory, when there, is the last cells' worth */
    const int32_t *memory = values + raw / 4 - cells;
    for (size_t i = 0; i < cells; i++) {
        int32_t v = values[i];
        if (v < WORLD_HEIGHT_MIN || v > WORLD_HEIGHT_MAX) {
            error_set(err, "store: tile snapshot %s holds a height outside the limits", path);
            goto out;
        }
        if ((layers & STORE_LAYER_COMPACTION) &&
            (memory[i] < 0 || memory[i] > WORLD_COMPACTION_MAX)) {
            error_set(err, "store: tile snapshot %s holds a compaction memory outside [0, %d]",
                      path, WORLD_COMPACTION_MAX);
            goto out;
        }
    }
    if (store_layers_scatter(w, r, layers, values, clip) != 0) {
        error_set(err, "store: out of memory for the per-cell state of tile snapshot %s", path);
        goto out;
    }
    rc = 0;
out:
    free(values);
    free(data);
    return rc;
}

int store_tile_write(const store_dir *st, const char *dir, const tile_copy *t, uint64_t tick,
                     ZSTD_CCtx *cctx, int level, error_text *err)
{
    size_t raw = (size_t)t->rect.w * t->rect.h * 4 * (size_t)store_layers_ints(t->layers);
    size_t cap = ZSTD_compressBound(raw);
    uint8_t *packed = malloc(cap);
    if (!packed) {
        error_set(err, "store: out of memory compressing a tile");
        return -1;
    }
    size_t n = ZSTD_compressCCtx(cctx, packed, cap, t->values, raw, level);
    if (ZSTD_isError(n)) {
        error_set(err, "store: zstd: %s", ZSTD_getErrorName(n));
        free(packed);
        return -1;
    }
    uint8_t h[TILE_HEADER] = {0};
    memcpy(h, TILE_MAGIC, 8);
    put32(h + 8, TILE_FORMAT_HEIGHTS + t->layers);
    put32(h + 12, (uint32_t)st->width);
    put32(h + 16, (uint32_t)st->height);
    put32(h + 20, (uint32_t)t->tx);
    put32(h + 24, (uint32_t)t->ty);
    put32(h + 28, (uint32_t)t->rect.w);
    put32(h + 32, (uint32_t)t->rect.h);
    put64(h + 36, tick);
    put32(h + 44, (uint32_t)n);
    put32(h + 48, store_crc32c(0, packed, n));
    put32(h + 52, store_crc32c(0, h, 52));
    char name[64];
    snprintf(name, sizeof name, "t-%05d-%05d.snap", t->tx, t->ty);
    int rc = store_dir_write_atomic(st, dir, name, h, sizeof h, packed, n, err);
    free(packed);
    return rc;
}
