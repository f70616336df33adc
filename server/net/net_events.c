/*
 * net_events.c: events for the admin connections that asked for them with
 * subscribe_events (proto/PROTOCOL.md "Events"; issue 22): world_created,
 * world_deleted and world_state (a world's lifecycle, docs/fleet.md). Whoever learns of one calls
 * net_server_event from any thread — a single daemon's POST and DELETE /v1/worlds
 * (app/serve_worlds.c), a cluster node seeing its registry listing change (app/serve_node.c, so
 * every node of a cluster tells its own admins) — which queues it under the
 * server's worlds_lock and wakes the net thread; the net thread sends each
 * one between two callbacks (net_events_apply, from net_catch_up) to every
 * ready client, in any world's state, that subscribed to it. Events take no
 * part in a tick. The drain's notice (net_server_drain, net_drain_apply)
 * travels the same way: set from any thread, sent by the net thread to
 * every client once.
 */
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>

#include "metrics/metrics.h"
#include "net/net_control_internal.h"
#include "net/net_server_internal.h"

static void queue_event(net_server *s, const char *event, const char *world, const char *state)
{
    static const char *const names[] = {NET_EVENT_NAMES};
    int bit = -1;
    for (int k = 0; k < NET_EVENT_COUNT; k++)
        if (strcmp(event, names[k]) == 0)
            bit = k;
    if (!s || bit < 0)
        return;
    pthread_mutex_lock(&s->worlds_lock);
    if (s->nevents < NET_EVENTS_MAX) {
        struct net_event *e = &s->events[s->nevents++];
        e->bit = bit;
        snprintf(e->world, sizeof e->world, "%s", world);
        snprintf(e->state, sizeof e->state, "%s", state);
    } else {
        metrics_count_frames_dropped(1); /* 256 waiting: the net thread is stuck anyway */
    }
    pthread_mutex_unlock(&s->worlds_lock);
    net_server_wake(s);
}

void net_server_event(net_server *s, const char *event, const char *world)
{
    queue_event(s, event, world, "");
}

void net_server_world_state(net_server *s, const char *world, const char *state)
{
    queue_event(s, "world_state", world, state);
}

static void send_event(net_state *w, const struct net_event *e)
{
    int bit = e->bit;
    static const char *const names[] = {NET_EVENT_NAMES};
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (!c->ready || c->closing || c->killed || c->remote || !(c->events & (1u << bit)))
            continue;
        cJSON *msg = cJSON_CreateObject();
        cJSON_AddStringToObject(msg, "type", "event");
        cJSON_AddStringToObject(msg, "event", names[bit]);
        cJSON_AddStringToObject(msg, "world", e->world);
        if (e->state[0])
            cJSON_AddStringToObject(msg, "state", e->state);
        net_send_json(c, msg);
    }
}

void net_events_apply(net_server *s)
{
    struct net_event events[NET_EVENTS_MAX];
    pthread_mutex_lock(&s->worlds_lock);
    int n = s->nevents;
    memcpy(events, s->events, (size_t)n * sizeof *events);
    s->nevents = 0;
    pthread_mutex_unlock(&s->worlds_lock);
    for (int e = 0; e < n; e++)
        for (int i = 0; net_state_at(s, i); i++)
            send_event(net_state_at(s, i), &events[e]);
}

/* ---- the drain (docs/fleet.md) ---- */

void net_server_drain(net_server *s, const char *why, int64_t grace_ms)
{
    int idle = 0;
    if (!s || !atomic_compare_exchange_strong(&s->st.draining, &idle, 2))
        return; /* draining already: the first reason stands */
    snprintf(s->st.drain_why, sizeof s->st.drain_why, "%s", why && why[0] ? why : "draining");
    s->st.drain_grace_ms = grace_ms;
    atomic_store(&s->st.draining, 1); /* why and grace are written first */
    net_server_wake(s);
}

const char *net_draining(const net_state *st)
{
    return atomic_load(&((net_state *)st)->draining) == 1 ? st->drain_why : NULL;
}

void net_drain_apply(net_server *s)
{
    if (s->st.drain_told || !net_draining(&s->st))
        return;
    s->st.drain_told = 1;
    int told = 0;
    for (int k = 0; net_state_at(s, k); k++) {
        net_state *w = net_state_at(s, k);
        for (int i = 0; i < w->nclients; i++) {
            net_client *c = w->clients[i];
            if (!c->ready || c->closing || c->killed)
                continue;
            cJSON *msg = cJSON_CreateObject();
            cJSON_AddStringToObject(msg, "type", "draining");
            cJSON_AddStringToObject(msg, "reason", s->st.drain_why);
            cJSON_AddNumberToObject(msg, "grace_ms", (double)s->st.drain_grace_ms);
            net_send_json(c, msg);
            told++;
        }
    }
    log_info("net: draining (%s): %d clients told, new clients refused", s->st.drain_why, told);
}
