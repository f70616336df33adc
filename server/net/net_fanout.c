/*
 * net_fanout.c: the sim thread's frames to the clients (the fan-out policy
 * of the net thread; the layers are listed in net_client_internal.h). In a
 * tick's terms: when the sim thread publishes a tick (step 9, hub_publish),
 * the hub's waker (net_server_wake) cancels the net thread's poll wait and
 * net_loop.c drains each world's hub here: net_drain_state → net_dispatch →
 * fan_out → net_enqueue. A relay's items from the owner (net_remote.c) come
 * through net_dispatch too.
 *
 * A client's queue is bounded three ways (its writes are in net_callback.c):
 *
 *   - tile deltas stop for a client whose pending bytes would pass
 *     max_pending_bytes ("slow"): its queued deltas are dropped, and once
 *     the queue has drained to half the limit it is sent fresh snapshots
 *     (a HUB_RESYNC); deltas resume after the last snapshot frame;
 *   - CONTACT, ACK and COLLIDERS frames of a slow client replace their older copies
 *     (each one says everything the older said, for a later tick);
 *   - FOOTPRINTS frames are dropped like tile deltas (and not sent at all to
 *     a slow client): events for visuals, nothing to resync;
 *   - end to end (issue 28, item 5: a client reading one frame per 20 ms
 *     was 52 s behind, its frames waiting in its own socket buffers where
 *     the daemon's queue cannot see them): a client that says which tick it
 *     has handled (PROTOCOL.md "seen") and is more than max_client_lag_ticks
 *     behind what was written to it goes slow too, and its snapshots wait
 *     until it has handled what was already on its way (seen_wait), so it
 *     reads them fresh; a client that never says keeps the two bounds above;
 *   - anything beyond hard_pending_bytes (room for max_pending_bytes, a
 *     whole snapshot of the largest allowed subscription area and a few
 *     messages) closes the connection: such a client has stopped reading
 *     and keeps asking for more.
 */
#include "net/net_server_internal.h"

#include <pthread.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

#define NET_DRAIN_BATCH 256 /* hub items taken per call */
#define NET_DRAIN_ROUNDS 64 /* batches per wake before serving sockets again */

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
    } else if (!c->slow && !c->seen_wait) /* before the drop: what made it slow */
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
        if (c->budget && net_budget_delta(c, o))
            continue; /* folded into its ledger: sent when its window has room */
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
 * bytes (issue 15: one frame per 20 ms was 54 s behind after 60 s). A
 * world's own tick calls it at HUB_OUT_TICK_DONE; a relay, which gets no
 * TICK_DONE from its owner, when the owner's next tick begins (relay_in). */
void net_drop_stale(net_state *w)
{
    uint64_t limit = (uint64_t)w->cfg.limits.max_client_lag_ticks;
    /* "seen" comes at most every 0.1 s, plus a round trip: a limit shorter than
     * that in ticks is judged as 0.25 s; a client-clocked world's ticks come in
     * bursts at its driver's pace, not the clock's, and are not judged by it */
    uint64_t said_limit = (uint64_t)(w->cfg.world.tick_hz * 0.25);
    said_limit = w->cfg.world.client_clock ? UINT64_MAX : said_limit > limit ? said_limit : limit;
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (!c->ready || c->closing || c->killed || c->remote || dropping_deltas(c))
            continue; /* a remote client's lag is its relay's to bound */
        uint64_t oldest = net_oldest_queued_tick(c);
        if (oldest && w->tick > oldest + limit) {
            go_slow(c, w->tick - oldest);
        } else if (c->seen_said && c->seen_tick >= c->seen_from && net_seen_lag(c) > said_limit) {
            log_info("net: client %u (%s) has handled tick %llu, %llu behind what was sent to it "
                     "(limit %d): deltas replaced by a snapshot once it has read what is on its "
                     "way",
                     c->id, c->peer, (unsigned long long)c->seen_tick,
                     (unsigned long long)net_seen_lag(c), (int)said_limit);
            metrics_count_client_behind();
            c->seen_wait = c->written_tick;
            go_slow(c, 0);
        }
    }
}

/* FOOTPRINTS are events for visuals, droppable like tile deltas: not sent to a
 * client whose deltas are being dropped or whose queue would pass
 * max_pending_bytes (no resync follows: a missed event is simply not drawn),
 * and queued as NET_ITEM_TILE so that going slow drops those still queued. */
static void send_footprints(net_client *c, hub_frame *f)
{
    if (dropping_deltas(c) || c->droppable_bytes + f->len > c->srv->cfg.limits.max_pending_bytes ||
        !net_budget_fits(c, f->len)) {
        metrics_count_footprints_dropped(1);
        hub_frame_unref(f);
        return;
    }
    uint64_t events =
        f->len >= TERRAD_FOOTPRINTS_FIXED ? (uint64_t)f->data[12] | (uint64_t)f->data[13] << 8 : 0;
    metrics_count_footprints_sent(1, events);
    net_enqueue(c, f, NET_ITEM_TILE);
}

/* CHECKSUM frames (PROTOCOL.md "CHECKSUM") compare a mirror that holds every
 * delta up to their tick: not sent to a client whose deltas are being dropped
 * (a resync under way), nor past max_pending_bytes, nor past a budget's
 * window (PROTOCOL.md "Budgets"); droppable like a delta. */
static void send_checksum(net_client *c, hub_frame *f)
{
    if (dropping_deltas(c) || c->droppable_bytes + f->len > c->srv->cfg.limits.max_pending_bytes) {
        metrics_count_checksums_skipped(1);
        hub_frame_unref(f);
        return;
    }
    f = net_checksum_for(c, f, net_budget_checksum_entries(c));
    if (!f)
        return;
    if (!net_budget_fits(c, f->len)) { /* a budget's window has no room: the next one checks */
        metrics_count_checksums_skipped(1);
        hub_frame_unref(f);
        return;
    }
    metrics_count_checksums(1, f->len);
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
        } else if (c && o->frame && c->relay_spectating) {
            /* a relayed spectator's replay: queued as its owner's pump queues
             * them (net_spectate.c), so its ACKs of past ticks are no lag */
            net_enqueue_held(c, o->frame);
            o->frame = NULL;
        } else if (c && o->frame && o->msg == TERRAD_MSG_FOOTPRINTS) {
            send_footprints(c, o->frame);
            o->frame = NULL;
        } else if (c && o->frame && o->msg == TERRAD_MSG_CHECKSUM) {
            send_checksum(c, o->frame);
            o->frame = NULL;
        } else if (c && o->frame && c->budget && o->msg == TERRAD_MSG_DELTA) {
            /* pieces go as its window allows; deltas held between them count
             * against max_pending_bytes like queued ones */
            if (net_budget_snapshot(c, o->frame))
                go_slow(c, 0);
            o->frame = NULL;
        } else if (c && o->frame && c->budget && o->msg == TERRAD_MSG_COLLIDERS &&
                   !net_budget_fits(c, o->frame->len)) {
            metrics_count_frames_coalesced(1); /* the next one says everything it said */
        } else if (c && o->frame) {
            int status = o->msg == TERRAD_MSG_CONTACT || o->msg == TERRAD_MSG_ACK ||
                         o->msg == TERRAD_MSG_COLLIDERS || o->msg == TERRAD_MSG_FORCES;
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
        net_drop_stale(w);
        net_budget_flush_state(w);
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

int net_drain_state(net_state *w)
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
    if (net_drain_state(w))
        lws_cancel_service(s->ctx);
}

void net_server_wake(void *arg)
{
    net_server *s = arg;
    /* Every world's tick wakes the net thread (its hub's frames, or only
     * TICK_DONE). A wake already on its way will see what the caller queued
     * before this call: the net thread clears the flag before it takes
     * anything (net_catch_up). With 128 worlds that is a cancel (a write to
     * lws' pipe, a lock) per tick fewer for most ticks (issue 32). */
    if (atomic_load(&s->wake_pending))
        return;
    pthread_mutex_lock(&s->wake_lock);
    if (s->ctx_live) {
        atomic_store(&s->wake_pending, 1);
        lws_cancel_service(s->ctx);
    }
    pthread_mutex_unlock(&s->wake_lock);
}
