/*
 * net_control_internal.h: the JSON control-message parser (PROTOCOL.md "Control
 * messages") as a pure function: text in, a parsed request or an error code
 * and message out. No libwebsockets, no client state: what it checks
 * depends only on the text and the server's configuration (limits, the
 * world's extent and materials), so it can be fuzzed on its own
 * (tests/fuzz/fuzz_control.c). net_requests.c applies what depends on the
 * client (hello twice, limits on colliders and subscriptions, ownership).
 * Internal to net/: outside server/net only its unit test
 * (tests/unit/test_net_control.c) and fuzz target include it.
 */
#ifndef TERRAD_NET_CONTROL_INTERNAL_H
#define TERRAD_NET_CONTROL_INTERNAL_H

#include <stddef.h>
#include <stdint.h>

#include <cjson/cJSON.h>

#include "collider/collider.h"
#include "net/net.h"

#define NET_REF_MAX_BYTES 64
#define NET_TOKEN_MAX_BYTES 256
#define NET_CLIENT_NAME_MAX_BYTES 64
#define NET_LOAD_MAX_N 1e9 /* a load-driven collider's load_n */

typedef enum net_control_kind {
    NET_CONTROL_NONE, /* no request type could be read, or an unknown one */
    NET_CONTROL_HELLO,
    NET_CONTROL_COLLIDER_CREATE,
    NET_CONTROL_COLLIDER_DELETE,
    NET_CONTROL_SUBSCRIBE,
    NET_CONTROL_UNSUBSCRIBE,
    NET_CONTROL_RESYNC,
    NET_CONTROL_EDIT,
    NET_CONTROL_SUBSCRIBE_EVENTS,
    NET_CONTROL_SEEN,
    NET_CONTROL_FOCUS,
    NET_CONTROL_SPECTATE,
    NET_CONTROL_SPECTATE_STEP,
    NET_CONTROL_SPECTATE_STOP,
} net_control_kind;

/* subscribe_events: the events an admin connection may ask for, one bit each
 * (net_server_event sends them; PROTOCOL.md "Events"). */
#define NET_EVENT_NAMES "world_created", "world_deleted", "world_state"
#define NET_EVENT_COUNT 3

/* What the parser may know about the server. */
typedef struct net_control_context {
    const net_limits *limits;
    const cJSON *materials; /* world.materials: a JSON array of strings */
    int world_width, world_height;
    int tile_size; /* cells per tile side: bounds resync's tiles (0: by cells alone) */
    int loads;     /* net_world_info.loads */
} net_control_context;

typedef struct net_control {
    net_control_kind kind; /* set as soon as "type" is read, even when a field fails */
    cJSON *ref;            /* the request's valid "ref" (owned), NULL if none (yet) */
    /* hello */
    int64_t protocol;
    int has_token;
    char token[NET_TOKEN_MAX_BYTES + 1];
    char client[NET_CLIENT_NAME_MAX_BYTES + 1]; /* "" when absent */
    char world[NET_CLIENT_NAME_MAX_BYTES + 1];  /* hello's world: "" when absent */
    int snapshot_base;  /* hello's snapshot_base: base snapshots asked for */
    int snapshot_slope; /* hello's snapshot_slope: it decodes slope snapshots (encoding 3) */
    int64_t budget;     /* hello's bandwidth budget, bytes/s: -1 absent, 0 none */
    /* focus: the point in cells its budget's nearest tiles are measured from
     * (has_focus 0: cleared) */
    int has_focus;
    double focus_x, focus_y;
    /* collider_create */
    collider_geometry geometry;
    collider_mesh *mesh; /* owned, mesh shapes (geometry.mesh points to it) */
    collider_pose pose;  /* in the collider module's frame; all-zero: no pose */
    int axis_z;          /* capsule / cylinder: the client's axis is z */
    char material[32];
    int feedback;
    double load_n;     /* > 0: load-driven (bekker worlds); 0: absent */
    int forces_height; /* its FORCES entries carry its height (PROTOCOL.md "FORCES") */
    /* collider_delete, unsubscribe, resync (id 0 and has_id 0: all) */
    uint32_t id;
    int has_id;
    /* resync's "tiles" (owned): tile_count [tile x, tile y] pairs, each >= 0;
     * with them, "id" is required (PROTOCOL.md "resync") */
    int32_t *tiles;
    int tile_count;
    int any_owner; /* collider_delete: an admin's delete of any client's collider */
    /* subscribe, spectate: inside the world */
    world_rect rect;
    /* spectate (PROTOCOL.md "Spectate"): the past tick it starts at, its
     * speed (1..8 times the tick rate) or stepping (spectate_step's ticks) */
    uint64_t from_tick;
    int speed, stepping;
    int64_t step_ticks;
    int colliders, footprints;
    int grousers; /* subscribe: COLLIDERS entries carry their grousers (the extension) */
    /* seen: the latest tick whose frames the client has handled */
    uint64_t seen_tick;
    /* subscribe_events: one bit per NET_EVENT_NAMES entry (0: none) */
    unsigned events;
    /* edit (owned; the command takes it over) */
    world_edit *edit;
} net_control;

typedef struct net_control_error {
    int code;  /* TERRAD_E_*; 0: none */
    int field; /* 0: the message itself is refused (JSON, type, ref); 1: a field of a request */
    int fatal; /* the connection closes after the error (bad_version) */
    char message[512];
} net_control_error;

/* Parses one text message (len bytes, not necessarily NUL-terminated).
 * Returns 0 with *out filled, or -1 with err set and *out filled as far as
 * parsing got (kind and ref as read). Either way free *out with
 * net_control_free. */
int net_control_parse(const char *text, size_t len, const net_control_context *ctx,
                      net_control *out, net_control_error *err);
void net_control_free(net_control *r);

/* |q|² within 0.81..1.21 (|q| within 0.9..1.1), as POSE_BATCH requires too. */
int net_control_quat_norm_ok(double w, double x, double y, double z);

#endif
