/*
 * cluster_internal.h: what cluster.c, cluster_lease.c, cluster_wal.c and
 * cluster_kv.c share — the connection, the JetStream context, the buckets
 * and this node's leases. Never included from outside server/cluster/.
 */
#ifndef TERRAD_CLUSTER_INTERNAL_H
#define TERRAD_CLUSTER_INTERNAL_H

#include <pthread.h>

#include <nats/nats.h>

#include "cluster/cluster.h"

#define CLUSTER_STREAM "TERRAD_WAL"
#define CLUSTER_SUBJECT_PREFIX "terrad.wal."
#define CLUSTER_BUCKET_LEASES "TERRAD_LEASES"
#define CLUSTER_BUCKET_TILES "TERRAD_TILES"
#define CLUSTER_BUCKET_WORLDS "TERRAD_WORLDS"

/* This node's view of one world's lease. */
typedef struct cluster_lease {
    char world[CLUSTER_WORLD_NAME_MAX + 1];
    int held;
    uint64_t revision;    /* the last revision seen (held: the one we wrote) */
    double seen_since_ms; /* when `revision` was first seen (monotonic) */
    double renewed_ms;    /* held: the last successful take or renewal */
} cluster_lease;

struct cluster {
    char node[CLUSTER_NODE_NAME_MAX + 1];
    char urls[1024];
    natsConnection *nc;
    jsCtx *js;
    kvStore *leases, *tiles, *worlds;
    int replicas;
    int lease_ms, timeout_ms;
    int64_t max_payload;
    int renew_ms;
    pthread_t renewer;
    int renewer_started, renewer_quit;
    pthread_cond_t renewer_wake;
    pthread_mutex_t lock; /* guards lease_list and renewer_quit */
    cluster_lease *lease_list;
    int64_t lease_count, lease_capacity;
};

/* "what: NATS: <nats status text> (<last error>)" into err. */
void cluster_error(error_text *err, natsStatus s, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/*
 * The latest value of key in bucket, asked of the bucket stream's leader:
 * kvStore_Get may be answered by any replica (direct get), and one that is
 * still catching up after a restart answers with an old value — an old
 * snapshot head would send recovery to a log already purged. 1: found
 * (*data malloc'd and NUL-terminated, *len, *revision), 0: absent or
 * deleted, -1: error (err names the key).
 */
int cluster_kv_read(cluster *cl, const char *bucket, const char *key, uint8_t **data, size_t *len,
                    uint64_t *revision, error_text *err);

/* The thread renewing held leases (cluster_lease.c). */
int cluster_renewer_start(cluster *cl);
void cluster_renewer_stop(cluster *cl);
/* The subject of world's log. */
void cluster_wal_subject(const char *world, char *out, size_t cap);
/* Deletes every snapshot of world (cluster_kv.c); -1 on an error. */
int cluster_snapshot_delete_all(cluster *cl, const char *world, error_text *err);

/* ---- what the store (cluster_store.c) and the replay reader
 * (cluster_history.c) share ---- */
/* A log record's tick and its payload (the store's record codec, store.h):
 * 1; 0 when it is corrupt; -1 for a version 1 record (heights in a format
 * of their own: only recovery reads those). */
int cluster_record_payload(const uint8_t *data, size_t len, uint64_t *tick, const uint8_t **payload,
                           size_t *payload_len);
/* A tile snapshot's bytes into w (through rec: only rec->clip's cells when
 * set): 1 applied, 0 corrupt or another tile's, -1 out of memory. */
int cluster_snapshot_apply(store_record *rec, world *w, int tx, int ty, const uint8_t *data,
                           size_t len);
/* Reading a log without writing it (a replay): the next whole record at or
 * after *from (markers skipped, parts put together in w), copied into *buf
 * (*cap grows): 1 with its length and *seq (its last part's); 0 when none
 * is there yet; -1 (err). *from moves past every message read; *first: the
 * sequence of the first message read (0: none). */
int cluster_wal_next(cluster_wal *w, uint64_t *from, uint64_t *first, uint8_t **buf, int64_t *cap,
                     size_t *len, uint64_t *seq, error_text *err);

#endif
