/*
 * store: the daemon's persistent, crash-safe terrain — one interface over a
 * storage backend. Today's backend is a data directory (docs/storage.md): a
 * write-ahead log of committed ticks compacted into tile snapshots; issue 11
 * adds a second one behind the same calls.
 *
 * The interface, in the order a daemon uses it:
 *   open      recover the stored terrain into the world (store_open)
 *   append    log one tick's changed rectangles (store_commit_tick)
 *   durable   say when the appended ticks are as durable as the policy
 *             promises, syncing when it is due (store_settle)
 *   snapshot  fold the log into snapshots, off the tick (internal: a
 *   compact   background thread of the backend, never stalling a tick)
 *   close     finish, sync, release (store_close)
 *
 * In the tick (docs/design.md) the service appends a tick's changes after the
 * deformation and before anything of that tick is published, and publishes
 * only once the store says the tick is durable. The thread that opens a store
 * is its sim thread: every call but store_open and the offline reader must
 * come from it (checked in debug builds).
 */
#ifndef TERRAD_STORE_H
#define TERRAD_STORE_H

#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "world/world.h"

typedef enum store_durability {
    STORE_EVERY_TICK, /* a sync before a tick is published */
    STORE_GROUP,      /* one sync per group_ms; ticks are held back until it */
    STORE_NONE,       /* written before publish, never synced */
} store_durability;

/* Zero means "default" for every number. */
typedef struct store_config {
    store_durability durability;
    int group_ms; /* STORE_GROUP */
    /* the data-directory backend */
    const char *dir;
    int64_t segment_bytes;  /* a log segment this large is compacted (0: 16 MiB) */
    const char *fault_path; /* test hook: while this file exists, writes fail ENOSPC */
    int compression_level;  /* zstd level (0: 3) */
    /* --recover-truncate: start on a damaged directory anyway, cutting what
     * is damaged and logging exactly what is lost (default: refuse) */
    int recover_truncate;
    /* replay (docs/storage.md "Retention"): the whole log is kept, compacted
     * segments included, while it is under this many bytes, so that every
     * tick since the first can be rebuilt (0: compacted segments go at once) */
    int64_t retain_bytes;
} store_config;

/* "every-tick", "none" or "group:MS" (MS in 1..10000). */
int store_parse_durability(const char *text, store_config *c, error_text *err);
const char *store_durability_name(const store_config *c, char *buf, size_t cap);

typedef struct store_recovery {
    uint64_t tick;            /* the last tick recovered (0: none logged) */
    int tiles_loaded;         /* snapshots read */
    int64_t records_replayed; /* log records applied */
    int64_t bytes_cut;        /* a torn or corrupt tail cut off the log */
    /* the tick the daemon goes on from: at least every tick any client saw,
     * even those that changed nothing (so tick numbers never go backwards) */
    uint64_t tick_floor;
    int damage; /* damage found (and, with recover_truncate, cut) */
    double ms;
} store_recovery;

typedef struct store store;

/*
 * Open (creating it if needed) the store for world w, whose heights must hold
 * the scene's base terrain: checks that the store belongs to this world and
 * replays what it holds into w. A store of another world or a corrupt one is
 * refused with an error naming what is wrong; a torn tail of the log (a crash
 * mid-write) is cut. The store is held exclusively until store_close.
 */
store *store_open(const store_config *c, world *w, store_recovery *rec, error_text *err);
/* Finishes a running compaction, syncs and closes. NULL is fine. */
void store_close(store *st);
/* This thread is the store's sim thread from now on (a world handed between sim workers). */
void store_claim(store *st);

/* ---- the backend interface ----
 * One table per kind of store (after Redis ae.c's one event-loop API over
 * several implementations). `state` is the backend's own object. Every entry
 * but open runs on the sim thread (store.c asserts it). The data directory's
 * table is internal to store/; a backend that lives in a higher layer (the
 * JetStream one in server/cluster) opens its state itself and hands it to
 * store_adopt. */
typedef struct store_backend {
    const char *name;
    /* Open and recover into w (base terrain already in it). NULL: err says why. */
    void *(*open)(const store_config *c, world *w, store_recovery *rec, error_text *err);
    void (*close)(void *state);
    int (*writable)(void *state);
    const char *(*failure)(const void *state);
    /* Append one tick's changed rectangles; 0, or -1 with nothing appended. */
    int (*append_tick)(void *state, const world *w, uint64_t tick, const world_rect *rects, int n);
    /* 1 when every appended tick is as durable as the policy promises. */
    int (*settle)(void *state);
    uint64_t (*durable_tick)(const void *state);
} store_backend;

/* A store over a backend whose state the caller opened (and recovered) on
 * the thread that will tick: store_close then closes the state. NULL: out of
 * memory (the state is then the caller's still). */
store *store_adopt(const store_backend *backend, void *state);

/* 1 when a tick's changes can be logged now; after a failure, 0 until a
 * retry (at most every 500 ms) finds the storage writable again. */
int store_writable(store *st);
/* Why it is not writable ("" when it is). */
const char *store_failure(const store *st);

/*
 * Append tick `tick`'s changed rectangles (values read from w). Returns 0, or
 * -1 when nothing was appended (the log is left as it was, the store becomes
 * unwritable, the reason is in store_failure): the caller must then undo the
 * tick's changes to w and publish none of them.
 */
int store_commit_tick(store *st, const world *w, uint64_t tick, const world_rect *rects, int n);

/* 1 when every tick appended so far is as durable as the policy promises (in
 * group mode this syncs once group_ms has passed since the last sync). The
 * caller publishes a tick's frames only when this says 1. */
int store_settle(store *st);

/* The last tick made durable (for /metrics and tests). */
uint64_t store_durable_tick(const store *st);

/* ---- offline use of a data directory (terrad export, tests) ---- */

/* Read-only recovery into w (base terrain already in it): nothing is cut or
 * written, no lock taken; a torn tail is skipped and reported in rec. With
 * upto_tick > 0 the world is rebuilt as of that tick (log records after it
 * are not applied); refused when a snapshot is newer than it (the log before
 * the snapshot was compacted away). */
int store_load_readonly(const char *dir, world *w, uint64_t upto_tick, store_recovery *rec,
                        error_text *err);

/* A rebuild's reader may stop it (a spectator whose client left, or whose
 * world leaves; an HTTP past-tick read whose world leaves): cancelled(ctx)
 * is asked before each record the rebuild applies and each snapshot it
 * loads, and at each store_cursor_next, from the reader's thread; once it
 * says nonzero (it must keep saying so) the call returns STORE_CANCELLED
 * with why "store: cancelled", never retried, so the reader waits on no more
 * than one record's work. */
typedef struct store_cancel {
    int (*cancelled)(void *ctx); /* NULL: never */
    void *ctx;
    int seen; /* the store's: set once cancelled said so */
} store_cancel;
#define STORE_CANCELLED (-2)

/*
 * GET /v1/heights?tick=N: rectangle r of the world as of tick `tick`, rebuilt
 * from data directory `dir` into dst (r.w * r.h heights) beside a live daemon
 * (its own reads of the files; nothing is written, nothing of the sim
 * thread's is touched). base holds the scene's base terrain (read with
 * world_base_fill_rect only, immutable). While the log is whole (segment 1
 * still present: retention kept it) the rebuild is the base and every record
 * up to the tick, else the tile snapshots and the records after them. Memory:
 * one world of base's size and one log segment at a time. cancel: NULL
 * (never), else copied. Returns 0; 1 when the store no longer holds the tick
 * (compacted away: why says so); STORE_CANCELLED; -1 on another error (why). */
int store_replay_rect(const char *dir, const world *base, uint64_t tick, world_rect r, int32_t *dst,
                      const store_cancel *cancel, error_text *why);

/* The same rebuild of r kept as a world (its heights and per-cell layers in
 * r as of the tick; elsewhere not meaningful), for the reads of a past tick
 * that need more than heights (?tick=N with layer=compaction, /v1/stats):
 * 0 with *out to world_free, 1 (no longer held: why), STORE_CANCELLED, -1. */
int store_replay_world(const char *dir, const world *base, uint64_t tick, world_rect r, world *out,
                       const store_cancel *cancel, error_text *why);

/*
 * A spectator's replay (PROTOCOL.md "spectate"): a cursor holds rectangle r
 * (nothing beside it: snapshots and records are clipped to r) as of tick `tick`, rebuilt as
 * store_replay_rect rebuilds it, then walks the log forward one record (one
 * tick's changed rectangles) at a time, beside the live daemon, off the tick.
 * open: 0, 1 when the store no longer holds the tick (why), STORE_CANCELLED,
 * -1 on another error. next: 1 with the next record's tick (at most upto) and rectangles
 * (valid until the next call), read but not applied (read r's heights before
 * it, then store_cursor_apply); 0 when the log holds none up to upto yet;
 * -1 (why) when it cannot go on (the log after the cursor was compacted
 * away, or damage), STORE_CANCELLED. One thread per cursor.
 */
typedef struct store_cursor store_cursor;
/* cancel: NULL (never), else copied into the cursor. */
int store_cursor_open(const char *dir, const world *base, uint64_t tick, world_rect r,
                      const store_cancel *cancel, store_cursor **out, error_text *why);
int store_cursor_next(store_cursor *c, uint64_t upto, uint64_t *tick, const world_rect **rects,
                      int *n, error_text *why);
int store_cursor_apply(store_cursor *c, error_text *why);
/* Heights of rectangle q (inside the cursor's rectangle r) as of its tick. */
void store_cursor_read(const store_cursor *c, world_rect q, int32_t *dst);
/* Cells the cursor's world holds (its stored tiles'): only r's tiles, since
 * every snapshot and record is clipped to r (terrad_spectate_cursor_cells_max);
 * *bytes (when not NULL): the bytes it holds, tiles, layers and tables. */
int64_t store_cursor_cells(const store_cursor *c, uint64_t *bytes);
uint64_t store_cursor_tick(const store_cursor *c);
void store_cursor_close(store_cursor *c);

/* Start data directory `dir` over (terrad serve --fresh): deletes the files
 * a data directory holds and nothing else. A directory holding any other
 * file is refused with an error naming it, and nothing is deleted; so is one
 * a running daemon holds. A missing directory is fine. *removed counts the
 * files deleted. 0, or -1 with err set. */
int store_remove(const char *dir, int *removed, error_text *err);
/* terrad fsck: check a data directory against CONTROL without changing
 * anything; every damage is logged (naming the file). 0 clean, 1 damaged
 * (err says the first), -1 when it cannot be read at all. */
int store_fsck(const char *dir, world *w, store_recovery *rec, error_text *err);

/* ---- a log record's payload: one codec for every backend (store_record.c) ----
 * u32 rectangle count with layer bits (bit 31, STORE_RECORD_SOIL: the soil
 * state follows; bit 30, STORE_RECORD_COMPACTION: the compaction memory
 * follows), per rectangle x, y, w, h (u32), u32 raw byte count, then zstd of
 * the rectangles' heights (i32, row by row, one rectangle after the other)
 * and, with the soil bit, their soil state (WORLD_SOIL_FIELDS i32 per cell,
 * same order), then with the compaction bit their compaction memory (one i32
 * per cell in [0, WORLD_COMPACTION_MAX], same order). A payload without a
 * bit (every one before that layer existed) still reads. The data
 * directory's log records and the JetStream store's log records and tile
 * snapshots all carry it (docs/storage.md, docs/cluster.md). */
#define STORE_RECORD_SOIL 0x80000000u
#define STORE_RECORD_COMPACTION 0x40000000u
#define STORE_RECORD_LAYER_BITS (STORE_RECORD_SOIL | STORE_RECORD_COMPACTION)

/* Which per-cell layers a record (or a tile copy) carries beside the heights. */
#define STORE_LAYER_SOIL 1u
#define STORE_LAYER_COMPACTION 2u

typedef struct store_record { /* scratch, reused from record to record */
    int32_t *values;
    int64_t values_cap;
    uint8_t *buf; /* the encoded record, after the caller's header room */
    int64_t buf_cap;
    /* store_record_apply writes only the cells inside clip (w 0: every cell):
     * a rebuild of one rectangle (a replay, a spectator's cursor) holds its
     * tiles, not the whole world's */
    world_rect clip;
    int32_t *part; /* a clipped rectangle's values */
    int64_t part_cap;
} store_record;

struct ZSTD_CCtx_s;

void store_record_free(store_record *c);
/* The layers w keeps (a record of w carries them all, so replay puts back
 * every cell it names whole). */
unsigned store_world_layers(const world *w);
/* The layers holding anything in r (a tile snapshot carries only those). */
unsigned store_rect_layers(const world *w, world_rect r);
/* int32 values per cell: the height and each layer's fields. */
int store_layers_ints(unsigned layers);
/* One rectangle's heights, then its layers, into dst (store_layers_ints per
 * cell): a record of that one rectangle's values, a tile copy's. */
void store_layers_gather(const world *w, world_rect r, unsigned layers, int32_t *dst);
/* The inverse: src (a tile copy's values) into w's heights and layers over
 * r, only where r meets *clip when clip is not NULL. 0, or -1 out of memory. */
int store_layers_scatter(world *w, world_rect r, unsigned layers, const int32_t *src,
                         const world_rect *clip);
/* rects' heights, then their layers, into c->values. 0, or -1 out of memory. */
int store_record_gather(store_record *c, const world *w, const world_rect *rects, int n,
                        unsigned layers);
/* Encodes rects with their values (laid out as store_record_gather lays
 * them) into c->buf + head (head bytes left for the caller's header): the
 * payload's length, or 0 with err set. */
size_t store_record_encode(store_record *c, struct ZSTD_CCtx_s *cctx, int level,
                           const world_rect *rects, int n, unsigned layers, const int32_t *values,
                           size_t head, error_text *err);
/* The layers a payload carries (its first word's bits). */
unsigned store_record_layers(const uint8_t *p, size_t len);
/* Checks a payload whole (every rectangle inside w and accepted by check,
 * when given; the sizes right; every memory in range) and only then applies
 * it to w (the cells inside c->clip, when set). 0; 1 when it is malformed
 * (nothing applied); -1 out of memory. */
int store_record_apply(store_record *c, world *w, const uint8_t *p, size_t len,
                       int (*check)(void *ctx, world_rect r), void *ctx);

/* ---- a world's past, wherever it is stored (PROTOCOL.md "Spectate") ----
 * Replays (a spectator's cursor, GET /v1/heights?tick=N) read a world's log
 * and snapshots beside the live daemon: from a data directory (dir), or
 * through a backend's reader (ops and ctx: the JetStream store's,
 * server/cluster/cluster_history.c, a layer above). A reader hands over the
 * same record payloads the data directory's log holds (the codec above), so
 * one cursor applies both. */
typedef struct store_history_ops {
    /* Loads into w (base terrain under rec->clip already there; only
     * rec->clip's cells are written) the newest stored state at or before
     * tick and starts a reader after it: 0 with *reader; 1 when the store
     * no longer holds the tick (why: compacted away); -1 (why). The cursor
     * then applies the records up to the tick (next). */
    int (*open)(void *ctx, world *w, uint64_t tick, store_record *rec, store_cancel *cancel,
                void **reader, error_text *why);
    /* The next record: 1 with its tick and payload (valid until the next
     * call); 0 when the log holds none after it yet; -1 (why) when it
     * cannot go on (the log after it was compacted away, or damage). */
    int (*next)(void *reader, uint64_t *tick, const uint8_t **payload, size_t *len,
                error_text *why);
    void (*close)(void *reader);
    /* The history's ctx is freed (the world is gone, no reader left). */
    void (*release)(void *ctx);
} store_history_ops;

typedef struct store_history {
    const char *dir; /* a data directory, or NULL */
    const store_history_ops *ops;
    void *ctx;
} store_history;

/* 1 when h names a past to replay (a directory or a reader). */
int store_history_kept(const store_history *h);
/* ctx released (ops->release) and h emptied. NULL is fine. */
void store_history_release(store_history *h);
/* store_cursor_open, store_replay_rect and store_replay_world over either
 * kind of history (a directory's go to those). */
int store_history_cursor(const store_history *h, const world *base, uint64_t tick, world_rect r,
                         const store_cancel *cancel, store_cursor **out, error_text *why);
int store_history_rect(const store_history *h, const world *base, uint64_t tick, world_rect r,
                       int32_t *dst, const store_cancel *cancel, error_text *why);
int store_history_world(const store_history *h, const world *base, uint64_t tick, world_rect r,
                        world *out, const store_cancel *cancel, error_text *why);

/* CRC32C (Castagnoli), as every record, snapshot and the manifest use it. */
uint32_t store_crc32c(uint32_t crc, const void *data, size_t len);

#endif
