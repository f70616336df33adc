/*
 * hub_worlds.c: the one table of the worlds served here (hub.h), which the
 * HTTP threads and the net thread both read. A world's host adds it once it
 * serves and removes it once it stops ticking it (host/host_world.c); nothing
 * of a tick goes through here — a request or a hello looks a world up, then
 * talks to its hub. Before issue 29 http/ and net/ each kept a table of their
 * own and removal waited for one, then the other.
 *
 * An entry lives in a slot the table allocates. Adding it waits until the
 * net thread holds it (so a hello right after finds it). Removal takes it out
 * of the array at once (nobody new finds it) and waits for its readers (HTTP
 * requests, whose reads fail fast once the hub's reads are closed, and
 * spectators' replay threads, which see the entry leaving themselves,
 * hub_worlds_leaving, between two records of their rebuild or replay, and
 * end) and for its holder (the net thread, which detaches the world's
 * clients between two callbacks: 10 s, after which the slot is left to
 * whoever lets go of it last).
 *
 * The readers' wait has a bound, HUB_WORLDS_READER_DEADLINE_MS, but only for
 * saying so: a reader still using the entry then is logged (the world, how
 * many) and counted (terrad_world_readers_overdue_total), and the removal
 * waits on, logging again once they let go. It cannot return instead: the
 * readers point into the world itself (its hub, base terrain, status and
 * data directory: hub_world's fields), which its host frees as soon as this
 * returns (host_world.c, world_unregister then host_sim_free), so returning
 * would hand them freed memory. Leaving the world to its last reader, as the
 * slot is left to the holder, would take the host's whole world (its GL
 * context is current on one worker only) and the registry's record of it
 * out of the host's hands: not done. What can be cancelled is: spectators
 * ask hub_worlds_leaving and HTTP past-tick rebuilds hub_reads_closed
 * between two records, HTTP height reads and edits fail on the closed hub.
 * So one past the bound is a bug or a stalled disk, and the count is how an
 * operator finds it (a delete that does not answer, one sim worker busy
 * with the world's end). The default
 * world is no entry apart: it is the one the default name names (a single
 * daemon's scene), or the first (a cluster node). One mutex, held for a copy
 * or a scan, and while the watcher (the net thread's waker: a short lock of
 * its own) is told.
 */
#include "hub/hub.h"

#include <pthread.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "metrics/metrics.h"

#define HOLDER_DEADLINE_MS 10000.0 /* then the net thread is left behind */
#define REWAKE_MS 50               /* the watcher is nudged again while a removal waits */

typedef struct slot {
    hub_world w;     /* first: a hub_world * is its slot */
    int readers;     /* HTTP requests using it */
    int held;        /* the net thread made a world state for it */
    atomic_int gone; /* out of the table; its holder lets go (hub_worlds_leaving reads it) */
    int left;        /* its remover gave up waiting: the last to let go frees it */
} slot;

struct hub_worlds {
    pthread_mutex_t lock;
    pthread_cond_t cond;
    slot *in[HUB_WORLDS_MAX]; /* in the order added */
    int n;
    slot *leaving[HUB_WORLDS_MAX]; /* removed, still held */
    int nleaving;                  /* n + nleaving <= HUB_WORLDS_MAX (hub_worlds_add) */
    atomic_uint generation;
    char default_name[HUB_WORLD_NAME_MAX + 1]; /* "": the first entry is the default */
    void (*changed)(void *ctx);
    void *changed_ctx;
};

hub_worlds *hub_worlds_create(void)
{
    hub_worlds *t = calloc(1, sizeof *t);
    if (!t)
        return NULL;
    pthread_mutex_init(&t->lock, NULL);
    pthread_cond_init(&t->cond, NULL);
    return t;
}

void hub_worlds_destroy(hub_worlds *t)
{
    if (!t)
        return;
    for (int i = 0; i < t->n; i++)
        free(t->in[i]);
    for (int i = 0; i < t->nleaving; i++)
        free(t->leaving[i]);
    pthread_mutex_destroy(&t->lock);
    pthread_cond_destroy(&t->cond);
    free(t);
}

void hub_worlds_watch(hub_worlds *t, void (*changed)(void *ctx), void *ctx)
{
    pthread_mutex_lock(&t->lock);
    t->changed = changed;
    t->changed_ctx = ctx;
    pthread_mutex_unlock(&t->lock);
}

/* Under the lock (so that once hub_worlds_watch returns, the old watcher is
 * never called again): the generation moves, the watcher is told. */
static void changed_locked(hub_worlds *t)
{
    atomic_fetch_add(&t->generation, 1u);
    if (t->changed)
        t->changed(t->changed_ctx);
}

static void wait_until(pthread_cond_t *cond, pthread_mutex_t *lock, int ms)
{
    struct timespec until = time_after_ms(CLOCK_REALTIME, ms);
    pthread_cond_timedwait(cond, lock, &until);
}

hub_world *hub_worlds_add(hub_worlds *t, const hub_world *w, error_text *err)
{
    slot *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "worlds: out of memory");
        return NULL;
    }
    s->w = *w;
    s->w.deleted = 0;
    pthread_mutex_lock(&t->lock);
    /* an entry still leaving counts: removal moves an entry from in[] to
     * leaving[], so leaving[] never overflows (an entry left out of it would
     * never be detached by the net thread, and would leak) */
    int full = t->n + t->nleaving >= HUB_WORLDS_MAX, leaving = t->nleaving;
    if (!full) {
        t->in[t->n++] = s;
        changed_locked(t);
    }
    double start = time_now_ms();
    while (!full && t->changed && !s->held && time_now_ms() - start < HOLDER_DEADLINE_MS) {
        wait_until(&t->cond, &t->lock, REWAKE_MS);
        if (t->changed && !s->held)
            t->changed(t->changed_ctx);
    }
    pthread_mutex_unlock(&t->lock);
    if (full) {
        error_set(err, "worlds: this node already serves %d worlds (%d of them still leaving)",
                  HUB_WORLDS_MAX, leaving);
        free(s);
        return NULL;
    }
    return &s->w;
}

static void drop_leaving(hub_worlds *t, slot *s)
{
    for (int i = 0; i < t->nleaving; i++)
        if (t->leaving[i] == s) {
            t->leaving[i] = t->leaving[--t->nleaving];
            return;
        }
}

int hub_worlds_remove(hub_worlds *t, hub_world *w, int deleted)
{
    slot *s = (slot *)w;
    pthread_mutex_lock(&t->lock);
    for (int i = 0; i < t->n; i++)
        if (t->in[i] == s) { /* out of the table first: no new request or hello finds it */
            memmove(&t->in[i], &t->in[i + 1], (size_t)(t->n - i - 1) * sizeof *t->in);
            t->n--;
            break;
        }
    s->w.deleted = deleted;
    s->gone = 1;
    if (s->held) /* room: it was counted in n (hub_worlds_add) */
        t->leaving[t->nleaving++] = s;
    changed_locked(t);
    double start = time_now_ms();
    int overdue = 0; /* readers still using it at the readers' deadline */
    while (s->readers > 0 || s->held) {
        double waited = time_now_ms() - start;
        if (s->held && s->readers == 0 && waited >= HOLDER_DEADLINE_MS)
            break;
        if (s->readers > 0 && !overdue && waited >= HUB_WORLDS_READER_DEADLINE_MS) {
            overdue = s->readers; /* said once; the wait goes on (the top of this file) */
            metrics_count_world_readers_overdue((uint64_t)overdue);
            pthread_mutex_unlock(&t->lock); /* a log that blocks must not block the table */
            log_error("worlds: %d reader%s (HTTP requests, spectators' replays) of world %s "
                      "still use it %.0f s after its removal began; waiting on, since what "
                      "they read is freed after",
                      overdue, overdue == 1 ? "" : "s", s->w.name,
                      HUB_WORLDS_READER_DEADLINE_MS / 1000.0);
            pthread_mutex_lock(&t->lock);
            continue;
        }
        wait_until(&t->cond, &t->lock, REWAKE_MS);
        if (s->held && t->changed)
            t->changed(t->changed_ctx); /* the holder may be asleep between callbacks */
    }
    int stuck = s->held;
    if (stuck)
        s->left = 1; /* hub_worlds_let_go frees it */
    /* the name for the lines below, copied while s is surely ours: once the
     * lock is let go a stuck holder's hub_worlds_let_go may free s at once */
    char name[sizeof s->w.name];
    memcpy(name, s->w.name, sizeof name);
    pthread_mutex_unlock(&t->lock);
    if (overdue)
        log_info("worlds: the readers of world %s let go %.1f s after its removal began", name,
                 (time_now_ms() - start) / 1000);
    if (stuck) {
        log_error("worlds: the websocket thread did not let go of world %s within %.0f s", name,
                  HOLDER_DEADLINE_MS / 1000);
        return -1;
    }
    free(s);
    return 0;
}

void hub_worlds_set_default(hub_worlds *t, const char *name)
{
    pthread_mutex_lock(&t->lock);
    snprintf(t->default_name, sizeof t->default_name, "%s", name ? name : "");
    pthread_mutex_unlock(&t->lock);
}

int hub_worlds_default(hub_worlds *t, char *name, size_t cap)
{
    pthread_mutex_lock(&t->lock);
    snprintf(name, cap, "%s", t->default_name);
    int set = t->default_name[0] != 0;
    pthread_mutex_unlock(&t->lock);
    return set;
}

hub_world *hub_worlds_acquire(hub_worlds *t, const char *name)
{
    pthread_mutex_lock(&t->lock);
    if (!name && t->default_name[0])
        name = t->default_name;
    slot *found = NULL;
    for (int i = 0; i < t->n && !found; i++)
        if (!name || strcmp(t->in[i]->w.name, name) == 0)
            found = t->in[i];
    if (found)
        found->readers++;
    pthread_mutex_unlock(&t->lock);
    return found ? &found->w : NULL;
}

int hub_worlds_leaving(const hub_world *w)
{
    return atomic_load(&((slot *)(uintptr_t)w)->gone);
}

void hub_worlds_release(hub_worlds *t, hub_world *w)
{
    slot *s = (slot *)w;
    pthread_mutex_lock(&t->lock);
    if (--s->readers == 0)
        pthread_cond_broadcast(&t->cond);
    pthread_mutex_unlock(&t->lock);
}

int hub_worlds_names(hub_worlds *t, char *out, size_t cap)
{
    if (cap)
        out[0] = 0;
    pthread_mutex_lock(&t->lock);
    int n = t->n;
    size_t at = 0;
    for (int i = 0; i < n && at < cap; i++)
        at += (size_t)snprintf(out + at, cap - at, "%s\"%s\"", i ? ", " : "", t->in[i]->w.name);
    pthread_mutex_unlock(&t->lock);
    return n;
}

unsigned hub_worlds_generation(hub_worlds *t)
{
    return atomic_load(&t->generation);
}

hub_world *hub_worlds_hold_next(hub_worlds *t)
{
    pthread_mutex_lock(&t->lock);
    slot *found = NULL;
    for (int i = 0; i < t->n && !found; i++)
        if (!t->in[i]->held)
            found = t->in[i];
    if (found) {
        found->held = 1;
        pthread_cond_broadcast(&t->cond); /* its add may be waiting for this */
    }
    pthread_mutex_unlock(&t->lock);
    return found ? &found->w : NULL;
}

hub_world *hub_worlds_gone_next(hub_worlds *t)
{
    pthread_mutex_lock(&t->lock);
    slot *found = t->nleaving ? t->leaving[0] : NULL;
    pthread_mutex_unlock(&t->lock);
    return found ? &found->w : NULL;
}

void hub_worlds_let_go(hub_worlds *t, hub_world *w)
{
    slot *s = (slot *)w;
    pthread_mutex_lock(&t->lock);
    s->held = 0;
    if (s->gone)
        drop_leaving(t, s);
    int free_it = s->left && s->readers == 0;
    pthread_cond_broadcast(&t->cond);
    pthread_mutex_unlock(&t->lock);
    if (free_it)
        free(s);
}
