/*
 * net_conn.c: who may open a websocket connection at all (the net_client
 * layer, see net_client_internal.h). Runs on the net thread when libwebsockets
 * has accepted a socket and before any byte of it is read, so that idle
 * strangers cannot take the descriptors the store, the probes and the
 * legitimate clients need (issue 15, item 4: 499 idle connections once
 * exhausted nofile 512, /healthz stopped answering and the store failed).
 *
 * Three checks, cheapest first:
 *   - the descriptor reserve: the kernel hands out the lowest free number, so
 *     an accepted descriptor at or above fd_ceiling (RLIMIT_NOFILE minus the
 *     reserve, computed at start) means fewer than the reserve are left free;
 *   - max_connections: established clients in all;
 *   - max_connections_per_address: established clients from the same address.
 * A refused socket is closed by libwebsockets at once; refusals are logged at
 * most once a second with a count of those not logged.
 */
#include "net/net_client_internal.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>

#define NET_REFUSAL_LOG_MS 1000.0
#define NET_SNDBUF (64 * 1024)

int net_fd_ceiling(int reserve)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0 || rl.rlim_cur == RLIM_INFINITY ||
        rl.rlim_cur > (rlim_t)1 << 30)
        return 1 << 30;
    long ceiling = (long)rl.rlim_cur - reserve;
    return ceiling < 16 ? 16 : (int)ceiling;
}

static void peer_of(int fd, char *out, size_t size)
{
    struct sockaddr_storage a;
    socklen_t n = sizeof a;
    out[0] = 0;
    if (getpeername(fd, (struct sockaddr *)&a, &n) != 0)
        return;
    if (a.ss_family == AF_INET)
        inet_ntop(AF_INET, &((struct sockaddr_in *)&a)->sin_addr, out, (socklen_t)size);
    else if (a.ss_family == AF_INET6)
        inet_ntop(AF_INET6, &((struct sockaddr_in6 *)&a)->sin6_addr, out, (socklen_t)size);
}

static void log_refusal(net_state *s, const char *peer, const char *why)
{
    double now = time_now_ms();
    s->conn_refused++;
    if (now - s->last_conn_refusal_log_ms < NET_REFUSAL_LOG_MS) {
        s->conn_refusals_unlogged++;
        return;
    }
    s->last_conn_refusal_log_ms = now;
    if (s->conn_refusals_unlogged)
        log_warn("net: refused a connection from %s: %s (and %llu more since the last such line)",
                 peer[0] ? peer : "?", why, (unsigned long long)s->conn_refusals_unlogged);
    else
        log_warn("net: refused a connection from %s: %s", peer[0] ? peer : "?", why);
    s->conn_refusals_unlogged = 0;
}

int net_admit_connection(net_state *s, int fd)
{
    THREAD_OWNED(&s->owner);
    const net_limits *l = &s->cfg.limits;
    char peer[64];
    peer_of(fd, peer, sizeof peer);
    if (s->fd_ceiling > 0 && fd >= s->fd_ceiling) {
        log_refusal(s, peer,
                    "file descriptors nearly exhausted (the rest are kept for the "
                    "store and the probes)");
        return 0;
    }
    if (l->max_connections > 0 && s->nclients >= l->max_connections) {
        log_refusal(s, peer, "max_connections reached");
        return 0;
    }
    if (l->max_connections_per_address > 0 && peer[0]) {
        int same = 0;
        for (int i = 0; i < s->nclients; i++)
            same += strcmp(s->clients[i]->peer, peer) == 0;
        if (same >= l->max_connections_per_address) {
            log_refusal(s, peer, "max_connections_per_address reached");
            return 0;
        }
    }
    /* Staleness is measured on the daemon's own queue (net_fanout.c net_drop_stale):
     * what the kernel has taken is out of reach. On loopback its send buffer
     * starts near 1.3 MB and may grow to 4 MB, seconds of frames for a slow
     * reader, so it is fixed at NET_SNDBUF (the kernel doubles it). */
    int sndbuf = NET_SNDBUF;
    setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &sndbuf, sizeof sndbuf);
    return 1;
}

void net_lws_log_line(int level, const char *line)
{
    size_t n = strlen(line);
    while (n && (line[n - 1] == '\n' || line[n - 1] == '\r'))
        n--;
    /* libwebsockets' own lines (accept errors among them) at a bounded rate:
     * a flood must not become a flood of log lines. lws logs from the net
     * thread only, so the window needs no lock. */
    static double window_ms;
    static unsigned in_window, dropped;
    double now = time_now_ms();
    if (now - window_ms > NET_REFUSAL_LOG_MS) {
        if (dropped)
            log_warn("libwebsockets: %u more lines not logged", dropped);
        window_ms = now;
        in_window = dropped = 0;
    }
    if (++in_window > 5) {
        dropped++;
        return;
    }
    if (level & LLL_ERR)
        log_error("libwebsockets: %.*s", (int)n, line);
    else
        log_warn("libwebsockets: %.*s", (int)n, line);
}

/* 1 if the comma-separated header value offers the protocol name. */
int net_offers_subprotocol(const char *value, const char *name)
{
    size_t n = strlen(name);
    const char *p = value;
    while (*p) {
        while (*p == ' ' || *p == '\t' || *p == ',')
            p++;
        const char *end = p;
        while (*end && *end != ',')
            end++;
        const char *last = end;
        while (last > p && (last[-1] == ' ' || last[-1] == '\t'))
            last--;
        if ((size_t)(last - p) == n && memcmp(p, name, n) == 0)
            return 1;
        p = end;
    }
    return 0;
}
