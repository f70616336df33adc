/*
 * net: the websocket side of terrad (proto/PROTOCOL.md). One service thread
 * runs libwebsockets with a single protocol callback ("terrad.v1"): it
 * checks every client message, answers control requests at once, turns the
 * accepted ones into hub commands and poses for the sim thread, and fans the
 * sim thread's frames out to the clients that need them.
 *
 * Nothing a client sends can reach the sim unchecked, and no client can make
 * the server hold unbounded memory: each client has a rate limit, a message
 * size limit and a bounded outgoing queue; a client that stops reading loses
 * its queued tile deltas and is given fresh snapshots when it catches up.
 */
#ifndef TERRAD_NET_H
#define TERRAD_NET_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#include "base/base.h"
#include "hub/hub.h"

/* Every limit once (issue 29 item 4): X(type, name, default, min, flags,
 * help), in the world message's order. net_limits' fields (type name) and
 * net_limit_table (net_limits.c) are made from this list, so a new limit is
 * one row. name: PROTOCOL.md's Limits table's, the config's and the world
 * message's; min: the config's smallest value (0: any > 0); flags: where it
 * may be set (NET_LIMIT_CONFIG: --config's "limits", a number in (0, 1e12],
 * >= min; NET_LIMIT_ZERO: 0 too, for a limit whose 0 means none or the
 * default its help names, so a config can say it) and whether the world
 * message's "limits" tells clients its value (NET_LIMIT_TOLD); help: serve
 * --help's line. Each limit is enforced where
 * it is used (net/, service/, http/). */
#define NET_LIMIT_CONFIG 1
#define NET_LIMIT_TOLD 2
#define NET_LIMIT_ZERO 4
#define NET_BUDGET_MIN 1024 /* bytes/s: the smallest budget a hello or a config may state */
#define NET_LIMITS(X)                                                                              \
    /* told to clients */                                                                          \
    X(size_t, max_message_bytes, 1048576, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                    \
      "largest websocket frame, text or binary")                                                   \
    X(int, max_colliders, 64, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "colliders per client")        \
    X(int, max_poses_per_batch, 64, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                          \
      "poses in one POSE_BATCH")                                                                   \
    X(int, max_subscriptions, 16, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                            \
      "subscriptions per client")                                                                  \
    X(int64_t, max_subscribed_cells, 4194304, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                \
      "cells over a client's subscriptions")                                                       \
    X(double, max_messages_per_s, 240, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                       \
      "a client's sustained messages per second (token bucket)")                                   \
    X(double, messages_burst, 480, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                           \
      "the token bucket's depth")                                                                  \
    X(int, max_mesh_vertices, 16384, 0, NET_LIMIT_TOLD, "vertices per mesh collider")              \
    /* a per-client budget, as max_active_cells */                                                 \
    X(int, max_mesh_triangles, 32768, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                        \
      "triangles over a client's mesh colliders")                                                  \
    X(int64_t, max_active_cells, 8192, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                       \
      "a client's colliders' cost in cells (docs/service.md: a quarter of a 60 Hz tick)")          \
    X(double, max_collider_extent_m, 50, 0, NET_LIMIT_TOLD,                                        \
      "largest length of any collider dimension")                                                  \
    X(size_t, max_pending_bytes, 8388608, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                    \
      "bytes queued for a client before it is treated as slow")                                    \
    X(double, hello_timeout_s, 5, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                            \
      "seconds allowed for hello")                                                                 \
    /* a client whose oldest queued delta or status frame is older is treated                      \
     * as slow (snapshots when it drains), as if over max_pending_bytes */                         \
    X(int, max_client_lag_ticks, 0, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD | NET_LIMIT_ZERO,         \
      "ticks a client's oldest queued frame may lag before it is slow (0: 2 s of ticks)")          \
    /* not per client (service_set_tick_budget); 0: none */                                        \
    X(int64_t, max_tick_cells, 32768, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD | NET_LIMIT_ZERO,       \
      "the tick's cost budget over every client (four clients' max_active_cells; 0: none)")        \
    /* per client: the poses that would pass it are refused */                                     \
    X(int64_t, max_sweep_cells, 32768, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD | NET_LIMIT_ZERO,      \
      "one client's cost this tick, its sweeps included (a whole tick's budget; 0: none)")         \
    X(int64_t, max_edit_cells, WORLD_EDIT_MAX_CELLS_DEFAULT, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, \
      "cells one terrain edit may change")                                                         \
    X(int, max_step_ticks, 600, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                              \
      "ticks one STEP of a client-clocked world may ask for (10 s of 60 Hz ticks)")                \
    /* desync detection (PROTOCOL.md "CHECKSUM", service_set_checksum_interval) */                 \
    X(int, checksum_interval_ticks, 30, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                      \
      "ticks between a subscription's CHECKSUM frames (0.5 s at 60 Hz)")                           \
    X(int, max_resync_tiles, 64, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                             \
      "tiles one resync request may name (a 512 x 512 window's)")                                  \
    /* bandwidth budgets, bytes/s (net_budget.c) */                                                \
    X(double, default_budget_bytes_per_s, 0, NET_BUDGET_MIN,                                       \
      NET_LIMIT_CONFIG | NET_LIMIT_TOLD | NET_LIMIT_ZERO,                                          \
      "a client's bandwidth budget when its hello states none (0: none; else >= 1024)")            \
    X(double, max_budget_bytes_per_s, 0, NET_BUDGET_MIN,                                           \
      NET_LIMIT_CONFIG | NET_LIMIT_TOLD | NET_LIMIT_ZERO,                                          \
      "the largest budget a hello may state (0: any, and none; else >= 1024)")                     \
    /* spectators' replay threads in the daemon, each holding a rebuild's memory                   \
     * (net_spectate.c); past it a spectate is refused (too_large) */                              \
    X(int, max_spectators, 16, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,                               \
      "spectators replaying at once in the daemon (a thread and a window's tiles each)")           \
    /* the server's own; admission (0: no cap), and whatever these say an                          \
     * accepted socket is refused while fewer than fd_reserve descriptors are                      \
     * left under RLIMIT_NOFILE */                                                                 \
    X(int, max_connections, 0, 0, NET_LIMIT_CONFIG | NET_LIMIT_ZERO,                               \
      "websocket connections in all (0: from RLIMIT_NOFILE)")                                      \
    X(int, max_connections_per_address, 256, 0, NET_LIMIT_CONFIG,                                  \
      "websocket connections from one address")                                                    \
    /* HTTP's, not the websocket's (0: http.c's defaults) */                                       \
    X(size_t, max_heights_bytes_per_address, 0, 0, NET_LIMIT_CONFIG | NET_LIMIT_ZERO,              \
      "HTTP: /v1/heights bytes one address may hold at once (0: 64 MiB)")                          \
    X(size_t, max_heights_bytes_in_flight, 0, 0, NET_LIMIT_CONFIG | NET_LIMIT_ZERO,                \
      "HTTP: the same over every address (0: 256 MiB)")                                            \
    X(int, fd_reserve, 64, 0, 0, "descriptors left free under RLIMIT_NOFILE")

/* Per-client limits (and a few of the server's): one field a row of NET_LIMITS. */
#define NET_LIMIT_FIELD(type, name, def, min, flags, help) type name;
typedef struct net_limits {
    NET_LIMITS(NET_LIMIT_FIELD)
} net_limits;
#undef NET_LIMIT_FIELD

/* A row of NET_LIMITS as data; net_limit_table ends with a row whose name is NULL. */
typedef enum { NET_LIMIT_INT, NET_LIMIT_INT64, NET_LIMIT_SIZE, NET_LIMIT_DOUBLE } net_limit_kind;
typedef struct net_limit_spec {
    const char *name;
    size_t offset; /* of its field in net_limits */
    net_limit_kind kind;
    double def; /* net_limits_default's */
    int flags;
    const char *help;
    double min;
} net_limit_spec;
extern const net_limit_spec net_limit_table[];
double net_limit_get(const net_limits *l, const net_limit_spec *s);
/* v as the field's type (an int field at most INT_MAX). */
void net_limit_set(net_limits *l, const net_limit_spec *s, double v);
/* The table's defaults. */
net_limits net_limits_default(void);
/* serve --help's limits section: the settable ones, their defaults, what they bound. */
void net_limits_usage(FILE *out);

/* What the world message tells a client (PROTOCOL.md "world"). */
typedef struct net_world_info {
    int width, height;
    double cell_size_m;
    int32_t units_per_m;
    double tick_hz;
    int tile_size;
    int32_t height_min, height_max;
    const char *models_json;    /* a JSON array of strings, e.g. ["persson-ssbo"]; NULL = [] */
    const char *materials_json; /* a JSON array of strings; NULL = ["default"] */
    int loads; /* the world's model carries loads (bekker): collider_create may give load_n */
    /* "clock": "client" — the world ticks only on its driver's STEP messages
     * (PROTOCOL.md "STEP"); 0: the server's wall clock */
    int client_clock;
    /* a named world's name (a created world, a cluster node's), sent in the
     * world message; NULL for a single daemon's default world, whose world
     * message is unchanged (its state is named by its entry of the table). */
    const char *name;
    /* The scene's twin config as a JSON object (scene_twin_config_json), sent
     * as the world message's "base" to a client whose hello asked for base
     * snapshots (PROTOCOL.md "Base snapshots"); NULL: the twin cannot make
     * this world's base, and such a client gets absolute snapshots. Copied. */
    const char *base_json;
} net_world_info;

typedef struct net_config {
    int port;     /* 0: pick a free port (see net_server_port) */
    int bind_any; /* 0: loopback only */
    /* who may do what (base.h "Authentication"): shared with the HTTP side and
     * reloaded on SIGHUP by its owner, which frees it after net_server_stop.
     * NULL: auth off (an empty table, made and freed here). */
    auth_table *auth;
    /* both set: wss:// only (libwebsockets' OpenSSL), the pair already checked
     * with tls_check_pair; a plain ws:// upgrade on the port fails its handshake */
    const char *tls_cert, *tls_key;
    net_limits limits;
    net_world_info world;    /* unused here: each world state's copy holds its world's */
    const char *server_name; /* world.server; NULL = "terrad/0.1.0" */
    /* the daemon's one table of worlds (hub.h, hub_worlds), which each
     * world's host adds it to: the net thread makes a state for every entry
     * (its info an net_world_info; info->name required, strings copied), its
     * sim thread at the other end of its hub, and when the entry leaves the
     * table tells its clients (shutting_down; 4020 "world deleted" for a
     * deleted one) and closes them before it lets go. NULL: none. */
    hub_worlds *worlds;
} net_config;

typedef struct net_server net_server;

/* Binds and starts the service thread. The strings of c are copied. Every
 * client waits in the lobby until its hello names a world of c->worlds (no
 * name: the table's default world — a single daemon's default scene, or a
 * cluster node's first world). On a single daemon where no world was ever
 * added beside the default one, any name is the default world (as before
 * worlds could be created). */
net_server *net_server_start(const net_config *c, error_text *err);
/* An event ("world_created", "world_deleted") about world, for every admin
 * connection that subscribed to it (subscribe_events). Any thread; sent by
 * the net thread soon after. */
void net_server_event(net_server *s, const char *event, const char *world);
/* The event "world_state": world's lifecycle state (docs/fleet.md: starting,
 * ready, driven, draining, failed, ended) is now state. Any thread. */
void net_server_world_state(net_server *s, const char *world, const char *state);

/* ---- any node serves any world (net_remote.c; docs/cluster.md) ----
 * A world another node owns is served here as a RELAY: a client's hello
 * naming it joins it here, and its messages go to the owner as they came
 * (net_remote_send_fn; the owner checks and applies them as from a client of
 * its own, a "remote client"); what the owner sends that client comes back
 * as NET_REMOTE_FRAME and CLOSE, and each tile delta of the world comes once
 * per tick to every relay (NET_REMOTE_DELTA), which fans it out to its own
 * subscribers as the owner does to its own: the same frame, not re-encoded. */
typedef enum net_remote_kind {
    NET_REMOTE_CLIENT_TEXT = 1, /* relay → owner: a client's text message */
    NET_REMOTE_CLIENT_BINARY,   /* relay → owner: a client's binary message */
    NET_REMOTE_CLIENT_GONE,     /* relay → owner: the client disconnected */
    NET_REMOTE_FRAME,           /* owner → relay: a frame (or a snapshot mark) for one client */
    NET_REMOTE_CLOSE,           /* owner → relay: close the client (close_code, the reason) */
    NET_REMOTE_DELTA,           /* owner → every relay: a tile delta frame */
} net_remote_kind;

typedef struct net_remote_msg {
    int kind;
    char node[65];      /* the relay's node name (all but DELTA) */
    uint32_t client;    /* the client's id on its relay */
    int binary;         /* FRAME, DELTA: a binary frame */
    int snapshot_done;  /* FRAME: the last of a subscription's snapshot */
    int close_code;     /* CLOSE */
    int tile_x, tile_y; /* DELTA */
    uint64_t tick;
} net_remote_msg;

/* Called on the net thread; bytes are the message or frame (not kept). */
typedef void (*net_remote_send_fn)(void *ctx, const char *world, const net_remote_msg *m,
                                   const void *bytes, size_t len);
/* This node's name and how to reach other nodes; before any world is added. */
void net_server_set_remote(net_server *s, const char *node, net_remote_send_fn send, void *ctx);
/* A world another node owns, relayed here (info->name required). Any thread. */
int net_server_add_relay(net_server *s, const net_world_info *info, error_text *err);
/* Stops relaying a world (its clients are told and closed); returns once the
 * net thread let go of it (0), or -1 when it did not answer within 10 s. Any
 * thread but the net thread. */
int net_server_remove_relay(net_server *s, const char *world);
/* A message from another node for a world served here (copied). Any thread. */
void net_server_remote_input(net_server *s, const char *world, const net_remote_msg *m,
                             const void *bytes, size_t len);
/* The daemon drains (docs/fleet.md; PROTOCOL.md "draining"): from now on a
 * hello is refused with error shutting_down naming why and closed with 4020
 * "draining", and every client that said hello is told once, soon after on
 * the net thread, with {"type": "draining", "reason": why, "grace_ms": N}
 * (grace_ms: how long the daemon waits for its clients before it stops).
 * The clients stay connected and served until they leave or the daemon
 * stops. Any thread; the first call's why is kept. */
void net_server_drain(net_server *s, const char *why, int64_t grace_ms);
int net_server_port(const net_server *s);
int net_server_client_count(const net_server *s); /* connected clients; any thread */
/* How long since the net thread last ran its heartbeat (every 100 ms when it is
 * healthy); any thread, for the watchdog behind /healthz. */
double net_server_stalled_ms(const net_server *s);
/* Closes every client with close code 1001 ("server shutting down", after an
 * error shutting_down), joins the thread and frees s. Call it after the sim
 * thread has stopped publishing (the hub's waker points into s). */
void net_server_stop(net_server *s);

#endif
