/*
 * net_peer.c: dead peers (the net_client layer, see net_client_internal.h).
 * A peer that closes its end, or dies, while libwebsockets still holds part
 * of a frame for it must be closed at once, whatever its backlog; in a
 * tick's terms this runs in the net thread's heartbeat, between ticks' fan-outs.
 *
 * Why: libwebsockets 4.1 meets such an EOF by deferring the close until its
 * buffered output drains (LRS_FLUSHING_BEFORE_CLOSE). A peer whose window is
 * shut never drains it, and lws's service loop retries the same readable
 * socket without polling again: recv() = 0 forever, the whole net thread
 * spinning inside one lws_service call (issue 15, item 1). So lws must never
 * see the EOF while it holds output: once a write leaves part of a frame in
 * lws (lws_partial_buffered), reading from that client is paused
 * (lws_rx_flow_control, which takes POLLIN out of the poll set) until lws has
 * flushed it, and meanwhile the heartbeat asks the kernel itself whether the
 * peer has hung up (POLLRDHUP). Such a peer is killed: lws's timeout close
 * is a violent one (no flush), and a zero linger drops the unsent bytes with a
 * reset instead of leaving them to the kernel.
 */
#include "net/net_server_internal.h"

#include <poll.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <sys/socket.h>

#include "metrics/metrics.h"

void net_rx_hold_update(net_client *c)
{
    if (c->killed)
        return;
    int buffered = lws_partial_buffered(c->wsi) != 0;
    if (buffered == c->rx_held)
        return;
    c->rx_held = buffered;
    lws_rx_flow_control(c->wsi, buffered ? 0 : 1);
    if (buffered) /* a writeable callback once lws has flushed: reading resumes there */
        lws_callback_on_writable(c->wsi);
}

/* 1 if the kernel says the peer has closed its end or the connection failed. */
static int peer_hung_up(struct lws *wsi)
{
    int fd = (int)lws_get_socket_fd(wsi);
    if (fd < 0)
        return 0;
    struct pollfd p = {.fd = fd, .events = POLLRDHUP};
    if (poll(&p, 1, 0) != 1)
        return 0;
    return (p.revents & (POLLRDHUP | POLLHUP | POLLERR)) != 0;
}

int net_reap_dead_peers(net_state *s)
{
    THREAD_OWNED(&s->owner);
    int reaped = 0;
    for (int i = 0; i < s->nclients; i++) {
        net_client *c = s->clients[i];
        if (c->killed || !c->rx_held || !peer_hung_up(c->wsi))
            continue;
        int fd = (int)lws_get_socket_fd(c->wsi);
        struct linger zero = {.l_onoff = 1, .l_linger = 0};
        if (fd >= 0)
            setsockopt(fd, SOL_SOCKET, SO_LINGER, &zero, sizeof zero);
        char why[128];
        snprintf(why, sizeof why, "the peer hung up with %zu bytes still queued for it",
                 c->pending_bytes);
        net_client_kill(c, why);
        reaped++;
    }
    return reaped;
}

/* Who closed, with which code and reason: the client's close frame, else
 * the one net_close_after_flush sent, else none at all. */
void net_log_disconnect(const net_client *c)
{
    const char *sep = c->ready ? ", " : "", *name = c->ready ? c->name : "";
    if (c->peer_close_code)
        log_info("net: client %u (%s%s%s) disconnected: the client closed with code %d (\"%s\")",
                 c->id, c->peer, sep, name, c->peer_close_code, c->peer_close_reason);
    else if (c->closing)
        log_info("net: client %u (%s%s%s) disconnected: the server closed with code %d (\"%s\")",
                 c->id, c->peer, sep, name, c->close_code, c->close_reason);
    else
        log_info("net: client %u (%s%s%s) disconnected: connection lost, no close frame", c->id,
                 c->peer, sep, name);
}

/* The client's close frame (2-byte code, then a reason): kept for the log,
 * any byte outside printable ASCII written as '?'. */
void net_client_peer_close(net_client *c, const unsigned char *in, size_t len)
{
    c->peer_close_code = len >= 2 ? (in[0] << 8 | in[1]) : LWS_CLOSE_STATUS_NO_STATUS;
    size_t n = len > 2 ? len - 2 : 0;
    if (n > sizeof c->peer_close_reason - 1)
        n = sizeof c->peer_close_reason - 1;
    for (size_t i = 0; i < n; i++)
        c->peer_close_reason[i] = in[2 + i] >= 0x20 && in[2 + i] < 0x7f ? (char)in[2 + i] : '?';
    c->peer_close_reason[n] = 0;
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
    net_spectate_drop(c);
    net_release_queue(c);
    net_budget_free(c);
    net_client_remove(w, c);
    free(c->q);
    free(c->rx);
    free(c->colliders);
    free(c->subs);
    if (!c->remote)
        metrics_set_clients(atomic_fetch_sub(&s->client_count, 1) - 1);
    free(c);
}
