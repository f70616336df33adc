/*
 * net.c: the websocket server's life (the top layer of net/, see
 * net_client_internal.h): its limits, the libwebsockets context, the net
 * thread's loop, and the stop. In a tick's terms: the net thread it starts
 * feeds the hub what the next tick takes (commands, poses, batch sequences,
 * net_callback.c) and, when the sim thread publishes a tick, wakes to send
 * its frames to the clients (net_loop.c, net_fanout.c).
 *
 * One libwebsockets context, one protocol callback ("terrad.v1"), one
 * thread. Outgoing data never comes from anywhere but a client's queue of
 * hub_frame references: the sim thread's frames (taken from the hub when its
 * waker cancels our poll wait), and our own replies.
 */
#include "net/net_requests_internal.h"
#include "net/net_server_internal.h"

#include <pthread.h>
#include <stdatomic.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

_Static_assert(HUB_FRAME_HEADROOM >= LWS_PRE, "hub frames need LWS_PRE bytes of headroom");

#define NET_STOP_GRACE_MS 800.0
#define NET_STOP_DEADLINE_MS 10000.0 /* then the thread is left behind, the process goes on */

/* ---- the service thread ---- */

static void *service_main(void *arg)
{
    net_server *s = arg;
    thread_owner_claim(&s->st.owner, "net");
    atomic_store(&s->last_beat_ms, time_now_ms());
    net_heartbeat_start(s);
    for (;;) {
        if (lws_service(s->ctx, 0) < 0)
            break;
        if (s->stopping && (atomic_load(&s->client_count) == 0 || atomic_load(&s->force_stop)))
            break;
    }
    lws_sul_cancel(&s->heartbeat);
    /* net_server_stop finishes on the caller's thread (lws_context_destroy
     * still calls back for every client left) */
    thread_owner_release(&s->st.owner);
    for (int i = 0; net_state_at(s, i); i++)
        if (net_state_at(s, i)->hub)
            hub_release_net_end(net_state_at(s, i)->hub);
    atomic_store(&s->thread_done, 1);
    return NULL;
}

static void server_free(net_server *s)
{
    if (!s)
        return;
    net_worlds_let_go(s); /* the table's entries its states were made for */
    net_state_release(&s->st);
    net_auth_stop(&s->st); /* after the worlds' states: they share its table */
    free(s->st.server_name);
    for (int i = 0; i < s->st.nworlds; i++) {
        if (s->st.worlds[i]->hub)
            hub_set_waker(s->st.worlds[i]->hub, NULL, NULL);
        net_world_state_free(s->st.worlds[i]);
    }
    free(s->st.worlds);
    for (int i = 0; i < s->nadding; i++)
        net_world_state_free(s->adding[i]);
    net_remote_drop_inbox(s);
    pthread_mutex_destroy(&s->wake_lock);
    pthread_mutex_destroy(&s->worlds_lock);
    pthread_cond_destroy(&s->worlds_cond);
    free(s);
}

static int limits_check(const net_limits *l, error_text *err)
{
    if (l->max_message_bytes < 1024 || l->max_colliders < 1 || l->max_poses_per_batch < 1 ||
        l->max_poses_per_batch > TERRAD_MAX_COUNT || l->max_subscriptions < 1 ||
        l->max_subscribed_cells < 1 || l->max_edit_cells < 1 || !(l->max_messages_per_s > 0) ||
        !(l->messages_burst >= 1) || l->max_mesh_vertices < 3 || l->max_mesh_triangles < 1 ||
        l->max_active_cells < 1 || l->max_spectators < 1 || !(l->max_collider_extent_m > 0) ||
        l->max_pending_bytes < 1024 || !(l->hello_timeout_s > 0) ||
        !isfinite(l->max_messages_per_s) || !isfinite(l->messages_burst) ||
        !isfinite(l->max_collider_extent_m) || !isfinite(l->hello_timeout_s)) {
        error_set(err, "net: a limit is out of range (each must be positive; "
                       "max_message_bytes and max_pending_bytes >= 1024)");
        return -1;
    }
    return 0;
}

net_server *net_server_start(const net_config *c, error_text *err)
{
    if (limits_check(&c->limits, err))
        return NULL;
    net_server *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "net: out of memory");
        return NULL;
    }
    pthread_mutex_init(&s->wake_lock, NULL);
    pthread_mutex_init(&s->worlds_lock, NULL);
    pthread_cond_init(&s->worlds_cond, NULL);
    s->st.cfg = *c; /* the lobby: every client's state until its hello names a world */
    s->st.cfg.world = (net_world_info){0};
    s->st.lobby = 1;
    s->st.server_name = strdup(c->server_name ? c->server_name : "terrad/0.1.0");
    s->st.cfg.tls_cert = s->st.cfg.tls_key = NULL; /* lws reads the files before start returns */
    s->st.cfg.server_name = s->st.server_name;
    s->st.next_client_id = 1;
    s->st.fd_ceiling = c->limits.fd_reserve > 0 ? net_fd_ceiling(c->limits.fd_reserve) : 0;
    s->st.next_collider_id = 1;
    s->st.poses = calloc((size_t)c->limits.max_poses_per_batch, sizeof *s->st.poses);
    s->st.models = net_parse_names(s->st.models_json, "[]", "world.models_json", err);
    s->st.materials = s->st.models ? net_parse_names(s->st.materials_json, "[\"default\"]",
                                                     "world.materials_json", err)
                                   : NULL;
    if (!s->st.models || !s->st.materials || !s->st.poses || !s->st.server_name ||
        net_auth_start(&s->st, err) != 0) {
        if (!s->st.poses || !s->st.server_name)
            error_set(err, "net: out of memory");
        server_free(s);
        return NULL;
    }
    const net_limits *l = &c->limits;
    s->st.hard_pending_bytes = 2 * l->max_pending_bytes + 4 * (size_t)l->max_subscribed_cells +
                               2 * l->max_message_bytes + 65536;

    lws_set_log_level(LLL_ERR, net_lws_log_line);
    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = c->port;
    info.iface = c->bind_any ? NULL : "127.0.0.1";
    info.protocols = net_protocols;
    info.gid = -1;
    info.uid = -1;
    info.user = s;
    info.options = c->bind_any ? 0 : LWS_SERVER_OPTION_DISABLE_IPV6;
    info.pt_serv_buf_size = 65536;
    if (c->tls_cert && c->tls_key) { /* wss:// only: a plain upgrade fails the TLS handshake */
        info.options |= LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT;
        info.ssl_cert_filepath = c->tls_cert;
        info.ssl_private_key_filepath = c->tls_key;
    }
    s->ctx = lws_create_context(&info);
    if (!s->ctx) {
        error_set(err, "net: cannot listen on %s port %d (in use, not allowed%s)",
                  c->bind_any ? "every address," : "127.0.0.1", c->port,
                  c->tls_cert ? ", or the TLS certificate and key refused" : "");
        server_free(s);
        return NULL;
    }
    struct lws_vhost *vh = lws_get_vhost_by_name(s->ctx, "default");
    s->port = vh ? lws_get_vhost_listen_port(vh) : c->port;
    s->ctx_live = 1;
    if (pthread_create(&s->thread, NULL, service_main, s) != 0) {
        error_set(err, "net: cannot start the service thread");
        lws_context_destroy(s->ctx);
        server_free(s);
        return NULL;
    }
    s->thread_started = 1;
    if (c->worlds) /* the worlds ticked here: the table wakes the net thread on a change */
        hub_worlds_watch(c->worlds, net_server_wake, s);
    log_info("net: websocket server listening on %s:%d (subprotocol %s)",
             c->bind_any ? "*" : "127.0.0.1", s->port, TERRAD_PROTO_SUBPROTOCOL);
    return s;
}

int net_server_port(const net_server *s)
{
    return s->port;
}

double net_server_stalled_ms(const net_server *s)
{
    double beat = atomic_load(&((net_server *)s)->last_beat_ms);
    return beat > 0 ? time_now_ms() - beat : 0;
}

int net_server_client_count(const net_server *s)
{
    return atomic_load(&((net_server *)s)->client_count);
}

void net_server_stop(net_server *s)
{
    if (!s)
        return;
    if (s->st.cfg.worlds)
        hub_worlds_watch(s->st.cfg.worlds, NULL, NULL);
    atomic_store(&s->stop_requested, 1);
    double start = time_now_ms();
    while (!atomic_load(&s->thread_done)) {
        net_server_wake(s);
        if (time_now_ms() - start > NET_STOP_GRACE_MS)
            atomic_store(&s->force_stop, 1);
        if (time_now_ms() - start > NET_STOP_DEADLINE_MS) {
            /* Wedged inside libwebsockets: its context cannot be destroyed
             * under it, so leave the thread and its memory to the exit. */
            log_error("net: the websocket thread did not stop within %.0f s: left behind",
                      NET_STOP_DEADLINE_MS / 1000);
            return;
        }
        struct timespec ts = {0, 5 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    pthread_join(s->thread, NULL);
    pthread_mutex_lock(&s->wake_lock);
    s->ctx_live = 0;
    pthread_mutex_unlock(&s->wake_lock);
    lws_context_destroy(s->ctx); /* closes what is left: CLOSED for each */
    net_flush_backlogs(s);
    if (s->st.backlog_count)
        log_warn("net: %d commands for the sim were still waiting at shutdown",
                 s->st.backlog_count);
    log_info("net: websocket server stopped");
    server_free(s);
}
