/*
 * http.c: GET /healthz, /readyz, /v1/world and /v1/stats on libmicrohttpd.
 * Handlers answer from the published http_status only, so a slow or hostile
 * HTTP client can never stall a tick. Connection limits and timeouts keep a
 * flood of idle sockets from holding the server.
 */
#include "http/http.h"

#include <arpa/inet.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct http_server {
    struct MHD_Daemon *daemon;
    http_status *status;
    int port;
};

static enum MHD_Result respond(struct MHD_Connection *c, unsigned code, const char *type,
                               const char *body)
{
    struct MHD_Response *r =
        MHD_create_response_from_buffer(strlen(body), (void *)body, MHD_RESPMEM_MUST_COPY);
    if (!r)
        return MHD_NO;
    MHD_add_response_header(r, "Content-Type", type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    enum MHD_Result ok = MHD_queue_response(c, code, r);
    MHD_destroy_response(r);
    return ok;
}

static enum MHD_Result handle(void *cls, struct MHD_Connection *c, const char *url,
                              const char *method, const char *version, const char *upload,
                              size_t *upload_size, void **state)
{
    (void)version;
    (void)upload;
    http_server *s = cls;
    /* First call of a request: only mark it (queueing now would force
     * "Connection: close" in libmicrohttpd 0.9.75, see shared notes). */
    if (*state == NULL) {
        *state = (void *)1;
        return MHD_YES;
    }
    if (*upload_size != 0) {
        *upload_size = 0; /* no endpoint takes a body: drop it */
        return MHD_YES;
    }
    if (strcmp(method, "GET") != 0 && strcmp(method, "HEAD") != 0)
        return respond(c, MHD_HTTP_METHOD_NOT_ALLOWED, "application/json",
                       "{\"error\":\"method not allowed\"}\n");
    char body[2048];
    http_status *st = s->status;
    pthread_mutex_lock(&st->lock);
    http_status snap = *st;
    pthread_mutex_unlock(&st->lock);
    if (strcmp(url, "/healthz") == 0)
        return respond(c, MHD_HTTP_OK, "text/plain; charset=utf-8", "ok\n");
    if (strcmp(url, "/readyz") == 0)
        return snap.ready ? respond(c, MHD_HTTP_OK, "text/plain; charset=utf-8", "ready\n")
                          : respond(c, MHD_HTTP_SERVICE_UNAVAILABLE, "text/plain; charset=utf-8",
                                    "not ready\n");
    if (strcmp(url, "/v1/stats") == 0) {
        snprintf(body, sizeof body,
                 "{\"tick\":%llu,\"volume\":%lld,\"last_tick_ms\":%.3f,\"overruns\":%llu}\n",
                 (unsigned long long)snap.tick, (long long)snap.volume, snap.last_tick_ms,
                 (unsigned long long)snap.overruns);
        return respond(c, MHD_HTTP_OK, "application/json", body);
    }
    if (strcmp(url, "/v1/world") == 0) {
        snprintf(body, sizeof body,
                 "{\"width\":%d,\"height\":%d,\"cell_size_m\":%.17g,\"units_per_m\":%d,"
                 "\"tick\":%llu,\"backend\":\"%s\",\"renderer\":\"%s\",\"models\":[\"%s\"],"
                 "\"metric\":\"%s\"}\n",
                 snap.world_width, snap.world_height, snap.cell_size_m, snap.units_per_m,
                 (unsigned long long)snap.tick, snap.backend, snap.renderer, snap.method,
                 snap.metric);
        return respond(c, MHD_HTTP_OK, "application/json", body);
    }
    return respond(c, MHD_HTTP_NOT_FOUND, "application/json", "{\"error\":\"not found\"}\n");
}

static void request_done(void *cls, struct MHD_Connection *c, void **state,
                         enum MHD_RequestTerminationCode code)
{
    (void)cls;
    (void)c;
    (void)code;
    *state = NULL;
}

http_server *http_server_start(int port, int bind_any, http_status *status, error_text *err)
{
    if (port < 0 || port > 65535) {
        error_set(err, "http: port %d out of range", port);
        return NULL;
    }
    http_server *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "http: out of memory");
        return NULL;
    }
    s->status = status;
    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t)port);
    addr.sin_addr.s_addr = htonl(bind_any ? INADDR_ANY : INADDR_LOOPBACK);
    s->daemon = MHD_start_daemon(
        MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_AUTO, (uint16_t)port, NULL, NULL,
        handle, s, MHD_OPTION_SOCK_ADDR, (struct sockaddr *)&addr, MHD_OPTION_CONNECTION_LIMIT,
        (unsigned)256, MHD_OPTION_PER_IP_CONNECTION_LIMIT, (unsigned)64,
        MHD_OPTION_CONNECTION_TIMEOUT, (unsigned)10, MHD_OPTION_CONNECTION_MEMORY_LIMIT,
        (size_t)65536, MHD_OPTION_NOTIFY_COMPLETED, request_done, s, MHD_OPTION_END);
    if (!s->daemon) {
        error_set(err, "http: cannot listen on port %d (in use or not permitted)", port);
        free(s);
        return NULL;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(s->daemon, MHD_DAEMON_INFO_BIND_PORT);
    s->port = info ? info->port : port;
    return s;
}

int http_server_port(const http_server *s)
{
    return s->port;
}

void http_server_stop(http_server *s)
{
    if (!s)
        return;
    MHD_stop_daemon(s->daemon);
    free(s);
}
