/*
 * net_loop.c: what the net thread does between callbacks (its layers are
 * listed in net_client_internal.h): on a wake (LWS_CALLBACK_EVENT_WAIT_CANCELLED,
 * net_catch_up) and on each heartbeat (every 100 ms) it adopts and detaches
 * worlds (net_worlds.c), takes the other nodes' messages (net_remote.c),
 * retries the commands waiting for the sims and drains the hubs' frames
 * (net_fanout.c). In a tick's terms: the tick's frames go out here once the
 * sim thread has published them (step 9), and the commands a later tick takes
 * (step 1) are retried here. The heartbeat also reaps dead peers, re-checks
 * roles after an auth reload, and starts the shutdown once it is asked for.
 */
#include "net/net_requests_internal.h"
#include "net/net_server_internal.h"

#include <stdatomic.h>

#include "terrad_proto.h"

#define NET_HEARTBEAT_US 100000 /* backlog retries, shutdown checks */

void net_drain_hubs(net_server *s)
{
    int more = 0;
    for (int i = 0; net_state_at(s, i); i++)
        more |= net_drain_state(net_state_at(s, i));
    if (more)
        lws_cancel_service(s->ctx); /* more to come: serve the sockets, then carry on */
}

/* The backlogs of commands for the sims, retried in order. */
void net_flush_backlogs(net_server *s)
{
    for (int i = 0; net_state_at(s, i); i++)
        net_flush_backlog(net_state_at(s, i));
}

/* ---- shutdown ---- */

static void begin_shutdown(net_server *s)
{
    s->stopping = 1;
    for (int k = 0; net_state_at(s, k); k++) {
        net_state *w = net_state_at(s, k);
        for (int i = 0; i < w->nclients; i++) {
            net_client *c = w->clients[i];
            if (c->killed || c->closing)
                continue;
            net_error(c, TERRAD_E_SHUTTING_DOWN, NULL, -1, 1, "server shutting down");
            net_close_after_flush(c, LWS_CLOSE_STATUS_GOINGAWAY, "server shutting down");
        }
    }
}

static void heartbeat(lws_sorted_usec_list_t *sul)
{
    net_server *s = lws_container_of(sul, net_server, heartbeat);
    fault_stall("net"); /* test hook (base/fault.c): a net thread that stops */
    atomic_store(&s->last_beat_ms, time_now_ms());
    net_drain_apply(s);
    net_worlds_apply(s);
    net_events_apply(s);
    net_remote_apply(s);
    for (int i = 0; net_state_at(s, i); i++) {
        net_reap_dead_peers(net_state_at(s, i));
        net_auth_recheck(net_state_at(s, i));
        net_budget_flush_state(net_state_at(s, i)); /* a window emptied between ticks */
        net_spectate_pump(net_state_at(s, i));
    }
    net_flush_backlogs(s);
    if (atomic_load(&s->stop_requested) && !s->stopping) {
        net_drain_hubs(s);
        begin_shutdown(s);
    }
    lws_sul_schedule(s->ctx, 0, &s->heartbeat, heartbeat, NET_HEARTBEAT_US);
}

void net_heartbeat_start(net_server *s)
{
    lws_sul_schedule(s->ctx, 0, &s->heartbeat, heartbeat, NET_HEARTBEAT_US);
}

void net_catch_up(net_server *s)
{
    atomic_store(&s->wake_pending, 0); /* before taking: a later wake cancels again */
    net_drain_apply(s); /* a drain's notice before a world's removal closes its clients */
    net_worlds_apply(s);
    net_events_apply(s);
    net_remote_apply(s);
    net_flush_backlogs(s);
    net_drain_hubs(s); /* the last tick's frames go out before the goodbye */
    for (int i = 0; net_state_at(s, i); i++)
        net_spectate_pump(net_state_at(s, i)); /* the replay threads' frames, the live tick */
    if (atomic_load(&s->stop_requested) && !s->stopping)
        begin_shutdown(s);
}
