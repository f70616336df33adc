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

#include "app/app.h"
#include "gl/gl.h"
#include "http/http.h"
#include "scene/scene.h"

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
    int bind_any;
    int demo_actors;
    long max_ticks; /* < 0: run until signalled */
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

static int parse_options(int argc, char **argv, serve_options *o)
{
    memset(o, 0, sizeof *o);
    o->backend = "gl";
    o->http_port = 8080;
    o->demo_actors = 6;
    o->max_ticks = -1;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i];
        if (strcmp(a, "--no-demo") == 0) {
            o->demo_actors = 0;
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
        if (strcmp(a, "--scene") == 0) {
            o->scene_path = v;
        } else if (strcmp(a, "--backend") == 0) {
            o->backend = v;
        } else if (strcmp(a, "--http-port") == 0) {
            if (parse_int(a, v, 0, 65535, &x) != 0)
                return -1;
            o->http_port = (int)x;
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
        a[i].geometry = (collider_geometry){.shape = COLLIDER_SPHERE,
                                            .radius = 0.25 + 0.35 * r[0]};
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
    return (double)w->heights[(size_t)cy * w->width + cx] / w->units_per_m;
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

int app_serve(int argc, char **argv)
{
    serve_options o;
    if (parse_options(argc, argv, &o) != 0)
        return 2;
    error_text err = {{0}};
    scene sc;
    if ((o.scene_path ? scene_load_file(o.scene_path, &sc, &err) : scene_load_default(&sc, &err)) !=
        0) {
        log_error("%s", err.message);
        return 1;
    }
    world w;
    if (scene_create_world(&sc, &w, &err) != 0) {
        log_error("%s", err.message);
        scene_free(&sc);
        return 1;
    }
    http_status status;
    memset(&status, 0, sizeof status);
    pthread_mutex_init(&status.lock, NULL);
    status.world_width = w.width;
    status.world_height = w.height;
    status.cell_size_m = w.cell_size_m;
    status.units_per_m = w.units_per_m;
    status.volume = world_volume(&w);

    int rc = 1;
    sim_params params;
    sim_backend *backend = NULL;
    sim_engine engine;
    memset(&engine, 0, sizeof engine);
    demo_actor *actors = NULL;
    sim_collider *colliders = NULL;
    http_server *http = http_server_start(o.http_port, o.bind_any, &status, &err);
    if (!http) {
        log_error("%s", err.message);
        goto done;
    }
    if (sim_params_from_material(&sc.material, w.cell_size_m, w.units_per_m, w.floor, &params,
                                 &err) != 0 ||
        !(backend = app_backend_create(o.backend, &err)) ||
        sim_engine_init(&engine, &w, &params, backend, sc.active_margin_cells, &err) != 0) {
        log_error("%s", err.message);
        goto done;
    }
    int count = sc.collider_count + o.demo_actors;
    actors = calloc((size_t)o.demo_actors + 1, sizeof *actors);
    colliders = calloc((size_t)count + 1, sizeof *colliders);
    if (!actors || !colliders) {
        log_error("serve: out of memory");
        goto done;
    }
    demo_actors_init(actors, o.demo_actors, &w);

    pthread_mutex_lock(&status.lock);
    status.ready = 1;
    snprintf(status.renderer, sizeof status.renderer, "%s", backend->renderer);
    snprintf(status.backend, sizeof status.backend, "%s", backend->name);
    snprintf(status.method, sizeof status.method, "persson-%s", sim_method_name(params.method));
    snprintf(status.metric, sizeof status.metric, "%s", sim_metric_name(params.metric));
    pthread_mutex_unlock(&status.lock);

    struct sigaction sa;
    memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_signal;
    sigaction(SIGINT, &sa, NULL);
    sigaction(SIGTERM, &sa, NULL);

    log_info("serving scene \"%s\" (%dx%d cells, %s backend, %d demo actors) on "
             "http://127.0.0.1:%d/",
             sc.name, w.width, w.height, backend->name, o.demo_actors, http_server_port(http));
    double period_ms = 1000.0 / sc.tick_hz;
    double next_ms = time_now_ms();
    uint64_t overruns = 0;
    for (long tick = 0; !stop_requested && (o.max_ticks < 0 || tick < o.max_ticks); tick++) {
        double t = (double)tick / sc.tick_hz;
        for (int c = 0; c < sc.collider_count; c++) {
            colliders[c].id = c;
            colliders[c].geometry = &sc.colliders[c].geometry;
            colliders[c].previous_pose = colliders[c].pose;
            colliders[c].pose = collider_motion_pose(&sc.colliders[c].motion, t);
            colliders[c].has_previous = tick > 0;
        }
        for (int a = 0; a < o.demo_actors; a++) {
            sim_collider *c = &colliders[sc.collider_count + a];
            c->id = sc.collider_count + a;
            c->geometry = &actors[a].geometry;
            c->previous_pose = c->pose;
            c->pose = demo_actor_step(&actors[a], &w, 1.0 / sc.tick_hz, t);
            c->has_previous = tick > 0;
        }
        double t0 = time_now_ms();
        sim_tick_report report;
        if (sim_engine_tick(&engine, colliders, count, &report, &err) != 0) {
            log_error("tick %ld: %s", tick, err.message);
            goto done;
        }
        double elapsed = time_now_ms() - t0;
        if (elapsed > period_ms)
            overruns++;
        pthread_mutex_lock(&status.lock);
        status.tick = (uint64_t)tick + 1;
        status.volume = world_volume(&w);
        status.last_tick_ms = elapsed;
        status.overruns = overruns;
        pthread_mutex_unlock(&status.lock);
        next_ms += period_ms;
        if (next_ms < time_now_ms())
            next_ms = time_now_ms(); /* behind: drop the backlog, keep the rate */
        sleep_until_ms(next_ms);
    }
    log_info("stopping after tick %llu (%llu overruns)", (unsigned long long)status.tick,
             (unsigned long long)overruns);
    rc = 0;
done:
    http_server_stop(http);
    free(colliders);
    free(actors);
    sim_engine_free(&engine);
    if (backend)
        backend->destroy(backend);
    world_free(&w);
    scene_free(&sc);
    pthread_mutex_destroy(&status.lock);
    return rc;
}
