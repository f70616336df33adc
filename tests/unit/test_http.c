/*
 * test_http.c: every HTTP endpoint of server/http, spoken to over a raw
 * HTTP/1.1 socket (no curl): probes, /v1/world and /v1/stats, /metrics
 * (through promtool when installed), /v1/heights in int32 and png16 against
 * the world's own heights, the embedded viewer files, and the refusals — bad
 * parameters, oversize rectangles, bodies, long queries, ".." paths, methods
 * other than GET/HEAD. A test thread plays the sim thread: it serves the
 * hub's height reads between "ticks", and can pause to force a timeout.
 */
// ctest-timeout: 60
#include <arpa/inet.h>
#include <errno.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <time.h>
#include <unistd.h>

#include "base/base.h"
#include "http/http.h"
#include "hub/hub.h"
#include "metrics/metrics.h"
#include "store/store.h"
#include "world/world.h"
#include "check.h"
#include "test_params.h"

/* ---- the sim thread's stand-in ---- */

static world test_world;
static hub *test_hub;
static atomic_int sim_stop, sim_paused;
static atomic_ullong sim_tick;

static void *sim_thread(void *arg)
{
    (void)arg;
    while (!atomic_load(&sim_stop)) {
        if (!atomic_load(&sim_paused)) { /* a tick: published, then its reads */
            uint64_t tick = atomic_fetch_add(&sim_tick, 1) + 1;
            hub_publish_tick(test_hub, tick);
            hub_serve_reads(test_hub, &test_world, tick);
        }
        struct timespec ts = {0, 1000000};
        nanosleep(&ts, NULL);
    }
    return NULL;
}

/* ---- a minimal HTTP/1.1 client ---- */

typedef struct conn {
    int fd;
    unsigned char *buf; /* bytes read but not yet consumed */
    size_t len, cap;
} conn;

typedef struct response {
    int status;
    char head[8192]; /* status line and headers */
    unsigned char *body;
    size_t body_len;
} response;

static int conn_open(conn *c, int port)
{
    memset(c, 0, sizeof *c);
    c->fd = socket(AF_INET, SOCK_STREAM, 0);
    if (c->fd < 0)
        return -1;
    struct timeval tv = {10, 0};
    setsockopt(c->fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
    struct sockaddr_in a = {0};
    a.sin_family = AF_INET;
    a.sin_port = htons((uint16_t)port);
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (connect(c->fd, (struct sockaddr *)&a, sizeof a) != 0) {
        close(c->fd);
        return -1;
    }
    return 0;
}

static void conn_close(conn *c)
{
    close(c->fd);
    free(c->buf);
    c->buf = NULL;
}

static int conn_send(conn *c, const char *data, size_t n)
{
    while (n) {
        ssize_t k = send(c->fd, data, n, MSG_NOSIGNAL);
        if (k <= 0)
            return -1;
        data += k;
        n -= (size_t)k;
    }
    return 0;
}

/* Read more bytes into the buffer; 0 on EOF or error. */
static size_t conn_fill(conn *c)
{
    if (c->cap - c->len < 65536) {
        c->cap = c->cap * 2 + 65536;
        c->buf = realloc(c->buf, c->cap);
    }
    ssize_t k = recv(c->fd, c->buf + c->len, c->cap - c->len, 0);
    if (k <= 0)
        return 0;
    c->len += (size_t)k;
    return (size_t)k;
}

static const char *header_value(const response *r, const char *name, char *out, size_t cap)
{
    size_t n = strlen(name);
    for (const char *p = strstr(r->head, "\r\n"); p && p[2]; p = strstr(p + 2, "\r\n")) {
        const char *line = p + 2;
        if (strncasecmp(line, name, n) == 0 && line[n] == ':') {
            const char *v = line + n + 1;
            while (*v == ' ')
                v++;
            const char *end = strstr(v, "\r\n");
            size_t len = end ? (size_t)(end - v) : strlen(v);
            if (len >= cap)
                len = cap - 1;
            memcpy(out, v, len);
            out[len] = '\0';
            return out;
        }
    }
    return NULL;
}

/* Read exactly one response (no body for HEAD). Returns 0 or -1. */
static int conn_read_response(conn *c, response *r, int head)
{
    memset(r, 0, sizeof *r);
    unsigned char *end = NULL;
    while (c->len < 4 || !(end = memmem(c->buf, c->len, "\r\n\r\n", 4)))
        if (!conn_fill(c))
            return -1;
    size_t head_len = (size_t)(end - c->buf) + 4;
    if (head_len >= sizeof r->head)
        return -1;
    memcpy(r->head, c->buf, head_len);
    r->head[head_len] = '\0';
    memmove(c->buf, c->buf + head_len, c->len - head_len);
    c->len -= head_len;
    if (sscanf(r->head, "HTTP/1.%*d %d", &r->status) != 1)
        return -1;
    char v[64];
    size_t want;
    if (head || r->status == 304 || r->status == 204) {
        want = 0;
    } else if (header_value(r, "Content-Length", v, sizeof v)) {
        want = (size_t)strtoull(v, NULL, 10);
    } else { /* until the server closes */
        while (conn_fill(c))
            ;
        want = c->len;
    }
    while (c->len < want)
        if (!conn_fill(c))
            return -1;
    r->body = malloc(want + 1);
    memcpy(r->body, c->buf, want);
    r->body[want] = '\0';
    r->body_len = want;
    memmove(c->buf, c->buf + want, c->len - want);
    c->len -= want;
    return 0;
}

static void response_free(response *r)
{
    free(r->body);
    r->body = NULL;
}

/* One request on a fresh connection. extra: more header lines ("" or
 * "Name: v\r\n..."), body may be NULL. */
static int request(int port, const char *method, const char *target, const char *extra,
                   const char *body, response *r)
{
    conn c;
    if (conn_open(&c, port) != 0)
        return -1;
    char req[8192];
    snprintf(req, sizeof req, "%s %s HTTP/1.1\r\nHost: 127.0.0.1\r\n%s\r\n%s", method, target,
             extra ? extra : "", body ? body : "");
    int rc = conn_send(&c, req, strlen(req));
    if (rc == 0)
        rc = conn_read_response(&c, r, strcmp(method, "HEAD") == 0);
    conn_close(&c);
    return rc;
}

static int get(int port, const char *target, response *r)
{
    return request(port, "GET", target, "", NULL, r);
}

static int body_has(const response *r, const char *s)
{
    return r->body && strstr((const char *)r->body, s) != NULL;
}

static int is_json_error(const response *r)
{
    char type[128];
    return header_value(r, "Content-Type", type, sizeof type) &&
           strncmp(type, "application/json", 16) == 0 && r->body &&
           strncmp((const char *)r->body, "{\"error\":\"", 10) == 0;
}

/* An error response: status, JSON {"error": ...} and a word of its message. */
static void expect_error(int port, const char *target, int status, const char *word)
{
    response r;
    int rc = get(port, target, &r);
    CHECK(rc == 0 && r.status == status && is_json_error(&r) && body_has(&r, word),
          "GET %s: expected %d with \"%s\", got %d %s", target, status, word, r.status,
          r.body ? (const char *)r.body : "(none)");
    response_free(&r);
}

static uint32_t be32(const unsigned char *p)
{
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | p[3];
}

/* ---- checks ---- */

static void check_probes(int port, http_status *status)
{
    response r;
    CHECK(get(port, "/healthz", &r) == 0 && r.status == 200 && body_has(&r, "ok"), "/healthz: %d",
          r.status);
    response_free(&r);
    CHECK(get(port, "/readyz", &r) == 0 && r.status == 200, "/readyz ready: %d", r.status);
    response_free(&r);
    pthread_mutex_lock(&status->lock);
    status->ready = 0;
    pthread_mutex_unlock(&status->lock);
    CHECK(get(port, "/readyz", &r) == 0 && r.status == 503 && is_json_error(&r),
          "/readyz not ready: %d", r.status);
    response_free(&r);
    pthread_mutex_lock(&status->lock);
    status->ready = 1;
    pthread_mutex_unlock(&status->lock);
}

static void check_views(int port)
{
    response r;
    char v[128];
    CHECK(get(port, "/v1/world", &r) == 0 && r.status == 200, "/v1/world: %d", r.status);
    CHECK(header_value(&r, "Content-Type", v, sizeof v) && strcmp(v, "application/json") == 0,
          "/v1/world type");
    CHECK(body_has(&r, "\"width\":64,\"height\":48") && body_has(&r, "\"units_per_m\":10000") &&
              body_has(&r, "\"tile_size\":32") && body_has(&r, "\"models\":[\"persson-single\"]") &&
              body_has(&r, "\"backend\":\"cpu\"") && body_has(&r, "\"cell_size_m\":0.1,") &&
              body_has(&r, "\"width_m\":6.4,") && body_has(&r, "\"tick_hz\":60,") &&
              body_has(&r, "\"extent\":{") && body_has(&r, "\"tick\":"),
          "/v1/world fields: %s", r.body);
    CHECK(body_has(&r, "\"renderer\":\"test \\\"renderer\\\"\""), "/v1/world escapes: %s", r.body);
    response_free(&r);

    CHECK(get(port, "/v1/stats", &r) == 0 && r.status == 200, "/v1/stats: %d", r.status);
    CHECK(body_has(&r, "\"tick\":77,") && body_has(&r, "\"volume\":9007199254740993,") &&
              body_has(&r, "\"clients\":3,") && body_has(&r, "\"colliders\":5,") &&
              body_has(&r, "\"last_tick_ms\":1.250,") && body_has(&r, "\"overruns\":2"),
          "/v1/stats fields: %s", r.body);
    response_free(&r);
}

static void check_metrics(int port)
{
    metrics_set_volume(9007199254740993LL);
    metrics_observe_tick_ms(3);
    metrics_count_refused(1);
    response r;
    char v[128];
    CHECK(get(port, "/metrics", &r) == 0 && r.status == 200, "/metrics: %d", r.status);
    CHECK(header_value(&r, "Content-Type", v, sizeof v) &&
              strcmp(v, "text/plain; version=0.0.4; charset=utf-8") == 0,
          "/metrics type: %s", v);
    CHECK(body_has(&r, "\nterrad_volume_units 9007199254740993\n") &&
              body_has(&r, "# TYPE terrad_tick_duration_seconds histogram"),
          "/metrics body");
    if (access("/usr/bin/promtool", X_OK) == 0) {
        char path[] = "/tmp/test_http_metrics_XXXXXX";
        int fd = mkstemp(path);
        CHECK(fd >= 0 && write(fd, r.body, r.body_len) == (ssize_t)r.body_len, "temp file");
        close(fd);
        char cmd[128];
        snprintf(cmd, sizeof cmd, "/usr/bin/promtool check metrics < %s", path);
        int rc = system(cmd);
        CHECK(rc == 0, "promtool check metrics on /metrics: %d (%s)", rc, path);
        if (rc == 0)
            unlink(path);
    } else {
        printf("skip: /usr/bin/promtool not installed, promtool check not run\n");
    }
    response_free(&r);
}

static void check_heights_int32(int port, int x, int y, int w, int h)
{
    char target[128], v[64], rect[64];
    snprintf(target, sizeof target, "/v1/heights?x=%d&y=%d&w=%d&h=%d%s", x, y, w, h,
             (x & 1) ? "&format=int32" : "");
    response r;
    CHECK(get(port, target, &r) == 0 && r.status == 200, "%s: %d %s", target, r.status,
          r.body ? (const char *)r.body : "");
    CHECK(r.body_len == (size_t)w * h * 4, "%s: %zu bytes", target, r.body_len);
    CHECK(header_value(&r, "Content-Type", v, sizeof v) &&
              strcmp(v, "application/octet-stream") == 0,
          "%s type", target);
    CHECK(header_value(&r, "X-Terrad-Tick", v, sizeof v) && strtoull(v, NULL, 10) > 0,
          "%s tick header", target);
    snprintf(rect, sizeof rect, "%d,%d,%d,%d", x, y, w, h);
    CHECK(header_value(&r, "X-Terrad-Rect", v, sizeof v) && strcmp(v, rect) == 0,
          "%s rect header %s", target, v);
    int same = r.body_len == (size_t)w * h * 4;
    for (int j = 0; same && j < h; j++)
        for (int i = 0; same && i < w; i++) {
            const unsigned char *b = r.body + 4 * ((size_t)j * w + i);
            int32_t got = (int32_t)((uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 |
                                    (uint32_t)b[3] << 24);
            same = got == world_height_at(&test_world, x + i, y + j);
        }
    CHECK(same, "%s: body equals the world's heights", target);
    response_free(&r);
}

static void check_heights_png(int port, int x, int y, int w, int h, int expect_clipped)
{
    char target[128], v[64];
    snprintf(target, sizeof target, "/v1/heights?x=%d&y=%d&w=%d&h=%d&format=png16", x, y, w, h);
    response r;
    CHECK(get(port, target, &r) == 0 && r.status == 200, "%s: %d", target, r.status);
    static const unsigned char sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
    CHECK(r.body_len > 33 && memcmp(r.body, sig, 8) == 0, "%s: PNG signature", target);
    if (r.body_len > 33) {
        CHECK(be32(r.body + 8) == 13 && memcmp(r.body + 12, "IHDR", 4) == 0 &&
                  be32(r.body + 16) == (uint32_t)w && be32(r.body + 20) == (uint32_t)h &&
                  r.body[24] == 16 && r.body[25] == 0,
              "%s: IHDR %ux%u depth %d type %d", target, be32(r.body + 16), be32(r.body + 20),
              r.body[24], r.body[25]);
    }
    CHECK(header_value(&r, "Content-Type", v, sizeof v) && strcmp(v, "image/png") == 0, "%s type",
          target);
    int32_t min = INT32_MAX;
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++) {
            int32_t hv = world_height_at(&test_world, x + i, y + j);
            if (hv < min)
                min = hv;
        }
    CHECK(header_value(&r, "X-Terrad-Offset", v, sizeof v) && atol(v) == min,
          "%s offset %s, min %d", target, v, min);
    CHECK(header_value(&r, "X-Terrad-Units-Per-Metre", v, sizeof v) && atol(v) == 10000,
          "%s units per metre", target);
    CHECK(header_value(&r, "X-Terrad-Clipped", v, sizeof v) && atoi(v) == expect_clipped,
          "%s clipped %s", target, v);
    /* the daemon's own reader (png16_decode): 16-bit greyscale only */
    uint16_t *values = NULL;
    int gw = 0, gh = 0;
    error_text err = {{0}};
    int ok = png16_decode(r.body, r.body_len, target, &gw, &gh, &values, &err) == 0 && gw == w &&
             gh == h;
    CHECK(ok, "%s: decodes as %d x %d (%d x %d) %s", target, w, h, gw, gh, err.message);
    int exact = ok;
    for (int j = 0; exact && j < h; j++)
        for (int i = 0; exact && i < w; i++) {
            int64_t want = (int64_t)world_height_at(&test_world, x + i, y + j) - min;
            if (want > 65535)
                want = 65535;
            exact = values[(size_t)j * w + i] == want;
        }
    CHECK(exact, "%s: pixel = clamp(h - offset)", target);
    free(values);
    response_free(&r);
}

static void check_heights_errors(int port)
{
    expect_error(port, "/v1/heights?y=0&w=1&h=1", 400, "parameter x");
    expect_error(port, "/v1/heights?x=0&y=0&w=1", 400, "parameter h");
    expect_error(port, "/v1/heights?x=abc&y=0&w=1&h=1", 400, "parameter x");
    expect_error(port, "/v1/heights?x=1.5&y=0&w=1&h=1", 400, "parameter x");
    expect_error(port, "/v1/heights?x=0&y=0x1&w=1&h=1", 400, "parameter y");
    expect_error(port, "/v1/heights?x=0&y=0&w=99999999999&h=1", 400, "parameter w");
    expect_error(port, "/v1/heights?x=0&y=0&w=-&h=1", 400, "parameter w");
    expect_error(port, "/v1/heights?x=0&y=0&w=0&h=1", 400, "parameter w");
    expect_error(port, "/v1/heights?x=0&y=0&w=1&h=-3", 400, "parameter h");
    expect_error(port, "/v1/heights?x=60&y=0&w=10&h=1", 400, "outside the world");
    expect_error(port, "/v1/heights?x=-1&y=0&w=2&h=1", 400, "outside the world");
    expect_error(port, "/v1/heights?x=0&y=40&w=1&h=9", 400, "parameters y and h");
    expect_error(port, "/v1/heights?x=0&y=0&w=1&h=1&format=jpeg", 400, "parameter format");
    /* Over the cell limit: 413, naming the limit, before any read. */
    expect_error(port, "/v1/heights?x=0&y=0&w=4096&h=1025", 413, "4194304");
    expect_error(port, "/v1/heights?x=0&y=0&w=65536&h=65536", 413, "limit");
}

static void check_static(int port)
{
    response r;
    char v[128];
    CHECK(get(port, "/", &r) == 0 && r.status == 200 && body_has(&r, "<html"), "/: %d", r.status);
    CHECK(header_value(&r, "Content-Type", v, sizeof v) && strncmp(v, "text/html", 9) == 0,
          "/ is html: %s", v);
    CHECK(header_value(&r, "Cache-Control", v, sizeof v) && strcmp(v, "no-cache") == 0,
          "/ Cache-Control no-cache");
    response_free(&r);
    CHECK(get(port, "/index.html", &r) == 0 && r.status == 200, "/index.html: %d", r.status);
    response_free(&r);
    expect_error(port, "/nope.js", 404, "not found");
    expect_error(port, "/v1/nope", 404, "not found");
    expect_error(port, "/a/../index.html", 400, "..");
    expect_error(port, "/%2e%2e/index.html", 400, "..");
    expect_error(port, "/index%00.html", 400, "NUL");
}

static void check_limits(int port)
{
    response r;
    char v[64];
    /* Other methods: 405 with Allow, with or without a body. */
    CHECK(request(port, "POST", "/healthz", "", NULL, &r) == 0 && r.status == 405 &&
              is_json_error(&r) && header_value(&r, "Allow", v, sizeof v) &&
              strcmp(v, "GET, HEAD") == 0,
          "POST: %d", r.status);
    response_free(&r);
    CHECK(request(port, "POST", "/v1/stats", "Content-Length: 5\r\n", "hello", &r) == 0 &&
              r.status == 405 && is_json_error(&r),
          "POST with body: %d", r.status);
    response_free(&r);
    CHECK(request(port, "DELETE", "/", "", NULL, &r) == 0 && r.status == 405, "DELETE: %d",
          r.status);
    response_free(&r);
    /* A body on a GET is refused. */
    CHECK(request(port, "GET", "/v1/stats", "Content-Length: 4\r\n", "abcd", &r) == 0 &&
              r.status == 413 && is_json_error(&r),
          "GET with body: %d", r.status);
    response_free(&r);
    /* Query strings over 1 KiB. */
    char target[1200];
    int n = snprintf(target, sizeof target, "/v1/heights?x=0&y=0&w=1&h=1&pad=");
    memset(target + n, 'a', 1030 - (size_t)n + 30);
    target[1030 + 30] = '\0';
    expect_error(port, target, 414, "query string");
    /* HEAD: headers only. */
    CHECK(request(port, "HEAD", "/v1/world", "", NULL, &r) == 0 && r.status == 200 &&
              r.body_len == 0,
          "HEAD /v1/world: %d", r.status);
    response_free(&r);
}

static void check_keep_alive(int port)
{
    conn c;
    CHECK(conn_open(&c, port) == 0, "connect");
    const char *two = "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
                      "GET /v1/stats HTTP/1.1\r\nHost: x\r\n\r\n";
    CHECK(conn_send(&c, two, strlen(two)) == 0, "send two requests");
    response a, b;
    CHECK(conn_read_response(&c, &a, 0) == 0 && a.status == 200 && body_has(&a, "ok"),
          "first of two: %d", a.status);
    char v[64];
    CHECK(!header_value(&a, "Connection", v, sizeof v) || strcasecmp(v, "close") != 0,
          "first response keeps the connection");
    CHECK(conn_read_response(&c, &b, 0) == 0 && b.status == 200 && body_has(&b, "\"tick\""),
          "second on the same connection: %d", b.status);
    response_free(&a);
    response_free(&b);
    /* A HEAD and then a GET, one after the other, still on this socket. */
    const char *head = "HEAD /v1/world HTTP/1.1\r\nHost: x\r\n\r\n";
    CHECK(conn_send(&c, head, strlen(head)) == 0 && conn_read_response(&c, &a, 1) == 0 &&
              a.status == 200,
          "HEAD on a kept-alive connection");
    response_free(&a);
    const char *heights = "GET /v1/heights?x=1&y=2&w=3&h=4 HTTP/1.1\r\nHost: x\r\n\r\n";
    CHECK(conn_send(&c, heights, strlen(heights)) == 0 && conn_read_response(&c, &a, 0) == 0 &&
              a.status == 200 && a.body_len == 48,
          "heights on a kept-alive connection");
    response_free(&a);
    conn_close(&c);
}

typedef struct slow_read {
    int port;
    int status;
    double ms;
    atomic_int done;
} slow_read;

static void *slow_read_thread(void *arg)
{
    slow_read *s = arg;
    double t0 = time_now_ms();
    response r;
    s->status = get(s->port, "/v1/heights?x=0&y=0&w=4&h=4", &r) == 0 ? r.status : -1;
    s->ms = time_now_ms() - t0;
    if (s->status == 503 && !is_json_error(&r))
        s->status = -2;
    response_free(&r);
    atomic_store(&s->done, 1);
    return NULL;
}

/* A table of worlds holding one, the default (test_hub may be NULL: no
 * heights); the HTTP server serves what is in it (hub_worlds). */
static hub_worlds *one_world(http_status *status, hub *h)
{
    hub_worlds *t = hub_worlds_create();
    hub_world e = {.name = "test", .h = h, .status = status};
    error_text err = {{0}};
    CHECK(t && hub_worlds_add(t, &e, &err), "a table of one world: %s", err.message);
    return t;
}

/* Empties and frees what one_world made. */
static void drop_worlds(hub_worlds *t)
{
    hub_world *w = hub_worlds_acquire(t, NULL);
    if (w) {
        hub_worlds_release(t, w);
        hub_worlds_remove(t, w, 0);
    }
    hub_worlds_destroy(t);
}

/* A server on a free port serving worlds from its first request (the table
 * goes in before the HTTP threads start: they read it unlocked). */
static http_server *start_serving(http_status *status, const http_limits *limits,
                                  hub_worlds *worlds, error_text *err)
{
    http_security sec = {.worlds = worlds};
    return http_server_start_secure(0, 0, status, limits, &sec, err);
}

/* A server with small limits: its own cell limit, and a short read timeout
 * while the "sim thread" is paused — probes must still answer meanwhile. */
static void check_limited_server(http_status *status, hub_worlds *worlds)
{
    error_text err = {{0}};
    /* a read timeout far longer than a probe takes even on a loaded machine: the probe must
     * answer while the read still waits (not after it), whatever the machine's speed */
    http_limits limits = {.heights_timeout_ms = 5000, .heights_max_cells = 100};
    http_server *s = start_serving(status, &limits, worlds, &err);
    CHECK(s != NULL, "limited server: %s", err.message);
    if (!s)
        return;
    int port = http_server_port(s);
    expect_error(port, "/v1/heights?x=0&y=0&w=11&h=10", 413, "limit of 100 cells");
    check_heights_int32(port, 0, 0, 10, 10);

    atomic_store(&sim_paused, 1);
    slow_read sr = {port, 0, 0, 0};
    pthread_t t;
    pthread_create(&t, NULL, slow_read_thread, &sr);
    struct timespec ts = {0, 100 * 1000000};
    nanosleep(&ts, NULL);
    response r;
    int rc = get(port, "/healthz", &r);
    int read_waiting = !atomic_load(&sr.done);
    CHECK(rc == 0 && r.status == 200 && read_waiting,
          "/healthz answers while a heights read waits (the read %s)",
          read_waiting ? "still waits" : "had already ended");
    response_free(&r);
    pthread_join(t, NULL);
    atomic_store(&sim_paused, 0);
    CHECK(sr.status == 503 && sr.ms >= 4900, "stalled read: %d after %.0f ms", sr.status, sr.ms);
    http_server_stop(s);

    /* No hub: /v1/heights is unavailable, the rest serves. */
    hub_worlds *no_hub = one_world(status, NULL);
    s = start_serving(status, NULL, no_hub, &err);
    CHECK(s != NULL, "server without a hub");
    if (s) {
        expect_error(http_server_port(s), "/v1/heights?x=0&y=0&w=1&h=1", 503, "not available");
        http_server_stop(s);
    }
    drop_worlds(no_hub);

    /* No world in its table: the world's views are unavailable, the probes serve. */
    hub_worlds *none = hub_worlds_create();
    s = start_serving(status, NULL, none, &err);
    CHECK(s != NULL, "server without a world");
    if (s) {
        expect_error(http_server_port(s), "/v1/world", 503, "not served");
        expect_error(http_server_port(s), "/v1/world?world=test", 404, "does not serve");
        response r;
        CHECK(get(http_server_port(s), "/healthz", &r) == 0 && r.status == 200,
              "/healthz without a world: %d", r.status);
        response_free(&r);
        http_server_stop(s);
    }
    hub_worlds_destroy(none);
}

static void fill_world(void)
{
    for (int y = 0; y < test_world.height; y++)
        for (int x = 0; x < test_world.width; x++) {
            int32_t v = (int32_t)(x * 37 + y * 1000) - 5000; /* negatives too */
            if (x >= 40 && y >= 40)
                v += 300000 * ((x + y) & 1); /* a range beyond 16 bits */
            world_set_height(&test_world, x, y, v);
        }
    world_set_height(&test_world, 0, 0, WORLD_HEIGHT_MIN);
}

/* ?tick=N of a world that is leaving (its hub's reads closed, as world_unregister closes
 * them before its removal waits for the requests): the rebuild from its data directory
 * stops at its first record, answered 503 naming why, for the heights and for /v1/stats;
 * the same world before its reads close rebuilds the tick (200). Without the rebuild's
 * cancel both leaving reads are 200. */
static void check_past_tick_leaving(void)
{
    char dir[96];
    snprintf(dir, sizeof dir, "/tmp/terrad_test_http_%d", (int)getpid());
    world base, live;
    test_dunes_world(&base, 64, 48, 7);
    test_dunes_world(&live, 64, 48, 7);
    store_config c = {.dir = dir, .durability = STORE_EVERY_TICK};
    store_recovery rec;
    error_text err = {{0}};
    store *st = store_open(&c, &live, &rec, &err);
    CHECK(st != NULL, "a data directory for the past ticks: %s", err.message);
    world_rect r = {0, 0, 8, 8};
    int32_t cells[64];
    for (uint64_t t = 1; st && t <= 5; t++) { /* five ticks, each raising r */
        world_gather_window(&live, r, cells);
        for (int i = 0; i < 64; i++)
            cells[i] += 100;
        world_scatter_window(&live, r, cells);
        CHECK(store_commit_tick(st, &live, t, &r, 1) == 0, "tick %llu logged",
              (unsigned long long)t);
    }
    store_close(st);
    http_status status;
    memset(&status, 0, sizeof status);
    pthread_mutex_init(&status.lock, NULL);
    status.ready = 1;
    status.tick = 5;
    status.world_width = base.width;
    status.world_height = base.height;
    status.cell_size_m = base.cell_size_m;
    status.units_per_m = base.units_per_m;
    status.tile_size = 32;
    status.history.dir = dir;
    hub *h = hub_create();
    hub_worlds *t = hub_worlds_create();
    hub_world e = {.name = "past", .h = h, .base = &base, .status = &status};
    hub_world *entry = t && h ? hub_worlds_add(t, &e, &err) : NULL;
    CHECK(entry != NULL, "a world with a data directory: %s", err.message);
    http_server *s = entry ? start_serving(&status, NULL, t, &err) : NULL;
    CHECK(s != NULL, "a server for it: %s", err.message);
    if (s) {
        int port = http_server_port(s);
        response ok;
        CHECK(get(port, "/v1/heights?world=past&x=0&y=0&w=8&h=8&tick=3", &ok) == 0 &&
                  ok.status == 200,
              "tick 3 is rebuilt while the world serves: %d", ok.status);
        response_free(&ok);
        hub_close_reads(h);
        expect_error(port, "/v1/heights?world=past&x=0&y=0&w=8&h=8&tick=3", 503,
                     "the world is leaving");
        expect_error(port, "/v1/stats?world=past&tick=3", 503, "the world is leaving");
        http_server_stop(s);
    }
    if (entry)
        hub_worlds_remove(t, entry, 0);
    hub_worlds_destroy(t);
    hub_destroy(h);
    pthread_mutex_destroy(&status.lock);
    world_free(&base);
    world_free(&live);
    char cmd[160];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0)
        printf("# could not remove %s\n", dir);
}

int main(void)
{
    error_text err = {{0}};
    if (world_init(&test_world, 64, 48, 0.1, 10000, WORLD_HEIGHT_MIN, &err) != 0) {
        printf("world_init: %s\n", err.message);
        return 1;
    }
    fill_world();
    test_hub = hub_create();
    pthread_t sim;
    pthread_create(&sim, NULL, sim_thread, NULL);

    http_status status;
    memset(&status, 0, sizeof status);
    pthread_mutex_init(&status.lock, NULL);
    status.ready = 1;
    status.tick = 77;
    status.volume = 9007199254740993LL;
    status.world_width = test_world.width;
    status.world_height = test_world.height;
    status.cell_size_m = 0.1;
    status.units_per_m = 10000;
    status.tile_size = 32;
    status.tick_hz = 60;
    status.clients = 3;
    status.colliders = 5;
    status.last_tick_ms = 1.25;
    status.overruns = 2;
    snprintf(status.renderer, sizeof status.renderer, "test \"renderer\"");
    snprintf(status.backend, sizeof status.backend, "cpu");
    snprintf(status.method, sizeof status.method, "persson-single");
    snprintf(status.metric, sizeof status.metric, "chebyshev");

    hub_worlds *worlds = one_world(&status, test_hub);
    http_server *s = start_serving(&status, NULL, worlds, &err);
    CHECK(s != NULL, "http_server_start_secure: %s", err.message);
    if (!s)
        return 1;
    int port = http_server_port(s);
    CHECK(port > 0, "bound port %d", port);
    /* the very first request finds the world: the table is the server's from
     * its start (set after the start, early requests were 503, a data race) */
    response first;
    CHECK(get(port, "/v1/world", &first) == 0 && first.status == 200,
          "the first request after the start serves the world: %d", first.status);
    response_free(&first);

    check_probes(port, &status);
    check_views(port);
    check_metrics(port);
    check_heights_int32(port, 0, 0, 64, 48);
    check_heights_int32(port, 5, 7, 10, 3);
    check_heights_int32(port, 63, 47, 1, 1);
    check_heights_png(port, 1, 1, 30, 20, 0);
    check_heights_png(port, 0, 0, 64, 48, 1);
    check_heights_png(port, 38, 38, 10, 10, 1);
    check_heights_errors(port);
    check_static(port);
    check_limits(port);
    check_keep_alive(port);
    check_limited_server(&status, worlds);
    check_past_tick_leaving();

    http_server_stop(s);
    drop_worlds(worlds);
    atomic_store(&sim_stop, 1);
    pthread_join(sim, NULL);
    hub_close_reads(test_hub);
    hub_destroy(test_hub);
    world_free(&test_world);
    pthread_mutex_destroy(&status.lock);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
