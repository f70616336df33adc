/*
 * serve.c: `terrad serve` — the daemon. The calling thread becomes the sim
 * thread: it alone owns the GL context and runs the fixed-rate tick loop
 * (poses → windows → deformation → scatter), publishing a status block that
 * the HTTP thread reads. A tick that overruns its period is counted, and the
 * loop does not try to catch up by running ticks back to back. SIGINT and
 * SIGTERM finish the current tick and stop cleanly.
 *
 * Without clients, built-in demo actors (spheres sliding and bouncing over
 * the terrain, after Wasmut's stress test) keep the terrain deforming so a
 * newcomer sees it work; --no-demo turns them off.
 */
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <cjson/cJSON.h>

#include "app/app.h"
#include "http/http.h"
#include "hub/hub.h"
#include "metrics/metrics.h"
#include "net/net.h"
#include "scene/scene.h"
#include "service/service.h"
#include "store/store.h"

static volatile sig_atomic_t stop_requested;

static void on_signal(int sig)
{
    (void)sig;
    stop_requested = 1;
}

typedef struct serve_options {
    const char *scene_path;
    const char *backend;
    int http_port;
    int ws_port;
    int bind_any;
    int demo_actors;
    double tick_hz;    /* 0: the scene's */
    const char *token; /* NULL: no token required */
    long max_ticks;    /* < 0: run until signalled */
    net_limits limits;
    const char *data_dir;    /* NULL: memory only (--no-data) */
    const char *durability;  /* every-tick | group:MS | none */
    long wal_segment_bytes;  /* compaction threshold */
    const char *store_fault; /* test hook: writes fail ENOSPC while this file exists */
    cJSON *config;           /* the --config document, kept for its strings */
} serve_options;

static int parse_int(const char *flag, const char *v, long lo, long hi, long *out)
{
    char *end;
    long x = strtol(v, &end, 10);
    if (!*v || *end || x < lo || x > hi) {
        fprintf(stderr, "terrad serve: %s must be an integer in [%ld, %ld] (got \"%s\")\n", flag,
                lo, hi, v);
        return -1;
    }
    *out = x;
    return 0;
}

/* --config FILE: a JSON object whose keys are the long options without the
 * dashes (dashes as underscores) plus "limits" with PROTOCOL.md's names.
 * Flags given on the command line after --config override it. */
static int load_config(const char *path, serve_options *o)
{
    FILE *f = fopen(path, "rb");
    if (!f) {
        fprintf(stderr, "terrad serve: --config %s: cannot open\n", path);
        return -1;
    }
    char *text = malloc(1 << 20);
    size_t n = text ? fread(text, 1, (1 << 20) - 1, f) : 0;
    fclose(f);
    if (!text)
        return -1;
    text[n] = 0;
    cJSON *doc = cJSON_Parse(text);
    free(text);
    if (!cJSON_IsObject(doc)) {
        fprintf(stderr, "terrad serve: --config %s: not a JSON object (syntax error?)\n", path);
        cJSON_Delete(doc);
        return -1;
    }
    o->config = doc;
    const cJSON *item;
    cJSON_ArrayForEach(item, doc)
    {
        const char *k = item->string;
        int ok = 1;
        if (strcmp(k, "scene") == 0 && cJSON_IsString(item))
            o->scene_path = item->valuestring;
        else if (strcmp(k, "backend") == 0 && cJSON_IsString(item))
            o->backend = item->valuestring;
        else if (strcmp(k, "token") == 0 && cJSON_IsString(item))
            o->token = item->valuestring;
        else if (strcmp(k, "data") == 0 && cJSON_IsString(item))
            o->data_dir = item->valuestring;
        else if (strcmp(k, "no_data") == 0 && cJSON_IsBool(item))
            o->data_dir = cJSON_IsTrue(item) ? NULL : o->data_dir;
        else if (strcmp(k, "durability") == 0 && cJSON_IsString(item))
            o->durability = item->valuestring;
        else if (strcmp(k, "store_fault") == 0 && cJSON_IsString(item))
            o->store_fault = item->valuestring;
        else if (strcmp(k, "wal_segment_bytes") == 0 && cJSON_IsNumber(item) &&
                 item->valuedouble >= 4096 && item->valuedouble <= 1e12)
            o->wal_segment_bytes = (long)item->valuedouble;
        else if (strcmp(k, "http_port") == 0 && cJSON_IsNumber(item) && item->valueint >= 0 &&
                 item->valueint <= 65535 && item->valuedouble == item->valueint)
            o->http_port = item->valueint;
        else if (strcmp(k, "ws_port") == 0 && cJSON_IsNumber(item) && item->valueint >= 0 &&
                 item->valueint <= 65535 && item->valuedouble == item->valueint)
            o->ws_port = item->valueint;
        else if (strcmp(k, "bind_any") == 0 && cJSON_IsBool(item))
            o->bind_any = cJSON_IsTrue(item);
        else if (strcmp(k, "demo_actors") == 0 && cJSON_IsNumber(item) && item->valueint >= 0 &&
                 item->valueint <= 256)
            o->demo_actors = item->valueint;
        else if (strcmp(k, "tick_hz") == 0 && cJSON_IsNumber(item) && item->valuedouble >= 1 &&
                 item->valuedouble <= 1000)
            o->tick_hz = item->valuedouble;
        else if (strcmp(k, "limits") == 0 && cJSON_IsObject(item)) {
            const cJSON *l;
            cJSON_ArrayForEach(l, item)
            {
                net_limits *m = &o->limits;
                double v = l->valuedouble;
                int good = cJSON_IsNumber(l) && v > 0 && v <= 1e12;
                const char *lk = l->string;
                if (good && strcmp(lk, "max_message_bytes") == 0)
                    m->max_message_bytes = (size_t)v;
                else if (good && strcmp(lk, "max_colliders") == 0)
                    m->max_colliders = (int)v;
                else if (good && strcmp(lk, "max_poses_per_batch") == 0)
                    m->max_poses_per_batch = (int)v;
                else if (good && strcmp(lk, "max_subscriptions") == 0)
                    m->max_subscriptions = (int)v;
                else if (good && strcmp(lk, "max_subscribed_cells") == 0)
                    m->max_subscribed_cells = (int64_t)v;
                else if (good && strcmp(lk, "max_messages_per_s") == 0)
                    m->max_messages_per_s = v;
                else if (good && strcmp(lk, "messages_burst") == 0)
                    m->messages_burst = v;
                else if (good && strcmp(lk, "max_pending_bytes") == 0)
                    m->max_pending_bytes = (size_t)v;
                else if (good && strcmp(lk, "hello_timeout_s") == 0)
                    m->hello_timeout_s = v;
                else {
                    fprintf(stderr,
                            "terrad serve: --config %s: limits.%s: unknown or not a positive "
                            "number\n",
                            path, lk);
                    return -1;
                }
            }
        } else
            ok = 0;
        if (!ok) {
            fprintf(stderr, "terrad serve: --config %s: %s: unknown key or bad value\n", path, k);
            return -1;
        }
    }
    return 0;
}

static int parse_options(int argc, char **argv, serve_options *o)
{
    memset(o, 0, sizeof *o);
    o->backend = "gl";
    o->http_port = 8080;
    o->ws_port = 8081;
    o->demo_actors = 6;
    o->max_ticks = -1;
    o->limits = net_limits_default();
    o->data_dir = "./data";
    o->durability = "every-tick";
    o->store_fault = getenv("TERRAD_STORE_FAULT");
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--no-demo") == 0) {
            o->demo_actors = 0;
            continue;
        }
        if (strcmp(a, "--no-data") == 0) {
            o->data_dir = NULL;
            continue;
        }
        if (strcmp(a, "--bind-any") == 0) {
            o->bind_any = 1;
            continue;
        }
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v) {
            fprintf(stderr, "terrad serve: %s needs a value (see terrad --help)\n", a);
            return -1;
        }
        i++;
        long x;
        if (strcmp(a, "--config") == 0) {
            if (o->config) {
                fprintf(stderr, "terrad serve: --config given twice\n");
                return -1;
            }
            if (load_config(v, o) != 0)
                return -1;
        } else if (strcmp(a, "--scene") == 0) {
            o->scene_path = v;
        } else if (strcmp(a, "--backend") == 0) {
            o->backend = v;
        } else if (strcmp(a, "--token") == 0) {
            o->token = v;
        } else if (strcmp(a, "--data") == 0) {
            o->data_dir = v;
        } else if (strcmp(a, "--durability") == 0) {
            o->durability = v;
        } else if (strcmp(a, "--store-fault") == 0) {
            o->store_fault = v;
        } else if (strcmp(a, "--wal-segment-bytes") == 0) {
            if (parse_int(a, v, 4096, 1L << 40, &x) != 0)
                return -1;
            o->wal_segment_bytes = x;
        } else if (strcmp(a, "--http-port") == 0) {
            if (parse_int(a, v, 0, 65535, &x) != 0)
                return -1;
            o->http_port = (int)x;
        } else if (strcmp(a, "--ws-port") == 0) {
            if (parse_int(a, v, 0, 65535, &x) != 0)
                return -1;
            o->ws_port = (int)x;
        } else if (strcmp(a, "--tick-hz") == 0) {
            if (parse_int(a, v, 1, 1000, &x) != 0)
                return -1;
            o->tick_hz = (double)x;
        } else if (strcmp(a, "--demo-actors") == 0) {
            if (parse_int(a, v, 0, 256, &x) != 0)
                return -1;
            o->demo_actors = (int)x;
        } else if (strcmp(a, "--ticks") == 0) {
            if (parse_int(a, v, 0, 1000000000, &x) != 0)
                return -1;
            o->max_ticks = x;
        } else {
            fprintf(stderr, "terrad serve: unknown option %s (see terrad --help)\n", a);
            return -1;
        }
    }
    return 0;
}

/* A sphere that slides across the world in a straight line, reflects off the
 * edges and bobs up and down, dipping into the terrain at the bottom. */
typedef struct demo_actor {
    collider_geometry geometry;
    double x, y, vx, vy, phase;
} demo_actor;

static void demo_actors_init(demo_actor *a, int count, const world *w)
{
    double size_x = w->width * w->cell_size_m, size_y = w->height * w->cell_size_m;
    uint32_t state = 12345u;
    for (int i = 0; i < count; i++) {
        /* a fixed LCG: the demo is the same every run */
        double r[5];
        for (int k = 0; k < 5; k++) {
            state = state * 1664525u + 1013904223u;
            r[k] = (state >> 8) / 16777216.0;
        }
        a[i].geometry = (collider_geometry){.shape = COLLIDER_SPHERE, .radius = 0.25 + 0.35 * r[0]};
        a[i].x = size_x * (0.1 + 0.8 * r[1]);
        a[i].y = size_y * (0.1 + 0.8 * r[2]);
        double speed = 0.6 + 1.4 * r[3], heading = 2.0 * M_PI * r[4];
        a[i].vx = speed * cos(heading);
        a[i].vy = speed * sin(heading);
        a[i].phase = r[4] * 6.0;
    }
}

static double terrain_height_m(const world *w, double x, double y)
{
    int cx = (int)floor(x / w->cell_size_m), cy = (int)floor(y / w->cell_size_m);
    if (cx < 0)
        cx = 0;
    if (cy < 0)
        cy = 0;
    if (cx >= w->width)
        cx = w->width - 1;
    if (cy >= w->height)
        cy = w->height - 1;
    return (double)world_height_at(w, cx, cy) / w->units_per_m;
}

static collider_pose demo_actor_step(demo_actor *a, const world *w, double dt, double time_s)
{
    double size_x = w->width * w->cell_size_m, size_y = w->height * w->cell_size_m;
    a->x += a->vx * dt;
    a->y += a->vy * dt;
    if (a->x < 0 || a->x > size_x) {
        a->vx = -a->vx;
        a->x = a->x < 0 ? -a->x : 2 * size_x - a->x;
    }
    if (a->y < 0 || a->y > size_y) {
        a->vy = -a->vy;
        a->y = a->y < 0 ? -a->y : 2 * size_y - a->y;
    }
    double ground = terrain_height_m(w, a->x, a->y);
    double bob = fabs(sin(1.3 * time_s + a->phase));
    double z = ground + a->geometry.radius * (0.6 + 1.2 * bob);
    return (collider_pose){{a->x, a->y, z}, {1, 0, 0, 0}};
}

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

int app_serve(int argc, char **argv)
{
    serve_options o;
    if (parse_options(argc, argv, &o) != 0) {
        cJSON_Delete(o.config);
        return 2;
    }
    error_text err = {{0}};
    scene sc;
    if ((o.scene_path ? scene_load_file(o.scene_path, &sc, &err) : scene_load_default(&sc, &err)) !=
        0) {
        log_error("%s", err.message);
        cJSON_Delete(o.config);
        return 1;
    }
    if (o.tick_hz > 0)
        sc.tick_hz = o.tick_hz;
    sc.material.tick_s = 1.0 / sc.tick_hz; /* per-second rates (refill) follow the tick */
    world w;
    if (scene_create_world(&sc, &w, &err) != 0) {
        log_error("%s", err.message);
        scene_free(&sc);
        cJSON_Delete(o.config);
        return 1;
    }
    /* the base terrain is in w: recover the data directory over it */
    store *st = NULL;
    store_recovery recovery = {0};
    if (o.data_dir) {
        store_config stc = {
            .dir = o.data_dir, .segment_bytes = o.wal_segment_bytes, .fault_path = o.store_fault};
        if (store_parse_durability(o.durability, &stc, &err) != 0 ||
            !(st = store_open(&stc, &w, &recovery, &err))) {
            log_error("%s", err.message);
            world_free(&w);
            scene_free(&sc);
            cJSON_Delete(o.config);
            return 1;
        }
        char dname[32];
        log_info("store: %s (durability %s): recovered tick %llu from %d tile snapshots and %lld "
                 "log records in %.1f ms%s",
                 o.data_dir, store_durability_name(&stc, dname, sizeof dname),
                 (unsigned long long)recovery.tick, recovery.tiles_loaded,
                 (long long)recovery.records_replayed, recovery.ms,
                 recovery.bytes_cut ? " (a torn tail was cut)" : "");
    } else {
        log_info("store: none (--no-data): the terrain lives in memory only");
    }
    http_status status;
    memset(&status, 0, sizeof status);
    pthread_mutex_init(&status.lock, NULL);
    status.world_width = w.width;
    status.world_height = w.height;
    status.cell_size_m = w.cell_size_m;
    status.units_per_m = w.units_per_m;
    status.tile_size = SERVICE_TILE_SIZE;
    status.tick_hz = sc.tick_hz;
    status.volume = world_volume(&w);

    int rc = 1;
    sim_params params;
    sim_backend *backend = NULL;
    sim_engine *engine = NULL;
    ground grd;
    memset(&grd, 0, sizeof grd);
    demo_actor *actors = NULL;
    sim_collider *extra = NULL;
    service *svc = NULL;
    net_server *net = NULL;
    http_server *http = NULL;
    char models[64];
    hub *h = hub_create();
    if (!h) {
        log_error("serve: out of memory");
        goto done;
    }
    http = http_server_start(o.http_port, o.bind_any, &status, h, &err);
    if (!http) {
        log_error("%s", err.message);
        goto done;
    }
    if (sim_params_from_material(&sc.material, w.cell_size_m, w.units_per_m, w.floor, &params,
                                 &err) != 0 ||
        !(backend = app_backend_create(o.backend, &err)) ||
        !(engine = sim_engine_create(&w, &params, backend, sc.active_margin_cells, &err)) ||
        app_ground_attach(&sc, &w, engine, &grd, &err) != 0 ||
        !(svc = service_create(engine, h, &err))) {
        log_error("%s", err.message);
        goto done;
    }
    if (st)
        service_attach_store(svc, st, recovery.tick);
    status.volume = service_volume(svc);
    status.tick = service_current_tick(svc);
    snprintf(models, sizeof models, "[\"%s\"]", sim_model_name(params.model));
    net_config nc = {.port = o.ws_port,
                     .bind_any = o.bind_any,
                     .token = o.token,
                     .limits = o.limits,
                     .world = {.width = w.width,
                               .height = w.height,
                               .cell_size_m = w.cell_size_m,
                               .units_per_m = w.units_per_m,
                               .tick_hz = sc.tick_hz,
                               .tile_size = SERVICE_TILE_SIZE,
                               .height_min = WORLD_HEIGHT_MIN,
                               .height_max = WORLD_HEIGHT_MAX,
                               .models_json = models,
                               .materials_json = "[\"default\"]"}};
    net = net_server_start(&nc, h, &err);
    if (!net) {
        log_error("%s", err.message);
        goto done;
    }
    actors = calloc((size_t)o.demo_actors + 1, sizeof *actors);
    extra = calloc((size_t)o.demo_actors + 1, sizeof *extra);
    if (!actors || !extra) {
        log_error("serve: out of memory");
        goto done;
    }
    demo_actors_init(actors, o.demo_actors, &w);

    pthread_mutex_lock(&status.lock);
    status.ready = 1;
    snprintf(status.renderer, sizeof status.renderer, "%s", backend->renderer);
    snprintf(status.backend, sizeof status.backend, "%s", backend->name);
    snprintf(status.method, sizeof status.method, "%s", sim_model_name(params.model));
    snprintf(status.metric, sizeof status.metric, "%s", sim_metric_name(params.metric));
    pthread_mutex_unlock(&status.lock);

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);
    signal(SIGPIPE, SIG_IGN);

    log_info("serving scene \"%s\" (%dx%d cells, %s backend, %d demo actors) on "
             "http://127.0.0.1:%d/ and ws://127.0.0.1:%d/",
             sc.name, w.width, w.height, backend->name, o.demo_actors, http_server_port(http),
             net_server_port(net));
    double period_ms = 1000.0 / sc.tick_hz;
    double next_ms = time_now_ms();
    uint64_t overruns = 0;
    for (long tick = 0; !stop_requested && (o.max_ticks < 0 || tick < o.max_ticks); tick++) {
        double t = (double)tick / sc.tick_hz;
        for (int a = 0; a < o.demo_actors; a++) {
            sim_collider *c = &extra[a];
            c->id = (int)(0x80000000u + (unsigned)a);
            c->geometry = &actors[a].geometry;
            c->previous_pose = c->pose;
            c->pose = demo_actor_step(&actors[a], &w, 1.0 / sc.tick_hz, t);
            c->has_previous = tick > 0;
        }
        service_tick_stats stats;
        if (service_tick(svc, extra, o.demo_actors, &stats, &err) != 0) {
            log_error("tick %ld: %s", tick, err.message);
            goto done;
        }
        if (stats.tick_ms > period_ms) {
            overruns++;
            metrics_count_tick_overrun();
        }
        publish_status(&status, svc, st, stats.tick_ms, overruns, net_server_client_count(net),
                       stats.colliders);
        publish_metrics(&stats, engine, svc, &w);
        next_ms += period_ms;
        if (next_ms < time_now_ms())
            next_ms = time_now_ms(); /* behind: drop the backlog, keep the rate */
        sleep_until_ms(next_ms);
    }
    log_info("stopping after tick %llu (%llu overruns)",
             (unsigned long long)service_current_tick(svc), (unsigned long long)overruns);
    rc = 0;
done:
    if (h)
        hub_close_reads(h);
    net_server_stop(net);
    http_server_stop(http);
    service_destroy(svc);
    store_close(st);
    free(extra);
    free(actors);
    sim_engine_destroy(engine);
    ground_free(&grd);
    if (backend)
        backend->destroy(backend);
    hub_destroy(h);
    world_free(&w);
    scene_free(&sc);
    pthread_mutex_destroy(&status.lock);
    cJSON_Delete(o.config);
    return rc;
}
