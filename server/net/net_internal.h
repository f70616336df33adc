/*
 * net_internal.h: what net.c (connections, queues, fan-out) and
 * net_requests.c (what clients ask for) share. Not part of the public face
 * of net/; everything here runs on the service thread only.
 */
#ifndef TERRAD_NET_INTERNAL_H
#define TERRAD_NET_INTERNAL_H

#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>
#include <libwebsockets.h>

#include "net/net.h"

/* What an outgoing queue entry is, for what may be dropped when. */
typedef enum net_item_kind {
    NET_ITEM_REPLY,  /* replies, errors, snapshots: always kept */
    NET_ITEM_TILE,   /* a fanned-out tile delta: dropped for a slow client */
    NET_ITEM_STATUS, /* CONTACT or ACK: a newer one replaces older ones when slow */
} net_item_kind;

typedef struct net_item {
    hub_frame *frame;
    unsigned char kind;
    unsigned char type; /* binary type byte (STATUS), else 0 */
} net_item;

typedef struct net_sub {
    uint32_t id;
    world_rect rect;
} net_sub;

typedef struct net_client {
    uint32_t id;
    struct lws *wsi;
    struct net_server *srv;
    int ready; /* hello accepted */
    char peer[64];
    char name[72];

    /* incoming message being reassembled */
    unsigned char *rx;
    size_t rx_len, rx_cap, rx_total;
    int rx_active, rx_binary, rx_oversize;

    /* rate limit: token bucket, and how long the flood has gone on */
    double tokens, refill_ms;
    double flood_since_ms, last_refusal_ms, last_rate_error_ms;

    /* ownership */
    uint32_t *colliders;
    int collider_count;
    net_sub *subs;
    int sub_count;
    uint32_t next_sub_id;
    int64_t sub_cells;

    /* outgoing queue: a ring of frame references */
    net_item *q;
    size_t q_head, q_count, q_cap;
    size_t pending_bytes;

    /* snapshots: every HUB_SUBSCRIBE and HUB_RESYNC gets exactly one
     * snapshot_done marker back, in order; tile deltas wait while
     * snapshots_done < resync_until */
    uint64_t snapshots_requested, snapshots_done, resync_until;
    int slow; /* dropped deltas for want of room: resync once the queue drains */

    int closing; /* close after the queue drains */
    int close_code;
    char close_reason[64];
    int killed; /* dropped without waiting for the queue */
} net_client;

typedef struct net_collider_slot {
    uint32_t id; /* 0 = empty */
    uint32_t owner;
    int axis_z; /* capsule / cylinder: the client's axis is z, the collider module's y */
} net_collider_slot;

struct net_server {
    net_config cfg;
    char *token, *models_json, *materials_json, *server_name;
    cJSON *models, *materials;
    hub *hub;

    struct lws_context *ctx;
    lws_sorted_usec_list_t heartbeat;
    struct terrad_pose *poses; /* max_poses_per_batch, for decoding */
    atomic_int thread_done;
    pthread_t thread;
    int thread_started;
    int port;
    atomic_int stop_requested;
    atomic_int force_stop;
    atomic_int client_count;
    pthread_mutex_t wake_lock;
    int ctx_live;
    int stopping;

    net_client **clients; /* sorted by id */
    int nclients, clients_cap;
    uint32_t next_client_id;
    uint32_t next_collider_id;

    net_collider_slot *colliders; /* open addressing, power-of-two capacity */
    size_t colliders_cap, colliders_used;

    hub_command *backlog; /* commands that must reach the sim, waiting for room */
    int backlog_count, backlog_cap;

    uint64_t tick; /* the latest tick seen from the sim */
    size_t hard_pending_bytes;

    double last_warn_ms;
    uint64_t warns_suppressed;
};

typedef struct net_server net_server;

/* net.c */
net_client *net_find_client(net_server *s, uint32_t id);
/* Queue a frame for a client (takes over the caller's reference). */
void net_enqueue(net_client *c, hub_frame *f, net_item_kind kind);
void net_send_json(net_client *c, cJSON *msg); /* frees msg */
/* Close the client once its queue drains (at most a few seconds). */
void net_close_after_flush(net_client *c, int code, const char *reason);
/* Drop the client's queued tile deltas; returns how many. */
/* Drop the queued tile deltas and the ACK/CONTACT frames that would vouch for them. */
int net_drop_tile_deltas(net_client *c);
/* Push a command the sim must get (client left, resync): queued locally
 * when the hub is full, retried in order. */
void net_push_must(net_server *s, const hub_command *cmd);
/* 0, or -1 when the hub (or the local backlog) is full: refuse the request. */
int net_push_refusable(net_server *s, const hub_command *cmd);
void net_warn_refusal(net_server *s, const net_client *c, int code, const char *message);

/* net_requests.c */
void net_error(net_client *c, int code, const cJSON *ref, int64_t collider, int fatal,
               const char *fmt, ...) __attribute__((format(printf, 6, 7)));
void net_handle_text(net_client *c, const char *text, size_t len);
void net_handle_binary(net_client *c, const unsigned char *data, size_t len);
void net_request_resync(net_client *c, uint32_t subscription);
/* collider table */
net_collider_slot *net_collider_find(net_server *s, uint32_t id);
int net_collider_insert(net_server *s, uint32_t id, uint32_t owner, int axis_z);
void net_collider_remove(net_server *s, uint32_t id);

#endif
