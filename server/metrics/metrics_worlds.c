/*
 * metrics_worlds.c: per-world series of a cluster node (docs/cluster.md) or
 * of a single daemon's created worlds,
 * labelled world="NAME". Each world's sim thread takes a slot when it starts
 * ticking a world and sets its figures once per tick; the slot is dropped
 * (its series disappear from /metrics) when the node stops ticking the world.
 * The label set is bounded: one value per world this process ticks now, at
 * most METRICS_MAX_WORLDS (64), above any --max-worlds (a node's 64, a
 * daemon's 63 created worlds), so a create/delete loop never grows it.
 * Values are relaxed atomics like the rest of metrics/; the slot table's
 * names are under a short mutex (taken only when a world comes or goes, and
 * by the renderer). Beside them, two unlabelled-by-world counters of the
 * worlds' comings and goings: terrad_world_requests_total (the lifecycle
 * API) and terrad_world_readers_overdue_total (hub_worlds_remove).
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <string.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

typedef struct world_slot {
    int used;
    char name[65];
    _Atomic uint64_t tick, ticks;
    _Atomic int64_t volume, colliders, clients;
    _Atomic int available;
    _Atomic double last_tick_ms, commit_p50_ms, commit_p99_ms;
} world_slot;

static world_slot slots[METRICS_MAX_WORLDS];
static pthread_mutex_t slots_lock = PTHREAD_MUTEX_INITIALIZER;

static const char *const forward_results[] = {METRICS_FORWARD_RESULTS};
#define FORWARD_RESULTS (sizeof forward_results / sizeof forward_results[0])
static atomic_uint_fast64_t forwarded[FORWARD_RESULTS];

void metrics_count_http_forwarded(const char *result)
{
    int i = metrics_label_index(forward_results, (int)FORWARD_RESULTS, result);
    if (i >= 0)
        atomic_fetch_add_explicit(&forwarded[i], 1, memory_order_relaxed);
}

static const char *const request_ops[] = {"create", "delete"};
static atomic_uint_fast64_t requests[2][2]; /* [op][ok] */

void metrics_count_world_request(const char *op, int ok)
{
    int i = metrics_label_index(request_ops, 2, op);
    if (i >= 0)
        atomic_fetch_add_explicit(&requests[i][ok != 0], 1, memory_order_relaxed);
}

static atomic_uint_fast64_t readers_overdue;

void metrics_count_world_readers_overdue(uint64_t n)
{
    atomic_fetch_add_explicit(&readers_overdue, n, memory_order_relaxed);
}

/* terrad_world_requests_total: every op and result, zeros too; then
 * terrad_world_readers_overdue_total. */
static int requests_text(char *out, size_t cap, size_t *n);

int metrics_world_slot(const char *name)
{
    pthread_mutex_lock(&slots_lock);
    int free_at = -1, at = -1;
    for (int i = 0; i < METRICS_MAX_WORLDS && at < 0; i++) {
        if (slots[i].used && strcmp(slots[i].name, name) == 0)
            at = i;
        else if (!slots[i].used && free_at < 0)
            free_at = i;
    }
    if (at < 0 && free_at >= 0) {
        at = free_at;
        world_slot *w = &slots[at];
        snprintf(w->name, sizeof w->name, "%s", name);
        atomic_store(&w->tick, 0);
        atomic_store(&w->ticks, 0);
        atomic_store(&w->volume, 0);
        atomic_store(&w->colliders, 0);
        atomic_store(&w->clients, 0);
        atomic_store(&w->available, 1);
        atomic_store(&w->last_tick_ms, 0);
        atomic_store(&w->commit_p50_ms, 0);
        atomic_store(&w->commit_p99_ms, 0);
        w->used = 1;
    }
    pthread_mutex_unlock(&slots_lock);
    return at;
}

void metrics_world_drop(int slot)
{
    if (slot < 0 || slot >= METRICS_MAX_WORLDS)
        return;
    pthread_mutex_lock(&slots_lock);
    slots[slot].used = 0;
    pthread_mutex_unlock(&slots_lock);
}

void metrics_world_tick(int slot, const metrics_world_figures *f)
{
    if (slot < 0 || slot >= METRICS_MAX_WORLDS)
        return;
    world_slot *w = &slots[slot];
    atomic_store_explicit(&w->tick, f->tick, memory_order_relaxed);
    atomic_fetch_add_explicit(&w->ticks, 1, memory_order_relaxed);
    atomic_store_explicit(&w->volume, f->volume, memory_order_relaxed);
    atomic_store_explicit(&w->colliders, f->colliders, memory_order_relaxed);
    atomic_store_explicit(&w->clients, f->clients, memory_order_relaxed);
    atomic_store_explicit(&w->available, f->store_available, memory_order_relaxed);
    atomic_store_explicit(&w->last_tick_ms, f->tick_ms, memory_order_relaxed);
    atomic_store_explicit(&w->commit_p50_ms, f->commit_p50_ms, memory_order_relaxed);
    atomic_store_explicit(&w->commit_p99_ms, f->commit_p99_ms, memory_order_relaxed);
}

/* One family: HELP and TYPE, then one sample per world in use. */
static int family(char *out, size_t cap, size_t *n, const char *name, const char *type,
                  const char *help, int which)
{
    int any = 0;
    for (int i = 0; i < METRICS_MAX_WORLDS; i++)
        any |= slots[i].used;
    if (!any)
        return 0;
    if (metrics_put(out, cap, n, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type) != 0)
        return -1;
    for (int i = 0; i < METRICS_MAX_WORLDS; i++) {
        world_slot *w = &slots[i];
        if (!w->used)
            continue;
        char value[64];
        switch (which) {
        case 0:
            snprintf(value, sizeof value, "%llu", (unsigned long long)atomic_load(&w->tick));
            break;
        case 1:
            snprintf(value, sizeof value, "%llu", (unsigned long long)atomic_load(&w->ticks));
            break;
        case 2:
            snprintf(value, sizeof value, "%lld", (long long)atomic_load(&w->volume));
            break;
        case 3:
            snprintf(value, sizeof value, "%lld", (long long)atomic_load(&w->colliders));
            break;
        case 4:
            snprintf(value, sizeof value, "%d", atomic_load(&w->available));
            break;
        case 5:
            snprintf(value, sizeof value, "%.6f", atomic_load(&w->last_tick_ms) / 1000);
            break;
        case 6:
            snprintf(value, sizeof value, "%.6f", atomic_load(&w->commit_p50_ms) / 1000);
            break;
        case 7:
            snprintf(value, sizeof value, "%.6f", atomic_load(&w->commit_p99_ms) / 1000);
            break;
        default:
            snprintf(value, sizeof value, "%lld", (long long)atomic_load(&w->clients));
            break;
        }
        /* world names are [A-Za-z0-9_-]: nothing to escape in a label value */
        if (metrics_put(out, cap, n, "%s{world=\"%s\"} %s\n", name, w->name, value) != 0)
            return -1;
    }
    return 0;
}

int metrics_worlds_text(char *out, size_t cap)
{
    static const struct {
        const char *name, *type, *help;
    } families[] = {
        {"terrad_world_tick", "gauge", "The last tick of the world ticked by this node."},
        {"terrad_world_ticks_total", "counter", "Ticks this node has run of the world."},
        {"terrad_world_volume", "gauge", "Sum of the world's heights (exact integer units)."},
        {"terrad_world_colliders", "gauge", "Live colliders in the world."},
        {"terrad_world_store_available", "gauge",
         "1 while the world's ticks can be committed to JetStream, 0 while they cannot."},
        {"terrad_world_last_tick_seconds", "gauge",
         "Duration of the world's last tick (as terrad_tick_duration_seconds measures it)."},
        {"terrad_world_commit_p50_seconds", "gauge",
         "Median commit latency of the world (publish to JetStream acknowledgement)."},
        {"terrad_world_commit_p99_seconds", "gauge",
         "99th percentile commit latency of the world (publish to acknowledgement)."},
        {"terrad_world_clients", "gauge",
         "Websocket clients in the world (on a cluster, counted by the node ticking it, "
         "relayed clients included)."},
    };
    size_t n = 0;
    if (cap)
        out[0] = 0;
    pthread_mutex_lock(&slots_lock);
    int rc = 0;
    for (int f = 0; f < (int)(sizeof families / sizeof families[0]) && rc == 0; f++)
        rc = family(out, cap, &n, families[f].name, families[f].type, families[f].help, f);
    pthread_mutex_unlock(&slots_lock);
    if (rc == 0)
        rc = requests_text(out, cap, &n);
    uint64_t any = 0;
    for (size_t i = 0; i < FORWARD_RESULTS; i++)
        any += atomic_load_explicit(&forwarded[i], memory_order_relaxed);
    int node = 0; /* a cluster node: one that ticks a world now, or has forwarded */
    for (int i = 0; i < METRICS_MAX_WORLDS; i++)
        node |= slots[i].used;
    if (!node && !any)
        return rc == 0 ? (int)n : -1;
    if (rc == 0)
        rc = metrics_put_labelled(
            out, cap, &n, "terrad_http_forwarded_total",
            "HTTP requests for a world another node ticks, asked of its owner, by result.",
            "result", forward_results, (int)FORWARD_RESULTS, forwarded);
    return rc == 0 ? (int)n : -1;
}

static int requests_text(char *out, size_t cap, size_t *n)
{
    int rc =
        metrics_put(out, cap, n,
                    "# HELP terrad_world_requests_total World lifecycle requests (POST /v1/worlds, "
                    "DELETE /v1/worlds/{name}) by op and result.\n"
                    "# TYPE terrad_world_requests_total counter\n");
    for (int i = 0; i < 2 && rc == 0; i++)
        for (int ok = 1; ok >= 0 && rc == 0; ok--)
            rc = metrics_put(
                out, cap, n, "terrad_world_requests_total{op=\"%s\",result=\"%s\"} %llu\n",
                request_ops[i], ok ? "ok" : "refused",
                (unsigned long long)atomic_load_explicit(&requests[i][ok], memory_order_relaxed));
    if (rc == 0)
        rc = metrics_put(
            out, cap, n,
            "# HELP terrad_world_readers_overdue_total Readers (HTTP requests, spectators' "
            "replays) still using a removed world 10 s after its removal began (it waits on).\n"
            "# TYPE terrad_world_readers_overdue_total counter\n"
            "terrad_world_readers_overdue_total %llu\n",
            (unsigned long long)atomic_load_explicit(&readers_overdue, memory_order_relaxed));
    return rc;
}
