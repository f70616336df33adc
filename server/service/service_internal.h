/*
 * service_internal.h: what the files of server/service share — the service
 * record, the tick's batch of working buffers, and the steps service_tick
 * (service.c) calls in order. Not part of the face of service/; everything
 * here runs on the sim thread only (service->owner).
 *
 *   service.c           life cycle, the tick's table of contents
 *   service_commands.c  take commands, poses and batch sequences from the hub
 *   service_contacts.c  contact feedback before/after the deformation, ACKs
 *   service_deltas.c    cut dirty rectangles into tiles, encode deltas, snapshots
 *   service_colliders.c COLLIDERS frames for viewers
 *   service_footprints.c FOOTPRINTS frames for viewers
 *   service_checksums.c CHECKSUM frames (desync detection), one tile's resync
 *   service_shed.c      the tick's cost budget: whose colliders wait a tick
 *   service_snapshots.c snapshots off the tick: copied here, framed by a worker
 *   service_edits.c     terrain edits from game logic, at the start of the tick
 *   service_steps.c     a client-clocked world's ticks: input from its driver's STEP
 *   service_shared.c    the leaf every step uses: lookups, the out queue, drops
 *
 * service.c calls the steps; a step calls only steps listed after it in the
 * tick and service_shared.c, so the call graph of service/ is acyclic.
 */
#ifndef TERRAD_SERVICE_INTERNAL_H
#define TERRAD_SERVICE_INTERNAL_H

#include "service/service.h"

#include "terrad_proto.h"

/* A frame never grows past the protocol's max_message_bytes. */
#define SERVICE_FRAME_MAX (1024 * 1024)
#define SERVICE_COMMANDS_PER_TICK 1024

typedef struct svc_subscription {
    uint32_t id;
    world_rect rect;
    int colliders;  /* asked for COLLIDERS frames */
    int grousers;   /* ... with the grousers extension */
    int footprints; /* asked for FOOTPRINTS frames */
} svc_subscription;

typedef struct svc_client {
    uint32_t id;
    uint32_t last_sequence;
    int sequence_pending; /* a batch was used since the last ACK */
    svc_subscription *subs;
    int sub_count;
    int64_t sub_capacity;
    uint64_t colliders_hash;      /* of the last COLLIDERS frame sent, 0: none yet */
    uint64_t colliders_sent_tick; /* when it was sent */
    /* the tick's cost budget (service_shed.c) */
    int64_t tick_cells; /* footprint cells of its posed colliders this tick */
    int held;           /* its colliders wait this tick (and its ACK with them) */
    int held_last;      /* they waited last tick: not held again this one */
    int snapshot_base;  /* its snapshots against the base (hello; PROTOCOL.md): 1 encoding 2,
                           2 encoding 2 or 3, whichever codes a piece shorter */
} svc_client;

typedef struct svc_collider {
    uint32_t id, client;
    collider_geometry *geometry; /* on the heap: backends cache by its address */
    collider_mesh *mesh;         /* owned, for mesh shapes */
    collider_pose pose, previous_pose;
    int has_pose; /* created without a pose: inert until its first POSE_BATCH */
    int has_previous, feedback;
    double load_n;     /* > 0: load-driven, its height the engine's (sim_collider.load_n) */
    int forces_height; /* collider_create "forces_height": FORCES carries its height */
    int held;          /* waits this tick (service_shed.c): no deformation, previous pose kept */
    /* a pose taken this tick (service_bound_sweeps may refuse it): where the
     * collider stood before it, and the POSE_BATCH it came in */
    int pose_new, had_pose;
    collider_pose pose_before;
    uint32_t pose_sequence;
    collider_cost cost; /* collider_cost_of, once at its creation (a mesh's is O(triangles)) */
} svc_collider;

typedef struct svc_contact {
    terrad_contact contact;
    uint32_t client;
} svc_contact;

typedef struct snapshot_job {
    uint32_t client;
    world_rect rect;
    int last;  /* the last job of its request: marks snapshot_done */
    int marks; /* on the last job: identical requests coalesced into this one */
    int quiet; /* one tile's resync (HUB_RESYNC_TILE): no snapshot_done mark */
} snapshot_job;

/* Snapshot cells compressed per tick, over every client: past it, requests
 * wait for a later tick (a request is never split, so its frames all carry
 * one tick's versions). One request per client per tick while others wait. */
#define SERVICE_SNAPSHOT_CELLS_PER_TICK (512 * 512)

/* An edit applied this tick (service_edits.c), until the tick is committed. */
typedef struct svc_edit {
    world_edit_op op;
    world_rect rect;
    int32_t *diff; /* new minus old over rect */
    int64_t volume;
    uint32_t client;         /* websocket sender (waiter == NULL) */
    char ref[64];            /* its ref, JSON text */
    hub_edit_waiter *waiter; /* HTTP sender */
} svc_edit;

/* An HTTP edit's answer held until its tick is durable (a group commit). */
typedef struct svc_edit_answer {
    hub_edit_waiter *waiter;
    world_edit_op op;
    hub_edit_result res;
} svc_edit_answer;

/* One piece of a dirty rectangle inside one tile. */
typedef struct tile_piece {
    int tile;   /* tile index */
    int window; /* engine window it came from; < 0: edit -1 - window */
    world_rect rect;
} tile_piece;

/* The tick's working buffers, kept from tick to tick so that a steady tick
 * allocates nothing (capacities are array_grow's). */
typedef struct service_batch {
    hub_command *commands; /* SERVICE_COMMANDS_PER_TICK, taken from the hub */
    hub_pose *poses;       /* taken from the hub */
    hub_batch *batches;    /* HUB_BATCH_CAPACITY, taken from the hub with the poses */
    int64_t pose_capacity;
    double oldest_pose_ms;   /* earliest arrival among this tick's poses, 0 if none */
    sim_collider *colliders; /* what the engine deforms with: posed clients' and extra */
    int64_t collider_capacity;
    svc_contact *contacts; /* contact feedback, measured before and finished after */
    int contact_count;
    int64_t contact_capacity;
    tile_piece *pieces; /* the dirty rectangles cut along tile edges, sorted by tile */
    int piece_count;
    int64_t piece_capacity;
    snapshot_job *snapshots; /* subscriptions and resyncs not yet answered (FIFO) */
    int snapshot_count;
    int64_t snapshot_capacity;
    hub_out *out; /* frames to publish; may hold earlier ticks' waiting for a group commit */
    int out_count;
    int64_t out_capacity;
} service_batch;

/* The STEP being ticked (service_steps.c): its ticks done so far. */
typedef struct service_step_state {
    hub_step step; /* ticks 0: none */
    uint32_t done;
} service_step_state;

struct service {
    sim_engine *engine;
    world *world;
    hub *hub;
    store *store;       /* NULL: memory only */
    int store_down;     /* last state told to the hub */
    int tick_logged;    /* the tick is in the store's log (or no store): its ACKs may go */
    thread_owner owner; /* the sim thread: claimed by service_create */
    uint64_t tick;
    int64_t volume;
    service_publish_fn publisher; /* the host's: the tick's status (service_set_publisher) */
    void *publisher_arg;
    int tiles_x, tiles_y;
    uint32_t *tile_versions;
    terrad_codec *codec;

    svc_client *clients;
    int client_count;
    int64_t client_capacity;
    svc_collider *colliders; /* sorted by id (ids only grow) */
    int collider_count;
    int64_t collider_capacity;

    service_batch batch;

    svc_edit *edits; /* this tick's, in the order applied */
    int edit_count;
    int64_t edit_capacity;
    svc_edit_answer *held_answers; /* HTTP edits of ticks not durable yet, oldest first */
    int held_answer_count;
    int64_t held_answer_capacity;
    world_rect *commit_rects; /* edits' and the engine's, for the store */
    int64_t commit_capacity;

    /* scratch */
    int32_t *values; /* one tile of values */
    uint8_t *packed; /* compressed tile */
    size_t packed_cap;
    int32_t *bottom; /* contact scratch */
    int64_t bottom_cap;
    terrad_collider_state *states; /* COLLIDERS scratch */
    int64_t state_capacity;
    terrad_collider_grousers *lugs; /* COLLIDERS scratch: each state's grousers */
    int64_t lug_capacity;
    terrad_footprint *events; /* FOOTPRINTS scratch: one client's events */
    int64_t event_capacity;

    struct snap_worker *snapper; /* service_snapshots.c */

    int client_clock; /* ticks made due by STEP messages (service_steps.c) */
    service_step_state step;

    /* the tick's cost budget and one client's sweep budget (service_shed.c); 0: none */
    int64_t max_tick_cells, max_sweep_cells;
    double last_shed_log_ms, last_sweep_log_ms;
    uint64_t shed_unlogged;

    int checksum_interval; /* ticks between CHECKSUM frames (service_checksums.c); 0: none */
    terrad_tile_sum *sums; /* CHECKSUM scratch: one subscription's tiles */
    int64_t sum_capacity;

    /* dropped work: logged at most once a second (the metric counts all) */
    double last_drop_log_ms;
    uint64_t drops_unlogged;
};

/* service_shared.c */
svc_client *service_find_client(service *s, uint32_t id);
int service_find_collider(const service *s, uint32_t id); /* index, or -1 */
/* Count dropped work (terrad_service_dropped_total{reason}) and log it, at
 * most once a second. */
void service_note_drop(service *s, const char *reason, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* Append a frame to the tick's out queue (takes over its reference). A NULL
 * frame (its allocation or encoding failed) or no room is counted as a
 * dropped frame; returns 0 or -1. */
int service_queue_out(service *s, hub_out item);
/* Queue frame f, a TERRAD_MSG_* msg, for one client (snapshot_done: the last
 * frame of a subscribe/resync answer). */
int service_queue_client(service *s, uint32_t client, hub_frame *f, int msg, int snapshot_done);
/* A JSON reply (obj, taken over) to a websocket client, with the request's ref
 * (JSON text, "" for null) added. */
void service_reply_json(service *s, uint32_t client, const char *ref, struct cJSON *obj);

/* service_commands.c */
void service_release_collider(service *s, svc_collider *c);
/* take the hub's commands, poses and batch sequences, and apply them */
void service_take_input(service *s);
/* Take n poses as this tick's (as from the pose table: a pose of a collider
 * gone or another client's is skipped). */
void service_apply_poses(service *s, const hub_pose *poses, int n);

/* service_steps.c */
/* A client-clocked world: the current step's poses for this tick (taking the
 * next step from the hub when none is under way), and its ACK. */
void service_step_input(service *s);
/* After the tick's frames: the step's last tick queues its STEPPED. */
void service_step_finish(service *s);

/* service_contacts.c */
void service_contacts_before_tick(service *s);
void service_contacts_after_tick(service *s, const sim_tick_report *report);
/* CONTACT, FORCES (bekker worlds: the report's contacts) and ACK per client. */
void service_publish_feedback(service *s, const sim_tick_report *report);

/* service_deltas.c */
int service_cut_into_tiles(service *s, const sim_tick_report *report);
void service_publish_deltas(service *s, service_tick_stats *stats);
void service_publish_snapshots(service *s);
/* A client left: its pending snapshot requests are dropped, never built. */
void service_drop_snapshots(service *s, uint32_t client);

/* service_snapshots.c: the worker that compresses and frames snapshots */
typedef struct snap_worker snap_worker;
int service_snapshots_start(service *s);
void service_snapshots_stop(service *s);
/* copy a job's cells and tile versions (tick t) for the worker */
void service_snapshot_stage(service *s, const snapshot_job *job);
void service_snapshots_hand_over(service *s); /* end of tick t */
void service_snapshots_collect(service *s);   /* start of tick t + 1: queue the frames */

/* service_shed.c: mark the colliders that wait this tick (before they are gathered) */
void service_shed(service *s);
void service_bound_sweeps(service *s); /* after the poses are taken, before service_shed */

/* service_edits.c */
void service_edit_command(service *s, hub_command *c); /* apply it now, or refuse it */
/* The tick's rectangles for the store: the edits', the engine's, then where only the soil
 * state changed (bekker) (-1: no memory). */
int service_edits_commit_rects(service *s, const sim_tick_report *report, const world_rect **rects,
                               int *n);
/* The store refused the tick: take the edits back (after the engine's
 * windows), tell their senders code and why. */
void service_edits_undo(service *s, int code, const char *why);
/* The tick is committed: tell each websocket sender its tick and volume
 * change (an `edited` reply, a frame of the tick, in order with its others). */
void service_edits_finish(service *s);
/* The tick is published (its status names it): tell each HTTP sender its
 * tick and volume change, which it answers at once — once the tick is also
 * durable: under a group commit (its frames still held in the batch) the
 * answers wait with the frames, and service_edits_answer_held tells them when
 * service_settle hands those frames over. */
void service_edits_answer(service *s);
void service_edits_answer_held(service *s);
void service_edits_free(service *s);

/* service_colliders.c */
void service_publish_colliders(service *s, const sim_collider *extra, int extra_count);

/* service_footprints.c */
void service_publish_footprints(service *s, const sim_tick_report *report);

/* service_checksums.c: every checksum_interval ticks, each subscription's
 * tile hashes (CHECKSUM frames) behind the tick's other frames; and a tile's
 * resync (HUB_RESYNC_TILE) queued as a quiet snapshot job */
void service_publish_checksums(service *s);
void service_resync_tile(service *s, const hub_command *c);

#endif
