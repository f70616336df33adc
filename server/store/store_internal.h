/*
 * store_internal.h: what the store's files share inside server/store/ — the
 * one backend interface every store implementation fills (store.c dispatches
 * to it), and the data-directory backend's layout, record format and state.
 *
 *   DIR/MANIFEST            JSON naming the world (dims, scale, CRC32C of the
 *                           base terrain) + a line "crc32c XXXXXXXX"
 *   DIR/LOCK                flock'ed while a daemon owns the directory
 *   DIR/CONTROL             what the directory must hold: segments first..last,
 *                           the tile snapshots, the last durable tick
 *   DIR/wal-<seq>.log       log segments: a 24-byte header, then records
 *   DIR/tiles/t-X-Y.snap    one per 256² tile ever changed
 *
 * Files: store_dir.c (open/close, appending a tick, syncing), store_log.c
 * (log segments and recovery), store_snapshot.c (manifest and tile
 * snapshots), store_control.c (CONTROL), store_recover.c (recovery and its
 * damage checks), store_compaction.c (the compaction thread). Never included from
 * outside server/store/.
 */
#ifndef TERRAD_STORE_INTERNAL_H
#define TERRAD_STORE_INTERNAL_H

#include <pthread.h>
#include <stdint.h>

#include <zstd.h>

#include "store/store.h"

/* The data directory (store_dir.c): a write-ahead log compacted into tile
 * snapshots. */
extern const store_backend store_backend_dir;

/* ---- the data directory's format ---- */

#define STORE_TILE_SIZE 256
#define WAL_MAGIC "TRDWAL01"
#define WAL_HEADER 24
#define REC_MAGIC 0x52445254u /* "TRDR" */
#define REC_HEADER 24
/* A record's payload is store_record.c's (store.h): with STORE_RECORD_SOIL
 * the soil state of every rectangle follows their heights, with
 * STORE_RECORD_COMPACTION their compaction memory; records without either
 * (format 1, and worlds without per-cell state) hold heights only. */
#define REC_MAX_PAYLOAD (1u << 30)
#define TILE_MAGIC "TRDTILE1"
#define TILE_HEADER 56
/* A snapshot's format (header offset 8) is 1 + the STORE_LAYER_* bits it
 * carries after the heights: 1 heights only; 2 then the tile's soil state
 * (WORLD_SOIL_FIELDS int32 per cell); 3 then its compaction memory (one int32
 * per cell); 4 both, in that order. Each is written only for a tile holding
 * those layers, so a tile without per-cell state stays format 1. */
#define TILE_FORMAT_HEIGHTS 1
#define TILE_FORMAT_MAX (1 + (STORE_LAYER_SOIL | STORE_LAYER_COMPACTION))
#define RETRY_MS 500.0
/* A snapshot or a segment read whole is at most this large. */
#define STORE_FILE_BYTES_MAX ((size_t)REC_MAX_PAYLOAD * 2)

/* little-endian fields */
static inline void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static inline void put64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static inline uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static inline uint64_t get64(const uint8_t *p)
{
    return (uint64_t)get32(p) | (uint64_t)get32(p + 4) << 32;
}

/* A changed tile copied at a tick boundary, for the compaction thread. */
typedef struct tile_copy {
    int tx, ty;
    world_rect rect;
    int32_t *values; /* heights, then the layers (store_layers_gather) */
    unsigned layers; /* STORE_LAYER_* */
} tile_copy;

/* DIR/CONTROL (store_control.c). */
typedef struct store_control {
    uint64_t tick;                /* the last tick durable when it was written */
    uint64_t first_seq, last_seq; /* every segment first..last must be present */
    int tiles_x, tiles_y;
    uint64_t *tile_tick; /* per tile: the tick of its snapshot, 0: none */
} store_control;

/* Ticks that change nothing are not logged, but one empty record is written
 * at least every STORE_TICK_LOG_EVERY ticks (and at close), so a restart can
 * go on from a tick no client has seen (store_recovery.tick_floor). */
#define STORE_TICK_LOG_EVERY 30

typedef struct store_dir {
    store_config cfg;
    char dir[1024];
    char fault[1024];
    int lock_fd;
    int width, height, tiles_x, tiles_y;

    int wal_fd;
    uint64_t wal_seq;
    int64_t wal_len; /* bytes known good in the current segment */
    uint64_t appended_tick, durable_tick;
    uint64_t seen_tick; /* the last tick handed to append_tick, logged or not */
    int unsynced;       /* records appended since the last fdatasync */
    double last_sync_ms;

    int failed;
    double failed_at_ms;
    double fail_logged_ms; /* the last failure logged (rate-limited) */
    long long fail_unlogged;
    char failure[256];

    uint8_t *changed; /* per tile: changed since the last compaction boundary */
    store_record rec; /* record scratch */
    ZSTD_CCtx *cctx;

    /* compaction: one job at a time, handed over under the mutex */
    thread_owner compaction_owner; /* claimed by the compaction thread */
    pthread_t thread;
    int thread_started;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int job_ready, job_running, quit;
    tile_copy *job_tiles;
    int job_count;
    uint64_t job_tick, job_first_live_seq;

    pthread_mutex_t ctl_lock; /* ctl: updated by the sim and compaction threads */
    store_control ctl;
} store_dir;

/* ---- files (store_dir.c) ---- */
/* write() all of it, or fail with errno (ENOSPC from the fault hook too). */
int store_dir_write_all(const store_dir *st, int fd, const void *data, size_t len);
int store_dir_fsync(const char *dir);
/* Atomic replacement: DIR/name.tmp, fsync, rename, fsync of DIR. */
int store_dir_write_atomic(const store_dir *st, const char *dir, const char *name, const void *a,
                           size_t alen, const void *b, size_t blen, error_text *err);
int store_dir_fault_active(const store_dir *st);
int store_dir_fault_is_fsync(const store_dir *st);
/* fdatasync, or EIO while the fault file says "fsync" (test hook). */
int store_dir_fdatasync(const store_dir *st, int fd);
/* After a failed fdatasync with ticks held for it: log and _exit (fsyncgate). */
void store_dir_sync_failed_fatal(const store_dir *st, int e);

/* ---- manifest and tile snapshots (store_snapshot.c) ---- */
uint32_t store_base_identity(const world *w);
char *store_manifest_text(const world *w, uint32_t base_crc);
int store_manifest_check(const char *path, const world *w, uint32_t base_crc, error_text *err);
world_rect store_tile_rect(int width, int height, int tx, int ty);
/* One tile snapshot into w (only the cells inside *clip, when clip is not
 * NULL; a tile outside it is checked but not loaded); upto_tick (0: any): a
 * snapshot of a later tick is refused, "compacted away". 0 or -1. */
int store_tile_load(const char *path, world *w, uint64_t upto_tick, const world_rect *clip,
                    uint64_t *tick_out, error_text *err);
int store_tile_write(const store_dir *st, const char *dir, const tile_copy *t, uint64_t tick,
                     ZSTD_CCtx *cctx, int level, error_text *err);

/* ---- log segments and recovery (store_log.c) ---- */
int store_list_segments(const char *dir, uint64_t **seqs, int *count);
void store_segment_path(const char *dir, uint64_t seq, char *out, size_t cap);
int store_segment_start(store_dir *st, uint64_t seq, error_text *err);
/* Apply every good record of one segment's bytes to w (w NULL: only count
 * them); stops at the first record that is torn or fails a check. */
typedef struct replay_result {
    uint64_t last_tick;
    int64_t records;
    int64_t good_len; /* offset after the last good record */
    int64_t file_len;
    int header_ok;
    char problem[200];
    /* good records found after the problem: it was damage, not a torn tail */
    int64_t later_records;
    uint64_t later_max_tick;
} replay_result;
/* clip (NULL: none): only the cells inside it are applied (store_record.clip). */
/* cancel (NULL: none) is asked before each record applied: once it says so
 * this returns -1, err "store: cancelled". */
int store_segment_replay(const char *path, world *w, const world_rect *clip, uint8_t *changed,
                         uint64_t after_tick, uint64_t upto_tick, store_cancel *cancel,
                         replay_result *res, error_text *err);
/* 1 when the cancel (NULL: never) said so, now or before (then c->seen). */
int store_cancel_now(store_cancel *c);

/* ---- replay keyframes (store_replay.c; docs/storage.md "Replay") ---- */
/* 1 when name is a keyframe (k-TICK-X-Y.snap: *done 0) or a generation's
 * marker (k-TICK.done: *done 1). */
int store_keyframe_name(const char *name, uint64_t *tick, int *tx, int *ty, int *done);
/* Under retention, after a compaction wrote tiles as of tick: links them as
 * keyframes, then marks the generation whole. 0 or -1 (errno). */
int store_keyframes_keep(const char *tiles_dir, const tile_copy *tiles, int count, uint64_t tick);
/* Retention over: every keyframe and marker goes (before the segments). */
void store_keyframes_drop(const char *tiles_dir);

/* ---- recovery (store_recover.c) ---- */
enum {
    STORE_RECOVER_REPAIR = 1,    /* cut a torn tail off the last segment */
    STORE_RECOVER_CHECK = 2,     /* hold the directory to CONTROL: damage refuses */
    STORE_RECOVER_TRUNCATE = 4,  /* damage is logged with what is lost, then cut */
    STORE_RECOVER_ALL = 8,       /* fsck: log every damage found, not only the first */
    STORE_RECOVER_NO_TILES = 16, /* replay: the whole log from the base, no snapshots */
};
typedef struct recover_args {
    const char *dir;
    world *w;
    uint8_t *changed;         /* per tile, or NULL */
    int flags;                /* STORE_RECOVER_* */
    uint64_t upto_tick;       /* 0: all */
    const store_control *ctl; /* NULL: none (no checks against it) */
    store_control *found;     /* filled when not NULL: snapshots loaded, segments */
    const world_rect *clip;   /* NULL, or a replay's rectangle: only its cells are loaded */
    store_cancel *cancel;     /* NULL, or a cursor's: asked per record and snapshot */
} recover_args;
int store_recover(const recover_args *a, uint64_t *last_seq, store_recovery *rec, error_text *err);
/* 1 when DIR holds a log record, a snapshot or CONTROL (a MANIFEST must then be there). */
int store_dir_has_data(const char *dir);

/* ---- CONTROL (store_control.c) ---- */
int store_control_init(store_control *c, int tiles_x, int tiles_y);
void store_control_free(store_control *c);
/* 0, 1 when there is none, -1 (err names the file) when it is corrupt. */
int store_control_read(const char *dir, store_control *c, error_text *err);
/* The text files (MANIFEST, CONTROL) end in a line "crc32c XXXXXXXX" over
 * everything before it, which ends in `tail` ("\n", or "}\n" for the
 * manifest's JSON): the start of that line when the checksum holds, else NULL. */
const char *store_text_crc_end(const char *text, const char *tail);
/* A data-directory file whole (at most STORE_FILE_BYTES_MAX, NUL-terminated
 * by file_read_all): 0, or -1 with err "store: cannot read WHAT<reason naming
 * the path>" (what: "" or "log segment " ...). */
int store_file_read(const char *path, const char *what, uint8_t **data, size_t *len,
                    error_text *err);
int store_control_write(const store_dir *st, const char *dir, const store_control *c,
                        error_text *err);
int store_control_save(store_dir *st, error_text *err);

/* ---- compaction (store_compaction.c) ---- */
void *store_compaction_main(void *arg);
/* At a tick boundary (sim thread): hand the changed tiles to the compaction
 * thread once the current segment is past its size. */
void store_compaction_maybe_start(store_dir *st, const world *w, uint64_t tick);
/* Wake the compaction thread, wait for it to finish, free an unstarted job. */
void store_compaction_stop(store_dir *st);

#endif
