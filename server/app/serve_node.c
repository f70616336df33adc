/*
 * serve_node.c: `terrad serve --cluster` — a node of the cluster
 * (docs/cluster.md). The node connects to NATS, opens one HTTP and one
 * websocket port, and then, on its main thread, keeps taking worlds whose
 * lease it can take (--worlds, or every registered world), up to
 * --max-worlds. Each world it takes is opened on a short-lived thread of
 * its own (world_main → host_world_start, the one life of every world,
 * host/host_world.c, with this file's registry backend, cluster_world_ops:
 * the world recovered from JetStream under the lease, its relays owned,
 * the lease checked after each tick), then ticked by the node's shared pool
 * of sim workers (host/host_ticker.c) until the node stops or the world is
 * lost (a fenced commit, or another node holds its lease). A lost world's
 * end runs on a worker (its clients are told and closed, it is freed, then
 * world_ended lets its lease go), and the node goes on with its other
 * worlds; a node with no world waits as a standby.
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
    host_world hw; /* its life (host/); hw.deleted: removed from the registry, its clients
                    * are told so (4020); hw.registered: served by the node's ports */
    serve_node *node;
    pthread_t thread;  /* opens the world, then ends (joined by reap_worlds) */
    atomic_int opened; /* world → node: it is on the pool */
    atomic_int done;   /* world → node: it has ended (freed by reap_worlds) */
    int joined;        /* its opening thread was joined */
    int lost;          /* the world belongs to another node now */
    double retried_ms; /* serve_cluster_check's last retry of a lapsed lease */
    char why[256];     /* why it was lost, or failed to open */
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
    hub_worlds *table;    /* the worlds it ticks, which both ports read */
    host_ticker *ticker;  /* the sim workers every world of the node ticks on */
    serve_relays *relays; /* the worlds other nodes tick, served here too */
    serve_node_api *api;  /* POST/GET /v1/worlds, DELETE /v1/worlds/NAME */
    char **registered;    /* the registry as last listed (node_list_worlds) */
    int nregistered;
    double listed_ms;     /* when it was last listed (0: never) */
    unsigned listings;    /* successful listings so far */
    pthread_mutex_t lock; /* worlds[] for the HTTP threads (readiness, watchdog) */
    node_world *worlds[NODE_MAX_WORLDS];
    int nworlds, max_worlds;
    int stopping;           /* node_stop: worlds end because the node does */
    atomic_int drain_asked; /* POST /v1/drain (an HTTP thread): the node loop ends */
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
        if (!atomic_load(&nw->hw.registered))
            continue;
        pthread_mutex_lock(&nw->hw.m.status.lock);
        if (!nw->hw.m.status.ready && !why[0])
            snprintf(why, sizeof why, "world %.64s: %.180s", nw->hw.m.name,
                     nw->hw.m.status.not_ready);
        pthread_mutex_unlock(&nw->hw.m.status.lock);
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
        if (atomic_load(&n->worlds[i]->hw.registered)) {
            double ms = http_status_stalled_ms(&n->worlds[i]->hw.m.status);
            worst = ms > worst ? ms : worst;
        }
    pthread_mutex_unlock(&n->lock);
    return worst;
}

static double net_stalled(const void *arg)
{
    return net_server_stalled_ms((const net_server *)arg);
}

/* The registry backend of a cluster world (host.h): the registered scene
 * and its store from JetStream, under this node's lease. */
static int world_open(host_world *hw, error_text *err)
{
    node_world *nw = hw->owner;
    return serve_cluster_open_world(nw->node->cl, &hw->m, nw->node->o, err);
}

/* On the ports: its relayed clients' messages come here from now on. */
static int world_registered(host_world *hw, error_text *err)
{
    node_world *nw = hw->owner;
    serve_node *n = nw->node;
    host_sim *m = &hw->m;
    if (serve_relays_own(n->relays, m->name, err) != 0)
        return -1;
    node_refresh_status(n);
    log_info("cluster: world %s: serving scene \"%s\" (%dx%d cells, %s backend, tick %llu) on "
             "http://127.0.0.1:%d/ and ws://127.0.0.1:%d/ (hello \"world\": \"%s\", "
             "/v1/*?world=%s)",
             m->name, m->sc.name, m->w.width, m->w.height, m->backend->name,
             (unsigned long long)service_current_tick(m->svc), http_server_port(n->http),
             net_server_port(n->net), m->name, m->name);
    return 0;
}

/* Leaving the ports: its relayed clients' messages stop coming. */
static void world_unregistering(host_world *hw)
{
    node_world *nw = hw->owner;
    serve_relays_drop(nw->node->relays, hw->m.name);
}

/* After each of a world's ticks: does this node still own it? */
static int world_check(host_world *hw, long tick, char *why, size_t cap)
{
    node_world *nw = hw->owner;
    host_sim *m = &hw->m;
    if (serve_cluster_check(nw->node->cl, m, &nw->retried_ms, why, cap) != 0) {
        /* a delete purges the log first, so the owner is usually fenced
         * before its next listing shows the world gone: ask the registry */
        char *scene = NULL;
        error_text err = {{0}};
        if (cluster_world_get(nw->node->cl, m->name, &scene, &err) == 0) {
            log_info("cluster: world %s was deleted from the registry: it stops here", m->name);
            hw->deleted = 1;
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

/* Off the ports and freed (on a worker, or on its opening thread when it
 * did not start): its lease let go unless another node has it. */
static void world_gone(node_world *nw)
{
    serve_node *n = nw->node;
    if (!nw->lost && !nw->hw.deleted) /* another node may take it at once */
        cluster_lease_release(n->cl, nw->hw.m.name);
    node_refresh_status(n);
    atomic_store(&nw->done, 1);
}

/* Its end ran on a worker. */
static void world_ended(host_world *hw, int rc)
{
    node_world *nw = hw->owner;
    if (rc != 0)
        snprintf(nw->why, sizeof nw->why, "%s", hw->why);
    log_info("cluster: world %s stopped here after tick %llu (%llu overruns)", hw->m.name,
             hw->last_tick, hw->overruns);
    world_gone(nw);
}

static const host_world_ops cluster_world_ops = {
    .open = world_open,
    .registered = world_registered,
    .unregistering = world_unregistering,
    .check = world_check,
    .ended = world_ended,
    .deleted_why = "was deleted",
    .stopped_why = "stopped on this node (moved, or the node stops)",
};

/* One world's opening thread: open, serve, hand to the pool (or leave). */
static void *world_main(void *arg)
{
    node_world *nw = arg;
    serve_node *n = nw->node;
    host_world *hw = &nw->hw;
    host_world_place(hw, &cluster_world_ops, nw, n->table, n->net, n->ticker);
    hw->config = serve_host_config(n->o);
    hw->max_ticks = n->o->max_ticks;
    if (host_world_start(hw, nw->why, sizeof nw->why) == 0) {
        atomic_store(&nw->opened, 1);
        return NULL;
    }
    world_gone(nw);
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
        if (nw->hw.deleted)
            forget_registered(n, nw->hw.m.name);
        if (nw->lost)
            log_warn("cluster: this node no longer owns world %s (%s): it stopped ticking it; "
                     "its clients were told to connect again",
                     nw->hw.m.name, nw->why);
        else if (nw->why[0] && !n->stopping && !nw->hw.deleted) {
            log_error("cluster: world %s: %s (tried again in %.0f s)", nw->hw.m.name, nw->why,
                      NODE_RETRY_MS / 1000);
            note_failed(n, nw->hw.m.name);
        }
        pthread_mutex_lock(&n->lock);
        n->worlds[i] = n->worlds[--n->nworlds];
        pthread_mutex_unlock(&n->lock);
        pthread_mutex_destroy(&nw->hw.m.status.lock);
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
        snprintf(held[count++], sizeof held[0], "%s", n->worlds[i]->hw.m.name);
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
    nw->hw.m.metrics_slot = -1;
    snprintf(nw->hw.m.name, sizeof nw->hw.m.name, "%s", name);
    pthread_mutex_init(&nw->hw.m.status.lock, NULL);
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
        pthread_mutex_destroy(&nw->hw.m.status.lock);
        free(nw);
        error_set(err, "cannot start a thread for world %s", name);
        return -1;
    }
    return 1;
}

/* The node's ports: one HTTP and one websocket server for all its worlds. */
/* POST /v1/drain on a node: as SIGTERM, it hands its worlds over and stops. */
static unsigned node_drain_call(void *ctx, char **json)
{
    serve_node *n = ctx;
    return serve_drain_json(atomic_exchange(&n->drain_asked, 1), 0, json);
}

static int node_open_ports(serve_node *n, error_text *err)
{
    const serve_options *o = n->o;
    int fd_reserve = 0;
    if (!(n->table = hub_worlds_create())) {
        error_set(err, "out of memory");
        return -1;
    }
    if (!(n->http = serve_http_open(o, n->auth, &n->status, n->table, &fd_reserve, err)) ||
        (o->probe_port >= 0 && !(n->probe = http_probe_start(n->http, o->probe_port, err))))
        return -1;
    http_server_host_worlds(n->http);
    net_config nc = {.port = o->ws_port,
                     .bind_any = o->bind_any,
                     .auth = n->auth,
                     .tls_cert = o->tls_cert,
                     .tls_key = o->tls_key,
                     .limits = o->limits,
                     .worlds = n->table};
    nc.limits.fd_reserve = fd_reserve;
    if (!(n->net = net_server_start(&nc, err)))
        return -1;
    int tls = o->tls_cert && o->tls_cert[0];
    http_server_set_websocket(n->http, net_server_port(n->net), tls, o->public_ws_url);
    if (!(n->relays = serve_relays_start(n->cl, n->net, n->http, n->name)) ||
        !(n->api = serve_node_api_start(n->cl, o, n->name, n->http))) {
        error_set(err, "out of memory");
        return -1;
    }
    http_server_set_drain(n->http, node_drain_call, n); /* POST /v1/drain */
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
        snprintf(busy[count++], sizeof busy[0], "%s", n->worlds[i]->hw.m.name);
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
            listed = strcmp(n->registered[k], nw->hw.m.name) == 0;
        if (listed || nw->hw.deleted || !atomic_load(&nw->opened)) /* opening: the next listing */
            continue;
        char *scene = NULL;
        error_text err = {{0}};
        int found = cluster_world_get(n->cl, nw->hw.m.name, &scene, &err);
        free(scene);
        if (found != 0)
            continue;
        log_info("cluster: world %s was deleted from the registry: it stops here", nw->hw.m.name);
        nw->hw.deleted = 1; /* read by its end, after the ticker's lock */
        host_world_end(&nw->hw);
    }
}

/* The node's life after its ports are open: take, tick, reap, until stop. */
static int node_loop(serve_node *n, volatile sig_atomic_t *stop, volatile sig_atomic_t *hangup)
{
    int said_standby = 0, first = 1;
    double warned_ms = 0;
    while (!*stop && !atomic_load(&n->drain_asked)) {
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
            host_sleep_ms(NODE_POLL_MS);
    }
    return 0;
}

/* A cluster node's drain (docs/fleet.md): a node stops at once on SIGTERM,
 * but first /readyz turns 503, new clients are refused and the connected
 * ones told (the "draining" message, before their worlds close), and then
 * each world's end releases its lease (world_gone): a standby takes it over
 * from JetStream without waiting for the lease to lapse. */
static void node_drain(serve_node *n)
{
    const char *why = atomic_load(&n->drain_asked)
                          ? "POST /v1/drain: this node hands its worlds to other nodes"
                          : "SIGTERM: this node hands its worlds to other nodes";
    if (n->http)
        http_server_set_draining(n->http, why);
    if (n->net)
        net_server_drain(n->net, why, 0);
}

static void node_stop(serve_node *n)
{
    node_drain(n);
    n->stopping = 1;
    while (n->nworlds > 0) {
        for (int i = 0; i < n->nworlds; i++)
            if (atomic_load(&n->worlds[i]->opened)) /* else still opening: asked next round */
                host_world_end(&n->worlds[i]->hw);
        reap_worlds(n);
        if (n->nworlds)
            host_sleep_ms(10);
    }
    host_ticker_stop(n->ticker);
    serve_relays_stop(n->relays);
    node_forget_worlds(n);
    http_server_stop(n->probe);
    http_server_stop(n->http); /* first: its watchdog reads the net server */
    serve_node_api_free(n->api);
    net_server_stop(n->net);
    hub_worlds_destroy(n->table); /* after both ports: they read it */
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
        !(n->ticker = host_ticker_start(host_ticker_default_workers(), &err)) ||
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
