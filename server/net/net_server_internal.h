/*
 * net_server_internal.h: the top layer of the net thread (see
 * net_client_internal.h) — the server itself: libwebsockets' context, the
 * thread, and the world states it keeps for the table of worlds and the
 * relayed worlds (net_worlds.c). Shared by
 * the files of net/ that need the server itself (its layers are listed in
 * net_client_internal.h).
 */
#ifndef TERRAD_NET_SERVER_INTERNAL_H
#define TERRAD_NET_SERVER_INTERNAL_H

#include <pthread.h>
#include <stdatomic.h>

#include "net/net_client_internal.h"

#define NET_MAX_WORLDS 512 /* worlds ticked here (256 at most) and relayed ones */
#define NET_EVENTS_MAX 256 /* events waiting for the net thread (net_events.c) */

struct net_event {
    int bit;        /* its index in NET_EVENT_NAMES */
    char world[65]; /* the world it is about */
    char state[16]; /* world_state: its lifecycle state ("" for the others) */
};

/* The net thread's state and libwebsockets' context. */
struct net_server {
    net_state st; /* the lobby: where a client waits until its hello names a world */
    struct lws_context *ctx;
    lws_sorted_usec_list_t heartbeat;
    atomic_int thread_done;
    pthread_t thread;
    int thread_started;
    int port;
    atomic_int stop_requested;
    atomic_int force_stop;
    atomic_int client_count;     /* read by any thread */
    _Atomic double last_beat_ms; /* the heartbeat's last run: the watchdog's clue */
    pthread_mutex_t wake_lock;
    int ctx_live;
    /* a wake is on its way: set by net_server_wake before it cancels the
     * poll, cleared by the net thread before it catches up (net_catch_up), so
     * the sims' wakes while it is behind cost one cancel, not one each */
    atomic_int wake_pending;
    int stopping;
    /* relayed worlds coming and going (any thread → the net thread), under
     * worlds_lock; the worlds ticked here come and go in st.cfg.worlds */
    pthread_mutex_t worlds_lock;
    pthread_cond_t worlds_cond;
    net_state *adding[NET_MAX_WORLDS];
    int nadding;
    struct net_removal {
        char name[65]; /* a relayed world's name */
    } removing[NET_MAX_WORLDS];
    int nremoving;
    unsigned table_seen; /* cfg.worlds' generation when the net thread last looked */
    /* messages from other nodes (net_server_remote_input), under worlds_lock */
    struct net_remote_item *inbox;
    int ninbox;
    int64_t inbox_cap;
    /* events for subscribed admins (net_server_event), under worlds_lock */
    struct net_event events[NET_EVENTS_MAX];
    int nevents;
};

typedef struct net_session {
    net_client *c;
} net_session;

/* Wakes the net thread (the hubs' waker, net_fanout.c). Any thread. */
void net_server_wake(void *arg);
/* Net thread: one batch of rounds of w's hub items dispatched; 1 when the hub has more. */
int net_drain_state(net_state *w);
/* Net thread (net_loop.c): every state's hub drained, a wake asked for when more is left. */
void net_drain_hubs(net_server *s);
/* Net thread: the backlogs of commands for the sims, retried in order. */
void net_flush_backlogs(net_server *s);
/* Net thread: a wake's work (worlds, inbox, backlogs, frames, the shutdown's start). */
void net_catch_up(net_server *s);
void net_events_apply(net_server *s);
/* Net thread: once draining, every client told (net_server_drain). */
void net_drain_apply(net_server *s);
/* Schedules the heartbeat (every 100 ms on the net thread). */
void net_heartbeat_start(net_server *s);
/* The protocol table (net_callback.c). */
extern const struct lws_protocols net_protocols[];
/* A JSON array of strings, or the fallback when text is NULL; NULL with err. */
cJSON *net_parse_names(const char *text, const char *fallback, const char *what, error_text *err);
/* A world's base_json as an object, or NULL (none, not an object, no memory). */
cJSON *net_parse_base(const char *json);
/* The i-th state: 0 the server's own, then the worlds; NULL past the last. */
net_state *net_state_at(net_server *s, int i);
/* Net thread: adopt the worlds added (to the table, or relayed) and detach the
 * ones removed since the last call. */
void net_worlds_apply(net_server *s);
/* Net thread: hand the frames waiting in w's hub to w's clients. */
void net_drain_world(net_server *s, net_state *w);
/* Net thread: one item from the sim (or from the owner, on a relay) to w's clients. */
void net_dispatch(net_state *w, hub_out *o);
/* Net thread, once a tick: w's clients too far behind (max_client_lag_ticks,
 * by their queue or by what they said handled) go slow (net_fanout.c). */
void net_drop_stale(net_state *w);
/* Net thread: frees a client record (its socket is gone, or it was a remote client; net_peer.c). */
void net_client_free(net_server *s, net_client *c);
/* Net thread: the messages from other nodes, and the remote clients closed since. */
void net_remote_apply(net_server *s);
/* Frees the inbox's messages unread (the server stops). */
void net_remote_drop_inbox(net_server *s);
/* A state for the world named name (world info copied, strings duplicated);
 * NULL with err. */
net_state *net_world_state_new(net_server *s, const char *name, const net_world_info *info, hub *h,
                               error_text *err);
/* Queues w for the net thread to adopt; -1 with err when the table is full. */
int net_world_queue_add(net_server *s, net_state *w, error_text *err);
/* Asks the net thread to detach the relayed world named name and waits. */
int net_world_queue_remove(net_server *s, const char *name);
/* The entries of the table held for the states left at the stop let go. */
void net_worlds_let_go(net_server *s);
/* Frees what a state holds but the shared token and server name (not w itself). */
void net_state_release(net_state *w);
/* limits.max_client_lag_ticks left at 0: two seconds of the world's ticks. */
void net_default_lag(net_state *w);
/* Frees a world's state (not the shared token and server name). */
void net_world_state_free(net_state *w);

#endif
