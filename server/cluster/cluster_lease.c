/*
 * cluster_lease.c: who ticks a world (cluster.h). A lease is one key of the
 * bucket TERRAD_LEASES whose value names the holder ("node=NAME
 * expires_ms=WALL"; empty: released). Every change is a compare-and-set on
 * the key's revision, so of two nodes racing for it exactly one wins. A
 * holder that stops renewing is detected without trusting anyone's clock:
 * a taker waits until the revision it sees has not changed for lease_ms of
 * its own monotonic time. The lease only decides who should tick; the WAL's
 * fencing (cluster_wal.c) is what makes a deposed owner's commit fail.
 *
 * The network calls run outside cl->lock, so cluster_lease_held (asked every
 * tick) never waits for NATS.
 */
#include "cluster/cluster_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/time.h>
#include <time.h>

static double wall_ms(void)
{
    struct timeval tv;
    gettimeofday(&tv, NULL);
    return (double)tv.tv_sec * 1000.0 + tv.tv_usec / 1000.0;
}

/* The entry for world, added when missing; cl->lock held. NULL: no memory. */
static cluster_lease *lease_find(cluster *cl, const char *world)
{
    for (int64_t i = 0; i < cl->lease_count; i++)
        if (strcmp(cl->lease_list[i].world, world) == 0)
            return &cl->lease_list[i];
    if (array_grow((void **)&cl->lease_list, &cl->lease_capacity, cl->lease_count + 1,
                   sizeof *cl->lease_list) != 0)
        return NULL;
    cluster_lease *l = &cl->lease_list[cl->lease_count++];
    memset(l, 0, sizeof *l);
    snprintf(l->world, sizeof l->world, "%s", world);
    return l;
}

/* A copy of world's entry (zeroed when absent). */
static cluster_lease lease_copy(cluster *cl, const char *world)
{
    cluster_lease copy = {0};
    pthread_mutex_lock(&cl->lock);
    cluster_lease *l = lease_find(cl, world);
    if (l)
        copy = *l;
    pthread_mutex_unlock(&cl->lock);
    return copy;
}

static void lease_store(cluster *cl, const cluster_lease *value)
{
    pthread_mutex_lock(&cl->lock);
    cluster_lease *l = lease_find(cl, value->world);
    if (l)
        *l = *value;
    pthread_mutex_unlock(&cl->lock);
}

static void lease_value(cluster *cl, char *out, size_t cap)
{
    snprintf(out, cap, "node=%s expires_ms=%.0f", cl->node, wall_ms() + cl->lease_ms);
}

/* The holder named in a lease value ("" when released). */
static void lease_holder_of(const char *value, char *holder, size_t cap)
{
    if (cap == 0)
        return;
    holder[0] = '\0';
    if (strncmp(value, "node=", 5) != 0)
        return;
    size_t n = strcspn(value + 5, " ");
    if (n >= cap)
        n = cap - 1;
    memcpy(holder, value + 5, n);
    holder[n] = '\0';
}

/* The current entry: 1 found (value copied, revision set), 0 none, -1 error. */
static int lease_read(cluster *cl, const char *world, char *value, size_t cap, uint64_t *revision,
                      error_text *err)
{
    uint8_t *data = NULL;
    size_t len = 0;
    int found = cluster_kv_read(cl, CLUSTER_BUCKET_LEASES, world, &data, &len, revision, err);
    if (found == 1)
        snprintf(value, cap, "%s", (const char *)data);
    free(data);
    return found;
}

/* Writes our value over `revision` (0: create). 1 won, 0 lost the race, -1 error. */
static int lease_write(cluster *cl, const char *world, uint64_t revision, uint64_t *new_rev,
                       error_text *err)
{
    char value[160];
    lease_value(cl, value, sizeof value);
    natsStatus s = revision ? kvStore_UpdateString(new_rev, cl->leases, world, value, revision)
                            : kvStore_CreateString(new_rev, cl->leases, world, value);
    if (s == NATS_OK)
        return 1;
    if (s == NATS_ERR) /* wrong last sequence: another node wrote first */
        return 0;
    cluster_error(err, s, "lease of world %s", world);
    return -1;
}

int cluster_lease_acquire(cluster *cl, const char *world, char *holder, size_t holder_cap,
                          error_text *err)
{
    if (!cluster_name_valid(world, "world", err))
        return -1;
    cluster_lease l = lease_copy(cl, world);
    if (l.held && time_now_ms() - l.renewed_ms < cl->lease_ms) {
        if (holder_cap)
            snprintf(holder, holder_cap, "%s", cl->node);
        return 1;
    }
    snprintf(l.world, sizeof l.world, "%s", world);
    l.held = 0;
    char value[160] = "", who[CLUSTER_NODE_NAME_MAX + 1] = "";
    uint64_t revision = 0, new_rev = 0;
    int found = lease_read(cl, world, value, sizeof value, &revision, err);
    if (found < 0)
        return -1;
    lease_holder_of(value, who, sizeof who);
    double now = time_now_ms();
    int take = !found || who[0] == '\0' || strcmp(who, cl->node) == 0;
    if (!take && found && revision != l.revision) {
        l.revision = revision; /* a change: the holder is alive; start timing anew */
        l.seen_since_ms = now;
    } else if (!take && now - l.seen_since_ms >= cl->lease_ms) {
        take = 1;
    }
    int won = 0;
    if (take) {
        won = lease_write(cl, world, found ? revision : 0, &new_rev, err);
        if (won < 0)
            return -1;
        if (won) {
            l.held = 1;
            l.revision = new_rev;
            l.seen_since_ms = l.renewed_ms = time_now_ms();
            snprintf(who, sizeof who, "%s", cl->node);
        } else if (lease_read(cl, world, value, sizeof value, &revision, err) >= 0) {
            lease_holder_of(value, who, sizeof who);
            l.revision = revision;
            l.seen_since_ms = time_now_ms();
        }
    }
    lease_store(cl, &l);
    if (holder_cap)
        snprintf(holder, holder_cap, "%s", who);
    return won;
}

cluster_status cluster_lease_renew(cluster *cl, const char *world, error_text *err)
{
    cluster_lease l = lease_copy(cl, world);
    if (!l.held) {
        error_set(err, "lease of world %s: not held by %s", world, cl->node);
        return CLUSTER_FENCED;
    }
    uint64_t new_rev = 0;
    int won = lease_write(cl, world, l.revision, &new_rev, err);
    double now = time_now_ms();
    if (won == 1) {
        l.revision = new_rev;
        l.renewed_ms = l.seen_since_ms = now;
    } else if (won == 0) {
        l.held = 0;
        error_set(err, "lease of world %s: taken by another node", world);
    } else if (now - l.renewed_ms >= cl->lease_ms) {
        l.held = 0; /* unrenewed past lease_ms: another node may hold it by now */
    }
    lease_store(cl, &l);
    if (won == 1)
        return CLUSTER_OK;
    return won == 0 ? CLUSTER_FENCED : CLUSTER_ERROR;
}

int cluster_lease_held(cluster *cl, const char *world)
{
    cluster_lease l = lease_copy(cl, world);
    return l.held && time_now_ms() - l.renewed_ms < cl->lease_ms;
}

void cluster_lease_release(cluster *cl, const char *world)
{
    cluster_lease l = lease_copy(cl, world);
    if (!l.held)
        return;
    uint64_t new_rev = 0;
    /* An empty value over our revision: refused if someone took it meanwhile. */
    if (kvStore_UpdateString(&new_rev, cl->leases, world, "", l.revision) != NATS_OK)
        log_warn("cluster: releasing the lease of world %s failed (another node may hold it)",
                 world);
    l.held = 0;
    l.revision = new_rev;
    lease_store(cl, &l);
}

int cluster_lease_holder(cluster *cl, const char *world, char *holder, size_t cap, error_text *err)
{
    char value[160] = "";
    uint64_t revision = 0;
    if (cap)
        holder[0] = '\0';
    int found = lease_read(cl, world, value, sizeof value, &revision, err);
    if (found <= 0)
        return found;
    lease_holder_of(value, holder, cap);
    return holder[0] != '\0';
}

/* ---- the renewal thread ---- */

/* Renews every held lease once renew_ms has passed since its last renewal;
 * a lease another node took is logged once, and cluster_lease_held says so. */
static void renew_due(cluster *cl)
{
    char due[16][CLUSTER_WORLD_NAME_MAX + 1];
    int n = 0;
    double now = time_now_ms();
    pthread_mutex_lock(&cl->lock);
    for (int64_t i = 0; i < cl->lease_count && n < 16; i++)
        if (cl->lease_list[i].held && now - cl->lease_list[i].renewed_ms >= cl->renew_ms)
            snprintf(due[n++], sizeof due[0], "%s", cl->lease_list[i].world);
    pthread_mutex_unlock(&cl->lock);
    for (int i = 0; i < n; i++) {
        error_text err = {{0}};
        cluster_status r = cluster_lease_renew(cl, due[i], &err);
        if (r == CLUSTER_FENCED)
            log_warn("cluster: node %s lost the lease of world %s: %s", cl->node, due[i],
                     err.message);
        else if (r == CLUSTER_ERROR && !cluster_lease_held(cl, due[i]))
            log_warn("cluster: node %s gave up the lease of world %s (not renewed for %d ms): %s",
                     cl->node, due[i], cl->lease_ms, err.message);
    }
}

static void *renewer_main(void *arg)
{
    cluster *cl = arg;
    pthread_mutex_lock(&cl->lock);
    while (!cl->renewer_quit) {
        pthread_mutex_unlock(&cl->lock);
        renew_due(cl);
        pthread_mutex_lock(&cl->lock);
        if (cl->renewer_quit)
            break;
        struct timespec ts =
            time_after_ms(CLOCK_REALTIME, cl->renew_ms > 400 ? 100 : cl->renew_ms / 4 + 1);
        pthread_cond_timedwait(&cl->renewer_wake, &cl->lock, &ts);
    }
    pthread_mutex_unlock(&cl->lock);
    return NULL;
}

int cluster_renewer_start(cluster *cl)
{
    if (pthread_create(&cl->renewer, NULL, renewer_main, cl) != 0)
        return -1;
    cl->renewer_started = 1;
    return 0;
}

void cluster_renewer_stop(cluster *cl)
{
    if (!cl->renewer_started)
        return;
    pthread_mutex_lock(&cl->lock);
    cl->renewer_quit = 1;
    pthread_cond_broadcast(&cl->renewer_wake);
    pthread_mutex_unlock(&cl->lock);
    pthread_join(cl->renewer, NULL);
    cl->renewer_started = 0;
}
