/*
 * http: the daemon's HTTP side on libmicrohttpd — liveness and readiness
 * probes, Prometheus metrics, JSON views of the world, height reads and the
 * viewer's static files. It runs on libmicrohttpd's own threads and never
 * touches the GL context: it reads a status block the sim thread publishes
 * under a mutex once per tick, and asks the sim thread for heights through
 * the hub (served between ticks, so a read never sees half a tick).
 *
 * Endpoints (GET and HEAD only; anything else is 405 with an Allow header):
 *   /healthz          200 "ok" while the process serves and no watched thread
 *                     (http_server_watch: the tick, the net thread) has gone
 *                     without progress past its limit; else 503 naming it
 *   /readyz           200 "ready" once status.ready and not draining, else
 *                     503 naming why (Kubernetes' readiness: alive but not
 *                     ready while recovering or draining; /healthz stays 200)
 *   /metrics          Prometheus text 0.0.4 (metrics_render)
 *   /v1/world         JSON: extent, cell size, units per metre, tick, tile size,
 *                     models, renderer, backend
 *   /v1/twin          JSON: the world's parameters as the twin library's config
 *                     keys, for a predicting client (docs/engines.md)
 *   /v1/stats         JSON: tick, volume (exact integer), compacted (every model),
 *                     soil_compacted (bekker's part of it),
 *                     clients, colliders, last tick ms, overruns
 *   /v1/heights?x=&y=&w=&h=[&format=int32|png16][&base=1][&layer=compaction]
 *                     int32 little-endian row-major (default) or a 16-bit
 *                     greyscale PNG; headers X-Terrad-Tick, X-Terrad-Rect,
 *                     and for png16 X-Terrad-Offset, X-Terrad-Units-Per-Metre,
 *                     X-Terrad-Clipped; base=1: the scene's base terrain
 *                     (tick 0), read without the sim thread; layer=compaction:
 *                     the compaction memory instead of the heights (zeros
 *                     where none; docs/materials.md); tick=N: as of past tick
 *                     N, rebuilt from the data directory (store_replay_rect;
 *                     400 future, 404 no log, 410 compacted away)
 *   (cluster mode: /v1/world, /v1/stats and /v1/heights take ?world=NAME, and
 *   answer for a world another node ticks too: asked of its owner over NATS)
 *   /v1/websocket     JSON: where this daemon's websocket is, for the viewer and
 *                     other clients: {"url", "port", "subprotocol", "from"} —
 *                     --public-ws-url as given, else ws[s]://<the Host the
 *                     request named>:<the websocket port>/ (http_server_set_websocket)
 *   /v1/openapi.yaml  this API in OpenAPI 3 (docs/openapi.yaml, embedded)
 *   /, /<file>        the embedded web/ files ("/" is web/index.html)
 * Every error is JSON {"error": "..."}.
 *
 * With auth on (http_security.auth), /v1/world, /v1/stats and /v1/heights
 * need "Authorization: Bearer TOKEN" (any role), else 401; the probes,
 * /metrics, /v1/openapi.yaml and the viewer's files stay open. With a TLS
 * pair every endpoint is HTTPS only (libmicrohttpd's GnuTLS).
 */
#ifndef TERRAD_HTTP_H
#define TERRAD_HTTP_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "hub/hub.h"
#include "store/store.h"

/* What the sim thread publishes each tick. Fill the world fields before
 * http_server_start; the rest under `lock` as they change. */
typedef struct http_status {
    pthread_mutex_t lock;
    int ready;              /* GL context (or CPU backend) up and the world loaded */
    char not_ready[256];    /* with ready == 0: why ("" = still starting) */
    uint64_t tick;          /* last completed tick */
    int64_t volume;         /* Σh, exact */
    int64_t soil_compacted; /* bekker: Σ compacted (units); volume + this is constant */
    int64_t compacted;      /* every model: Σ compacted (soil state + compaction memory, units) */
    int world_width, world_height; /* cells; /v1/heights validates against them */
    double cell_size_m;
    int32_t units_per_m;
    int tile_size;  /* cells per tile side (deltas and fan-out) */
    double tick_hz; /* configured tick rate; 0 = not reported */
    int clients;    /* connected websocket clients */
    int colliders;  /* live colliders (client and demo) */
    char renderer[256];
    char backend[16];
    char backend_reason[320]; /* why this backend: `--backend auto`'s choice, or forced */
    char method[16];          /* the model, e.g. "persson-single"; /v1/world "models" */
    char metric[16];
    double last_tick_ms;
    uint64_t overruns;
    double published_ms; /* time_now_ms() of the last tick's publication (or of
                          * becoming ready, before the first); 0 = not yet */
    int waiting;      /* a client-clocked world waiting for its driver's next step: not stalled */
    int client_clock; /* its scene's "clock": "client" (GET /v1/worlds says "clock") */
    char world_name[65]; /* cluster mode: the world's registered name; "" for a single daemon */
    char scene_name[65]; /* the scene's name (GET /v1/worlds); the default world is named so */
    /* where /v1/heights?tick=N rebuilds past ticks from (store_history_rect):
     * the data directory, or a cluster node's JetStream reader
     * (cluster_history_make); empty: none (memory only). Set before the
     * world is on the ports; outlives it (host_sim_free releases it). */
    store_history history;
} http_status;

/* Limits against slow or hostile clients; a zero field takes the default. */
typedef struct http_limits {
    unsigned connections;         /* open connections in all (default 256) */
    unsigned connections_per_ip;  /* default 64 */
    unsigned timeout_s;           /* idle connection timeout (default 10) */
    size_t memory_per_connection; /* request headers and state (default 64 KiB) */
    int heights_timeout_ms;       /* wait for the sim thread, then 503 (default 2000) */
    int64_t heights_max_cells;    /* w*h per /v1/heights, else 413 (default 4,194,304) */
    /* /v1/heights answers held (built, not yet read) per client address and
     * in all, else 429 (defaults 64 MiB and 256 MiB) */
    size_t heights_bytes_per_address, heights_bytes_total;
    int64_t edit_max_cells; /* cells one POST /v1/worlds/{name}/edits may change (net's
                               max_edit_cells) */
} http_limits;

#define HTTP_DEFAULT_CONNECTIONS 256
#define HTTP_DEFAULT_CONNECTIONS_PER_IP 64
#define HTTP_DEFAULT_TIMEOUT_S 10
#define HTTP_DEFAULT_MEMORY_PER_CONNECTION (64 * 1024)
#define HTTP_DEFAULT_HEIGHTS_TIMEOUT_MS 2000
#define HTTP_DEFAULT_HEIGHTS_MAX_CELLS (4 * 1024 * 1024)
#define HTTP_DEFAULT_HEIGHTS_BYTES_PER_ADDRESS ((size_t)64 << 20)
#define HTTP_DEFAULT_HEIGHTS_BYTES_TOTAL ((size_t)256 << 20)
#define HTTP_MAX_QUERY_BYTES 1024

typedef struct http_server http_server;

/* Listen on 127.0.0.1 unless bind_any; port 0 picks a free one. status is
 * the server's readiness (/readyz; a single daemon's default world's) and
 * must outlive the server; the worlds it serves are in the table of worlds
 * (http_security.worlds; none: /v1/world, /v1/stats, /v1/heights are 503).
 * Uses the default limits. */
http_server *http_server_start(int port, int bind_any, http_status *status, error_text *err);
/* The same with explicit limits (NULL = defaults). */
http_server *http_server_start_limited(int port, int bind_any, http_status *status,
                                       const http_limits *limits, error_text *err);
/* Who may read, how the bytes travel and what is served; all fields optional. */
typedef struct http_security {
    auth_table *auth;               /* NULL or not enabled: no token needed; outlives the server */
    const char *tls_cert, *tls_key; /* both: HTTPS only (checked with tls_check_pair first) */
    /* the daemon's one table of worlds (below), outlives the server: given
     * here, before the first request, because the HTTP threads read it
     * unlocked from their start */
    hub_worlds *worlds;
} http_security;
/* The same with a token gate, TLS and the table of worlds (sec NULL: none). */
http_server *http_server_start_secure(int port, int bind_any, http_status *status,
                                      const http_limits *limits, const http_security *sec,
                                      error_text *err);
/* GET /v1/twin answers json (the world's parameters as the twin library's
 * config keys: scene_twin_config_json), or 404 with why when json is NULL.
 * Copied; call once. */
void http_server_set_twin(http_server *s, const char *json, const char *why);
int http_server_port(const http_server *s);
/* GET /v1/websocket answers with the websocket server's place: public_url
 * when given (checked by the caller: ws:// or wss://), else a URL built from
 * the Host header the client used and port (wss when tls). Before the call,
 * 503: the websocket server is not up yet. Copied; call once the port is known. */
#define HTTP_PUBLIC_URL_MAX 512
void http_server_set_websocket(http_server *s, int port, int tls, const char *public_url);
/* A second listener on 127.0.0.1:port (0 = any) for /healthz, /readyz and
 * /metrics only, with its own small connection budget, so that slow or idle
 * strangers on the main port cannot starve the probes. Stop it before main. */
http_server *http_probe_start(http_server *main, int port, error_text *err);

/* ---- the worlds served here (http_worlds.c; docs/cluster.md) ----
 * /v1/world, /v1/stats, /v1/heights (?world=NAME; without it the default
 * world: a single daemon's scene, a cluster node's first) and
 * /v1/worlds/NAME/edits read the daemon's one table of worlds (hub.h,
 * hub_worlds: each world's host adds it there once, for the HTTP and the
 * websocket port alike, with its status, hub and base terrain, which
 * /v1/heights?base=1 serves; http_security.worlds, so set before the port
 * serves). 404 names the
 * worlds served when NAME is not one of them; 503 while the default is
 * none. http_server_host_worlds: a cluster node (its 404s and 503s say so);
 * /readyz and /healthz stay the server's (status and the watches). */
void http_server_host_worlds(http_server *s);
/* Any node serves any world (http_views.c): a request for a world this node
 * does not serve goes, as bytes, to forward, which carries it to the world's
 * owner and returns 1 with the owner's answer bytes (*answer malloc'd), 0
 * when no world of that name is relayed here (404 as before), or -1 with the
 * status and why (503: no node ticks it now; 504: the owner did not answer).
 * The owner turns the request bytes into the answer bytes its own port would
 * send with http_server_answer (an answer longer than max_len becomes a 413
 * saying so): 0, or -1 out of memory. The request was checked (auth, limits)
 * by the node it came to. */
typedef int (*http_forward_fn)(void *ctx, const char *world, const void *request, size_t len,
                               void **answer, size_t *answer_len, unsigned *code, char *why,
                               size_t cap);
/* fn NULL: none any more; returns once no call of the old one runs. */
void http_server_set_forward(http_server *s, http_forward_fn fn, void *ctx);
int http_server_answer(http_server *s, const char *world, const void *request, size_t len,
                       size_t max_len, void **answer, size_t *answer_len);

/* ---- the world lifecycle API on a single daemon (http_world_api.c) ----
 * POST /v1/worlds (admin), GET /v1/worlds (any known token) and
 * DELETE /v1/worlds/{name}[?keep=1] (admin) call these on an HTTP thread;
 * each returns the HTTP status and sets *json to the answer's body
 * (malloc'd JSON; NULL: out of memory). The daemon adds each created world
 * to the table of worlds (http_security.worlds, without
 * http_server_host_worlds): /v1/world, /v1/stats and /v1/heights with
 * ?world=NAME and /v1/worlds/NAME/edits then reach it, while requests
 * naming no world (or the default scene's name) stay the default world's. */
typedef struct http_world_api {
    unsigned (*create)(void *ctx, const char *body, size_t len, char **json);
    unsigned (*list)(void *ctx, char **json);
    unsigned (*remove)(void *ctx, const char *name, int keep, char **json);
    void *ctx;
} http_world_api;
/* Before the port serves requests (api copied; NULL: none, /v1/worlds is 404). */
void http_server_set_world_api(http_server *s, const http_world_api *api);

/* ---- the drain (docs/fleet.md) ----
 * POST /v1/drain (admin role, no body) calls drain on an HTTP thread, which
 * starts the daemon's drain (the same as SIGTERM's) and answers as the world
 * API's calls do (202 and JSON). Set once before the port serves (NULL:
 * /v1/drain is 404). */
typedef unsigned (*http_drain_fn)(void *ctx, char **json);
void http_server_set_drain(http_server *s, http_drain_fn drain, void *ctx);
/* From now on /readyz answers 503 "not ready: draining: <why>" whatever the
 * status says (the probe port too); /healthz is untouched. Any thread. */
void http_server_set_draining(http_server *s, const char *why);

/* The watchdog behind /healthz: stalled_ms(arg) says how long the thread
 * `name` has gone without progress (any thread may call it); past limit_ms
 * /healthz answers 503 naming it. At most HTTP_MAX_WATCHES; -1 when full. */
#define HTTP_MAX_WATCHES 4
typedef double (*http_stalled_fn)(const void *arg);
int http_server_watch(http_server *s, const char *name, http_stalled_fn stalled_ms, const void *arg,
                      double limit_ms);
/* A stalled_ms for the tick: how long since status->published_ms (0 before it
 * is set, and while a client-clocked world waits for its driver). */
double http_status_stalled_ms(const void *status);
void http_server_stop(http_server *s); /* NULL is fine */

#endif
