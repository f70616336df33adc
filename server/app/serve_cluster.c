/*
 * serve_cluster.c: one world of `terrad serve --cluster` (docs/cluster.md)
 * as the NATS cluster sees it. serve_node.c asks serve_cluster_take for a
 * world whose lease this node can take (--worlds, or every registered world
 * in name order); the world's sim thread then loads its registered scene and
 * recovers it from JetStream (serve_cluster_open_world: snapshots and log,
 * fencing the previous owner off), and asks serve_cluster_check once per tick
 * whether this node still owns it: a fenced commit or a lease another node
 * took ends that world's thread, and the node goes on with its other worlds.
 */
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "app/app.h"
#include "app/serve_internal.h"

void serve_node_name(const serve_options *o, char *out, size_t cap)
{
    if (o->node) {
        snprintf(out, cap, "%s", o->node);
        return;
    }
    char host[256] = "node";
    gethostname(host, sizeof host - 1);
    snprintf(out, cap, "%.64s", host);
    for (char *p = out; *p; p++)
        if (!((*p >= 'a' && *p <= 'z') || (*p >= 'A' && *p <= 'Z') || (*p >= '0' && *p <= '9') ||
              *p == '_' || *p == '-'))
            *p = '-';
}

static int listed(char *const *registered, int count, const char *name)
{
    for (int i = 0; i < count; i++)
        if (strcmp(registered[i], name) == 0)
            return 1;
    return 0;
}

/* The i-th name of --worlds ("a,b,c") into out; the count when out is NULL. */
static int worlds_option_name(const char *list, int i, char *out, size_t cap)
{
    int k = 0;
    for (const char *p = list;; k++) {
        const char *end = strchr(p, ',');
        size_t len = end ? (size_t)(end - p) : strlen(p);
        if (out && k == i) {
            snprintf(out, cap, "%.*s", (int)(len < cap - 1 ? len : cap - 1), p);
            return len < cap ? k : -1; /* too long: no world has that name */
        }
        if (!end)
            return k + 1;
        p = end + 1;
    }
}

int serve_cluster_take(cluster *cl, const serve_options *o, char *const *registered,
                       int nregistered, char (*held)[CLUSTER_WORLD_NAME_MAX + 1], int n, char *out,
                       error_text *err)
{
    /* --worlds in its own order, every name registered; else the registry's (name) order */
    int count = o->worlds ? worlds_option_name(o->worlds, 0, NULL, 0) : nregistered;
    char name[CLUSTER_WORLD_NAME_MAX + 1];
    for (int i = 0; o->worlds && i < count; i++)
        if (worlds_option_name(o->worlds, i, name, sizeof name) < 0 || !name[0] ||
            !listed(registered, nregistered, name)) {
            error_set(err, "no world named \"%s\" in the cluster (terrad world add)", name);
            return -1;
        }
    for (int i = 0; i < count; i++) {
        if (o->worlds)
            worlds_option_name(o->worlds, i, name, sizeof name);
        else
            snprintf(name, sizeof name, "%s", registered[i]);
        int mine = 0;
        for (int k = 0; k < n; k++)
            mine |= strcmp(held[k], name) == 0;
        error_text ignored = {{0}};
        if (!mine && cluster_lease_acquire(cl, name, NULL, 0, &ignored) == 1) {
            snprintf(out, CLUSTER_WORLD_NAME_MAX + 1, "%s", name);
            return 1;
        }
    }
    return 0;
}

int serve_cluster_open_world(cluster *cl, host_sim *m, const serve_options *o, error_text *err)
{
    char *scene_json = NULL;
    if (cluster_world_get(cl, m->name, &scene_json, err) != 1) {
        if (!err->message[0])
            error_set(err, "world %s was removed", m->name);
        return -1;
    }
    int rc = scene_load_json(scene_json, ".", &m->sc, err);
    free(scene_json);
    if (rc != 0) {
        error_prefix(err, "the registered scene of this world", ": ");
        return -1;
    }
    if (o->tick_hz > 0)
        m->sc.tick_hz = o->tick_hz;
    m->sc.material.tick_s = 1.0 / m->sc.tick_hz;
    if (scene_create_world(&m->sc, &m->w, err) != 0)
        return -1;
    cluster_store_config sc = {.compact_records = o->compact_records};
    m->cs = cluster_store_open(cl, m->name, &m->w, &sc, &m->recovery, err);
    if (!m->cs)
        return -1;
    m->st = cluster_store_as_store(m->cs);
    if (!m->st) {
        cluster_store_close(m->cs);
        m->cs = NULL;
        error_set(err, "out of memory");
        return -1;
    }
    /* spectators and ?tick=N read its past back from JetStream (cluster_history.c) */
    if (cluster_history_make(cl, m->name, &m->status.history, err) != 0)
        return -1;
    const store_recovery *rec = &m->recovery;
    log_info("cluster: world %s recovered at tick %llu from %d tile snapshots and %lld log "
             "records in %.1f ms",
             m->name, (unsigned long long)rec->tick, rec->tiles_loaded,
             (long long)rec->records_replayed, rec->ms);
    return 0;
}

int serve_cluster_check(cluster *cl, host_sim *m, double *retried_ms, char *lost, size_t cap)
{
    if (cluster_store_fenced(m->cs)) {
        snprintf(lost, cap, "%s", cluster_store_failure(m->cs));
        return -1;
    }
    if (cluster_lease_held(cl, m->name))
        return 0;
    /* The lease lapsed (no renewal for lease_ms: NATS unreachable). Commits
     * are refused meanwhile (store_writable); once connected again, try to
     * take it back — at most once a second, and never while disconnected, so
     * the tick does not wait on NATS. Another holder means the world is lost. */
    double now = time_now_ms();
    if (!cluster_connected(cl) || now - *retried_ms < 1000)
        return 0;
    *retried_ms = now;
    char holder[CLUSTER_NODE_NAME_MAX + 1] = "";
    error_text err = {{0}};
    int r = cluster_lease_acquire(cl, m->name, holder, sizeof holder, &err);
    /* the lease still naming this node is its own lapsed renewal: no one took
     * it, so keep the world and try again (fencing guards the log either way) */
    if (r == 0 && holder[0] && strcmp(holder, cluster_node(cl)) != 0) {
        snprintf(lost, cap, "node %s took the lease of world %s", holder, m->name);
        return -1;
    }
    if (r == 1)
        log_info("cluster: the lease of world %s is held again", m->name);
    return 0;
}
