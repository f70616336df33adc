/*
 * http.c: the HTTP endpoints (see http.h) on libmicrohttpd.
 *
 * How it fits the tick: nothing here runs on the sim thread or touches the
 * GL context. Probes, /v1/world and /v1/stats answer from the http_status
 * block the sim thread publishes after each tick; /metrics renders the
 * process-wide atomics; /v1/heights queues a read in the hub, which the sim
 * thread serves between two ticks, so the answer is the heights as of the
 * end of one named tick (X-Terrad-Tick) and a tick never waits on HTTP.
 *
 * libmicrohttpd runs a pool of four polling threads: a heights read blocks
 * its thread for up to one tick (or the timeout), and the other three keep
 * answering probes meanwhile. Connection, per-IP, memory and idle-time limits
 * keep a flood of slow sockets from holding the server; bodies, long query
 * strings and methods other than GET/HEAD are refused before any work, but
 * for POST /v1/worlds/{name}/edits (http_edits.c), whose body is kept up to
 * HTTP_EDIT_MAX_BYTES.
 *
 * Every request takes two calls of the access handler: the first only marks
 * the request, the second answers. Answering on the first call makes
 * libmicrohttpd 0.9.75 send "Connection: close" (shared notes), which would
 * break keep-alive for probes and the viewer.
 */
#include "http/http_internal.h"

#include <arpa/inet.h>
#include <stdatomic.h>
#include <microhttpd.h>
#include <netinet/in.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

#define ALLOWED_METHODS "GET, HEAD"

/* Per-request state, created by the URI log callback (which sees the raw
 * request target before libmicrohttpd splits and unescapes it) and freed
 * when the request completes. */
typedef struct request {
    int seen;   /* the first handler call has happened */
    int body;   /* body bytes arrived: refused with 413 */
    int edit;   /* POST /v1/worlds/{name}/edits: the body is kept (http_edits.c) */
    int api;    /* /v1/worlds or /v1/worlds/{name}: the world lifecycle API (http_world_api.c);
                 * a POST's body is kept as an edit's is */
    char *data; /* its bytes */
    size_t len, cap;
    size_t query_len; /* bytes after '?' in the raw target */
    int raw_nul;      /* "%00" in the raw target */
    int refused;      /* http_guard_headers_done's: past a connection limit, answered 503 */
} request;

/* ---- responses ---- */

enum MHD_Result http_queue(struct MHD_Connection *c, unsigned code, struct MHD_Response *r)
{
    if (!r)
        return MHD_NO;
    MHD_add_response_header(r, "X-Content-Type-Options", "nosniff");
    enum MHD_Result ok = MHD_queue_response(c, code, r);
    MHD_destroy_response(r);
    return ok;
}

static struct MHD_Response *text_response(const char *type, const char *body)
{
    struct MHD_Response *r =
        MHD_create_response_from_buffer(strlen(body), (void *)body, MHD_RESPMEM_MUST_COPY);
    if (r) {
        MHD_add_response_header(r, "Content-Type", type);
        MHD_add_response_header(r, "Cache-Control", "no-store");
    }
    return r;
}

static enum MHD_Result respond(struct MHD_Connection *c, unsigned code, const char *type,
                               const char *body)
{
    return http_queue(c, code, text_response(type, body));
}

static enum MHD_Result respond_error(struct MHD_Connection *c, unsigned code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static enum MHD_Result respond_error(struct MHD_Connection *c, unsigned code, const char *fmt, ...)
{
    char message[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    http_answer a = {0};
    http_answer_error(&a, code, "%s", message);
    return http_answer_queue(c, &a);
}

static enum MHD_Result respond_not_allowed(struct MHD_Connection *c, const char *method)
{
    char m[32];
    http_json_escape(method, m, sizeof m);
    char body[128];
    snprintf(body, sizeof body, "{\"error\":\"method %s not allowed; use GET or HEAD\"}\n", m);
    struct MHD_Response *r = text_response("application/json", body);
    if (r)
        MHD_add_response_header(r, "Allow", ALLOWED_METHODS);
    return http_queue(c, MHD_HTTP_METHOD_NOT_ALLOWED, r);
}

/* ---- status views ---- */

static void status_copy(http_server *s, http_status *snap)
{
    pthread_mutex_lock(&s->status->lock);
    *snap = *s->status; /* the copied lock is never used */
    pthread_mutex_unlock(&s->status->lock);
}

static enum MHD_Result serve_metrics(struct MHD_Connection *c)
{
    size_t len = 0;
    char *text = metrics_render(&len);
    if (!text)
        return respond_error(c, MHD_HTTP_INTERNAL_SERVER_ERROR, "out of memory rendering metrics");
    struct MHD_Response *r = MHD_create_response_from_buffer(len, text, MHD_RESPMEM_MUST_FREE);
    if (!r) {
        free(text);
        return MHD_NO;
    }
    MHD_add_response_header(r, "Content-Type", "text/plain; version=0.0.4; charset=utf-8");
    MHD_add_response_header(r, "Cache-Control", "no-store");
    return http_queue(c, MHD_HTTP_OK, r);
}

/* ---- static files ---- */

static const char *content_type(const char *name)
{
    static const struct {
        const char *ext, *type;
    } types[] = {
        {".html", "text/html; charset=utf-8"},
        {".js", "text/javascript; charset=utf-8"},
        {".mjs", "text/javascript; charset=utf-8"},
        {".css", "text/css; charset=utf-8"},
        {".svg", "image/svg+xml"},
        {".png", "image/png"},
        {".json", "application/json"},
        {".yaml", "application/yaml"},
        {".wasm", "application/wasm"},
    };
    const char *dot = strrchr(name, '.');
    if (dot)
        for (size_t i = 0; i < sizeof types / sizeof types[0]; i++)
            if (strcasecmp(dot, types[i].ext) == 0)
                return types[i].type;
    return "application/octet-stream";
}

static enum MHD_Result serve_embedded(struct MHD_Connection *c, const char *name);

static enum MHD_Result serve_static(struct MHD_Connection *c, const char *url)
{
    char name[512];
    if (strcmp(url, "/v1/openapi.yaml") == 0) /* this API's description, as in the repository */
        snprintf(name, sizeof name, "docs/openapi.yaml");
    else if (strcmp(url, "/") == 0)
        snprintf(name, sizeof name, "web/index.html");
    else if (snprintf(name, sizeof name, "web/%s", url + 1) >= (int)sizeof name)
        return respond_error(c, MHD_HTTP_NOT_FOUND, "not found");
    return serve_embedded(c, name);
}

/* An embedded file by its repository path, or 404. */
static enum MHD_Result serve_embedded(struct MHD_Connection *c, const char *name)
{
    size_t size = 0;
    const char *data = embedded_file_find(name, &size);
    if (!data)
        return respond_error(c, MHD_HTTP_NOT_FOUND, "not found");
    /* The table is static: no copy. */
    struct MHD_Response *r =
        MHD_create_response_from_buffer(size, (void *)data, MHD_RESPMEM_PERSISTENT);
    if (!r)
        return MHD_NO;
    MHD_add_response_header(r, "Content-Type", content_type(name));
    /* The viewer changes with the binary: always revalidate. */
    MHD_add_response_header(r, "Cache-Control", "no-cache");
    return http_queue(c, MHD_HTTP_OK, r);
}

/* GET /v1/twin: what a predicting client gives its twin (http_server_set_twin). */
static enum MHD_Result serve_twin(http_server *s, struct MHD_Connection *c)
{
    const char *t = atomic_load(&s->twin);
    if (!t || t[0] == '!')
        return respond_error(c, MHD_HTTP_NOT_FOUND, "no twin config for this world: %s",
                             t ? t + 1 : "not set (a cluster node's worlds have none)");
    return respond(c, MHD_HTTP_OK, "application/json", t);
}

/* The host part of a Host header ("name", "1.2.3.4" or "[v6]", without the
 * port) into out: 0, or -1 when absent, too long or not a host name. */
static int host_of(const char *host, char *out, size_t cap)
{
    if (!host || !host[0])
        return -1;
    size_t n = 0;
    if (host[0] == '[') { /* an IPv6 literal: up to its bracket */
        const char *end = strchr(host, ']');
        if (!end)
            return -1;
        n = (size_t)(end - host) + 1;
        for (const char *p = host + 1; p < end; p++)
            if (!strchr("0123456789abcdefABCDEF:.", *p))
                return -1;
    } else {
        while (host[n] && host[n] != ':') {
            char ch = host[n++];
            if (!((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') ||
                  (ch >= '0' && ch <= '9') || ch == '.' || ch == '-' || ch == '_'))
                return -1;
        }
    }
    if (n == 0 || n >= cap)
        return -1;
    memcpy(out, host, n);
    out[n] = 0;
    return 0;
}

/* GET /v1/websocket: where the websocket is (http_server_set_websocket). The
 * viewer asks this rather than guessing a port: a daemon's two ports need not
 * be neighbours, and behind a proxy neither may be what the page sees. */
static enum MHD_Result serve_websocket(http_server *s, struct MHD_Connection *c)
{
    if (!atomic_load(&s->ws_ready))
        return respond_error(c, MHD_HTTP_SERVICE_UNAVAILABLE, "the websocket server is not up yet");
    char url[HTTP_PUBLIC_URL_MAX + 16], host[256];
    const char *from = "public_ws_url";
    if (s->ws_public[0]) {
        http_json_escape(s->ws_public, url, sizeof url);
    } else {
        from = "host";
        if (host_of(MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_HOST), host,
                    sizeof host) != 0)
            return respond_error(c, MHD_HTTP_BAD_REQUEST,
                                 "Host: missing or not a host name; the websocket URL is built "
                                 "from it (or give the daemon --public-ws-url)");
        snprintf(url, sizeof url, "%s://%s:%d/", s->ws_tls ? "wss" : "ws", host, s->ws_port);
    }
    char body[HTTP_PUBLIC_URL_MAX + 160];
    snprintf(body, sizeof body,
             "{\"url\":\"%s\",\"port\":%d,\"subprotocol\":\"" TERRAD_PROTO_SUBPROTOCOL
             "\",\"from\":\"%s\"}\n",
             url, s->ws_port, from);
    return respond(c, MHD_HTTP_OK, "application/json", body);
}

/* ---- dispatch ---- */

/* 1 if the request announces a body (any body is refused). */
static int announces_body(struct MHD_Connection *c)
{
    if (MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_TRANSFER_ENCODING))
        return 1;
    const char *len =
        MHD_lookup_connection_value(c, MHD_HEADER_KIND, MHD_HTTP_HEADER_CONTENT_LENGTH);
    if (!len)
        return 0;
    for (const char *p = len; *p; p++)
        if (*p != '0' && *p != ' ' && *p != '\t')
            return 1;
    return 0;
}

/* Liveness: 503 when a watched thread has made no progress past its limit. */
static enum MHD_Result serve_health(http_server *s, struct MHD_Connection *c)
{
    pthread_mutex_lock(&s->watch_lock);
    http_watch w[HTTP_MAX_WATCHES];
    int n = s->nwatches;
    memcpy(w, s->watches, sizeof w);
    pthread_mutex_unlock(&s->watch_lock);
    for (int i = 0; i < n; i++) {
        double stalled = w[i].stalled_ms(w[i].arg);
        if (stalled > w[i].limit_ms)
            return respond_error(c, MHD_HTTP_SERVICE_UNAVAILABLE,
                                 "the %s thread has made no progress for %.1f s", w[i].name,
                                 stalled / 1000);
    }
    return respond(c, MHD_HTTP_OK, "text/plain; charset=utf-8", "ok\n");
}

int http_server_watch(http_server *s, const char *name, http_stalled_fn stalled_ms, const void *arg,
                      double limit_ms)
{
    pthread_mutex_lock(&s->watch_lock);
    int i = s->nwatches < HTTP_MAX_WATCHES ? s->nwatches++ : -1;
    if (i >= 0) {
        snprintf(s->watches[i].name, sizeof s->watches[i].name, "%s", name);
        s->watches[i].stalled_ms = stalled_ms;
        s->watches[i].arg = arg;
        s->watches[i].limit_ms = limit_ms;
    }
    pthread_mutex_unlock(&s->watch_lock);
    return i < 0 ? -1 : 0;
}

double http_status_stalled_ms(const void *status)
{
    http_status *st = (http_status *)status;
    pthread_mutex_lock(&st->lock);
    double at = st->waiting ? 0 : st->published_ms;
    pthread_mutex_unlock(&st->lock);
    return at > 0 ? time_now_ms() - at : 0;
}

/* /v1/world, /v1/stats or /v1/heights for the world ?world= names (the
 * default world when none is named: the table's); on a cluster node a world
 * another node ticks is asked of its owner. */
static enum MHD_Result serve_hosted(http_server *s, struct MHD_Connection *c, http_view view)
{
    unsigned code = 0;
    char why[512];
    const char *name = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "world");
    hub_world *w = http_world_acquire(s, name, &code, why, sizeof why);
    http_answer a = {0};
    if (w) {
        http_args args = {.c = c};
        http_view_hosted(s, w, view, &args, &a);
        http_world_release(s, w);
    } else if (!(name && code == MHD_HTTP_NOT_FOUND &&
                 http_forward_request(s, c, name, view, &a))) {
        return respond_error(c, code, "%s", why);
    }
    return http_answer_queue(c, &a);
}

static int method_allowed(const char *method)
{
    return strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
}

/* A request that came past a connection limit with no room to make
 * (http_guard.c): its body is read and dropped, then it is answered 503 with
 * Retry-After and the connection closed; nothing of it was done. */
static enum MHD_Result refuse_busy(http_server *s, struct MHD_Connection *c, int why,
                                   size_t *upload_size)
{
    if (*upload_size != 0) {
        *upload_size = 0;
        return MHD_YES;
    }
    unsigned per_address = 0, all = 0;
    http_guard_limits(s->guard, &per_address, &all);
    metrics_count_http_refused(why == HTTP_GUARD_REFUSED_ADDRESS ? 0 : 1);
    char body[256];
    snprintf(body, sizeof body,
             "{\"error\":\"busy: %s (%u); nothing was done: retry after 1 s\"}\n",
             why == HTTP_GUARD_REFUSED_ADDRESS
                 ? "this address already has as many connections in requests as it may"
                 : "the server already has as many connections in requests as it may",
             why == HTTP_GUARD_REFUSED_ADDRESS ? per_address : all);
    struct MHD_Response *r = text_response("application/json", body);
    if (r) {
        MHD_add_response_header(r, "Retry-After", "1");
        MHD_add_response_header(r, MHD_HTTP_HEADER_CONNECTION, "close");
    }
    return http_queue(c, MHD_HTTP_SERVICE_UNAVAILABLE, r);
}

/* POST /v1/worlds/{name}/edits: keep the body, then answer (http_edits.c). */
static enum MHD_Result edit_request(http_server *s, struct MHD_Connection *c, const char *url,
                                    request *rq, const char *upload, size_t *upload_size)
{
    if (*upload_size != 0) {
        size_t n = *upload_size;
        *upload_size = 0;
        if (rq->len + n > HTTP_EDIT_MAX_BYTES) {
            rq->body = 1; /* over the limit: the rest is dropped, 413 at the end */
            return MHD_YES;
        }
        if (rq->len + n + 1 > rq->cap) {
            size_t cap = rq->cap ? rq->cap : 4096;
            while (cap < rq->len + n + 1)
                cap *= 2;
            char *grown = realloc(rq->data, cap);
            if (!grown) {
                rq->body = 1;
                return MHD_YES;
            }
            rq->data = grown;
            rq->cap = cap;
        }
        memcpy(rq->data + rq->len, upload, n);
        rq->len += n;
        return MHD_YES;
    }
    if (s->main)
        return respond_error(c, MHD_HTTP_NOT_FOUND,
                             "the probe port serves /healthz, /readyz and /metrics only");
    if (rq->body)
        return respond_error(c, MHD_HTTP_CONTENT_TOO_LARGE,
                             "body: over %d bytes (or no memory for it)", HTTP_EDIT_MAX_BYTES);
    http_answer a = {0};
    if (rq->api) {
        http_world_api_answer(s, c, url, "POST", rq->data ? rq->data : "", rq->len, &a);
        return http_answer_queue(c, &a);
    }
    char name[80];
    http_edit_path(url, name, sizeof name);
    http_edit_post(s, c, name, rq->data ? rq->data : "", rq->len, &a);
    return http_answer_queue(c, &a);
}

static enum MHD_Result handle(void *cls, struct MHD_Connection *c, const char *url,
                              const char *method, const char *version, const char *upload,
                              size_t *upload_size, void **state)
{
    (void)version;
    (void)upload;
    http_server *s = cls;
    request *rq = *state;
    if (!rq) { /* the URI callback's allocation failed */
        rq = calloc(1, sizeof *rq);
        if (!rq)
            return MHD_NO;
        *state = rq;
    }
    if (!rq->seen) {
        rq->seen = 1;
        rq->refused = http_guard_headers_done(s->guard, c);
        if (rq->refused < 0)
            return MHD_NO; /* cut to make room, and told so: nothing of it is done */
        if (rq->refused)
            return MHD_YES; /* read it whole, then answer 503 (refuse_busy) */
        /* A body we will not read: answer now, which also closes the
         * connection, rather than drain the body first. */
        char name[80];
        rq->edit = strcmp(method, "POST") == 0 && http_edit_path(url, name, sizeof name);
        rq->api = !rq->edit && http_world_api_path(s, url);
        if (rq->api && strcmp(method, "POST") == 0)
            rq->edit = 1; /* its body is kept */
        if (announces_body(c) && !rq->edit) {
            if (!method_allowed(method))
                return respond_not_allowed(c, method);
            return respond_error(c, MHD_HTTP_CONTENT_TOO_LARGE, "request bodies are not accepted");
        }
        return MHD_YES;
    }
    if (rq->refused)
        return refuse_busy(s, c, rq->refused, upload_size);
    if (rq->edit)
        return edit_request(s, c, url, rq, upload, upload_size);
    if (*upload_size != 0) {
        rq->body = 1;
        *upload_size = 0; /* drop it; answered once the upload ends */
        return MHD_YES;
    }
    if (rq->api && !s->main && !rq->body) {
        http_answer a = {0};
        http_world_api_answer(s, c, url, method, NULL, 0, &a);
        return http_answer_queue(c, &a);
    }
    if (!method_allowed(method))
        return respond_not_allowed(c, method);
    if (rq->body)
        return respond_error(c, MHD_HTTP_CONTENT_TOO_LARGE, "request bodies are not accepted");
    if (rq->query_len > HTTP_MAX_QUERY_BYTES)
        return respond_error(c, MHD_HTTP_URI_TOO_LONG,
                             "query string of %zu bytes exceeds the limit of %d bytes",
                             rq->query_len, HTTP_MAX_QUERY_BYTES);
    if (rq->raw_nul || strstr(url, ".."))
        return respond_error(c, MHD_HTTP_BAD_REQUEST, "path must not contain \"..\" or NUL");

    if (s->main) { /* the probe listener: probes and metrics only */
        s = s->main;
        if (strcmp(url, "/healthz") != 0 && strcmp(url, "/readyz") != 0 &&
            strcmp(url, "/metrics") != 0)
            return respond_error(c, MHD_HTTP_NOT_FOUND,
                                 "the probe port serves /healthz, /readyz and /metrics only");
    }
    if (strcmp(url, "/healthz") == 0)
        return serve_health(s, c);
    if (strcmp(url, "/metrics") == 0)
        return serve_metrics(c);
    http_status snap;
    status_copy(s, &snap);
    if (strcmp(url, "/readyz") == 0) {
        char why[320], draining[256];
        http_draining(s, draining, sizeof draining);
        if (draining[0]) /* alive (/healthz) but taking nothing new */
            return respond_error(c, MHD_HTTP_SERVICE_UNAVAILABLE, "not ready: draining: %s",
                                 draining);
        snprintf(why, sizeof why, "not ready: %s",
                 snap.not_ready[0] ? snap.not_ready : "the GL context or the world is not up");
        return snap.ready ? respond(c, MHD_HTTP_OK, "text/plain; charset=utf-8", "ready\n")
                          : respond_error(c, MHD_HTTP_SERVICE_UNAVAILABLE, "%s", why);
    }
    struct MHD_Response *refusal = http_auth_refusal(c, url, s->auth);
    if (refusal)
        return http_queue(c, MHD_HTTP_UNAUTHORIZED, refusal);
    if (strcmp(url, "/v1/twin") == 0)
        return serve_twin(s, c);
    if (strcmp(url, "/v1/websocket") == 0)
        return serve_websocket(s, c);
    int stats = strcmp(url, "/v1/stats") == 0, about = strcmp(url, "/v1/world") == 0,
        heights = strcmp(url, "/v1/heights") == 0;
    if (!(stats || about || heights))
        return serve_static(c, url);
    return serve_hosted(s, c,
                        stats   ? HTTP_VIEW_STATS
                        : about ? HTTP_VIEW_WORLD
                                : HTTP_VIEW_HEIGHTS);
}

static void *request_begin(void *cls, const char *uri, struct MHD_Connection *c)
{
    (void)cls;
    (void)c;
    request *rq = calloc(1, sizeof *rq);
    if (!rq)
        return NULL;
    const char *q = strchr(uri, '?');
    size_t path_len = q ? (size_t)(q - uri) : strlen(uri);
    rq->query_len = q ? strlen(q + 1) : 0;
    /* An escaped NUL would cut the unescaped path short; look at the raw
     * path for it before libmicrohttpd decodes it. */
    for (size_t i = 0; i + 2 < path_len; i++)
        if (uri[i] == '%' && uri[i + 1] == '0' && uri[i + 2] == '0')
            rq->raw_nul = 1;
    return rq;
}

static void request_done(void *cls, struct MHD_Connection *c, void **state,
                         enum MHD_RequestTerminationCode code)
{
    http_server *s = cls;
    (void)code;
    http_guard_request_done(s->guard, c);
    request *rq = *state;
    if (rq)
        free(rq->data);
    free(*state);
    *state = NULL;
}

static unsigned or_default(unsigned v, unsigned d)
{
    return v ? v : d;
}

http_server *http_server_start_secure(int port, int bind_any, http_status *status,
                                      const http_limits *limits, const http_security *sec,
                                      error_text *err)
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
    s->auth = sec ? sec->auth : NULL;
    s->worlds = sec ? sec->worlds : NULL; /* read by the HTTP threads from their start */
    if (http_tls_load(&s->tls, sec, err) != 0) {
        free(s);
        return NULL;
    }
    pthread_mutex_init(&s->watch_lock, NULL);
    pthread_mutex_init(&s->worlds_lock, NULL);
    pthread_cond_init(&s->worlds_cond, NULL);
    http_limits l = limits ? *limits : (http_limits){0};
    l.connections = or_default(l.connections, HTTP_DEFAULT_CONNECTIONS);
    l.connections_per_ip = or_default(l.connections_per_ip, HTTP_DEFAULT_CONNECTIONS_PER_IP);
    l.timeout_s = or_default(l.timeout_s, HTTP_DEFAULT_TIMEOUT_S);
    if (!l.memory_per_connection)
        l.memory_per_connection = HTTP_DEFAULT_MEMORY_PER_CONNECTION;
    if (l.heights_timeout_ms <= 0)
        l.heights_timeout_ms = HTTP_DEFAULT_HEIGHTS_TIMEOUT_MS;
    if (l.heights_max_cells <= 0)
        l.heights_max_cells = HTTP_DEFAULT_HEIGHTS_MAX_CELLS;
    if (l.edit_max_cells <= 0)
        l.edit_max_cells = WORLD_EDIT_MAX_CELLS_DEFAULT;
    if (!l.heights_bytes_per_address)
        l.heights_bytes_per_address = HTTP_DEFAULT_HEIGHTS_BYTES_PER_ADDRESS;
    if (!l.heights_bytes_total)
        l.heights_bytes_total = HTTP_DEFAULT_HEIGHTS_BYTES_TOTAL;
    s->limits = l;
    /* The connection limits are the guard's: it makes room by closing the
     * oldest connection still sending its headers. libmicrohttpd's own limit
     * sits above them (the closed ones linger until its thread sees the end),
     * as a last stop. */
    unsigned soft = l.connections - l.connections / 8;
    s->guard = http_guard_start(l.heights_bytes_per_address, l.heights_bytes_total, l.timeout_s,
                                soft, l.connections_per_ip < soft ? l.connections_per_ip : soft,
                                http_tls_on(&s->tls));
    if (!s->guard) {
        error_set(err, "http: cannot start the connection guard (out of memory or threads)");
        pthread_mutex_destroy(&s->watch_lock);
        free(s);
        return NULL;
    }

    struct sockaddr_in addr;
    memset(&addr, 0, sizeof addr);
    addr.sin_family = AF_INET;
    addr.sin_port = htons((uint16_t)port);
    addr.sin_addr.s_addr = htonl(bind_any ? INADDR_ANY : INADDR_LOOPBACK);
    s->daemon = MHD_start_daemon(
        MHD_USE_INTERNAL_POLLING_THREAD | MHD_USE_AUTO | (http_tls_on(&s->tls) ? MHD_USE_TLS : 0),
        (uint16_t)port, NULL, NULL, handle, s, MHD_OPTION_ARRAY, s->tls.options,
        MHD_OPTION_SOCK_ADDR, (struct sockaddr *)&addr, MHD_OPTION_THREAD_POOL_SIZE, (unsigned)4,
        MHD_OPTION_CONNECTION_LIMIT, l.connections, MHD_OPTION_CONNECTION_TIMEOUT, l.timeout_s,
        MHD_OPTION_CONNECTION_MEMORY_LIMIT, l.memory_per_connection, MHD_OPTION_URI_LOG_CALLBACK,
        request_begin, s, MHD_OPTION_NOTIFY_COMPLETED, request_done, s,
        MHD_OPTION_NOTIFY_CONNECTION, http_guard_notify, s->guard, MHD_OPTION_END);
    if (!s->daemon) {
        error_set(err, "http: cannot listen on port %d (in use, not permitted, or TLS refused)",
                  port);
        http_guard_stop(s->guard);
        pthread_mutex_destroy(&s->watch_lock);
        http_tls_free(&s->tls);
        free(s);
        return NULL;
    }
    const union MHD_DaemonInfo *info = MHD_get_daemon_info(s->daemon, MHD_DAEMON_INFO_BIND_PORT);
    s->port = info ? info->port : port;
    return s;
}

http_server *http_server_start_limited(int port, int bind_any, http_status *status,
                                       const http_limits *limits, error_text *err)
{
    return http_server_start_secure(port, bind_any, status, limits, NULL, err);
}

http_server *http_server_start(int port, int bind_any, http_status *status, error_text *err)
{
    return http_server_start_limited(port, bind_any, status, NULL, err);
}

void http_server_set_twin(http_server *s, const char *json, const char *why)
{
    size_t n = strlen(json ? json : why) + 2;
    char *text = malloc(n);
    if (!text)
        return; /* /v1/twin then answers 404 "not set" */
    snprintf(text, n, "%s%s", json ? "" : "!", json ? json : why);
    char *old = atomic_exchange(&s->twin, text);
    free(old); /* NULL: set once, before a request can hold it */
}

http_server *http_probe_start(http_server *main, int port, error_text *err)
{
    /* loopback only, a few connections with a short timeout: for the
     * orchestrator on this host, never reachable by the strangers who may
     * fill the main port */
    http_limits l = {.connections = 16, .connections_per_ip = 16, .timeout_s = 3};
    http_server *p = http_server_start_limited(port, 0, main->status, &l, err);
    if (p)
        p->main = main;
    return p;
}

void http_server_set_websocket(http_server *s, int port, int tls, const char *public_url)
{
    s->ws_port = port;
    s->ws_tls = tls;
    snprintf(s->ws_public, sizeof s->ws_public, "%s", public_url ? public_url : "");
    atomic_store(&s->ws_ready, 1);
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
    http_guard_stop(s->guard);
    pthread_mutex_destroy(&s->watch_lock);
    http_tls_free(&s->tls);
    free(atomic_load(&s->twin));
    pthread_mutex_destroy(&s->worlds_lock);
    pthread_cond_destroy(&s->worlds_cond);
    free(s);
}
