/*
 * net_remote.c: any node serves any world (docs/cluster.md). Two roles, both
 * on the net thread, fed by net_server_remote_input (any thread: NATS
 * delivers there) through an inbox under the server's worlds_lock:
 *
 *   RELAY (a world another node owns): a client's hello naming it moves the
 *   client into the relay's state; every later message of the client goes to
 *   the owner as it came (net_relay_forward, net_remote_send.c). What the owner sends the client
 *   (NET_REMOTE_FRAME: replies, snapshots, ACK, CONTACT...) and every tile
 *   delta of the world (NET_REMOTE_DELTA, sent once per tick for all relays)
 *   go through net_dispatch exactly as a local world's hub items do: the same
 *   frames, the same fan-out by subscription, the same slow-client rules
 *   (the lag rule, net_drop_stale, once per tick of the owner's: relay_in). The
 *   relay learns the client's subscriptions from the owner's "subscribed" and
 *   "unsubscribed" replies, and asks the owner for a resync when the client
 *   falls behind.
 *
 *   OWNER: a relayed client is a REMOTE client here — a client record with
 *   no socket, checked, limited and applied like any other (its colliders,
 *   budgets, subscriptions and the sim's snapshots are the owner's); its
 *   frames go back to its relay (net_remote_frame, net_remote_send.c) and it gets no tile
 *   deltas of its own (its relay fans out the world's).
 */
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "net/net_requests_internal.h"
#include "net/net_server_internal.h"
#include "terrad_proto.h"

#define NET_INBOX_MAX 65536 /* items waiting for the net thread; beyond, dropped */

struct net_remote_item {
    char world[65];
    net_remote_msg m;
    unsigned char *bytes; /* len bytes and a NUL */
    size_t len;
};

void net_server_set_remote(net_server *s, const char *node, net_remote_send_fn send, void *ctx)
{
    s->st.remote_send = send;
    s->st.remote_ctx = ctx;
    snprintf(s->st.node, sizeof s->st.node, "%s", node);
}

int net_server_add_relay(net_server *s, const net_world_info *info, error_text *err)
{
    if (!s->st.remote_send) {
        error_set(err, "net: a relay needs net_server_set_remote first");
        return -1;
    }
    net_state *w = net_world_state_new(s, info->name, info, NULL, err);
    if (!w)
        return -1;
    w->relay = 1;
    return net_world_queue_add(s, w, err);
}

int net_server_remove_relay(net_server *s, const char *world)
{
    return net_world_queue_remove(s, world);
}

void net_server_remote_input(net_server *s, const char *world, const net_remote_msg *m,
                             const void *bytes, size_t len)
{
    unsigned char *copy = malloc(len + 1);
    if (!copy) {
        metrics_count_frames_dropped(1);
        return;
    }
    if (len)
        memcpy(copy, bytes, len);
    copy[len] = 0;
    pthread_mutex_lock(&s->worlds_lock);
    int ok = s->ninbox < NET_INBOX_MAX && array_grow((void **)&s->inbox, &s->inbox_cap,
                                                     (int64_t)s->ninbox + 1, sizeof *s->inbox) == 0;
    if (ok) {
        struct net_remote_item *it = &s->inbox[s->ninbox++];
        snprintf(it->world, sizeof it->world, "%s", world);
        it->m = *m;
        it->bytes = copy;
        it->len = len;
    }
    pthread_mutex_unlock(&s->worlds_lock);
    if (!ok) {
        free(copy);
        metrics_count_frames_dropped(1);
        return;
    }
    net_server_wake(s);
}

/* ---- the relay's side ---- */

/* The owner's replies that change what the relay fans out to the client. */
static void relay_track(net_client *c, const unsigned char *text, size_t len)
{
    cJSON *msg = cJSON_ParseWithLength((const char *)text, len);
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(msg, "type");
    const cJSON *id = cJSON_GetObjectItemCaseSensitive(msg, "id");
    if (!cJSON_IsString(type) || !cJSON_IsNumber(id)) {
        cJSON_Delete(msg);
        return;
    }
    uint32_t sid = (uint32_t)id->valuedouble;
    if (strcmp(type->valuestring, "subscribed") == 0 &&
        array_grow((void **)&c->subs, &c->sub_capacity, (int64_t)c->sub_count + 1,
                   sizeof *c->subs) == 0) {
        const char *k[4] = {"x", "y", "w", "h"};
        int v[4] = {0};
        for (int i = 0; i < 4; i++) {
            const cJSON *n = cJSON_GetObjectItemCaseSensitive(msg, k[i]);
            v[i] = cJSON_IsNumber(n) ? (int)n->valuedouble : 0;
        }
        c->subs[c->sub_count++] = (net_sub){sid, {v[0], v[1], v[2], v[3]}};
        c->snapshots_requested++; /* the owner ends the subscription's snapshot with a mark */
    } else if (strcmp(type->valuestring, "spectating") == 0) {
        c->relay_spectating = 1;
    } else if (strcmp(type->valuestring, "spectate_end") == 0) {
        c->relay_spectating = 0;
    } else if (strcmp(type->valuestring, "unsubscribed") == 0) {
        for (int i = 0; i < c->sub_count; i++)
            if (c->subs[i].id == sid) {
                c->subs[i] = c->subs[--c->sub_count];
                break;
            }
    }
    cJSON_Delete(msg);
}

static void relay_in(net_state *w, const struct net_remote_item *it)
{
    const net_remote_msg *m = &it->m;
    hub_out o = {.tick = m->tick};
    /* The owner's next tick begins: its last one is all here (one publisher's
     * order), and the owner sends relays no TICK_DONE; the relay holds the
     * client's socket, so it judges its lag, once a tick, as the owner would. */
    if (m->tick > w->tick && w->tick > 0)
        net_drop_stale(w);
    if (m->kind == NET_REMOTE_DELTA && m->tile_x == 0xffff) { /* deltas were lost on the way */
        for (int i = 0; i < w->nclients; i++)
            if (w->clients[i]->ready && !w->clients[i]->closing)
                net_request_resync(w->clients[i], 0);
        return;
    }
    if (m->kind == NET_REMOTE_DELTA) {
        o.kind = HUB_OUT_TILE_DELTA;
        o.tile_x = m->tile_x;
        o.tile_y = m->tile_y;
    } else if (m->kind == NET_REMOTE_CLOSE && m->client == 0) { /* a new owner: start again */
        for (int i = 0; i < w->nclients; i++) {
            net_client *c = w->clients[i];
            if (c->closing || c->killed)
                continue;
            net_error(c, TERRAD_E_SHUTTING_DOWN, NULL, -1, 1,
                      "world %s has a new owner (%s): connect again", w->world_name,
                      (const char *)it->bytes);
            net_close_after_flush(c, LWS_CLOSE_STATUS_GOINGAWAY, "world moved");
        }
        return;
    } else {
        net_client *c = strcmp(m->node, w->node) == 0 ? net_find_client(w, m->client) : NULL;
        if (!c)
            return;
        if (m->kind == NET_REMOTE_CLOSE) {
            net_close_after_flush(c, m->close_code, (const char *)it->bytes);
            return;
        }
        if (m->kind != NET_REMOTE_FRAME)
            return;
        if (!m->binary)
            relay_track(c, it->bytes, it->len);
        o.kind = HUB_OUT_CLIENT;
        o.client = c->id;
        o.snapshot_done = m->snapshot_done;
        /* the relay has only the owner's wire bytes: the type is their third byte */
        o.msg = m->binary && it->len > 2 ? it->bytes[2] : 0;
    }
    if (it->len) {
        o.frame = hub_frame_new(m->binary, it->len);
        if (!o.frame) {
            metrics_count_frames_dropped(1);
            return;
        }
        memcpy(o.frame->data, it->bytes, it->len);
    }
    net_dispatch(w, &o);
}

/* ---- the owner's side ---- */

static net_client *remote_client(net_server *s, net_state *w, const net_remote_msg *m)
{
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (c->remote && c->remote_client == m->client && strcmp(c->remote_node, m->node) == 0)
            return c;
    }
    if (m->kind != NET_REMOTE_CLIENT_TEXT) /* a client starts with its hello */
        return NULL;
    net_client *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->id = s->st.next_client_id++;
    c->srv = w;
    c->remote = 1;
    c->remote_client = m->client;
    snprintf(c->remote_node, sizeof c->remote_node, "%s", m->node);
    c->next_sub_id = 1;
    c->tokens = w->cfg.limits.messages_burst;
    c->refill_ms = time_now_ms();
    snprintf(c->peer, sizeof c->peer, "node %.40s", m->node);
    snprintf(c->name, sizeof c->name, "?");
    if (net_client_add(w, c) != 0) {
        free(c);
        return NULL;
    }
    log_info("net: client %u of node %s (its client %u) joins world %s", c->id, m->node, m->client,
             w->world_name);
    return c;
}

static void owner_in(net_server *s, net_state *w, const struct net_remote_item *it)
{
    net_client *c = remote_client(s, w, &it->m);
    if (!c || c->remote_gone)
        return;
    switch (it->m.kind) {
    case NET_REMOTE_CLIENT_TEXT:
        net_handle_text(c, (const char *)it->bytes, it->len);
        break;
    case NET_REMOTE_CLIENT_BINARY:
        net_handle_binary(c, it->bytes, it->len);
        break;
    case NET_REMOTE_CLIENT_GONE:
        log_info("net: client %u of node %s left world %s", c->id, c->remote_node, w->world_name);
        c->closing = 1;
        c->remote_gone = 1;
        break;
    default:
        break;
    }
}

static net_state *find_world(net_server *s, const char *name)
{
    for (int i = 0; i < s->st.nworlds; i++)
        if (strcmp(s->st.worlds[i]->world_name, name) == 0)
            return s->st.worlds[i];
    return NULL;
}

void net_remote_apply(net_server *s)
{
    pthread_mutex_lock(&s->worlds_lock);
    struct net_remote_item *items = s->inbox;
    int n = s->ninbox;
    s->inbox = NULL;
    s->ninbox = 0;
    s->inbox_cap = 0;
    pthread_mutex_unlock(&s->worlds_lock);
    for (int i = 0; i < n; i++) {
        net_state *w = find_world(s, items[i].world);
        if (w && w->relay)
            relay_in(w, &items[i]);
        else if (w)
            owner_in(s, w, &items[i]);
        free(items[i].bytes);
    }
    free(items);
    for (int k = 0; k < s->st.nworlds; k++) {
        net_state *w = s->st.worlds[k];
        for (int i = 0; i < w->nclients; i++)
            if (w->clients[i]->remote && w->clients[i]->remote_gone)
                net_client_free(s, w->clients[i--]);
    }
}

void net_remote_drop_inbox(net_server *s)
{
    for (int i = 0; i < s->ninbox; i++)
        free(s->inbox[i].bytes);
    free(s->inbox);
    s->inbox = NULL;
    s->ninbox = 0;
}
