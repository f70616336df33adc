/*
 * store_dir.c: the data-directory backend (store_internal.h) — opening and
 * recovering a directory, appending a tick's record to the current log
 * segment, syncing by the durability policy, and the failure state that
 * refuses deformation while the directory cannot be written. Every entry
 * runs on the sim thread, in the tick's commit step (docs/design.md); the
 * snapshots are left to the compaction thread (store_compaction.c).
 */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include "metrics/metrics.h"
#include "store/store_internal.h"

/* ---- files ---- */

int store_dir_fault_active(const store_dir *st)
{
    return st->fault[0] && access(st->fault, F_OK) == 0 && !store_dir_fault_is_fsync(st);
}

/* The fault file holding "fsync": writes work, every fdatasync of the log fails EIO. */
int store_dir_fault_is_fsync(const store_dir *st)
{
    if (!st->fault[0])
        return 0;
    FILE *f = fopen(st->fault, "r");
    char word[8] = {0};
    int yes = f && fread(word, 1, 5, f) == 5 && memcmp(word, "fsync", 5) == 0;
    if (f)
        fclose(f);
    return yes;
}

int store_dir_fdatasync(const store_dir *st, int fd)
{
    if (st && store_dir_fault_is_fsync(st)) {
        errno = EIO;
        return -1;
    }
    return fdatasync(fd);
}

/*
 * A failed fdatasync of the log is never retried into a success (fsyncgate:
 * Linux reports a writeback error once, then marks the pages clean, so the
 * next fdatasync "succeeds" without the data being on disk). Records written
 * since the last good sync may be lost; when any of them is a tick held back
 * for it (group commit), nothing of those ticks has been published, and the
 * daemon stops here — a restart recovers from what is durable, as PostgreSQL
 * panics. Every-tick mode never gets here: its one unsynced record is cut and
 * its tick undone by the caller.
 */
void store_dir_sync_failed_fatal(const store_dir *st, int e)
{
    if (st->durable_tick == st->appended_tick)
        return;
    log_error("store: fdatasync of the log failed (%s, %s): ticks %llu..%llu were written but "
              "may not be on disk; none of them was published. Stopping now so that a restart "
              "recovers from what is durable (a retried fdatasync cannot be trusted)",
              strerror(e), st->dir, (unsigned long long)st->durable_tick + 1,
              (unsigned long long)st->appended_tick);
    _exit(70); /* EX_SOFTWARE: no clean-up may sync or publish anything more */
}

int store_dir_write_all(const store_dir *st, int fd, const void *data, size_t len)
{
    if (st && store_dir_fault_active(st)) {
        errno = ENOSPC;
        return -1;
    }
    const uint8_t *p = data;
    while (len > 0) {
        ssize_t n = write(fd, p, len);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            return -1;
        }
        p += n;
        len -= (size_t)n;
    }
    return 0;
}

int store_dir_fsync(const char *dir)
{
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    if (fd < 0)
        return -1;
    int rc = fsync(fd);
    close(fd);
    return rc;
}

int store_dir_write_atomic(const store_dir *st, const char *dir, const char *name, const void *a,
                           size_t alen, const void *b, size_t blen, error_text *err)
{
    char path[1200], tmp[1210];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        error_set(err, "store: cannot create %s: %s", tmp, strerror(errno));
        return -1;
    }
    if (store_dir_write_all(st, fd, a, alen) != 0 ||
        (blen && store_dir_write_all(st, fd, b, blen) != 0) || fsync(fd) != 0) {
        error_set(err, "store: writing %s: %s", tmp, strerror(errno));
        close(fd);
        unlink(tmp);
        return -1;
    }
    close(fd);
    if (rename(tmp, path) != 0 || store_dir_fsync(dir) != 0) {
        error_set(err, "store: renaming %s to %s: %s", tmp, path, strerror(errno));
        unlink(tmp);
        return -1;
    }
    return 0;
}

/* ---- open / close ---- */

static void dir_close(void *state);
static int dir_append_tick(void *state, const world *w, uint64_t tick, const world_rect *rects,
                           int n);

/* The manifest: checked, or written for a new directory. A directory that
 * holds data without one is damage (refused unless truncating). */
static int dir_open_manifest(store_dir *st, const world *w, error_text *err)
{
    char path[1100];
    uint32_t base_crc = store_base_identity(w);
    snprintf(path, sizeof path, "%s/MANIFEST", st->dir);
    if (access(path, F_OK) == 0)
        return store_manifest_check(path, w, base_crc, err);
    if (store_dir_has_data(st->dir)) {
        if (!st->cfg.recover_truncate) {
            error_set(err,
                      "store: refusing to start: %s is missing next to existing data (nothing "
                      "says which world it belongs to; --recover-truncate writes one)",
                      path);
            return -1;
        }
        log_error("store: damage: %s is missing next to existing data; --recover-truncate: "
                  "writing one for this scene and starting anyway",
                  path);
    }
    char *text = store_manifest_text(w, base_crc);
    int rc =
        text ? store_dir_write_atomic(NULL, st->dir, "MANIFEST", text, strlen(text), NULL, 0, err)
             : -1;
    free(text);
    return rc;
}

/* Manifest, CONTROL, recovery, a fresh segment and a new CONTROL. */
static int dir_open_recover(store_dir *st, world *w, store_recovery *rec, error_text *err)
{
    int had_data = store_dir_has_data(st->dir);
    if (dir_open_manifest(st, w, err) != 0)
        return -1;
    store_control old;
    if (store_control_init(&old, st->tiles_x, st->tiles_y) != 0) {
        error_set(err, "store: out of memory");
        return -1;
    }
    int truncate = st->cfg.recover_truncate;
    int have = store_control_read(st->dir, &old, err);
    int rc = -1;
    if (have == 1 && had_data) {
        error_set(err, "store: refusing to start: %s/CONTROL is missing next to existing data",
                  st->dir);
        have = -1;
    }
    if (have < 0 && !truncate)
        goto out;
    if (have < 0)
        log_error("%s; --recover-truncate: recovering without it", err->message);
    recover_args a = {.dir = st->dir,
                      .w = w,
                      .changed = st->changed,
                      .flags = STORE_RECOVER_REPAIR | STORE_RECOVER_CHECK |
                               (truncate ? STORE_RECOVER_TRUNCATE : 0),
                      .ctl = have == 0 ? &old : NULL,
                      .found = &st->ctl};
    uint64_t last_seq = 0;
    if (store_recover(&a, &last_seq, rec, err) != 0)
        goto out;
    st->appended_tick = st->durable_tick = st->seen_tick = rec->tick;
    /* a fresh segment: nothing is ever appended after a possibly cut tail */
    if (store_segment_start(st, last_seq + 1, err) != 0)
        goto out;
    if (!st->ctl.first_seq)
        st->ctl.first_seq = st->wal_seq;
    st->ctl.last_seq = st->wal_seq;
    st->ctl.tick = rec->tick;
    rc = store_control_save(st, err);
out:
    store_control_free(&old);
    return rc;
}

static void *dir_open(const store_config *c, world *w, store_recovery *rec, error_text *err)
{
    store_dir *st = calloc(1, sizeof *st);
    if (!st) {
        error_set(err, "store: out of memory");
        return NULL;
    }
    st->cfg = *c;
    if (st->cfg.segment_bytes <= 0)
        st->cfg.segment_bytes = 16 << 20;
    if (st->cfg.compression_level <= 0)
        st->cfg.compression_level = 3;
    st->lock_fd = st->wal_fd = -1;
    pthread_mutex_init(&st->lock, NULL);
    pthread_cond_init(&st->cond, NULL);
    pthread_mutex_init(&st->ctl_lock, NULL);
    snprintf(st->dir, sizeof st->dir, "%s", c->dir);
    if (c->fault_path)
        snprintf(st->fault, sizeof st->fault, "%s", c->fault_path);
    st->width = w->width;
    st->height = w->height;
    st->tiles_x = (w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    st->tiles_y = (w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    st->changed = calloc((size_t)st->tiles_x * st->tiles_y, 1);
    st->cctx = ZSTD_createCCtx();
    if (!st->changed || !st->cctx || store_control_init(&st->ctl, st->tiles_x, st->tiles_y) != 0) {
        error_set(err, "store: out of memory");
        goto fail;
    }
    char tiles_dir[1100], path[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", st->dir);
    const char *made = st->dir;
    if ((mkdir(st->dir, 0755) != 0 && errno != EEXIST) ||
        (made = tiles_dir, mkdir(tiles_dir, 0755) != 0 && errno != EEXIST)) {
        error_set(err, "store: --data: cannot create %s: %s", made, strerror(errno));
        goto fail;
    }
    snprintf(path, sizeof path, "%s/LOCK", st->dir);
    st->lock_fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (st->lock_fd < 0 || flock(st->lock_fd, LOCK_EX | LOCK_NB) != 0) {
        error_set(err, "store: %s: %s", path,
                  errno == EWOULDBLOCK ? "the data directory is in use by another terrad"
                                       : strerror(errno));
        goto fail;
    }
    if (dir_open_recover(st, w, rec, err) != 0)
        goto fail;
    st->last_sync_ms = time_now_ms();
    if (pthread_create(&st->thread, NULL, store_compaction_main, st) == 0)
        st->thread_started = 1;
    metrics_set_store_recovery(rec->ms, rec->records_replayed, rec->bytes_cut);
    metrics_set_store_durable_tick(st->durable_tick);
    metrics_set_store_available(1);
    return st;
fail:
    dir_close(st);
    return NULL;
}

static void dir_close(void *state)
{
    store_dir *st = state;
    if (!st)
        return;
    store_compaction_stop(st);
    if (st->wal_fd >= 0) {
        /* the last tick, even one that changed nothing, so the next start
         * goes on after it; then CONTROL says it is durable */
        if (!st->failed && st->seen_tick > st->appended_tick)
            dir_append_tick(st, NULL, st->seen_tick, NULL, 0);
        error_text err = {{0}};
        int synced = !st->failed && store_dir_fdatasync(st, st->wal_fd) == 0;
        if (!st->failed && !synced)
            store_dir_sync_failed_fatal(st, errno);
        if (synced) {
            pthread_mutex_lock(&st->ctl_lock);
            st->ctl.tick = st->appended_tick;
            pthread_mutex_unlock(&st->ctl_lock);
            if (store_control_save(st, &err) != 0)
                log_error("%s", err.message);
        }
        close(st->wal_fd);
    }
    if (st->lock_fd >= 0)
        close(st->lock_fd); /* releases the flock */
    pthread_mutex_destroy(&st->lock);
    pthread_cond_destroy(&st->cond);
    pthread_mutex_destroy(&st->ctl_lock);
    store_control_free(&st->ctl);
    ZSTD_freeCCtx(st->cctx);
    free(st->changed);
    store_record_free(&st->rec);
    free(st);
}

/* ---- the tick ---- */

/* The failure is logged once, then at most every FAIL_LOG_MS (with how many
 * were not logged): a full disk must not fill the log too. */
#define FAIL_LOG_MS 10000.0

static void set_failed(store_dir *st, const char *kind, const char *what, int e)
{
    double now = time_now_ms();
    if (!st->fail_logged_ms || now - st->fail_logged_ms >= FAIL_LOG_MS) {
        log_error("store: %s: %s (%s): new deformation is refused until it can be written "
                  "again; reads go on (%lld failures not logged since the last line)",
                  what, strerror(e), st->dir, (long long)st->fail_unlogged);
        st->fail_logged_ms = now;
        st->fail_unlogged = 0;
    } else {
        st->fail_unlogged++;
    }
    st->failed = 1;
    st->failed_at_ms = time_now_ms();
    snprintf(st->failure, sizeof st->failure, "%s: %s", what, strerror(e));
    metrics_count_store_error(kind);
    metrics_set_store_available(0);
}

/*
 * The free space a retry asks for besides its probe write (issue 20, item 3:
 * on a full tmpfs the 4 KiB probe fitted in the pages the failed record had
 * taken and the truncate gave back, "writable again" was logged, the next
 * record failed, and readiness flapped). Room for a tile snapshot (256 x 256
 * cells, 256 KiB raw) and many ticks' records; at most a quarter of the file
 * system, so a small one can still resume. 0 when there is that room (or the
 * file system does not say), else ENOSPC.
 */
#define RESUME_FREE_BYTES (2.0 * 1048576.0)

static int free_space_short(const store_dir *st)
{
    struct statvfs v;
    if (fstatvfs(st->wal_fd, &v) != 0 || v.f_blocks == 0)
        return 0;
    double unit = v.f_frsize ? (double)v.f_frsize : (double)v.f_bsize;
    double want = RESUME_FREE_BYTES, quarter = (double)v.f_blocks * unit / 4.0;
    if (want > quarter)
        want = quarter;
    return (double)v.f_bavail * unit < want ? ENOSPC : 0;
}

static int dir_writable(void *state)
{
    store_dir *st = state;
    if (!st->failed)
        return 1;
    if (time_now_ms() - st->failed_at_ms < RETRY_MS)
        return 0;
    /* retry: cut back anything a failed write left, then write new bytes
     * (a block past the log's end, synced, then cut again): truncating and
     * syncing need no free space, so only a real write says the disk has room */
    st->failed_at_ms = time_now_ms();
    static const uint8_t probe[4096];
    int ok = ftruncate(st->wal_fd, st->wal_len) == 0 &&
             lseek(st->wal_fd, st->wal_len, SEEK_SET) >= 0 &&
             store_dir_write_all(st, st->wal_fd, probe, sizeof probe) == 0 &&
             store_dir_fdatasync(st, st->wal_fd) == 0;
    int e = errno;
    if (ftruncate(st->wal_fd, st->wal_len) != 0 || lseek(st->wal_fd, st->wal_len, SEEK_SET) < 0)
        ok = 0;
    if (ok && (e = free_space_short(st)) != 0)
        ok = 0; /* the probe fitted in the crumbs: not yet */
    if (!ok) {
        set_failed(st, e == ENOSPC ? "enospc" : "write", "still cannot write the log", e);
        return 0;
    }
    log_info("store: %s is writable again: deformation resumes", st->dir);
    st->failed = 0;
    st->failure[0] = 0;
    metrics_set_store_available(1);
    return 1;
}

static const char *dir_failure(const void *state)
{
    const store_dir *st = state;
    return st->failure;
}

static uint64_t dir_durable_tick(const void *state)
{
    const store_dir *st = state;
    return st->durable_tick;
}

static int sync_now(store_dir *st)
{
    double t0 = time_now_ms();
    if (store_dir_fdatasync(st, st->wal_fd) != 0) {
        int e = errno;
        set_failed(st, "fsync", "fdatasync of the log", e);
        if (st->cfg.durability == STORE_GROUP)
            store_dir_sync_failed_fatal(st, e);
        return -1;
    }
    double now = time_now_ms();
    metrics_observe_store_fsync_ms(now - t0);
    st->last_sync_ms = now;
    st->durable_tick = st->appended_tick;
    st->unsynced = 0;
    metrics_set_store_durable_tick(st->durable_tick);
    return 0;
}

static int dir_append_tick(void *state, const world *w, uint64_t tick, const world_rect *rects,
                           int n)
{
    store_dir *st = state;
    if (st->failed)
        return -1;
    if (tick > st->seen_tick)
        st->seen_tick = tick;
    /* a tick that changed nothing is logged (an empty record) only every
     * STORE_TICK_LOG_EVERY ticks, so a restart never reuses a tick number */
    if (n <= 0 && tick < st->appended_tick + STORE_TICK_LOG_EVERY)
        return 0;
    unsigned layers = store_world_layers(w);
    error_text err = {{0}};
    if (store_record_gather(&st->rec, w, rects, n, layers) != 0) {
        set_failed(st, "memory", "no memory for a log record", ENOMEM);
        return -1;
    }
    size_t plen = store_record_encode(&st->rec, st->cctx, st->cfg.compression_level, rects, n,
                                      layers, st->rec.values, REC_HEADER, &err);
    if (plen == 0) {
        set_failed(st, "compress", err.message, EIO);
        return -1;
    }
    for (int i = 0; i < n; i++) {
        world_rect r = rects[i];
        for (int ty = r.y / STORE_TILE_SIZE; ty <= (r.y + r.h - 1) / STORE_TILE_SIZE; ty++)
            for (int tx = r.x / STORE_TILE_SIZE; tx <= (r.x + r.w - 1) / STORE_TILE_SIZE; tx++)
                st->changed[ty * st->tiles_x + tx] = 1;
    }
    uint8_t *p = st->rec.buf + REC_HEADER;
    uint8_t *h = st->rec.buf;
    put32(h, REC_MAGIC);
    put32(h + 4, (uint32_t)plen);
    put64(h + 8, tick);
    put32(h + 16, store_crc32c(0, p, plen));
    put32(h + 20, store_crc32c(0, h, 20));
    if (store_dir_write_all(st, st->wal_fd, st->rec.buf, REC_HEADER + plen) != 0) {
        int e = errno;
        /* leave the log exactly as it was: a half-written record is cut now (and
         * would be cut as a torn tail by recovery anyway) */
        if (ftruncate(st->wal_fd, st->wal_len) == 0)
            lseek(st->wal_fd, st->wal_len, SEEK_SET);
        set_failed(st, e == ENOSPC ? "enospc" : "write", "appending to the log", e);
        return -1;
    }
    int64_t before = st->wal_len;
    uint64_t before_tick = st->appended_tick;
    st->wal_len += (int64_t)(REC_HEADER + plen);
    st->appended_tick = tick;
    st->unsynced++;
    metrics_count_store_wal_bytes(REC_HEADER + plen);
    if (st->cfg.durability == STORE_EVERY_TICK && sync_now(st) != 0) {
        /* the caller undoes this tick, so its record must not survive to be replayed */
        st->wal_len = before;
        st->appended_tick = before_tick;
        if (ftruncate(st->wal_fd, before) == 0)
            lseek(st->wal_fd, before, SEEK_SET);
        return -1;
    } else if (st->cfg.durability == STORE_NONE) {
        st->durable_tick = tick; /* as durable as promised: in the page cache */
        metrics_set_store_durable_tick(tick);
    }
    if (w)
        store_compaction_maybe_start(st, w, tick);
    return 0;
}

static int dir_settle(void *state)
{
    store_dir *st = state;
    if (st->durable_tick == st->appended_tick)
        return 1;
    if (st->cfg.durability != STORE_GROUP)
        return 0; /* every-tick after a failed sync: held until a retry syncs */
    if (time_now_ms() - st->last_sync_ms < st->cfg.group_ms)
        return 0;
    return sync_now(st) == 0;
}

int store_load_readonly(const char *dir, world *w, uint64_t upto_tick, store_recovery *rec,
                        error_text *err)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/MANIFEST", dir);
    uint32_t base_crc = store_base_identity(w);
    if (store_manifest_check(path, w, base_crc, err) != 0)
        return -1;
    uint64_t last_seq;
    recover_args a = {.dir = dir, .w = w, .upto_tick = upto_tick};
    return store_recover(&a, &last_seq, rec, err);
}

int store_fsck(const char *dir, world *w, store_recovery *rec, error_text *err)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/MANIFEST", dir);
    memset(rec, 0, sizeof *rec);
    if (access(dir, F_OK) != 0) {
        error_set(err, "store: %s: %s", dir, strerror(errno));
        return -1;
    }
    if (access(path, F_OK) != 0) {
        error_set(err, "store: %s is missing%s", path,
                  store_dir_has_data(dir) ? " next to existing data" : "");
        log_error("store: damage: %s", err->message + 7);
        return 1;
    }
    if (store_manifest_check(path, w, store_base_identity(w), err) != 0) {
        log_error("store: damage: %s", err->message + 7);
        return 1;
    }
    int tiles_x = (w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    int tiles_y = (w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    store_control ctl, found;
    if (store_control_init(&ctl, tiles_x, tiles_y) != 0 ||
        store_control_init(&found, tiles_x, tiles_y) != 0) {
        error_set(err, "store: out of memory");
        return -1;
    }
    error_text cerr = {{0}};
    int have = store_control_read(dir, &ctl, &cerr);
    int damaged = 0;
    if (have != 0) {
        error_set(err, "store: %s/CONTROL is %s", dir, have > 0 ? "missing" : "corrupt");
        log_error("store: damage: %s", have > 0 ? err->message + 7 : cerr.message + 7);
        damaged = 1;
    }
    uint64_t last_seq;
    error_text rerr = {{0}};
    recover_args a = {.dir = dir,
                      .w = w,
                      .flags = STORE_RECOVER_CHECK | STORE_RECOVER_ALL,
                      .ctl = have == 0 ? &ctl : NULL,
                      .found = &found};
    if (store_recover(&a, &last_seq, rec, &rerr) != 0) {
        if (!damaged)
            *err = rerr;
        damaged = 1;
    }
    store_control_free(&ctl);
    store_control_free(&found);
    return damaged;
}

const store_backend store_backend_dir = {
    .name = "dir",
    .open = dir_open,
    .close = dir_close,
    .writable = dir_writable,
    .failure = dir_failure,
    .append_tick = dir_append_tick,
    .settle = dir_settle,
    .durable_tick = dir_durable_tick,
};
