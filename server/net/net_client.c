/*
 * net_client.c: the net thread's state (the bottom layer of net/, see
 * net_client_internal.h): the client list, each client's outgoing queue and token
 * bucket, the collider table (id -> owner), and the commands that must
 * reach the sim waiting for room in the hub. It calls only
 * net_remote_send.c: every other file of net/ builds on it.
 *
 * A client's outgoing queue holds hub_frame references: the sim thread's
 * frames (fanned out by net_fanout.c) and the net thread's own replies. Its size
 * is bounded (see net_fanout.c's top comment for the policy); a client whose queue
 * passes hard_pending_bytes has stopped reading and is dropped.
 */
#include "net/net_client_internal.h"

#include <stdarg.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

#define NET_QUEUE_MAX_ITEMS 65536  /* frames queued for one client, at most */
#define NET_CLOSE_GRACE_S 3        /* a closing client gets this long to take its last frames */
#define NET_FLOOD_FATAL_MS 10000.0 /* sustained rate limiting closes with 4010 */
#define NET_FLOOD_FORGIVE_S 3.0    /* the most a flood owes: seconds of allowance */

/* ---- the client list ---- */

net_client *net_find_client(net_state *s, uint32_t id)
{
    int lo = 0, hi = s->nclients - 1;
    while (lo <= hi) {
        int mid = lo + (hi - lo) / 2;
        uint32_t at = s->clients[mid]->id;
        if (at == id)
            return s->clients[mid];
        if (at < id)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return NULL;
}

int net_client_add(net_state *s, net_client *c)
{
    if (array_grow((void **)&s->clients, &s->clients_cap, (int64_t)s->nclients + 1,
                   sizeof *s->clients) != 0)
        return -1;
    /* ids only grow, so a new client goes last; one moving from the lobby to
     * a world may have said hello after a later one: kept sorted for the search */
    int at = s->nclients;
    while (at > 0 && s->clients[at - 1]->id > c->id)
        at--;
    memmove(&s->clients[at + 1], &s->clients[at], (size_t)(s->nclients - at) * sizeof *s->clients);
    s->clients[at] = c;
    s->nclients++;
    return 0;
}

net_collider_slot *net_collider_owned(net_client *c, uint32_t id, const cJSON *ref, int any_owner)
{
    net_collider_slot *slot = net_collider_find(c->srv, id);
    if (!slot) {
        net_error(c, TERRAD_E_UNKNOWN_COLLIDER, ref, id, 0, "collider %u does not exist", id);
        return NULL;
    }
    if (slot->owner != c->id && !any_owner) {
        net_error(c, TERRAD_E_NOT_OWNER, ref, id, 0, "collider %u belongs to another client", id);
        return NULL;
    }
    return slot;
}

void net_client_remove(net_state *s, net_client *c)
{
    if (s->driver == c->id)
        s->driver = 0; /* a client-clocked world waits for its next driver */
    for (int i = 0; i < s->nclients; i++)
        if (s->clients[i] == c) {
            memmove(&s->clients[i], &s->clients[i + 1],
                    (size_t)(s->nclients - i - 1) * sizeof *s->clients);
            s->nclients--;
            return;
        }
}

/* The state of the world hello's world names in the lobby, or NULL. "" (a
 * cluster node's hello naming none): the first world ticked here, else (a
 * node that ticks none) the first relayed. */
static net_state *find_world(net_state *lobby, const char *world)
{
    net_state *to = NULL;
    for (int i = 0; i < lobby->nworlds && !to; i++)
        if (world[0] ? strcmp(lobby->worlds[i]->world_name, world) == 0 : !lobby->worlds[i]->relay)
            to = lobby->worlds[i];
    if (!to && !world[0] && lobby->nworlds)
        to = lobby->worlds[0];
    return to;
}

int net_client_join_world(net_client *c, const char *world, char *why, size_t cap)
{
    net_state *lobby = c->srv;
    /* a single daemon's default world: the one its table's default name names */
    char def[HUB_WORLD_NAME_MAX + 1] = "";
    int daemon = lobby->cfg.worlds && hub_worlds_default(lobby->cfg.worlds, def, sizeof def);
    net_state *to = find_world(lobby, daemon && !world[0] ? def : world);
    if (!to && daemon && !lobby->hosted_worlds) /* any name: its one world, as it always was */
        to = find_world(lobby, def);
    if (!to && daemon) {
        char names[300];
        hub_worlds_names(lobby->cfg.worlds, names, sizeof names);
        snprintf(why, cap,
                 "world: no world \"%s\" on this daemon (its worlds: %s; GET /v1/worlds "
                 "lists them)",
                 world, names);
        return -1;
    }
    if (!to) {
        size_t n =
            (size_t)snprintf(why, cap, "world: this node does not serve world \"%s\"", world);
        for (int i = 0; i < lobby->nworlds && n < cap; i++)
            n += (size_t)snprintf(why + n, cap - n, "%s world \"%s\"", i ? "," : "; it serves",
                                  lobby->worlds[i]->world_name);
        if (n < cap)
            snprintf(why + n, cap - n, "%s (terrad world list names each world's node)",
                     lobby->nworlds ? "" : "; it serves no world now");
        return -1;
    }
    if (net_client_add(to, c) != 0) {
        snprintf(why, cap, "out of memory");
        return -1;
    }
    net_client_remove(lobby, c);
    c->srv = to;
    return 0;
}

/* ---- the outgoing queue ---- */

void net_release_queue(net_client *c)
{
    for (size_t i = 0; i < c->q_count; i++)
        hub_frame_unref(c->q[(c->q_head + i) % c->q_cap].frame);
    c->q_head = c->q_count = 0;
    c->pending_bytes = c->droppable_bytes = 0;
}

/* Drop every queued item for which drop(item) says so; returns how many. */
static int queue_filter(net_client *c, int (*drop)(const net_item *, int), int arg)
{
    size_t kept = 0;
    int dropped = 0;
    for (size_t i = 0; i < c->q_count; i++) {
        net_item it = c->q[(c->q_head + i) % c->q_cap];
        if (drop(&it, arg)) {
            c->pending_bytes -= it.frame->len;
            if (it.kind != NET_ITEM_REPLY)
                c->droppable_bytes -= it.frame->len;
            hub_frame_unref(it.frame);
            dropped++;
        } else {
            c->q[(c->q_head + kept) % c->q_cap] = it;
            kept++;
        }
    }
    c->q_count = kept;
    return dropped;
}

/* Tile deltas, and the ACK and CONTACT frames queued behind them: an ACK of
 * tick t promises t's deltas came first, so it cannot outlive them. */
static int is_tile_or_status(const net_item *it, int arg)
{
    (void)arg;
    return it->kind == NET_ITEM_TILE || it->kind == NET_ITEM_STATUS;
}

static int is_status_of(const net_item *it, int type)
{
    return it->kind == NET_ITEM_STATUS && it->type == type;
}

uint64_t net_oldest_queued_tick(const net_client *c)
{
    /* replies (snapshots among them) come first in a queue that is catching
     * up; the first TILE or STATUS item is the oldest: items are queued in
     * tick order */
    for (size_t i = 0; i < c->q_count; i++) {
        const net_item *it = &c->q[(c->q_head + i) % c->q_cap];
        if (it->tick)
            return it->tick;
    }
    return 0;
}

void net_seen_written(net_client *c, uint64_t tick)
{
    if (c->unseen_count == NET_UNSEEN_MAX) { /* the newest entry takes it: judged by the older */
        c->unseen_tick[(c->unseen_head + c->unseen_count - 1) % NET_UNSEEN_MAX] = tick;
        return;
    }
    int at = (c->unseen_head + c->unseen_count) % NET_UNSEEN_MAX;
    c->unseen_tick[at] = tick;
    c->unseen_at[at] = c->srv->tick;
    c->unseen_count++;
}

void net_seen_handled(net_client *c)
{
    while (c->unseen_count && c->unseen_tick[c->unseen_head] <= c->seen_tick) {
        c->unseen_head = (c->unseen_head + 1) % NET_UNSEEN_MAX;
        c->unseen_count--;
    }
}

uint64_t net_seen_lag(const net_client *c)
{
    uint64_t at = c->unseen_count ? c->unseen_at[c->unseen_head] : 0;
    return c->unseen_count && c->srv->tick > at ? c->srv->tick - at : 0;
}

int net_drop_tile_deltas(net_client *c)
{
    return queue_filter(c, is_tile_or_status, 0);
}

void net_client_kill(net_client *c, const char *why)
{
    if (c->killed)
        return;
    c->killed = 1;
    uint64_t frames = c->q_count;
    net_release_queue(c);
    metrics_count_frames_dropped(frames);
    log_warn("net: client %u (%s) closed: %s", c->id, c->peer, why);
    if (c->remote)
        net_remote_close(c, LWS_CLOSE_STATUS_POLICY_VIOLATION, "killed");
    else
        lws_set_timeout(c->wsi, PENDING_TIMEOUT_USER_OK, LWS_TO_KILL_ASYNC);
}

/* net_enqueue and net_enqueue_held; held: the budget counts the frame as
 * data that waited for room (tile data), not as a reply or status frame. */
static void enqueue(net_client *c, hub_frame *f, net_item_kind kind, int held)
{
    net_state *s = c->srv;
    THREAD_OWNED(&s->owner);
    if (c->killed || c->remote) { /* a remote client's frames go to its relay at once */
        if (c->remote && !c->remote_gone)
            net_remote_frame(c, f, 0);
        hub_frame_unref(f);
        return;
    }
    net_item it = {.frame = f, .kind = (unsigned char)kind};
    if (kind != NET_ITEM_REPLY)
        it.tick = s->tick ? s->tick : 1;
    if (kind == NET_ITEM_STATUS) {
        it.type = f->len > 2 ? f->data[2] : 0;
        if (c->droppable_bytes + f->len > s->cfg.limits.max_pending_bytes) {
            int n = queue_filter(c, is_status_of, it.type);
            if (n)
                metrics_count_frames_coalesced((uint64_t)n);
        }
    }
    if (c->pending_bytes + f->len > s->hard_pending_bytes || c->q_count >= NET_QUEUE_MAX_ITEMS) {
        hub_frame_unref(f);
        metrics_count_frames_dropped(1);
        net_client_kill(c, "outgoing queue over its bound (the client stopped reading)");
        return;
    }
    if (c->q_count == c->q_cap) {
        size_t cap = c->q_cap ? c->q_cap * 2 : 64;
        net_item *grown = malloc(cap * sizeof *grown);
        if (!grown) {
            hub_frame_unref(f);
            net_client_kill(c, "out of memory for its outgoing queue");
            return;
        }
        for (size_t i = 0; i < c->q_count; i++)
            grown[i] = c->q[(c->q_head + i) % c->q_cap];
        free(c->q);
        c->q = grown;
        c->q_cap = cap;
        c->q_head = 0;
    }
    c->q[(c->q_head + c->q_count) % c->q_cap] = it;
    c->q_count++;
    c->pending_bytes += f->len;
    if (kind != NET_ITEM_REPLY)
        c->droppable_bytes += f->len;
    net_budget_charge(c, f->len, held);
    lws_callback_on_writable(c->wsi);
}

void net_enqueue(net_client *c, hub_frame *f, net_item_kind kind)
{
    enqueue(c, f, kind, kind == NET_ITEM_TILE);
}

void net_enqueue_held(net_client *c, hub_frame *f)
{
    enqueue(c, f, NET_ITEM_REPLY, 1);
}

void net_send_json(net_client *c, cJSON *msg)
{
    char *text = json_print_delete(msg);
    hub_frame *f = text ? hub_frame_from_text(text) : NULL;
    free(text);
    if (!f) {
        log_error("net: out of memory for a reply to client %u", c->id);
        return;
    }
    net_enqueue(c, f, NET_ITEM_REPLY);
}

cJSON *net_ref_copy(const cJSON *ref)
{
    return ref ? cJSON_Duplicate(ref, 1) : cJSON_CreateNull();
}

void net_error(net_client *c, int code, const cJSON *ref, int64_t collider, int fatal,
               const char *fmt, ...)
{
    char message[512];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    if (code != TERRAD_E_SHUTTING_DOWN && code != TERRAD_E_INTERNAL) {
        metrics_count_refused(code);
        net_warn_refusal(c->srv, c, code, message);
    }
    if (!fatal && c->pending_bytes > c->srv->cfg.limits.max_pending_bytes) {
        metrics_count_frames_dropped(1); /* it is not reading its errors anyway */
        return;
    }
    cJSON *e = cJSON_CreateObject();
    cJSON_AddStringToObject(e, "type", "error");
    cJSON_AddNumberToObject(e, "code", code);
    cJSON_AddStringToObject(e, "name", terrad_err_name(code));
    cJSON_AddStringToObject(e, "message", message);
    cJSON_AddItemToObject(e, "ref", net_ref_copy(ref));
    if (collider >= 0)
        cJSON_AddNumberToObject(e, "collider", (double)collider);
    if (fatal)
        cJSON_AddBoolToObject(e, "fatal", 1);
    net_send_json(c, e);
}

void net_close_after_flush(net_client *c, int code, const char *reason)
{
    if (c->closing)
        return;
    c->closing = 1;
    c->close_code = code;
    snprintf(c->close_reason, sizeof c->close_reason, "%s", reason);
    if (c->remote) {
        net_remote_close(c, code, reason);
        return;
    }
    lws_set_timer_usecs(c->wsi, LWS_SET_TIMER_USEC_CANCEL);
    lws_set_timeout(c->wsi, PENDING_TIMEOUT_USER_OK, NET_CLOSE_GRACE_S);
    lws_callback_on_writable(c->wsi);
}

/* The flood's clock runs on what the client sent, not on when the net thread
 * got to it: a loaded server reads a flooding client late and in bunches (the
 * messages wait in the socket), so the gaps between refusals say nothing about
 * the client. flood_debt counts the refused messages the client has not earned
 * back; it shrinks only when the bucket would overflow, i.e. while the client
 * sends less than its rate. A stalled server refills the bucket, but the
 * messages that queued meanwhile drain it again and the debt stays: the flood
 * goes on and is closed after 10 s however slow the server was. A client that
 * really pauses (NET_FLOOD_FORGIVE_S of allowance beyond its burst, at most)
 * starts afresh. */
int net_rate_allow(net_client *c)
{
    const net_limits *l = &c->srv->cfg.limits;
    double now = time_now_ms();
    c->tokens += (now - c->refill_ms) / 1000.0 * l->max_messages_per_s;
    if (c->tokens > l->messages_burst) {
        c->flood_debt -= c->tokens - l->messages_burst; /* sent less than its rate */
        if (c->flood_debt < 0)
            c->flood_debt = 0;
        c->tokens = l->messages_burst;
    }
    c->refill_ms = now;
    if (c->tokens >= 1.0) {
        c->tokens -= 1.0;
        return 1;
    }
    if (c->flood_debt <= c->tokens)
        c->flood_since_ms = now; /* a new flood: the last one was earned back */
    c->flood_debt += 1.0;
    if (c->flood_debt > l->max_messages_per_s * NET_FLOOD_FORGIVE_S)
        c->flood_debt = l->max_messages_per_s * NET_FLOOD_FORGIVE_S;
    if (now - c->flood_since_ms >= NET_FLOOD_FATAL_MS) {
        net_error(c, TERRAD_E_RATE_LIMITED, NULL, -1, 1,
                  "over %g messages per second for 10 s: closing", l->max_messages_per_s);
        net_close_after_flush(c, 4000 + TERRAD_E_RATE_LIMITED, "rate limited");
    } else if (c->last_rate_error_ms == 0 || now - c->last_rate_error_ms >= 1000.0) {
        c->last_rate_error_ms = now;
        net_error(c, TERRAD_E_RATE_LIMITED, NULL, -1, 0,
                  "over %g messages per second (burst %g): message dropped", l->max_messages_per_s,
                  l->messages_burst);
    } else {
        metrics_count_refused(TERRAD_E_RATE_LIMITED);
    }
    return 0;
}

/* ---- commands for the sim ---- */

void net_flush_backlog(net_state *s)
{
    int sent = 0;
    while (sent < s->backlog_count && hub_push_command(s->hub, &s->backlog[sent]) == 0)
        sent++;
    if (sent) {
        memmove(s->backlog, s->backlog + sent,
                (size_t)(s->backlog_count - sent) * sizeof *s->backlog);
        s->backlog_count -= sent;
    }
}

void net_push_must(net_state *s, const hub_command *cmd)
{
    THREAD_OWNED(&s->owner);
    net_flush_backlog(s);
    if (s->backlog_count == 0 && hub_push_command(s->hub, cmd) == 0)
        return;
    if (array_grow((void **)&s->backlog, &s->backlog_cap, (int64_t)s->backlog_count + 1,
                   sizeof *s->backlog) != 0) {
        log_error("net: out of memory: a command for client %u is lost", cmd->client);
        return;
    }
    s->backlog[s->backlog_count++] = *cmd;
}

int net_push_refusable(net_state *s, const hub_command *cmd)
{
    THREAD_OWNED(&s->owner);
    net_flush_backlog(s);
    if (s->backlog_count)
        return -1; /* keep the order: what must go waits in front */
    return hub_push_command(s->hub, cmd);
}

/* Fresh snapshots of every subscription of c: tile deltas stop at once (the
 * queued ones are dropped) and resume after the sim's last snapshot frame.
 * A resync of one subscription resyncs them all, because deltas are held
 * back per client, not per subscription. */
void net_request_resync(net_client *c, uint32_t subscription)
{
    (void)subscription;
    int n = net_drop_tile_deltas(c);
    if (n)
        metrics_count_frames_coalesced((uint64_t)n);
    c->slow = 0;
    net_budget_reset(c); /* the snapshots replace whatever it was still owed */
    /* whatever asked for it (the client, going slow, an overflow): "seen" is
     * judged again once the client has handled the snapshots' tick */
    c->seen_wait = 0;
    c->seen_from = c->srv->tick;
    if (c->sub_count == 0)
        return;
    c->snapshots_requested++;
    c->resync_until = c->snapshots_requested;
    if (c->srv->relay) { /* the owner sends the snapshots: asked as by the client */
        static const char resync[] = "{\"type\":\"resync\"}";
        net_relay_forward(c, 0, resync, sizeof resync - 1);
        return;
    }
    hub_command cmd = {.kind = HUB_RESYNC, .client = c->id, .subscription = 0};
    net_push_must(c->srv, &cmd);
}

void net_warn_refusal(net_state *s, const net_client *c, int code, const char *message)
{
    double now = time_now_ms();
    if (s->last_warn_ms > 0 && now - s->last_warn_ms < 1000.0) {
        s->warns_suppressed++;
        return;
    }
    if (s->warns_suppressed)
        log_warn("net: client %u (%s): refused %s: %s (and %llu more refusals in the last "
                 "second, not logged)",
                 c->id, c->peer, terrad_err_name(code), message,
                 (unsigned long long)s->warns_suppressed);
    else
        log_warn("net: client %u (%s): refused %s: %s", c->id, c->peer, terrad_err_name(code),
                 message);
    s->warns_suppressed = 0;
    s->last_warn_ms = now;
}

/* ---- collider table: id -> owner, open addressing, backward-shift deletion ---- */

static size_t slot_of(uint32_t id, size_t cap)
{
    uint32_t x = id * 0x9e3779b1u;
    return (x ^ (x >> 16)) & (cap - 1);
}

net_collider_slot *net_collider_find(net_state *s, uint32_t id)
{
    if (!s->colliders_cap || id == 0)
        return NULL;
    for (size_t i = slot_of(id, s->colliders_cap);; i = (i + 1) & (s->colliders_cap - 1)) {
        if (s->colliders[i].id == id)
            return &s->colliders[i];
        if (s->colliders[i].id == 0)
            return NULL;
    }
}

static void table_put(net_collider_slot *t, size_t cap, net_collider_slot v)
{
    size_t i = slot_of(v.id, cap);
    while (t[i].id != 0)
        i = (i + 1) & (cap - 1);
    t[i] = v;
}

int net_collider_insert(net_state *s, uint32_t id, uint32_t owner, int axis_z)
{
    if ((s->colliders_used + 1) * 2 > s->colliders_cap) {
        size_t cap = s->colliders_cap ? s->colliders_cap * 2 : 256;
        net_collider_slot *t = calloc(cap, sizeof *t);
        if (!t)
            return -1;
        for (size_t i = 0; i < s->colliders_cap; i++)
            if (s->colliders[i].id)
                table_put(t, cap, s->colliders[i]);
        free(s->colliders);
        s->colliders = t;
        s->colliders_cap = cap;
    }
    table_put(s->colliders, s->colliders_cap,
              (net_collider_slot){.id = id, .owner = owner, .axis_z = axis_z});
    s->colliders_used++;
    return 0;
}

void net_collider_remove(net_state *s, uint32_t id)
{
    net_collider_slot *at = net_collider_find(s, id);
    if (!at)
        return;
    size_t mask = s->colliders_cap - 1;
    size_t i = (size_t)(at - s->colliders);
    s->colliders[i].id = 0;
    s->colliders_used--;
    /* shift later members of the probe run back into the hole */
    for (size_t j = (i + 1) & mask; s->colliders[j].id != 0; j = (j + 1) & mask) {
        size_t home = slot_of(s->colliders[j].id, s->colliders_cap);
        /* j's entry may move to i if home is not cyclically in (i, j] */
        int between = (i <= j) ? (home > i && home <= j) : (home > i || home <= j);
        if (!between) {
            s->colliders[i] = s->colliders[j];
            s->colliders[j].id = 0;
            i = j;
        }
    }
}
