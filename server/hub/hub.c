/*
 * hub.c: bounded queues and tables between the network, HTTP and sim
 * threads (see hub.h, whose top comment lists every meeting point of the
 * daemon's threads). Each structure has its own mutex, held only for
 * copies, so the threads never wait on each other's work; each end asserts
 * the thread that owns it (THREAD_OWNED, in debug and sanitizer builds).
 */
#include "hub/hub.h"

#include <errno.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "base/base.h"
#include "terrad_proto.h"

#define HUB_COMMAND_CAPACITY 4096
#define HUB_POSE_CAPACITY 65536
#define HUB_POSE_SLOTS (HUB_POSE_CAPACITY * 2)
#define HUB_OUT_CAPACITY 65536
#define HUB_MAX_READS 32

typedef struct hub_read {
    world_rect rect;
    hub_layer layer;
    int32_t *out;
    uint64_t tick;
    int active, done;
} hub_read;

struct hub {
    thread_owner sim_end, net_end; /* claimed by each side's thread (hub_claim_*) */
    pthread_mutex_t command_lock;
    hub_command *commands;
    int command_head, command_count;
    char edits_closed[256]; /* hub_close_edits: why edits are refused now ("" while open) */

    pthread_mutex_t pose_lock;
    hub_pose *poses; /* pending, in arrival order of first set */
    int pose_count;
    int32_t *slots; /* open addressing: collider -> index + 1 into poses */

    hub_batch *batches; /* one per client with a batch since the last take */
    int batch_count;

    pthread_mutex_t out_lock;
    hub_out *out;
    int out_head, out_count;
    int overflow;
    void (*wake)(void *);
    void *wake_arg;

    _Atomic uint64_t published_tick; /* hub_publish_tick */
    pthread_mutex_t read_lock;
    pthread_cond_t read_done;
    hub_read reads[HUB_MAX_READS];
    int reads_closed;

    char store_unavailable[256]; /* "" while the store is writable; under out_lock */

    pthread_mutex_t step_lock;
    hub_step steps[HUB_STEP_CAPACITY];
    int step_head, step_count;
    void (*step_notify)(void *arg, uint32_t ticks);
    void *step_notify_arg;
};

hub *hub_create(void)
{
    hub *h = calloc(1, sizeof *h);
    if (!h)
        return NULL;
    h->commands = calloc(HUB_COMMAND_CAPACITY, sizeof *h->commands);
    h->poses = calloc(HUB_POSE_CAPACITY, sizeof *h->poses);
    h->slots = calloc(HUB_POSE_SLOTS, sizeof *h->slots);
    h->out = calloc(HUB_OUT_CAPACITY, sizeof *h->out);
    h->batches = calloc(HUB_BATCH_CAPACITY, sizeof *h->batches);
    if (!h->commands || !h->poses || !h->slots || !h->out || !h->batches) {
        free(h->batches);
        free(h->commands);
        free(h->poses);
        free(h->slots);
        free(h->out);
        free(h);
        return NULL;
    }
    pthread_mutex_init(&h->command_lock, NULL);
    pthread_mutex_init(&h->pose_lock, NULL);
    pthread_mutex_init(&h->out_lock, NULL);
    pthread_mutex_init(&h->read_lock, NULL);
    pthread_mutex_init(&h->step_lock, NULL);
    pthread_condattr_t attr;
    pthread_condattr_init(&attr);
    pthread_condattr_setclock(&attr, CLOCK_MONOTONIC);
    pthread_cond_init(&h->read_done, &attr);
    pthread_condattr_destroy(&attr);
    return h;
}

void hub_destroy(hub *h)
{
    if (!h)
        return;
    for (int i = 0; i < h->command_count; i++) {
        hub_command *c = &h->commands[(h->command_head + i) % HUB_COMMAND_CAPACITY];
        if (c->mesh) {
            collider_mesh_free(c->mesh);
            free(c->mesh);
        }
        if (c->edit) {
            world_edit_free(c->edit);
            free(c->edit);
        }
        hub_edit_finish(c->waiter, &(hub_edit_result){.code = TERRAD_E_SHUTTING_DOWN,
                                                      .message = "the world is stopping"});
    }
    for (int i = 0; i < h->out_count; i++) {
        hub_out *o = &h->out[(h->out_head + i) % HUB_OUT_CAPACITY];
        if (o->frame)
            hub_frame_unref(o->frame);
    }
    pthread_mutex_destroy(&h->command_lock);
    pthread_mutex_destroy(&h->pose_lock);
    pthread_mutex_destroy(&h->out_lock);
    pthread_mutex_destroy(&h->read_lock);
    pthread_cond_destroy(&h->read_done);
    for (int i = 0; i < h->step_count; i++)
        hub_step_free(&h->steps[(h->step_head + i) % HUB_STEP_CAPACITY]);
    pthread_mutex_destroy(&h->step_lock);
    free(h->commands);
    free(h->poses);
    free(h->slots);
    free(h->out);
    free(h->batches);
    free(h);
}

/* ---- commands ---- */

void hub_claim_sim_end(hub *h)
{
    thread_owner_claim(&h->sim_end, "sim");
}

void hub_claim_net_end(hub *h)
{
    thread_owner_claim(&h->net_end, "net");
}

void hub_release_net_end(hub *h)
{
    thread_owner_release(&h->net_end);
}

int hub_push_command(hub *h, const hub_command *cmd)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->command_lock);
    if (h->command_count == HUB_COMMAND_CAPACITY) {
        pthread_mutex_unlock(&h->command_lock);
        return -1;
    }
    h->commands[(h->command_head + h->command_count) % HUB_COMMAND_CAPACITY] = *cmd;
    h->command_count++;
    pthread_mutex_unlock(&h->command_lock);
    return 0;
}

/* ---- steps ---- */

void hub_step_free(hub_step *st)
{
    free(st->poses);
    st->poses = NULL;
}

int hub_push_step(hub *h, hub_step *st)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->step_lock);
    if (h->step_count == HUB_STEP_CAPACITY) {
        pthread_mutex_unlock(&h->step_lock);
        return -1;
    }
    h->steps[(h->step_head + h->step_count) % HUB_STEP_CAPACITY] = *st;
    h->step_count++;
    void (*fn)(void *, uint32_t) = h->step_notify;
    void *arg = h->step_notify_arg;
    pthread_mutex_unlock(&h->step_lock);
    st->poses = NULL;
    if (fn) /* outside the lock: it takes the clock's own */
        fn(arg, st->ticks);
    return 0;
}

int hub_take_step(hub *h, hub_step *out)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->step_lock);
    int n = h->step_count > 0;
    if (n) {
        *out = h->steps[h->step_head];
        h->step_head = (h->step_head + 1) % HUB_STEP_CAPACITY;
        h->step_count--;
    }
    pthread_mutex_unlock(&h->step_lock);
    return n;
}

void hub_set_step_notify(hub *h, void (*fn)(void *arg, uint32_t ticks), void *arg)
{
    pthread_mutex_lock(&h->step_lock);
    h->step_notify = fn;
    h->step_notify_arg = arg;
    pthread_mutex_unlock(&h->step_lock);
}

/* ---- http → sim: edits ---- */

/* Shared by the HTTP thread and the sim thread: the last to let go frees it. */
struct hub_edit_waiter {
    pthread_mutex_t lock;
    pthread_cond_t done_cond;
    int done, refs;
    hub_edit_result result;
};

static void waiter_unref(hub_edit_waiter *w)
{
    pthread_mutex_lock(&w->lock);
    int last = --w->refs == 0;
    pthread_mutex_unlock(&w->lock);
    if (last) {
        pthread_mutex_destroy(&w->lock);
        pthread_cond_destroy(&w->done_cond);
        free(w);
    }
}

void hub_edit_finish(hub_edit_waiter *w, const hub_edit_result *res)
{
    if (!w)
        return;
    pthread_mutex_lock(&w->lock);
    w->result = *res;
    w->done = 1;
    pthread_cond_signal(&w->done_cond);
    pthread_mutex_unlock(&w->lock);
    waiter_unref(w);
}

int hub_edit_submit(hub *h, world_edit *e, hub_edit_result *res, int timeout_ms)
{
    hub_edit_waiter *w = calloc(1, sizeof *w);
    if (!w) {
        world_edit_free(e);
        free(e);
        snprintf(res->message, sizeof res->message, "out of memory");
        return -1;
    }
    pthread_mutex_init(&w->lock, NULL);
    pthread_condattr_t attr;
    pthread_condattr_init(&attr);
    pthread_condattr_setclock(&attr, CLOCK_MONOTONIC);
    pthread_cond_init(&w->done_cond, &attr);
    pthread_condattr_destroy(&attr);
    w->refs = 2; /* this thread's and the command's */
    pthread_mutex_lock(&h->command_lock);
    if (h->edits_closed[0]) { /* the world stops: no tick will take it */
        *res = (hub_edit_result){.code = TERRAD_E_SHUTTING_DOWN};
        snprintf(res->message, sizeof res->message, "%s", h->edits_closed);
        pthread_mutex_unlock(&h->command_lock);
        world_edit_free(e);
        free(e);
        w->refs = 1;
        waiter_unref(w);
        return 0;
    }
    int full = h->command_count == HUB_COMMAND_CAPACITY;
    if (!full) {
        h->commands[(h->command_head + h->command_count) % HUB_COMMAND_CAPACITY] =
            (hub_command){.kind = HUB_EDIT, .edit = e, .waiter = w};
        h->command_count++;
    }
    pthread_mutex_unlock(&h->command_lock);
    if (full) {
        world_edit_free(e);
        free(e);
        w->refs = 1;
        waiter_unref(w);
        snprintf(res->message, sizeof res->message,
                 "server busy: the simulation's command queue is full, try again");
        return -1;
    }
    struct timespec until = time_after_ms(CLOCK_MONOTONIC, timeout_ms);
    pthread_mutex_lock(&w->lock);
    while (!w->done && pthread_cond_timedwait(&w->done_cond, &w->lock, &until) == 0)
        ;
    int done = w->done;
    if (done)
        *res = w->result;
    pthread_mutex_unlock(&w->lock);
    waiter_unref(w);
    return done ? 0 : 1;
}

void hub_close_edits(hub *h, const char *why)
{
    hub_edit_result res = {.code = TERRAD_E_SHUTTING_DOWN};
    snprintf(res.message, sizeof res.message, "%s", why);
    pthread_mutex_lock(&h->command_lock);
    snprintf(h->edits_closed, sizeof h->edits_closed, "%s", why);
    for (int i = 0; i < h->command_count; i++) {
        hub_command *c = &h->commands[(h->command_head + i) % HUB_COMMAND_CAPACITY];
        if (c->kind == HUB_EDIT && c->waiter) {
            hub_edit_finish(c->waiter, &res); /* its HTTP thread answers now, not at 10 s */
            c->waiter = NULL;
        }
    }
    pthread_mutex_unlock(&h->command_lock);
}

int hub_take_commands(hub *h, hub_command *out, int max)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->command_lock);
    int n = h->command_count < max ? h->command_count : max;
    for (int i = 0; i < n; i++)
        out[i] = h->commands[(h->command_head + i) % HUB_COMMAND_CAPACITY];
    h->command_head = (h->command_head + n) % HUB_COMMAND_CAPACITY;
    h->command_count -= n;
    pthread_mutex_unlock(&h->command_lock);
    return n;
}

/* ---- poses ---- */

static uint32_t slot_of(uint32_t collider)
{
    uint32_t x = collider * 0x9e3779b1u;
    return (x ^ (x >> 15)) & (HUB_POSE_SLOTS - 1);
}

/* Index + 1 of the collider's pending pose, 0 if none; *slot receives where
 * it is or where it would go. */
static int32_t pose_find(const hub *h, uint32_t collider, uint32_t *slot)
{
    uint32_t s = slot_of(collider);
    while (h->slots[s] != 0) {
        if (h->poses[h->slots[s] - 1].collider == collider) {
            *slot = s;
            return h->slots[s];
        }
        s = (s + 1) & (HUB_POSE_SLOTS - 1);
    }
    *slot = s;
    return 0;
}

/* Latest wins per collider; the caller holds pose_lock. */
static int store_pose_locked(hub *h, const hub_pose *pose_in, double now_ms)
{
    hub_pose pose = *pose_in;
    pose.received_ms = now_ms;
    uint32_t slot;
    int32_t at = pose_find(h, pose.collider, &slot);
    if (at) {
        h->poses[at - 1] = pose;
    } else if (h->pose_count < HUB_POSE_CAPACITY) {
        h->poses[h->pose_count] = pose;
        h->slots[slot] = ++h->pose_count;
    } else {
        return -1;
    }
    return 0;
}

/* Latest wins per client; the caller holds pose_lock. */
static void note_batch_locked(hub *h, uint32_t client, uint32_t sequence)
{
    int i = 0;
    while (i < h->batch_count && h->batches[i].client != client)
        i++;
    if (i < h->batch_count)
        h->batches[i].sequence = sequence;
    else if (h->batch_count < HUB_BATCH_CAPACITY)
        h->batches[h->batch_count++] = (hub_batch){client, sequence};
}

int hub_set_pose(hub *h, const hub_pose *pose)
{
    THREAD_OWNED(&h->net_end);
    double now = time_now_ms();
    pthread_mutex_lock(&h->pose_lock);
    int rc = store_pose_locked(h, pose, now);
    pthread_mutex_unlock(&h->pose_lock);
    return rc;
}

int hub_set_batch(hub *h, uint32_t client, uint32_t sequence, const hub_pose *poses, int n)
{
    THREAD_OWNED(&h->net_end);
    double now = time_now_ms();
    pthread_mutex_lock(&h->pose_lock);
    int stored = 0;
    while (stored < n && store_pose_locked(h, &poses[stored], now) == 0)
        stored++;
    note_batch_locked(h, client, sequence);
    pthread_mutex_unlock(&h->pose_lock);
    return stored;
}

/* Rebuild the slot table after removing entries (cheap: only pending poses). */
static void pose_reindex(hub *h)
{
    memset(h->slots, 0, HUB_POSE_SLOTS * sizeof *h->slots);
    for (int i = 0; i < h->pose_count; i++) {
        uint32_t slot;
        pose_find(h, h->poses[i].collider, &slot);
        h->slots[slot] = i + 1;
    }
}

void hub_forget_pose(hub *h, uint32_t collider)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->pose_lock);
    uint32_t slot;
    int32_t at = pose_find(h, collider, &slot);
    if (at) {
        h->poses[at - 1] = h->poses[--h->pose_count];
        pose_reindex(h);
    }
    pthread_mutex_unlock(&h->pose_lock);
}

/* Every pending pose is taken: empty exactly the slots they used. Walking
 * each pose's probe run from its home slot to the first empty one clears its
 * whole cluster (every used slot lies in the run of some pose's home), so the
 * table is empty again without pose_reindex's memset of all HUB_POSE_SLOTS —
 * 512 KiB per tick per world, most of an idle world's tick (issue 22). */
static void pose_clear_slots(hub *h)
{
    for (int i = 0; i < h->pose_count; i++)
        for (uint32_t s = slot_of(h->poses[i].collider); h->slots[s] != 0;
             s = (s + 1) & (HUB_POSE_SLOTS - 1))
            h->slots[s] = 0;
}

/* The caller holds pose_lock. */
static int take_poses_locked(hub *h, hub_pose *out, int max)
{
    int n = h->pose_count < max ? h->pose_count : max;
    if (n == 0)
        return 0; /* nothing pending: the slot table is empty already */
    memcpy(out, h->poses, (size_t)n * sizeof *out);
    if (n == h->pose_count) {
        pose_clear_slots(h);
        h->pose_count = 0;
        return n;
    }
    memmove(h->poses, h->poses + n, (size_t)(h->pose_count - n) * sizeof *h->poses);
    h->pose_count -= n;
    pose_reindex(h);
    return n;
}

/* The caller holds pose_lock. */
static int take_batches_locked(hub *h, hub_batch *out, int max)
{
    int n = h->batch_count < max ? h->batch_count : max;
    memcpy(out, h->batches, (size_t)n * sizeof *out);
    memmove(h->batches, h->batches + n, (size_t)(h->batch_count - n) * sizeof *h->batches);
    h->batch_count -= n;
    return n;
}

int hub_take_poses(hub *h, hub_pose *out, int max)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->pose_lock);
    int n = take_poses_locked(h, out, max);
    pthread_mutex_unlock(&h->pose_lock);
    return n;
}

void hub_note_batch(hub *h, uint32_t client, uint32_t sequence)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->pose_lock);
    note_batch_locked(h, client, sequence);
    pthread_mutex_unlock(&h->pose_lock);
}

int hub_take_input(hub *h, hub_pose *poses, int max_poses, int *pose_count, hub_batch *batches)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->pose_lock);
    *pose_count = take_poses_locked(h, poses, max_poses);
    int n = take_batches_locked(h, batches, HUB_BATCH_CAPACITY);
    pthread_mutex_unlock(&h->pose_lock);
    return n;
}

/* ---- frames ---- */

hub_frame *hub_frame_new(int binary, size_t len)
{
    hub_frame *f = malloc(sizeof *f + HUB_FRAME_HEADROOM + len + 1);
    if (!f)
        return NULL;
    atomic_init(&f->refs, 1);
    f->binary = binary;
    f->len = len;
    f->data = f->storage + HUB_FRAME_HEADROOM;
    f->data[len] = 0;
    return f;
}

hub_frame *hub_frame_from_text(const char *text)
{
    size_t len = strlen(text);
    hub_frame *f = hub_frame_new(0, len);
    if (f)
        memcpy(f->data, text, len);
    return f;
}

void hub_frame_ref(hub_frame *f)
{
    atomic_fetch_add_explicit(&f->refs, 1, memory_order_relaxed);
}

void hub_frame_unref(hub_frame *f)
{
    if (f && atomic_fetch_sub_explicit(&f->refs, 1, memory_order_acq_rel) == 1)
        free(f);
}

/* ---- outbound ---- */

int hub_publish(hub *h, hub_out *items, int count)
{
    THREAD_OWNED(&h->sim_end);
    int dropped = 0;
    pthread_mutex_lock(&h->out_lock);
    for (int i = 0; i < count; i++) {
        if (h->out_count == HUB_OUT_CAPACITY) {
            /* Nothing may block the tick: drop, and have every client resync. */
            if (items[i].frame)
                hub_frame_unref(items[i].frame);
            h->overflow = 1;
            dropped++;
            continue;
        }
        h->out[(h->out_head + h->out_count) % HUB_OUT_CAPACITY] = items[i];
        h->out_count++;
    }
    void (*wake)(void *) = h->wake;
    void *arg = h->wake_arg;
    pthread_mutex_unlock(&h->out_lock);
    if (wake)
        wake(arg);
    return dropped;
}

int hub_take_outbound(hub *h, hub_out *out, int max)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->out_lock);
    int n = h->out_count < max ? h->out_count : max;
    for (int i = 0; i < n; i++)
        out[i] = h->out[(h->out_head + i) % HUB_OUT_CAPACITY];
    h->out_head = (h->out_head + n) % HUB_OUT_CAPACITY;
    h->out_count -= n;
    pthread_mutex_unlock(&h->out_lock);
    return n;
}

int hub_take_overflow(hub *h)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->out_lock);
    int o = h->overflow;
    h->overflow = 0;
    pthread_mutex_unlock(&h->out_lock);
    return o;
}

void hub_set_waker(hub *h, void (*wake)(void *arg), void *arg)
{
    pthread_mutex_lock(&h->out_lock);
    h->wake = wake;
    h->wake_arg = arg;
    pthread_mutex_unlock(&h->out_lock);
}

/* ---- height reads ---- */

int hub_read_heights(hub *h, world_rect r, int32_t *out, uint64_t *tick, int timeout_ms)
{
    return hub_read_layer(h, HUB_LAYER_HEIGHTS, r, out, tick, timeout_ms);
}

int hub_read_layer(hub *h, hub_layer layer, world_rect r, int32_t *out, uint64_t *tick,
                   int timeout_ms)
{
#ifdef TERRAD_THREAD_CHECKS
    /* the sim thread serves reads between ticks: waiting here it would wait for itself */
    if (h->sim_end.tid && h->sim_end.tid == (unsigned long)pthread_self()) {
        log_error("hub_read_heights: called from the sim thread, which serves the reads");
        abort();
    }
#endif
    struct timespec deadline = time_after_ms(CLOCK_MONOTONIC, timeout_ms);
    pthread_mutex_lock(&h->read_lock);
    hub_read *slot = NULL;
    for (int i = 0; i < HUB_MAX_READS && !slot; i++)
        if (!h->reads[i].active)
            slot = &h->reads[i];
    if (!slot || h->reads_closed) {
        pthread_mutex_unlock(&h->read_lock);
        return -1;
    }
    *slot = (hub_read){.rect = r, .layer = layer, .out = out, .active = 1};
    pthread_mutex_unlock(&h->read_lock);
    /* a client-clocked world may be waiting for its driver: it serves reads between steps too */
    pthread_mutex_lock(&h->step_lock);
    void (*fn)(void *, uint32_t) = h->step_notify;
    void *arg = h->step_notify_arg;
    pthread_mutex_unlock(&h->step_lock);
    if (fn)
        fn(arg, 0);
    pthread_mutex_lock(&h->read_lock);
    int rc = 0;
    while (!slot->done && !h->reads_closed) {
        if (pthread_cond_timedwait(&h->read_done, &h->read_lock, &deadline) == ETIMEDOUT) {
            rc = slot->done ? 0 : -1;
            break;
        }
    }
    if (!slot->done)
        rc = -1;
    else
        *tick = slot->tick;
    slot->active = 0; /* the sim thread will not touch `out` after this */
    pthread_mutex_unlock(&h->read_lock);
    return rc;
}

int hub_reads_pending(hub *h)
{
    pthread_mutex_lock(&h->read_lock);
    int n = 0;
    for (int i = 0; i < HUB_MAX_READS; i++)
        n += h->reads[i].active && !h->reads[i].done;
    pthread_mutex_unlock(&h->read_lock);
    return n;
}

void hub_publish_tick(hub *h, uint64_t tick)
{
    THREAD_OWNED(&h->sim_end);
    atomic_store(&h->published_tick, tick);
}

uint64_t hub_published_tick(hub *h)
{
    return atomic_load(&h->published_tick);
}

void hub_serve_reads(hub *h, const world *w, uint64_t tick)
{
    THREAD_OWNED(&h->sim_end);
#ifdef TERRAD_THREAD_CHECKS
    /* a read never names a tick before it is published (service_tick, row 9) */
    if (tick > atomic_load(&h->published_tick)) {
        log_error("hub_serve_reads: tick %llu is not published (the hub's tick is %llu)",
                  (unsigned long long)tick, (unsigned long long)atomic_load(&h->published_tick));
        abort();
    }
#endif
    pthread_mutex_lock(&h->read_lock);
    int served = 0;
    for (int i = 0; i < HUB_MAX_READS; i++) {
        hub_read *r = &h->reads[i];
        if (!r->active || r->done)
            continue;
        world_rect clipped = r->rect;
        if (world_clip_rect(w, &clipped) && clipped.x == r->rect.x && clipped.y == r->rect.y &&
            clipped.w == r->rect.w && clipped.h == r->rect.h) {
            if (r->layer == HUB_LAYER_COMPACTION)
                world_layer_gather(w, WORLD_LAYER_COMPACTION, r->rect, r->out);
            else
                world_gather_window(w, r->rect, r->out);
        } else
            memset(r->out, 0, (size_t)r->rect.w * r->rect.h * sizeof *r->out);
        r->tick = tick;
        r->done = 1;
        served++;
    }
    if (served)
        pthread_cond_broadcast(&h->read_done);
    pthread_mutex_unlock(&h->read_lock);
}

void hub_close_reads(hub *h)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->read_lock);
    h->reads_closed = 1;
    pthread_cond_broadcast(&h->read_done);
    pthread_mutex_unlock(&h->read_lock);
}

int hub_reads_closed(hub *h)
{
    pthread_mutex_lock(&h->read_lock);
    int closed = h->reads_closed;
    pthread_mutex_unlock(&h->read_lock);
    return closed;
}

void hub_set_store_unavailable(hub *h, const char *reason)
{
    THREAD_OWNED(&h->sim_end);
    pthread_mutex_lock(&h->out_lock);
    snprintf(h->store_unavailable, sizeof h->store_unavailable, "%s", reason ? reason : "");
    pthread_mutex_unlock(&h->out_lock);
}

int hub_store_unavailable(hub *h, char *reason, size_t cap)
{
    THREAD_OWNED(&h->net_end);
    pthread_mutex_lock(&h->out_lock);
    int down = h->store_unavailable[0] != 0;
    if (down && reason && cap)
        snprintf(reason, cap, "%s", h->store_unavailable);
    pthread_mutex_unlock(&h->out_lock);
    return down;
}
