/*
 * http_internal.h: the HTTP server's own state, shared by http.c (the
 * endpoints) and http_worlds.c (a cluster node's table of worlds). Not part
 * of the face of http/ (that is http.h).
 */
#ifndef TERRAD_HTTP_INTERNAL_H
#define TERRAD_HTTP_INTERNAL_H

#include <microhttpd.h>
#include <pthread.h>
#include <stdatomic.h>

#include "http/http.h"

typedef struct http_watch {
    char name[32];
    http_stalled_fn stalled_ms;
    const void *arg;
    double limit_ms;
} http_watch;

/* One world a cluster node serves: its status block, its hub for height
 * reads and its base terrain. refs: requests using it now (under worlds_lock);
 * removal waits until none is. */
typedef struct http_world {
    char name[65];
    http_status *status;
    hub *heights;
    const world *base;
    int refs;
} http_world;

struct http_server {
    struct MHD_Daemon *daemon;
    http_status *status;
    hub *heights;
    _Atomic(const world *) base; /* /v1/heights?base=1 (NULL: 503); see http_server_set_base */
    http_limits limits;
    int port;
    pthread_mutex_t watch_lock; /* watches are added while MHD's threads serve */
    http_watch watches[HTTP_MAX_WATCHES];
    int nwatches;
    /* a cluster node (http_server_host_worlds): /v1/world, /v1/stats and
     * /v1/heights answer for the world ?world=NAME names */
    int hosts_worlds;
    pthread_mutex_t worlds_lock;
    pthread_cond_t worlds_cond;
    http_world *worlds[HTTP_MAX_WORLDS];
    int nworlds;
};

/* The world a request names (?world=NAME; without it, the node's first
 * world), counted as in use: NULL with the status to answer and why. */
http_world *http_world_acquire(http_server *s, const char *name, unsigned *code, char *why,
                               size_t cap);
void http_world_release(http_server *s, http_world *w);

#endif
