/*
 * cluster: terrad on a NATS JetStream cluster (docs/cluster.md). A node
 * connects to a list of NATS servers and gets, per world:
 *
 *   - a LEASE in the key-value bucket TERRAD_LEASES (key = world): taken with
 *     a create (or, once the holder has stopped renewing for lease_ms, an
 *     update of the revision seen), renewed every second with an update of
 *     the last revision; a renewal that fails means another node holds it;
 *   - a FENCED write-ahead log: the stream TERRAD_WAL, one subject
 *     terrad.wal.<world>, where every append expects the subject's last
 *     sequence as this owner saw it. A new owner first appends an owner
 *     marker (cluster_wal_take), so any later append of a deposed owner is
 *     refused by JetStream itself: two nodes can never both commit;
 *   - tile snapshots in the bucket TERRAD_TILES, each naming the log sequence
 *     it covers (written with compare-and-set, so an older snapshot never
 *     replaces a newer one), and the purge of the log they cover;
 *   - the world registry, the bucket TERRAD_WORLDS (name -> scene JSON).
 *
 * In the tick (DESIGN.md "One tick"), the JetStream store calls
 * cluster_wal_append after the deformation and before anything of the tick is
 * published: the publish is acknowledged by the stream's replicas (Raft) or
 * the tick is undone. Records and snapshots are opaque bytes here; their
 * format is the store's. A record or snapshot larger than the servers'
 * max_payload is split into parts and put back together on reading.
 *
 * Layer: above store (it may use store's public types) and below service.
 * Every call is blocking and thread-safe (the NATS client has its own
 * threads); a world name is 1..64 of [A-Za-z0-9_-].
 */
#ifndef TERRAD_CLUSTER_H
#define TERRAD_CLUSTER_H

#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "store/store.h"
#include "world/world.h"

#define CLUSTER_WORLD_NAME_MAX 64
#define CLUSTER_NODE_NAME_MAX 64

typedef enum cluster_status {
    CLUSTER_OK = 0,
    CLUSTER_ERROR = -1,  /* NATS unreachable, timed out or refused; err says which */
    CLUSTER_FENCED = -2, /* another owner appended or took the lease: stop claiming */
} cluster_status;

typedef struct cluster_config {
    const char *urls; /* "nats://127.0.0.1:4222,nats://..." (comma-separated) */
    const char *node; /* this node's name, 1..64 of [A-Za-z0-9_-] */
    int replicas;     /* of the stream and buckets; 0: 3 when >= 3 servers are known, else 1 */
    int lease_ms;     /* a lease not renewed for this long may be taken (0: 3000) */
    int renew_ms;     /* a thread renews held leases this often (0: 1000; < 0: no thread,
                         the caller renews with cluster_lease_renew) */
    int timeout_ms;   /* connect and each request (0: 2000) */
} cluster_config;

typedef struct cluster cluster;

/* Connects (refusing with an error naming the URLs when none answers),
 * then creates the stream and buckets if missing. A JetStream cluster that
 * is still electing its leader is waited for, up to a few timeouts. */
cluster *cluster_connect(const cluster_config *c, error_text *err);
/* Releases the leases held, closes. NULL is fine. */
void cluster_close(cluster *cl);

/* 1 while connected to a server (the client reconnects by itself). */
int cluster_connected(cluster *cl);
const char *cluster_node(const cluster *cl);
/* The largest message the servers take (their max_payload). */
int64_t cluster_max_payload(const cluster *cl);
/* The replicas used for the stream and the buckets. */
int cluster_replicas(const cluster *cl);

/* 1 when name is a valid world (or node) name, else 0 with err saying why. */
int cluster_name_valid(const char *name, const char *what, error_text *err);

/* ---- Messages between nodes (cluster.c) ----
 * Plain NATS subjects, not JetStream: nothing is stored or acknowledged.
 * NATS delivers the messages of one publisher to one subscription in the
 * order they were published; that is all the relays (docs/cluster.md, any
 * node serves any world) rely on. */
typedef struct cluster_sub cluster_sub;
/* Called on a thread of the NATS client, one message at a time per subscription. */
typedef void (*cluster_msg_fn)(void *ctx, const char *subject, const void *data, size_t len);
/* Publishes (buffered by the client, no answer): CLUSTER_OK, or CLUSTER_ERROR. */
cluster_status cluster_publish(cluster *cl, const char *subject, const void *data, size_t len);
/* fn gets every message on subject (NATS wildcards allowed) until unsubscribed. */
cluster_sub *cluster_subscribe(cluster *cl, const char *subject, cluster_msg_fn fn, void *ctx,
                               error_text *err);
/* Request and answer (any node serves any world's HTTP views): fn turns a
 * request's bytes into its answer's (*answer malloc'd, or NULL: no answer). */
typedef void (*cluster_answer_fn)(void *ctx, const void *data, size_t len, void **answer,
                                  size_t *answer_len);
/* fn answers every request on subject until unsubscribed (on a NATS thread). */
cluster_sub *cluster_serve_requests(cluster *cl, const char *subject, cluster_answer_fn fn,
                                    void *ctx, error_text *err);
/* Sends a request on subject and waits up to timeout_ms for its answer: 1
 * with *answer (malloc'd), 0 when nobody serves the subject now (NATS's "no
 * responders"), -1 with err (no answer in time, NATS unreachable). */
int cluster_request(cluster *cl, const char *subject, const void *data, size_t len, int timeout_ms,
                    void **answer, size_t *answer_len, error_text *err);
/* Messages the client dropped for this subscription (it fell behind), since it began. */
int64_t cluster_sub_dropped(cluster_sub *s);
/* Ends it; returns once no call of fn runs (or after 2 s). NULL is fine. */
void cluster_unsubscribe(cluster_sub *s);

/* ---- Leases (cluster_lease.c) ---- */

/*
 * Tries to take world's lease for this node. Returns 1 when this node holds
 * it now, 0 when another node holds it (holder, if not NULL, gets its name),
 * -1 on an error. A lease whose revision has not changed for lease_ms since
 * this node first saw it is taken over; so is a released one.
 */
int cluster_lease_acquire(cluster *cl, const char *world, char *holder, size_t holder_cap,
                          error_text *err);
/* Renews a held lease (the renewal thread does it every renew_ms): CLUSTER_OK, CLUSTER_FENCED when
 * another node took it (it is no longer held), CLUSTER_ERROR when NATS did
 * not answer (still held until lease_ms after the last renewal). */
cluster_status cluster_lease_renew(cluster *cl, const char *world, error_text *err);
/* 1 while this node holds world's lease: taken and renewed less than
 * lease_ms ago (so a node cut off from NATS stops claiming by itself). */
int cluster_lease_held(cluster *cl, const char *world);
/* Deletes the lease if this node holds it, so another node takes it at once. */
void cluster_lease_release(cluster *cl, const char *world);
/* The node holding world's lease ("" when none): 1, 0 when none, -1 error. */
int cluster_lease_holder(cluster *cl, const char *world, char *holder, size_t cap, error_text *err);

/* ---- The fenced write-ahead log (cluster_wal.c) ---- */

typedef struct cluster_wal cluster_wal;

/* One world's log; no network access yet. */
cluster_wal *cluster_wal_open(cluster *cl, const char *world, error_text *err);
void cluster_wal_close(cluster_wal *w);

/* Called for each record in order; a non-zero return stops the reading. */
typedef int (*cluster_record_fn)(void *ctx, uint64_t seq, const uint8_t *data, size_t len);

/*
 * Reads the world's records with sequences >= from_seq up to the subject's
 * current end (owner markers and confirm records are skipped, a record whose parts are not all
 * there is dropped), and makes that end the sequence the next append
 * expects. Returns CLUSTER_OK or CLUSTER_ERROR.
 */
cluster_status cluster_wal_read(cluster_wal *w, uint64_t from_seq, cluster_record_fn on_record,
                                void *ctx, error_text *err);
/*
 * Becomes the world's writer: reads from from_seq to the end (as
 * cluster_wal_read) and appends an owner marker naming this node, expecting
 * that end; if another writer appended meanwhile, reads on and tries again.
 * Then it confirms the take: a confirm record expecting the marker, and a
 * read from the end it recovered to that must find only its own marker and
 * confirm record — else what it found is applied and the take made again
 * (nats-server 2.9 can store an old owner's append in flight beside the
 * marker). After it returns CLUSTER_OK, on_record has had every record of
 * the log and every later append of an earlier owner is refused.
 */
cluster_status cluster_wal_take(cluster_wal *w, uint64_t from_seq, cluster_record_fn on_record,
                                void *ctx, error_text *err);
/* How many times the last cluster_wal_take found its take not clean and made it again. */
int64_t cluster_wal_takes_redone(const cluster_wal *w);
/*
 * Appends one record, expecting the subject's last sequence to be the one
 * this writer last saw; returns once the stream has acknowledged it
 * (*seq: its sequence). CLUSTER_FENCED: another owner appended since; the
 * log is unchanged by this call and this writer must stop.
 */
cluster_status cluster_wal_append(cluster_wal *w, const void *data, size_t len, uint64_t *seq,
                                  error_text *err);
/* The sequence the next append expects (0: the world has no record). */
uint64_t cluster_wal_last_seq(const cluster_wal *w);
/* Removes the world's records with sequences < seq (snapshots cover them);
 * the last message this writer saw always stays (the next append expects it). */
cluster_status cluster_wal_purge_below(cluster_wal *w, uint64_t seq, error_text *err);
/* The same without a writer (any thread): the caller keeps seq <= the last. */
cluster_status cluster_log_purge_below(cluster *cl, const char *world, uint64_t seq,
                                       error_text *err);

/* ---- Tile snapshots (cluster_kv.c) ---- */

/*
 * Stores world's snapshot of tile (tx, ty) that covers the log up to
 * covers_seq. Compare-and-set: when the stored one covers more, nothing is
 * written and CLUSTER_FENCED is returned (a deposed owner never replaces a
 * newer snapshot).
 */
cluster_status cluster_snapshot_put(cluster *cl, const char *world, int tx, int ty,
                                    uint64_t covers_seq, const void *data, size_t len,
                                    error_text *err);
/* 1 and a malloc'd *data when present, 0 when absent, -1 on an error. */
int cluster_snapshot_get(cluster *cl, const char *world, int tx, int ty, uint8_t **data,
                         size_t *len, uint64_t *covers_seq, error_text *err);
/*
 * The world's snapshot index, "<world>.index": the log sequence the last
 * complete compaction covers — recovery replays the log from there — and
 * every tile with a snapshot. put merges tiles into the stored index and
 * moves covers_seq forward only (compare-and-set, retried).
 */
cluster_status cluster_snapshot_index_put(cluster *cl, const char *world, uint64_t covers_seq,
                                          const int (*tiles)[2], int count, error_text *err);
/* 1 and a malloc'd *tiles (count pairs tx, ty), 0 when the world has none, -1 error. */
int cluster_snapshot_index_get(cluster *cl, const char *world, uint64_t *covers_seq,
                               int (**tiles)[2], int *count, error_text *err);

/* ---- The world registry (cluster_kv.c) ---- */

/* Registers a world: CLUSTER_FENCED when the name is taken. */
cluster_status cluster_world_add(cluster *cl, const char *name, const char *scene_json,
                                 error_text *err);
/* 1 and a malloc'd NUL-terminated *scene_json, 0 when unknown, -1 on an error. */
int cluster_world_get(cluster *cl, const char *name, char **scene_json, error_text *err);
/* The registered names, sorted, malloc'd (free each and the array); -1 on an
 * error. A listing that fails while NATS elects a leader is tried again for
 * up to 15 s (or 4 timeouts). */
int cluster_world_list(cluster *cl, char ***names, int *count, error_text *err);
/* The same, tried once: for a loop that lists again anyway and must not wait. */
int cluster_world_list_now(cluster *cl, char ***names, int *count, error_text *err);
/* Unregisters a world and deletes its log, snapshots and lease: 1, 0 when unknown, -1 error. */
int cluster_world_remove(cluster *cl, const char *name, error_text *err);

/* ---- A world's store on JetStream (cluster_store.c) ----
 * What the data directory (store.h) is on one machine: a tick's changed
 * rectangles with their new absolute values, zstd-compressed, as one record
 * of the fenced log; every compact_records records, the tiles changed since
 * the last time are copied at that tick boundary and a background thread
 * writes them as snapshots and then purges the log they cover. Recovery loads
 * the snapshots, replays the log over them (absolute values: a record older
 * than a snapshot followed by the newer records gives the same heights) and
 * fences earlier owners off. Only one thread (the sim thread) commits. */

typedef struct cluster_store cluster_store;

typedef struct cluster_store_config {
    int compact_records;   /* records between compactions (0: 600, 10 s at 60 Hz) */
    int compression_level; /* zstd level (0: 1) */
} cluster_store_config;

/* Takes world_name's log (see cluster_wal_take) and recovers it into w,
 * whose heights must hold the scene's base terrain. rec->tick: the last
 * tick committed, so the new owner continues the numbering. */
cluster_store *cluster_store_open(cluster *cl, const char *world_name, world *w,
                                  const cluster_store_config *c, store_recovery *rec,
                                  error_text *err);
/* Waits for a running compaction and closes (the lease is the caller's). */
void cluster_store_close(cluster_store *cs);
/*
 * Commits tick `tick`'s changed rectangles (values read from w); returns
 * once the stream acknowledged it. CLUSTER_ERROR: NATS did not answer (the
 * caller undoes the tick and retries later); CLUSTER_FENCED: another node
 * owns the world now (the caller undoes the tick and stops ticking it).
 */
cluster_status cluster_store_commit_tick(cluster_store *cs, const world *w, uint64_t tick,
                                         const world_rect *rects, int n, error_text *err);
/* 1 when a commit can be tried now: connected, the lease held, not fenced,
 * and 500 ms past a failed commit. Otherwise 0, and cluster_store_failure
 * says why. */
int cluster_store_writable(cluster_store *cs);
/* 1 once a commit was refused as fenced: another node owns the world now
 * (or the log moved on after an unanswered commit); this store is done. */
int cluster_store_fenced(const cluster_store *cs);
/* Why commits fail ("" when the last one succeeded). */
const char *cluster_store_failure(const cluster_store *cs);
/* The last tick committed (recovered or acknowledged). */
uint64_t cluster_store_tick(const cluster_store *cs);
/* Commit latency (publish to acknowledgement), milliseconds: p50 and p99. */
void cluster_store_commit_ms(const cluster_store *cs, double *p50, double *p99);
/* Compactions done, and the tiles they wrote (for tests and /metrics). */
void cluster_store_compactions(cluster_store *cs, int64_t *count, int64_t *tiles);
/* Waits until no compaction is pending or running. */
void cluster_store_wait_compaction(cluster_store *cs);
/* The store's face (store.h) over cs, for the service: commits go through
 * cluster_store_commit_tick, a tick is durable once committed, and
 * store_close closes cs. Call on the sim thread. NULL: out of memory. */
store *cluster_store_as_store(cluster_store *cs);

/* ---- A world's past for replays (cluster_history.c) ----
 * The reader spectators and GET /v1/heights?tick=N use on a cluster node
 * (store.h "a world's past"): any tick from the one the tile snapshots are
 * as of, read from JetStream on the replay's own thread. out->ctx is the
 * caller's until store_history_release. 0, or -1 (err). */
int cluster_history_make(cluster *cl, const char *world, store_history *out, error_text *err);

#endif
