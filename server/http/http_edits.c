/*
 * http_edits.c: POST /v1/worlds/{name}/edits, terrain edits from a game
 * backend's HTTP client (issue 22; docs/openapi.yaml). The body is one edit,
 * the same JSON object as the websocket's `edit` message (hub_edit_parse),
 * and needs a driver or admin token where the server has tokens. The edit
 * joins the websocket clients' commands in the world's hub, in arrival
 * order; the HTTP thread waits (hub_edit_submit) for the tick that applies
 * it and answers with that tick and the exact volume change, or refuses it
 * naming the field. Nothing here touches the world: the sim thread applies
 * the edit at the start of a tick (service_edits.c).
 *
 * {name} is the world's: a cluster node's registered world that it ticks,
 * or on a single daemon its scene's name or a world created beside it
 * (POST /v1/worlds).
 */
#include <cjson/cJSON.h>
#include <microhttpd.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "http/http_internal.h"
#include "metrics/metrics.h"
#include "terrad_proto.h"

/* A tick is at most a few hundred ms even on a loaded machine; under --durability group:MS
 * (MS <= 10 s) the answer also waits for the sync that makes its tick durable. */
#define EDIT_WAIT_MS 30000

int http_edit_path(const char *url, char *name, size_t cap)
{
    static const char prefix[] = "/v1/worlds/", suffix[] = "/edits";
    size_t n = strlen(url), p = sizeof prefix - 1, q = sizeof suffix - 1;
    if (n <= p + q || strncmp(url, prefix, p) != 0 || strcmp(url + n - q, suffix) != 0 ||
        n - p - q >= cap)
        return 0;
    memcpy(name, url + p, n - p - q);
    name[n - p - q] = 0;
    return strchr(name, '/') == NULL;
}

static unsigned status_of(int code)
{
    switch (code) {
    case TERRAD_E_TOO_LARGE:
        return MHD_HTTP_CONTENT_TOO_LARGE;
    case TERRAD_E_REFUSED_HEIGHT_LIMIT:
        return MHD_HTTP_UNPROCESSABLE_CONTENT;
    case TERRAD_E_STORE_UNAVAILABLE:
    case TERRAD_E_SHUTTING_DOWN:
    case TERRAD_E_INTERNAL:
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    default:
        return MHD_HTTP_BAD_REQUEST;
    }
}

/* {"error": message, "name": the protocol's error name}. */
static void answer_refusal(http_answer *a, unsigned status, int code, const char *message)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "error", message);
    cJSON_AddStringToObject(o, "name", terrad_err_name(code));
    char *text = json_print_delete(o);
    if (!text)
        return;
    a->code = status;
    snprintf(a->type, sizeof a->type, "application/json");
    a->len = strlen(text);
    a->body = text;
}

/* Parse, submit and wait: the answer into a. */
static void edit_world(http_server *s, hub *h, const http_status *st, const char *body, size_t len,
                       http_answer *a)
{
    cJSON *msg = cJSON_ParseWithLength(body, len);
    if (!cJSON_IsObject(msg)) {
        cJSON_Delete(msg);
        answer_refusal(a, MHD_HTTP_BAD_REQUEST, TERRAD_E_BAD_JSON,
                       "body: not a JSON object (one edit, as the websocket's edit message)");
        return;
    }
    world_edit *e = malloc(sizeof *e);
    hub_edit_error werr = {0};
    int rc = e ? hub_edit_parse(msg, st->world_width, st->world_height, s->limits.edit_max_cells, e,
                                &werr)
               : -1;
    cJSON_Delete(msg);
    if (rc != 0) {
        if (!e)
            snprintf(werr.message, sizeof werr.message, "out of memory");
        free(e);
        answer_refusal(a, status_of(werr.code), werr.code ? werr.code : TERRAD_E_INTERNAL,
                       werr.message);
        return;
    }
    const char *op = world_edit_op_name(e->op);
    hub_edit_result res = {0};
    int waited = hub_edit_submit(h, e, &res, EDIT_WAIT_MS);
    if (waited != 0) {
        answer_refusal(
            a, waited < 0 ? MHD_HTTP_SERVICE_UNAVAILABLE : MHD_HTTP_GATEWAY_TIMEOUT,
            TERRAD_E_INTERNAL,
            waited < 0
                ? res.message
                : "edit: no tick took it (and made it durable) within 30 s; it is still queued and "
                  "will be applied or refused (watch /v1/stats)");
        return;
    }
    if (res.code != 0) {
        answer_refusal(a, status_of(res.code), res.code, res.message);
        return;
    }
    char *text = malloc(256);
    if (!text)
        return;
    snprintf(text, 256,
             "{\"op\":\"%s\",\"tick\":%llu,\"volume_change\":%lld,\"x\":%d,\"y\":%d,\"w\":%d,"
             "\"h\":%d}\n",
             op, (unsigned long long)res.tick, (long long)res.volume, res.rect.x, res.rect.y,
             res.rect.w, res.rect.h);
    a->code = MHD_HTTP_OK;
    snprintf(a->type, sizeof a->type, "application/json");
    a->len = strlen(text);
    a->body = text;
}

void http_edit_post(http_server *s, struct MHD_Connection *c, const char *name, const char *body,
                    size_t len, http_answer *a)
{
    char why[320];
    unsigned refused =
        http_role_refusal(c, s->auth, AUTH_DRIVER, "edit the terrain", why, sizeof why);
    if (refused) {
        answer_refusal(a, refused,
                       refused == MHD_HTTP_FORBIDDEN ? TERRAD_E_FORBIDDEN : TERRAD_E_UNAUTHORIZED,
                       why);
        return;
    }
    unsigned code = 0;
    hub_world *w = http_world_acquire(s, name, &code, why, sizeof why);
    if (!w) {
        char def[HUB_WORLD_NAME_MAX + 1] = "";
        if (s->worlds && hub_worlds_default(s->worlds, def, sizeof def))
            snprintf(why, sizeof why,
                     "name: no world \"%.64s\" on this daemon (its default world is \"%.64s\"; "
                     "GET /v1/worlds lists them)",
                     name, def);
        answer_refusal(a, MHD_HTTP_NOT_FOUND, TERRAD_E_BAD_VALUE, why);
        return;
    }
    http_status st, *from = w->status;
    pthread_mutex_lock(&from->lock);
    st = *from;
    pthread_mutex_unlock(&from->lock);
    edit_world(s, w->h, &st, body, len, a);
    http_world_release(s, w);
}
