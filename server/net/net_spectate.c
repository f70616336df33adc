/*
 * net_spectate.c: spectators (PROTOCOL.md "Spectate"): a client that watches
 * a window of the world from a past tick, played forward at 1–8× the world's
 * tick rate (or a step at a time) until it reaches the live tick, with the
 * frames a live subscriber got: a snapshot of the window at the start tick,
 * then per tick the DELTA frames of the tiles that tick changed (the tick's
 * dirty rectangles cut along tile edges, one rectangle per tile, as
 * service_publish_deltas cuts them) and an ACK of the tick (sequence 0) as
 * its end mark.
 *
 * Where the frames come from: the world's data directory, never the sim
 * thread. Each spectator has a thread of its own (spectate_main) that opens a
 * store cursor (store_cursor_open: the window as of the start tick, rebuilt
 * as GET /v1/heights?tick=N rebuilds it), then reads the log forward one
 * record (one tick) at a time, paced by the clock, and puts the frames in its
 * outbox. The net thread moves them to the client's queue (net_spectate_pump,
 * on every wake and heartbeat) as the client's queue and budget have room,
 * and tells the thread the live tick; the thread never touches a client and
 * the net thread never waits for a rebuild. The thread reads the world's
 * base terrain, which goes with the world: it holds the world's table entry
 * as a reader (hub_worlds_acquire) until it ends, so a leaving world's
 * removal (hub_worlds_remove, on the host's thread) waits for it, while the
 * net thread only cancels it and reaps it later from the lobby's list
 * (net_spectate_leave). So that the removal waits no longer than one
 * record's work, the thread stops itself (stopped: asked by its store cursor
 * between the records and snapshots of its rebuild, and between its ticks)
 * once it is cancelled or its world's entry is leaving (hub_worlds_leaving),
 * whether or not the net thread got to it yet; a cancelled thread tells its
 * client nothing (the net thread does: spectate_end "stopped", or the
 * world's shutting_down error). A spectator holds no subscription while it
 * watches: the live deltas, CHECKSUMs and resyncs are not its business, so
 * its frames are replies to the net thread (never dropped, never making it
 * slow) and its own queue bound and budget pace its thread instead.
 * In the layers of net_client_internal.h: below net_peer.c (which drops a
 * leaving client's spectator), above net_budget.c.
 */
#include "net/net_client_internal.h"
#include "net/net_control_internal.h"

#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "metrics/metrics.h"
#include "store/store.h"
#include "terrad_proto.h"

#define SPECTATE_WAIT_MS 50

struct net_spectator {
    /* set before the thread starts, read-only after */
    store_history history; /* where the past is read: a directory, or a cluster's reader */
    const world *base;
    world_rect rect; /* the window */
    uint64_t from;
    int speed, stepping;
    double tick_hz;
    int tile, width, height;
    size_t room; /* the bytes its outbox and the client's queue may hold together */
    net_server *server;
    hub_worlds *table; /* entry held as a reader until the thread ends: base and history stay */
    hub_world *entry;
    pthread_t thread;
    /* the net thread's */
    uint32_t id;
    cJSON *ref;
    int told;                   /* "spectating" sent */
    struct net_spectator *next; /* on its state's list of spectators whose client left */
    /* shared, under lock */
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int cancelled, started, ended, finished;
    uint64_t live_tick, steps, at_tick;
    size_t client_bytes; /* the client's pending bytes, as the net thread last saw them */
    net_outbox box;
    int end_code; /* 0: spectate_end; else an error code (the start failed) */
    char end_reason[16];
    char end_why[480];
};

static atomic_int running; /* threads alive, all daemons of the process */

static double now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec * 1e3 + t.tv_nsec / 1e6;
}

/* ---- the spectator's thread ---- */

int net_outbox_put(net_outbox *o, hub_frame *f)
{
    if (!f || array_grow((void **)&o->frames, &o->cap, (int64_t)o->n + 1, sizeof *o->frames) != 0) {
        if (f)
            hub_frame_unref(f);
        metrics_count_spectate_dropped(1);
        return -1;
    }
    o->frames[o->n++] = f;
    o->bytes += f->len;
    metrics_count_spectate_frames(1, f->len); /* here: once posted, the net thread may free f */
    return 0;
}

/* f (NULL: it could not be made) to the net thread: 0, or -1 when it was
 * dropped (counted). The spectator's mirror would then miss it for good (a
 * spectator has no resync), so the caller ends the replay "failed". */
static int post(net_spectator *j, hub_frame *f)
{
    pthread_mutex_lock(&j->lock);
    int rc = net_outbox_put(&j->box, f);
    pthread_mutex_unlock(&j->lock);
    if (rc == 0)
        net_server_wake(j->server);
    return rc;
}

static void post_end(net_spectator *j, int code, const char *reason, const char *why)
{
    pthread_mutex_lock(&j->lock);
    j->ended = 1;
    j->end_code = code;
    snprintf(j->end_reason, sizeof j->end_reason, "%s", reason);
    snprintf(j->end_why, sizeof j->end_why, "%s", why);
    pthread_mutex_unlock(&j->lock);
    net_server_wake(j->server);
}

static hub_frame *ack_frame(uint64_t tick)
{
    hub_frame *f = hub_frame_new(1, TERRAD_ACK_SIZE);
    if (f && terrad_ack_encode(f->data, TERRAD_ACK_SIZE, &f->len, tick, 0) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    return f;
}

/* One rectangle's values as a one-rectangle DELTA frame of tick. */
static hub_frame *rect_frame(terrad_codec *codec, terrad_rect *rect, const int32_t *values,
                             uint64_t tick)
{
    size_t cells = (size_t)rect->w * rect->h, cap = terrad_rect_compress_bound(cells), len = 0;
    uint8_t *packed = malloc(cap);
    hub_frame *f = NULL;
    if (packed && terrad_rect_compress(codec, values, cells, packed, cap, &len) == 0) {
        rect->data = packed;
        rect->data_len = (uint32_t)len;
        size_t size = terrad_delta_size(rect, 1);
        f = hub_frame_new(1, size);
        if (f && terrad_delta_encode(f->data, size, &f->len, tick, rect, 1) != 0) {
            hub_frame_unref(f);
            f = NULL;
        }
    }
    free(packed);
    return f;
}

typedef struct replay {
    net_spectator *j;
    store_cursor *cur;
    terrad_codec *codec;
    int tx0, ty0, ntx, nty;
    uint32_t *versions; /* per tile of the window: the version the spectator holds */
    world_rect *boxes;  /* per tile: the box a record changed (w 0: none) */
    int32_t **before;   /* per tile: the box's heights before the record */
} replay;

static world_rect tile_rect(const replay *p, int i)
{
    int ts = p->j->tile;
    return (world_rect){(p->tx0 + i % p->ntx) * ts, (p->ty0 + i / p->ntx) * ts, ts, ts};
}

/* The snapshot: the window's part of each tile, version 1, as of from. */
static int send_snapshot(replay *p)
{
    net_spectator *j = p->j;
    for (int i = 0; i < p->ntx * p->nty; i++) {
        world_rect q = world_rect_meet(j->rect, tile_rect(p, i));
        int32_t *v = malloc((size_t)q.w * q.h * sizeof *v);
        if (!v)
            return -1;
        store_cursor_read(p->cur, q, v);
        p->versions[i] = 1;
        terrad_rect r = {.x = q.x,
                         .y = q.y,
                         .w = (uint16_t)q.w,
                         .h = (uint16_t)q.h,
                         .base_version = 0,
                         .new_version = 1,
                         .encoding = TERRAD_ENC_SNAPSHOT};
        int rc = post(j, rect_frame(p->codec, &r, v, j->from));
        free(v);
        if (rc != 0)
            return -1;
    }
    return post(j, ack_frame(j->from));
}

/* One record: per tile of the window, the box its rectangles' pieces in the
 * tile span (service_cut_into_tiles' pieces, combined as
 * service_publish_deltas combines them), its heights before and after,
 * their difference as that tile's delta. 0 or -1 (why). */
static int send_record(replay *p, uint64_t tick, const world_rect *rects, int n, error_text *why)
{
    int tiles = p->ntx * p->nty;
    for (int i = 0; i < tiles; i++) {
        world_rect t = tile_rect(p, i), box = {0, 0, 0, 0};
        for (int k = 0; k < n; k++) {
            if (!world_rects_overlap(rects[k], t))
                continue;
            world_rect piece = world_rect_meet(rects[k], t);
            box = box.w ? world_rect_union(box, piece) : piece;
        }
        p->boxes[i] = box;
        if (box.w && !(p->before[i] = malloc((size_t)box.w * box.h * sizeof *p->before[i]))) {
            error_set(why, "out of memory");
            return -1;
        }
        if (box.w)
            store_cursor_read(p->cur, box, p->before[i]);
    }
    if (store_cursor_apply(p->cur, why) != 0)
        return -1;
    for (int i = 0; i < tiles; i++) {
        world_rect box = p->boxes[i];
        if (!box.w)
            continue;
        size_t cells = (size_t)box.w * box.h;
        int32_t *after = malloc(cells * sizeof *after);
        if (!after) {
            error_set(why, "out of memory");
            return -1;
        }
        store_cursor_read(p->cur, box, after);
        int any = 0;
        for (size_t c = 0; c < cells; c++) {
            after[c] = (int32_t)((uint32_t)after[c] - (uint32_t)p->before[i][c]);
            any |= after[c] != 0;
        }
        if (any) {
            terrad_rect r = {.x = box.x,
                             .y = box.y,
                             .w = (uint16_t)box.w,
                             .h = (uint16_t)box.h,
                             .base_version = p->versions[i],
                             .new_version = p->versions[i] + 1,
                             .encoding = TERRAD_ENC_DELTA};
            p->versions[i]++;
            if (post(p->j, rect_frame(p->codec, &r, after, tick)) != 0) {
                free(after);
                error_set(why, "out of memory: a frame of tick %llu was dropped",
                          (unsigned long long)tick);
                return -1;
            }
        }
        free(after);
        free(p->before[i]);
        p->before[i] = NULL;
    }
    return 0;
}

/* The thread's stop, under j->lock: cancelled by the net thread, or its
 * world leaves. */
static int stop_locked(const net_spectator *j)
{
    return j->cancelled || hub_worlds_leaving(j->entry);
}

/* The store cursor's cancel (store_cancel), asked between records. */
static int stopped(void *ctx)
{
    net_spectator *j = ctx;
    pthread_mutex_lock(&j->lock);
    int stop = stop_locked(j);
    pthread_mutex_unlock(&j->lock);
    return stop;
}

/* Waits until tick t + 1 may go: 1 go, 0 caught up with the live tick, -1
 * stopped. */
static int wait_turn(net_spectator *j, uint64_t t, double *t0)
{
    pthread_mutex_lock(&j->lock);
    int rc;
    for (;;) {
        if (stop_locked(j)) {
            rc = -1;
            break;
        }
        if (t >= j->live_tick) {
            rc = 0;
            break;
        }
        double now = now_ms();
        double due = *t0 + (double)(t + 1 - j->from) * 1000.0 / (j->tick_hz * j->speed);
        if (!j->stepping && now > due + 1000.0) /* held back (room): no burst to catch up */
            *t0 += now - due, due = now;
        int turn = j->stepping ? j->steps > 0 : now >= due;
        int room = j->box.bytes + j->client_bytes <= j->room;
        if (turn && room) {
            j->steps -= j->stepping;
            rc = 1;
            break;
        }
        double wait = turn || j->stepping ? SPECTATE_WAIT_MS : due - now;
        if (wait > SPECTATE_WAIT_MS)
            wait = SPECTATE_WAIT_MS;
        struct timespec until = time_after_ms(CLOCK_REALTIME, wait + 1e-6);
        pthread_cond_timedwait(&j->cond, &j->lock, &until);
    }
    pthread_mutex_unlock(&j->lock);
    return rc;
}

static void play(replay *p)
{
    net_spectator *j = p->j;
    error_text why = {{0}};
    uint64_t t = j->from;
    double t0 = now_ms();
    for (;;) {
        int go = wait_turn(j, t, &t0);
        if (go < 0)
            return;
        if (go == 0) {
            post_end(j, 0, "live", "caught up with the live tick");
            return;
        }
        uint64_t rt;
        const world_rect *rects;
        int n, rc;
        while ((rc = store_cursor_next(p->cur, t + 1, &rt, &rects, &n, &why)) == 1)
            if (send_record(p, rt, rects, n, &why) != 0) {
                rc = -1;
                break;
            }
        if (rc == STORE_CANCELLED)
            return;
        if (rc < 0) {
            post_end(j, 0, "failed", why.message);
            return;
        }
        t++;
        if (post(j, ack_frame(t)) != 0) {
            post_end(j, 0, "failed", "out of memory: a tick's ACK was dropped");
            return;
        }
        metrics_count_spectate_ticks(1);
        pthread_mutex_lock(&j->lock);
        j->at_tick = t;
        pthread_mutex_unlock(&j->lock);
    }
}

static void *spectate_main(void *arg)
{
    net_spectator *j = arg;
    int ts = j->tile;
    replay p = {.j = j,
                .tx0 = j->rect.x / ts,
                .ty0 = j->rect.y / ts,
                .ntx = (j->rect.x + j->rect.w - 1) / ts - j->rect.x / ts + 1,
                .nty = (j->rect.y + j->rect.h - 1) / ts - j->rect.y / ts + 1};
    int tiles = p.ntx * p.nty;
    /* the window's tiles whole: a tile's delta box may reach past the window */
    world_rect span = {p.tx0 * ts, p.ty0 * ts, p.ntx * ts, p.nty * ts};
    if (span.x + span.w > j->width)
        span.w = j->width - span.x;
    if (span.y + span.h > j->height)
        span.h = j->height - span.y;
    p.codec = terrad_codec_new(0);
    p.versions = calloc((size_t)tiles, sizeof *p.versions);
    p.boxes = calloc((size_t)tiles, sizeof *p.boxes);
    p.before = calloc((size_t)tiles, sizeof *p.before);
    error_text why = {{0}};
    double start = now_ms();
    store_cancel cancel = {.cancelled = stopped, .ctx = j};
    int rc = !p.codec || !p.versions || !p.boxes || !p.before
                 ? -1
                 : store_history_cursor(&j->history, j->base, j->from, span, &cancel, &p.cur, &why);
    if (rc == STORE_CANCELLED) {
        /* its client is told by the net thread */
    } else if (rc == 1) {
        post_end(j, TERRAD_E_BAD_VALUE, "gone", why.message);
    } else if (rc != 0) {
        post_end(j, TERRAD_E_INTERNAL, "failed", why.message[0] ? why.message : "out of memory");
    } else {
        metrics_observe_spectate_seek_ms(now_ms() - start);
        metrics_observe_spectate_cursor_cells(store_cursor_cells(p.cur, NULL));
        pthread_mutex_lock(&j->lock);
        j->started = 1;
        j->at_tick = j->from;
        pthread_mutex_unlock(&j->lock);
        if (send_snapshot(&p) != 0)
            post_end(j, 0, "failed", "out of memory for the snapshot");
        else
            play(&p);
        /* a cursor's tiles are never freed: its most is its last */
        metrics_observe_spectate_cursor_cells(store_cursor_cells(p.cur, NULL));
    }
    store_cursor_close(p.cur);
    terrad_codec_free(p.codec);
    for (int i = 0; p.before && i < tiles; i++)
        free(p.before[i]);
    free(p.before);
    free(p.boxes);
    free(p.versions);
    hub_worlds_release(j->table, j->entry); /* its base and history are no longer read */
    pthread_mutex_lock(&j->lock);
    j->finished = 1;
    pthread_mutex_unlock(&j->lock);
    atomic_fetch_sub(&running, 1);
    metrics_set_spectators(atomic_load(&running));
    net_server_wake(j->server);
    return NULL;
}

/* ---- the net thread's side ---- */

static void spectator_free(net_spectator *j)
{
    pthread_join(j->thread, NULL);
    for (int i = 0; i < j->box.n; i++)
        hub_frame_unref(j->box.frames[i]);
    free(j->box.frames);
    cJSON_Delete(j->ref);
    pthread_mutex_destroy(&j->lock);
    pthread_cond_destroy(&j->cond);
    free(j);
}

static void cancel(net_spectator *j)
{
    pthread_mutex_lock(&j->lock);
    j->cancelled = 1;
    pthread_cond_signal(&j->cond);
    pthread_mutex_unlock(&j->lock);
}

/* The client no longer watches: its thread is told to stop and joined once
 * it has (on the state's list until then: net_spectate_pump reaps it). */
static void let_go(net_client *c)
{
    net_spectator *j = c->spectate;
    if (!j)
        return;
    c->spectate = NULL;
    cancel(j);
    j->next = c->srv->spectators_gone;
    c->srv->spectators_gone = j;
}

void net_spectate_drop(net_client *c)
{
    let_go(c);
}

int net_spectating(const net_client *c)
{
    return c->spectate != NULL;
}

static void refuse(net_client *c, const cJSON *ref, int code, const char *field, const char *fmt,
                   ...) __attribute__((format(printf, 5, 6)));
static void refuse(net_client *c, const cJSON *ref, int code, const char *field, const char *fmt,
                   ...)
{
    char msg[600];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    metrics_count_spectate_refused(field);
    net_error(c, code, ref, -1, 0, "%s", msg);
}

/* The request's checks that need the connection and the world (the parser
 * checked its fields): 0, or -1 refused. */
static int refused(net_client *c, const net_control *m)
{
    net_state *w = c->srv;
    const net_limits *l = &w->cfg.limits;
    if (c->spectate) {
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "state",
               "type: this connection is already spectating (spectate_stop first)");
    } else if (c->sub_count) {
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "state",
               "type: this connection has %d live subscription(s); a spectator holds none "
               "(unsubscribe first, or spectate on another connection)",
               c->sub_count);
    } else if (!w->entry || !w->entry->history || !w->entry->base || w->relay || !w->cfg.worlds) {
        /* a relayed client's spectate is its owner's (c->remote here): its
         * frames go back through the relay as any reply does */
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "from_tick",
               "from_tick: this world keeps no log to replay (a memory-only world)");
    } else if (m->from_tick > hub_published_tick(w->entry->h)) {
        /* the published tick, not w->tick (the frames this thread has
         * dispatched, held back under group:MS): a tick /v1/stats or a read
         * named is never in the future here */
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "from_tick",
               "from_tick: %llu is in the future (the world is at tick %llu)",
               (unsigned long long)m->from_tick,
               (unsigned long long)hub_published_tick(w->entry->h));
    } else if ((int64_t)m->rect.w * m->rect.h > l->max_subscribed_cells) {
        refuse(c, m->ref, TERRAD_E_LIMIT_SUBSCRIPTIONS, "w",
               "w: %lld cells pass max_subscribed_cells (%lld)", (long long)m->rect.w * m->rect.h,
               (long long)l->max_subscribed_cells);
    } else if (atomic_fetch_add(&running, 1) >= l->max_spectators) {
        atomic_fetch_sub(&running, 1); /* each thread holds a rebuild's memory: a limit */
        refuse(c, m->ref, TERRAD_E_TOO_LARGE, "busy",
               "type: max_spectators (%d) spectators already replay in this daemon; retry later",
               l->max_spectators);
    } else {
        return 0;
    }
    return -1;
}

void net_spectate_request(net_client *c, const net_control *m)
{
    net_state *w = c->srv;
    if (refused(c, m) != 0)
        return;
    /* the thread's hold on the world: a world leaving meanwhile is out of the table */
    hub_world *e = hub_worlds_acquire(w->cfg.worlds, w->entry->name);
    if (e != w->entry) {
        if (e)
            hub_worlds_release(w->cfg.worlds, e);
        atomic_fetch_sub(&running, 1);
        refuse(c, m->ref, TERRAD_E_SHUTTING_DOWN, "state",
               "type: world %s is leaving this server (deleted, or stopping)", w->entry->name);
        return;
    }
    net_spectator *j = calloc(1, sizeof *j);
    if (!j) {
        hub_worlds_release(w->cfg.worlds, e);
        atomic_fetch_sub(&running, 1);
        refuse(c, m->ref, TERRAD_E_INTERNAL, "busy", "type: out of memory");
        return;
    }
    j->table = w->cfg.worlds;
    j->entry = e;
    j->history = *(const store_history *)w->entry->history;
    j->base = w->entry->base;
    j->rect = m->rect;
    j->from = m->from_tick;
    j->speed = m->speed;
    j->stepping = m->stepping;
    j->tick_hz = w->cfg.world.tick_hz > 0 ? w->cfg.world.tick_hz : 60;
    j->tile = w->cfg.world.tile_size;
    j->width = w->cfg.world.width;
    j->height = w->cfg.world.height;
    j->room = w->cfg.limits.max_pending_bytes;
    j->server = w->server;
    j->id = ++w->spectate_ids;
    j->ref = m->ref ? cJSON_Duplicate(m->ref, 1) : NULL;
    j->live_tick = w->tick;
    pthread_mutex_init(&j->lock, NULL);
    pthread_cond_init(&j->cond, NULL);
    if (pthread_create(&j->thread, NULL, spectate_main, j) != 0) {
        hub_worlds_release(j->table, j->entry);
        atomic_fetch_sub(&running, 1);
        cJSON_Delete(j->ref);
        pthread_mutex_destroy(&j->lock);
        pthread_cond_destroy(&j->cond);
        free(j);
        refuse(c, m->ref, TERRAD_E_INTERNAL, "busy", "type: no thread for the replay");
        return;
    }
    metrics_set_spectators(atomic_load(&running));
    c->spectate = j;
}

void net_spectate_step(net_client *c, const net_control *m)
{
    net_spectator *j = c->spectate;
    if (!j || !j->stepping) {
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "state",
               "type: spectate_step needs a spectate with \"step\": true on this connection");
        return;
    }
    pthread_mutex_lock(&j->lock);
    j->steps += (uint64_t)m->step_ticks;
    pthread_cond_signal(&j->cond);
    pthread_mutex_unlock(&j->lock);
}

static void send_end(net_client *c, const net_spectator *j, const char *reason, uint64_t tick,
                     const char *why, const cJSON *ref)
{
    cJSON *msg = cJSON_CreateObject();
    cJSON_AddStringToObject(msg, "type", "spectate_end");
    cJSON_AddItemToObject(msg, "ref", net_ref_copy(ref));
    cJSON_AddNumberToObject(msg, "id", j->id);
    cJSON_AddStringToObject(msg, "reason", reason);
    cJSON_AddNumberToObject(msg, "tick", (double)tick);
    if (why && why[0])
        cJSON_AddStringToObject(msg, "message", why);
    net_send_json(c, msg);
}

void net_spectate_stop(net_client *c, const net_control *m)
{
    net_spectator *j = c->spectate;
    if (!j) {
        refuse(c, m->ref, TERRAD_E_BAD_VALUE, "state",
               "type: spectate_stop: this connection is not spectating");
        return;
    }
    pthread_mutex_lock(&j->lock);
    uint64_t at = j->at_tick;
    pthread_mutex_unlock(&j->lock);
    send_end(c, j, "stopped", at, "", m->ref);
    let_go(c); /* what its outbox still holds is not sent */
}

static void tell_started(net_client *c, net_spectator *j)
{
    cJSON *rep = cJSON_CreateObject();
    cJSON_AddStringToObject(rep, "type", "spectating");
    cJSON_AddItemToObject(rep, "ref", net_ref_copy(j->ref));
    cJSON_AddNumberToObject(rep, "id", j->id);
    cJSON_AddNumberToObject(rep, "x", j->rect.x);
    cJSON_AddNumberToObject(rep, "y", j->rect.y);
    cJSON_AddNumberToObject(rep, "w", j->rect.w);
    cJSON_AddNumberToObject(rep, "h", j->rect.h);
    cJSON_AddNumberToObject(rep, "from_tick", (double)j->from);
    cJSON_AddNumberToObject(rep, "live_tick", (double)c->srv->tick);
    if (j->stepping)
        cJSON_AddTrueToObject(rep, "step");
    else
        cJSON_AddNumberToObject(rep, "speed", j->speed);
    net_send_json(c, rep);
    j->told = 1;
}

/* One client's outbox into its queue, as far as its queue bound and budget
 * allow; its end told once the outbox is empty. */
static void pump_client(net_client *c)
{
    net_spectator *j = c->spectate;
    size_t room = c->srv->cfg.limits.max_pending_bytes;
    pthread_mutex_lock(&j->lock);
    j->live_tick = c->srv->tick;
    if (j->started && !j->told)
        tell_started(c, j);
    int taken = 0;
    while (taken < j->box.n && !c->killed) {
        hub_frame *f = j->box.frames[taken];
        if ((c->pending_bytes + f->len > room && c->q_count) || !net_budget_fits_held(c, f->len))
            break;
        size_t len = f->len; /* a remote client's frame is sent and let go at once */
        net_enqueue_held(c, f);
        j->box.bytes -= len;
        taken++;
    }
    if (taken) { /* box.frames is NULL until the thread posts its first frame */
        memmove(j->box.frames, j->box.frames + taken,
                (size_t)(j->box.n - taken) * sizeof *j->box.frames);
        j->box.n -= taken;
    }
    j->client_bytes = c->pending_bytes;
    int done = j->ended && j->box.n == 0;
    pthread_cond_signal(&j->cond);
    pthread_mutex_unlock(&j->lock);
    if (!done)
        return;
    if (j->end_code) {
        metrics_count_spectate_refused("from_tick");
        int gone = strcmp(j->end_reason, "gone") == 0;
        net_error(c, j->end_code, j->ref, -1, 0, "from_tick: tick %llu %s%s: %.400s",
                  (unsigned long long)j->from,
                  gone ? "is no longer held (the log before a newer tile snapshot was compacted "
                         "away"
                       : "cannot be rebuilt",
                  !gone            ? ""
                  : j->history.dir ? "; keep more with --replay-retain-bytes)"
                                   : ")",
                  j->end_why);
    } else {
        send_end(c, j, j->end_reason, j->at_tick, j->end_why, j->ref);
    }
    let_go(c);
}

void net_spectate_pump(net_state *w)
{
    for (int i = 0; i < w->nclients; i++)
        if (w->clients[i]->spectate)
            pump_client(w->clients[i]);
    for (net_spectator **at = &w->spectators_gone; *at;) {
        net_spectator *j = *at;
        pthread_mutex_lock(&j->lock);
        int finished = j->finished;
        pthread_mutex_unlock(&j->lock);
        if (finished) {
            *at = j->next;
            spectator_free(j);
        } else {
            at = &j->next;
        }
    }
}

void net_spectate_leave(net_state *w, net_state *lobby)
{
    for (int i = 0; i < w->nclients; i++)
        let_go(w->clients[i]);
    net_spectator **tail = &lobby->spectators_gone;
    while (*tail)
        tail = &(*tail)->next;
    *tail = w->spectators_gone; /* reaped by the lobby's net_spectate_pump */
    w->spectators_gone = NULL;
}

void net_spectate_join_all(net_state *w)
{
    for (int i = 0; i < w->nclients; i++)
        let_go(w->clients[i]);
    while (w->spectators_gone) {
        net_spectator *j = w->spectators_gone;
        w->spectators_gone = j->next;
        spectator_free(j); /* cancelled: joined once its rebuild or wait ends */
    }
}
