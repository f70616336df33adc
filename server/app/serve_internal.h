/*
 * serve_internal.h: what `terrad serve`'s files share inside server/app/ —
 * the options (serve_options.c reads them from the command line and
 * --config) and the demo actors (serve_demo.c) that keep the terrain
 * deforming without clients. serve.c runs the daemon on them.
 */
#ifndef TERRAD_SERVE_INTERNAL_H
#define TERRAD_SERVE_INTERNAL_H

#include <stdio.h>

#include "base/base.h"
#include "collider/collider.h"
#include "net/net.h"
#include "world/world.h"

#define SERVE_CONFIG_STRING_MAX 4096

typedef struct serve_options {
    const char *scene_path;
    const char *backend;
    int http_port;
    int ws_port;
    int bind_any;
    int demo_actors;
    double tick_hz;    /* 0: the scene's */
    const char *token; /* NULL: no token required */
    long max_ticks;    /* < 0: run until signalled */
    net_limits limits;
    const char *data_dir;    /* NULL: memory only (--no-data) */
    const char *durability;  /* every-tick | group:MS | none */
    long wal_segment_bytes;  /* compaction threshold */
    const char *store_fault; /* test hook: writes fail ENOSPC while this file exists */
    int config_loaded;       /* --config was given */
    /* the --config file's strings, which the pointers above may point into */
    char config_scene[SERVE_CONFIG_STRING_MAX], config_backend[64],
        config_token[SERVE_CONFIG_STRING_MAX], config_data[SERVE_CONFIG_STRING_MAX],
        config_durability[64], config_store_fault[SERVE_CONFIG_STRING_MAX];
} serve_options;

/* The command line (argv[0] = "serve"); fills o with the defaults first.
 * CLI_OK, CLI_HELP (printed) or CLI_ERROR (printed). */
cli_result serve_options_parse(int argc, char **argv, serve_options *o);

/* A sphere that slides across the world in a straight line, reflects off the
 * edges and bobs up and down, dipping into the terrain at the bottom. */
typedef struct demo_actor {
    collider_geometry geometry;
    double x, y, vx, vy, phase;
} demo_actor;

void demo_actors_init(demo_actor *a, int count, const world *w);
collider_pose demo_actor_step(demo_actor *a, const world *w, double dt, double time_s);

#endif
