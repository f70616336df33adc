/*
 * http_guard.c: what one client address may hold of the HTTP threads (issue
 * 15, items 6 and 7), beside libmicrohttpd's own connection limits and idle
 * timeout (http.c):
 *
 *   - heights bytes in flight: each /v1/heights answer is one allocation of
 *     the whole rectangle held until the client has read it; 62 unread
 *     answers from one address once took RSS to 1.3 GB. An answer reserves
 *     its bytes against its address (and against everyone) before it is
 *     built, and gives them back when its request ends: sent, timed out by
 *     MHD's idle timeout (an unread answer makes no progress), or the peer
 *     gone. Past a budget the request is refused (429, JSON, a metric).
 *   - a deadline for a request's headers: MHD's timeout counts idle time, so
 *     a client sending one byte every few seconds (slowloris) was never cut.
 *     A sweeper thread shuts down (shutdown(2), MHD then closes it) every
 *     connection that has not sent a whole request's headers within
 *     header_deadline_s of opening or of its previous request's end.
 *   - room for the next connection (issue 20, item 3: 300 slow connections
 *     from one address held its 64 slots, and only 99 of 120 API calls from
 *     that address answered in 40 s). Past the per-address or the overall
 *     connection limit a new connection does not wait for a slot: the oldest
 *     connection that is still sending its headers (from that address, or
 *     from any) is closed to make room. A client that sends its request at
 *     once is never that one; a slow crowd only pushes its own out.
 *   - never a silent close of a request (issue 28, item 5: of 200 concurrent
 *     edits from one address, 77 were closed without an answer, some of them
 *     applied). A connection whose bytes wait unread in the kernel is not
 *     slow: the HTTP threads are busy (an edit holds its thread until its
 *     tick), so it waits its turn, never cut. One closed to make room gets a
 *     503 with Retry-After written before the close (plain HTTP; under TLS
 *     the guard cannot write through the session and closes it as before);
 *     it had sent no whole request, and the handler refuses any request of a
 *     connection cut meanwhile, so nothing of it is applied. When every
 *     connection of the address (or in all) is inside a request or waiting
 *     its turn, the new one is refused: it is read and answered 503 with
 *     Retry-After (http.c), never applied, counted in
 *     terrad_http_refused_total.
 *
 * The HTTP threads and the sweeper meet under one mutex, held for a short
 * walk; nothing here touches the tick.
 */
#include "http/http_internal.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <time.h>

#include "metrics/metrics.h"

#define GUARD_ADDRESSES 1024 /* distinct addresses holding bytes at once */
#define GUARD_SWEEP_MS 250

typedef struct guard_address {
    int family; /* 0: free */
    unsigned char addr[16];
    size_t bytes;
} guard_address;

typedef struct guard_conn {
    struct guard_conn *prev, *next;
    int fd;
    int family;
    unsigned char addr[16];
    double since_ms; /* opened, or its previous request ended */
    int in_request;  /* headers seen, the request not ended */
    int refused;     /* HTTP_GUARD_REFUSED_*: answered 503 once its request is read */
    int served;      /* requests it has ended: a cut between two is a keep-alive's close */
    int cut;
    size_t reserved; /* heights bytes of its current request */
} guard_conn;

struct http_guard {
    pthread_mutex_t lock;
    pthread_cond_t wake;
    pthread_t thread;
    int stop;
    size_t per_address, total, in_flight;
    double deadline_ms;
    unsigned max_conns, max_per_address; /* 0: no limit */
    int tls; /* answers cannot be written around the TLS session: a cut is a close */
    unsigned evicted_unlogged;
    double last_evict_log_ms;
    guard_conn *conns;
    guard_address addresses[GUARD_ADDRESSES];
    double last_log_ms;
    unsigned cuts_unlogged;
};

static guard_conn *conn_of(struct MHD_Connection *c)
{
    const union MHD_ConnectionInfo *i =
        MHD_get_connection_info(c, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
    return i ? i->socket_context : NULL;
}

static guard_address *address_slot(http_guard *g, const guard_conn *gc, int create)
{
    guard_address *free_slot = NULL;
    for (int i = 0; i < GUARD_ADDRESSES; i++) {
        guard_address *a = &g->addresses[i];
        if (a->family == gc->family && memcmp(a->addr, gc->addr, sizeof a->addr) == 0)
            return a;
        if (!a->family && !free_slot)
            free_slot = a;
    }
    if (!create || !free_slot)
        return NULL;
    free_slot->family = gc->family;
    memcpy(free_slot->addr, gc->addr, sizeof free_slot->addr);
    free_slot->bytes = 0;
    return free_slot;
}

/* Give back what gc's request reserved (under the lock). */
static void release(http_guard *g, guard_conn *gc)
{
    if (!gc->reserved)
        return;
    guard_address *a = address_slot(g, gc, 0);
    if (a) {
        a->bytes -= gc->reserved < a->bytes ? gc->reserved : a->bytes;
        if (!a->bytes)
            a->family = 0;
    }
    g->in_flight -= gc->reserved < g->in_flight ? gc->reserved : g->in_flight;
    gc->reserved = 0;
}

/* 1 when the client has sent its request's headers whole and they wait
 * unread in the kernel: it is not slow, the HTTP threads have not got to it
 * yet (libmicrohttpd handles headers as soon as it reads their end, so the
 * end is among the unread bytes; one split inside "\r\n\r\n" is missed). Under TLS the bytes are
 * ciphertext: any unread ones count. A slow sender's byte also waits a moment for a busy thread:
 * only a whole request's headers protect it. */
static int waits_its_turn(const http_guard *g, const guard_conn *gc)
{
    int n = 0;
    if (gc->fd < 0 || ioctl(gc->fd, FIONREAD, &n) != 0 || n <= 0)
        return 0;
    if (g->tls)
        return 1;
    char buf[4096];
    ssize_t got = recv(gc->fd, buf, sizeof buf, MSG_PEEK | MSG_DONTWAIT);
    if (got <= 0)
        return 0;
    for (ssize_t i = 0; i + 3 < got; i++)
        if (buf[i] == '\r' && buf[i + 1] == '\n' && buf[i + 2] == '\r' && buf[i + 3] == '\n')
            return 1;
    return 0;
}

/* Close gc (under the lock), telling the client why first where the bytes
 * can be written straight to the socket: not TLS, and before its first
 * request (nothing was ever written on it). An idle keep-alive connection
 * (served) is closed as any server closes one between requests: its last
 * answer may still be on its way, and bytes after it would be garbage. */
static void cut(http_guard *g, guard_conn *gc, const char *status, const char *why)
{
    if (gc->fd >= 0 && !g->tls && !gc->served) {
        char body[256], answer[512];
        int n = snprintf(body, sizeof body, "{\"error\":\"%s\"}\n", why);
        int len = snprintf(answer, sizeof answer,
                           "HTTP/1.1 %s\r\nContent-Type: application/json\r\nRetry-After: "
                           "1\r\nConnection: close\r\nCache-Control: no-store\r\n"
                           "Content-Length: %d\r\n\r\n%s",
                           status, n, body);
        if (len > 0 && (size_t)len < sizeof answer)
            (void)!send(gc->fd, answer, (size_t)len, MSG_DONTWAIT | MSG_NOSIGNAL);
    }
    if (gc->fd >= 0)
        shutdown(gc->fd, SHUT_RDWR); /* MHD sees the end and closes it */
    gc->cut = 1;
    metrics_count_http_cut(1);
}

static void sweep(http_guard *g)
{
    double now = time_now_ms();
    unsigned n = 0;
    for (guard_conn *gc = g->conns; gc; gc = gc->next) {
        if (gc->in_request || gc->cut || now - gc->since_ms < g->deadline_ms ||
            waits_its_turn(g, gc))
            continue;
        cut(g, gc, "408 Request Timeout", "no whole request within the header deadline");
        n++;
    }
    if (!n)
        return;
    g->cuts_unlogged += n;
    if (now - g->last_log_ms >= 1000.0) {
        log_warn("http: closed %u connection(s) that sent no whole request within %.0f s",
                 g->cuts_unlogged, g->deadline_ms / 1000);
        g->cuts_unlogged = 0;
        g->last_log_ms = now;
    }
}

static void *sweeper(void *arg)
{
    http_guard *g = arg;
    pthread_mutex_lock(&g->lock);
    while (!g->stop) {
        struct timespec t = time_after_ms(CLOCK_REALTIME, GUARD_SWEEP_MS);
        pthread_cond_timedwait(&g->wake, &g->lock, &t);
        if (!g->stop)
            sweep(g);
    }
    pthread_mutex_unlock(&g->lock);
    return NULL;
}

http_guard *http_guard_start(size_t per_address, size_t total, unsigned header_deadline_s,
                             unsigned max_conns, unsigned max_per_address, int tls)
{
    http_guard *g = calloc(1, sizeof *g);
    if (!g)
        return NULL;
    g->max_conns = max_conns;
    g->max_per_address = max_per_address;
    g->tls = tls;
    g->per_address = per_address;
    g->total = total;
    g->deadline_ms = header_deadline_s * 1000.0;
    pthread_mutex_init(&g->lock, NULL);
    pthread_cond_init(&g->wake, NULL);
    if (pthread_create(&g->thread, NULL, sweeper, g) != 0) {
        pthread_cond_destroy(&g->wake);
        pthread_mutex_destroy(&g->lock);
        free(g);
        return NULL;
    }
    return g;
}

void http_guard_stop(http_guard *g)
{
    if (!g)
        return;
    pthread_mutex_lock(&g->lock);
    g->stop = 1;
    pthread_cond_signal(&g->wake);
    pthread_mutex_unlock(&g->lock);
    pthread_join(g->thread, NULL);
    while (g->conns) { /* MHD has stopped: whatever it did not report closed */
        guard_conn *gc = g->conns;
        g->conns = gc->next;
        free(gc);
    }
    pthread_cond_destroy(&g->wake);
    pthread_mutex_destroy(&g->lock);
    free(g);
}

static int same_address(const guard_conn *a, const guard_conn *b)
{
    return a->family == b->family && memcmp(a->addr, b->addr, sizeof a->addr) == 0;
}

/* Close the oldest connection still sending its headers (from nc's address
 * when same, else from any), answering it 503 where it can; when there is
 * none (every other one is in a request or waits its turn), nc is refused:
 * answered 503 once its request is read. Under the lock. */
static void evict_oldest(http_guard *g, guard_conn *nc, int same)
{
    guard_conn *pick = NULL;
    for (guard_conn *gc = g->conns; gc; gc = gc->next)
        if (gc != nc && !gc->in_request && !gc->cut && !gc->refused &&
            (!same || same_address(gc, nc)) && (!pick || gc->since_ms <= pick->since_ms) &&
            !waits_its_turn(g, gc))
            pick = gc; /* newest first in the list: "<=" ends on the oldest */
    if (!pick) {
        nc->refused = same ? HTTP_GUARD_REFUSED_ADDRESS : HTTP_GUARD_REFUSED_ALL;
        return;
    }
    cut(g, pick, "503 Service Unavailable",
        same ? "too many connections from this address at once; nothing was done: retry"
             : "too many connections at once; nothing was done: retry");
    g->evicted_unlogged++;
    double now = time_now_ms();
    if (now - g->last_evict_log_ms >= 1000.0) {
        log_warn("http: closed %u connection(s) still sending their headers to make room for "
                 "new ones (limits: %u per address, %u in all)",
                 g->evicted_unlogged, g->max_per_address, g->max_conns);
        g->evicted_unlogged = 0;
        g->last_evict_log_ms = now;
    }
}

/* Under the lock, nc just added: make room past either connection limit. */
static void make_room(http_guard *g, guard_conn *nc)
{
    unsigned all = 0, mine = 0;
    for (guard_conn *gc = g->conns; gc; gc = gc->next) {
        if (gc->cut || gc->refused)
            continue;
        all++;
        mine += same_address(gc, nc);
    }
    if (g->max_per_address && mine > g->max_per_address)
        evict_oldest(g, nc, 1);
    else if (g->max_conns && all > g->max_conns)
        evict_oldest(g, nc, 0);
}

static void conn_started(http_guard *g, struct MHD_Connection *c, void **socket_context)
{
    guard_conn *gc = calloc(1, sizeof *gc);
    if (!gc)
        return; /* unguarded: MHD's own limits still hold */
    const union MHD_ConnectionInfo *fd =
        MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
    const union MHD_ConnectionInfo *ad =
        MHD_get_connection_info(c, MHD_CONNECTION_INFO_CLIENT_ADDRESS);
    gc->fd = fd ? fd->connect_fd : -1;
    if (ad && ad->client_addr && ad->client_addr->sa_family == AF_INET) {
        gc->family = AF_INET;
        memcpy(gc->addr, &((const struct sockaddr_in *)ad->client_addr)->sin_addr, 4);
    } else if (ad && ad->client_addr && ad->client_addr->sa_family == AF_INET6) {
        gc->family = AF_INET6;
        memcpy(gc->addr, &((const struct sockaddr_in6 *)ad->client_addr)->sin6_addr, 16);
    } else {
        gc->family = -1; /* one shared slot for whatever else */
    }
    gc->since_ms = time_now_ms();
    pthread_mutex_lock(&g->lock);
    gc->next = g->conns;
    if (g->conns)
        g->conns->prev = gc;
    g->conns = gc;
    make_room(g, gc);
    pthread_mutex_unlock(&g->lock);
    *socket_context = gc;
}

void http_guard_notify(void *cls, struct MHD_Connection *c, void **socket_context,
                       enum MHD_ConnectionNotificationCode code)
{
    http_guard *g = cls;
    if (code == MHD_CONNECTION_NOTIFY_STARTED) {
        conn_started(g, c, socket_context);
        return;
    }
    guard_conn *gc = *socket_context;
    if (!gc)
        return;
    pthread_mutex_lock(&g->lock);
    release(g, gc);
    if (gc->prev)
        gc->prev->next = gc->next;
    else
        g->conns = gc->next;
    if (gc->next)
        gc->next->prev = gc->prev;
    pthread_mutex_unlock(&g->lock);
    free(gc);
    *socket_context = NULL;
}

int http_guard_headers_done(http_guard *g, struct MHD_Connection *c)
{
    guard_conn *gc = conn_of(c);
    if (!gc)
        return 0;
    pthread_mutex_lock(&g->lock);
    int r = gc->cut ? -1 : gc->refused;
    gc->in_request = 1; /* never cut from now on: it gets its answer */
    pthread_mutex_unlock(&g->lock);
    return r;
}

void http_guard_limits(const http_guard *g, unsigned *per_address, unsigned *all)
{
    *per_address = g->max_per_address;
    *all = g->max_conns;
}

int http_guard_reserve(http_guard *g, struct MHD_Connection *c, size_t bytes)
{
    guard_conn *gc = conn_of(c);
    if (!gc)
        return 0;
    pthread_mutex_lock(&g->lock);
    guard_address *a = address_slot(g, gc, 1);
    int ok = a && a->bytes + bytes <= g->per_address && g->in_flight + bytes <= g->total;
    if (ok) {
        a->bytes += bytes;
        g->in_flight += bytes;
        gc->reserved += bytes;
    } else if (a && !a->bytes) {
        a->family = 0;
    }
    pthread_mutex_unlock(&g->lock);
    if (!ok)
        metrics_count_heights_refused();
    return ok ? 0 : -1;
}

void http_guard_request_done(http_guard *g, struct MHD_Connection *c)
{
    guard_conn *gc = conn_of(c);
    if (!gc)
        return;
    pthread_mutex_lock(&g->lock);
    release(g, gc);
    gc->in_request = 0;
    gc->served++;
    gc->since_ms = time_now_ms();
    pthread_mutex_unlock(&g->lock);
}
