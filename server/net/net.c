/*
 * net.c: the websocket thread (the top layer of net/, see net_client_internal.h): the
 * libwebsockets context, the protocol callback, writes, and the fan-out of
 * the sim thread's frames. In a tick's terms: it feeds the hub what the
 * next tick takes (commands, poses, batch sequences) and, when the sim
 * thread publishes a tick, wakes to send its frames to the clients.
 *
 * One libwebsockets context, one protocol callback ("terrad.v1"), one
 * thread. Everything a connection owns (its reassembly buffer, its token
 * bucket, its colliders and subscriptions, its outgoing queue) lives in a
 * net_client that only this thread touches, so there are no locks here
 * beyond the hub's own.
 *
 * Outgoing data never comes from anywhere but a client's queue of hub_frame
 * references: the sim thread's frames (taken from the hub when its waker
 * cancels our poll wait), and our own replies. A queue is written one frame
 * per SERVER_WRITEABLE callback. Its size is bounded three ways:
 *
 *   - tile deltas stop for a client whose pending bytes would pass
 *     max_pending_bytes ("slow"): its queued deltas are dropped, and once
 *     the queue has drained to half the limit it is sent fresh snapshots
 *     (a HUB_RESYNC); deltas resume after the last snapshot frame;
 *   - CONTACT, ACK and COLLIDERS frames of a slow client replace their older copies
 *     (each one says everything the older said, for a later tick);
 *   - FOOTPRINTS frames are dropped like tile deltas (and not sent at all to
 *     a slow client): events for visuals, nothing to resync;
 *   - anything beyond hard_pending_bytes (room for max_pending_bytes, a
 *     whole snapshot of the largest allowed subscription area and a few
 *     messages) closes the connection: such a client has stopped reading
 *     and keeps asking for more.
 *
 * Incoming messages are reassembled up to max_message_bytes, rate limited by
 * a token bucket (net_client.c), and handed to net_requests.c.
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

#define NET_DRAIN_BATCH 256     /* hub items taken per call */
#define NET_DRAIN_ROUNDS 64     /* batches per wake before serving sockets again */
#define NET_HEARTBEAT_US 100000 /* backlog retries, shutdown checks */
#define NET_STOP_GRACE_MS 800.0
#define NET_STOP_DEADLINE_MS 10000.0 /* then the thread is left behind, the process goes on */

net_limits net_limits_default(void)
{
    return (net_limits){
        .max_message_bytes = 1048576,
        .max_colliders = 64,
        .max_poses_per_batch = 64,
        .max_subscriptions = 16,
        .max_subscribed_cells = 4194304,
        .max_messages_per_s = 240,
        .messages_burst = 480,
        .max_mesh_vertices = 16384,
        .max_mesh_triangles = 32768,
        .max_active_cells = 262144,
        .max_collider_extent_m = 50,
        .max_pending_bytes = 8388608,
        .hello_timeout_s = 5,
        .max_connections = 0, /* 0: derived from RLIMIT_NOFILE by the caller, or none */
        .max_connections_per_address = 256,
        .fd_reserve = 64,
    };
}

/* ---- frames from the sim ---- */

static int dropping_deltas(const net_client *c)
{
    return c->slow || c->snapshots_done < c->resync_until;
}

/* behind: 0 when the client's queue is over max_pending_bytes, else how many
 * ticks old its oldest queued delta is (past max_client_lag_ticks) */
static void go_slow(net_client *c, uint64_t behind)
{
    if (!c->slow && behind) {
        log_info("net: client %u (%s) is stale (%llu ticks behind, limit %d): deltas replaced "
                 "by a snapshot once it catches up",
                 c->id, c->peer, (unsigned long long)behind,
                 c->srv->cfg.limits.max_client_lag_ticks);
        metrics_count_client_stale();
    } else if (!c->slow) /* before the drop, so the figure is what made it slow */
        log_info("net: client %u (%s) is slow (%zu bytes pending, limit %zu): deltas replaced "
                 "by a snapshot once it catches up",
                 c->id, c->peer, c->pending_bytes, c->srv->cfg.limits.max_pending_bytes);
    int n = net_drop_tile_deltas(c);
    metrics_count_frames_coalesced((uint64_t)n + 1);
    c->slow = 1;
    lws_callback_on_writable(c->wsi);
}

static int sub_meets(const net_client *c, world_rect tile)
{
    for (int i = 0; i < c->sub_count; i++)
        if (world_rects_overlap(c->subs[i].rect, tile))
            return 1;
    return 0;
}

static void fan_out(net_state *w, const hub_out *o)
{
    int ts = w->cfg.world.tile_size;
    world_rect tile = {o->tile_x * ts, o->tile_y * ts, ts, ts};
    if (tile.x + tile.w > w->cfg.world.width)
        tile.w = w->cfg.world.width - tile.x;
    if (tile.y + tile.h > w->cfg.world.height)
        tile.h = w->cfg.world.height - tile.y;
    if (tile.w <= 0 || tile.h <= 0 || tile.x < 0 || tile.y < 0)
        return;
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (!c->ready || c->closing || c->killed || c->remote || !sub_meets(c, tile))
            continue; /* a remote client gets the delta from its relay */
        if (dropping_deltas(c)) {
            metrics_count_frames_coalesced(1);
            continue;
        }
        if (c->droppable_bytes + o->frame->len > w->cfg.limits.max_pending_bytes) {
            go_slow(c, 0);
            continue;
        }
        hub_frame_ref(o->frame);
        net_enqueue(c, o->frame, NET_ITEM_TILE);
    }
}

/* Staleness, once a tick: a client whose oldest queued delta or status frame
 * is more than max_client_lag_ticks old goes slow like one over
 * max_pending_bytes (its deltas dropped, snapshots once it drains), so that
 * a client reading steadily but too slowly is bounded in ticks, not only in
 * bytes (issue 15: one frame per 20 ms was 54 s behind after 60 s). */
static void drop_stale(net_state *w)
{
    uint64_t limit = (uint64_t)w->cfg.limits.max_client_lag_ticks;
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (!c->ready || c->closing || c->killed || c->remote || dropping_deltas(c))
            continue; /* a remote client's lag is its relay's to bound */
        uint64_t oldest = net_oldest_queued_tick(c);
        if (oldest && w->tick > oldest + limit)
            go_slow(c, w->tick - oldest);
    }
}

static int is_footprints(const hub_frame *f)
{
    return f->binary && f->len > 2 && f->data[2] == TERRAD_MSG_FOOTPRINTS;
}

/* FOOTPRINTS are events for visuals, droppable like tile deltas: not sent to a
 * client whose deltas are being dropped or whose queue would pass
 * max_pending_bytes (no resync follows: a missed event is simply not drawn),
 * and queued as NET_ITEM_TILE so that going slow drops those still queued. */
static void send_footprints(net_client *c, hub_frame *f)
{
    if (dropping_deltas(c) || c->droppable_bytes + f->len > c->srv->cfg.limits.max_pending_bytes) {
        metrics_count_footprints_dropped(1);
        hub_frame_unref(f);
        return;
    }
    uint64_t events =
        f->len >= TERRAD_FOOTPRINTS_FIXED ? (uint64_t)f->data[12] | (uint64_t)f->data[13] << 8 : 0;
    metrics_count_footprints_sent(1, events);
    net_enqueue(c, f, NET_ITEM_TILE);
}

void net_dispatch(net_state *w, hub_out *o)
{
    if (o->tick > w->tick)
        w->tick = o->tick;
    switch (o->kind) {
    case HUB_OUT_CLIENT: {
        net_client *c = net_find_client(w, o->client);
        if (c && c->remote) { /* its relay decides what to drop, as for its own clients */
            if (!c->remote_gone && (o->frame || o->snapshot_done))
                net_remote_frame(c, o->frame, o->snapshot_done);
        } else if (c && o->frame && is_footprints(o->frame)) {
            send_footprints(c, o->frame);
            o->frame = NULL;
        } else if (c && o->frame) {
            int status =
                o->frame->binary && o->frame->len > 2 &&
                (o->frame->data[2] == TERRAD_MSG_CONTACT || o->frame->data[2] == TERRAD_MSG_ACK ||
                 o->frame->data[2] == TERRAD_MSG_COLLIDERS ||
                 o->frame->data[2] == TERRAD_MSG_FORCES);
            if (status && dropping_deltas(c)) {
                /* An ACK of tick t promises that tick t's deltas came first: while
                 * deltas are dropped for a resync, the tick's ACK, CONTACT and FORCES
                 * go too. */
                metrics_count_frames_coalesced(1);
            } else {
                net_enqueue(c, o->frame, status ? NET_ITEM_STATUS : NET_ITEM_REPLY);
                o->frame = NULL;
            }
        }
        if (c && o->snapshot_done && c->snapshots_done < c->snapshots_requested)
            c->snapshots_done++;
        break;
    }
    case HUB_OUT_TILE_DELTA:
        if (o->frame)
            fan_out(w, o);
        if (o->frame && w->remote_send && !w->relay) { /* once, for every relay */
            net_remote_msg m = {.kind = NET_REMOTE_DELTA,
                                .binary = o->frame->binary,
                                .tile_x = o->tile_x,
                                .tile_y = o->tile_y,
                                .tick = o->tick};
            w->remote_send(w->remote_ctx, w->world_name, &m, o->frame->data, o->frame->len);
        }
        break;
    case HUB_OUT_TICK_DONE:
        drop_stale(w);
        break;
    }
    if (o->frame)
        hub_frame_unref(o->frame);
}

/* Every client must start over from snapshots: the hub dropped frames. */
static void resync_everyone(net_state *w)
{
    log_warn("net: the outbound queue overflowed: every client gets fresh snapshots");
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (!c->ready || c->sub_count == 0)
            continue;
        /* markers may have been lost with the dropped frames: forget them */
        c->snapshots_done = c->snapshots_requested;
        c->resync_until = c->snapshots_done;
        go_slow(c, 0);
    }
}

/* 1 when w's hub has more to take (it was taken in whole batches). */
static int drain_state(net_state *w)
{
    if (!w->hub)
        return 0;
    if (hub_take_overflow(w->hub))
        resync_everyone(w);
    hub_out items[NET_DRAIN_BATCH];
    for (int round = 0; round < NET_DRAIN_ROUNDS; round++) {
        int n = hub_take_outbound(w->hub, items, NET_DRAIN_BATCH);
        for (int i = 0; i < n; i++)
            net_dispatch(w, &items[i]);
        if (n < NET_DRAIN_BATCH)
            return 0;
    }
    return 1;
}

void net_drain_world(net_server *s, net_state *w)
{
    if (drain_state(w))
        lws_cancel_service(s->ctx);
}

static void drain_hub(net_server *s)
{
    int more = 0;
    for (int i = 0; net_state_at(s, i); i++)
        more |= drain_state(net_state_at(s, i));
    if (more)
        lws_cancel_service(s->ctx); /* more to come: serve the sockets, then carry on */
}

/* The backlogs of commands for the sims, retried in order. */
static void flush_backlogs(net_server *s)
{
    for (int i = 0; net_state_at(s, i); i++)
        net_flush_backlog(net_state_at(s, i));
}

void net_server_wake(void *arg)
{
    net_server *s = arg;
    pthread_mutex_lock(&s->wake_lock);
    if (s->ctx_live)
        lws_cancel_service(s->ctx);
    pthread_mutex_unlock(&s->wake_lock);
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
    net_worlds_apply(s);
    net_remote_apply(s);
    for (int i = 0; net_state_at(s, i); i++) {
        net_reap_dead_peers(net_state_at(s, i));
        net_auth_recheck(net_state_at(s, i));
    }
    flush_backlogs(s);
    if (atomic_load(&s->stop_requested) && !s->stopping) {
        drain_hub(s);
        begin_shutdown(s);
    }
    lws_sul_schedule(s->ctx, 0, &s->heartbeat, heartbeat, NET_HEARTBEAT_US);
}

/* ---- the protocol callback ---- */

static void client_established(net_server *s, struct lws *wsi, net_session *pss)
{
    net_client *c = calloc(1, sizeof *c);
    if (c)
        c->id = s->st.next_client_id++; /* before the add: the list is sorted by id */
    if (!c || net_client_add(&s->st, c) != 0) {
        free(c);
        log_error("net: out of memory for a new client");
        lws_set_timeout(wsi, PENDING_TIMEOUT_USER_OK, LWS_TO_KILL_ASYNC);
        return;
    }
    c->wsi = wsi;
    c->srv = &s->st;
    c->next_sub_id = 1;
    c->tokens = s->st.cfg.limits.messages_burst;
    c->refill_ms = time_now_ms();
    lws_get_peer_simple(wsi, c->peer, sizeof c->peer);
    snprintf(c->name, sizeof c->name, "?");
    pss->c = c;
    metrics_set_clients(atomic_fetch_add(&s->client_count, 1) + 1);
    log_info("net: client %u connected from %s", c->id, c->peer);
    lws_set_timer_usecs(wsi, (lws_usec_t)(s->st.cfg.limits.hello_timeout_s * 1e6));
}

void net_client_free(net_server *s, net_client *c)
{
    net_state *w = c->srv; /* the lobby, or the world it said hello to */
    for (int i = 0; i < c->collider_count; i++) {
        hub_forget_pose(w->hub, c->colliders[i]);
        net_collider_remove(w, c->colliders[i]);
    }
    if (c->ready && w->relay) { /* the owner drops its remote client */
        net_remote_msg m = {.kind = NET_REMOTE_CLIENT_GONE, .client = c->id};
        snprintf(m.node, sizeof m.node, "%s", w->node);
        w->remote_send(w->remote_ctx, w->world_name, &m, NULL, 0);
    } else if (c->ready) {
        hub_command cmd = {.kind = HUB_CLIENT_LEFT, .client = c->id};
        net_push_must(w, &cmd); /* the sim deletes its colliders */
    }
    net_release_queue(c);
    net_client_remove(w, c);
    free(c->q);
    free(c->rx);
    free(c->colliders);
    free(c->subs);
    if (!c->remote)
        metrics_set_clients(atomic_fetch_sub(&s->client_count, 1) - 1);
    free(c);
}

static void client_closed(net_server *s, net_session *pss)
{
    net_client *c = pss->c;
    if (!c)
        return;
    pss->c = NULL;
    net_log_disconnect(c);
    net_client_free(s, c);
}

static int client_receive(net_server *s, struct lws *wsi, net_client *c, const void *in, size_t len)
{
    const net_limits *l = &s->st.cfg.limits;
    if (!c->rx_active) {
        c->rx_active = 1;
        c->rx_len = c->rx_total = 0;
        c->rx_oversize = 0;
        c->rx_binary = lws_frame_is_binary(wsi);
    }
    c->rx_total += len;
    if (c->rx_total > 4 * l->max_message_bytes) {
        metrics_count_bytes_in(c->rx_total);
        metrics_count_refused(TERRAD_E_TOO_LARGE);
        log_warn("net: client %u (%s) sent a message over 4 x max_message_bytes: closing", c->id,
                 c->peer);
        static const char reason[] = "message too big";
        c->closing = 1; /* for the disconnect log line */
        c->close_code = LWS_CLOSE_STATUS_MESSAGE_TOO_LARGE;
        snprintf(c->close_reason, sizeof c->close_reason, "%s", reason);
        lws_close_reason(wsi, LWS_CLOSE_STATUS_MESSAGE_TOO_LARGE, (unsigned char *)reason,
                         sizeof reason - 1);
        return -1;
    }
    if (!c->rx_oversize) {
        if (c->rx_len + len > l->max_message_bytes) {
            c->rx_oversize = 1;
            c->rx_len = 0;
            if (c->rx_cap > 65536) { /* do not keep a big buffer for nothing */
                free(c->rx);
                c->rx = NULL;
                c->rx_cap = 0;
            }
        } else {
            if (array_grow((void **)&c->rx, &c->rx_cap, (int64_t)(c->rx_len + len + 1), 1) != 0) {
                log_error("net: out of memory reassembling a message of client %u", c->id);
                return -1;
            }
            if (len)
                memcpy(c->rx + c->rx_len, in, len);
            c->rx_len += len;
        }
    }
    if (!lws_is_final_fragment(wsi) || lws_remaining_packet_payload(wsi) > 0)
        return 0;

    /* one whole message */
    c->rx_active = 0;
    metrics_count_bytes_in(c->rx_total);
    metrics_count_messages_in(1);
    if (c->closing || c->killed)
        return 0;
    if (!net_rate_allow(c))
        return 0;
    if (c->rx_oversize) {
        net_error(c, TERRAD_E_TOO_LARGE, NULL, -1, 0,
                  "message of %zu bytes is over max_message_bytes (%zu): dropped", c->rx_total,
                  l->max_message_bytes);
    } else if (c->rx_binary) {
        net_handle_binary(c, c->rx, c->rx_len);
    } else {
        c->rx[c->rx_len] = 0;
        net_handle_text(c, (const char *)c->rx, c->rx_len);
    }
    if (c->rx_cap > 65536) {
        free(c->rx);
        c->rx = NULL;
        c->rx_cap = 0;
    }
    return 0;
}

static int client_writeable(net_server *s, struct lws *wsi, net_client *c)
{
    if (c->killed)
        return -1;
    net_rx_hold_update(c); /* lws has flushed what it held: read again */
    if (c->slow && c->pending_bytes <= s->st.cfg.limits.max_pending_bytes / 2 && !c->closing) {
        c->slow = 0;
        net_request_resync(c, 0); /* caught up: fresh snapshots, then deltas again */
    }
    if (c->q_count) {
        net_item it = c->q[c->q_head];
        c->q_head = (c->q_head + 1) % c->q_cap;
        c->q_count--;
        c->pending_bytes -= it.frame->len;
        if (it.kind != NET_ITEM_REPLY)
            c->droppable_bytes -= it.frame->len;
        int n = lws_write(wsi, it.frame->data, it.frame->len,
                          it.frame->binary ? LWS_WRITE_BINARY : LWS_WRITE_TEXT);
        if (n >= 0) {
            metrics_count_bytes_out(it.frame->len);
            metrics_count_frames_out(1);
        }
        hub_frame_unref(it.frame);
        if (n < 0)
            return -1;
        net_rx_hold_update(c); /* the kernel took only part of it: stop reading (net_peer.c) */
        if (c->q_count) {
            lws_callback_on_writable(wsi);
            return 0;
        }
    }
    if (c->closing) {
        size_t n = strlen(c->close_reason);
        lws_close_reason(wsi, (enum lws_close_status)c->close_code,
                         (unsigned char *)c->close_reason, n);
        return -1;
    }
    return 0;
}

static int net_callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in,
                        size_t len)
{
    net_session *pss = user;
    struct lws_context *ctx = lws_get_context(wsi);
    net_server *s = ctx ? lws_context_user(ctx) : NULL;
    if (!s)
        return 0;
    THREAD_OWNED(&s->st.owner);

    switch (reason) {
    case LWS_CALLBACK_FILTER_NETWORK_CONNECTION:
        return s->stopping || !net_admit_connection(&s->st, (int)(intptr_t)in);
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION: {
        if (s->stopping)
            return 1;
        char offered[256] = "";
        if (lws_hdr_total_length(wsi, WSI_TOKEN_PROTOCOL) <= 0 ||
            lws_hdr_copy(wsi, offered, sizeof offered, WSI_TOKEN_PROTOCOL) <= 0 ||
            !net_offers_subprotocol(offered, TERRAD_PROTO_SUBPROTOCOL)) {
            char peer[64] = "";
            lws_get_peer_simple(wsi, peer, sizeof peer);
            log_info("net: refused a handshake from %s without subprotocol %s", peer,
                     TERRAD_PROTO_SUBPROTOCOL);
            lws_return_http_status(wsi, HTTP_STATUS_BAD_REQUEST,
                                   "the websocket subprotocol terrad.v1 is required");
            return 1;
        }
        return 0;
    }
    case LWS_CALLBACK_ESTABLISHED:
        pss->c = NULL;
        client_established(s, wsi, pss);
        return 0;
    case LWS_CALLBACK_WS_PEER_INITIATED_CLOSE:
        if (pss->c)
            net_client_peer_close(pss->c, in, len);
        return 0; /* lws echoes the close */
    case LWS_CALLBACK_CLOSED:
        client_closed(s, pss);
        return 0;
    case LWS_CALLBACK_TIMER:
        if (pss->c && !pss->c->ready && !pss->c->closing) {
            net_error(pss->c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1, "no hello within %g s",
                      s->st.cfg.limits.hello_timeout_s);
            net_close_after_flush(pss->c, 4000 + TERRAD_E_UNAUTHORIZED, "no hello");
        }
        return 0;
    case LWS_CALLBACK_RECEIVE:
        if (!pss->c)
            return -1;
        return client_receive(s, wsi, pss->c, in, len);
    case LWS_CALLBACK_SERVER_WRITEABLE:
        if (!pss->c)
            return 0;
        return client_writeable(s, wsi, pss->c);
    case LWS_CALLBACK_EVENT_WAIT_CANCELLED:
        net_worlds_apply(s);
        net_remote_apply(s);
        flush_backlogs(s);
        drain_hub(s); /* the last tick's frames go out before the goodbye */
        if (atomic_load(&s->stop_requested) && !s->stopping)
            begin_shutdown(s);
        return 0;
    default:
        return 0;
    }
}

static const struct lws_protocols net_protocols[] = {
    {TERRAD_PROTO_SUBPROTOCOL, net_callback, sizeof(net_session), 65536, 0, NULL, 0},
    {NULL, NULL, 0, 0, 0, NULL, 0},
};

/* ---- the service thread ---- */

static void *service_main(void *arg)
{
    net_server *s = arg;
    thread_owner_claim(&s->st.owner, "net");
    atomic_store(&s->last_beat_ms, time_now_ms());
    if (s->st.hub)
        hub_claim_net_end(s->st.hub);
    lws_sul_schedule(s->ctx, 0, &s->heartbeat, heartbeat, NET_HEARTBEAT_US);
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

static char *dup_or_null(const char *text)
{
    return text ? strdup(text) : NULL;
}

/* A JSON array of strings, or a default when text is NULL. */
static void server_free(net_server *s)
{
    if (!s)
        return;
    net_state_release(&s->st);
    net_auth_stop(&s->st); /* after the worlds' states: they share its table */
    free(s->st.token);
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
        l->max_subscribed_cells < 1 || !(l->max_messages_per_s > 0) || !(l->messages_burst >= 1) ||
        l->max_mesh_vertices < 3 || l->max_mesh_triangles < 1 || l->max_active_cells < 1 ||
        !(l->max_collider_extent_m > 0) || l->max_pending_bytes < 1024 ||
        !(l->hello_timeout_s > 0) || !isfinite(l->max_messages_per_s) ||
        !isfinite(l->messages_burst) || !isfinite(l->max_collider_extent_m) ||
        !isfinite(l->hello_timeout_s)) {
        error_set(err, "net: a limit is out of range (each must be positive; "
                       "max_message_bytes and max_pending_bytes >= 1024)");
        return -1;
    }
    return 0;
}

net_server *net_server_start(const net_config *c, hub *h, error_text *err)
{
    if (limits_check(&c->limits, err))
        return NULL;
    if (h && (c->world.width < 1 || c->world.height < 1 || c->world.tile_size < 1 ||
              !(c->world.cell_size_m > 0))) {
        error_set(err, "net: the world info is incomplete (extent, cell size, tile size)");
        return NULL;
    }
    net_server *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "net: out of memory");
        return NULL;
    }
    pthread_mutex_init(&s->wake_lock, NULL);
    pthread_mutex_init(&s->worlds_lock, NULL);
    pthread_cond_init(&s->worlds_cond, NULL);
    s->st.cfg = *c;
    s->st.hub = h;
    s->st.lobby = h == NULL;
    s->st.token = dup_or_null(c->token && c->token[0] ? c->token : NULL);
    s->st.models_json = dup_or_null(c->world.models_json);
    s->st.materials_json = dup_or_null(c->world.materials_json);
    s->st.server_name = strdup(c->server_name ? c->server_name : "terrad/0.1.0");
    s->st.cfg.token = s->st.token;
    s->st.cfg.tls_cert = s->st.cfg.tls_key = NULL; /* lws reads the files before start returns */
    s->st.cfg.world.models_json = s->st.models_json;
    s->st.cfg.world.materials_json = s->st.materials_json;
    s->st.cfg.server_name = s->st.server_name;
    s->st.world_name = dup_or_null(c->world.name);
    s->st.cfg.world.name = s->st.world_name;
    s->st.next_client_id = 1;
    if (!s->st.lobby) /* a node's worlds each take theirs (net_world_state_new) */
        net_default_lag(&s->st);
    s->st.fd_ceiling = c->limits.fd_reserve > 0 ? net_fd_ceiling(c->limits.fd_reserve) : 0;
    s->st.next_collider_id = 1;
    s->st.poses = calloc((size_t)c->limits.max_poses_per_batch, sizeof *s->st.poses);
    s->st.models = net_parse_names(s->st.models_json, "[]", "world.models_json", err);
    s->st.materials = s->st.models ? net_parse_names(s->st.materials_json, "[\"default\"]",
                                                     "world.materials_json", err)
                                   : NULL;
    if (!s->st.models || !s->st.materials || !s->st.poses || !s->st.server_name ||
        (c->world.name && !s->st.world_name) || net_auth_start(&s->st, err) != 0) {
        if (!s->st.poses || !s->st.server_name || (c->world.name && !s->st.world_name))
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
    if (h)
        hub_set_waker(h, net_server_wake, s);
    if (pthread_create(&s->thread, NULL, service_main, s) != 0) {
        error_set(err, "net: cannot start the service thread");
        if (h)
            hub_set_waker(h, NULL, NULL);
        lws_context_destroy(s->ctx);
        server_free(s);
        return NULL;
    }
    s->thread_started = 1;
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
    if (s->st.hub)
        hub_set_waker(s->st.hub, NULL, NULL);
    pthread_mutex_lock(&s->wake_lock);
    s->ctx_live = 0;
    pthread_mutex_unlock(&s->wake_lock);
    lws_context_destroy(s->ctx); /* closes what is left: CLOSED for each */
    flush_backlogs(s);
    if (s->st.backlog_count)
        log_warn("net: %d commands for the sim were still waiting at shutdown",
                 s->st.backlog_count);
    log_info("net: websocket server stopped");
    server_free(s);
}
