// ctest-timeout: 120
/*
 * test_c_client: the C client library (clients/c/terrad_client.h) against the
 * real daemon on loopback.
 *
 * Starts `$TERRAD_BIN serve --http-port 0 --ws-port 0 --backend cpu --no-data
 * --no-demo` (unless TERRAD_WS_PORT and TERRAD_HTTP_PORT name a running
 * one), connects, drives a wheel (a cylinder turned to roll along x) across
 * the dunes for about three seconds with a pose every tick while subscribed
 * to the strip it ploughs, then parks it in the air and checks:
 *   - the mirror rebuilt from snapshots and deltas equals GET /v1/heights of
 *     the strip, bit for bit, at the same tick (the client keeps a copy of
 *     its mirror at every ACK; /v1/heights names its tick);
 *   - Σh (GET /v1/stats volume) is unchanged;
 *   - ACKs and CONTACT frames came, with penetrating volume > 0 in the snow;
 *   - refusals come back as protocol errors (outside_world, unknown_collider);
 *   - another client's lugged wheel in COLLIDERS frames (PROTOCOL.md, the
 *     grousers extension): a subscription with grousers reads its grousers
 *     exactly and its phase, one without reads the rim, grousers all zero;
 *   - SIGTERM stops the daemon with exit status 0.
 * Prints "N passed, N failed"; exits 77 only when the daemon binary is missing.
 */
#include <arpa/inet.h>
#include <cjson/cJSON.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <libwebsockets.h>

#include "check.h"
#include "terrad_client.h"

static char log_path[256];

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void sleep_s(double s)
{
    if (s <= 0)
        return;
    struct timespec ts = {(time_t)s, (long)((s - (double)(time_t)s) * 1e9)};
    nanosleep(&ts, NULL);
}

/* ---- the daemon ------------------------------------------------------------ */

static pid_t daemon_pid;

static void print_log_tail(void)
{
    if (!log_path[0])
        return;
    FILE *f = fopen(log_path, "r");
    if (!f)
        return;
    fseek(f, 0, SEEK_END);
    long size = ftell(f);
    fseek(f, size > 6000 ? size - 6000 : 0, SEEK_SET);
    printf("---- daemon stderr (tail) ----\n");
    char buf[1024];
    size_t n;
    while ((n = fread(buf, 1, sizeof buf, f)) > 0)
        fwrite(buf, 1, n, stdout);
    printf("---- end ----\n");
    fclose(f);
}

/* Returns 0 with the ports, 77 when the binary is missing, 1 on failure. */
static int start_daemon(int *http_port, int *ws_port)
{
    const char *bin = getenv("TERRAD_BIN");
    if (!bin || !*bin)
        bin = "build/terrad";
    if (access(bin, X_OK) != 0) {
        printf("skip: no daemon binary at %s\n", bin);
        return 77;
    }
    snprintf(log_path, sizeof log_path, "/tmp/test_c_client.%d.log", (int)getpid());
    int fd = open(log_path, O_CREAT | O_TRUNC | O_WRONLY, 0644);
    if (fd < 0)
        return 1;
    pid_t pid = fork();
    if (pid < 0)
        return 1;
    if (pid == 0) {
        dup2(fd, 2);
        int devnull = open("/dev/null", O_RDWR);
        if (devnull >= 0)
            dup2(devnull, 0);
        execl(bin, bin, "serve", "--http-port", "0", "--ws-port", "0", "--backend", "cpu",
              "--no-demo", "--no-data", (char *)NULL);
        _exit(127);
    }
    close(fd);
    daemon_pid = pid;
    double deadline = now_s() + 60;
    while (now_s() < deadline) {
        FILE *f = fopen(log_path, "r");
        char line[2048];
        while (f && fgets(line, sizeof line, f)) {
            const char *h = strstr(line, "http://127.0.0.1:");
            const char *w = h ? strstr(h, "ws://127.0.0.1:") : NULL;
            if (h && w) {
                *http_port = atoi(h + strlen("http://127.0.0.1:"));
                *ws_port = atoi(w + strlen("ws://127.0.0.1:"));
                fclose(f);
                return 0;
            }
        }
        if (f)
            fclose(f);
        int st;
        if (waitpid(pid, &st, WNOHANG) == pid) {
            printf("the daemon exited before listening (status %d)\n", st);
            daemon_pid = 0;
            print_log_tail();
            return 1;
        }
        sleep_s(0.05);
    }
    printf("the daemon did not print its ports within 60 s\n");
    print_log_tail();
    return 1;
}

static int stop_daemon(void)
{
    if (!daemon_pid)
        return -1;
    kill(daemon_pid, SIGTERM);
    double deadline = now_s() + 15;
    int st = 0;
    while (now_s() < deadline) {
        pid_t r = waitpid(daemon_pid, &st, WNOHANG);
        if (r == daemon_pid) {
            daemon_pid = 0;
            return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
        }
        sleep_s(0.05);
    }
    kill(daemon_pid, SIGKILL);
    waitpid(daemon_pid, &st, 0);
    daemon_pid = 0;
    return -2;
}

/* ---- raw HTTP/1.0 GET ------------------------------------------------------ */

typedef struct http_reply {
    int status;
    long long tick; /* X-Terrad-Tick, -1 when absent */
    char *body;
    size_t len;
} http_reply;

static int http_get(int port, const char *path, http_reply *r)
{
    memset(r, 0, sizeof *r);
    r->tick = -1;
    int s = socket(AF_INET, SOCK_STREAM, 0);
    if (s < 0)
        return -1;
    struct timeval tv = {10, 0};
    setsockopt(s, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    struct sockaddr_in a = {0};
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t)port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(s, (struct sockaddr *)&a, sizeof a) != 0) {
        close(s);
        return -1;
    }
    char req[512];
    int n = snprintf(req, sizeof req,
                     "GET %s HTTP/1.0\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n", path);
    if (write(s, req, (size_t)n) != n) {
        close(s);
        return -1;
    }
    size_t cap = 65536, len = 0;
    char *buf = malloc(cap + 1);
    for (;;) {
        if (len == cap) {
            cap *= 2;
            char *b = realloc(buf, cap + 1);
            if (!b)
                break;
            buf = b;
        }
        ssize_t got = read(s, buf + len, cap - len);
        if (got <= 0)
            break;
        len += (size_t)got;
    }
    close(s);
    buf[len] = 0;
    char *end = strstr(buf, "\r\n\r\n");
    if (!end || sscanf(buf, "HTTP/%*s %d", &r->status) != 1) {
        free(buf);
        return -1;
    }
    *end = 0;
    for (char *p = buf; (p = strchr(p, '\n')) != NULL;) {
        p++;
        if (strncasecmp(p, "X-Terrad-Tick:", 14) == 0)
            r->tick = atoll(p + 14);
    }
    size_t body = (size_t)(end + 4 - buf);
    r->len = len - body;
    r->body = malloc(r->len + 1);
    memcpy(r->body, buf + body, r->len);
    r->body[r->len] = 0;
    free(buf);
    return 0;
}

/* Σh and tick from /v1/stats; 0 on success. */
static int get_stats(int port, long long *volume, long long *tick)
{
    http_reply r;
    if (http_get(port, "/v1/stats", &r) != 0)
        return -1;
    cJSON *j = cJSON_Parse(r.body);
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(j, "volume");
    const cJSON *t = cJSON_GetObjectItemCaseSensitive(j, "tick");
    int ok = r.status == 200 && cJSON_IsNumber(v) && cJSON_IsNumber(t);
    if (ok) {
        *volume = (long long)v->valuedouble;
        *tick = (long long)t->valuedouble;
    }
    cJSON_Delete(j);
    free(r.body);
    return ok ? 0 : -1;
}

/* GET /v1/heights of a rectangle into out (w*h int32); returns its tick or -1. */
static long long get_heights(int port, int x, int y, int w, int h, int32_t *out)
{
    char path[128];
    snprintf(path, sizeof path, "/v1/heights?x=%d&y=%d&w=%d&h=%d", x, y, w, h);
    http_reply r;
    if (http_get(port, path, &r) != 0)
        return -1;
    long long tick = -1;
    if (r.status == 200 && r.len == (size_t)w * h * 4) {
        for (size_t i = 0; i < (size_t)w * h; i++) {
            const uint8_t *p = (const uint8_t *)r.body + 4 * i;
            out[i] = (int32_t)((uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 |
                               (uint32_t)p[3] << 24);
        }
        tick = r.tick >= 0 ? r.tick : 0;
    } else {
        printf("GET %s: status %d, %zu bytes\n", path, r.status, r.len);
    }
    free(r.body);
    return tick;
}

/* ---- mirror history: a copy of the mirror at every ACK -------------------- */

#define HISTORY 256

typedef struct history {
    uint32_t sid;
    size_t cells;
    uint64_t ticks[HISTORY];
    int32_t *copies; /* HISTORY * cells */
    int complete[HISTORY];
} history;

static void on_frame(void *user, terrad_client *c, int msg_type, uint64_t tick)
{
    history *h = user;
    if (msg_type != TERRAD_MSG_ACK || !h->sid)
        return;
    const terrad_mirror *m = terrad_client_mirror(c, h->sid);
    if (!m)
        return;
    size_t slot = tick % HISTORY;
    h->ticks[slot] = tick;
    memcpy(h->copies + slot * h->cells, m->heights, h->cells * sizeof(int32_t));
    h->complete[slot] = terrad_client_mirror_complete(c, h->sid);
}

/* ---- the drive ------------------------------------------------------------- */

static void drive(int http_port, int ws_port)
{
    history hist;
    memset(&hist, 0, sizeof hist);
    char err[512];
    terrad_client *c = terrad_client_connect(
        (terrad_client_desc){
            .port = ws_port, .name = "test_c_client", .hook = on_frame, .user = &hist},
        err, sizeof err);
    CHECK(c != NULL, "connect + hello -> world: %s", err);
    if (!c)
        return;
    const terrad_world_info *w = terrad_client_world(c);
    CHECK(w->width > 0 && w->height > 0 && w->tile_size > 0 && w->cell_size_m > 0 &&
              w->units_per_m > 0 && w->tick_hz > 0,
          "world info: %dx%d tile %d cell %g units %d hz %g", w->width, w->height, w->tile_size,
          w->cell_size_m, w->units_per_m, w->tick_hz);
    if (w->width < 64 || w->height < 64) {
        terrad_client_close(c);
        return;
    }
    const double cell = w->cell_size_m, units = w->units_per_m, hz = w->tick_hz;

    /* refusals are protocol errors, and the connection goes on */
    uint32_t sid_bad = 0;
    int rc = terrad_client_subscribe(c, w->width - 4, 0, 8, 8, &sid_bad);
    CHECK(rc == TERRAD_E_OUTSIDE_WORLD, "subscribe past the edge: %d (%s)", rc,
          terrad_client_last_error(c));
    rc = terrad_client_delete_collider(c, 0x7fffff00u);
    CHECK(rc == TERRAD_E_UNKNOWN_COLLIDER, "delete an unknown collider: %d (%s)", rc,
          terrad_client_last_error(c));
    rc = terrad_client_create_collider(
        c, (terrad_collider_desc){.shape = TERRAD_SHAPE_SPHERE, .radius = NAN}, NULL);
    CHECK(rc == TERRAD_E_BAD_VALUE, "a NaN radius is refused locally: %d", rc);

    /* the strip */
    const int rw = w->width - 16 < 160 ? w->width - 16 : 160, rh = 48;
    const int rx = 8, ry = w->height / 2 - rh / 2, yc = w->height / 2;
    const size_t cells = (size_t)rw * rh;
    int32_t *server = malloc(cells * sizeof *server);
    int32_t *row = malloc((size_t)rw * sizeof *row);
    hist.cells = cells;
    hist.copies = calloc(HISTORY * cells, sizeof(int32_t));

    long long vol0 = 0, tick0 = 0;
    CHECK(get_stats(http_port, &vol0, &tick0) == 0, "GET /v1/stats");
    CHECK(get_heights(http_port, rx, yc, rw, 1, row) >= 0, "GET /v1/heights of the path");

    uint32_t wheel = 0;
    const double radius = 0.3;
    rc = terrad_client_create_collider(c,
                                       (terrad_collider_desc){.shape = TERRAD_SHAPE_CYLINDER,
                                                              .radius = radius,
                                                              .half_length = 0.1},
                                       &wheel);
    CHECK(rc == 0 && wheel > 0, "collider_create cylinder: %d (%s)", rc,
          terrad_client_last_error(c));
    uint32_t sid = 0;
    rc = terrad_client_subscribe(c, rx, ry, (uint32_t)rw, (uint32_t)rh, &sid);
    CHECK(rc == 0 && sid > 0, "subscribe: %d (%s)", rc, terrad_client_last_error(c));
    hist.sid = sid;
    double t_end = now_s() + 5;
    while (!terrad_client_mirror_complete(c, sid) && now_s() < t_end)
        terrad_client_poll(c, 50);
    CHECK(terrad_client_mirror_complete(c, sid), "the snapshot of the subscription arrives");

    /* drive: a pose every tick, the cylinder's axis turned onto world y */
    const float qw = (float)cos(M_PI / 4), qx = (float)sin(M_PI / 4);
    const int ticks = (int)(3 * hz);
    const double x0 = (rx + 12) * cell, x1 = (rx + rw - 12) * cell, y = (yc + 0.5) * cell;
    int64_t max_volume = 0;
    uint64_t contact_frames0 = terrad_client_get_stats(c)->contact_frames;
    double next = now_s();
    int send_errors = 0;
    for (int i = 0; i < ticks && terrad_client_is_open(c); i++) {
        double x = x0 + (x1 - x0) * i / (ticks - 1);
        int col = (int)(x / cell) - rx;
        col = col < 0 ? 0 : col >= rw ? rw - 1 : col;
        double ground = row[col] / units;
        terrad_pose p = {wheel, (float)x, (float)y, (float)(ground + radius - 0.06), qw, qx, 0, 0};
        if (terrad_client_send_poses(c, &p, 1, NULL) != 0)
            send_errors++;
        next += 1 / hz;
        while (now_s() < next && terrad_client_is_open(c))
            terrad_client_poll(c, (int)((next - now_s()) * 1000) + 1);
        terrad_contact ct;
        if (terrad_client_contact(c, wheel, &ct, NULL) && ct.volume > max_volume)
            max_volume = ct.volume;
    }
    const terrad_client_stats *st = terrad_client_get_stats(c);
    CHECK(send_errors == 0, "every pose batch was sent");
    /* behaviour, not speed: a loaded machine may merge ticks, so no count per batch */
    CHECK(st->acks > 0, "ACKs came: %llu for %d batches", (unsigned long long)st->acks, ticks);
    CHECK(st->contact_frames - contact_frames0 > 0, "CONTACT frames came: %llu",
          (unsigned long long)(st->contact_frames - contact_frames0));
    CHECK(max_volume > 0, "penetrating volume > 0 in the snow (max %lld)", (long long)max_volume);
    CHECK(st->delta_frames > 2, "DELTA frames came: %llu", (unsigned long long)st->delta_frames);
    CHECK(st->errors == 0, "no unsolicited errors (%llu; last: %s)", (unsigned long long)st->errors,
          terrad_client_last_error(c));

    /* park in the air; compare at an ACKed tick */
    int same = 0, found = 0;
    long long tick = -1;
    for (int attempt = 0; attempt < 6 && !same; attempt++) {
        terrad_pose p = {wheel, (float)x1, (float)y, 5.0f, qw, qx, 0, 0};
        terrad_client_send_poses(c, &p, 1, NULL);
        tick = get_heights(http_port, rx, ry, rw, rh, server);
        if (tick < 0)
            continue;
        t_end = now_s() + 5;
        while (terrad_client_get_stats(c)->ack_tick < (uint64_t)tick && now_s() < t_end &&
               terrad_client_is_open(c)) {
            terrad_client_send_poses(c, &p, 1, NULL);
            terrad_client_poll(c, (int)(500 / hz) + 1);
        }
        size_t slot = (size_t)tick % HISTORY;
        if (hist.ticks[slot] == (uint64_t)tick && hist.complete[slot]) {
            found = 1;
            same = memcmp(hist.copies + slot * cells, server, cells * sizeof(int32_t)) == 0;
        }
    }
    CHECK(found, "a mirror copy at the tick of GET /v1/heights (%lld)", tick);
    if (found && !same) {
        size_t slot = (size_t)tick % HISTORY, diff = 0, first = 0;
        for (size_t i = 0; i < cells; i++)
            if (hist.copies[slot * cells + i] != server[i] && diff++ == 0)
                first = i;
        printf("  %zu cells differ; first at (%d,%d): mirror %d, server %d\n", diff,
               rx + (int)(first % rw), ry + (int)(first / rw), hist.copies[slot * cells + first],
               server[first]);
    }
    CHECK(same, "the mirror equals GET /v1/heights bit for bit at tick %lld", tick);
    /* and the terrain did change where the wheel went */
    int32_t *now_row = malloc((size_t)rw * sizeof *now_row);
    size_t changed = 0;
    if (get_heights(http_port, rx, yc, rw, 1, now_row) >= 0)
        for (int i = 0; i < rw; i++)
            changed += now_row[i] != row[i];
    CHECK(changed > 10, "the wheel changed its path (%zu cells)", changed);
    free(now_row);

    long long vol1 = 0, tick1 = 0;
    CHECK(get_stats(http_port, &vol1, &tick1) == 0 && vol1 == vol0, "Σh unchanged: %lld -> %lld",
          vol0, vol1);

    /* terrain edits: a crater with its rim keeps Σh; without, Σh falls by what the reply says */
    uint64_t etick = 0;
    int64_t evol = -1;
    rc = terrad_client_crater(c, rx + 20, yc, 6, 20000, 1, &etick, &evol);
    CHECK(rc == 0 && etick > 0 && evol == 0, "a crater with its rim: tick %llu, volume %lld (%s)",
          (unsigned long long)etick, (long long)evol, terrad_client_last_error(c));
    rc = terrad_client_crater(c, rx + 60, yc, 5, 20000, 0, &etick, &evol);
    CHECK(rc == 0 && evol < 0, "a crater without: volume %lld", (long long)evol);
    long long vol2 = 0, tick2 = 0;
    for (int i = 0; i < 200 && get_stats(http_port, &vol2, &tick2) == 0 && tick2 < (long long)etick;
         i++)
        usleep(20000);
    CHECK(vol2 - vol1 == evol, "Σh moved by the declared %lld: %lld -> %lld", (long long)evol, vol1,
          vol2);
    rc = terrad_client_edit(c, "{\"op\":\"explode\"}", NULL, NULL);
    CHECK(rc == TERRAD_E_BAD_VALUE && strstr(terrad_client_last_error(c), "op"),
          "an unknown op is refused naming it: %d (%s)", rc, terrad_client_last_error(c));

    rc = terrad_client_delete_collider(c, wheel);
    CHECK(rc == 0, "collider_delete: %d (%s)", rc, terrad_client_last_error(c));
    rc = terrad_client_unsubscribe(c, sid);
    CHECK(rc == 0 && terrad_client_mirror(c, sid) == NULL, "unsubscribe: %d", rc);
    CHECK(terrad_client_is_open(c), "the connection is still open");
    terrad_client_close(c);
    free(server);
    free(row);
    free(hist.copies);
}

/* PROTOCOL.md "Budgets": desc.budget goes in hello, the world message says the one in force */
static void budgeted(int ws_port)
{
    char err[512];
    for (int k = 0; k < 2; k++) {
        int64_t asked = k == 0 ? 20000 : -1;
        terrad_client *c = terrad_client_connect(
            (terrad_client_desc){.port = ws_port, .name = "test_c_budget", .budget = asked}, err,
            sizeof err);
        CHECK(c != NULL, "connect with budget %lld: %s", (long long)asked, err);
        if (!c)
            continue;
        const terrad_world_info *w = terrad_client_world(c);
        CHECK(w->budget == (asked > 0 ? asked : 0), "budget %lld asked, %lld in force",
              (long long)asked, (long long)w->budget);
        CHECK(terrad_client_focus(c, 1, 10, 10) == 0 && terrad_client_focus(c, 0, 0, 0) == 0,
              "focus sent and cleared");
        uint32_t sid = 0;
        int rc = terrad_client_subscribe(c, 0, 0, 16, 16, &sid);
        CHECK(rc == 0 && terrad_client_is_open(c), "a budgeted client subscribes and goes on: %d",
              rc);
        terrad_client_close(c);
    }
}

/* Waits (polling every client) until `watch` holds the collider id in its latest COLLIDERS
 * frame; fills *st and *lugs. 0 when it never came. */
static int wait_collider(terrad_client *watch, terrad_client *const *others, int nothers,
                         uint32_t id, terrad_collider_state *st, terrad_collider_grousers *lugs)
{
    static terrad_collider_state states[64];
    static terrad_collider_grousers grousers[64];
    for (double end = now_s() + 60; now_s() < end && terrad_client_is_open(watch);) {
        terrad_client_poll(watch, 20);
        for (int k = 0; k < nothers; k++)
            terrad_client_poll(others[k], 0);
        size_t n = terrad_client_colliders(watch, states, grousers, 64, NULL);
        for (size_t i = 0; i < n && i < 64; i++)
            if (states[i].id == id) {
                *st = states[i];
                *lugs = grousers[i];
                return 1;
            }
    }
    return 0;
}

/* Another client's lugged wheel as two viewers see it: with and without the grousers. */
static void lugged_seen(int ws_port)
{
    char err[512];
    terrad_client *cl[3];
    const char *names[3] = {"test_c_driver", "test_c_viewer", "test_c_plain"};
    for (int k = 0; k < 3; k++) {
        cl[k] = terrad_client_connect((terrad_client_desc){.port = ws_port, .name = names[k]}, err,
                                      sizeof err);
        CHECK(cl[k] != NULL, "connect %s: %s", names[k], err);
        if (!cl[k]) {
            for (int j = 0; j < k; j++)
                terrad_client_close(cl[j]);
            return;
        }
    }
    uint32_t sid = 0, id = 0;
    CHECK(terrad_client_subscribe_colliders(cl[1], 0, 0, 64, 64, 1, &sid) == 0 &&
              terrad_client_subscribe_colliders(cl[2], 0, 0, 64, 64, 0, &sid) == 0,
          "subscribed with COLLIDERS frames (%s)", terrad_client_last_error(cl[1]));
    terrad_collider_desc wheel = {.shape = TERRAD_SHAPE_WHEEL, .radius = 0.3, .width = 0.2};
    int rc = terrad_client_create_lugged_collider(cl[0], wheel, (terrad_grousers){30, 0.01, 0.004},
                                                  0.0, &id);
    CHECK(rc == 0, "a lugged wheel: %d (%s)", rc, terrad_client_last_error(cl[0]));
    double cs = terrad_client_world(cl[0])->cell_size_m;
    float qw = (float)cos(0.25), qy = (float)sin(0.25); /* half a radian about the axle */
    terrad_pose p = {id, (float)(20 * cs), (float)(20 * cs), 5.0f, qw, 0, qy, 0};
    terrad_client_send_poses(cl[0], &p, 1, NULL);
    terrad_collider_state st;
    terrad_collider_grousers g;
    terrad_client *const drivers[2] = {cl[0], cl[2]};
    int seen = wait_collider(cl[1], drivers, 2, id, &st, &g);
    CHECK(seen, "the viewer sees the wheel in a COLLIDERS frame");
    if (seen) {
        CHECK(g.count == 30 && g.height_m == 0.01f && g.thickness_m == 0.004f,
              "with the option, its grousers exactly: %u, %.9g, %.9g", g.count, g.height_m,
              g.thickness_m);
        CHECK(st.kind == TERRAD_KIND_CYLINDER && st.owner == TERRAD_OWNER_OTHER && st.q[0] == qw &&
                  st.q[2] == qy,
              "another client's wheel, its phase (q %g %g %g %g)", st.q[0], st.q[1], st.q[2],
              st.q[3]);
    }
    terrad_client *const viewers[2] = {cl[0], cl[1]};
    seen = wait_collider(cl[2], viewers, 2, id, &st, &g);
    CHECK(seen && g.count == 0 && g.height_m == 0 && g.thickness_m == 0 && st.dims[0] == 0.3f,
          "without the option, the rim only (grousers %u)", g.count);
    for (int k = 0; k < 3; k++)
        CHECK(terrad_client_get_stats(cl[k])->errors == 0, "%s: no errors (%s)", names[k],
              terrad_client_last_error(cl[k]));
    for (int k = 0; k < 3; k++)
        terrad_client_close(cl[k]);
}

int main(void)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    signal(SIGPIPE, SIG_IGN);
    lws_set_log_level(LLL_ERR, NULL);
    int http_port = 0, ws_port = 0;
    const char *hp = getenv("TERRAD_HTTP_PORT"), *wp = getenv("TERRAD_WS_PORT");
    if (hp && wp && *hp && *wp) {
        http_port = atoi(hp);
        ws_port = atoi(wp);
    } else {
        int rc = start_daemon(&http_port, &ws_port);
        if (rc == 77)
            return 77;
        if (rc) {
            printf("0 passed, 1 failed\n");
            return 1;
        }
    }
    drive(http_port, ws_port);
    budgeted(ws_port);
    lugged_seen(ws_port);
    if (daemon_pid) {
        int st = stop_daemon();
        CHECK(st == 0, "SIGTERM stops the daemon with status 0 (got %d)", st);
    }
    if (failed)
        print_log_tail();
    if (log_path[0])
        unlink(log_path);
    return check_report();
}
