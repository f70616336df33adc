/*
 * serve_node.c: `terrad serve --cluster` — a node of the cluster
 * (docs/cluster.md). The node connects to NATS, opens one HTTP and one
 * websocket port, and then, on its main thread, keeps taking worlds whose
 * lease it can take (--worlds, or every registered world), up to
 * --max-worlds. Each world it takes is opened on a short-lived thread of
 * its own (world_main: recover the world from JetStream, start its engine
 * and service, add it to the HTTP and websocket servers), then handed to the
 * node's shared pool of sim workers (serve_ticker.c), which runs the same
 * serve_sim_step a single daemon runs at the world's rate until the node
 * stops or the world is lost (a fenced commit, or another node holds its
 * lease). A lost world's end runs on a worker (world_end: its clients are
 * told and closed, it is freed), and the node goes on with its other worlds;
 * a node with no world waits as a standby.
 *
 * Why a pool rather than a thread per world: the worlds share the cores on
 * one schedule (earliest due first, so one heavy world does not starve the
 * others), and a world costs no thread while it ticks. The pool has more
 * workers than cores, so a tick waiting on its JetStream commit does not
 * hold the other worlds up.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "app/app.h"
#include "app/serve_internal.h"
#include "metrics/metrics.h"

#define NODE_MAX_WORLDS SERVE_WORLDS_MAX
#define NODE_POLL_MS 250
#define NODE_LIST_MS 1000.0  /* the registry is listed again after this */
#define NODE_RETRY_MS 5000.0 /* a world that failed to open is tried again after this */

typedef struct serve_node serve_node;

typedef struct node_world {
    serve_sim m;
    serve_node *node;
    pthread_t thread;      /* opens the world, then ends (joined by reap_worlds) */
    serve_tick_job job;    /* on the node's pool once opened */
    atomic_int opened;     /* world → node: the job is on the pool */
    atomic_int done;       /* world → node: it has ended (freed by reap_worlds) */
    int joined;            /* its opening thread was joined */
    atomic_int registered; /* served by the HTTP and websocket ports */
    int lost;              /* the world belongs to another node now */
    int deleted;           /* removed from the registry: its clients are told so (4020) */
    double retried_ms;     /* serve_cluster_check's last retry of a lapsed lease */
    char why[256];         /* why it was lost, or failed to open */
} node_world;

struct serve_node {
    const serve_options *o;
    auth_table *auth;   /* the daemon's (serve_security.c); NULL: no tokens */
    http_server *probe; /* --probe-port */
    char name[CLUSTER_NODE_NAME_MAX + 1];
    cluster *cl;
    http_status status; /* the node's: /readyz */
    http_server *http;
    net_server *net;
    serve_ticker *ticker; /* the sim workers every world of the node ticks on */
    serve_relays *relays; /* the worlds other nodes tick, served here too */
    serve_node_api *api;  /* POST/GET /v1/worlds, DELETE /v1/worlds/NAME */
    char **registered;    /* the registry as last listed (node_list_worlds) */
    int nregistered;
    double listed_ms;     /* when it was last listed (0: never) */
    unsigned listings;    /* successful listings so far */
    pthread_mutex_t lock; /* worlds[] for the HTTP threads (readiness, watchdog) */
    node_world *worlds[NODE_MAX_WORLDS];
    int nworlds, max_worlds;
    int stopping; /* node_stop: worlds end because the node does */
    char failed[NODE_MAX_WORLDS][CLUSTER_WORLD_NAME_MAX + 1]; /* not retried before failed_ms */
    double failed_ms[NODE_MAX_WORLDS];
};

/* /readyz: ready while the node ticks at least one world and every world it
 * ticks can commit; otherwise it says why. */
static void node_refresh_status(serve_node *n)
{
    char why[256] = "";
    int ready = 0;
    pthread_mutex_lock(&n->lock);
    for (int i = 0; i < n->nworlds; i++) {
        node_world *nw = n->worlds[i];
        if (!atomic_load(&nw->registered))
            continue;
        pthread_mutex_lock(&nw->m.status.lock);
        if (!nw->m.status.ready && !why[0])
            snprintf(why, sizeof why, "world %.64s: %.180s", nw->m.name, nw->m.status.not_ready);
        pthread_mutex_unlock(&nw->m.status.lock);
        ready = 1;
    }
    pthread_mutex_unlock(&n->lock);
    pthread_mutex_lock(&n->status.lock);
    n->status.ready = ready && !why[0];
    snprintf(n->status.not_ready, sizeof n->status.not_ready, "%s",
             why[0] ? why : "this node ticks no world now (a standby)");
    pthread_mutex_unlock(&n->status.lock);
}

/* The watchdog behind /healthz: the longest any world's tick loop has gone
 * without publishing (0 while none ticks). */
static double node_stalled_ms(const void *arg)
{
    serve_node *n = (serve_node *)arg;
    double worst = 0;
    pthread_mutex_lock(&n->lock);
    for (int i = 0; i < n->nworlds; i++)
        if (atomic_load(&n->worlds[i]->registered)) {
            double ms = http_status_stalled_ms(&n->worlds[i]->m.status);
            worst = ms > worst ? ms : worst;
        }
    pthread_mutex_unlock(&n->lock);
    return worst;
}

static double net_stalled(const void *arg)
{
    return net_server_stalled_ms((const net_server *)arg);
}

/* The world joins the node's ports. */
static int world_register(serve_node *n, node_world *nw, error_text *err)
{
    serve_sim *m = &nw->m;
    net_world_info info = serve_sim_world_info(m);
    if (http_server_add_world(n->http, m->name, &m->status, m->h, &m->w, err) != 0)
        return -1;
    if (net_server_add_world(n->net, &info, m->h, err) != 0) {
        http_server_remove_world(n->http, m->name);
        return -1;
    }
    if (serve_relays_own(n->relays, m->name, err) != 0) {
        net_server_remove_world(n->net, m->h);
        http_server_remove_world(n->http, m->name);
        return -1;
    }
    m->metrics_slot = metrics_world_slot(m->name);
    serve_sim_ready(m);
    atomic_store(&nw->registered, 1);
    node_refresh_status(n);
    log_info("cluster: world %s: serving scene \"%s\" (%dx%d cells, %s backend, tick %llu) on "
             "http://127.0.0.1:%d/ and ws://127.0.0.1:%d/ (hello \"world\": \"%s\", "
             "/v1/*?world=%s)",
             m->name, m->sc.name, m->w.width, m->w.height, m->backend->name,
             (unsigned long long)service_current_tick(m->svc), http_server_port(n->http),
             net_server_port(n->net), m->name, m->name);
    return 0;
}

/* The world leaves the node's ports: reads fail fast, requests in flight end,
 * its clients are told and closed. */
static void world_unregister(serve_node *n, node_world *nw)
{
    serve_sim *m = &nw->m;
    if (m->h) {
        char why[160];
        snprintf(why, sizeof why, "world %s %s", m->name,
                 nw->deleted ? "was deleted" : "stopped on this node (moved, or the node stops)");
        hub_close_reads(m->h);
        hub_close_edits(m->h, why);
    }
    if (!atomic_load(&nw->registered))
        return;
    atomic_store(&nw->registered, 0);
    serve_relays_drop(n->relays, m->name); /* its relayed clients' messages stop coming */
    http_server_remove_world(n->http, m->name);
    if ((nw->deleted ? net_server_delete_world(n->net, m->h)
                     : net_server_remove_world(n->net, m->h)) != 0)
        m->h = NULL; /* the net thread may still hold it: left to the exit */
    metrics_world_drop(m->metrics_slot);
}

/* After each of a world's ticks: does this node still own it? */
static int world_check(void *ctx, serve_sim *m, long tick, char *why, size_t cap)
{
    node_world *nw = ctx;
    if (serve_cluster_check(nw->node->cl, m, &nw->retried_ms, why, cap) != 0) {
        /* a delete purges the log first, so the owner is usually fenced
         * before its next listing shows the world gone: ask the registry */
        char *scene = NULL;
        error_text err = {{0}};
        if (cluster_world_get(nw->node->cl, m->name, &scene, &err) == 0) {
            log_info("cluster: world %s was deleted from the registry: it stops here", m->name);
            nw->deleted = 1;
        } else {
            nw->lost = 1;
        }
        free(scene);
        return 1;
    }
    if (tick % 8 == 0) /* /readyz follows the store at once, whatever the node loop waits on */
        node_refresh_status(nw->node);
    return 0;
}

/* The job's end, on a worker: off the ports, freed, its lease let go. */
static void world_end(serve_tick_job *j, int rc)
{
    node_world *nw = j->ctx;
    serve_node *n = nw->node;
    serve_sim *m = &nw->m;
    if (rc != 0)
        snprintf(nw->why, sizeof nw->why, "%s", j->why);
    world_unregister(n, nw);
    log_info("cluster: world %s stopped here after tick %llu (%llu overruns)", m->name,
             (unsigned long long)service_current_tick(m->svc), (unsigned long long)m->overruns);
    serve_sim_free(m);
    if (!nw->lost && !nw->deleted) /* another node may take it at once */
        cluster_lease_release(n->cl, m->name);
    node_refresh_status(n);
    atomic_store(&nw->done, 1);
}

/* One world's opening thread: open, serve, hand to the pool (or leave). */
static void *world_main(void *arg)
{
    node_world *nw = arg;
    serve_node *n = nw->node;
    serve_sim *m = &nw->m;
    error_text err = {{0}};
    if (serve_cluster_open_world(n->cl, m, n->o, &err) == 0) {
        serve_sim_status_init(m);
        nw->job = (serve_tick_job){.m = m,
                                   .net = n->net,
                                   .max_ticks = n->o->max_ticks,
                                   .check = world_check,
                                   .end = world_end,
                                   .ctx = nw};
        if (!(m->h = hub_create()))
            error_set(&err, "out of memory");
        else if (serve_sim_start(m, n->o, &err) == 0 && world_register(n, nw, &err) == 0 &&
                 serve_ticker_add(n->ticker, &nw->job, &err) == 0) {
            atomic_store(&nw->opened, 1);
            return NULL;
        }
    }
    snprintf(nw->why, sizeof nw->why, "%s", err.message);
    world_unregister(n, nw);
    serve_sim_free(m);
    if (!nw->lost && !nw->deleted) /* another node may take it at once */
        cluster_lease_release(n->cl, m->name);
    node_refresh_status(n);
    atomic_store(&nw->done, 1);
    return NULL;
}

static int recently_failed(serve_node *n, const char *name)
{
    for (int i = 0; i < NODE_MAX_WORLDS; i++)
        if (n->failed[i][0] && strcmp(n->failed[i], name) == 0)
            return time_now_ms() < n->failed_ms[i];
    return 0;
}

static void note_failed(serve_node *n, const char *name)
{
    int at = 0;
    for (int i = 0; i < NODE_MAX_WORLDS; i++)
        if (!n->failed[i][0] || strcmp(n->failed[i], name) == 0 ||
            n->failed_ms[i] < n->failed_ms[at]) {
            at = i;
            if (!n->failed[i][0] || strcmp(n->failed[i], name) == 0)
                break;
        }
    snprintf(n->failed[at], sizeof n->failed[at], "%s", name);
    n->failed_ms[at] = time_now_ms() + NODE_RETRY_MS;
}

/* A deleted world leaves the last listing at once: not taken again from it
 * (and its world_deleted event goes now: the next listing will not differ). */
static void forget_registered(serve_node *n, const char *name)
{
    for (int i = 0; i < n->nregistered; i++)
        if (strcmp(n->registered[i], name) == 0) {
            net_server_event(n->net, "world_deleted", name);
            free(n->registered[i]);
            memmove(&n->registered[i], &n->registered[i + 1],
                    (size_t)(n->nregistered - i - 1) * sizeof *n->registered);
            n->nregistered--;
            return;
        }
}

/* Joins the worlds whose threads ended: lost, failed or stopped. */
static void reap_worlds(serve_node *n)
{
    for (int i = 0; i < n->nworlds; i++) {
        node_world *nw = n->worlds[i];
        if (!nw->joined && (atomic_load(&nw->opened) || atomic_load(&nw->done))) {
            pthread_join(nw->thread, NULL); /* its opening thread has ended */
            nw->joined = 1;
        }
        if (!atomic_load(&nw->done))
            continue;
        if (nw->deleted)
            forget_registered(n, nw->m.name);
        if (nw->lost)
            log_warn("cluster: this node no longer owns world %s (%s): it stopped ticking it; "
                     "its clients were told to connect again",
                     nw->m.name, nw->why);
        else if (nw->why[0] && !n->stopping && !nw->deleted) {
            log_error("cluster: world %s: %s (tried again in %.0f s)", nw->m.name, nw->why,
                      NODE_RETRY_MS / 1000);
            note_failed(n, nw->m.name);
        }
        pthread_mutex_lock(&n->lock);
        n->worlds[i] = n->worlds[--n->nworlds];
        pthread_mutex_unlock(&n->lock);
        pthread_mutex_destroy(&nw->m.status.lock);
        free(nw);
        i--;
    }
}

static void node_forget_worlds(serve_node *n)
{
    for (int i = 0; i < n->nregistered; i++)
        free(n->registered[i]);
    free(n->registered);
    n->registered = NULL;
    n->nregistered = 0;
}

static int named(char *const *names, int count, const char *name)
{
    for (int i = 0; i < count; i++)
        if (strcmp(names[i], name) == 0)
            return 1;
    return 0;
}

/* world_created / world_deleted for this node's subscribed admins: what a
 * new listing has that the last had not, and the reverse. Every node lists,
 * so the admins of every node hear of a world made or ended on any of them. */
static void tell_changes(serve_node *n, char *const *names, int count)
{
    for (int i = 0; i < count; i++)
        if (!named(n->registered, n->nregistered, names[i]))
            net_server_event(n->net, "world_created", names[i]);
    for (int i = 0; i < n->nregistered; i++)
        if (!named(names, count, n->registered[i]))
            net_server_event(n->net, "world_deleted", n->registered[i]);
}

/* The registry, listed again once NODE_LIST_MS has passed. A listing is an
 * ordered consumer on the bucket that the NATS servers must agree on, so the
 * node lists once a second for its lease polls and its relays together
 * rather than once per poll, and only the first listing waits out a leader
 * election: later ones are tried once, and one that fails leaves the last in
 * place, so lease polls go on while NATS elects (a lapsed owner is taken
 * over on time). 0, or -1 when no listing has succeeded yet. */
static int node_list_worlds(serve_node *n, error_text *err)
{
    if (n->listed_ms > 0 && time_now_ms() - n->listed_ms < NODE_LIST_MS)
        return 0;
    char **names = NULL;
    int count = 0;
    int first = n->listed_ms == 0;
    if ((first ? cluster_world_list(n->cl, &names, &count, err)
               : cluster_world_list_now(n->cl, &names, &count, err)) != 0) {
        /* a failed try waited out a timeout: a second of lease polls before the next */
        if (!first)
            n->listed_ms = time_now_ms();
        return first ? -1 : 0;
    }
    if (!first)
        tell_changes(n, names, count);
    node_forget_worlds(n);
    n->registered = names;
    n->listings++;
    n->nregistered = count;
    n->listed_ms = time_now_ms();
    return 0;
}

/* Takes one more world if one is free: 1 took one, 0 none, -1 error. */
static int take_world(serve_node *n, error_text *err)
{
    char held[NODE_MAX_WORLDS + 1][CLUSTER_WORLD_NAME_MAX + 1];
    int count = 0;
    for (int i = 0; i < n->nworlds; i++)
        snprintf(held[count++], sizeof held[0], "%s", n->worlds[i]->m.name);
    for (int i = 0; i < NODE_MAX_WORLDS && count < NODE_MAX_WORLDS; i++)
        if (n->failed[i][0] && recently_failed(n, n->failed[i]))
            snprintf(held[count++], sizeof held[0], "%s", n->failed[i]);
    char name[CLUSTER_WORLD_NAME_MAX + 1];
    int took =
        serve_cluster_take(n->cl, n->o, n->registered, n->nregistered, held, count, name, err);
    if (took != 1)
        return took;
    node_world *nw = calloc(1, sizeof *nw);
    if (!nw) {
        cluster_lease_release(n->cl, name);
        error_set(err, "out of memory");
        return -1;
    }
    nw->node = n;
    nw->m.metrics_slot = -1;
    snprintf(nw->m.name, sizeof nw->m.name, "%s", name);
    pthread_mutex_init(&nw->m.status.lock, NULL);
    serve_relays_drop(n->relays, name); /* relayed here until now: its clients connect again */
    log_info("cluster: node %s owns world %s (NATS %s, %d replicas)", n->name, name,
             n->o->cluster_urls, cluster_replicas(n->cl));
    pthread_mutex_lock(&n->lock);
    n->worlds[n->nworlds++] = nw;
    pthread_mutex_unlock(&n->lock);
    if (pthread_create(&nw->thread, NULL, world_main, nw) != 0) {
        pthread_mutex_lock(&n->lock);
        n->nworlds--;
        pthread_mutex_unlock(&n->lock);
        cluster_lease_release(n->cl, name);
        pthread_mutex_destroy(&nw->m.status.lock);
        free(nw);
        error_set(err, "cannot start a thread for world %s", name);
        return -1;
    }
    return 1;
}

/* The node's ports: one HTTP and one websocket server for all its worlds. */
static int node_open_ports(serve_node *n, error_text *err)
{
    const serve_options *o = n->o;
    int fd_reserve = 0;
    if (!(n->http = serve_http_open(o, n->auth, &n->status, NULL, &fd_reserve, err)) ||
        (o->probe_port >= 0 && !(n->probe = http_probe_start(n->http, o->probe_port, err))))
        return -1;
    http_server_host_worlds(n->http);
    net_config nc = {.port = o->ws_port,
                     .bind_any = o->bind_any,
                     .auth = n->auth,
                     .tls_cert = o->tls_cert,
                     .tls_key = o->tls_key,
                     .limits = o->limits};
    nc.limits.fd_reserve = fd_reserve;
    if (!(n->net = net_server_start(&nc, NULL, err)))
        return -1;
    int tls = o->tls_cert && o->tls_cert[0];
    http_server_set_websocket(n->http, net_server_port(n->net), tls, o->public_ws_url);
    if (!(n->relays = serve_relays_start(n->cl, n->net, n->http, n->name)) ||
        !(n->api = serve_node_api_start(n->cl, o, n->name, n->http))) {
        error_set(err, "out of memory");
        return -1;
    }
    http_server_watch(n->http, "tick", node_stalled_ms, n, 10000.0);
    http_server_watch(n->http, "net", net_stalled, n->net, 10000.0);
    if (n->probe)
        log_info("probes: http://127.0.0.1:%d/healthz (and /readyz, /metrics)",
                 http_server_port(n->probe));
    log_info("cluster: node %s listens on %s://127.0.0.1:%d/ and websocket port %d", n->name,
             tls ? "https" : "http", http_server_port(n->http), net_server_port(n->net));
    return 0;
}

/* Relay every registered world this node neither ticks nor is taking. */
static void refresh_relays(serve_node *n)
{
    char busy[NODE_MAX_WORLDS][CLUSTER_WORLD_NAME_MAX + 1];
    int count = 0;
    for (int i = 0; i < n->nworlds; i++)
        snprintf(busy[count++], sizeof busy[0], "%s", n->worlds[i]->m.name);
    serve_relays_refresh(n->relays, n->registered, n->nregistered, busy, count);
}

/* After a new listing: each world this node ticks that the registry no
 * longer names (checked once more by name: a listing is a snapshot) was
 * deleted (DELETE /v1/worlds/NAME on any node, or `terrad world remove`):
 * it stops, and its clients are closed with 4020 "world deleted". */
static void stop_deleted(serve_node *n)
{
    for (int i = 0; i < n->nworlds; i++) {
        node_world *nw = n->worlds[i];
        int listed = 0;
        for (int k = 0; k < n->nregistered && !listed; k++)
            listed = strcmp(n->registered[k], nw->m.name) == 0;
        if (listed || nw->deleted || !atomic_load(&nw->opened)) /* opening: the next listing */
            continue;
        char *scene = NULL;
        error_text err = {{0}};
        int found = cluster_world_get(n->cl, nw->m.name, &scene, &err);
        free(scene);
        if (found != 0)
            continue;
        log_info("cluster: world %s was deleted from the registry: it stops here", nw->m.name);
        nw->deleted = 1; /* read by its end, after the ticker's lock */
        serve_ticker_end(n->ticker, &nw->job);
    }
}

/* The node's life after its ports are open: take, tick, reap, until stop. */
static int node_loop(serve_node *n, volatile sig_atomic_t *stop, volatile sig_atomic_t *hangup)
{
    int said_standby = 0, first = 1;
    double warned_ms = 0;
    while (!*stop) {
        reap_worlds(n);
        error_text err = {{0}};
        double listed_ms = n->listed_ms;
        unsigned listings = n->listings;
        int took = 0;
        if ((cluster_connected(n->cl) || first) && node_list_worlds(n, &err) != 0)
            took = -1;
        else if (n->nworlds < n->max_worlds)
            took = take_world(n, &err);
        if (took < 0 && first) {
            log_error("%s", err.message);
            return 1;
        }
        if (took < 0 && time_now_ms() - warned_ms > 10000) {
            warned_ms = time_now_ms();
            log_warn("cluster: cannot take a world now: %s", err.message);
        }
        first = 0;
        if (n->nworlds == 0 && !said_standby) {
            said_standby = 1;
            log_info("cluster: node %s is a standby: %s owned by another node; waiting", n->name,
                     n->o->worlds ? n->o->worlds : "every registered world is");
        }
        if (n->nworlds > 0)
            said_standby = 0;
        node_refresh_status(n);
        if (*hangup) {
            *hangup = 0;
            serve_security_reload(n->o, n->auth);
        }
        if (n->listed_ms != listed_ms) /* listed again (or tried): the relays follow */
            refresh_relays(n);
        if (n->listings != listings)
            stop_deleted(n);
        if (took != 1) /* took one: look for the next at once */
            serve_sleep_ms(NODE_POLL_MS);
    }
    return 0;
}

static void node_stop(serve_node *n)
{
    n->stopping = 1;
    while (n->nworlds > 0) {
        for (int i = 0; i < n->nworlds; i++)
            if (atomic_load(&n->worlds[i]->opened)) /* else still opening: asked next round */
                serve_ticker_end(n->ticker, &n->worlds[i]->job);
        reap_worlds(n);
        if (n->nworlds)
            serve_sleep_ms(10);
    }
    serve_ticker_stop(n->ticker);
    serve_relays_stop(n->relays);
    node_forget_worlds(n);
    http_server_stop(n->probe);
    http_server_stop(n->http); /* first: its watchdog reads the net server */
    serve_node_api_free(n->api);
    net_server_stop(n->net);
    cluster_close(n->cl);
}

int serve_node_run(const serve_options *o, auth_table *auth, volatile sig_atomic_t *stop,
                   volatile sig_atomic_t *hangup)
{
    serve_node *n = calloc(1, sizeof *n);
    if (!n) {
        log_error("serve: out of memory");
        return 1;
    }
    n->o = o;
    n->auth = auth;
    pthread_mutex_init(&n->lock, NULL);
    pthread_mutex_init(&n->status.lock, NULL);
    serve_node_name(o, n->name, sizeof n->name);
    n->max_worlds = o->max_worlds;
    if (n->max_worlds <= 0) { /* --worlds: every world named; else one */
        n->max_worlds = 1;
        for (const char *p = o->worlds; p && *p; p++)
            n->max_worlds += *p == ',';
    }
    error_text err = {{0}};
    cluster_config cc = {.urls = o->cluster_urls, .node = n->name};
    int rc = 1;
    if (!(n->cl = cluster_connect(&cc, &err)) ||
        !(n->ticker = serve_ticker_start(serve_ticker_default_workers(), &err)) ||
        node_open_ports(n, &err) != 0)
        log_error("%s", err.message);
    else
        rc = node_loop(n, stop, hangup);
    node_stop(n);
    pthread_mutex_destroy(&n->status.lock);
    pthread_mutex_destroy(&n->lock);
    free(n);
    return rc;
}
