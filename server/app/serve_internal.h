/*
 * serve_internal.h: what `terrad serve`'s files share inside server/app/ —
 * the options (serve_options.c reads them from the command line and
 * --config), the demo actors (serve_demo.c) that keep the terrain
 * deforming without clients, and cluster mode (serve_cluster.c: which world
 * this node ticks, and its store on JetStream). serve.c runs the daemon on
 * them.
 */
#ifndef TERRAD_SERVE_INTERNAL_H
#define TERRAD_SERVE_INTERNAL_H

#include <signal.h>
#include <stdio.h>

#include "base/base.h"
#include "cluster/cluster.h"
#include "collider/collider.h"
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
    int insecure_open; /* --insecure-open: --bind-any without any token is allowed */
    int probe_port;    /* -1: none; else --probe-port (0 = any free port) */
    int demo_actors;
    double tick_hz;                 /* 0: the scene's */
    const char *token;              /* NULL: no token required (deprecated: one admin token) */
    const char *auth_file;          /* --auth-file: tokens' hashes and roles, reread on SIGHUP */
    const char *tls_cert, *tls_key; /* --tls-cert, --tls-key: wss:// and https:// only */
    long max_ticks;                 /* < 0: run until signalled */
    net_limits limits;
    /* limits.max_heights_bytes_per_address / _in_flight: /v1/heights answers
     * held at once (0: http.c's defaults, 64 MiB and 256 MiB) */
    size_t heights_bytes_per_address, heights_bytes_in_flight;
    const char *data_dir;     /* NULL: memory only (--no-data, or a demo without --data) */
    int data_given;           /* --data, or "data" in --config */
    int demo_in_memory;       /* demo actors and no --data: no store */
    int fresh;                /* --fresh: store_remove before store_open */
    const char *durability;   /* every-tick | group:MS | none */
    long wal_segment_bytes;   /* compaction threshold */
    const char *store_fault;  /* test hook: writes fail ENOSPC while this file exists */
    int recover_truncate;     /* start on a damaged data directory, cutting the damage */
    int config_loaded;        /* --config was given */
    const char *cluster_urls; /* --cluster: NULL when not in a cluster */
    const char *node;         /* --node */
    const char *world_name;   /* --world: NULL for the first one free */
    /* the --config file's strings, which the pointers above may point into */
    char config_scene[SERVE_CONFIG_STRING_MAX], config_backend[64],
        config_token[SERVE_CONFIG_STRING_MAX], config_data[SERVE_CONFIG_STRING_MAX],
        config_durability[64], config_store_fault[SERVE_CONFIG_STRING_MAX],
        config_auth_file[SERVE_CONFIG_STRING_MAX], config_tls_cert[SERVE_CONFIG_STRING_MAX],
        config_tls_key[SERVE_CONFIG_STRING_MAX];
} serve_options;

/* The command line (argv[0] = "serve"); fills o with the defaults first.
 * CLI_OK, CLI_HELP (printed) or CLI_ERROR (printed). */
cli_result serve_options_parse(int argc, char **argv, serve_options *o);

/* ---- who may connect, and how (serve_security.c) ---- */

/* Before any port opens: the TLS pair checked (a bad file named), the auth
 * table read (a malformed line named). *auth NULL when neither a file nor a
 * token was given. 0, or -1 with err. */
int serve_security_open(const serve_options *o, auth_table **auth, error_text *err);
/* SIGHUP: read the auth file again (a bad file is logged and the old
 * tokens kept); the net thread then closes connections of revoked tokens. */
void serve_security_reload(const serve_options *o, auth_table *auth);
/* Reads a config's "auth_file", "tls_cert" and "tls_key" into o. */
int serve_security_config(const cJSON *doc, serve_options *o, error_text *err);

/* ---- cluster mode (serve_cluster.c) ---- */

/* A node's hold on one world: the connection, the world's name and its store. */
typedef struct serve_cluster {
    cluster *cl;
    char world[CLUSTER_WORLD_NAME_MAX + 1];
    cluster_store *cs;
    char lost[256];    /* why this node no longer owns the world */
    double retried_ms; /* the last attempt to take a lapsed lease back */
} serve_cluster;

/*
 * Joins the cluster and becomes the owner of one world: --world, or the
 * first registered world whose lease this node can take; while none can be
 * taken it waits (a standby), until *stop is set (then -1, err empty). Loads
 * the world's scene from the registry into sc. 0, or -1 with err.
 */
int serve_cluster_join(serve_cluster *c, const serve_options *o, volatile sig_atomic_t *stop,
                       scene *sc, error_text *err);
/* The world's store, recovered into w (whose base terrain is in it): takes
 * the log (fencing the previous owner off) and wraps it for the service. */
store *serve_cluster_open_store(serve_cluster *c, world *w, store_recovery *rec, error_text *err);
/* Once per tick: 0 while this node owns the world (a lapsed lease is taken
 * back when NATS answers again), -1 once it does not (c->lost says why). */
int serve_cluster_check(serve_cluster *c);
/* Releases the lease if held and disconnects (store_close closes the store). */
void serve_cluster_leave(serve_cluster *c);

/* A sphere that slides across the world in a straight line, reflects off the
 * edges and bobs up and down, dipping into the terrain at the bottom. */
typedef struct demo_actor {
    collider_geometry geometry;
    double x, y, vx, vy, phase;
} demo_actor;

void demo_actors_init(demo_actor *a, int count, const world *w);
collider_pose demo_actor_step(demo_actor *a, const world *w, double dt, double time_s);

#endif
