/*
 * http: the daemon's HTTP side on libmicrohttpd — liveness and readiness
 * probes and a few JSON views of the world. It runs on libmicrohttpd's own
 * thread and never touches the GL context: it reads a status block the sim
 * thread publishes under a mutex once per tick.
 */
#ifndef TERRAD_HTTP_H
#define TERRAD_HTTP_H

#include <pthread.h>
#include <stdint.h>

#include "base/base.h"

/* What the sim thread publishes each tick for the probes. */
typedef struct http_status {
    pthread_mutex_t lock;
    int ready;          /* GL context (or CPU backend) up and the world loaded */
    uint64_t tick;
    int64_t volume;     /* Σh */
    int world_width, world_height;
    double cell_size_m;
    int32_t units_per_m;
    char renderer[256];
    char backend[16];
    char method[16];
    char metric[16];
    double last_tick_ms;
    uint64_t overruns;
} http_status;

typedef struct http_server http_server;

/* Listen on 127.0.0.1 unless bind_any; port 0 picks a free one. */
http_server *http_server_start(int port, int bind_any, http_status *status, error_text *err);
int http_server_port(const http_server *s);
void http_server_stop(http_server *s);

#endif
