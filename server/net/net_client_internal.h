/*
 * net_client_internal.h: the bottom layer of the net thread — its state. Not part of
 * the face of net/ (that is net.h); included only by the files of net/ (and
 * tests/unit/test_net_desync.c, which builds a client record alone).
 *
 *   net.c           the server's life: limits, lws context, thread, stop
 *     ↓
 *   net_callback.c  the lws protocol callback: a client's start and end, its
 *                   reassembled messages, its writes
 *     ↓
 *   net_loop.c      between callbacks: a wake's and the heartbeat's work
 *     ↓
 *   net_events.c    world_created / world_deleted to the admins who asked
 *     ↓
 *   net_remote.c    any node serves any world: the inbox from other nodes
 *     ↓
 *   net_worlds.c    worlds coming and going (the table of worlds, relays)
 *     ↓
 *   net_fanout.c    the sim's frames to the clients (net_dispatch), the waker
 *     ↓
 *   net_requests.c  what clients ask for (control messages, POSE_BATCH)
 *   net_control.c   the pure JSON control-message parser it uses
 *   net_auth.c      who may do what
 *   net_peer.c      a client's end: dead peers, the disconnect line, freeing it
 *     ↓
 *   net_spectate.c  spectators: a window replayed from a past tick by a
 *                   thread of its own, its frames moved to the client's
 *                   queue as its bound and budget allow
 *     ↓
 *   net_budget.c    a client's bandwidth budget: its byte window and its
 *                   ledger of tiles not sent yet (net_fanout.c hands it
 *                   a budgeted client's deltas and snapshots)
 *     ↓ (and net_enqueue charges its window, net_request_resync clears its ledger)
 *   net_client.c    this layer: per-client records (limits, rate bucket,
 *                   owned colliders, subscriptions, outgoing queue), the
 *                   collider table, commands waiting for the hub
 *   net_desync.c    CHECKSUM frames per client, resyncs of single tiles
 *   net_conn.c      admission of sockets before their handshake
 *   net_remote_send.c  frames to another node (a leaf)
 *
 * Each layer calls only the ones below it (the call graph of net/ is
 * acyclic). Everything here runs on the net thread only (net_state.owner),
 * except where net.c notes otherwise.
 */
#ifndef TERRAD_NET_CLIENT_INTERNAL_H
#define TERRAD_NET_CLIENT_INTERNAL_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>
#include <libwebsockets.h>

#include "net/net.h"
#include "terrad_proto.h"

/* What an outgoing queue entry is, for what may be dropped when. */
typedef enum net_item_kind {
    NET_ITEM_REPLY,  /* replies, errors, snapshots: always kept */
    NET_ITEM_TILE,   /* a fanned-out tile delta: dropped for a slow client */
    NET_ITEM_STATUS, /* CONTACT or ACK: a newer one replaces older ones when slow */
} net_item_kind;

typedef struct net_item {
    hub_frame *frame;
    uint64_t tick; /* TILE and STATUS: the tick it was queued in (staleness); 0 for replies */
    unsigned char kind;
    unsigned char type; /* binary type byte (STATUS), else 0 */
} net_item;

typedef struct net_sub {
    uint32_t id;
    world_rect rect;
} net_sub;

typedef struct net_state net_state;
typedef struct net_budget net_budget;       /* net_budget.c */
typedef struct net_spectator net_spectator; /* net_spectate.c */

#define NET_UNSEEN_MAX 64 /* written ticks remembered for "seen"; full: the newest merge */

typedef struct net_client {
    uint32_t id;
    struct lws *wsi;
    net_state *srv;
    int ready; /* hello accepted */
    /* its snapshots are coded against the base (PROTOCOL.md): 0 no, 1 as
     * encoding 2, 2 as encoding 2 or 3 (slope snapshots), the shorter */
    int snapshot_base;
    unsigned events; /* subscribe_events: one bit per NET_EVENT_NAMES entry */
    /* what its hello's token allows (net_auth.c), the token's entry name for
     * log lines and its hash, looked up again after each reload */
    auth_role role;
    char auth_name[AUTH_NAME_MAX + 1];
    unsigned char token_hash[32];
    char peer[64];
    char name[72];

    /* incoming message being reassembled */
    unsigned char *rx;
    int64_t rx_cap;
    size_t rx_len, rx_total;
    int rx_active, rx_binary, rx_oversize;

    /* rate limit: token bucket, and how long the flood has gone on: since
     * flood_since_ms, while flood_debt (refusals not yet earned back) lasts */
    double tokens, refill_ms;
    double flood_since_ms, flood_debt, last_rate_error_ms;

    /* ownership */
    uint32_t *colliders;
    int collider_count;
    int64_t active_cells;   /* Σ over its colliders: max_active_cells */
    int64_t mesh_triangles; /* Σ over its mesh colliders: max_mesh_triangles */
    int64_t collider_capacity;
    net_sub *subs;
    int sub_count;
    int64_t sub_capacity;
    uint32_t next_sub_id;
    int64_t sub_cells;

    /* outgoing queue: a ring of frame references */
    net_item *q;
    size_t q_head, q_count, q_cap;
    size_t pending_bytes;
    /* of which TILE and STATUS items: what going slow can drop, and what
     * max_pending_bytes is compared with (a snapshot larger than the limit,
     * queued in one go, must not make its client slow again at once) */
    size_t droppable_bytes;

    /* snapshots: every HUB_SUBSCRIBE and HUB_RESYNC gets exactly one
     * snapshot_done marker back, in order; tile deltas wait while
     * snapshots_done < resync_until */
    uint64_t snapshots_requested, snapshots_done, resync_until;
    int slow; /* dropped deltas for want of room: resync once the queue drains */
    /* end to end (PROTOCOL.md "seen"): the latest tick of a ticked frame
     * handed to the socket; the latest the client said it has handled
     * (seen_said: it ever said); seen_wait: slow for that lag, the snapshots
     * wait until the client has handled this tick (what was on its way);
     * seen_from: after a resync (net_request_resync) it is judged again once
     * it has handled this tick (its snapshots: of this tick or later) */
    uint64_t written_tick, seen_tick, seen_wait, seen_from;
    int seen_said;
    /* the ticked frames written and not yet said handled, as (frame tick,
     * the server's tick when written), oldest first: the client is behind by
     * how long ago the oldest was written, not by the frames' ticks (a frame
     * after two idle seconds carries a tick 120 past the last one the client
     * said, and was judged behind the moment it was written) */
    uint64_t unseen_tick[NET_UNSEEN_MAX], unseen_at[NET_UNSEEN_MAX];
    int unseen_head, unseen_count;
    size_t checksum_next; /* the first CHECKSUM entry of the next trimmed frame */

    int closing; /* close after the queue drains */
    int close_code;
    char close_reason[64];
    int killed; /* dropped without waiting for the queue */
    /* the client's close frame, for the disconnect log line: code (0 = none
     * came) and reason, made printable, at most 123 bytes as RFC 6455 allows */
    /* a remote client (net_remote.c): its socket is on the relay node
     * remote_node, where its id is remote_client; frames for it go there */
    int remote;
    char remote_node[65];
    uint32_t remote_client;
    int remote_gone; /* closed: freed by the net thread at its next pass */
    int peer_close_code;
    char peer_close_reason[124];
    /* lws holds part of a frame the kernel would not take: reading is paused
     * until it drains (net_peer.c), so that lws never meets the
     * peer's EOF with output buffered, and the heartbeat watches for the EOF */
    int rx_held;
    /* its bandwidth budget (net_budget.c; NULL: none) and its `focus`
     * message's point, in cells (has_focus 0: its colliders' poses) */
    net_budget *budget;
    int has_focus;
    double focus_x, focus_y;
    net_spectator *spectate; /* PROTOCOL.md "Spectate" (net_spectate.c); NULL: not spectating */
    /* a relay's client whose owner said "spectating" (until its spectate_end):
     * the owner's frames of past ticks go to it as replies (net_dispatch),
     * never judged against the live tick's lag or dropped for a resync */
    int relay_spectating;
} net_client;

typedef struct net_collider_slot {
    uint32_t id; /* 0 = empty */
    uint32_t owner;
    int axis_z;    /* capsule / cylinder: the client's axis is z, the collider module's y */
    int64_t cells; /* its cost against the owner's budgets (net_requests.c) */
    int triangles;
} net_collider_slot;

/* What the net thread knows, apart from libwebsockets' context (net.c). */
struct net_state {
    thread_owner owner; /* the net thread: claimed when it starts, released when it ends */
    net_config cfg;
    auth_table *auth; /* cfg.auth, or an empty one (own_auth) */
    int own_auth;
    unsigned auth_generation; /* the table's, when the clients' roles were last checked */
    char *models_json, *materials_json, *server_name, *world_name;
    cJSON *models, *materials;
    cJSON *base; /* cfg.world.base_json parsed (net_parse_base); NULL: no base snapshots */
    hub *hub;
    struct terrad_pose *poses; /* max_poses_per_batch, for decoding */

    net_client **clients; /* sorted by id */
    int nclients;
    int64_t clients_cap;
    uint32_t next_client_id;
    uint32_t next_collider_id;

    net_collider_slot *colliders; /* open addressing, power-of-two capacity */
    size_t colliders_cap, colliders_used;

    hub_command *backlog; /* commands that must reach the sim, waiting for room */
    int backlog_count;
    int64_t backlog_cap;

    uint64_t tick;   /* the latest tick seen from the sim */
    uint32_t driver; /* a client-clocked world: the client whose STEPs tick it (0: none) */
    size_t hard_pending_bytes;

    double last_warn_ms;
    uint64_t warns_suppressed;

    /* admission (net_conn.c) */
    int fd_ceiling; /* accepted descriptors at or above it are refused; 0 = none */
    uint64_t conn_refused, conn_refusals_unlogged;
    double last_conn_refusal_log_ms;

    /* The worlds of the table (cfg.worlds) and the relayed ones, each with its
     * own state (net_worlds.c). The server's own state is the lobby: every
     * client starts there and moves, at its hello, to the state of the world
     * it names (its own hub, world info, collider table and backlog).
     * hosted_worlds: a world other than a single daemon's default one was
     * ever served here. lobby: this is the server's own state (a remote
     * client, one another node relays, starts in its world's state). */
    int lobby;
    int hosted_worlds;
    /* the server's own state only: the daemon drains (net_server_drain) —
     * drain_why and drain_grace_ms are written before draining is set */
    atomic_int draining;
    int drain_told; /* the net thread told the clients (net_drain_apply) */
    char drain_why[200];
    int64_t drain_grace_ms;
    int relay; /* a world another node owns, served through it (net_remote.c) */
    net_remote_send_fn remote_send; /* to other nodes; NULL for a single daemon */
    void *remote_ctx;
    char node[65];              /* this node's name */
    hub_world *entry;           /* a world of the table (cfg.worlds) this state was made for */
    terrad_codec *budget_codec; /* budgeted clients' deltas, summed and encoded (net_budget.c) */
    net_state **worlds;         /* the lobby's: every world's state */
    net_server *server;         /* a world's: the server whose thread serves it (its waker) */
    uint32_t spectate_ids;      /* the last spectator's id */
    net_spectator *spectators_gone; /* their clients left; joined once their threads end */
    int nworlds;
    int64_t worlds_cap;
};

/* Why the daemon drains (st: the server's own state, where every client
 * says hello), or NULL (net_events.c). Any thread. */
const char *net_draining(const net_state *st);

/* ---- the client list ---- */
net_client *net_find_client(net_state *s, uint32_t id);
int net_client_add(net_state *s, net_client *c); /* ids only grow: appended */
void net_client_remove(net_state *s, net_client *c);
/* A lobby's client whose hello names world (or "" for the default one: the
 * one the table's default name names, else the first) moved to that world's
 * state (c->srv). 0, or -1 with why (no such world here). */
int net_client_join_world(net_client *c, const char *world, char *why, size_t cap);

/* ---- a client's outgoing queue ---- */
/* Queue a frame for a client (takes over the caller's reference). */
void net_enqueue(net_client *c, hub_frame *f, net_item_kind kind);
/* A spectator's replay frame: queued as a reply (never dropped), but charged
 * to a budget as tile data: it waited for room (net_budget_fits_held), so
 * the window's rule for tile data applies to it. */
void net_enqueue_held(net_client *c, hub_frame *f);
void net_send_json(net_client *c, cJSON *msg); /* frees msg */
/* A copy of a request's "ref" for a reply (JSON null when there is none). */
cJSON *net_ref_copy(const cJSON *ref);
/* An error message to the client (PROTOCOL.md "error"), counted as refused
 * unless code is shutting_down or internal. */
void net_error(net_client *c, int code, const cJSON *ref, int64_t collider, int fatal,
               const char *fmt, ...) __attribute__((format(printf, 6, 7)));
/* "seen" (PROTOCOL.md): a ticked frame of tick `tick` was written to c now,
 * and c said it has handled every tick up to seen_tick. */
void net_seen_written(net_client *c, uint64_t tick);
void net_seen_handled(net_client *c);
/* How many server ticks ago the oldest frame c has not said it handled was
 * written (0: none). */
uint64_t net_seen_lag(const net_client *c);
/* Close the client once its queue drains (at most a few seconds). */
void net_close_after_flush(net_client *c, int code, const char *reason);
/* Drop the queued tile deltas and the ACK/CONTACT frames that would vouch for them. */
int net_drop_tile_deltas(net_client *c);
/* The tick of the oldest queued TILE or STATUS item, 0 when none is queued. */
uint64_t net_oldest_queued_tick(const net_client *c);
/* Drop every queued frame (the client is gone or being dropped). */
void net_release_queue(net_client *c);
/* The client stopped reading and asked for more: let it go. */
void net_client_kill(net_client *c, const char *why);
/* Token bucket; 1 if the message may pass. Refusals are answered at most
 * once a second; a flood not earned back for 10 s (by what the client sent,
 * however late the server read it) closes the connection. */
int net_rate_allow(net_client *c);

/* ---- spectators (net_spectate.c; PROTOCOL.md "Spectate") ---- */
struct net_control;
/* A spectate request whose fields the parser checked: refused (an error
 * naming the field, counted), or a replay thread started; "spectating"
 * follows once it has rebuilt the start tick. */
void net_spectate_request(net_client *c, const struct net_control *m);
void net_spectate_step(net_client *c, const struct net_control *m); /* spectate_step */
void net_spectate_stop(net_client *c, const struct net_control *m); /* spectate_stop */
int net_spectating(const net_client *c);
/* The client leaves: its replay thread is stopped (joined later). */
void net_spectate_drop(net_client *c);
/* A spectator's outbox: the frames its replay thread made, in order, that
 * the net thread moves into the client's queue (under the spectator's lock). */
typedef struct net_outbox {
    hub_frame **frames; /* NULL until the first frame */
    int n;
    int64_t cap;
    size_t bytes; /* the frames' lengths summed */
} net_outbox;
/* f appended (taken) and counted as made: 0. Or -1: f is NULL (a frame that
 * could not be made) or the outbox could not grow (no memory); f dropped and
 * counted in terrad_spectate_frames_dropped_total. A spectator has no resync,
 * so its thread ends it "failed" after a drop. */
int net_outbox_put(net_outbox *o, hub_frame *f);
/* Every spectator's frames into its client's queue as it has room; threads
 * that ended are joined. Each wake and heartbeat. */
void net_spectate_pump(net_state *w);
/* The world leaves (its state is freed next): every replay thread of it is
 * cancelled and handed to the lobby's list, reaped there once it ended; the
 * net thread never waits for one (each holds the world's table entry, so
 * the world's removal waits for it instead). */
void net_spectate_leave(net_state *w, net_state *lobby);
/* The state is freed: every replay thread of it stopped and joined (the
 * lobby's, when the server stops; a world's were handed over before). */
void net_spectate_join_all(net_state *w);
/* The hubs' waker (net_fanout.c): any thread. */
void net_server_wake(void *arg);

/* ---- bandwidth budgets (net_budget.c; PROTOCOL.md "Budgets") ---- */
/* Give c a budget of rate bytes/s: 0, or -1 (no memory). */
int net_budget_start(net_client *c, double rate);
void net_budget_free(net_client *c);         /* logs what it sent */
double net_budget_rate(const net_client *c); /* 0: none */
/* Every frame queued for a budgeted client (tile_data: a delta, a snapshot
 * piece, FOOTPRINTS or a spectator's replay frame, which wait for room; else
 * it was never held). */
void net_budget_charge(net_client *c, size_t len, int tile_data);
/* 1 if a frame of len bytes fits the window now (always without a budget). */
int net_budget_fits(net_client *c, size_t len);
/* How many CHECKSUM entries a frame may carry for c: as many as its window
 * has room for now (at least 1), SIZE_MAX without a budget. */
size_t net_budget_checksum_entries(net_client *c);
/* 1 if a frame of len bytes that waits for room may go now, by the ledger's
 * rule (flush_tile's): the window has room for it, or holds no tile data (a
 * frame larger than its room goes then, whatever replies and status frames
 * it holds: an overrun, counted). A spectator's frames (net_spectate.c),
 * queued by net_enqueue_held; always 1 without a budget. */
int net_budget_fits_held(net_client *c, size_t len);
/* A tile delta (o: HUB_OUT_TILE_DELTA) for a budgeted client: 0 when the
 * caller queues it as for any client, 1 when the ledger took it. */
int net_budget_delta(net_client *c, const hub_out *o);
/* A snapshot frame for a budgeted client: into the ledger (takes f); 1 when
 * the deltas held between its pieces pass max_pending_bytes (go slow). */
int net_budget_snapshot(net_client *c, hub_frame *f);
/* After an unsubscribe: drops the pieces and tiles no subscription takes. */
void net_budget_prune(net_client *c);
/* The ledger forgets everything (a resync sends fresh snapshots). */
void net_budget_reset(net_client *c);
/* Send what the window has room for, nearest the client's focus first. */
void net_budget_flush(net_client *c);
void net_budget_flush_state(net_state *w);
/* The latest poses of c's colliders: near them counts as near, whatever its focus. */
void net_budget_note_poses(net_client *c, const terrad_pose *poses, size_t count);
/* 1 if tile (tx, ty) of a subscription of c is current for it: every change
 * of it has been queued to it (not in its budget's ledger, no resync or
 * snapshot outstanding). For per-tile checksums: only current tiles compare. */
int net_client_tile_current(const net_client *c, int tx, int ty);

/* ---- admission (net_conn.c) ---- */
/* RLIMIT_NOFILE's soft limit minus reserve (at least 16; huge when unlimited). */
int net_fd_ceiling(int reserve);
/* 1 if a freshly accepted socket may stay, else 0 (logged at a bounded rate). */
int net_admit_connection(net_state *s, int fd);
/* 1 if the comma-separated header value offers the protocol name. */
int net_offers_subprotocol(const char *value, const char *name);
/* libwebsockets' log lines (lws_set_log_level), at most 5 a second. */
void net_lws_log_line(int level, const char *line);

/* ---- to other nodes (net_remote_send.c) ---- */
/* A relay's client: its text or binary message goes to the world's owner as it came. */
void net_relay_forward(net_client *c, int binary, const void *data, size_t len);
/* A remote client's frame goes back to its relay (the frame is the caller's). */
void net_remote_frame(net_client *c, const hub_frame *f, int snapshot_done);
/* A remote client is closed: its relay is told (code, reason). */
void net_remote_close(net_client *c, int code, const char *reason);

/* ---- dead peers (net_peer.c) ---- */
/* After a write: pause reading while lws holds part of a frame, resume once it is flushed. */
void net_rx_hold_update(net_client *c);
/* Kill the paused clients whose peer has hung up; how many. */
int net_reap_dead_peers(net_state *s);
/* The disconnect log line: who closed, with which code and reason. */
void net_log_disconnect(const net_client *c);
/* Keeps the client's close frame (code, printable reason) for that line. */
void net_client_peer_close(net_client *c, const unsigned char *in, size_t len);

/* ---- commands for the sim ---- */
/* Push a command the sim must get (client left, resync): queued locally
 * when the hub is full, retried in order. */
void net_push_must(net_state *s, const hub_command *cmd);
/* 0, or -1 when the hub (or the local backlog) is full: refuse the request. */
int net_push_refusable(net_state *s, const hub_command *cmd);
/* Retry the backlog, in order. */
void net_flush_backlog(net_state *s);
/* Fresh snapshots of every subscription of c (see net_client.c). */
void net_request_resync(net_client *c, uint32_t subscription);
void net_warn_refusal(net_state *s, const net_client *c, int code, const char *message);

/* ---- desync detection and repair (net_desync.c) ---- */
/* The sim's CHECKSUM frame f (the caller's reference, taken over) as c gets
 * it: f itself, or a copy of only c's current tiles (NULL: no memory), at
 * most max_entries of them: a budget's window may not have room for a whole
 * window's (PROTOCOL.md "Budgets"), so each frame then carries the next
 * max_entries in turn (c->checksum_next) and every tile is checked within a
 * few frames. */
hub_frame *net_checksum_for(net_client *c, hub_frame *f, size_t max_entries);
/* resync with "tiles" (n [x, y] pairs) of subscription sub: each tile must meet
 * it (else outside_world naming tiles[i], nothing asked); each becomes one
 * HUB_RESYNC_TILE, a quiet snapshot of tile ∩ subscription. */
void net_request_resync_tiles(net_client *c, const net_sub *sub, const int32_t *tiles, int n,
                              const cJSON *ref);

/* ---- the collider table: id -> owner ---- */
net_collider_slot *net_collider_find(net_state *s, uint32_t id);
/* The collider id of c's (or, any_owner, anyone's): NULL after an error
 * unknown_collider or not_owner naming it. */
net_collider_slot *net_collider_owned(net_client *c, uint32_t id, const cJSON *ref, int any_owner);
int net_collider_insert(net_state *s, uint32_t id, uint32_t owner, int axis_z);
void net_collider_remove(net_state *s, uint32_t id);

#endif
