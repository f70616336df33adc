/*
 * store_replay.c: the world as of a past tick, rebuilt from a data directory
 * beside the live daemon (GET /v1/heights?tick=N; docs/storage.md "Replay"),
 * and the keyframes that make it quick. It runs on an HTTP worker, never in
 * the tick: it reads the files the sim and compaction threads write (every
 * whole file appears by rename or link, every record is complete before its
 * tick is published), into a world of its own.
 *
 * Keyframes: under retention a compaction's tile snapshots (the world as of
 * its tick, tiles changed since the previous one) are kept, hard-linked as
 * tiles/k-TICK-X-Y.snap, and tiles/k-TICK.done says the generation is whole.
 * The world at a whole generation's tick G is, per tile, its newest keyframe
 * at or before G (a tile changed since would be in a later generation), else
 * the base. So a rebuild of tick N starts from the newest whole generation at
 * or before N, loads only the requested rectangle's tiles, and replays the
 * records after G up to N, skipping the segments before. Without one: the
 * whole log from the base (while retention keeps segment 1), else the tile
 * snapshots and the log after them (a snapshot newer than N: 410). Records
 * hold absolute heights, so replaying a record older than the start is
 * harmless: the later ones of the same cells follow it.
 */
#include <dirent.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "store/store_internal.h"

int store_keyframe_name(const char *name, uint64_t *tick, int *tx, int *ty, int *done)
{
    unsigned long long t;
    int a, b, end = -1;
    *done = 0;
    if (sscanf(name, "k-%16llu-%5d-%5d.snap%n", &t, &a, &b, &end) == 3 && end > 0 && !name[end]) {
        *tick = t, *tx = a, *ty = b;
        return 1;
    }
    end = -1;
    if (sscanf(name, "k-%16llu.done%n", &t, &end) == 1 && end > 0 && !name[end]) {
        *tick = t, *done = 1;
        return 1;
    }
    return 0;
}

int store_keyframes_keep(const char *tiles_dir, const tile_copy *tiles, int count, uint64_t tick)
{
    char from[1200], to[1200];
    for (int i = 0; i < count; i++) {
        snprintf(from, sizeof from, "%s/t-%05d-%05d.snap", tiles_dir, tiles[i].tx, tiles[i].ty);
        snprintf(to, sizeof to, "%s/k-%016llu-%05d-%05d.snap", tiles_dir, (unsigned long long)tick,
                 tiles[i].tx, tiles[i].ty);
        unlink(to); /* a retried compaction of the same tick */
        if (link(from, to) != 0)
            return -1;
    }
    /* the links are durable before the marker says the generation is whole */
    if (store_dir_fsync(tiles_dir) != 0)
        return -1;
    snprintf(to, sizeof to, "%s/k-%016llu.done", tiles_dir, (unsigned long long)tick);
    int fd = open(to, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd < 0)
        return -1;
    close(fd);
    return store_dir_fsync(tiles_dir);
}

void store_keyframes_drop(const char *tiles_dir)
{
    DIR *d = opendir(tiles_dir);
    struct dirent *e;
    uint64_t tick;
    int tx, ty, done;
    char path[1400];
    /* before the segments go: a reader that still finds a generation and
     * then misses its records fails and tries again without one */
    while (d && (e = readdir(d)))
        if (store_keyframe_name(e->d_name, &tick, &tx, &ty, &done)) {
            snprintf(path, sizeof path, "%s/%s", tiles_dir, e->d_name);
            unlink(path);
        }
    if (d)
        closedir(d);
    store_dir_fsync(tiles_dir);
}

/* The newest whole generation at or before tick (0: none) and, per tile of
 * r, the tick of its newest keyframe at or before it (0: the base). */
static uint64_t keyframe_start(const char *tiles_dir, uint64_t tick, world_rect r,
                               uint64_t *tile_tick, int tiles_x)
{
    DIR *d = opendir(tiles_dir);
    struct dirent *e;
    uint64_t g = 0, t;
    int tx, ty, done;
    while (d && (e = readdir(d)))
        if (store_keyframe_name(e->d_name, &t, &tx, &ty, &done) && done && t <= tick && t > g)
            g = t;
    if (d)
        rewinddir(d);
    int x0 = r.x / STORE_TILE_SIZE, y0 = r.y / STORE_TILE_SIZE;
    int x1 = (r.x + r.w - 1) / STORE_TILE_SIZE, y1 = (r.y + r.h - 1) / STORE_TILE_SIZE;
    while (g && d && (e = readdir(d)))
        if (store_keyframe_name(e->d_name, &t, &tx, &ty, &done) && !done && t <= g && tx >= x0 &&
            tx <= x1 && ty >= y0 && ty <= y1 && t > tile_tick[ty * tiles_x + tx])
            tile_tick[ty * tiles_x + tx] = t;
    if (d)
        closedir(d);
    return g;
}

/* A segment's first record's tick (UINT64_MAX: none yet, or unreadable). */
static uint64_t segment_first_tick(const char *path)
{
    uint8_t h[WAL_HEADER + REC_HEADER];
    int fd = open(path, O_RDONLY);
    if (fd < 0)
        return UINT64_MAX;
    ssize_t n = pread(fd, h, sizeof h, 0);
    close(fd);
    return n == (ssize_t)sizeof h ? get64(h + WAL_HEADER + 8) : UINT64_MAX;
}

/* From generation g: the rectangle's tiles' keyframes, then the segments
 * that can hold records after g, up to tick. 0 or -1. */
static int replay_from_keyframes(const char *dir, world *w, uint64_t tick, world_rect r,
                                 store_cancel *cancel, error_text *why)
{
    char tiles_dir[1100], path[1400];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", dir);
    int tiles_x = (w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    int tiles_y = (w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    uint64_t *tile_tick = calloc((size_t)tiles_x * tiles_y, sizeof *tile_tick);
    uint64_t *seqs = NULL, *first = NULL;
    int count = 0, rc = -1;
    if (!tile_tick) {
        error_set(why, "store: out of memory");
        return -1;
    }
    uint64_t g = keyframe_start(tiles_dir, tick, r, tile_tick, tiles_x);
    if (!g) {
        free(tile_tick);
        return 1; /* no generation at or before the tick */
    }
    for (int i = 0; i < tiles_x * tiles_y; i++) {
        uint64_t t;
        if (!tile_tick[i])
            continue;
        if (store_cancel_now(cancel)) {
            error_set(why, "store: cancelled");
            goto out;
        }
        snprintf(path, sizeof path, "%s/k-%016llu-%05d-%05d.snap", tiles_dir,
                 (unsigned long long)tile_tick[i], i % tiles_x, i / tiles_x);
        if (store_tile_load(path, w, 0, &r, &t, why) != 0)
            goto out;
    }
    if (store_list_segments(dir, &seqs, &count) != 0 ||
        !(first = malloc(sizeof *first * ((size_t)count + 1)))) {
        error_set(why, "store: cannot list the segments of %s", dir);
        goto out;
    }
    if (count == 0 || seqs[0] != 1) { /* retention ended meanwhile: try again without */
        error_set(why, "store: the first log segment of %s went during the rebuild", dir);
        goto out;
    }
    for (int i = 0; i < count; i++) {
        store_segment_path(dir, seqs[i], path, sizeof path);
        first[i] = segment_first_tick(path);
    }
    for (int i = 0; i < count; i++) {
        if (i + 1 < count && first[i + 1] <= g + 1)
            continue; /* every record of it is at or before g */
        if (first[i] != UINT64_MAX && first[i] > tick)
            break; /* every record from here on is after the tick */
        replay_result res;
        store_segment_path(dir, seqs[i], path, sizeof path);
        if (store_segment_replay(path, w, &r, NULL, 0, tick, cancel, &res, why) != 0)
            goto out;
        if (res.problem[0] && i != count - 1) {
            error_set(why, "store: %s: %s", path, res.problem);
            goto out;
        }
    }
    rc = 0;
out:
    free(tile_tick);
    free(seqs);
    free(first);
    return rc;
}

/* w made as base's geometry, holding base's heights in r (the replay
 * world's own base is flat): cells no record or snapshot names keep them. */
static int rebuild_base(const world *base, world_rect r, world *w, int32_t *scratch,
                        error_text *why)
{
    if (world_init_tiled(w, base->width, base->height, base->cell_size_m, base->units_per_m,
                         base->floor, base->tile_cells, why) != 0)
        return -1;
    world_base_fill_rect(base, r, scratch);
    world_scatter_window(w, r, scratch);
    return 0;
}

/* One rebuild of r as of tick into w (initialised here; the caller frees
 * it, whatever the result); 0, 1 (gone), -1 or STORE_CANCELLED (cancel:
 * NULL, or a cursor's, asked between records and snapshots). Only r's cells are loaded and
 * replayed (store_record.clip): a small rectangle of a large world holds its
 * own tiles, never the whole world's (every snapshot is still checked, so a
 * tick compacted away is refused as before). */
static int rebuild(const char *dir, const world *base, uint64_t tick, world_rect r, world *w,
                   int32_t *scratch, store_cancel *cancel, error_text *why)
{
    if (rebuild_base(base, r, w, scratch, why) != 0)
        return -1;
    /* keyframes and the whole log both need every record since the first */
    char first[1100];
    store_segment_path(dir, 1, first, sizeof first);
    int whole = access(first, F_OK) == 0;
    if (tick == 0) { /* before the first tick: the base (a cursor reads on from segment 1) */
        if (!whole)
            error_set(why, "store: tick 0: the log's first segment was compacted away");
        return whole ? 0 : 1;
    }
    int rc = whole ? replay_from_keyframes(dir, w, tick, r, cancel, why) : 1;
    if (rc == 1) {
        recover_args a = {
            .dir = dir,
            .w = w,
            .upto_tick = tick,
            .flags = whole ? STORE_RECOVER_NO_TILES : 0,
            .clip = &r,
            .cancel = cancel,
        };
        uint64_t last_seq;
        store_recovery rec;
        rc = 0;
        if (store_recover(&a, &last_seq, &rec, why) != 0)         /* store_tile_load's refusal */
            rc = strstr(why->message, "compacted away") ? 1 : -1; /* of a newer snapshot */
    }
    if (rc != 0 && store_cancel_now(cancel)) {
        error_set(why, "store: cancelled");
        rc = STORE_CANCELLED;
    }
    return rc;
}

/* One rebuild; 0, 1 (gone), -1 or STORE_CANCELLED. */
static int replay_once(const char *dir, const world *base, uint64_t tick, world_rect r,
                       int32_t *dst, store_cancel *cancel, error_text *why)
{
    world w;
    int rc = rebuild(dir, base, tick, r, &w, dst, cancel, why);
    if (rc == 0)
        world_gather_window(&w, r, dst);
    world_free(&w);
    return rc;
}

/* The caller's cancel, or one that never says stop: the store's own copy (its seen). */
static store_cancel cancel_copy(const store_cancel *cancel)
{
    return cancel ? (store_cancel){.cancelled = cancel->cancelled, .ctx = cancel->ctx}
                  : (store_cancel){0};
}

int store_replay_rect(const char *dir, const world *base, uint64_t tick, world_rect r, int32_t *dst,
                      const store_cancel *cancel, error_text *why)
{
    store_cancel c = cancel_copy(cancel);
    /* a compaction may delete a segment or replace a snapshot between the
     * listing and the read: the next try sees the directory after it (a
     * cancelled rebuild is not tried again) */
    int rc = -1;
    for (int attempt = 0; attempt < 3 && rc == -1; attempt++) {
        memset(why, 0, sizeof *why);
        rc = replay_once(dir, base, tick, r, dst, &c, why);
    }
    return rc;
}

int store_replay_world(const char *dir, const world *base, uint64_t tick, world_rect r, world *out,
                       const store_cancel *cancel, error_text *why)
{
    store_cancel c = cancel_copy(cancel);
    int32_t *scratch = malloc((size_t)r.w * r.h * sizeof *scratch + 1);
    if (!scratch) {
        error_set(why, "store: out of memory for a rebuild of %d x %d cells", r.w, r.h);
        return -1;
    }
    int rc = -1;
    for (int attempt = 0; attempt < 3 && rc == -1; attempt++) { /* as store_replay_rect */
        memset(why, 0, sizeof *why);
        memset(out, 0, sizeof *out);
        rc = rebuild(dir, base, tick, r, out, scratch, &c, why);
        if (tick == 0 && rc == 1)
            rc = 0; /* the base needs no log */
        if (rc != 0)
            world_free(out);
    }
    free(scratch);
    return rc;
}

/* ---- a cursor: the world as of a tick, then forward record by record ----
 * (a spectator, PROTOCOL.md "spectate"). It keeps the segment it reads open:
 * a compaction that deletes it meanwhile leaves the open file readable. */

struct store_cursor {
    char dir[1024];
    world w;
    world_rect r;
    uint64_t tick; /* the world holds r as of the end of this tick */
    uint64_t seq;  /* the segment being read (0: none yet) */
    int fd;
    uint64_t at;      /* the next record's offset in it */
    uint8_t *payload; /* the record next returned, not applied yet (pending) */
    int64_t payload_cap;
    uint32_t payload_len;
    uint64_t pending_tick;
    int pending;
    world_rect *rects;
    int64_t rects_cap;
    store_record rec;
    store_cancel cancel; /* its reader's (cancelled NULL: never) */
    /* a backend's history (store_history_cursor) instead of a directory */
    const store_history_ops *ops;
    void *reader;
    const uint8_t *data; /* the record next returned (payload, or the reader's) */
    int peeked;          /* the reader returned data (its tick pending_tick), not handed out yet */
};

/* Opens segment seq (0, or -1 when it is not there). */
static int cursor_open_segment(store_cursor *c, uint64_t seq)
{
    char path[1200];
    store_segment_path(c->dir, seq, path, sizeof path);
    int fd = open(path, O_RDONLY | O_CLOEXEC);
    if (fd < 0)
        return -1;
    if (c->fd >= 0)
        close(c->fd);
    c->fd = fd, c->seq = seq, c->at = WAL_HEADER;
    return 0;
}

/* The record header at the cursor: 1 with its tick and payload length, 0
 * when none is there (yet: the end, or a record being written). */
static int cursor_header(store_cursor *c, uint64_t *tick, uint32_t *plen)
{
    uint8_t h[REC_HEADER];
    if (c->fd < 0 || pread(c->fd, h, sizeof h, (off_t)c->at) != (ssize_t)sizeof h)
        return 0;
    if (get32(h) != REC_MAGIC || get32(h + 20) != store_crc32c(0, h, 20) ||
        get32(h + 4) > REC_MAX_PAYLOAD)
        return 0;
    *plen = get32(h + 4);
    *tick = get64(h + 8);
    return 1;
}

/* After the rebuild: the first record after c->tick (segments whose records
 * are all at or before it skipped, then headers only). 0 or -1. */
static int cursor_seek(store_cursor *c, error_text *why)
{
    uint64_t *seqs = NULL;
    int count = 0;
    if (store_list_segments(c->dir, &seqs, &count) != 0) {
        error_set(why, "store: cannot list the segments of %s", c->dir);
        return -1;
    }
    int i = 0;
    char path[1200];
    while (i + 1 < count) {
        store_segment_path(c->dir, seqs[i + 1], path, sizeof path);
        uint64_t next_first = segment_first_tick(path);
        if (next_first == UINT64_MAX || next_first > c->tick + 1)
            break;
        i++; /* every record of segment i is at or before the tick */
    }
    int rc = count && cursor_open_segment(c, seqs[i]) != 0 ? -1 : 0;
    free(seqs);
    if (rc != 0) {
        error_set(why, "store: a log segment of %s went during the rebuild", c->dir);
        return -1;
    }
    uint64_t t;
    uint32_t plen;
    while (cursor_header(c, &t, &plen) && t <= c->tick) /* headers of one segment: quick */
        c->at += REC_HEADER + plen;
    return 0;
}

/* A cursor of r at tick, before its rebuild, and the rebuild's scratch
 * (r's cells, the caller's to free); NULL (why) out of memory. */
static store_cursor *cursor_new(world_rect r, uint64_t tick, const store_cancel *cancel,
                                int32_t **scratch, error_text *why)
{
    store_cursor *c = calloc(1, sizeof *c);
    *scratch = malloc((size_t)r.w * r.h * sizeof **scratch + 1);
    if (!c || !*scratch) {
        free(c);
        free(*scratch);
        error_set(why, "store: out of memory for a replay cursor");
        return NULL;
    }
    c->fd = -1, c->r = r, c->tick = tick;
    c->rec.clip = r; /* every record from here on: only r's cells */
    c->cancel = cancel_copy(cancel);
    return c;
}

int store_cursor_open(const char *dir, const world *base, uint64_t tick, world_rect r,
                      const store_cancel *cancel, store_cursor **out, error_text *why)
{
    int32_t *scratch = NULL;
    store_cursor *c = cursor_new(r, tick, cancel, &scratch, why);
    *out = NULL;
    if (!c)
        return -1;
    snprintf(c->dir, sizeof c->dir, "%s", dir);
    int rc = -1;
    for (int attempt = 0; attempt < 3 && rc == -1; attempt++) { /* as store_replay_rect */
        memset(why, 0, sizeof *why);
        if (attempt) {
            world_free(&c->w);
            memset(&c->w, 0, sizeof c->w);
        }
        rc = rebuild(dir, base, tick, r, &c->w, scratch, &c->cancel, why);
        if (rc == 0 && cursor_seek(c, why) != 0)
            rc = -1;
    }
    free(scratch);
    if (rc != 0) {
        world_free(&c->w);
        if (c->fd >= 0)
            close(c->fd);
        free(c);
        return rc;
    }
    *out = c;
    return 0;
}

void store_cursor_read(const store_cursor *c, world_rect r, int32_t *dst)
{
    world_gather_window(&c->w, r, dst);
}

static void add_cells(void *ctx, int tx, int ty, world_rect cells, uint64_t generation)
{
    (void)tx, (void)ty, (void)generation;
    *(int64_t *)ctx += (int64_t)cells.w * cells.h;
}

int64_t store_cursor_cells(const store_cursor *c, uint64_t *bytes)
{
    int64_t cells = 0;
    world_for_each_stored_tile(&c->w, add_cells, &cells);
    if (bytes) {
        *bytes = world_resident_bytes(&c->w);
        for (world_layer_id i = 0; i < WORLD_LAYERS; i++)
            *bytes += world_layer_bytes(&c->w, i);
    }
    return cells;
}

uint64_t store_cursor_tick(const store_cursor *c)
{
    return c->tick;
}

/* At the end of segment seq: the next one, if there is one. 1 moved (or a
 * record came at the end of seq meanwhile), 0 not yet, -1 a gap (compacted
 * away: why says so). */
static int cursor_next_segment(store_cursor *c, error_text *why)
{
    uint64_t *seqs = NULL;
    int count = 0, rc = 0;
    if (store_list_segments(c->dir, &seqs, &count) != 0) {
        error_set(why, "store: cannot list the segments of %s", c->dir);
        return -1;
    }
    /* the sim thread finishes a segment's last record before it starts the
     * next one: a record written between the caller's look at the header and
     * this listing is read before moving on, never skipped */
    uint64_t t;
    uint32_t plen;
    if (cursor_header(c, &t, &plen)) {
        free(seqs);
        return 1;
    }
    for (int i = 0; i < count && rc == 0; i++)
        if (seqs[i] > c->seq) {
            rc = seqs[i] == c->seq + 1 && cursor_open_segment(c, seqs[i]) == 0 ? 1 : -1;
            if (rc < 0)
                error_set(why, "store: the log after tick %llu was compacted away",
                          (unsigned long long)c->tick);
        }
    free(seqs);
    return rc;
}

/* The record in c->data (plen bytes, of tick t) becomes the pending one:
 * its rectangles parsed for the caller. 1, or -1 (why). */
static int cursor_take(store_cursor *c, uint64_t t, uint32_t plen, uint64_t *tick,
                       const world_rect **rects, int *n, error_text *why)
{
    uint32_t nrect = plen >= 4 ? get32(c->data) & ~STORE_RECORD_LAYER_BITS : 0;
    if ((uint64_t)nrect * 16 + 8 > plen ||
        array_grow((void **)&c->rects, &c->rects_cap, (int64_t)nrect + 1, sizeof *c->rects) != 0) {
        error_set(why, "store: a malformed record of tick %llu", (unsigned long long)t);
        return -1;
    }
    for (uint32_t i = 0; i < nrect; i++) {
        const uint8_t *q = c->data + 4 + 16 * i;
        c->rects[i] = (world_rect){(int32_t)get32(q), (int32_t)get32(q + 4), (int32_t)get32(q + 8),
                                   (int32_t)get32(q + 12)};
    }
    c->payload_len = plen;
    c->pending_tick = t;
    c->pending = 1;
    c->peeked = 0;
    *tick = t;
    *rects = c->rects;
    *n = (int)nrect;
    return 1;
}

/* store_cursor_next over a backend's reader: the record it returned last
 * (peeked: past the rebuild's tick, or past upto) first. */
static int history_next(store_cursor *c, uint64_t upto, uint64_t *tick, const world_rect **rects,
                        int *n, error_text *why)
{
    if (!c->peeked) {
        size_t len = 0;
        int rc = c->ops->next(c->reader, &c->pending_tick, &c->data, &len, why);
        if (rc <= 0)
            return rc;
        if (len > REC_MAX_PAYLOAD) {
            error_set(why, "store: a record of tick %llu is too large",
                      (unsigned long long)c->pending_tick);
            return -1;
        }
        c->payload_len = (uint32_t)len;
        c->peeked = 1;
    }
    if (c->pending_tick > upto)
        return 0;
    return cursor_take(c, c->pending_tick, c->payload_len, tick, rects, n, why);
}

int store_cursor_next(store_cursor *c, uint64_t upto, uint64_t *tick, const world_rect **rects,
                      int *n, error_text *why)
{
    uint64_t t;
    uint32_t plen;
    if (c->pending) {
        error_set(why, "store: the cursor's record was not applied");
        return -1;
    }
    if (store_cancel_now(&c->cancel)) {
        error_set(why, "store: cancelled");
        return STORE_CANCELLED;
    }
    if (c->ops)
        return history_next(c, upto, tick, rects, n, why);
    while (!cursor_header(c, &t, &plen)) {
        int moved = cursor_next_segment(c, why);
        if (moved <= 0) /* a header at the end of the newest segment: not yet written */
            return moved;
    }
    if (t > upto)
        return 0;
    if (array_grow((void **)&c->payload, &c->payload_cap, (int64_t)plen + 1, 1) != 0) {
        error_set(why, "store: out of memory for a log record");
        return -1;
    }
    uint8_t h[REC_HEADER];
    if (pread(c->fd, h, sizeof h, (off_t)c->at) != (ssize_t)sizeof h ||
        pread(c->fd, c->payload, plen, (off_t)(c->at + REC_HEADER)) != (ssize_t)plen ||
        store_crc32c(0, c->payload, plen) != get32(h + 16))
        return 0; /* still being written */
    c->data = c->payload;
    return cursor_take(c, t, plen, tick, rects, n, why);
}

int store_cursor_apply(store_cursor *c, error_text *why)
{
    if (!c->pending)
        return 0;
    int rc = store_record_apply(&c->rec, &c->w, c->data, c->payload_len, NULL, NULL);
    if (rc != 0) {
        error_set(why, "store: the record of tick %llu %s", (unsigned long long)c->pending_tick,
                  rc > 0 ? "is malformed" : "needs more memory than there is");
        return -1;
    }
    if (!c->ops)
        c->at += REC_HEADER + c->payload_len;
    c->tick = c->pending_tick;
    c->pending = 0;
    return 0;
}

void store_cursor_close(store_cursor *c)
{
    if (!c)
        return;
    if (c->fd >= 0)
        close(c->fd);
    if (c->reader)
        c->ops->close(c->reader);
    world_free(&c->w);
    store_record_free(&c->rec);
    free(c->payload);
    free(c->rects);
    free(c);
}

/* ---- a backend's history (store.h "a world's past"): the same cursor ---- */

int store_history_kept(const store_history *h)
{
    return h && (h->dir || h->ops);
}

void store_history_release(store_history *h)
{
    if (h && h->ops && h->ops->release)
        h->ops->release(h->ctx);
    if (h)
        memset(h, 0, sizeof *h);
}

/* The reader's state at or before tick, then its records up to the tick;
 * a record past it stays peeked for the first store_cursor_next. 0, 1
 * (gone), -1, STORE_CANCELLED. */
static int history_rebuild(store_cursor *c, const store_history *h, const world *base,
                           uint64_t tick, int32_t *scratch, error_text *why)
{
    if (rebuild_base(base, c->r, &c->w, scratch, why) != 0)
        return -1;
    int rc = h->ops->open(h->ctx, &c->w, tick, &c->rec, &c->cancel, &c->reader, why);
    while (rc == 0) {
        size_t len = 0;
        if (store_cancel_now(&c->cancel)) {
            rc = -1;
            break;
        }
        int got = h->ops->next(c->reader, &c->pending_tick, &c->data, &len, why);
        if (got <= 0) {
            rc = got; /* 0: every record up to the tick is applied (it is not in the future) */
            break;
        }
        if (len > REC_MAX_PAYLOAD) {
            error_set(why, "store: a record of tick %llu is too large",
                      (unsigned long long)c->pending_tick);
            rc = -1;
        } else if (c->pending_tick > tick) {
            c->payload_len = (uint32_t)len;
            c->peeked = 1;
            break;
        } else if ((got = store_record_apply(&c->rec, &c->w, c->data, len, NULL, NULL)) != 0) {
            error_set(why, "store: the record of tick %llu %s", (unsigned long long)c->pending_tick,
                      got > 0 ? "is malformed" : "needs more memory than there is");
            rc = -1;
        }
    }
    if (rc != 0 && store_cancel_now(&c->cancel)) {
        error_set(why, "store: cancelled");
        rc = STORE_CANCELLED;
    }
    return rc;
}

int store_history_cursor(const store_history *h, const world *base, uint64_t tick, world_rect r,
                         const store_cancel *cancel, store_cursor **out, error_text *why)
{
    if (h->dir)
        return store_cursor_open(h->dir, base, tick, r, cancel, out, why);
    int32_t *scratch = NULL;
    store_cursor *c = cursor_new(r, tick, cancel, &scratch, why);
    *out = NULL;
    if (!c)
        return -1;
    c->ops = h->ops;
    int rc = -1;
    /* a compaction may purge what the reader was about to read: try again */
    for (int attempt = 0; attempt < 3 && rc == -1; attempt++) {
        memset(why, 0, sizeof *why);
        if (attempt) {
            if (c->reader)
                c->ops->close(c->reader);
            c->reader = NULL, c->peeked = 0;
            world_free(&c->w);
            memset(&c->w, 0, sizeof c->w);
        }
        rc = history_rebuild(c, h, base, tick, scratch, why);
    }
    free(scratch);
    if (rc != 0) {
        store_cursor_close(c);
        return rc;
    }
    *out = c;
    return 0;
}

int store_history_rect(const store_history *h, const world *base, uint64_t tick, world_rect r,
                       int32_t *dst, const store_cancel *cancel, error_text *why)
{
    if (h->dir)
        return store_replay_rect(h->dir, base, tick, r, dst, cancel, why);
    if (tick == 0) {
        world_base_fill_rect(base, r, dst);
        return 0;
    }
    store_cursor *c = NULL;
    int rc = store_history_cursor(h, base, tick, r, cancel, &c, why);
    if (rc == 0)
        store_cursor_read(c, r, dst);
    store_cursor_close(c);
    return rc;
}

int store_history_world(const store_history *h, const world *base, uint64_t tick, world_rect r,
                        world *out, const store_cancel *cancel, error_text *why)
{
    if (h->dir)
        return store_replay_world(h->dir, base, tick, r, out, cancel, why);
    memset(out, 0, sizeof *out);
    store_cursor *c = NULL;
    int rc = store_history_cursor(h, base, tick, r, cancel, &c, why);
    if (rc == 1 && tick == 0) { /* the base needs no log */
        int32_t *scratch = malloc((size_t)r.w * r.h * sizeof *scratch + 1);
        rc = scratch ? rebuild_base(base, r, out, scratch, why) : -1;
        if (!scratch)
            error_set(why, "store: out of memory for a rebuild of %d x %d cells", r.w, r.h);
        free(scratch);
        return rc;
    }
    if (rc == 0) { /* the cursor's world is the answer */
        *out = c->w;
        memset(&c->w, 0, sizeof c->w);
    }
    store_cursor_close(c);
    return rc;
}
