/*
 * serve.c: `terrad serve` — the daemon. The calling thread becomes the sim
 * thread: it alone owns the GL context and runs the fixed-rate tick loop
 * (poses → windows → deformation → scatter; docs/design.md), publishing a
 * status block that the HTTP thread reads. A tick that overruns its period is
 * counted, and the loop does not try to catch up by running ticks back to
 * back. SIGINT and SIGTERM finish the current tick and stop cleanly; SIGHUP reads the
 * --auth-file again between two ticks (serve_security.c). /healthz fails when the tick loop or
 * the net thread stops moving.
 *
 * app_serve reads as the daemon's life: open the world (scene, base terrain,
 * recovered store) → start the threads (hub, HTTP, engine and service, net)
 * → the tick loop → stop. Options: serve_options.c; the world's simulation
 * and one step of the loop: host_sim.c; demo actors, which keep the terrain
 * deforming without clients: host_demo.c. With --cluster the daemon is a
 * node of a cluster instead, ticking several worlds (serve_node.c).
 */
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "app/app.h"
#include "app/serve_internal.h"
#include "http/http.h"
#include "hub/hub.h"
#include "metrics/metrics.h"
#include "net/net.h"
#include "scene/scene.h"
#include "service/service.h"
#include "store/store.h"

static volatile sig_atomic_t stop_requested;
static volatile sig_atomic_t hangup_seen;

/* SIGHUP (a closed terminal, a log rotation's nudge, an operator's reload) must not
 * kill a daemon: noted here; the tick loop (or a node's loop) reads the auth file
 * again (the log is stderr: nothing to reopen). */
static void on_hangup(int sig)
{
    (void)sig;
    hangup_seen = 1;
}

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

/* Everything the daemon holds; zero means "not made yet", so one stop
 * releases whatever was made. */
typedef struct serve_daemon {
    serve_options o;
    host_sim m; /* the one world: scene, world, store, engine, service, hub */
    net_server *net;
    http_server *http;
    http_server *probe;   /* --probe-port */
    auth_table *auth;     /* NULL: no tokens, every client an admin (serve_security.c) */
    serve_worlds *worlds; /* worlds created by API beside the default one (serve_worlds.c) */
} serve_daemon;

static void sleep_until_ms(double deadline_ms)
{
    double now = time_now_ms();
    if (deadline_ms <= now)
        return;
    double wait = deadline_ms - now;
    struct timespec ts = {(time_t)(wait / 1000.0), (long)(fmod(wait, 1000.0) * 1e6)};
    nanosleep(&ts, NULL);
}

static void serve_catch_signals(void)
{
    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    sa.sa_handler = on_hangup;
    sigaction(SIGHUP, &sa, NULL);
}

/* The scene, its world, and the store recovered over the world's base. */
static int serve_open_world(serve_daemon *d, error_text *err)
{
    serve_options *o = &d->o;
    host_sim *m = &d->m;
    if ((o->scene_path ? scene_load_file(o->scene_path, &m->sc, err)
                       : scene_load_default(&m->sc, err)) != 0)
        return -1;
    if (o->tick_hz > 0)
        m->sc.tick_hz = o->tick_hz;
    m->sc.material.tick_s = 1.0 / m->sc.tick_hz; /* per-second rates (refill) follow the tick */
    if (scene_create_world(&m->sc, &m->w, err) != 0)
        return -1;
    /* the base terrain is in w: recover the data directory over it */
    if (!o->data_dir) {
        if (o->demo_in_memory)
            log_info("demo: world in memory (give --data DIR to keep it)");
        else
            log_info("store: none (--no-data): the terrain lives in memory only");
        return 0;
    }
    int removed = 0;
    if (o->fresh && (serve_worlds_fresh(o->data_dir, err) != 0 ||
                     store_remove(o->data_dir, &removed, err) != 0))
        return -1;
    if (o->fresh)
        log_info("store: --fresh: %s started over (%d files removed)", o->data_dir, removed);
    store_config stc = {.dir = o->data_dir,
                        .segment_bytes = o->wal_segment_bytes,
                        .fault_path = o->store_fault,
                        .recover_truncate = o->recover_truncate};
    if (store_parse_durability(o->durability, &stc, err) != 0 ||
        !(m->st = store_open(&stc, &m->w, &m->recovery, err)))
        return -1;
    char dname[32];
    const store_recovery *r = &m->recovery;
    log_info("store: %s (durability %s): recovered tick %llu from %d tile snapshots and %lld "
             "log records in %.1f ms%s",
             o->data_dir, store_durability_name(&stc, dname, sizeof dname),
             (unsigned long long)r->tick, r->tiles_loaded, (long long)r->records_replayed, r->ms,
             r->damage      ? " (DAMAGED: --recover-truncate cut what is listed above)"
             : r->bytes_cut ? " (a torn tail was cut)"
                            : "");
    return 0;
}

/* /healthz's watchdog: the tick loop and the net thread must keep moving. */
#define SERVE_STALL_LIMIT_MS 10000.0

static double net_stalled(const void *arg)
{
    return net_server_stalled_ms((const net_server *)arg);
}

/* Start the threads around the sim thread: hub, HTTP, engine, net; then ready. */
static int serve_start(serve_daemon *d, error_text *err)
{
    host_sim *m = &d->m;
    if (!(m->h = hub_create())) {
        error_set(err, "serve: out of memory");
        return -1;
    }
    int fd_reserve = 0;
    if (!(d->http = serve_http_open(&d->o, d->auth, &m->status, m->h, &fd_reserve, err)) ||
        (d->o.probe_port >= 0 && !(d->probe = http_probe_start(d->http, d->o.probe_port, err))))
        return -1;
    http_server_set_base(d->http, &m->w); /* the base never changes once the world is made */
    error_text why = {{0}};
    char *twin = scene_twin_config_json(&m->sc, &why); /* GET /v1/twin, for predicting clients */
    http_server_set_twin(d->http, twin, why.message);
    free(twin);
    host_sim_config cfg = serve_host_config(&d->o);
    if (host_sim_start(m, &cfg, err) != 0)
        return -1;
    net_config nc = {.port = d->o.ws_port,
                     .bind_any = d->o.bind_any,
                     .auth = d->auth,
                     .tls_cert = d->o.tls_cert,
                     .tls_key = d->o.tls_key,
                     .limits = d->o.limits,
                     .world = host_sim_world_info(m)};
    nc.world.scene_name = m->sc.name;
    nc.limits.fd_reserve = fd_reserve;
    if (!(d->net = net_server_start(&nc, m->h, err)) ||
        !(d->worlds = serve_worlds_start(&d->o, m, d->http, d->net, err)))
        return -1;
    int tls = d->o.tls_cert && d->o.tls_cert[0];
    /* GET /v1/websocket: the viewer asks where the websocket is, never guesses */
    http_server_set_websocket(d->http, net_server_port(d->net), tls, d->o.public_ws_url);
    http_server_watch(d->http, "tick", http_status_stalled_ms, &m->status, SERVE_STALL_LIMIT_MS);
    http_server_watch(d->http, "net", net_stalled, d->net, SERVE_STALL_LIMIT_MS);
    host_sim_ready(m);
    serve_catch_signals();
    signal(SIGPIPE, SIG_IGN);
    /* before the "serving" line, which tells a supervisor (and the tests) that
     * every port is known */
    if (d->probe)
        log_info("probes: http://127.0.0.1:%d/healthz (and /readyz, /metrics)",
                 http_server_port(d->probe));
    log_info("serving scene \"%s\" (%dx%d cells, %s backend, %d demo actors) on "
             "%s://127.0.0.1:%d/ and %s://127.0.0.1:%d/",
             m->sc.name, m->w.width, m->w.height, m->backend->name, d->o.demo_actors,
             tls ? "https" : "http", http_server_port(d->http), tls ? "wss" : "ws",
             net_server_port(d->net));
    return 0;
}

/* The fixed-rate tick loop, until --ticks or a signal. */
static int serve_run_ticks(serve_daemon *d, error_text *err)
{
    host_sim *m = &d->m;
    double period_ms = 1000.0 / m->sc.tick_hz;
    double next_ms = time_now_ms();
    for (long tick = 0; !stop_requested && (d->o.max_ticks < 0 || tick < d->o.max_ticks); tick++) {
        if (host_sim_step(m, tick, net_server_client_count(d->net), err) != 0)
            return -1;
        if (hangup_seen) {
            hangup_seen = 0;
            serve_security_reload(&d->o, d->auth);
        }
        next_ms += period_ms;
        if (next_ms < time_now_ms())
            next_ms = time_now_ms(); /* behind: drop the backlog, keep the rate */
        sleep_until_ms(next_ms);
    }
    log_info("stopping after tick %llu (%llu overruns)",
             (unsigned long long)service_current_tick(m->svc), (unsigned long long)m->overruns);
    return 0;
}

/* Stop the threads, then release in the reverse order of making. */
static void serve_stop(serve_daemon *d)
{
    serve_worlds_stop(d->worlds); /* its worlds leave the ports first */
    if (d->m.h)
        hub_close_reads(d->m.h);
    http_server_stop(d->probe);
    http_server_stop(d->http); /* first: its watchdog reads the net server */
    net_server_stop(d->net);
    auth_free(d->auth); /* after both servers: they check tokens against it */
    host_sim_free(&d->m);
}

int app_serve(int argc, char **argv)
{
    serve_daemon *d = calloc(1, sizeof *d);
    if (!d) {
        log_error("serve: out of memory");
        return 1;
    }
    pthread_mutex_init(&d->m.status.lock, NULL);
    d->m.metrics_slot = -1;
    serve_catch_signals(); /* from the start: a SIGTERM while connecting still stops cleanly */
    cli_result parsed = serve_options_parse(argc, argv, &d->o);
    int rc = parsed == CLI_HELP ? 0 : parsed == CLI_ERROR ? 2 : 1;
    error_text err = {{0}};
    if (parsed == CLI_OK && serve_security_open(&d->o, &d->auth, &err) != 0) {
        log_error("%s", err.message);
    } else if (parsed == CLI_OK && d->o.cluster_urls) {
        /* a node of a cluster: its worlds each tick on their own thread (serve_node.c) */
        signal(SIGPIPE, SIG_IGN);
        rc = serve_node_run(&d->o, d->auth, &stop_requested, &hangup_seen);
    } else if (parsed == CLI_OK) {
        if (serve_open_world(d, &err) == 0) {
            host_sim_status_init(&d->m);
            if (serve_start(d, &err) == 0 && serve_run_ticks(d, &err) == 0)
                rc = 0;
        }
        if (rc != 0 && err.message[0])
            log_error("%s", err.message);
    }
    serve_stop(d);
    pthread_mutex_destroy(&d->m.status.lock);
    free(d);
    return rc;
}
