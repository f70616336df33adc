/*
 * cluster_history.c: a world's past read back from JetStream, beside its
 * owner (store.h "a world's past"; PROTOCOL.md "Spectate"): the reader a
 * spectator's store cursor and GET /v1/heights?tick=N use on a cluster
 * node, as they use a data directory on a single daemon. Never in the tick:
 * it runs on a spectator's thread or an HTTP worker and only reads what the
 * world's store (cluster_store.c) wrote — the snapshot index, the tile
 * snapshots and the log — asking the stream's leader, as recovery does.
 *
 * What a cluster holds: the newest snapshot of each tile, as of the log
 * sequence C the index covers (the state at the end of the tick of the
 * record at C), and the log from C on (everything below C is purged once
 * the index names C). So a tick T is held when T >= that record's tick:
 * the rebuild loads the snapshots of the tiles under the rectangle, then
 * the cursor applies the records from C up to T (records hold absolute
 * values, so the record at C applied again changes nothing). A compaction
 * running meanwhile is seen (a tile snapshot covering more than the index,
 * the record at C gone) and the rebuild is made again. While reading on, a
 * record could be purged under the reader only by a compaction that covers
 * more than the reader's position — the index says so first — so the
 * reader fails ("compacted away") instead of skipping records.
 */
#include "cluster/cluster_internal.h"

#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#define HISTORY_ATTEMPTS 20 /* rebuilds tried while compactions run */
#define HISTORY_RETRY_MS 100

typedef struct cluster_history {
    cluster *cl;
    char world[CLUSTER_WORLD_NAME_MAX + 1];
} cluster_history;

typedef struct history_reader {
    cluster_history *h;
    cluster_wal *wal; /* read only: its parts are put together here */
    uint64_t from;    /* the next sequence to ask for */
    uint8_t *buf;     /* the record last read */
    int64_t cap;
    uint64_t tick; /* the last record's tick */
} history_reader;

static int cancelled(store_cancel *cancel)
{
    return cancel && cancel->cancelled && cancel->cancelled(cancel->ctx);
}

/* The index's covered sequence now (0: none): 0, or -1 (why). */
static int index_covers(cluster_history *h, uint64_t *covers, error_text *why)
{
    int(*tiles)[2] = NULL;
    int count = 0;
    *covers = 0;
    int rc = cluster_snapshot_index_get(h->cl, h->world, covers, &tiles, &count, why);
    free(tiles);
    return rc < 0 ? -1 : 0;
}

/* The next whole record: 1 with its tick and payload, 0 none yet, -1. */
static int reader_next(void *state, uint64_t *tick, const uint8_t **payload, size_t *len,
                       error_text *why)
{
    history_reader *r = state;
    uint64_t asked = r->from, first = 0, seq = 0, covers = 0;
    size_t n = 0;
    int rc = cluster_wal_next(r->wal, &r->from, &first, &r->buf, &r->cap, &n, &seq, why);
    if (rc < 0)
        return -1;
    /* a message skipped between asked and first: another world's, or one of
     * ours a compaction purged — possible only when the index now covers
     * more than asked (deletes come after the index) */
    if (first > asked && index_covers(r->h, &covers, why) != 0)
        return -1;
    if (first > asked && covers > asked) {
        error_set(why,
                  "world %s: the log after tick %" PRIu64 " was compacted away (into tile "
                  "snapshots as of log sequence %" PRIu64 ") while it was read",
                  r->h->world, r->tick, covers);
        return -1;
    }
    if (rc == 0)
        return 0;
    int got = cluster_record_payload(r->buf, n, tick, payload, len);
    if (got <= 0) {
        error_set(why, "world %s: the log record at sequence %" PRIu64 " %s", r->h->world, seq,
                  got < 0 ? "is a version 1 record (heights only), which replays do not read"
                          : "is corrupt");
        return -1;
    }
    r->tick = *tick;
    return 1;
}

static void reader_close(void *state)
{
    history_reader *r = state;
    if (!r)
        return;
    cluster_wal_close(r->wal);
    free(r->buf);
    free(r);
}

/* The snapshots of the index's tiles under rec->clip (the whole world when
 * not set) into w: 0; 1 when one covers more than the index (a compaction
 * is running: try again); -1 (why). */
static int load_tiles(cluster_history *h, world *w, store_record *rec, uint64_t covers,
                      const int (*tiles)[2], int count, store_cancel *cancel, error_text *why)
{
    const world_rect *clip = rec->clip.w ? &rec->clip : NULL;
    for (int i = 0; i < count; i++) {
        int tx = tiles[i][0], ty = tiles[i][1];
        if (tx < 0 || ty < 0 || tx >= w->tiles_x || ty >= w->tiles_y) {
            error_set(why, "world %s: a snapshot of tile %d,%d, outside the world", h->world, tx,
                      ty);
            return -1;
        }
        if (clip && !world_rects_overlap(*clip, world_tile_rect(w, tx, ty)))
            continue;
        if (cancelled(cancel)) {
            error_set(why, "store: cancelled");
            return -1;
        }
        uint8_t *data = NULL;
        size_t len = 0;
        uint64_t tile_covers = 0;
        int found = cluster_snapshot_get(h->cl, h->world, tx, ty, &data, &len, &tile_covers, why);
        if (found <= 0) {
            if (found == 0) /* replaced meanwhile (its parts gone): the next try sees the new one */
                error_set(why, "world %s: the snapshot of tile %d,%d is missing", h->world, tx, ty);
            free(data);
            return found == 0 ? 1 : -1;
        }
        int ok = tile_covers > covers ? 2 : cluster_snapshot_apply(rec, w, tx, ty, data, len);
        free(data);
        if (ok == 2)
            return 1;
        if (ok <= 0) {
            error_set(why, "world %s: the snapshot of tile %d,%d %s", h->world, tx, ty,
                      ok < 0 ? "needs more memory than there is" : "is corrupt");
            return -1;
        }
    }
    return 0;
}

/* One try: 0 (*r reads from the index's sequence), 1 gone, 2 try again, -1. */
static int open_once(cluster_history *h, world *w, uint64_t tick, store_record *rec,
                     store_cancel *cancel, history_reader *r, error_text *why)
{
    int(*tiles)[2] = NULL;
    int count = 0;
    uint64_t covers = 0;
    if (cluster_snapshot_index_get(h->cl, h->world, &covers, &tiles, &count, why) < 0)
        return -1;
    r->from = covers ? covers : 1;
    int rc = 0;
    if (covers) {
        /* the tick the snapshots are as of: the record at covers' (it stays) */
        uint64_t first = 0, seq = 0, held = 0;
        size_t n = 0;
        const uint8_t *payload = NULL;
        int got = cluster_wal_next(r->wal, &r->from, &first, &r->buf, &r->cap, &n, &seq, why);
        if (got < 0)
            rc = -1;
        else if (first != covers) /* purged by a newer compaction meanwhile */
            rc = 2;
        else if (got == 0 || cluster_record_payload(r->buf, n, &held, &payload, &n) <= 0)
            rc = 1, error_set(why,
                              "world %s: the tick of the log record the tile snapshots cover "
                              "(sequence %" PRIu64 ") cannot be read",
                              h->world, covers);
        else if (tick < held) /* seq != covers: a record in parts; held is the next one's */
            rc = 1, error_set(why,
                              "world %s: the log before tick %" PRIu64 " was compacted into tile "
                              "snapshots (a cluster keeps no older log)",
                              h->world, held);
        r->from = covers;
        cluster_wal_close(r->wal); /* the parts seen so far go: read again from covers */
        r->wal = cluster_wal_open(h->cl, h->world, why);
        if (!r->wal)
            rc = -1;
    }
    if (rc == 0) {
        rc = load_tiles(h, w, rec, covers, (const int(*)[2])tiles, count, cancel, why);
        rc = rc == 1 ? 2 : rc;
    }
    free(tiles);
    return rc;
}

static int history_open(void *ctx, world *w, uint64_t tick, store_record *rec, store_cancel *cancel,
                        void **out, error_text *why)
{
    cluster_history *h = ctx;
    history_reader *r = calloc(1, sizeof *r);
    *out = NULL;
    if (!r || !(r->wal = cluster_wal_open(h->cl, h->world, why))) {
        if (r)
            free(r);
        else
            error_set(why, "out of memory");
        return -1;
    }
    r->h = h;
    int rc = 2;
    for (int attempt = 0; attempt < HISTORY_ATTEMPTS && rc == 2; attempt++) {
        if (attempt)
            nats_Sleep(HISTORY_RETRY_MS);
        if (cancelled(cancel)) {
            error_set(why, "store: cancelled");
            rc = -1;
            break;
        }
        memset(why, 0, sizeof *why);
        rc = open_once(h, w, tick, rec, cancel, r, why);
    }
    if (rc == 2) {
        error_set(why, "world %s: compactions kept replacing the tile snapshots during the rebuild",
                  h->world);
        rc = -1;
    }
    if (rc != 0) {
        reader_close(r);
        return rc;
    }
    *out = r;
    return 0;
}

static void history_release(void *ctx)
{
    free(ctx);
}

static const store_history_ops cluster_history_ops = {
    .open = history_open,
    .next = reader_next,
    .close = reader_close,
    .release = history_release,
};

int cluster_history_make(cluster *cl, const char *world, store_history *out, error_text *err)
{
    memset(out, 0, sizeof *out);
    if (!cluster_name_valid(world, "world", err))
        return -1;
    cluster_history *h = calloc(1, sizeof *h);
    if (!h) {
        error_set(err, "out of memory");
        return -1;
    }
    h->cl = cl;
    snprintf(h->world, sizeof h->world, "%s", world);
    out->ops = &cluster_history_ops;
    out->ctx = h;
    return 0;
}
