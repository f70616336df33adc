/*
 * net_callback.c: the libwebsockets protocol callback ("terrad.v1") of the
 * net thread (its layers are listed in net_client_internal.h): admission and
 * the subprotocol check, a client's start and end, the reassembly of its
 * messages and their hand-over to net_requests.c, and its writes — one frame
 * of its queue per SERVER_WRITEABLE. In a tick's terms: what clients send
 * here becomes the hub's commands, poses and batch sequences that the next
 * tick takes (step 1); a wake after a tick (EVENT_WAIT_CANCELLED) hands over
 * to net_loop.c.
 *
 * Everything a connection owns (its reassembly buffer, its token bucket, its
 * colliders and subscriptions, its outgoing queue) lives in a net_client
 * that only this thread touches, so there are no locks here beyond the hub's
 * own. Incoming messages are reassembled up to max_message_bytes, rate
 * limited by a token bucket (net_client.c), and handed to net_requests.c.
 */
#include "net/net_requests_internal.h"
#include "net/net_server_internal.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

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
    /* a client-clocked world's driver paces itself (a STEP waits for its
     * STEPPED; at most HUB_STEP_CAPACITY wait): its steps pass the bucket */
    int step = c->rx_binary && c->rx_len >= 3 && c->rx[2] == TERRAD_MSG_STEP &&
               c->srv->cfg.world.client_clock && (!c->srv->driver || c->srv->driver == c->id);
    if (!step && !net_rate_allow(c))
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
    if (c->slow && c->pending_bytes <= s->st.cfg.limits.max_pending_bytes / 2 && !c->closing &&
        c->seen_tick >= c->seen_wait) {
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
        if (it.frame->binary && it.frame->len >= 12 && it.frame->data[2] >= TERRAD_MSG_DELTA) {
            uint64_t tick = 0; /* every server frame from DELTA on has its u64 tick at 4 */
            for (int b = 7; b >= 0; b--)
                tick = tick << 8 | it.frame->data[4 + b];
            if (tick > c->written_tick) {
                c->written_tick = tick;
                net_seen_written(c, tick);
            }
        }
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
        net_catch_up(s);
        return 0;
    default:
        return 0;
    }
}

const struct lws_protocols net_protocols[] = {
    {TERRAD_PROTO_SUBPROTOCOL, net_callback, sizeof(net_session), 65536, 0, NULL, 0},
    {NULL, NULL, 0, 0, 0, NULL, 0},
};
