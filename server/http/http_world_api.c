/*
 * http_world_api.c: the world lifecycle API on a single daemon (issue 22;
 * docs/openapi.yaml): POST /v1/worlds creates a world (admin role),
 * GET /v1/worlds lists them (any known token), DELETE /v1/worlds/{name}
 * ends one (admin; ?keep=1 keeps its storage). Only the routing, the role
 * and the answer's shape are here: the daemon (app/serve_worlds.c) does the
 * work through the callbacks it set, off any tick (each world ticks on the
 * daemon's pool of sim workers). A created world's reads and edits go through the
 * server's table of worlds (http_worlds.c) by ?world=NAME or
 * /v1/worlds/{name}/edits, beside the default world's.
 */
#include <microhttpd.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "http/http_internal.h"
#include "metrics/metrics.h"

#define PREFIX "/v1/worlds"
#define DRAIN_PATH "/v1/drain"

void http_server_set_world_api(http_server *s, const http_world_api *api)
{
    pthread_mutex_lock(&s->worlds_lock);
    s->world_api = api ? *api : (http_world_api){0};
    pthread_mutex_unlock(&s->worlds_lock);
}

void http_server_set_drain(http_server *s, http_drain_fn drain, void *ctx)
{
    pthread_mutex_lock(&s->worlds_lock);
    s->drain = drain;
    s->drain_ctx = ctx;
    pthread_mutex_unlock(&s->worlds_lock);
}

void http_server_set_draining(http_server *s, const char *why)
{
    pthread_mutex_lock(&s->worlds_lock);
    snprintf(s->draining, sizeof s->draining, "%s", why && why[0] ? why : "draining");
    pthread_mutex_unlock(&s->worlds_lock);
}

void http_draining(http_server *s, char *why, size_t cap)
{
    pthread_mutex_lock(&s->worlds_lock);
    snprintf(why, cap, "%s", s->draining);
    pthread_mutex_unlock(&s->worlds_lock);
}

static int drain_on(http_server *s)
{
    pthread_mutex_lock(&s->worlds_lock);
    int on = s->drain != NULL;
    pthread_mutex_unlock(&s->worlds_lock);
    return on;
}

static int api_on(http_server *s)
{
    pthread_mutex_lock(&s->worlds_lock);
    int on = s->world_api.create != NULL;
    pthread_mutex_unlock(&s->worlds_lock);
    return on;
}

int http_world_api_path(http_server *s, const char *url)
{
    if (strcmp(url, DRAIN_PATH) == 0)
        return drain_on(s);
    size_t p = sizeof PREFIX - 1;
    if (strncmp(url, PREFIX, p) != 0 || !api_on(s))
        return 0;
    return url[p] == 0 || (url[p] == '/' && url[p + 1] && !strchr(url + p + 1, '/'));
}

static void answer_json(http_answer *a, unsigned code, char *json)
{
    if (!json)
        return; /* code 0: out of memory */
    a->code = code;
    snprintf(a->type, sizeof a->type, "application/json");
    a->body = json;
    a->len = strlen(json);
}

/* POST /v1/drain: admin, no body; the daemon's drain answers. */
static void drain_answer(http_server *s, struct MHD_Connection *c, const char *method, size_t len,
                         http_answer *a)
{
    if (strcmp(method, "POST") != 0) {
        http_answer_error(a, MHD_HTTP_METHOD_NOT_ALLOWED, "method %.16s not allowed here; use POST",
                          method);
        snprintf(a->extra, sizeof a->extra, "Allow: POST\n");
        return;
    }
    char why[200];
    unsigned refused = http_role_refusal(c, s->auth, AUTH_ADMIN, "drain", why, sizeof why);
    if (refused) {
        http_answer_error(a, refused, "%s", why);
        return;
    }
    if (len > 0) {
        http_answer_error(a, MHD_HTTP_BAD_REQUEST, "body: POST /v1/drain takes no body");
        metrics_count_http_bad_request();
        return;
    }
    pthread_mutex_lock(&s->worlds_lock);
    http_drain_fn drain = s->drain;
    void *ctx = s->drain_ctx;
    pthread_mutex_unlock(&s->worlds_lock);
    char *json = NULL;
    unsigned code = drain(ctx, &json);
    answer_json(a, code, json);
}

void http_world_api_answer(http_server *s, struct MHD_Connection *c, const char *url,
                           const char *method, const char *body, size_t len, http_answer *a)
{
    if (strcmp(url, DRAIN_PATH) == 0) {
        drain_answer(s, c, method, len, a);
        return;
    }
    pthread_mutex_lock(&s->worlds_lock);
    http_world_api api = s->world_api; /* set once before the port opens; copied for the lock */
    pthread_mutex_unlock(&s->worlds_lock);
    const char *name = url[sizeof PREFIX - 1] == '/' ? url + sizeof PREFIX : NULL;
    int post = strcmp(method, "POST") == 0, del = strcmp(method, "DELETE") == 0;
    int get = strcmp(method, "GET") == 0 || strcmp(method, "HEAD") == 0;
    if (name ? !del : !(post || get)) {
        http_answer_error(a, MHD_HTTP_METHOD_NOT_ALLOWED, "method %.16s not allowed here; use %s",
                          method, name ? "DELETE" : "GET or POST");
        snprintf(a->extra, sizeof a->extra, "Allow: %s\n", name ? "DELETE" : "GET, HEAD, POST");
        return;
    }
    char why[200];
    unsigned refused =
        http_role_refusal(c, s->auth, get ? AUTH_VIEWER : AUTH_ADMIN,
                          get ? "list worlds" : "create or delete worlds", why, sizeof why);
    if (refused) {
        http_answer_error(a, refused, "%s", why);
        return;
    }
    char *json = NULL;
    unsigned code;
    if (get) {
        code = api.list(api.ctx, &json);
    } else if (post) {
        code = api.create(api.ctx, body, len, &json);
    } else {
        const char *keep = MHD_lookup_connection_value(c, MHD_GET_ARGUMENT_KIND, "keep");
        code = api.remove(api.ctx, name, keep && strcmp(keep, "0") != 0, &json);
    }
    answer_json(a, code, json);
}
