/*
 * loadgen.c: `terrad loadgen` — a load generator for a running daemon, in C so that the service
 * bench measures the daemon and not its clients. One process, one thread, non-blocking sockets:
 * N clients of the C client library (clients/c/terrad_client.h), each with K wheels driving circles
 * inside its own 64 x 64 cell block, a POSE_BATCH every tick, a subscription to that block and a
 * mirror of it. One poll() over every client's socket waits for the next frame or the next tick.
 *
 * Measured while driving: ticks/s (the server's tick counter from GET /v1/stats, before and
 * after), pose→ACK latency (a POSE_BATCH sent → the ACK of the tick that used it; every DELTA of
 * tick t arrives before the ACK of tick t, so this covers the delta too), delta bytes per tick and
 * per changed cell (cells of the mirror that a DELTA changed), frames the server dropped
 * (terrad_frames_dropped_total) and resyncs the clients asked for. At the end every wheel is
 * parked in the air, the world settles, and each mirror is compared with GET /v1/heights of its
 * block: "mirrors_equal". With --worlds W the clients spread over W worlds a daemon created
 * (POST /v1/worlds, named PREFIX0 .. PREFIX<W-1>; client i joins world i mod W), which is what
 * the many-worlds bench drives (tests/bench/bench_worlds.py). Prints a table, or JSON with --json.
 * Exit 0 when every mirror is equal and no client failed, 1 otherwise, 2 for a usage error.
 */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "app/loadgen_internal.h"
#include "terrad_client.h"

#define BLOCK 64      /* cells: each client's block */
#define SEQ_RING 1024 /* send times kept per client, by sequence number */
#define RADIUS_M 0.3  /* wheel radius */

typedef struct lg_client {
    terrad_client *c;
    int index;
    uint32_t sid, last_acked;
    uint32_t *wheels;
    int32_t bx, by; /* block origin, cells */
    int32_t *prev;  /* the mirror as of the last DELTA, for changed cells */
    double sent_ms[SEQ_RING];
    uint32_t sent_seq[SEQ_RING];
    uint64_t changed_cells;
    int measuring, failed;
    char world[96]; /* a created world's name; "" the default world */
    double *lat;    /* ms */
    int64_t lat_n, lat_cap;
} lg_client;

typedef struct lg_options {
    const char *url, *http;
    long clients, wheels, worlds;
    const char *world_prefix;
    double seconds;
    int json;
} lg_options;

static const cli_option loadgen_table[] = {
    {"url", "URL", "the daemon's websocket, ws://HOST:PORT/ (default ws://127.0.0.1:8081/)",
     CLI_AT_STRING(lg_options, url)},
    {"http", "URL", "its HTTP API, http://HOST:PORT (default: the --url host, port 8080)",
     CLI_AT_STRING(lg_options, http)},
    {"clients", "N", "websocket clients (default 8)", CLI_AT_LONG(lg_options, clients, 1, 4096)},
    {"seconds", "S", "seconds of driving (default 5)",
     CLI_AT_DOUBLE(lg_options, seconds, 0.1, 3600)},
    {"wheels-per-client", "K", "wheels each client drives (default 1)",
     CLI_AT_LONG(lg_options, wheels, 1, 64)},
    {"worlds", "W",
     "spread the clients over W created worlds, PREFIX0..PREFIX<W-1>\n"
     "(client i joins world i mod W; default: the default world)",
     CLI_AT_LONG(lg_options, worlds, 1, 4096)},
    {"world-prefix", "PREFIX", "the created worlds' names (default \"w\")",
     CLI_AT_STRING(lg_options, world_prefix)},
    {"json", NULL, "print one JSON object instead of the table", CLI_AT_FLAG(lg_options, json)},
    {0},
};

static const char loadgen_usage[] = "[--url ws://HOST:PORT/] [--clients N] [--seconds S] [options]";

void app_loadgen_usage(FILE *out)
{
    cli_print_help(out, "loadgen", loadgen_usage, loadgen_table);
}

/* ---- Frames: latency at each ACK, changed cells at each DELTA ---- */

static void on_frame(void *user, terrad_client *c, int msg_type, uint64_t tick)
{
    lg_client *k = user;
    (void)tick;
    if (msg_type == TERRAD_MSG_ACK) {
        uint32_t seq = terrad_client_get_stats(c)->ack_seq;
        double now = time_now_ms();
        /* every batch up to seq was covered by this tick (a later one supersedes an earlier) */
        for (uint32_t s = k->last_acked + 1; seq - s < SEQ_RING && s <= seq; s++) {
            uint32_t slot = s % SEQ_RING;
            if (k->sent_seq[slot] != s || !k->measuring)
                continue;
            if (k->lat_n == k->lat_cap &&
                array_grow((void **)&k->lat, &k->lat_cap, k->lat_n + 1, sizeof *k->lat) != 0)
                return;
            k->lat[k->lat_n++] = now - k->sent_ms[slot];
        }
        if (seq > k->last_acked)
            k->last_acked = seq;
    } else if (msg_type == TERRAD_MSG_DELTA && k->prev) {
        const terrad_mirror *m = terrad_client_mirror(c, k->sid);
        if (!m)
            return;
        size_t n = (size_t)m->w * m->h;
        uint64_t changed = 0;
        for (size_t i = 0; i < n; i++)
            changed += m->heights[i] != k->prev[i];
        if (k->measuring)
            k->changed_cells += changed;
        memcpy(k->prev, m->heights, n * sizeof *k->prev);
    }
}

static void on_log(void *user, int level, const char *message)
{
    lg_client *k = user;
    if (level <= TERRAD_LOG_WARN)
        fprintf(stderr, "terrad loadgen: client %d: %s\n", k->index, message);
}

/* ---- Setting up ---- */

/* "ws://host:port/..." → host and port. */
static int parse_ws_url(const char *url, char *host, size_t cap, int *port)
{
    const char *p = strncmp(url, "ws://", 5) == 0 ? url + 5 : NULL;
    if (!p)
        return -1;
    const char *colon = strchr(p, ':'), *slash = strchr(p, '/');
    size_t hl = colon && (!slash || colon < slash) ? (size_t)(colon - p)
                                                   : (size_t)(slash ? slash - p : (long)strlen(p));
    if (hl == 0 || hl >= cap)
        return -1;
    memcpy(host, p, hl);
    host[hl] = 0;
    *port = colon && (!slash || colon < slash) ? atoi(colon + 1) : 80;
    return *port > 0 && *port < 65536 ? 0 : -1;
}

/* Connects client k, creates its wheels and subscribes to its block. */
static int client_start(lg_client *k, const char *host, int port, long wheels)
{
    char err[256];
    char name[32];
    snprintf(name, sizeof name, "loadgen-%d", k->index);
    /* a daemon with tokens: $TERRAD_TOKEN (a driver's), never a flag that /proc shows */
    k->c = terrad_client_connect_world((terrad_client_desc){.host = host,
                                                            .port = port,
                                                            .token = getenv("TERRAD_TOKEN"),
                                                            .name = name,
                                                            .timeout_ms = 30000,
                                                            .hook = on_frame,
                                                            .user = k,
                                                            .log = on_log,
                                                            .log_level = TERRAD_LOG_WARN},
                                       k->world, err, sizeof err);
    if (!k->c) {
        fprintf(stderr, "terrad loadgen: client %d: %s\n", k->index, err);
        return -1;
    }
    const terrad_world_info *w = terrad_client_world(k->c);
    int per_row = w->width / BLOCK > 0 ? w->width / BLOCK : 1;
    int rows = w->height / BLOCK > 0 ? w->height / BLOCK : 1;
    k->bx = (k->index % per_row) * BLOCK;
    k->by = ((k->index / per_row) % rows) * BLOCK;
    k->wheels = calloc((size_t)wheels, sizeof *k->wheels);
    k->prev = calloc((size_t)BLOCK * BLOCK, sizeof *k->prev);
    if (!k->wheels || !k->prev)
        return -1;
    for (long i = 0; i < wheels; i++)
        if (terrad_client_create_collider(k->c,
                                          (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL,
                                                                 .radius = RADIUS_M,
                                                                 .width = 0.2,
                                                                 .no_feedback = 1},
                                          &k->wheels[i]) != 0)
            goto refused;
    if (terrad_client_subscribe(k->c, k->bx, k->by, BLOCK, BLOCK, &k->sid) != 0)
        goto refused;
    return 0;
refused:
    fprintf(stderr, "terrad loadgen: client %d: %s\n", k->index, terrad_client_last_error(k->c));
    return -1;
}

/* ---- Driving ---- */

/* One POSE_BATCH: every wheel of k on its circle at tick step (parked: in the air). */
static void send_poses(lg_client *k, long wheels, long step, double hz, const int32_t *ground,
                       int parked)
{
    const terrad_world_info *w = terrad_client_world(k->c);
    terrad_pose poses[64];
    double cell = w->cell_size_m;
    double cx = (k->bx + BLOCK / 2.0) * cell, cy = (k->by + BLOCK / 2.0) * cell;
    for (long i = 0; i < wheels; i++) {
        double rad = BLOCK * cell * (0.15 + 0.25 * (double)i / (double)wheels);
        double a = step / hz * 0.9 + k->index + 2.4 * (double)i;
        double x = cx + rad * cos(a), y = cy + rad * sin(a);
        int ci = (int)(x / cell), cj = (int)(y / cell);
        double g =
            ground ? ground[(cj - k->by) * BLOCK + (ci - k->bx)] / (double)w->units_per_m : 0.0;
        double z = g + RADIUS_M - 0.05 + (parked ? 5.0 : 0.0);
        double yaw = a + 1.5707963267948966; /* the axle turned with the heading */
        poses[i] = (terrad_pose){k->wheels[i],        (float)x, (float)y, (float)z,
                                 (float)cos(yaw / 2), 0,        0,        (float)sin(yaw / 2)};
    }
    uint32_t seq = 0;
    if (terrad_client_send_poses(k->c, poses, (size_t)wheels, &seq) != 0) {
        k->failed = 1;
        return;
    }
    k->sent_seq[seq % SEQ_RING] = seq;
    k->sent_ms[seq % SEQ_RING] = time_now_ms();
}

/* Services every client until time_now_ms() reaches until: one poll() over all sockets. */
static void service_all(lg_client *cl, long n, struct pollfd *fds, double until)
{
    for (;;) {
        double left = until - time_now_ms();
        for (long i = 0; i < n; i++) {
            fds[i].fd = cl[i].c && !cl[i].failed ? terrad_client_fd(cl[i].c) : -1;
            fds[i].events = POLLIN;
            fds[i].revents = 0;
        }
        int ready = poll(fds, (nfds_t)n, left > 0 ? (int)ceil(left) : 0);
        for (long i = 0; ready > 0 && i < n; i++)
            if (fds[i].revents && terrad_client_poll(cl[i].c, 0) < 0 &&
                !terrad_client_is_open(cl[i].c) && !cl[i].failed) {
                fprintf(stderr, "terrad loadgen: client %d: the connection closed\n", cl[i].index);
                cl[i].failed = 1;
            }
        if (left <= 0)
            return;
    }
}

static int all_complete(lg_client *cl, long n)
{
    for (long i = 0; i < n; i++)
        if (!cl[i].failed && !terrad_client_mirror_complete(cl[i].c, cl[i].sid))
            return 0;
    return 1;
}

static uint64_t sum_stat(lg_client *cl, long n, int which)
{
    uint64_t s = 0;
    for (long i = 0; i < n; i++) {
        const terrad_client_stats *st = terrad_client_get_stats(cl[i].c);
        s += which == 0 ? st->delta_bytes : which == 1 ? st->delta_frames : st->resyncs;
    }
    return s;
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* Drives for o->seconds; fills r's driving figures. */
static void drive(lg_client *cl, const lg_options *o, const lg_http *http, int32_t **grounds,
                  struct pollfd *fds, lg_report *r)
{
    double hz =
        terrad_client_world(cl[0].c)->tick_hz > 0 ? terrad_client_world(cl[0].c)->tick_hz : 60.0;
    lg_stats s0 = {0}, s1 = {0};
    lg_http_stats(http, &s0);
    uint64_t bytes0 = sum_stat(cl, o->clients, 0), frames0 = sum_stat(cl, o->clients, 1);
    uint64_t resync0 = sum_stat(cl, o->clients, 2);
    for (long i = 0; i < o->clients; i++)
        cl[i].measuring = 1;
    double t0 = time_now_ms();
    long steps = (long)(o->seconds * hz);
    for (long step = 0; step < steps; step++) {
        for (long i = 0; i < o->clients; i++)
            if (!cl[i].failed)
                send_poses(&cl[i], o->wheels, step, hz, grounds[i], 0);
        service_all(cl, o->clients, fds, t0 + (step + 1) * 1000.0 / hz);
    }
    double t1 = time_now_ms();
    lg_http_stats(http, &s1);
    for (long i = 0; i < o->clients; i++)
        cl[i].measuring = 0;
    r->drive_s = (t1 - t0) / 1000.0;
    r->hz = hz;
    r->ticks = s1.tick - s0.tick;
    r->ticks_per_s = r->ticks / r->drive_s;
    r->overruns = s1.overruns - s0.overruns;
    if (s1.tick_count > s0.tick_count)
        r->tick_mean_ms =
            (s1.tick_seconds - s0.tick_seconds) / (s1.tick_count - s0.tick_count) * 1e3;
    r->frames_dropped = s1.frames_dropped - s0.frames_dropped;
    r->poses_sent = (uint64_t)steps * (uint64_t)o->clients * (uint64_t)o->wheels;
    r->delta_bytes = sum_stat(cl, o->clients, 0) - bytes0;
    r->delta_frames = sum_stat(cl, o->clients, 1) - frames0;
    r->resyncs = sum_stat(cl, o->clients, 2) - resync0;
    int64_t n = 0;
    for (long i = 0; i < o->clients; i++) {
        n += cl[i].lat_n;
        r->changed_cells += cl[i].changed_cells;
    }
    double *all = malloc((size_t)(n > 0 ? n : 1) * sizeof *all);
    if (all) {
        int64_t at = 0;
        for (long i = 0; i < o->clients; i++) {
            memcpy(all + at, cl[i].lat, (size_t)cl[i].lat_n * sizeof *all);
            at += cl[i].lat_n;
        }
        qsort(all, (size_t)n, sizeof *all, cmp_double);
        r->lat_n = n;
        if (n > 0) {
            r->p50_ms = all[(int64_t)(0.50 * (double)(n - 1))];
            r->p99_ms = all[(int64_t)(0.99 * (double)(n - 1))];
            r->max_ms = all[n - 1];
        }
        free(all);
    }
}

/* Parks every wheel in the air, waits for the world to settle, then compares each mirror with
 * GET /v1/heights of its block (several tries: a late delta may still be on its way). */
static void check_mirrors(lg_client *cl, const lg_options *o, const lg_http *http,
                          struct pollfd *fds, lg_report *r)
{
    double hz = r->hz > 0 ? r->hz : 60.0;
    for (int step = 0; step < 10; step++) {
        for (long i = 0; i < o->clients; i++)
            if (!cl[i].failed)
                send_poses(&cl[i], o->wheels, step, hz, NULL, 1);
        service_all(cl, o->clients, fds, time_now_ms() + 1000.0 / hz);
    }
    int32_t *server = malloc((size_t)BLOCK * BLOCK * sizeof *server);
    r->mirrors_checked = 0;
    r->mirrors_equal = 0;
    for (int attempt = 0; attempt < 20 && server; attempt++) {
        /* quiet: no DELTA for half a second and every mirror complete */
        double deadline = time_now_ms() + 30000;
        uint64_t frames = sum_stat(cl, o->clients, 1);
        do {
            frames = sum_stat(cl, o->clients, 1);
            service_all(cl, o->clients, fds, time_now_ms() + 500);
        } while ((sum_stat(cl, o->clients, 1) != frames || !all_complete(cl, o->clients)) &&
                 time_now_ms() < deadline);
        long equal = 0, checked = 0;
        for (long i = 0; i < o->clients; i++) {
            if (cl[i].failed)
                continue;
            checked++;
            const terrad_mirror *m = terrad_client_mirror(cl[i].c, cl[i].sid);
            if (lg_http_heights(http, cl[i].world, cl[i].bx, cl[i].by, BLOCK, BLOCK, server) == 0 &&
                m && memcmp(server, m->heights, (size_t)BLOCK * BLOCK * sizeof *server) == 0)
                equal++;
        }
        r->mirrors_checked = checked;
        r->mirrors_equal = equal;
        if (equal == checked)
            break;
    }
    free(server);
}

/* Runs the clients; 0 when every mirror equals the server's heights. */
static int run_clients(lg_client *cl, const lg_options *o, const char *host, int port,
                       const lg_http *http, lg_report *r)
{
    int32_t **grounds = calloc((size_t)o->clients, sizeof *grounds);
    struct pollfd *fds = calloc((size_t)o->clients, sizeof *fds);
    int rc = 1;
    if (!grounds || !fds)
        goto done;
    for (long i = 0; i < o->clients; i++) {
        cl[i].index = (int)i;
        if (o->worlds > 0)
            snprintf(cl[i].world, sizeof cl[i].world, "%.60s%ld", o->world_prefix, i % o->worlds);
        if (client_start(&cl[i], host, port, o->wheels) != 0)
            goto done;
    }
    double deadline = time_now_ms() + 60000;
    while (!all_complete(cl, o->clients) && time_now_ms() < deadline)
        service_all(cl, o->clients, fds, time_now_ms() + 50);
    /* the ground under each block, for the wheels' heights (the mirrors hold it now) */
    for (long i = 0; i < o->clients; i++) {
        const terrad_mirror *m = terrad_client_mirror(cl[i].c, cl[i].sid);
        grounds[i] = malloc((size_t)BLOCK * BLOCK * sizeof **grounds);
        if (!grounds[i] || !m)
            goto done;
        memcpy(grounds[i], m->heights, (size_t)BLOCK * BLOCK * sizeof **grounds);
        memcpy(cl[i].prev, m->heights, (size_t)BLOCK * BLOCK * sizeof **grounds);
    }
    drive(cl, o, http, grounds, fds, r);
    check_mirrors(cl, o, http, fds, r);
    for (long i = 0; i < o->clients; i++)
        r->failed_clients += cl[i].failed;
    rc = r->mirrors_checked == o->clients && r->mirrors_equal == r->mirrors_checked ? 0 : 1;
done:
    for (long i = 0; grounds && i < o->clients; i++)
        free(grounds[i]);
    free(grounds);
    free(fds);
    return rc;
}

int app_loadgen(int argc, char **argv)
{
    lg_options o = {.url = "ws://127.0.0.1:8081/",
                    .clients = 8,
                    .seconds = 5,
                    .wheels = 1,
                    .world_prefix = "w"};
    cli_result parsed = cli_parse("loadgen", loadgen_usage, loadgen_table, argc, argv, &o, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    char host[256];
    int port = 0;
    if (parse_ws_url(o.url, host, sizeof host, &port) != 0) {
        fprintf(stderr, "terrad loadgen: --url must be ws://HOST:PORT/ (got %s)\n", o.url);
        return 2;
    }
    lg_http http;
    if (lg_http_init(&http, o.http, host) != 0) {
        fprintf(stderr, "terrad loadgen: --http must be http://HOST:PORT (got %s)\n", o.http);
        return 2;
    }
    lg_client *cl = calloc((size_t)o.clients, sizeof *cl);
    lg_report r = {.clients = o.clients, .wheels_per_client = o.wheels, .mirrors_checked = -1};
    if (!cl)
        return 1;
    lg_stats before = {0};
    int rc = lg_http_stats(&http, &before) != 0 ? 1 : run_clients(cl, &o, host, port, &http, &r);
    if (before.tick == 0 && rc != 0 && r.ticks == 0)
        fprintf(stderr, "terrad loadgen: no answer from %s:%d/v1/stats\n", http.host, http.port);
    lg_print_report(stdout, &r, o.json);
    for (long i = 0; i < o.clients; i++) {
        if (cl[i].c)
            terrad_client_close(cl[i].c);
        free(cl[i].wheels);
        free(cl[i].prev);
        free(cl[i].lat);
    }
    free(cl);
    return rc;
}
