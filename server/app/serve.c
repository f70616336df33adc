/*
 * serve.c: `terrad serve` — the daemon. The calling thread becomes the sim
 * thread: it alone owns the GL context and runs the fixed-rate tick loop
 * (poses → windows → deformation → scatter; docs/design.md), publishing a
 * status block that the HTTP thread reads. A tick that overruns its period is
 * counted, and the loop does not try to catch up by running ticks back to
 * back. SIGINT and SIGTERM finish the current tick and stop cleanly; SIGHUP reads the
 * --auth-file again between two ticks (serve_security.c). /healthz fails when the tick loop or the
 * net thread stops moving (serve_watch_threads).
 *
 * app_serve reads as the daemon's life: open the world (scene, base terrain,
 * recovered store) → start the threads (hub, HTTP, engine and service, net)
 * → the tick loop → stop. Options: serve_options.c; demo actors, which keep
 * the terrain deforming without clients: serve_demo.c.
 */
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
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
 * kill a daemon: noted here; the tick loop reads the auth file again (the log is
 * stderr: nothing to reopen). */
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
    scene sc;
    world w;
    store *st; /* NULL: memory only */
    store_recovery recovery;
    http_status status;
    sim_params params;
    sim_backend *backend;
    sim_engine *engine;
    ground grd;
    demo_actor *actors;
    sim_collider *extra;
    service *svc;
    net_server *net;
    http_server *http;
    http_server *probe; /* --probe-port */
    hub *h;
    auth_table *auth; /* NULL: no tokens, every client an admin (serve_security.c) */
    char models[64];
    serve_cluster cluster; /* --cluster: the world this node owns */
    int lost_world;        /* the cluster gave the world to another node */
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

static void publish_status(http_status *status, const service *svc, const store *st, double tick_ms,
                           uint64_t overruns, int clients, int colliders)
{
    pthread_mutex_lock(&status->lock);
    if (st) { /* not ready while deformation is refused; reads go on */
        const char *why = store_failure(st);
        status->ready = why[0] == 0;
        snprintf(status->not_ready, sizeof status->not_ready, "%s%s",
                 why[0] ? "storage unavailable, deformation refused: " : "", why);
    }
    status->tick = service_current_tick(svc);
    status->volume = service_volume(svc);
    status->last_tick_ms = tick_ms;
    status->overruns = overruns;
    status->clients = clients;
    status->colliders = colliders;
    status->published_ms = time_now_ms();
    pthread_mutex_unlock(&status->lock);
}

static void publish_metrics(const service_tick_stats *st, const sim_engine *engine,
                            const service *svc, const world *w)
{
    const sim_stage_times *t = &st->report.times;
    metrics_observe_tick_ms(st->tick_ms);
#define OBSERVE_STAGE(name) metrics_observe_stage_ms(#name, t->name);
    SIM_STAGE_LIST(OBSERVE_STAGE)
#undef OBSERVE_STAGE
    metrics_observe_stage_ms("gather_scatter", st->report.gather_scatter_ms);
    metrics_observe_stage_ms("model", st->report.model_ms);
    metrics_set_tick(service_current_tick(svc));
    metrics_set_sim_threads(sim_threads());
    metrics_set_volume(service_volume(svc));
    metrics_set_active_cells(st->report.active_cells);
    metrics_set_colliders(st->colliders);
    if (st->report.refused_windows)
        metrics_count_refused_windows((uint64_t)st->report.refused_windows);
    sim_engine_stats es;
    sim_engine_get_stats(engine, &es);
    metrics_set_memory_bytes("world_heights", world_resident_bytes(w));
    metrics_set_memory_bytes("sim_scratch", es.peak_scratch_bytes);
    /* what the scene's models hold, by stage (docs/models.md) */
#define SET_STAGE_MEMORY(name) metrics_set_stage_memory_bytes(#name, es.memory.name);
    SIM_MEMORY_STAGE_LIST(SET_STAGE_MEMORY)
#undef SET_STAGE_MEMORY
    sim_tile_cache_stats cache;
    sim_backend_tile_cache_stats(sim_engine_backend(engine), &cache);
    metrics_set_memory_bytes("gpu_tile_cache", cache.texture_bytes);
    metrics_set_gpu_tile_cache(cache.uploads, cache.upload_bytes, cache.evictions,
                               cache.resident_tiles);
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

/* --cluster: the world this node owns, its scene from the registry and its
 * store on JetStream (serve_cluster.c). A standby waits here. */
static int serve_open_cluster_world(serve_daemon *d, error_text *err)
{
    serve_catch_signals();
    if (serve_cluster_join(&d->cluster, &d->o, &stop_requested, &d->sc, err) != 0)
        return -1;
    if (d->o.tick_hz > 0)
        d->sc.tick_hz = d->o.tick_hz;
    d->sc.material.tick_s = 1.0 / d->sc.tick_hz;
    if (scene_create_world(&d->sc, &d->w, err) != 0)
        return -1;
    d->st = serve_cluster_open_store(&d->cluster, &d->w, &d->recovery, err);
    return d->st ? 0 : -1;
}

/* The scene, its world, and the store recovered over the world's base. */
static int serve_open_world(serve_daemon *d, error_text *err)
{
    serve_options *o = &d->o;
    if (o->cluster_urls)
        return serve_open_cluster_world(d, err);
    if ((o->scene_path ? scene_load_file(o->scene_path, &d->sc, err)
                       : scene_load_default(&d->sc, err)) != 0)
        return -1;
    if (o->tick_hz > 0)
        d->sc.tick_hz = o->tick_hz;
    d->sc.material.tick_s = 1.0 / d->sc.tick_hz; /* per-second rates (refill) follow the tick */
    if (scene_create_world(&d->sc, &d->w, err) != 0)
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
    if (o->fresh && store_remove(o->data_dir, &removed, err) != 0)
        return -1;
    if (o->fresh)
        log_info("store: --fresh: %s started over (%d files removed)", o->data_dir, removed);
    store_config stc = {.dir = o->data_dir,
                        .segment_bytes = o->wal_segment_bytes,
                        .fault_path = o->store_fault,
                        .recover_truncate = o->recover_truncate};
    if (store_parse_durability(o->durability, &stc, err) != 0 ||
        !(d->st = store_open(&stc, &d->w, &d->recovery, err)))
        return -1;
    char dname[32];
    const store_recovery *r = &d->recovery;
    log_info("store: %s (durability %s): recovered tick %llu from %d tile snapshots and %lld "
             "log records in %.1f ms%s",
             o->data_dir, store_durability_name(&stc, dname, sizeof dname),
             (unsigned long long)r->tick, r->tiles_loaded, (long long)r->records_replayed, r->ms,
             r->damage      ? " (DAMAGED: --recover-truncate cut what is listed above)"
             : r->bytes_cut ? " (a torn tail was cut)"
                            : "");
    return 0;
}

static void serve_status_init(serve_daemon *d)
{
    http_status *s = &d->status;
    s->world_width = d->w.width;
    s->world_height = d->w.height;
    s->cell_size_m = d->w.cell_size_m;
    s->units_per_m = d->w.units_per_m;
    s->tile_size = SERVICE_TILE_SIZE;
    s->tick_hz = d->sc.tick_hz;
    if (d->cluster.cs)
        snprintf(s->world_name, sizeof s->world_name, "%s", d->cluster.world);
    s->volume = world_volume(&d->w);
}

/* The engine on its backend, the scene's ground and the service on them. */
static int serve_start_engine(serve_daemon *d, error_text *err)
{
    world *w = &d->w;
    if (sim_params_from_material(&d->sc.material, w->cell_size_m, w->units_per_m, w->floor,
                                 &d->params, err) != 0 ||
        !(d->backend = app_backend_create(d->o.backend, err)) ||
        !(d->engine =
              sim_engine_create(w, &d->params, d->backend, d->sc.active_margin_cells, err)) ||
        app_ground_attach(&d->sc, w, d->engine, &d->grd, err) != 0 ||
        !(d->svc = service_create(d->engine, d->h, err)))
        return -1;
    service_set_tick_budget(d->svc, d->o.limits.max_tick_cells);
    if (d->st)
        /* go on from the recovered tick, or past it where the store says a
         * client may have seen later (unlogged idle) ticks */
        service_attach_store(d->svc, d->st,
                             d->recovery.tick_floor > d->recovery.tick ? d->recovery.tick_floor
                                                                       : d->recovery.tick);
    d->status.volume = service_volume(d->svc);
    d->status.tick = service_current_tick(d->svc);
    return 0;
}

/* /healthz's watchdog: the tick loop and the net thread must keep moving. */
#define SERVE_STALL_LIMIT_MS 10000.0

static double net_stalled(const void *arg)
{
    return net_server_stalled_ms((const net_server *)arg);
}

static void serve_watch_threads(serve_daemon *d)
{
    http_server_watch(d->http, "tick", http_status_stalled_ms, &d->status, SERVE_STALL_LIMIT_MS);
    http_server_watch(d->http, "net", net_stalled, d->net, SERVE_STALL_LIMIT_MS);
}

static int serve_start_net(serve_daemon *d, error_text *err)
{
    const world *w = &d->w;
    snprintf(d->models, sizeof d->models, "[\"%s\"]", sim_model_name(d->params.model));
    net_config nc = {.port = d->o.ws_port,
                     .bind_any = d->o.bind_any,
                     .token = d->o.token,
                     .auth = d->auth,
                     .tls_cert = d->o.tls_cert,
                     .tls_key = d->o.tls_key,
                     .limits = d->o.limits,
                     .world = {.width = w->width,
                               .height = w->height,
                               .cell_size_m = w->cell_size_m,
                               .units_per_m = w->units_per_m,
                               .tick_hz = d->sc.tick_hz,
                               .tile_size = SERVICE_TILE_SIZE,
                               .height_min = WORLD_HEIGHT_MIN,
                               .height_max = WORLD_HEIGHT_MAX,
                               .models_json = d->models,
                               .name = d->cluster.cs ? d->cluster.world : NULL,
                               .materials_json = "[\"default\"]"}};
    d->net = net_server_start(&nc, d->h, err);
    if (!d->net)
        return -1;
    serve_watch_threads(d);
    return 0;
}

/* Descriptors: HTTP gets a quarter of RLIMIT_NOFILE (8..256 connections),
 * SERVE_FD_STORE stay free for the store and the process, and websocket
 * sockets are refused past the rest (net_conn.c), so that no stranger can
 * take the descriptors the store and the probes need. */
#define SERVE_FD_STORE 32

static unsigned serve_http_connections(void)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0 || rl.rlim_cur == RLIM_INFINITY)
        return HTTP_DEFAULT_CONNECTIONS;
    long n = ((long)rl.rlim_cur - SERVE_FD_STORE) / 4;
    return n < 8 ? 8 : n > HTTP_DEFAULT_CONNECTIONS ? HTTP_DEFAULT_CONNECTIONS : (unsigned)n;
}

static http_server *serve_start_http(serve_daemon *d, error_text *err)
{
    http_limits hl = {.connections = serve_http_connections(),
                      .heights_bytes_per_address = d->o.heights_bytes_per_address,
                      .heights_bytes_total = d->o.heights_bytes_in_flight};
    hl.connections_per_ip = hl.connections < HTTP_DEFAULT_CONNECTIONS_PER_IP
                                ? hl.connections
                                : HTTP_DEFAULT_CONNECTIONS_PER_IP;
    d->o.limits.fd_reserve = SERVE_FD_STORE + (int)hl.connections;
    http_security sec = {.auth = d->auth, .tls_cert = d->o.tls_cert, .tls_key = d->o.tls_key};
    return http_server_start_secure(d->o.http_port, d->o.bind_any, &d->status, d->h, &hl, &sec,
                                    err);
}

/* Start the threads around the sim thread: hub, HTTP, net; then ready. */
static int serve_start(serve_daemon *d, error_text *err)
{
    if (!(d->h = hub_create())) {
        error_set(err, "serve: out of memory");
        return -1;
    }
    if (!(d->http = serve_start_http(d, err)) ||
        (d->o.probe_port >= 0 && !(d->probe = http_probe_start(d->http, d->o.probe_port, err))))
        return -1;
    http_server_set_base(d->http, &d->w); /* the base never changes once the world is made */
    if (serve_start_engine(d, err) != 0 || serve_start_net(d, err) != 0)
        return -1;
    d->actors = calloc((size_t)d->o.demo_actors + 1, sizeof *d->actors);
    d->extra = calloc((size_t)d->o.demo_actors + 1, sizeof *d->extra);
    if (!d->actors || !d->extra) {
        error_set(err, "serve: out of memory");
        return -1;
    }
    demo_actors_init(d->actors, d->o.demo_actors, &d->w);

    pthread_mutex_lock(&d->status.lock);
    d->status.ready = 1;
    snprintf(d->status.renderer, sizeof d->status.renderer, "%s", d->backend->renderer);
    snprintf(d->status.backend, sizeof d->status.backend, "%s", d->backend->name);
    snprintf(d->status.method, sizeof d->status.method, "%s", sim_model_name(d->params.model));
    snprintf(d->status.metric, sizeof d->status.metric, "%s", sim_metric_name(d->params.metric));
    pthread_mutex_unlock(&d->status.lock);

    serve_catch_signals();
    signal(SIGPIPE, SIG_IGN);

    /* before the "serving" line, which tells a supervisor (and the tests) that
     * every port is known */
    if (d->probe)
        log_info("probes: http://127.0.0.1:%d/healthz (and /readyz, /metrics)",
                 http_server_port(d->probe));
    int tls = d->o.tls_cert && d->o.tls_cert[0];
    log_info("serving scene \"%s\" (%dx%d cells, %s backend, %d demo actors) on "
             "%s://127.0.0.1:%d/ and %s://127.0.0.1:%d/",
             d->sc.name, d->w.width, d->w.height, d->backend->name, d->o.demo_actors,
             tls ? "https" : "http", http_server_port(d->http), tls ? "wss" : "ws",
             net_server_port(d->net));
    return 0;
}

/* The demo actors' poses for this tick, as colliders beside the clients'. */
static void serve_step_demo(serve_daemon *d, long tick)
{
    double t = (double)tick / d->sc.tick_hz;
    for (int a = 0; a < d->o.demo_actors; a++) {
        sim_collider *c = &d->extra[a];
        c->id = (int)(0x80000000u + (unsigned)a);
        c->geometry = &d->actors[a].geometry;
        c->previous_pose = c->pose;
        c->pose = demo_actor_step(&d->actors[a], &d->w, 1.0 / d->sc.tick_hz, t);
        c->has_previous = tick > 0;
    }
}

/* The fixed-rate tick loop, until --ticks or a signal. */
static int serve_run_ticks(serve_daemon *d, error_text *err)
{
    double period_ms = 1000.0 / d->sc.tick_hz;
    double next_ms = time_now_ms();
    uint64_t overruns = 0;
    for (long tick = 0; !stop_requested && (d->o.max_ticks < 0 || tick < d->o.max_ticks); tick++) {
        fault_stall("tick"); /* test hook (base/fault.c): a sim thread that stops */
        serve_step_demo(d, tick);
        service_tick_stats stats;
        error_text tick_err = {{0}};
        if (service_tick(d->svc, d->extra, d->o.demo_actors, &stats, &tick_err) != 0) {
            error_set(err, "tick %ld: %s", tick, tick_err.message);
            return -1;
        }
        if (stats.tick_ms > period_ms) {
            overruns++;
            metrics_count_tick_overrun();
        }
        publish_status(&d->status, d->svc, d->st, stats.tick_ms, overruns,
                       net_server_client_count(d->net), stats.colliders);
        publish_metrics(&stats, d->engine, d->svc, &d->w);
        if (hangup_seen) {
            hangup_seen = 0;
            serve_security_reload(&d->o, d->auth);
        }
        if (d->cluster.cs && serve_cluster_check(&d->cluster) != 0) {
            log_warn("cluster: this node no longer owns world %s (%s): stopping, to wait again "
                     "as a standby",
                     d->cluster.world, d->cluster.lost);
            d->lost_world = 1;
            break;
        }
        next_ms += period_ms;
        if (next_ms < time_now_ms())
            next_ms = time_now_ms(); /* behind: drop the backlog, keep the rate */
        sleep_until_ms(next_ms);
    }
    log_info("stopping after tick %llu (%llu overruns)",
             (unsigned long long)service_current_tick(d->svc), (unsigned long long)overruns);
    return 0;
}

/* Stop the threads, then release in the reverse order of making. */
static void serve_stop(serve_daemon *d)
{
    if (d->h)
        hub_close_reads(d->h);
    http_server_stop(d->probe);
    http_server_stop(d->http); /* first: its watchdog reads the net server */
    net_server_stop(d->net);
    auth_free(d->auth); /* after both servers: they check tokens against it */
    service_destroy(d->svc);
    store_close(d->st);
    serve_cluster_leave(&d->cluster);
    free(d->extra);
    free(d->actors);
    sim_engine_destroy(d->engine);
    ground_free(&d->grd);
    if (d->backend)
        d->backend->destroy(d->backend);
    hub_destroy(d->h);
    world_free(&d->w);
    scene_free(&d->sc);
    pthread_mutex_destroy(&d->status.lock);
}

/* A node that lost its world starts over as a standby: the same command
 * line, a fresh process (every thread and port of this run is closed). */
static void serve_restart(int argc, char **argv)
{
    char **args = calloc((size_t)argc + 3, sizeof *args);
    if (!args)
        return;
    args[0] = "terrad";
    args[1] = "serve";
    for (int i = 1; i < argc; i++)
        args[i + 1] = argv[i];
    execv("/proc/self/exe", args);
    log_error("cluster: cannot start again (%s): exiting", strerror(errno));
    free(args);
}

int app_serve(int argc, char **argv)
{
    serve_daemon *d = calloc(1, sizeof *d);
    if (!d) {
        log_error("serve: out of memory");
        return 1;
    }
    pthread_mutex_init(&d->status.lock, NULL);
    cli_result parsed = serve_options_parse(argc, argv, &d->o);
    int rc = parsed == CLI_HELP ? 0 : parsed == CLI_ERROR ? 2 : 1;
    error_text err = {{0}};
    if (parsed == CLI_OK) {
        if (serve_security_open(&d->o, &d->auth, &err) == 0 && serve_open_world(d, &err) == 0) {
            serve_status_init(d);
            if (serve_start(d, &err) == 0 && serve_run_ticks(d, &err) == 0)
                rc = 0;
        }
        if (rc != 0 && err.message[0])
            log_error("%s", err.message);
        if (rc != 0 && !err.message[0] && stop_requested)
            rc = 0; /* a standby stopped before it owned a world */
    }
    serve_stop(d);
    int lost = d->lost_world;
    free(d);
    if (lost)
        serve_restart(argc, argv);
    return rc;
}
