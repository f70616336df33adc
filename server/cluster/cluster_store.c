/*
 * cluster_store.c: a world's terrain on JetStream (cluster.h) — the
 * cluster's counterpart of the data directory. In the tick the service
 * commits after the deformation and before anything of the tick is
 * published; the commit returns once the stream's replicas acknowledged the
 * record (the promise of --durability every-tick). Compaction runs on its own
 * thread from copies of the changed tiles taken at a tick boundary, so it
 * never stalls a tick.
 *
 *   record   "TRC3" | tick u64 | CRC32C u32 | payload
 *   snapshot "TRS3" | tx, ty (i32) | CRC32C u32 | payload of one rectangle, the tile
 *
 * The payload is the data directory's log record payload, written and read
 * by the one codec store_record.c (store.h): the changed rectangles' heights
 * and their per-cell state — for a bekker world its soil state, for a world
 * whose materials remember compaction (the persson models, sumner) its
 * compaction memory — so a world that fails over or restarts resumes with
 * its plastic sinkage, shear displacement and compaction, not fresh soil.
 * The checksum covers the payload. Version 3 may carry the compaction memory
 * (payload bit 30) and is written only when it does; version 2 (heights and
 * at most soil state) is written otherwise, so a world without the memory
 * stays readable by builds before it; both are read by one path. Version 1,
 * heights only, is still read (never written):
 *   record   "TRC1" | tick u64 | rects u32 | raw bytes u32 | CRC32C u32 | zstd(raw)
 *            raw: per rectangle x, y, w, h (i32) then w*h heights (i32)
 *   snapshot "TRS1" | tx, ty, w, h (i32) | raw bytes u32 | CRC32C u32 | zstd(heights)
 *
 * Integers are little-endian (terrad runs on little-endian hosts only, as the
 * wire format does).
 */
#include "cluster/cluster_internal.h"

#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#include <zstd.h>

#define RECORD_MAGIC "TRC2"
#define RECORD3_MAGIC "TRC3"
#define RECORD_HEADER 16
#define SNAP_MAGIC "TRS2"
#define SNAP3_MAGIC "TRS3"
#define SNAP_HEADER 16
#define RECORD1_MAGIC "TRC1"
#define RECORD1_HEADER 24
#define SNAP1_MAGIC "TRS1"
#define SNAP1_HEADER 28
#define RAW_MAX (1u << 30)

typedef struct tile_copy {
    int tx, ty;
    world_rect rect;
    unsigned layers; /* STORE_LAYER_*: what values holds after the heights */
    int32_t *values; /* heights, then the layers (store_layers_gather) */
} tile_copy;

struct cluster_store {
    cluster *cl;
    char world[CLUSTER_WORLD_NAME_MAX + 1];
    cluster_wal *wal;
    cluster_store_config cfg;
    int tiles_x, tiles_y, tile_cells;
    uint8_t *changed; /* per tile: changed since the last compaction boundary */
    int records_since;
    uint64_t tick;
    ZSTD_CCtx *cctx;
    store_record rec; /* the record codec's scratch (sim thread) */
    uint8_t *raw;     /* a version 1 record, decompressed */
    int64_t raw_cap;
    stat_series commit_ms;
    /* compaction: one job at a time, handed over under the mutex */
    pthread_mutex_t lock;
    pthread_cond_t cond;
    pthread_t thread;
    int thread_started, quit, job_ready, job_running, job_failed;
    tile_copy *job_tiles;
    int job_count;
    uint64_t job_seq;
    int64_t compactions, compacted_tiles;
    /* the store's face (store.h): why commits are refused, and since when */
    int fenced;
    char failure[256];
    double failed_ms;
};

static void put_u32(uint8_t *p, uint32_t v)
{
    memcpy(p, &v, 4);
}

static uint32_t get_u32(const uint8_t *p)
{
    uint32_t v;
    memcpy(&v, p, 4);
    return v;
}

/* ---- records ---- */

/* Encodes a tick into cs->rec.buf; returns its length, 0 on failure. */
static size_t record_encode(cluster_store *cs, const world *w, uint64_t tick,
                            const world_rect *rects, int n, error_text *err)
{
    unsigned layers = store_world_layers(w);
    if (store_record_gather(&cs->rec, w, rects, n, layers) != 0) {
        error_set(err, "world %s: out of memory for a log record", cs->world);
        return 0;
    }
    size_t len = store_record_encode(&cs->rec, cs->cctx, cs->cfg.compression_level, rects, n,
                                     layers, cs->rec.values, RECORD_HEADER, err);
    if (len == 0)
        return 0;
    memcpy(cs->rec.buf, layers & STORE_LAYER_COMPACTION ? RECORD3_MAGIC : RECORD_MAGIC, 4);
    memcpy(cs->rec.buf + 4, &tick, 8);
    put_u32(cs->rec.buf + 12, store_crc32c(0, cs->rec.buf + RECORD_HEADER, len));
    return RECORD_HEADER + len;
}

typedef struct replay_ctx {
    cluster_store *cs;
    world *w;
    store_recovery *rec;
    error_text *err;
} replay_ctx;

/* A version 1 record (heights only) into w: 1 applied, 0 corrupt. */
static int record1_apply(cluster_store *cs, world *w, const uint8_t *data, size_t len)
{
    uint32_t n = 0, raw_len = 0;
    int ok = len >= RECORD1_HEADER;
    if (ok) {
        n = get_u32(data + 12);
        raw_len = get_u32(data + 16);
        ok = raw_len <= RAW_MAX &&
             array_grow((void **)&cs->raw, &cs->raw_cap, raw_len ? raw_len : 1, 1) == 0 &&
             ZSTD_decompress(cs->raw, raw_len, data + RECORD1_HEADER, len - RECORD1_HEADER) ==
                 raw_len &&
             store_crc32c(0, cs->raw, raw_len) == get_u32(data + 20);
    }
    const uint8_t *p = cs->raw, *end = cs->raw + raw_len;
    for (uint32_t i = 0; ok && i < n; i++) {
        int32_t h[4];
        ok = end - p >= 16;
        if (ok)
            memcpy(h, p, 16);
        world_rect rect = {h[0], h[1], h[2], h[3]}, clipped = rect;
        ok = ok && rect.w > 0 && rect.h > 0 && world_clip_rect(w, &clipped) &&
             memcmp(&rect, &clipped, sizeof rect) == 0 &&
             (end - p - 16) / 4 >= (int64_t)rect.w * rect.h;
        if (ok) {
            world_scatter_window(w, rect, (const int32_t *)(const void *)(p + 16));
            p += 16 + 4 * (size_t)rect.w * rect.h;
        }
    }
    return ok;
}

int cluster_record_payload(const uint8_t *data, size_t len, uint64_t *tick, const uint8_t **payload,
                           size_t *payload_len)
{
    if (len < RECORD_HEADER)
        return 0;
    memcpy(tick, data + 4, 8);
    if (memcmp(data, RECORD1_MAGIC, 4) == 0)
        return -1;
    if ((memcmp(data, RECORD_MAGIC, 4) != 0 && memcmp(data, RECORD3_MAGIC, 4) != 0) ||
        store_crc32c(0, data + RECORD_HEADER, len - RECORD_HEADER) != get_u32(data + 12))
        return 0;
    *payload = data + RECORD_HEADER;
    *payload_len = len - RECORD_HEADER;
    return 1;
}

/* Applies one record to the world; a record that does not decode stops recovery. */
static int record_apply(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    replay_ctx *r = ctx;
    cluster_store *cs = r->cs;
    uint64_t tick = 0;
    const uint8_t *payload = NULL;
    size_t payload_len = 0;
    int ok = cluster_record_payload(data, len, &tick, &payload, &payload_len), applied = 1;
    if (ok > 0) {
        applied = store_record_apply(&cs->rec, r->w, payload, payload_len, NULL, NULL);
        ok = applied == 0;
    } else if (ok < 0) {
        ok = record1_apply(cs, r->w, data, len);
    }
    if (applied < 0) {
        error_set(r->err, "world %s: out of memory replaying log sequence %" PRIu64, cs->world,
                  seq);
        return -1;
    }
    if (!ok) {
        error_set(r->err, "world %s: log record at sequence %" PRIu64 " is corrupt", cs->world,
                  seq);
        return -1;
    }
    if (tick > cs->tick)
        cs->tick = tick;
    r->rec->records_replayed++;
    return 0;
}

/* ---- snapshots ---- */

/* A tile copy as a snapshot, in rec->buf: its length, or 0 with err set. */
static size_t snapshot_encode(const tile_copy *t, store_record *rec, ZSTD_CCtx *cctx, int level,
                              error_text *err)
{
    size_t len =
        store_record_encode(rec, cctx, level, &t->rect, 1, t->layers, t->values, SNAP_HEADER, err);
    if (len == 0)
        return 0;
    int32_t hdr[2] = {t->tx, t->ty};
    memcpy(rec->buf, t->layers & STORE_LAYER_COMPACTION ? SNAP3_MAGIC : SNAP_MAGIC, 4);
    memcpy(rec->buf + 4, hdr, 8);
    put_u32(rec->buf + 12, store_crc32c(0, rec->buf + SNAP_HEADER, len));
    return SNAP_HEADER + len;
}

/* A snapshot's one rectangle must be its tile. */
static int snapshot_rect_check(void *ctx, world_rect r)
{
    const world_rect *want = ctx;
    return memcmp(&r, want, sizeof r) != 0;
}

int cluster_snapshot_apply(store_record *rec, world *w, int tx, int ty, const uint8_t *data,
                           size_t len)
{
    world_rect rect = world_tile_rect(w, tx, ty);
    int32_t hdr[4] = {0};
    if (len >= SNAP_HEADER &&
        (memcmp(data, SNAP_MAGIC, 4) == 0 || memcmp(data, SNAP3_MAGIC, 4) == 0)) {
        memcpy(hdr, data + 4, 8);
        if (hdr[0] != tx || hdr[1] != ty ||
            store_crc32c(0, data + SNAP_HEADER, len - SNAP_HEADER) != get_u32(data + 12) ||
            len - SNAP_HEADER < 4 || (get_u32(data + SNAP_HEADER) & ~STORE_RECORD_LAYER_BITS) != 1)
            return 0;
        int r = store_record_apply(rec, w, data + SNAP_HEADER, len - SNAP_HEADER,
                                   snapshot_rect_check, &rect);
        return r < 0 ? -1 : r == 0;
    }
    /* version 1: heights only */
    size_t raw = 4 * (size_t)rect.w * rect.h;
    if (len < SNAP1_HEADER || memcmp(data, SNAP1_MAGIC, 4) != 0)
        return 0;
    memcpy(hdr, data + 4, 16);
    int32_t *values = malloc(raw ? raw : 1);
    if (!values)
        return -1;
    int ok = hdr[0] == tx && hdr[1] == ty && hdr[2] == rect.w && hdr[3] == rect.h &&
             get_u32(data + 20) == raw &&
             ZSTD_decompress(values, raw, data + SNAP1_HEADER, len - SNAP1_HEADER) == raw &&
             store_crc32c(0, values, raw) == get_u32(data + 24);
    if (ok)
        world_scatter_window(w, rect, values);
    free(values);
    return ok;
}

/* Loads tile (tx, ty)'s snapshot into w; -1 (err names the tile) when it is corrupt. */
static int snapshot_load(cluster_store *cs, world *w, int tx, int ty, error_text *err)
{
    uint8_t *data = NULL;
    size_t len = 0;
    uint64_t covers = 0;
    int found = cluster_snapshot_get(cs->cl, cs->world, tx, ty, &data, &len, &covers, err);
    if (found <= 0)
        return found;
    int ok = cluster_snapshot_apply(&cs->rec, w, tx, ty, data, len);
    if (ok < 0)
        error_set(err, "world %s: out of memory loading the snapshot of tile %d,%d", cs->world, tx,
                  ty);
    else if (!ok)
        error_set(err, "world %s: the snapshot of tile %d,%d is corrupt or of another world",
                  cs->world, tx, ty);
    free(data);
    return ok > 0 ? 1 : -1;
}

/* Loads the snapshots the index names; *from_seq: where the log replay starts. */
static int snapshots_load(cluster_store *cs, world *w, uint64_t *from_seq, store_recovery *rec,
                          error_text *err)
{
    int(*tiles)[2] = NULL;
    int count = 0;
    uint64_t covers = 0;
    if (cluster_snapshot_index_get(cs->cl, cs->world, &covers, &tiles, &count, err) < 0)
        return -1;
    int rc = 0;
    for (int i = 0; rc == 0 && i < count; i++) {
        int tx = tiles[i][0], ty = tiles[i][1];
        if (tx < 0 || ty < 0 || tx >= cs->tiles_x || ty >= cs->tiles_y) {
            error_set(err, "world %s: a snapshot of tile %d,%d, outside the world", cs->world, tx,
                      ty);
            rc = -1;
        } else {
            int got = snapshot_load(cs, w, tx, ty, err);
            if (got < 0)
                rc = -1;
            else if (got == 0) {
                error_set(err, "world %s: the snapshot of tile %d,%d is missing", cs->world, tx,
                          ty);
                rc = -1;
            } else {
                rec->tiles_loaded++;
            }
        }
    }
    free(tiles);
    *from_seq = covers > 0 ? covers : 1;
    return rc;
}

/* ---- compaction thread ---- */

/* Writes the job's tiles, then the index naming them and seq (recovery
 * replays from there), and only then purges the log below seq. 0, or -1. */
static int compaction_run(cluster_store *cs, ZSTD_CCtx *cctx, store_record *rec,
                          const tile_copy *tiles, int count, uint64_t seq, error_text *err)
{
    int(*xy)[2] = calloc((size_t)count + 1, sizeof *xy);
    if (!xy) {
        error_set(err, "out of memory");
        return -1;
    }
    for (int i = 0; i < count; i++) {
        xy[i][0] = tiles[i].tx;
        xy[i][1] = tiles[i].ty;
    }
    cluster_status indexed = CLUSTER_ERROR;
    for (int i = 0; i < count; i++) {
        size_t len = snapshot_encode(&tiles[i], rec, cctx, cs->cfg.compression_level, err);
        if (len == 0) {
            free(xy);
            return -1;
        }
        cluster_status r = cluster_snapshot_put(cs->cl, cs->world, tiles[i].tx, tiles[i].ty, seq,
                                                rec->buf, len, err);
        if (r == CLUSTER_ERROR) {
            free(xy);
            return -1;
        }
        /* CLUSTER_FENCED: a newer owner stored a newer snapshot; fine */
    }
    indexed = cluster_snapshot_index_put(cs->cl, cs->world, seq, (const int(*)[2])xy, count, err);
    free(xy);
    if (indexed != CLUSTER_OK)
        return -1;
    /* record `seq` itself stays, so the subject keeps its last message */
    return cluster_log_purge_below(cs->cl, cs->world, seq, err) == CLUSTER_OK ? 0 : -1;
}

static void *compaction_main(void *arg)
{
    cluster_store *cs = arg;
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    store_record rec = {0}; /* this thread's codec scratch */
    pthread_mutex_lock(&cs->lock);
    for (;;) {
        while (!cs->job_ready && !cs->quit)
            pthread_cond_wait(&cs->cond, &cs->lock);
        if (!cs->job_ready)
            break;
        tile_copy *tiles = cs->job_tiles;
        int count = cs->job_count;
        uint64_t seq = cs->job_seq;
        cs->job_ready = 0;
        cs->job_running = 1;
        pthread_mutex_unlock(&cs->lock);

        double t0 = time_now_ms();
        error_text err = {{0}};
        int ok = cctx && compaction_run(cs, cctx, &rec, tiles, count, seq, &err) == 0;
        if (ok)
            log_info("cluster: world %s: %d tiles compacted as of log sequence %" PRIu64
                     " in %.1f ms",
                     cs->world, count, seq, time_now_ms() - t0);
        else
            log_error("cluster: world %s: compaction failed: %s (the log is kept)", cs->world,
                      err.message[0] ? err.message : "out of memory");

        pthread_mutex_lock(&cs->lock);
        if (ok) {
            cs->compactions++;
            cs->compacted_tiles += count;
        } else { /* the sim thread marks these tiles changed again */
            cs->job_failed = 1;
            cs->job_tiles = tiles;
            cs->job_count = count;
            tiles = NULL;
        }
        for (int i = 0; tiles && i < count; i++)
            free(tiles[i].values);
        free(tiles);
        cs->job_running = 0;
        pthread_cond_broadcast(&cs->cond);
    }
    pthread_mutex_unlock(&cs->lock);
    store_record_free(&rec);
    ZSTD_freeCCtx(cctx);
    return NULL;
}

/* After a failed compaction: its tiles count as changed again. cs->lock held. */
static void compaction_take_back(cluster_store *cs)
{
    for (int i = 0; i < cs->job_count; i++) {
        cs->changed[cs->job_tiles[i].ty * cs->tiles_x + cs->job_tiles[i].tx] = 1;
        free(cs->job_tiles[i].values);
    }
    free(cs->job_tiles);
    cs->job_tiles = NULL;
    cs->job_count = 0;
    cs->job_failed = 0;
}

/* At a tick boundary: copy the changed tiles and hand them to the thread. */
static void compaction_maybe_start(cluster_store *cs, const world *w)
{
    pthread_mutex_lock(&cs->lock);
    if (cs->job_failed)
        compaction_take_back(cs);
    int busy = cs->job_ready || cs->job_running;
    pthread_mutex_unlock(&cs->lock);
    if (busy || cs->records_since < cs->cfg.compact_records || !cs->thread_started)
        return;
    int total = cs->tiles_x * cs->tiles_y, n = 0, k = 0;
    for (int i = 0; i < total; i++)
        n += cs->changed[i];
    tile_copy *tiles = calloc((size_t)n + 1, sizeof *tiles);
    for (int i = 0; tiles && i < total; i++) {
        if (!cs->changed[i])
            continue;
        tile_copy *t = &tiles[k];
        t->tx = i % cs->tiles_x;
        t->ty = i / cs->tiles_x;
        t->rect = world_tile_rect(w, t->tx, t->ty);
        t->layers = store_rect_layers(w, t->rect);
        size_t cells = (size_t)t->rect.w * t->rect.h;
        t->values = malloc(4 * cells * (size_t)store_layers_ints(t->layers));
        if (!t->values)
            break;
        store_layers_gather(w, t->rect, t->layers, t->values);
        k++;
    }
    if (!tiles || k != n) {
        for (int i = 0; i < k; i++)
            free(tiles[i].values);
        free(tiles);
        return;
    }
    memset(cs->changed, 0, (size_t)total);
    cs->records_since = 0;
    pthread_mutex_lock(&cs->lock);
    cs->job_tiles = tiles;
    cs->job_count = n;
    cs->job_seq = cluster_wal_last_seq(cs->wal);
    cs->job_ready = 1;
    pthread_cond_broadcast(&cs->cond);
    pthread_mutex_unlock(&cs->lock);
}

/* ---- the store ---- */

static void mark_changed(cluster_store *cs, const world_rect *rects, int n)
{
    for (int i = 0; i < n; i++) {
        int tc = cs->tile_cells;
        for (int ty = rects[i].y / tc; ty <= (rects[i].y + rects[i].h - 1) / tc; ty++)
            for (int tx = rects[i].x / tc; tx <= (rects[i].x + rects[i].w - 1) / tc; tx++)
                cs->changed[ty * cs->tiles_x + tx] = 1;
    }
}

/* Replayed records change tiles too: the next compaction covers them. */
static int replay_record(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    replay_ctx *r = ctx;
    if (record_apply(ctx, seq, data, len) != 0)
        return -1;
    r->cs->records_since++;
    return 0;
}

cluster_store *cluster_store_open(cluster *cl, const char *world_name, world *w,
                                  const cluster_store_config *c, store_recovery *rec,
                                  error_text *err)
{
    double t0 = time_now_ms();
    memset(rec, 0, sizeof *rec);
    cluster_store *cs = calloc(1, sizeof *cs);
    if (!cs) {
        error_set(err, "out of memory");
        return NULL;
    }
    cs->cl = cl;
    snprintf(cs->world, sizeof cs->world, "%s", world_name);
    cs->cfg.compact_records = c && c->compact_records > 0 ? c->compact_records : 600;
    cs->cfg.compression_level = c && c->compression_level > 0 ? c->compression_level : 1;
    cs->tiles_x = w->tiles_x;
    cs->tiles_y = w->tiles_y;
    cs->tile_cells = w->tile_cells;
    cs->changed = calloc((size_t)w->tiles_x * w->tiles_y, 1);
    cs->cctx = ZSTD_createCCtx();
    pthread_mutex_init(&cs->lock, NULL);
    pthread_cond_init(&cs->cond, NULL);
    if (!cs->changed || !cs->cctx) {
        error_set(err, "out of memory");
        cluster_store_close(cs);
        return NULL;
    }
    cs->wal = cluster_wal_open(cl, world_name, err);
    replay_ctx r = {cs, w, rec, err};
    uint64_t from_seq = 1;
    if (!cs->wal || snapshots_load(cs, w, &from_seq, rec, err) != 0 ||
        cluster_wal_take(cs->wal, from_seq, replay_record, &r, err) != CLUSTER_OK) {
        cluster_store_close(cs);
        return NULL;
    }
    /* every tile a replayed record touched is compacted at the first boundary */
    for (int i = 0; cs->records_since > 0 && i < cs->tiles_x * cs->tiles_y; i++)
        cs->changed[i] = world_tile_generation(w, i % cs->tiles_x, i / cs->tiles_x) > 0;
    rec->tick = cs->tick;
    if (pthread_create(&cs->thread, NULL, compaction_main, cs) == 0)
        cs->thread_started = 1;
    rec->ms = time_now_ms() - t0;
    return cs;
}

void cluster_store_close(cluster_store *cs)
{
    if (!cs)
        return;
    if (cs->thread_started) {
        pthread_mutex_lock(&cs->lock);
        cs->quit = 1;
        pthread_cond_broadcast(&cs->cond);
        pthread_mutex_unlock(&cs->lock);
        pthread_join(cs->thread, NULL);
    }
    if (cs->job_ready || cs->job_failed) {
        for (int i = 0; i < cs->job_count; i++)
            free(cs->job_tiles[i].values);
        free(cs->job_tiles);
    }
    cluster_wal_close(cs->wal);
    ZSTD_freeCCtx(cs->cctx);
    free(cs->changed);
    free(cs->raw);
    store_record_free(&cs->rec);
    stat_series_free(&cs->commit_ms);
    pthread_cond_destroy(&cs->cond);
    pthread_mutex_destroy(&cs->lock);
    free(cs);
}

cluster_status cluster_store_commit_tick(cluster_store *cs, const world *w, uint64_t tick,
                                         const world_rect *rects, int n, error_text *err)
{
    if (cs->fenced) {
        error_set(err, "%s", cs->failure);
        return CLUSTER_FENCED;
    }
    size_t len = record_encode(cs, w, tick, rects, n, err);
    if (len == 0)
        return CLUSTER_ERROR;
    double t0 = time_now_ms();
    cluster_status r = cluster_wal_append(cs->wal, cs->rec.buf, len, NULL, err);
    if (r != CLUSTER_OK) {
        cs->fenced = r == CLUSTER_FENCED;
        snprintf(cs->failure, sizeof cs->failure, "%s", err->message);
        cs->failed_ms = time_now_ms();
        return r;
    }
    cs->failure[0] = '\0';
    if (cs->commit_ms.count >= 65536) /* the latest minutes are what /metrics shows */
        stat_series_free(&cs->commit_ms);
    stat_series_add(&cs->commit_ms, time_now_ms() - t0);
    cs->tick = tick;
    cs->records_since++;
    mark_changed(cs, rects, n);
    compaction_maybe_start(cs, w);
    return CLUSTER_OK;
}

int cluster_store_writable(cluster_store *cs)
{
    if (cs->fenced)
        return 0;
    if (!cluster_connected(cs->cl)) {
        snprintf(cs->failure, sizeof cs->failure, "world %s: not connected to NATS (%.120s)",
                 cs->world, cs->cl->urls);
        return 0;
    }
    if (!cluster_lease_held(cs->cl, cs->world)) {
        snprintf(cs->failure, sizeof cs->failure,
                 "world %s: this node (%s) does not hold its lease", cs->world, cs->cl->node);
        return 0;
    }
    /* after a failed commit, try again at most every 500 ms */
    if (cs->failure[0] && time_now_ms() - cs->failed_ms < 500)
        return 0;
    cs->failure[0] = '\0';
    return 1;
}

int cluster_store_fenced(const cluster_store *cs)
{
    return cs->fenced;
}

const char *cluster_store_failure(const cluster_store *cs)
{
    return cs->failure;
}

uint64_t cluster_store_tick(const cluster_store *cs)
{
    return cs->tick;
}

void cluster_store_commit_ms(const cluster_store *cs, double *p50, double *p99)
{
    *p50 = stat_series_percentile(&cs->commit_ms, 50);
    *p99 = stat_series_percentile(&cs->commit_ms, 99);
}

void cluster_store_compactions(cluster_store *cs, int64_t *count, int64_t *tiles)
{
    pthread_mutex_lock(&cs->lock);
    *count = cs->compactions;
    *tiles = cs->compacted_tiles;
    pthread_mutex_unlock(&cs->lock);
}

void cluster_store_wait_compaction(cluster_store *cs)
{
    pthread_mutex_lock(&cs->lock);
    while (cs->job_ready || cs->job_running)
        pthread_cond_wait(&cs->cond, &cs->lock);
    pthread_mutex_unlock(&cs->lock);
}

/* ---- the store's face (store.h): this store behind store_adopt ---- */

static void backend_close(void *state)
{
    cluster_store_close(state);
}

static int backend_writable(void *state)
{
    return cluster_store_writable(state);
}

static const char *backend_failure(const void *state)
{
    return cluster_store_failure(state);
}

/* A refused commit is logged when commits start failing, not at every tick. */
static int backend_append(void *state, const world *w, uint64_t tick, const world_rect *rects,
                          int n)
{
    cluster_store *cs = state;
    int was_failing = cs->failure[0] != '\0';
    error_text err = {{0}};
    if (cluster_store_commit_tick(cs, w, tick, rects, n, &err) == CLUSTER_OK)
        return 0;
    if (!was_failing)
        log_error("cluster: tick %llu not committed: %s", (unsigned long long)tick, err.message);
    return -1;
}

/* Every commit returned once acknowledged: nothing is ever waiting. */
static int backend_settle(void *state)
{
    (void)state;
    return 1;
}

static uint64_t backend_durable_tick(const void *state)
{
    return cluster_store_tick(state);
}

static const store_backend cluster_store_backend = {
    .name = "jetstream",
    .close = backend_close,
    .writable = backend_writable,
    .failure = backend_failure,
    .append_tick = backend_append,
    .settle = backend_settle,
    .durable_tick = backend_durable_tick,
};

store *cluster_store_as_store(cluster_store *cs)
{
    return store_adopt(&cluster_store_backend, cs);
}
