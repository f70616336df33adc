/*
 * serve_cluster.c: `terrad serve --cluster URLS` (docs/cluster.md). Before
 * the daemon opens its world, the node joins the NATS cluster and becomes the
 * owner of one registered world — --world, or the first whose lease it can
 * take — waiting as a standby while every world is owned; the world's scene
 * comes from the registry and its store is the JetStream one (recovery from
 * the snapshots and the log, fencing the previous owner off). During the tick
 * loop, serve.c asks serve_cluster_check once per tick whether this node
 * still owns the world: a fenced commit or a lease another node took ends the
 * run, and the daemon starts again as a standby.
 */
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "app/app.h"
#include "app/serve_internal.h"

/* --node, or the host name with anything but [A-Za-z0-9_-] made '-'. */
static void node_name(const serve_options *o, char *out, size_t cap)
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

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

/* One pass over the candidates: 1 took one (c->world), 0 none free, -1 error. */
static int take_a_world(serve_cluster *c, const serve_options *o, error_text *err)
{
    char **names = NULL;
    int count = 0;
    if (o->world_name) {
        char *scene_json = NULL;
        int found = cluster_world_get(c->cl, o->world_name, &scene_json, err);
        free(scene_json);
        if (found == 0)
            error_set(err, "no world named \"%s\" in the cluster (terrad world add)",
                      o->world_name);
        if (found <= 0)
            return -1;
        names = malloc(sizeof *names);
        if (!names || !(names[0] = strdup(o->world_name))) {
            free(names);
            error_set(err, "out of memory");
            return -1;
        }
        count = 1;
    } else if (cluster_world_list(c->cl, &names, &count, err) != 0) {
        return -1;
    }
    int took = 0;
    for (int i = 0; i < count; i++) {
        if (!took && cluster_lease_acquire(c->cl, names[i], NULL, 0, err) == 1) {
            snprintf(c->world, sizeof c->world, "%s", names[i]);
            took = 1;
        }
        free(names[i]);
    }
    free(names);
    return took;
}

int serve_cluster_join(serve_cluster *c, const serve_options *o, volatile sig_atomic_t *stop,
                       scene *sc, error_text *err)
{
    char node[CLUSTER_NODE_NAME_MAX + 1];
    node_name(o, node, sizeof node);
    cluster_config cc = {.urls = o->cluster_urls, .node = node};
    if (!(c->cl = cluster_connect(&cc, err)))
        return -1;
    int said = 0;
    for (;;) {
        if (*stop) {
            err->message[0] = '\0';
            return -1;
        }
        int took = take_a_world(c, o, err);
        if (took < 0)
            return -1;
        if (took)
            break;
        if (!said++)
            log_info("cluster: node %s is a standby: %s owned by another node; waiting", node,
                     o->world_name ? o->world_name : "every registered world is");
        sleep_ms(250);
    }
    char *scene_json = NULL;
    if (cluster_world_get(c->cl, c->world, &scene_json, err) != 1) {
        if (!err->message[0])
            error_set(err, "world %s was removed", c->world);
        return -1;
    }
    int rc = scene_load_json(scene_json, ".", sc, err);
    free(scene_json);
    if (rc != 0) {
        error_prefix(err, "the registered scene of this world", ": ");
        return -1;
    }
    log_info("cluster: node %s owns world %s (NATS %s, %d replicas)", node, c->world,
             o->cluster_urls, cluster_replicas(c->cl));
    return 0;
}

store *serve_cluster_open_store(serve_cluster *c, world *w, store_recovery *rec, error_text *err)
{
    c->cs = cluster_store_open(c->cl, c->world, w, NULL, rec, err);
    if (!c->cs)
        return NULL;
    store *st = cluster_store_as_store(c->cs);
    if (!st) {
        cluster_store_close(c->cs);
        c->cs = NULL;
        error_set(err, "out of memory");
        return NULL;
    }
    log_info("cluster: world %s recovered at tick %llu from %d tile snapshots and %lld log "
             "records in %.1f ms",
             c->world, (unsigned long long)rec->tick, rec->tiles_loaded,
             (long long)rec->records_replayed, rec->ms);
    return st;
}

int serve_cluster_check(serve_cluster *c)
{
    if (cluster_store_fenced(c->cs)) {
        snprintf(c->lost, sizeof c->lost, "%s", cluster_store_failure(c->cs));
        return -1;
    }
    if (cluster_lease_held(c->cl, c->world))
        return 0;
    /* The lease lapsed (no renewal for lease_ms: NATS unreachable). Commits
     * are refused meanwhile (store_writable); once connected again, try to
     * take it back — at most once a second, and never while disconnected, so
     * the tick does not wait on NATS. Another holder means the world is lost. */
    double now = time_now_ms();
    if (!cluster_connected(c->cl) || now - c->retried_ms < 1000)
        return 0;
    c->retried_ms = now;
    char holder[CLUSTER_NODE_NAME_MAX + 1] = "";
    error_text err = {{0}};
    int r = cluster_lease_acquire(c->cl, c->world, holder, sizeof holder, &err);
    if (r == 0 && holder[0]) {
        snprintf(c->lost, sizeof c->lost, "node %s took the lease of world %s", holder, c->world);
        return -1;
    }
    if (r == 1)
        log_info("cluster: the lease of world %s is held again", c->world);
    return 0;
}

void serve_cluster_leave(serve_cluster *c)
{
    if (c->cl && c->world[0])
        cluster_lease_release(c->cl, c->world);
    cluster_close(c->cl);
    c->cl = NULL;
}
