/*
 * http_internal.h: what the files of server/http share; not part of the face
 * of http/ (that is http.h).
 *
 *   http.c        the MHD daemon, routing, probes, metrics, static files
 *   http_views.c  the /v1 answers (world, stats, heights), also for a
 *                 request another node forwarded (any node serves any world)
 *   http_worlds.c the world ?world=NAME names, from the daemon's one table
 *                 of worlds (hub.h, hub_worlds)
 *   http_world_api.c  POST/GET /v1/worlds, DELETE /v1/worlds/{name}
 *   http_png.c    /v1/heights?format=png16
 *   http_guard.c  what one address may hold: heights bytes in flight, and the
 *                 deadline for a request's headers (slowloris)
 *   http_auth.c   who may read (a bearer token's role) and the TLS pair
 *                 libmicrohttpd serves HTTPS with
 */
#ifndef TERRAD_HTTP_INTERNAL_H
#define TERRAD_HTTP_INTERNAL_H

#include "http/http.h"
#include "world/world.h" /* png16_memory */

#include <microhttpd.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

/* ---- http_png.c ---- */
/* Heights → 16-bit greyscale PNG, value = clamp(h - offset, 0, 65535) with
 * offset = the rectangle's minimum, so the image inverts exactly whenever the
 * rectangle's range fits 16 bits (*clipped says whether it did). Returns 0,
 * or -1 with out->data freed. */
int http_png16_encode(const int32_t *heights, int w, int h, int32_t *offset, int *clipped,
                      png16_memory *out);

/* ---- http_guard.c ---- */
typedef struct http_guard http_guard;

/* A guard for one listener: heights answers may hold at most per_address
 * bytes for one client address and total bytes in all; a connection that has
 * not sent a whole request's headers header_deadline_s after it opened (or
 * after its previous request ended) is cut. Past max_per_address connections
 * from one address or max_conns in all (0: none), the oldest connection still
 * sending its headers is closed to make room. Starts its sweeper thread. */
http_guard *http_guard_start(size_t per_address, size_t total, unsigned header_deadline_s,
                             unsigned max_conns, unsigned max_per_address, int tls);
void http_guard_stop(http_guard *g); /* after MHD_stop_daemon */
/* MHD_OPTION_NOTIFY_CONNECTION (cls: the guard). */
void http_guard_notify(void *cls, struct MHD_Connection *c, void **socket_context,
                       enum MHD_ConnectionNotificationCode code);
/* The handler has seen the request's headers: no deadline until it ends.
 * 0: serve it; HTTP_GUARD_REFUSED_ADDRESS or _ALL: answer 503 with
 * Retry-After (it came past a connection limit with no room to make), never
 * act on it; -1: the connection was cut meanwhile (answered where it could
 * be): give up, never act on it. */
#define HTTP_GUARD_REFUSED_ADDRESS 1
#define HTTP_GUARD_REFUSED_ALL 2
int http_guard_headers_done(http_guard *g, struct MHD_Connection *c);
/* The connection limits it keeps (for the refusal's message). */
void http_guard_limits(const http_guard *g, unsigned *per_address, unsigned *all);
/* Reserve bytes of a heights answer for c's address until its request ends:
 * 0, or -1 (nothing reserved) when the address or everyone is over budget. */
int http_guard_reserve(http_guard *g, struct MHD_Connection *c, size_t bytes);
/* The request ended (sent, timed out, or the peer left): its bytes are
 * released, the next request's headers are awaited from now. */
void http_guard_request_done(http_guard *g, struct MHD_Connection *c);

/* ---- http_auth.c ---- */
/* The PEM texts libmicrohttpd's GnuTLS reads (it keeps pointers to them for
 * the daemon's life), and the option list that hands them over: empty (only
 * MHD_OPTION_END) without TLS. */
typedef struct http_tls {
    char *cert, *key;
    struct MHD_OptionItem options[3];
} http_tls;

/* Reads sec's files (already checked with tls_check_pair); sec NULL or without
 * files: no TLS. 0, or -1 with err naming the file. */
int http_tls_load(http_tls *t, const http_security *sec, error_text *err);
void http_tls_free(http_tls *t);
int http_tls_on(const http_tls *t);

/* The data endpoints' gate (url: /v1/world, /v1/stats, /v1/heights; any other
 * passes): with auth on, the request must carry
 * "Authorization: Bearer TOKEN" of a known token (any role). NULL when it
 * may go on, else a 401 response (JSON error, WWW-Authenticate) to queue;
 * the refusal is counted in terrad_auth_refused_total{reason="bad_token"}. */
struct MHD_Response *http_auth_refusal(struct MHD_Connection *c, const char *url, auth_table *auth);

/* 0 when the request's bearer token has at least role least (or auth is
 * off); else 401 (no known token) or 403 (a lesser role) with why naming
 * what it may not do, counted in terrad_auth_refused_total. */
unsigned http_role_refusal(struct MHD_Connection *c, auth_table *auth, auth_role least,
                           const char *what, char *why, size_t cap);

/* ---- the server (http.c) and its worlds (http_worlds.c) ---- */
typedef struct http_watch {
    char name[32];
    http_stalled_fn stalled_ms;
    const void *arg;
    double limit_ms;
} http_watch;

struct http_server {
    struct MHD_Daemon *daemon;
    http_status *status; /* readiness (/readyz): a node's, or a single daemon's default world's */
    /* GET /v1/twin: the world's twin config as JSON, or "!" and why there is
     * none (NULL: not set); set once (http_server_set_twin), freed at stop */
    _Atomic(char *) twin;
    http_limits limits;
    int port;
    pthread_mutex_t watch_lock; /* watches are added while MHD's threads serve */
    http_watch watches[HTTP_MAX_WATCHES];
    int nwatches;
    /* a cluster node (http_server_host_worlds): /v1/world, /v1/stats and
     * /v1/heights answer for the world ?world=NAME names */
    int hosts_worlds;
    pthread_mutex_t worlds_lock;
    pthread_cond_t worlds_cond; /* forward_calls ended */
    hub_worlds *worlds;         /* the daemon's one table of worlds (http_security.worlds) */
    auth_table *auth;           /* the data endpoints' gate (http_auth.c) */
    http_tls tls;
    http_server *main; /* a probe listener: the server whose status and watches it reports */
    http_guard *guard; /* heights bytes per address, the header deadline (http_guard.c) */
    /* a world ticked elsewhere (http_server_set_forward); under worlds_lock,
     * forward_calls: calls of forward running now */
    http_forward_fn forward;
    void *forward_ctx;
    int forward_calls;
    http_world_api world_api; /* a single daemon's lifecycle API (under worlds_lock) */
    http_drain_fn drain;      /* POST /v1/drain (under worlds_lock) */
    void *drain_ctx;
    char draining[256]; /* "" or why /readyz fails: the daemon drains (under worlds_lock) */
    /* GET /v1/websocket (http_server_set_websocket): ws_port 0 until the
     * websocket server is up; written once before ws_ready is set */
    int ws_port, ws_tls;
    char ws_public[HTTP_PUBLIC_URL_MAX];
    atomic_int ws_ready;
};

/* The world a request names (?world=NAME; without it, the default world),
 * counted as in use: NULL with the status to answer and why. */
hub_world *http_world_acquire(http_server *s, const char *name, unsigned *code, char *why,
                              size_t cap);
void http_world_release(http_server *s, hub_world *w);

/* Queues r (NULL: MHD_NO) with the headers every answer carries. */
enum MHD_Result http_queue(struct MHD_Connection *c, unsigned code, struct MHD_Response *r);

/* ---- the /v1 answers (http_views.c) ---- */
/* One answer, built before it is sent (or carried to another node). */
typedef struct http_answer {
    unsigned code;   /* 0: out of memory (nothing to send) */
    char type[64];   /* Content-Type */
    char extra[256]; /* further header lines, "Name: value\n" each */
    void *body;      /* malloc'd */
    size_t len;
} http_answer;
/* The query arguments: this request's (c), or packed "key\0value\0…" from another node. */
typedef struct http_args {
    struct MHD_Connection *c; /* NULL: packed; also whom a heights answer's bytes are held for */
    const char *packed;
    size_t len;
} http_args;
typedef enum http_view { HTTP_VIEW_WORLD, HTTP_VIEW_STATS, HTTP_VIEW_HEIGHTS } http_view;

/* s as the inside of a JSON string (quotes and control characters escaped;
 * bounded, long input is cut). */
void http_json_escape(const char *s, char *out, size_t cap);
void http_answer_error(http_answer *a, unsigned code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
void http_answer_free(http_answer *a);
/* Sends a (Cache-Control: no-store), which gives up its body. */
enum MHD_Result http_answer_queue(struct MHD_Connection *c, http_answer *a);
void http_view_stats(const http_status *st, http_answer *a);

/* http_world_api.c: the world lifecycle API. 1 when url is /v1/worlds or
 * /v1/worlds/{name} and the API is on, or /v1/drain and a drain is set. */
int http_world_api_path(http_server *s, const char *url);
/* "" or why the daemon drains (http_server_set_draining), copied into why. */
void http_draining(http_server *s, char *why, size_t cap);
/* The answer to method on url (body: a POST's). */
void http_world_api_answer(http_server *s, struct MHD_Connection *c, const char *url,
                           const char *method, const char *body, size_t len, http_answer *a);

/* http_edits.c: POST /v1/worlds/{name}/edits. */
#define HTTP_EDIT_MAX_BYTES (24 * 1024 * 1024) /* a stamp of max_edit_cells int32s, base64 */
/* 1 with {name} when url is an edits path. */
int http_edit_path(const char *url, char *name, size_t cap);
void http_edit_post(http_server *s, struct MHD_Connection *c, const char *name, const char *body,
                    size_t len, http_answer *a);
void http_view_world(const http_status *st, http_answer *a);
void http_view_heights(http_server *s, hub *from, const world *base, const http_args *args,
                       const http_status *st, http_answer *a);
/* A hosted world's view, from a snapshot of its status. */
void http_view_hosted(http_server *s, hub_world *w, http_view view, const http_args *args,
                      http_answer *a);
/* The request of a world this node does not serve, asked of its owner
 * through s->forward: 1 with *a to send (the owner's answer, or why there is
 * none), 0 when the world is not relayed here. */
int http_forward_request(http_server *s, struct MHD_Connection *c, const char *world,
                         http_view view, http_answer *a);

#endif
