/*
 * store_log.c: the data directory's write-ahead log — segments of records,
 * one record per committed tick (its changed rectangles and their new
 * absolute values, zstd compressed, CRC32C checked) — and recovery.
 *
 * Records hold absolute values, not differences, so replaying a record twice,
 * or a record older than a tile snapshot followed by the newer ones, gives the
 * same heights: recovery simply replays every segment still present, in
 * order, over the snapshots. Recovery runs before the first tick; a segment
 * is started on the sim thread (at open, and when compaction leaves the old
 * one behind).
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "store/store_internal.h"

/* A record at `at` whose header and payload checksums hold: its length, or 0. */
static size_t record_at(const uint8_t *data, size_t len, size_t at, uint64_t *tick)
{
    if (len - at < REC_HEADER)
        return 0;
    const uint8_t *h = data + at;
    uint32_t plen = get32(h + 4);
    if (get32(h) != REC_MAGIC || get32(h + 20) != store_crc32c(0, h, 20) ||
        plen > REC_MAX_PAYLOAD || len - at - REC_HEADER < plen ||
        store_crc32c(0, h + REC_HEADER, plen) != get32(h + 16))
        return 0;
    *tick = get64(h + 8);
    return REC_HEADER + plen;
}

/* After a bad record: are there good records further on? A crash can only
 * tear the end of what was being written, so any good record after the bad
 * one means the bad one is damage in the middle of the log. */
static void scan_after(const uint8_t *data, size_t len, size_t from, replay_result *res)
{
    for (size_t at = from; at + REC_HEADER <= len;) {
        uint64_t tick;
        size_t n = record_at(data, len, at, &tick);
        if (!n) {
            at++;
            continue;
        }
        res->later_records++;
        if (tick > res->later_max_tick)
            res->later_max_tick = tick;
        at += n;
    }
}

/* While a record is checked: the tiles its rectangles touch are changed. */
typedef struct mark_ctx {
    uint8_t *changed;
    int tiles_x;
} mark_ctx;

static int mark_tiles(void *ctx, world_rect r)
{
    mark_ctx *m = ctx;
    if (m->changed)
        for (int ty = r.y / STORE_TILE_SIZE; ty <= (r.y + r.h - 1) / STORE_TILE_SIZE; ty++)
            for (int tx = r.x / STORE_TILE_SIZE; tx <= (r.x + r.w - 1) / STORE_TILE_SIZE; tx++)
                m->changed[ty * m->tiles_x + tx] = 1;
    return 0;
}

/* Apply every good record of one segment to w (and mark changed tiles); with
 * w NULL only count them. Stops at the first record that is torn or fails its
 * checksum, then looks for good records after it (res->later_records). */
int store_segment_replay(const char *path, world *w, const world_rect *clip, uint8_t *changed,
                         uint64_t after_tick, uint64_t upto_tick, store_cancel *cancel,
                         replay_result *res, error_text *err)
{
    memset(res, 0, sizeof *res);
    res->last_tick = after_tick;
    uint8_t *data;
    size_t len;
    if (store_file_read(path, "log segment ", &data, &len, err) != 0)
        return -1;
    res->file_len = (int64_t)len;
    if (len < WAL_HEADER || memcmp(data, WAL_MAGIC, 8) != 0 ||
        get32(data + 16) != store_crc32c(0, data, 16)) {
        snprintf(res->problem, sizeof res->problem, "torn or corrupt segment header");
        free(data);
        return 0;
    }
    res->header_ok = 1;
    size_t at = WAL_HEADER;
    res->good_len = WAL_HEADER;
    store_record rec = {.clip = clip ? *clip : (world_rect){0, 0, 0, 0}};
    mark_ctx mark = {changed, (w ? w->width + STORE_TILE_SIZE - 1 : 0) / STORE_TILE_SIZE};
    while (at < len) {
        if (!w) { /* count only */
            uint64_t tick;
            size_t n = record_at(data, len, at, &tick);
            if (!n) {
                snprintf(res->problem, sizeof res->problem,
                         "record at offset %zu is torn or fails its checksum", at);
                break;
            }
            res->records++;
            res->last_tick = tick;
            at += n;
            res->good_len = (int64_t)at;
            continue;
        }
        if (store_cancel_now(cancel)) { /* a record's work at most after its reader stops */
            error_set(err, "store: cancelled");
            store_record_free(&rec);
            free(data);
            return -1;
        }
        if (len - at < REC_HEADER) {
            snprintf(res->problem, sizeof res->problem, "torn record header at offset %zu", at);
            break;
        }
        const uint8_t *h = data + at;
        uint32_t plen = get32(h + 4);
        uint64_t tick = get64(h + 8);
        if (get32(h) != REC_MAGIC || get32(h + 20) != store_crc32c(0, h, 20) ||
            plen > REC_MAX_PAYLOAD) {
            snprintf(res->problem, sizeof res->problem,
                     "record header at offset %zu fails its checksum", at);
            break;
        }
        if (len - at - REC_HEADER < plen) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu is torn (%u payload bytes, %zu present)",
                     (unsigned long long)tick, at, plen, len - at - REC_HEADER);
            break;
        }
        const uint8_t *p = h + REC_HEADER;
        if (upto_tick && tick > upto_tick)
            break; /* a rebuild as of an earlier tick: the rest is not wanted */
        if (store_crc32c(0, p, plen) != get32(h + 16)) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu fails its payload checksum",
                     (unsigned long long)tick, at);
            break;
        }
        /* checksummed, so a malformed payload is a writer bug: still refuse it */
        int applied =
            tick > res->last_tick ? store_record_apply(&rec, w, p, plen, mark_tiles, &mark) : 1;
        if (applied > 0) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu is malformed", (unsigned long long)tick,
                     at);
            break;
        }
        if (applied < 0) {
            error_set(err, "store: out of memory for the per-cell state replaying %s", path);
            store_record_free(&rec);
            free(data);
            return -1;
        }
        res->records++;
        res->last_tick = tick;
        at += REC_HEADER + plen;
        res->good_len = (int64_t)at;
    }
    if (res->problem[0])
        scan_after(data, len, at + 1, res);
    store_record_free(&rec);
    free(data);
    return 0;
}

int store_cancel_now(store_cancel *c)
{
    if (c && !c->seen && c->cancelled && c->cancelled(c->ctx))
        c->seen = 1;
    return c && c->seen;
}

static int compare_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* The log segments' sequence numbers, ascending. */
int store_list_segments(const char *dir, uint64_t **seqs, int *count)
{
    *seqs = NULL;
    *count = 0;
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    int64_t cap = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        unsigned long long seq;
        char tail[8];
        if (sscanf(e->d_name, "wal-%16llu.%7s", &seq, tail) == 2 && strcmp(tail, "log") == 0) {
            if (array_grow((void **)seqs, &cap, (int64_t)*count + 1, sizeof **seqs) != 0) {
                closedir(d);
                return -1;
            }
            (*seqs)[(*count)++] = seq;
        }
    }
    closedir(d);
    if (*count > 1)
        qsort(*seqs, (size_t)*count, sizeof **seqs, compare_u64);
    return 0;
}

void store_segment_path(const char *dir, uint64_t seq, char *out, size_t cap)
{
    snprintf(out, cap, "%s/wal-%016llu.log", dir, (unsigned long long)seq);
}

/* Start segment seq: header written and synced, directory synced. */
int store_segment_start(store_dir *st, uint64_t seq, error_text *err)
{
    char path[1100];
    store_segment_path(st->dir, seq, path, sizeof path);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        error_set(err, "store: cannot create %s: %s", path, strerror(errno));
        return -1;
    }
    uint8_t h[WAL_HEADER] = {0};
    memcpy(h, WAL_MAGIC, 8);
    put64(h + 8, seq);
    put32(h + 16, store_crc32c(0, h, 16));
    if (store_dir_write_all(st, fd, h, sizeof h) != 0 || store_dir_fdatasync(st, fd) != 0 ||
        store_dir_fsync(st->dir) != 0) {
        error_set(err, "store: cannot start %s: %s", path, strerror(errno));
        close(fd);
        unlink(path);
        return -1;
    }
    if (st->wal_fd >= 0)
        close(st->wal_fd);
    st->wal_fd = fd;
    st->wal_seq = seq;
    st->wal_len = WAL_HEADER;
    return 0;
}
