/*
 * drive_wheel.c: drive a wheel across the terrain with the C client library and check that the
 * heights it rebuilt from snapshots and deltas equal the server's.
 *
 *     cc drive_wheel.c -o drive_wheel $(pkg-config --cflags --libs terrad-client) -lm
 *     ./drive_wheel [HOST [WS_PORT [HTTP_PORT]]]      (default 127.0.0.1 8081 8080)
 *
 * Connects, creates a wheel, subscribes to the strip it drives along and sends a pose every tick
 * for three seconds. Then it parks the wheel above the snow (still sending poses, so that every
 * tick has an ACK), reads the strip with GET /v1/heights (which names its tick in X-Terrad-Tick)
 * and compares it with its own mirror as it was at that very tick: they must be equal, cell for
 * cell, even while other colliders (the demo actors) keep deforming the world. The client keeps
 * a copy of its mirror at every ACK through the frame hook: every DELTA of tick t arrives before
 * the ACK of tick t.
 *
 * Prints "mirror == GET /v1/heights" and exits 0 when they are equal; exits 1 otherwise.
 */
#define _POSIX_C_SOURCE 200809L

#include <arpa/inet.h>
#include <math.h>
#include <netdb.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include <terrad/terrad_client.h>

#define HISTORY 256 /* mirror copies kept, one per ACKed tick */

typedef struct history {
    uint32_t sid;
    size_t cells;
    uint64_t ticks[HISTORY];
    int32_t *copies; /* HISTORY * cells */
} history;

/* The frame hook: after each ACK, copy the mirror as of that tick. */
static void on_frame(void *user, terrad_client *c, int msg_type, uint64_t tick)
{
    history *h = user;
    if (msg_type != TERRAD_MSG_ACK || !h->copies)
        return;
    const terrad_mirror *m = terrad_client_mirror(c, h->sid);
    if (!m || !terrad_client_mirror_complete(c, h->sid))
        return;
    size_t slot = tick % HISTORY;
    memcpy(h->copies + slot * h->cells, m->heights, h->cells * sizeof(int32_t));
    h->ticks[slot] = tick;
}

static void on_log(void *user, int level, const char *message)
{
    (void)user;
    static const char *const names[] = {"", "error", "warning", "info"};
    fprintf(stderr, "terrad-client %s: %s\n", names[level > 0 && level < 4 ? level : 0], message);
}

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

/* GET /v1/heights?x=&y=&w=&h= (int32 little-endian) into out; returns the tick or -1. */
static long long get_heights_once(const char *host, const char *port, int x, int y, int w, int h,
                                  int32_t *out)
{
    struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM}, *ai = NULL;
    if (getaddrinfo(host, port, &hints, &ai) != 0)
        return -1;
    int s = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
    int ok = s >= 0 && connect(s, ai->ai_addr, ai->ai_addrlen) == 0;
    freeaddrinfo(ai);
    if (!ok) {
        if (s >= 0)
            close(s);
        return -1;
    }
    char req[256];
    int n = snprintf(req, sizeof req,
                     "GET /v1/heights?x=%d&y=%d&w=%d&h=%d HTTP/1.0\r\nHost: %s\r\n\r\n", x, y, w, h,
                     host);
    size_t body_len = (size_t)w * h * 4, cap = body_len + 4096, len = 0;
    char *buf = malloc(cap + 1);
    if (!buf || write(s, req, (size_t)n) != n) {
        free(buf);
        close(s);
        return -1;
    }
    ssize_t got;
    while (len < cap && (got = read(s, buf + len, cap - len)) > 0)
        len += (size_t)got;
    close(s);
    buf[len] = 0;
    long long tick = -1;
    int status = 0;
    char *end = NULL;
    for (size_t i = 0; i + 4 <= len; i++)
        if (memcmp(buf + i, "\r\n\r\n", 4) == 0) {
            end = buf + i;
            break;
        }
    if (end && sscanf(buf, "HTTP/%*s %d", &status) == 1 && status == 200 &&
        (size_t)(buf + len - (end + 4)) == body_len) {
        *end = 0;
        for (char *p = buf; (p = strchr(p, '\n')) != NULL;)
            if (strncasecmp(++p, "X-Terrad-Tick:", 14) == 0)
                tick = atoll(p + 14);
        const unsigned char *b = (const unsigned char *)end + 4;
        for (size_t i = 0; i < body_len / 4; i++)
            out[i] = (int32_t)((uint32_t)b[4 * i] | (uint32_t)b[4 * i + 1] << 8 |
                               (uint32_t)b[4 * i + 2] << 16 | (uint32_t)b[4 * i + 3] << 24);
    }
    free(buf);
    return tick;
}

/* The sim thread serves heights between ticks and answers 503 when it cannot within its read
 * timeout (a busy machine): ask again, for up to 30 s, as any client should. */
static long long get_heights(const char *host, const char *port, int x, int y, int w, int h,
                             int32_t *out)
{
    const double end = now_s() + 30;
    for (;;) {
        long long tick = get_heights_once(host, port, x, y, w, h, out);
        if (tick >= 0 || now_s() > end)
            return tick;
        nanosleep(&(struct timespec){0, 200 * 1000 * 1000}, NULL);
    }
}

/* Send one pose and service the connection until the next tick is due. */
static int pose_and_wait(terrad_client *c, terrad_pose p, double *next, double period)
{
    if (terrad_client_send_poses(c, &p, 1, NULL) != 0)
        return -1;
    *next += period;
    while (now_s() < *next && terrad_client_is_open(c))
        terrad_client_poll(c, (int)((*next - now_s()) * 1000) + 1);
    return terrad_client_is_open(c) ? 0 : -1;
}

int main(int argc, char **argv)
{
    const char *host = argc > 1 ? argv[1] : "127.0.0.1";
    int ws_port = argc > 2 ? atoi(argv[2]) : 8081;
    const char *http_port = argc > 3 ? argv[3] : "8080";
    history hist = {0};
    char err[512];
    terrad_client *c = terrad_client_connect((terrad_client_desc){.host = host,
                                                                  .port = ws_port,
                                                                  .name = "drive_wheel.c",
                                                                  .hook = on_frame,
                                                                  .user = &hist,
                                                                  .log = on_log,
                                                                  .log_level = TERRAD_LOG_WARN},
                                             err, sizeof err);
    if (!c) {
        fprintf(stderr, "drive_wheel: %s\n", err);
        return 1;
    }
    const terrad_world_info *w = terrad_client_world(c);
    const double cell = w->cell_size_m, units = w->units_per_m, hz = w->tick_hz;
    const int rw = w->width - 16 < 160 ? w->width - 16 : 160, rh = 48;
    const int rx = 8, yc = w->height / 2, ry = yc - rh / 2;
    hist.cells = (size_t)rw * rh;
    hist.copies = calloc(HISTORY * hist.cells, sizeof(int32_t));
    int32_t *server = malloc(hist.cells * sizeof *server);
    int32_t ground = 0;
    uint32_t wheel = 0;
    const double radius = 0.3;
    int rc = -1;
    if (!hist.copies || !server || get_heights(host, http_port, rx + 12, yc, 1, 1, &ground) < 0) {
        fprintf(stderr,
                "drive_wheel: out of memory, or GET /v1/heights on port %s failed for 30 s\n",
                http_port);
        goto done;
    }
    if (terrad_client_subscribe(c, rx, ry, (uint32_t)rw, (uint32_t)rh, &hist.sid) != 0 ||
        terrad_client_create_collider(
            c, (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL, .radius = radius, .width = 0.2},
            &wheel) != 0) {
        fprintf(stderr, "drive_wheel: setting up failed: %s\n", terrad_client_last_error(c));
        goto done;
    }

    /* Drive: a pose every tick, rolling about the axle (local y). */
    const int ticks = (int)(3 * hz);
    const double x0 = (rx + 12) * cell, x1 = (rx + rw - 12) * cell, y = (yc + 0.5) * cell;
    const double z = ground / units + radius - 0.06;
    double next = now_s();
    int64_t most = 0;
    terrad_contact contact;
    for (int i = 0; i < ticks; i++) {
        double x = x0 + (x1 - x0) * i / (ticks - 1), angle = (x - x0) / radius;
        terrad_pose p = {
            wheel, (float)x, (float)y, (float)z, (float)cos(angle / 2), 0, (float)sin(angle / 2),
            0};
        if (pose_and_wait(c, p, &next, 1 / hz) != 0)
            goto done;
        if (terrad_client_contact(c, wheel, &contact, NULL) && contact.volume > most)
            most = contact.volume;
    }

    /* Park in the air, poses twice a tick; compare at a tick the mirror has a copy of. */
    terrad_pose parked = {wheel, (float)x1, (float)y, (float)(z + 5), 1, 0, 0, 0};
    long long tick = -1;
    const int32_t *mine = NULL;
    for (int attempt = 0; attempt < 5 && !mine; attempt++) {
        if (pose_and_wait(c, parked, &next, 0.5 / hz) != 0)
            goto done;
        tick = get_heights(host, http_port, rx, ry, rw, rh, server);
        double deadline = now_s() + 10;
        while (tick >= 0 && terrad_client_get_stats(c)->ack_tick < (uint64_t)tick &&
               now_s() < deadline)
            if (pose_and_wait(c, parked, &next, 0.5 / hz) != 0)
                goto done;
        if (tick >= 0 && hist.ticks[tick % HISTORY] == (uint64_t)tick)
            mine = hist.copies + (size_t)(tick % HISTORY) * hist.cells;
    }
    if (!mine) {
        fprintf(stderr, "drive_wheel: no mirror copy at the server's tick %lld\n", tick);
        goto done;
    }
    int same = memcmp(mine, server, hist.cells * sizeof *server) == 0;
    printf("drove %d ticks; at tick %lld the mirror %s GET /v1/heights over %dx%d cells\n", ticks,
           tick, same ? "==" : "!=", rw, rh);
    printf("deepest contact while driving: %lld height units x cells\n", (long long)most);
    rc = same ? 0 : 1;

done:
    terrad_client_close(c);
    free(hist.copies);
    free(server);
    return rc == 0 ? 0 : 1;
}
