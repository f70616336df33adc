/*
 * hub: the meeting point of the websocket thread, the HTTP threads and the
 * sim thread (docs/design.md, "Threads"); one tick takes its input from here
 * first and publishes its frames here last.
 *
 *   net → sim   commands (client joined/left, collider create/delete,
 *               subscribe/unsubscribe, resync) in a bounded queue, and a
 *               latest-pose table (latest wins per collider);
 *   sim → net   the tick's outbound frames in order: each encoded once,
 *               reference counted, and either addressed to one client or
 *               tagged with the tile it belongs to for fan-out;
 *   http → sim  height reads, served by the sim thread between ticks.
 *
 * Every call takes one mutex for a short copy; none waits on another thread
 * except hub_read_heights, which is only called from the HTTP threads. The
 * sim thread never blocks on the network, and the network never blocks a
 * tick. Queues are bounded: a full command queue refuses the command (the
 * net thread answers the client), a full outbound queue drops tile deltas
 * and marks every client for a resync (counted).
 *
 * The daemon's threads and every place they meet are mapped once, in
 * docs/design.md ("Threads" and "Where they meet"); the hub is the main one.
 * Ownership is checked, not only described: each end of the hub asserts its
 * thread (THREAD_OWNED) in debug and sanitizer builds; the sim thread claims
 * the sim end (service_create), the net thread the net end while it runs;
 * hub_read_heights refuses the sim thread. The HTTP pool has no single
 * owner thread to claim: it meets the others only at the hub's height reads,
 * http_status and the metrics (and its listener's guard).
 */
#ifndef TERRAD_HUB_H
#define TERRAD_HUB_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "collider/collider.h"
#include "world/world.h"

typedef struct hub hub;

hub *hub_create(void);
void hub_destroy(hub *h);

/* Thread ownership of the two ends: each side claims its end from its own
 * thread (the sim thread when it creates the service, the net thread when it
 * starts); until then, and after the net end is released, nothing is checked. */
void hub_claim_sim_end(hub *h);
void hub_claim_net_end(hub *h);
void hub_release_net_end(hub *h);

/* ---- net → sim: commands ---- */

typedef enum hub_command_kind {
    HUB_CLIENT_JOINED,
    HUB_CLIENT_LEFT,     /* sim deletes the client's colliders */
    HUB_COLLIDER_CREATE, /* id assigned by the net thread, unique for the daemon's life */
    HUB_COLLIDER_DELETE,
    HUB_SUBSCRIBE, /* sim answers with snapshot frames for the client */
    HUB_UNSUBSCRIBE,
    HUB_RESYNC, /* fresh snapshots of one (subscription != 0) or all subscriptions */
    HUB_EDIT,   /* a terrain edit: from a client (client != 0) or HTTP (waiter != NULL) */
    /* a snapshot of one tile of a subscription (rect: tile ∩ subscription), no
     * snapshot_done mark: the client's other tiles' deltas never pause
     * (PROTOCOL.md "resync" with "tiles") */
    HUB_RESYNC_TILE,
} hub_command_kind;

/* An HTTP caller waiting for its edit (hub_edit_submit); opaque. */
typedef struct hub_edit_waiter hub_edit_waiter;

typedef struct hub_command {
    hub_command_kind kind;
    uint32_t client;
    uint32_t collider;          /* create / delete */
    uint32_t subscription;      /* subscribe / unsubscribe / resync (0 = all) */
    world_rect rect;            /* subscribe: inside the world (checked by the net thread) */
    collider_geometry geometry; /* create; for a mesh, geometry.mesh == mesh */
    collider_mesh *mesh;        /* create, mesh shapes: owned by the command, then by the sim */
    collider_pose pose;         /* create: initial pose */
    char material[32];          /* create */
    int feedback;               /* create: send CONTACT entries for this collider */
    double load_n;              /* create: > 0 load-driven (bekker), the load in newtons */
    int forces_height;          /* create: its FORCES entries carry its pose height */
    int colliders;              /* subscribe: send COLLIDERS frames for this region */
    int grousers;               /* subscribe: ... with the grousers extension (PROTOCOL.md) */
    int footprints;             /* subscribe: send FOOTPRINTS frames for this region */
    int snapshot_base;          /* joined: 0, or its snapshots against the base: 1 encoding 2,
                                   2 encoding 2 or 3 (PROTOCOL.md "Slope snapshots") */
    char ref[64];               /* the client's request reference, echoed in replies */
    world_edit *edit;           /* edit: owned by the command, then by the sim */
    hub_edit_waiter *waiter;    /* edit from HTTP: hub_edit_finish tells it the outcome */
} hub_command;

/* Returns 0, or -1 when the queue is full (the command is not taken: the
 * caller still owns cmd->mesh). */
int hub_push_command(hub *h, const hub_command *cmd);
/* sim thread: move up to max queued commands into out, in arrival order. */
int hub_take_commands(hub *h, hub_command *out, int max);

/* ---- http → sim: terrain edits ---- */

/* What became of an edit. code 0: applied at `tick`, changing the cells of
 * rect by `volume` units in all; else a TERRAD_E_* code and why. */
typedef struct hub_edit_result {
    int code;
    uint64_t tick;
    int64_t volume;
    world_rect rect;
    char message[320];
} hub_edit_result;

/* Any thread but the sim thread (the HTTP threads): queue the edit (taken
 * over, whatever happens) with the commands, in arrival order, and wait up
 * to timeout_ms for the tick that applies or refuses it. 0 with *res
 * filled; -1 when the queue is full (nothing queued); 1 on timeout (the edit
 * stays queued and is still applied or refused at its tick). */
int hub_edit_submit(hub *h, world_edit *e, hub_edit_result *res, int timeout_ms);
/* sim thread: an HTTP edit's outcome, for its waiter (which may be gone). */
void hub_edit_finish(hub_edit_waiter *w, const hub_edit_result *res);

/* ---- net → sim: poses ---- */

typedef struct hub_pose {
    uint32_t collider;
    uint32_t client;
    uint32_t sequence; /* the client's POSE_BATCH sequence it came in */
    collider_pose pose;
    double received_ms; /* set by hub_set_pose: for the pose-to-delta latency */
} hub_pose;

/* Latest wins per collider. The net thread has already checked ownership
 * and values. Returns -1 if the table is full (it holds every live collider,
 * so only when far more than the limits allow exist). */
int hub_set_pose(hub *h, const hub_pose *pose);
/* Drop a collider's pending pose (collider deleted). */
void hub_forget_pose(hub *h, uint32_t collider);
/* sim thread: take every pose set since the last call (max entries). */
int hub_take_poses(hub *h, hub_pose *out, int max);

/* Every accepted POSE_BATCH, empty or not: the next tick ACKs the client's
 * latest sequence. Latest wins per client. */
typedef struct hub_batch {
    uint32_t client;
    uint32_t sequence;
} hub_batch;

#define HUB_BATCH_CAPACITY 4096 /* clients with a pending batch sequence */

void hub_note_batch(hub *h, uint32_t client, uint32_t sequence);

/* One POSE_BATCH whole: its poses (as hub_set_pose) and its sequence (as
 * hub_note_batch) under one hold of the lock, so a tick that takes its input
 * with hub_take_input gets all of a batch or none of it, and the ACK it sends
 * names the last batch whose poses it used (PROTOCOL.md, ACK; a predicting
 * client replays the ticks from the ACKs, docs/engines.md). Returns the poses
 * stored: fewer than n when the table is full. */
int hub_set_batch(hub *h, uint32_t client, uint32_t sequence, const hub_pose *poses, int n);
/* sim thread: a tick's input in one hold of the lock: every pose set since the
 * last take (up to max_poses, *pose_count of them) and every noted batch
 * (batches: HUB_BATCH_CAPACITY entries). Returns the batches taken. */
int hub_take_input(hub *h, hub_pose *poses, int max_poses, int *pose_count, hub_batch *batches);

/* ---- net → sim: steps of a client-clocked world (PROTOCOL.md "STEP") ----
 * Such a world ticks only when its driver says so: each accepted STEP is
 * queued here whole (its poses checked by the net thread), and each of its
 * ticks takes its pose set from it instead of the pose table. */

typedef struct hub_step {
    uint32_t client; /* the driver */
    uint32_t seq;    /* the client's step number (ACK and STEPPED echo it) */
    uint32_t ticks;  /* >= 1 */
    int count, sets; /* poses per set; sets 0 (hold), 1 (first tick) or ticks */
    hub_pose *poses; /* sets * count, tick-major; malloc'd, owned by the step */
} hub_step;

#define HUB_STEP_CAPACITY 64 /* steps queued per world: a driver's pipeline depth */

/* Queue a step (taken over: its poses are the hub's then the sim's), then
 * call the notify function with its ticks (a height read calls it with 0:
 * the world serves reads between steps). 0, or -1 when HUB_STEP_CAPACITY
 * steps wait already (nothing taken). Net thread. */
int hub_push_step(hub *h, hub_step *st);
/* sim thread: the oldest queued step (1), or 0 when none waits. */
int hub_take_step(hub *h, hub_step *out);
/* How the world's clock learns that ticks are due (the ticker's client clock:
 * fn adds ticks to what it owes the world). Set before any step can come. */
void hub_set_step_notify(hub *h, void (*fn)(void *arg, uint32_t ticks), void *arg);
void hub_step_free(hub_step *st);

/* ---- sim → net: frames ---- */

/* Bytes of headroom before a frame's payload: libwebsockets writes its frame
 * header there (the net thread asserts HUB_FRAME_HEADROOM >= LWS_PRE). */
#define HUB_FRAME_HEADROOM 32

typedef struct hub_frame {
    atomic_int refs;
    int binary; /* 1: binary frame, 0: text (JSON) */
    size_t len;
    unsigned char *data; /* = storage + HUB_FRAME_HEADROOM */
    unsigned char storage[];
} hub_frame;

hub_frame *hub_frame_new(int binary, size_t len); /* refs = 1 */
hub_frame *hub_frame_from_text(const char *text); /* a JSON text frame */
void hub_frame_ref(hub_frame *f);
void hub_frame_unref(hub_frame *f);

typedef enum hub_out_kind {
    HUB_OUT_CLIENT,     /* for one client (replies, snapshots, contacts, acks) */
    HUB_OUT_TILE_DELTA, /* for every client whose subscriptions meet the tile */
    HUB_OUT_TICK_DONE,  /* the tick's frames are all out (frame is NULL) */
} hub_out_kind;

typedef struct hub_out {
    hub_out_kind kind;
    uint32_t client;    /* HUB_OUT_CLIENT */
    int tile_x, tile_y; /* HUB_OUT_TILE_DELTA: tile coordinates (cells / tile_size) */
    int snapshot_done;  /* HUB_OUT_CLIENT: the last snapshot frame of a subscribe/resync */
    int msg; /* HUB_OUT_CLIENT: the frame's TERRAD_MSG_* type as its maker knew it (0: a JSON
              * reply); the net thread's drop rules go by it, not by the wire byte */
    uint64_t tick;
    hub_frame *frame; /* the queue holds one reference */
} hub_out;

/* sim thread: append in order (takes over the frames' references) and wake
 * the net thread. Returns the number dropped because the queue was full. */
int hub_publish(hub *h, hub_out *items, int count);
/* net thread: take up to max items in order; the caller owns their references. */
int hub_take_outbound(hub *h, hub_out *out, int max);
/* 1 once if the outbound queue overflowed since the last call (every client
 * must then be resynchronised). */
int hub_take_overflow(hub *h);
/* How the sim thread wakes the net thread (lws_cancel_service). */
void hub_set_waker(hub *h, void (*wake)(void *arg), void *arg);

/* ---- sim → net: storage state ---- */

/* sim thread: whether the store can make ticks durable, and why not. While it
 * cannot, the net thread refuses pose batches with store_unavailable. */
void hub_set_store_unavailable(hub *h, const char *reason); /* NULL or "": available */
/* net thread: 1 and the reason while unavailable, else 0. */
int hub_store_unavailable(hub *h, char *reason, size_t cap);

/* ---- http → sim: height reads ---- */

/* What a read copies: the heights, or the per-cell compaction memory
 * (world_layer_gather of WORLD_LAYER_COMPACTION: zeros where none). */
typedef enum hub_layer { HUB_LAYER_HEIGHTS, HUB_LAYER_COMPACTION } hub_layer;

/* Any thread but the sim thread (the HTTP threads): copy a rectangle (inside the world) of
 * heights as of the end of a tick. Waits up to timeout_ms; returns 0, or -1
 * on timeout or when the sim thread is gone. */
int hub_read_heights(hub *h, world_rect r, int32_t *out, uint64_t *tick, int timeout_ms);
/* The same for any layer. */
int hub_read_layer(hub *h, hub_layer layer, world_rect r, int32_t *out, uint64_t *tick,
                   int timeout_ms);
/* Reads waiting to be served (any thread). */
int hub_reads_pending(hub *h);
/* sim thread, between ticks: serve the pending reads, answered as of tick,
 * which hub_publish_tick has published (debug and sanitizer builds abort
 * otherwise: nothing names a tick before its status). */
void hub_serve_reads(hub *h, const world *w, uint64_t tick);
/* sim thread: tick is published — first of all who tell of it (service_tick
 * row 9: then its host's status, its frames, the reads it answers); at
 * service_attach_store, the recovered tick. */
void hub_publish_tick(hub *h, uint64_t tick);
/* Any thread: the world's published tick (0 before any). Nothing names a
 * later tick — no frame, read or status — so a check of "is tick N in the
 * future" that reads it never refuses a tick a client was told of; the net
 * thread's own tick (the frames it has dispatched) may lag behind it, under
 * group:MS by up to MS. */
uint64_t hub_published_tick(hub *h);
/* sim thread, at exit: fail every pending and future read. */
void hub_close_reads(hub *h);
/* Any thread: 1 once the reads are closed (the world is leaving), so a long
 * read beside the hub (a past-tick rebuild from the files) stops too. */
int hub_reads_closed(hub *h);
/* The world stops (deleted, lost, or the daemon stops): every HTTP edit
 * waiting for a tick, and every later one, is answered at once with
 * TERRAD_E_SHUTTING_DOWN and why, instead of waiting out its timeout. Any
 * thread. */
void hub_close_edits(hub *h, const char *why);

/* ---- the one table of the worlds served here (hub_worlds.c) ----
 * Every world a daemon or a cluster node ticks is one entry, added once by
 * its host (host/host_world.c) when it serves and removed once when it stops;
 * the HTTP threads (?world=NAME, GET /v1/worlds' 404s) and the net thread
 * (hello's world) read this one table. HTTP requests and spectators' replay
 * threads (net_spectate.c) take an entry for as long as they run
 * (hub_worlds_acquire); the net thread holds each entry it
 * made a world state for (hub_worlds_hold_next) until it detached it
 * (hub_worlds_let_go). Removal takes the entry out of the table at once, so
 * nobody new finds it, then waits for both to let go. Any thread. */
#define HUB_WORLDS_MAX 320    /* a node's 256 (--max-worlds), with room for those leaving */
#define HUB_WORLD_NAME_MAX 64 /* as cluster names */
typedef struct hub_worlds hub_worlds;
/* One world on the ports, as its host fills it (read-only once added). The
 * ports' own views of it are opaque here, hub/ sitting below them: status is
 * http/'s http_status, info net/'s net_world_info; both, like h and base,
 * stay valid until hub_worlds_remove returns. */
typedef struct hub_world {
    char name[HUB_WORLD_NAME_MAX + 1];
    hub *h;
    const world *base; /* its base terrain (/v1/heights?base=1) */
    /* where replays beside it read its past (?tick=N, spectators): store/'s
     * store_history (opaque here, hub/ beside store/) — a data directory, or
     * a cluster node's JetStream reader; NULL: none (memory only) */
    const void *history;
    void *status;
    const void *info;
    int deleted; /* set by hub_worlds_remove: its clients are told it was deleted */
} hub_world;

hub_worlds *hub_worlds_create(void);
/* After every entry was removed and the readers stopped. NULL is fine. */
void hub_worlds_destroy(hub_worlds *t);
/* changed(ctx) is called (under the table's lock: quick, never calling the
 * table) after every add and remove, and again while a removal waits for its
 * holder: the net thread's waker. One watcher; NULL stops it, and once this
 * returns the old one is not called again. */
void hub_worlds_watch(hub_worlds *t, void (*changed)(void *ctx), void *ctx);
/* w copied into the table: the entry, or NULL with err (the table is full).
 * With a watcher set, returns once the holder holds it (10 s at most), so a
 * client told the world serves finds it on the websocket port too. */
hub_world *hub_worlds_add(hub_worlds *t, const hub_world *w, error_text *err);
/* A single daemon's default world is the entry named name (copied; NULL or
 * "": none, as on a cluster node, whose first entry is the default). */
void hub_worlds_set_default(hub_worlds *t, const char *name);
/* 1 with the default name in name when one is set, else 0 (name ""). */
int hub_worlds_default(hub_worlds *t, char *name, size_t cap);
/* w leaves the table (deleted: its clients are told so), then this waits for
 * the requests using it to end (close its hub's reads first) and for its
 * holder to let go: 0, or -1 when the holder did not within 10 s (w is then
 * left to it, and so must its hub be: the holder may still use it). Readers
 * are waited for however long they take, since they read w's fields; those
 * still using it after HUB_WORLDS_READER_DEADLINE_MS are logged and counted
 * (terrad_world_readers_overdue_total). */
#define HUB_WORLDS_READER_DEADLINE_MS 10000.0
int hub_worlds_remove(hub_worlds *t, hub_world *w, int deleted);
/* The world named name (NULL: the default world — the entry of the default
 * name when one is set, else the first), counted as in use until
 * hub_worlds_release; NULL when there is none. */
hub_world *hub_worlds_acquire(hub_worlds *t, const char *name);
void hub_worlds_release(hub_worlds *t, hub_world *w);
/* 1 once w's removal began (a reader that runs long, a spectator's replay
 * thread, asks between records and lets go: the removal waits for it). */
int hub_worlds_leaving(const hub_world *w);
/* The names in the table, each quoted, ", " between, into out (cut at cap): how many. */
int hub_worlds_names(hub_worlds *t, char *out, size_t cap);
/* Changes on every add and remove: a holder compares it to skip the rest. */
unsigned hub_worlds_generation(hub_worlds *t);
/* The holder (the net thread): an entry of the table it does not hold yet,
 * held from now on; NULL when it holds them all. */
hub_world *hub_worlds_hold_next(hub_worlds *t);
/* The holder: an entry it holds that has left the table; NULL when none. It
 * detaches what it made for it, then lets go. */
hub_world *hub_worlds_gone_next(hub_worlds *t);
void hub_worlds_let_go(hub_worlds *t, hub_world *w);

/* ---- a terrain edit's wire form (hub_edit.c; PROTOCOL.md "edit") ---- */

typedef struct hub_edit_error {
    int code;          /* TERRAD_E_BAD_VALUE, _OUTSIDE_WORLD, _TOO_LARGE (proto/c) */
    char message[300]; /* names the field */
} hub_edit_error;
/* An `edit` message's fields (its "type" and "ref" are the caller's) into
 * out, for a width x height world, refusing one over max_cells. 0, or -1
 * with err (nothing held). Free a parsed edit with world_edit_free. Any thread. */
int hub_edit_parse(const cJSON *msg, int width, int height, int64_t max_cells, world_edit *out,
                   hub_edit_error *err);

#endif
