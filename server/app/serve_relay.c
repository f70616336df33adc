/*
 * serve_relay.c: any node of a cluster serves any world (docs/cluster.md).
 * The net server relays (net_remote.c); this file carries its messages over
 * NATS, on two plain subjects per world:
 *
 *   terrad.in.<world>   relays → the owner: a relayed client's messages as
 *                       they came (and that it left); the owner's world
 *                       thread subscribes while it ticks the world;
 *   terrad.out.<world>  the owner → every relay: each tile delta of the
 *                       world, once per tick, and the frames for relayed
 *                       clients (each naming its relay node). One subject,
 *                       so that a client's ACK of tick t never overtakes
 *                       tick t's deltas (NATS keeps one publisher's order per
 *                       subscription); a relay skips the frames of other
 *                       relays' clients.
 *
 * The node relays every registered world it does not tick (refreshed once a
 * second by the node loop) and stops relaying one just before it takes it.
 * Every message starts with a 28-byte header (wire_put) and the node name.
 */
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "app/serve_internal.h"
#include "metrics/metrics.h"

#define RELAY_MAX 128
#define WIRE_HEADER 28
#define RELAY_HTTP_TIMEOUT_MS 5000

typedef struct relay_entry {
    char world[CLUSTER_WORLD_NAME_MAX + 1];
    int owned; /* 1: this node ticks it (its ingress); 0: relayed here */
    cluster_sub *sub;
    cluster_sub *http_sub; /* owned: the HTTP requests relays forward (terrad.http.<world>) */
    int64_t dropped;       /* messages NATS dropped for it: its clients resync */
    serve_relays *r;
} relay_entry;

struct serve_relays {
    cluster *cl;
    net_server *net;
    http_server *http;
    char node[CLUSTER_NODE_NAME_MAX + 1];
    pthread_mutex_t lock; /* entries: the node loop and the world threads */
    relay_entry *entries[RELAY_MAX];
    int n;
    double warned_ms;
};

/* ---- the wire ---- */

static void put16(unsigned char *p, unsigned v)
{
    p[0] = (unsigned char)v;
    p[1] = (unsigned char)(v >> 8);
}

static void put32(unsigned char *p, uint32_t v)
{
    put16(p, v & 0xffff);
    put16(p + 2, v >> 16);
}

static uint32_t get32(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The header and the node name into out (WIRE_HEADER + 64 bytes at most); its length. */
static size_t wire_put(unsigned char *out, const net_remote_msg *m)
{
    size_t node_len = strnlen(m->node, CLUSTER_NODE_NAME_MAX);
    memset(out, 0, WIRE_HEADER);
    out[0] = 'T';
    out[1] = 'R';
    out[2] = 1;
    out[3] = (unsigned char)m->kind;
    out[4] = (unsigned char)((m->binary ? 1 : 0) | (m->snapshot_done ? 2 : 0));
    out[5] = (unsigned char)node_len;
    put32(out + 8, m->client);
    put32(out + 12, (uint32_t)m->close_code);
    put16(out + 16, (unsigned)m->tile_x);
    put16(out + 18, (unsigned)m->tile_y);
    put32(out + 20, (uint32_t)m->tick);
    put32(out + 24, (uint32_t)(m->tick >> 32));
    memcpy(out + WIRE_HEADER, m->node, node_len);
    return WIRE_HEADER + node_len;
}

/* 0 and the message, its payload at *payload; -1 when it is not one of ours. */
static int wire_get(const unsigned char *in, size_t len, net_remote_msg *m,
                    const unsigned char **payload, size_t *payload_len)
{
    if (len < WIRE_HEADER || in[0] != 'T' || in[1] != 'R' || in[2] != 1 || in[5] > 64 ||
        len < WIRE_HEADER + (size_t)in[5] || in[3] < NET_REMOTE_CLIENT_TEXT ||
        in[3] > NET_REMOTE_DELTA)
        return -1;
    memset(m, 0, sizeof *m);
    m->kind = in[3];
    m->binary = in[4] & 1;
    m->snapshot_done = (in[4] >> 1) & 1;
    m->client = get32(in + 8);
    m->close_code = (int)get32(in + 12);
    m->tile_x = in[16] | in[17] << 8;
    m->tile_y = in[18] | in[19] << 8;
    m->tick = get32(in + 20) | (uint64_t)get32(in + 24) << 32;
    memcpy(m->node, in + WIRE_HEADER, in[5]);
    *payload = in + WIRE_HEADER + in[5];
    *payload_len = len - WIRE_HEADER - in[5];
    return 0;
}

/* The net thread's way out (net_remote_send_fn). */
static void relay_send(void *ctx, const char *world, const net_remote_msg *m, const void *bytes,
                       size_t len)
{
    serve_relays *r = ctx;
    unsigned char *buf = malloc(WIRE_HEADER + 64 + len);
    if (!buf) {
        metrics_count_frames_dropped(1);
        return;
    }
    size_t head = wire_put(buf, m);
    if (len)
        memcpy(buf + head, bytes, len);
    char subject[CLUSTER_WORLD_NAME_MAX + 16];
    int to_owner = m->kind == NET_REMOTE_CLIENT_TEXT || m->kind == NET_REMOTE_CLIENT_BINARY ||
                   m->kind == NET_REMOTE_CLIENT_GONE;
    snprintf(subject, sizeof subject, "terrad.%s.%s", to_owner ? "in" : "out", world);
    if (cluster_publish(r->cl, subject, buf, head + len) != CLUSTER_OK)
        metrics_count_frames_dropped(1); /* NATS unreachable: the client's resync repairs */
    free(buf);
}

/* A message for a world of this node (a NATS client thread). */
static void relay_receive(void *ctx, const char *subject, const void *data, size_t len)
{
    (void)subject;
    relay_entry *e = ctx;
    serve_relays *r = e->r;
    net_remote_msg m;
    const unsigned char *payload;
    size_t payload_len;
    if (wire_get(data, len, &m, &payload, &payload_len) != 0) {
        metrics_count_frames_dropped(1);
        return;
    }
    int for_owner = m.kind <= NET_REMOTE_CLIENT_GONE;
    if (for_owner != e->owned)
        return;
    if (!e->owned && m.kind != NET_REMOTE_DELTA && m.client != 0 && strcmp(m.node, r->node) != 0)
        return; /* a frame for another relay's client */
    int64_t dropped = cluster_sub_dropped(e->sub);
    if (dropped != e->dropped) { /* NATS fell behind: deltas were lost, snapshots repair */
        e->dropped = dropped;
        net_remote_msg resync = {.kind = NET_REMOTE_DELTA, .tile_x = 0xffff, .tile_y = 0xffff};
        net_server_remote_input(r->net, e->world, &resync, NULL, 0);
    }
    net_server_remote_input(r->net, e->world, &m, payload, payload_len);
}

/* ---- HTTP: a relay asks the owner, which answers as its own port would ---- */

/* The entry of world; under r->lock. -1: none. */
static int find(serve_relays *r, const char *world)
{
    for (int i = 0; i < r->n; i++)
        if (strcmp(r->entries[i]->world, world) == 0)
            return i;
    return -1;
}

/* The owner's side, on a NATS thread: the request's bytes → the answer's. */
static void owner_http_answer(void *ctx, const void *data, size_t len, void **answer,
                              size_t *answer_len)
{
    relay_entry *e = ctx;
    int64_t max = cluster_max_payload(e->r->cl);
    if (http_server_answer(e->r->http, e->world, data, len, max > 0 ? (size_t)max : 1 << 20, answer,
                           answer_len) != 0)
        *answer = NULL; /* out of memory: the relay's request times out */
}

/* The relay's side, on an HTTP thread (http_forward_fn). */
static int relay_http_forward(void *ctx, const char *world, const void *request, size_t len,
                              void **answer, size_t *answer_len, unsigned *code, char *why,
                              size_t cap)
{
    serve_relays *r = ctx;
    pthread_mutex_lock(&r->lock);
    int at = find(r, world), relayed = at >= 0 && !r->entries[at]->owned;
    pthread_mutex_unlock(&r->lock);
    if (!relayed)
        return 0;
    char subject[CLUSTER_WORLD_NAME_MAX + 16];
    snprintf(subject, sizeof subject, "terrad.http.%s", world);
    error_text err = {{0}};
    /* longer than the owner's wait for its sim thread (heights_timeout_ms, 2 s by default) */
    int rc = cluster_request(r->cl, subject, request, len, RELAY_HTTP_TIMEOUT_MS, answer,
                             answer_len, &err);
    if (rc == 0) {
        *code = 503;
        snprintf(why, cap,
                 "no node ticks world \"%s\" now (its owner is gone and no node has taken it "
                 "over yet); retry in a few seconds",
                 world);
    } else if (rc < 0) {
        *code = 504;
        snprintf(why, cap, "the owner of world \"%s\" did not answer: %s", world, err.message);
    }
    return rc == 1 ? 1 : -1;
}

/* ---- the table of worlds ---- */

serve_relays *serve_relays_start(cluster *cl, net_server *net, http_server *http, const char *node)
{
    serve_relays *r = calloc(1, sizeof *r);
    if (!r)
        return NULL;
    r->cl = cl;
    r->net = net;
    r->http = http;
    snprintf(r->node, sizeof r->node, "%s", node);
    pthread_mutex_init(&r->lock, NULL);
    net_server_set_remote(net, node, relay_send, r);
    http_server_set_forward(http, relay_http_forward, r);
    return r;
}

/* Subscribes world's subject for its role; under r->lock. */
static int entry_add(serve_relays *r, const char *world, int owned, error_text *err)
{
    if (r->n >= RELAY_MAX) {
        error_set(err, "this node relays %d worlds already", RELAY_MAX);
        return -1;
    }
    relay_entry *e = calloc(1, sizeof *e);
    if (!e) {
        error_set(err, "out of memory");
        return -1;
    }
    snprintf(e->world, sizeof e->world, "%s", world);
    e->owned = owned;
    e->r = r;
    char subject[CLUSTER_WORLD_NAME_MAX + 16];
    snprintf(subject, sizeof subject, "terrad.%s.%s", owned ? "in" : "out", world);
    if (!(e->sub = cluster_subscribe(r->cl, subject, relay_receive, e, err))) {
        free(e);
        return -1;
    }
    snprintf(subject, sizeof subject, "terrad.http.%s", world);
    if (owned &&
        !(e->http_sub = cluster_serve_requests(r->cl, subject, owner_http_answer, e, err))) {
        cluster_unsubscribe(e->sub);
        free(e);
        return -1;
    }
    r->entries[r->n++] = e;
    return 0;
}

static void entry_remove(serve_relays *r, int i)
{
    relay_entry *e = r->entries[i];
    r->entries[i] = r->entries[--r->n];
    cluster_unsubscribe(e->sub);
    cluster_unsubscribe(e->http_sub);
    if (!e->owned)
        net_server_remove_relay(r->net, e->world);
    free(e);
}

int serve_relays_own(serve_relays *r, const char *world, error_text *err)
{
    pthread_mutex_lock(&r->lock);
    int i = find(r, world);
    if (i >= 0)
        entry_remove(r, i);
    int rc = entry_add(r, world, 1, err);
    pthread_mutex_unlock(&r->lock);
    if (rc == 0) {
        /* Clients relayed to an earlier owner are unknown here: every relay
         * closes them now (client 0: all), and they connect again. */
        net_remote_msg m = {.kind = NET_REMOTE_CLOSE, .client = 0, .close_code = 1001};
        relay_send(r, world, &m, r->node, strlen(r->node));
    }
    return rc;
}

void serve_relays_drop(serve_relays *r, const char *world)
{
    pthread_mutex_lock(&r->lock);
    int i = find(r, world);
    if (i >= 0)
        entry_remove(r, i);
    pthread_mutex_unlock(&r->lock);
}

/* The world info a relay needs: the extent from the registered scene. */
static int relay_world(serve_relays *r, const char *world, error_text *err)
{
    char *json = NULL;
    if (cluster_world_get(r->cl, world, &json, err) != 1) {
        free(json);
        return -1;
    }
    scene sc;
    memset(&sc, 0, sizeof sc);
    int rc = scene_load_json(json, ".", &sc, err);
    free(json);
    if (rc != 0)
        return -1;
    net_world_info info = {.width = sc.width,
                           .height = sc.height,
                           .cell_size_m = sc.cell_size_m,
                           .units_per_m = sc.units_per_m,
                           .tick_hz = sc.tick_hz,
                           .tile_size = SERVICE_TILE_SIZE,
                           .height_min = WORLD_HEIGHT_MIN,
                           .height_max = WORLD_HEIGHT_MAX,
                           .name = world};
    scene_free(&sc);
    if (net_server_add_relay(r->net, &info, err) != 0)
        return -1;
    if (entry_add(r, world, 0, err) != 0) {
        net_server_remove_relay(r->net, world);
        return -1;
    }
    log_info("cluster: node %s relays world %s (its owner ticks it; clients may connect here)",
             r->node, world);
    return 0;
}

void serve_relays_refresh(serve_relays *r, char *const *names, int count,
                          char (*busy)[CLUSTER_WORLD_NAME_MAX + 1], int nbusy)
{
    error_text err = {{0}};
    pthread_mutex_lock(&r->lock);
    for (int i = 0; i < r->n; i++) { /* unregistered: no longer relayed */
        int listed = 0;
        for (int k = 0; k < count; k++)
            listed |= strcmp(names[k], r->entries[i]->world) == 0;
        if (!listed && !r->entries[i]->owned)
            entry_remove(r, i--);
    }
    for (int k = 0; k < count; k++) {
        int mine = 0;
        for (int b = 0; b < nbusy; b++)
            mine |= strcmp(busy[b], names[k]) == 0;
        if (!mine && find(r, names[k]) < 0 && relay_world(r, names[k], &err) != 0 &&
            time_now_ms() - r->warned_ms > 10000) {
            r->warned_ms = time_now_ms();
            log_warn("cluster: cannot relay world %s: %s", names[k], err.message);
        }
    }
    pthread_mutex_unlock(&r->lock);
}

void serve_relays_stop(serve_relays *r)
{
    if (!r)
        return;
    http_server_set_forward(r->http, NULL, NULL); /* no HTTP thread uses r after this */
    pthread_mutex_lock(&r->lock);
    while (r->n > 0)
        entry_remove(r, r->n - 1);
    pthread_mutex_unlock(&r->lock);
    pthread_mutex_destroy(&r->lock);
    free(r);
}
