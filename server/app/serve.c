/*
 * serve.c: `terrad serve` — the daemon. Its default world (--scene) is an
 * ordinary world of host/ (host/host_world.c): opened, started, ticked on
 * the process's shared pool of sim workers at the scene's rate (poses →
 * windows → deformation → scatter; docs/design.md) beside the worlds
 * created by API, and ended there: an entry of the one table of worlds both
 * ports read like the others (hub.h, hub_worlds), the one its scene's name
 * names and the one a request or hello naming no world finds. Where it
 * differs is its registry backend (default_world_ops): its scene is
 * --scene's, its store --data itself. A tick that overruns
 * its period is counted, and the world does not try to catch up by running
 * ticks back to back (host/host_clock.c). The main thread waits: SIGINT and
 * SIGTERM (or POST /v1/drain, admin) start a drain (docs/fleet.md) — /readyz
 * fails while /healthz stays ok, new clients and worlds are refused naming
 * it, connected clients are told — and once they have all left, or
 * --drain-grace-ms later, the default world ends after its current tick and
 * the daemon stops cleanly (every tick persisted, exit 0); a second signal
 * stops it at once. SIGHUP reads the --auth-file again (serve_security.c).
 * /healthz fails when the ticks or the net thread stop moving.
 *
 * app_serve reads as the daemon's life: open the world (scene, base terrain,
 * recovered store) → the HTTP and websocket ports (serve_open_net) → its
 * simulation, on the ports → ticking → stop. Options: serve_options.c; demo actors,
 * which keep the terrain deforming without clients: host/host_demo.c. With
 * --cluster the daemon is a node of a cluster instead (serve_node.c).
 */
#include <errno.h>
#include <signal.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

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
 * kill a daemon: noted here; the main thread (serve_wait, or a node's loop) reads the
 * auth file again (the log is stderr: nothing to reopen). */
static void on_hangup(int sig)
{
    (void)sig;
    hangup_seen = 1;
}

static volatile sig_atomic_t drain_signal;  /* the first SIGTERM or SIGINT */
static volatile sig_atomic_t signal_drains; /* a single daemon's: set before it serves */

/* The first SIGTERM or SIGINT drains a single daemon (an orchestrator's stop,
 * docs/fleet.md); a second one stops it at once (an operator who will not
 * wait). A cluster node, and a daemon still starting, stop at once. */
static void on_signal(int sig)
{
    (void)sig;
    if (drain_signal || !signal_drains)
        stop_requested = 1;
    drain_signal = 1;
}

/* How often the main thread looks at the signals' flags while the world ticks. */
#define SERVE_WAIT_MS 50

/* Everything the daemon holds; zero means "not made yet", so one stop
 * releases whatever was made. */
typedef struct serve_daemon {
    serve_options o;
    host_world def;      /* the default world: scene, world, store, engine, service, hub */
    host_ticker *ticker; /* the sim workers every world of the daemon ticks on */
    int running;         /* def is on the ticker */
    atomic_int ended;    /* def's end ran (default_ended) */
    int end_rc;
    net_server *net;
    http_server *http;
    hub_worlds *table;      /* the worlds created beside it, which both ports read */
    http_server *probe;     /* --probe-port */
    auth_table *auth;       /* NULL: no tokens, every client an admin (serve_security.c) */
    serve_worlds *worlds;   /* worlds created by API beside the default one (serve_worlds.c) */
    int fd_reserve;         /* descriptors the websocket server leaves free (serve_http_open) */
    atomic_int drain_asked; /* POST /v1/drain (an HTTP thread) */
    int draining;           /* the main thread started the drain (serve_drain) */
    double drain_deadline_ms;
} serve_daemon;

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
static int default_open(host_world *hw, error_text *err)
{
    serve_daemon *d = hw->owner;
    serve_options *o = &d->o;
    host_sim *m = &hw->m;
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
                        .retain_bytes = o->replay_retain_bytes,
                        .fault_path = o->store_fault,
                        .recover_truncate = o->recover_truncate};
    if (store_parse_durability(o->durability, &stc, err) != 0 ||
        !(m->st = store_open(&stc, &m->w, &m->recovery, err)))
        return -1;
    m->status.history.dir = o->data_dir; /* /v1/heights?tick=N rebuilds from it */
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

unsigned serve_drain_json(int already, int grace_ms, char **json)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddBoolToObject(o, "draining", 1);
    cJSON_AddBoolToObject(o, "already", already);
    cJSON_AddNumberToObject(o, "grace_ms", grace_ms);
    *json = json_print_delete(o);
    return 202;
}

/* POST /v1/drain (admin; http_server_set_drain): the main thread drains. */
static unsigned drain_call(void *ctx, char **json)
{
    serve_daemon *d = ctx;
    int again = atomic_exchange(&d->drain_asked, 1);
    return serve_drain_json(again || drain_signal, d->o.drain_grace_ms, json);
}

/* The websocket port (a lobby until the default world joins the table), the
 * created worlds and the watchdogs; before the default world runs. */
static int serve_open_net(serve_daemon *d, error_text *err)
{
    host_sim *m = &d->def.m;
    net_config nc = {.port = d->o.ws_port,
                     .bind_any = d->o.bind_any,
                     .auth = d->auth,
                     .tls_cert = d->o.tls_cert,
                     .tls_key = d->o.tls_key,
                     .limits = d->o.limits,
                     .worlds = d->table};
    nc.limits.fd_reserve = d->fd_reserve;
    if (!(d->net = net_server_start(&nc, err)) ||
        !(d->worlds = serve_worlds_start(&d->o, m, d->http, d->table, d->net, d->ticker, err)))
        return -1;
    http_server_set_drain(d->http, drain_call, d); /* POST /v1/drain */
    signal_drains = 1;
    int tls = d->o.tls_cert && d->o.tls_cert[0];
    /* GET /v1/websocket: the viewer asks where the websocket is, never guesses */
    http_server_set_websocket(d->http, net_server_port(d->net), tls, d->o.public_ws_url);
    http_server_watch(d->http, "tick", http_status_stalled_ms, &m->status, SERVE_STALL_LIMIT_MS);
    http_server_watch(d->http, "net", net_stalled, d->net, SERVE_STALL_LIMIT_MS);
    return 0;
}

/* Ready, before its first tick: the "serving" line, which tells a supervisor
 * (and the tests) that every port is known. */
static int default_registered(host_world *hw, error_text *err)
{
    (void)err;
    serve_daemon *d = hw->owner;
    host_sim *m = &hw->m;
    serve_catch_signals();
    signal(SIGPIPE, SIG_IGN);
    if (d->probe)
        log_info("probes: http://127.0.0.1:%d/healthz (and /readyz, /metrics)",
                 http_server_port(d->probe));
    int tls = d->o.tls_cert && d->o.tls_cert[0];
    log_info("serving scene \"%s\" (%dx%d cells, %s backend, %d demo actors) on "
             "%s://127.0.0.1:%d/ and %s://127.0.0.1:%d/",
             m->sc.name, m->w.width, m->w.height, m->backend->name, d->o.demo_actors,
             tls ? "https" : "http", http_server_port(d->http), tls ? "wss" : "ws",
             net_server_port(d->net));
    return 0;
}

/* Its end ran on a worker (--ticks reached, a signal, or a failed tick). */
static void default_ended(host_world *hw, int rc)
{
    serve_daemon *d = hw->owner;
    if (rc == 0)
        log_info("stopping after tick %llu (%llu overruns)", hw->last_tick, hw->overruns);
    d->end_rc = rc;
    atomic_store(&d->ended, 1);
}

/* Its registry backend: no check after a tick; at its end it leaves the
 * ports as every world does (its clients are told the daemon stops). */
static const host_world_ops default_world_ops = {.open = default_open,
                                                 .registered = default_registered,
                                                 .ended = default_ended,
                                                 .deleted_why = "was deleted",
                                                 .stopped_why = "stopped (the daemon stops)"};

/* The ports on the opened world (HTTP and its probes, the websocket server,
 * the created worlds), then its simulation and ticks: it joins the table of
 * worlds both ports read (host_world_run), an entry like the others, found
 * by its scene's name or by naming no world. */
static int serve_start(serve_daemon *d, error_text *err)
{
    host_sim *m = &d->def.m;
    if (!(d->table = hub_worlds_create())) {
        error_set(err, "out of memory");
        return -1;
    }
    hub_worlds_set_default(d->table, m->sc.name);
    if (!(d->ticker = host_ticker_start(host_ticker_default_workers(), err)) ||
        !(d->http = serve_http_open(&d->o, d->auth, &m->status, d->table, &d->fd_reserve, err)) ||
        (d->o.probe_port >= 0 && !(d->probe = http_probe_start(d->http, d->o.probe_port, err))))
        return -1;
    error_text why = {{0}};
    char *twin = scene_twin_config_json(&m->sc, &why); /* GET /v1/twin, for predicting clients */
    http_server_set_twin(d->http, twin, why.message);
    free(twin);
    if (serve_open_net(d, err) != 0)
        return -1;
    host_world_place(&d->def, &default_world_ops, d, d->table, d->net, d->ticker);
    d->def.config = serve_host_config(&d->o);
    d->def.max_ticks = d->o.max_ticks;
    if (host_world_run(&d->def, err->message, sizeof err->message) != 0)
        return -1;
    d->running = 1;
    return 0;
}

/* The drain begins: readiness off, new clients and worlds refused naming
 * why, connected clients told; the world ticks on for them meanwhile. */
static void serve_drain(serve_daemon *d, const char *why)
{
    d->draining = 1;
    d->drain_deadline_ms = time_now_ms() + (double)d->o.drain_grace_ms;
    http_server_set_draining(d->http, why);
    serve_worlds_drain(d->worlds, why);
    serve_worlds_watch(d->worlds); /* "draining" told before the daemon may stop */
    net_server_drain(d->net, why, d->o.drain_grace_ms);
    log_info("drain: %s: not ready, taking no new clients or worlds; stopping once %d clients "
             "have left, or in %d ms",
             why, net_server_client_count(d->net), d->o.drain_grace_ms);
}

/* Until --ticks, a signal that stops, or a drain's end: the default world
 * ticks on the pool; this thread reads the auth file again on SIGHUP. */
static int serve_wait(serve_daemon *d, error_text *err)
{
    while (!stop_requested && !atomic_load(&d->ended)) {
        if (hangup_seen) {
            hangup_seen = 0;
            serve_security_reload(&d->o, d->auth);
        }
        if (!d->draining && (drain_signal || atomic_load(&d->drain_asked)))
            serve_drain(d, drain_signal ? "SIGTERM" : "POST /v1/drain");
        serve_worlds_watch(d->worlds); /* world_state events */
        if (d->draining) {
            int left = net_server_client_count(d->net);
            if (left == 0 || time_now_ms() >= d->drain_deadline_ms) {
                log_info("drain: %s", left ? "the grace is over" : "every client has left");
                break;
            }
        }
        host_sleep_ms(SERVE_WAIT_MS); /* a signal cuts it short */
    }
    host_world_end(&d->def); /* nothing when it ended already */
    while (!atomic_load(&d->ended))
        host_sleep_ms(1);
    d->running = 0;
    if (d->end_rc == 0)
        return 0;
    error_set(err, "%s", d->def.why);
    return -1;
}

/* Stop the threads, then release in the reverse order of making. */
static void serve_stop(serve_daemon *d)
{
    if (d->running) { /* started, never waited for */
        host_world_end(&d->def);
        while (!atomic_load(&d->ended))
            host_sleep_ms(1);
    }
    serve_worlds_stop(d->worlds); /* its worlds leave the ports first */
    http_server_stop(d->probe);
    http_server_stop(d->http); /* first: its watchdog reads the net server */
    net_server_stop(d->net);
    host_ticker_stop(d->ticker);  /* every world has ended: the workers are joined */
    auth_free(d->auth);           /* after both servers: they check tokens against it */
    hub_worlds_destroy(d->table); /* and read this */
    host_world_free(&d->def);     /* opened, never run: nothing else freed it */
}

int app_serve(int argc, char **argv)
{
    serve_daemon *d = calloc(1, sizeof *d);
    if (!d) {
        log_error("serve: out of memory");
        return 1;
    }
    pthread_mutex_init(&d->def.m.status.lock, NULL);
    d->def.ops = &default_world_ops; /* its open runs before the ports are made */
    d->def.owner = d;
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
        if (host_world_open(&d->def, err.message, sizeof err.message) == 0 &&
            serve_start(d, &err) == 0 && serve_wait(d, &err) == 0)
            rc = 0;
        if (rc != 0 && err.message[0])
            log_error("%s", err.message);
    }
    serve_stop(d);
    pthread_mutex_destroy(&d->def.m.status.lock);
    free(d);
    return rc;
}
