/*
 * store_compaction.c: the store's fourth thread. When the current log
 * segment passes its size, the sim thread (at a tick boundary, inside
 * store_commit_tick) starts a new segment, copies the tiles changed since the
 * last boundary and hands them over; the compaction thread writes them as
 * tile snapshots and only then deletes the segments before the boundary. A
 * crash anywhere in between leaves either the old segments or the new
 * snapshots, both enough, and no tick ever waits for a snapshot.
 *
 * The two threads meet only in the job fields under st->lock (see
 * store_internal.h); each side's entries assert which thread they run on.
 */
#include <errno.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "metrics/metrics.h"
#include "store/store_internal.h"

/* The bytes of every log segment present. */
static int64_t compaction_log_bytes(const store_dir *st)
{
    uint64_t *seqs;
    int n;
    int64_t total = 0;
    if (store_list_segments(st->dir, &seqs, &n) != 0)
        return INT64_MAX; /* cannot tell: delete as without retention */
    for (int i = 0; i < n; i++) {
        char path[1100];
        struct stat sb;
        store_segment_path(st->dir, seqs[i], path, sizeof path);
        if (stat(path, &sb) == 0)
            total += sb.st_size;
    }
    free(seqs);
    return total;
}

/* Write one job's tiles, then drop the segments they make unneeded.
 * Returns 1 when every tile is on disk. Compaction thread only. */
static int compaction_run_job(store_dir *st, ZSTD_CCtx *cctx, const tile_copy *tiles, int count,
                              uint64_t tick, uint64_t live)
{
    THREAD_OWNED(&st->compaction_owner);
    char tiles_dir[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", st->dir);
    double t0 = time_now_ms();
    error_text err = {{0}};
    int ok = cctx != NULL;
    for (int i = 0; ok && i < count; i++)
        ok = store_tile_write(st, tiles_dir, &tiles[i], tick, cctx, st->cfg.compression_level,
                              &err) == 0;
    if (!ok) {
        /* the segments stay, so nothing is lost; the tiles are retried next time */
        metrics_count_store_error("compaction");
        log_error("store: compaction as of tick %llu failed: %s (the log is kept)",
                  (unsigned long long)tick, err.message[0] ? err.message : "out of memory");
        return 0;
    }
    /* every changed tile is on disk: CONTROL records them, then the older
     * segments are no longer needed (a crash before CONTROL is written keeps
     * them: recovery replays them over the new snapshots, which is harmless) */
    /* retention: while the whole log is under retain_bytes nothing is
     * deleted, so every tick since the first can be replayed (store_replay.c);
     * past it the folded segments go as before */
    /* keyframes describe the world only while no record was ever deleted
     * (segment 1 present): once retention ends it stays ended */
    char first[1100];
    store_segment_path(st->dir, 1, first, sizeof first);
    if (st->cfg.retain_bytes > 0 && access(first, F_OK) == 0 &&
        compaction_log_bytes(st) <= st->cfg.retain_bytes) {
        live = 0;
        if (store_keyframes_keep(tiles_dir, tiles, count, tick) != 0)
            log_error("store: keeping the keyframes of tick %llu: %s (replays start earlier)",
                      (unsigned long long)tick, strerror(errno));
    } else {
        store_keyframes_drop(tiles_dir); /* any left, before their records go */
    }
    pthread_mutex_lock(&st->ctl_lock);
    for (int i = 0; i < count; i++)
        st->ctl.tile_tick[tiles[i].ty * st->tiles_x + tiles[i].tx] = tick;
    if (live > st->ctl.first_seq)
        st->ctl.first_seq = live;
    pthread_mutex_unlock(&st->ctl_lock);
    if (store_control_save(st, &err) != 0) {
        metrics_count_store_error("compaction");
        log_error("store: compaction as of tick %llu: %s (the log is kept)",
                  (unsigned long long)tick, err.message);
        return 0;
    }
    uint64_t *seqs;
    int n;
    if (store_list_segments(st->dir, &seqs, &n) == 0) {
        for (int i = 0; i < n; i++) {
            if (seqs[i] >= live)
                continue;
            char path[1100];
            store_segment_path(st->dir, seqs[i], path, sizeof path);
            unlink(path);
        }
        free(seqs);
        store_dir_fsync(st->dir);
    }
    metrics_count_store_compaction(time_now_ms() - t0);
    log_info("store: compacted %d tiles as of tick %llu in %.1f ms", count,
             (unsigned long long)tick, time_now_ms() - t0);
    return 1;
}

void *store_compaction_main(void *arg)
{
    store_dir *st = arg;
    thread_owner_claim(&st->compaction_owner, "compaction");
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    pthread_mutex_lock(&st->lock);
    for (;;) {
        while (!st->job_ready && !st->quit)
            pthread_cond_wait(&st->cond, &st->lock);
        if (!st->job_ready)
            break;
        tile_copy *tiles = st->job_tiles;
        int count = st->job_count;
        uint64_t tick = st->job_tick, live = st->job_first_live_seq;
        st->job_ready = 0;
        st->job_running = 1;
        pthread_mutex_unlock(&st->lock);

        int ok = compaction_run_job(st, cctx, tiles, count, tick, live);
        for (int i = 0; i < count; i++)
            free(tiles[i].values);
        free(tiles);

        pthread_mutex_lock(&st->lock);
        st->job_running = 0;
        if (!ok) /* the sim thread re-marks these tiles when it sees the failure */
            st->job_first_live_seq = 0;
        pthread_cond_broadcast(&st->cond);
    }
    pthread_mutex_unlock(&st->lock);
    ZSTD_freeCCtx(cctx);
    return NULL;
}

/* At a tick boundary: start a new segment, copy the changed tiles, hand them
 * to the compaction thread. Skipped while a compaction is still running. */
void store_compaction_maybe_start(store_dir *st, const world *w, uint64_t tick)
{
    if (st->wal_len < st->cfg.segment_bytes || !st->thread_started)
        return;
    pthread_mutex_lock(&st->lock);
    int busy = st->job_ready || st->job_running;
    pthread_mutex_unlock(&st->lock);
    if (busy)
        return;
    int n = 0;
    for (int i = 0; i < st->tiles_x * st->tiles_y; i++)
        n += st->changed[i];
    tile_copy *tiles = calloc((size_t)n + 1, sizeof *tiles);
    if (!tiles)
        return;
    int k = 0;
    for (int i = 0; i < st->tiles_x * st->tiles_y; i++) {
        if (!st->changed[i])
            continue;
        tile_copy *t = &tiles[k];
        t->tx = i % st->tiles_x;
        t->ty = i / st->tiles_x;
        t->rect = store_tile_rect(st->width, st->height, t->tx, t->ty);
        size_t cells = (size_t)t->rect.w * t->rect.h;
        t->layers = store_rect_layers(w, t->rect);
        t->values = malloc(cells * 4 * (size_t)store_layers_ints(t->layers));
        if (!t->values)
            break;
        store_layers_gather(w, t->rect, t->layers, t->values);
        k++;
    }
    /* every record so far is synced before the old segment is left behind */
    error_text err = {{0}};
    int synced = k == n && store_dir_fdatasync(st, st->wal_fd) == 0;
    if (k == n && !synced)
        store_dir_sync_failed_fatal(st, errno); /* never retried into a success */
    if (!synced || store_segment_start(st, st->wal_seq + 1, &err) != 0) {
        for (int i = 0; i < k; i++)
            free(tiles[i].values);
        free(tiles);
        if (err.message[0])
            log_error("%s (compaction postponed)", err.message);
        return;
    }
    st->durable_tick = st->appended_tick;
    st->unsynced = 0;
    memset(st->changed, 0, (size_t)st->tiles_x * st->tiles_y);
    /* CONTROL: the new segment belongs to the log now */
    pthread_mutex_lock(&st->ctl_lock);
    st->ctl.last_seq = st->wal_seq;
    st->ctl.tick = st->durable_tick;
    pthread_mutex_unlock(&st->ctl_lock);
    if (store_control_save(st, &err) != 0)
        log_error("%s", err.message);
    pthread_mutex_lock(&st->lock);
    st->job_tiles = tiles;
    st->job_count = n;
    st->job_tick = tick;
    st->job_first_live_seq = st->wal_seq;
    st->job_ready = 1;
    pthread_cond_broadcast(&st->cond);
    pthread_mutex_unlock(&st->lock);
}

void store_compaction_stop(store_dir *st)
{
    if (st->thread_started) {
        pthread_mutex_lock(&st->lock);
        st->quit = 1;
        pthread_cond_broadcast(&st->cond);
        pthread_mutex_unlock(&st->lock);
        pthread_join(st->thread, NULL);
        st->thread_started = 0;
    }
    if (st->job_ready) { /* never picked up */
        for (int i = 0; i < st->job_count; i++)
            free(st->job_tiles[i].values);
        free(st->job_tiles);
        st->job_ready = 0;
    }
}
