/*
 * serve_internal.h: what `terrad serve`'s files share inside server/app/ —
 * the options (serve_options.c reads them from the command line and
 * --config), the demo actors (host_demo.c) that keep the terrain
 * deforming without clients, and cluster mode (serve_cluster.c: which world
 * this node ticks, and its store on JetStream). serve.c runs the daemon on
 * them.
 */
#ifndef TERRAD_SERVE_INTERNAL_H
#define TERRAD_SERVE_INTERNAL_H

#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>

#include "app/app.h"
#include "base/base.h"
#include "cluster/cluster.h"
#include "collider/collider.h"
#include "ground/ground.h"
#include "http/http.h"
#include "host/host.h"
#include "hub/hub.h"
#include "service/service.h"
#include "sim/sim.h"
#include "net/net.h"
#include "scene/scene.h"
#include "store/store.h"
#include "world/world.h"

#define SERVE_CONFIG_STRING_MAX 4096

typedef struct serve_options {
    const char *scene_path;
    const char *backend;
    int http_port;
    int ws_port;
    int bind_any;
    int insecure_open;  /* --insecure-open: --bind-any without any token is allowed */
    int probe_port;     /* -1: none; else --probe-port (0 = any free port) */
    int drain_grace_ms; /* --drain-grace-ms: how long a drain waits for clients to leave */
    int demo_actors;
    double tick_hz;                 /* 0: the scene's */
    const char *auth_file;          /* --auth-file: tokens' hashes and roles, reread on SIGHUP */
    const char *tls_cert, *tls_key; /* --tls-cert, --tls-key: wss:// and https:// only */
    long max_ticks;                 /* < 0: run until signalled */
    net_limits limits;
    const char *data_dir;      /* NULL: memory only (--no-data, or a demo without --data) */
    int data_given;            /* --data, or "data" in --config */
    int demo_in_memory;        /* demo actors and no --data: no store */
    int fresh;                 /* --fresh: store_remove before store_open */
    const char *durability;    /* every-tick | group:MS | none */
    long wal_segment_bytes;    /* compaction threshold */
    long replay_retain_bytes;  /* keep the whole log while under this (replay) */
    const char *store_fault;   /* test hook: writes fail ENOSPC while this file exists */
    int recover_truncate;      /* start on a damaged data directory, cutting the damage */
    int config_loaded;         /* --config was given */
    const char *cluster_urls;  /* --cluster: NULL when not in a cluster */
    const char *node;          /* --node */
    const char *worlds;        /* --worlds a,b,... (or --world a): NULL for any registered */
    int max_worlds;            /* --max-worlds: worlds one node ticks at once (0: see below),
                                * or a single daemon creates beside its default one */
    const char *scene_dir;     /* --scene-dir: scenes POST /v1/worlds may name (NULL: none) */
    int compact_records;       /* --compact-records: a cluster world's records per compaction */
    const char *public_ws_url; /* --public-ws-url: GET /v1/websocket's answer (NULL: built) */
    /* the --config file's strings, which the pointers above may point into */
    char config_scene[SERVE_CONFIG_STRING_MAX], config_backend[64],
        config_data[SERVE_CONFIG_STRING_MAX], config_durability[64],
        config_store_fault[SERVE_CONFIG_STRING_MAX], config_auth_file[SERVE_CONFIG_STRING_MAX],
        config_tls_cert[SERVE_CONFIG_STRING_MAX], config_tls_key[SERVE_CONFIG_STRING_MAX],
        config_scene_dir[SERVE_CONFIG_STRING_MAX], config_public_ws_url[HTTP_PUBLIC_URL_MAX];
} serve_options;

/* The command line (argv[0] = "serve"); fills o with the defaults first.
 * CLI_OK, CLI_HELP (printed) or CLI_ERROR (printed). */
cli_result serve_options_parse(int argc, char **argv, serve_options *o);
/* What a world's simulation takes from the options (host_sim_start). */
host_sim_config serve_host_config(const serve_options *o);

/* ---- who may connect, and how (serve_security.c) ---- */

/* Before any port opens: the TLS pair checked (a bad file named), the auth
 * table read (a malformed line named). *auth NULL when no --auth-file was
 * given. 0, or -1 with err. */
int serve_security_open(const serve_options *o, auth_table **auth, error_text *err);
/* SIGHUP: read the auth file again (a bad file is logged and the old
 * tokens kept); the net thread then closes connections of revoked tokens. */
void serve_security_reload(const serve_options *o, auth_table *auth);
/* The HTTP listener on o's port: its connections a quarter of RLIMIT_NOFILE,
 * the /v1/heights byte budgets, the token gate and TLS; status its readiness,
 * worlds the table of worlds it serves. *fd_reserve: the descriptors the
 * websocket server must leave free (net_limits.fd_reserve). */
http_server *serve_http_open(const serve_options *o, auth_table *auth, http_status *status,
                             hub_worlds *worlds, int *fd_reserve, error_text *err);
/* Reads a config's "auth_file", "tls_cert" and "tls_key" into o. */
int serve_security_config(const cJSON *doc, serve_options *o, error_text *err);

/* ---- a single daemon's created worlds (serve_worlds.c) ---- */
/* --max-worlds' ceiling: worlds a node ticks, or a daemon creates beside its
 * default one (the HTTP, websocket and metrics tables hold one more). */
#define SERVE_WORLDS_MAX 256
typedef struct serve_worlds serve_worlds;
/* After the daemon's ports are open: the worlds of DATA/worlds recovered and
 * started (each on ticker, the daemon's pool, and in table, which both ports
 * read), then POST/GET /v1/worlds and DELETE /v1/worlds/NAME served on http.
 * main_world: the default world. */
serve_worlds *serve_worlds_start(const serve_options *o, const host_sim *main_world,
                                 http_server *http, hub_worlds *table, net_server *net,
                                 host_ticker *ticker, error_text *err);
/* The daemon drains (serve.c): POST /v1/worlds is refused with 503 naming
 * why, and GET /v1/worlds says every world's lifecycle is "draining". */
void serve_worlds_drain(serve_worlds *ws, const char *why);
/* POST /v1/drain's answer (serve.c; a single daemon's and a node's): 202. */
unsigned serve_drain_json(int already, int grace_ms, char **json);
/* The main thread, now and then: each world whose lifecycle changed since the
 * last call is told to the admins that subscribed (world_state events). */
void serve_worlds_watch(serve_worlds *ws);
/* Every created world stopped (its storage kept), before the ports close. NULL is fine. */
void serve_worlds_stop(serve_worlds *ws);
/* --fresh: DATA/worlds and everything in it removed (worlds-kept/ stays). */
int serve_worlds_fresh(const char *data_dir, error_text *err);

/* ---- the body of POST /v1/worlds, checked once for both (serve_worlds_body.c) ---- */
/* {"error": why, "field": field}: the body of every refusal (malloc'd). */
char *worlds_error_json(const char *field, const char *why);
/* Counted (terrad_world_requests_total), logged, and *json set: returns code. */
unsigned worlds_refuse(const char *op, unsigned code, const char *field, const char *why,
                       char **json);
/* The body's name and scene text (malloc'd; the scene parsed by the
 * daemon's parser, made into nothing): 0, or the status with field (the
 * refused one: "name", "scene", a NaN's key...) and why. default_name: a
 * name refused with 409 (a single daemon's default world; NULL: none). */
unsigned worlds_body_check(const char *body, size_t len, const char *scene_dir,
                           const char *default_name, char *name, char **scene_text, char *field,
                           size_t fcap, char *why, size_t cap);

/* ---- cluster mode (serve_node.c, serve_cluster.c) ---- */

/*
 * `terrad serve --cluster`: the node joins the NATS cluster and ticks every
 * world it can take, up to --max-worlds (default 1; with --worlds, as many
 * as it names), all on one pool of sim workers; one HTTP and one websocket port
 * serve them all. Returns the exit status. stop: set by SIGINT/SIGTERM.
 */
int serve_node_run(const serve_options *o, auth_table *auth, volatile sig_atomic_t *stop,
                   volatile sig_atomic_t *hangup);

/* ---- any node serves any world (serve_relay.c) ---- */
/* A node's POST/GET /v1/worlds and DELETE /v1/worlds/NAME, through the
 * registry and leases (serve_node_api.c); freed after http stopped. */
typedef struct serve_node_api serve_node_api;
serve_node_api *serve_node_api_start(cluster *cl, const serve_options *o, const char *node,
                                     http_server *http);
void serve_node_api_free(serve_node_api *a);
typedef struct serve_relays serve_relays;
/* Makes net reach other nodes over cl (net_server_set_remote), and http answer
 * for the worlds relayed here by asking their owners (http_server_set_forward).
 * NULL: out of memory. */
serve_relays *serve_relays_start(cluster *cl, net_server *net, http_server *http, const char *node);
/* Relay every world of registered (the registry as last listed) but those
 * in busy (ticked or being taken here); stop relaying the unregistered ones. */
void serve_relays_refresh(serve_relays *r, char *const *registered, int nregistered,
                          char (*busy)[CLUSTER_WORLD_NAME_MAX + 1], int nbusy);
/* This node ticks world now: its relayed clients' messages come here. */
int serve_relays_own(serve_relays *r, const char *world, error_text *err);
/* Neither ticked nor relayed here any more (its clients are told and closed). */
void serve_relays_drop(serve_relays *r, const char *world);
/* Ends every subscription and relay. NULL is fine. */
void serve_relays_stop(serve_relays *r);

/* --node, or the host name with anything but [A-Za-z0-9_-] made '-'. */
void serve_node_name(const serve_options *o, char *out, size_t cap);
/* One pass over the candidate worlds (--worlds, or every one of registered,
 * the registry as last listed, in name order) not in held (count n): 1 and
 * the world's lease taken (its name in out), 0 when none is free, -1 on an
 * error (a --worlds name that is not registered). */
int serve_cluster_take(cluster *cl, const serve_options *o, char *const *registered,
                       int nregistered, char (*held)[CLUSTER_WORLD_NAME_MAX + 1], int n, char *out,
                       error_text *err);
/* The world's registered scene into m->sc, then its world and its store
 * recovered from JetStream (fencing the previous owner off) into m. */
int serve_cluster_open_world(cluster *cl, host_sim *m, const serve_options *o, error_text *err);
/* Once per tick: 0 while this node owns the world (a lapsed lease is taken
 * back when NATS answers again, at most once a second: *retried_ms), -1 once
 * it does not (lost says why). */
int serve_cluster_check(cluster *cl, host_sim *m, double *retried_ms, char *lost, size_t cap);

#endif
