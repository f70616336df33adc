/*
 * store: the daemon's persistent, crash-safe terrain (docs/storage.md). A data
 * directory holds a manifest naming the world it belongs to, zstd-compressed
 * snapshots of every 256×256-cell tile ever changed, and a write-ahead log of
 * committed ticks (each record: the tick, its changed rectangles and their new
 * absolute values, a CRC32C). In the tick (DESIGN.md "One tick") the service
 * appends a tick's changes after the deformation and before anything of that
 * tick is published, and publishes only once the store says the tick is as
 * durable as the policy promises. A background thread folds the log into tile
 * snapshots from copies of the changed tiles taken at a tick boundary, so it
 * never stalls a tick.
 *
 * Only the sim thread calls into a store (the compaction thread is internal).
 */
#ifndef TERRAD_STORE_H
#define TERRAD_STORE_H

#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "world/world.h"

#define STORE_TILE_SIZE 256

typedef enum store_durability {
    STORE_EVERY_TICK, /* fdatasync of the log before a tick is published */
    STORE_GROUP,      /* one fdatasync per group_ms; ticks are held back until it */
    STORE_NONE,       /* written (page cache) before publish, never synced */
} store_durability;

typedef struct store_config {
    const char *dir;
    store_durability durability;
    int group_ms;           /* STORE_GROUP */
    int64_t segment_bytes;  /* a log segment this large is compacted (0: 16 MiB) */
    const char *fault_path; /* test hook: while this file exists, writes fail ENOSPC */
    int compression_level;  /* zstd level (0: 3) */
} store_config;

/* "every-tick", "none" or "group:MS" (MS in 1..10000). */
int store_parse_durability(const char *text, store_config *c, error_text *err);
const char *store_durability_name(const store_config *c, char *buf, size_t cap);

typedef struct store_recovery {
    uint64_t tick;            /* the last tick recovered (0: none logged) */
    int tiles_loaded;         /* tile snapshots read */
    int64_t records_replayed; /* log records applied */
    int64_t bytes_cut;        /* a torn or corrupt tail cut off the last log segment */
    double ms;
} store_recovery;

typedef struct store store;

/*
 * Open (creating it if needed) the data directory for world w, whose heights
 * must hold the scene's base terrain: checks the manifest against it, loads
 * the tile snapshots and replays the log into w. A data directory of another
 * world, a corrupt snapshot or a corrupt record before the log's last segment
 * is refused with an error naming the file. Takes a lock on the directory.
 */
store *store_open(const store_config *c, world *w, store_recovery *rec, error_text *err);
/* Finishes a running compaction, syncs the log and closes. NULL is fine. */
void store_close(store *st);

/* 1 when a tick's changes can be logged now; after a failure, 0 until a
 * retry (at most every 500 ms) finds the directory writable again. */
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

/* ---- offline use (terrad export, tests) ---- */

/* Read-only recovery into w (base terrain already in it): nothing is cut or
 * written, no lock taken; a torn tail is skipped and reported in rec. With
 * upto_tick > 0 the world is rebuilt as of that tick (log records after it
 * are not applied); refused when a tile snapshot is newer than it (the log
 * before the snapshot was compacted away). */
int store_load_readonly(const char *dir, world *w, uint64_t upto_tick, store_recovery *rec,
                        error_text *err);

/* CRC32C (Castagnoli), as every record, snapshot and the manifest use it. */
uint32_t store_crc32c(uint32_t crc, const void *data, size_t len);

#endif
