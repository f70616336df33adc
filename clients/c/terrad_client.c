/*
 * terrad_client.c: the synchronous C client of terrad_client.h.
 *
 * One libwebsockets context per client, with a single protocol callback and
 * the client as the context's user pointer. Outgoing messages wait in a
 * small FIFO and go out one per CLIENT_WRITEABLE callback (libwebsockets'
 * rule); incoming fragments are reassembled into one buffer and handled
 * whole: JSON replies complete the request being waited for, DELTA frames
 * go through terrad_mirror_apply for every subscription, CONTACT and ACK
 * frames replace the latest ones.
 *
 * Blocking waits are lws_service() calls bounded by a wsi timer
 * (LWS_CALLBACK_TIMER wakes the service loop at the deadline): since
 * libwebsockets 3.2 the service call's own timeout argument is ignored.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L
#endif

#include "terrad_client.h"
#include "terrad_client_internal.h"

#include <cjson/cJSON.h>
#include <libwebsockets.h>
#include <math.h>
#include <poll.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#define CLIENT_MAX_MESSAGE (64u << 20) /* largest frame we reassemble */
#define CLIENT_RX_CHUNK 65536
#define CLIENT_STEP_RING 128 /* more than the server queues (64): no answer overwritten unread */

typedef struct out_msg {
    struct out_msg *next;
    size_t len;
    int binary;
    unsigned char buf[]; /* LWS_PRE bytes of headroom, then len bytes */
} out_msg;

typedef struct client_sub {
    uint32_t id;
    terrad_mirror m;
    int32_t *heights;
    uint32_t *versions;
    int32_t *base; /* base snapshots: the scene's base over the region (m.base) */
} client_sub;

struct terrad_client {
    struct lws_context *ctx;
    struct lws *wsi;
    int established, closed, closing, got_world;
    int timeout_ms;
    char err[512];
    terrad_world_info world;
    terrad_client_stats stats;
    terrad_client_hook hook;
    void *user;
    terrad_client_log_fn log;
    int log_level;

    out_msg *out_head, *out_tail;

    uint8_t *rx;
    size_t rx_len, rx_cap;
    int rx_binary, rx_in_msg, rx_overflow;

    /* the request being waited for */
    char wait_ref[32];
    int wait_done, wait_code;
    int64_t wait_id;
    int64_t wait_tick, wait_volume; /* an "edited" reply's */
    unsigned ref_counter;
    uint64_t poll_mark;
    /* PROTOCOL.md "seen": the latest tick handled (the hook has run), what the
     * server was told, and when (it bounds this client's lag by it) */
    uint64_t handled_tick, said_tick;
    int64_t said_us;
    int no_seen;          /* a daemon from before "seen" refused it (unknown_type) */
    int max_resync_tiles; /* the world's limits.max_resync_tiles */
    uint32_t seq;

    client_sub *subs;
    size_t nsubs, subs_cap;
    terrad_contact *contacts;
    size_t ncontacts, contacts_cap;
    uint64_t contact_tick;
    terrad_force *forces; /* the latest FORCES frame (bekker worlds) */
    size_t nforces, forces_cap;
    double *force_heights; /* its heights (nforce_heights 0: it had none) */
    size_t nforce_heights, force_heights_cap;
    uint64_t forces_tick;
    terrad_collider_state *colliders;        /* the latest COLLIDERS frame (colliders in view) */
    terrad_collider_grousers *collider_lugs; /* their grousers (all zero without the flag) */
    size_t ncolliders, colliders_cap, lugs_cap;
    uint64_t colliders_tick;
    terrad_rect *rects;
    size_t rects_cap;
    int32_t *scratch;
    size_t scratch_cells;
    terrad_codec *codec;
    char world_name[72]; /* the world message's name */
    client_own *own;     /* the colliders this client created */
    size_t nown, own_cap;
    terrad_prediction *predictions; /* terrad_client_predict.c */
    /* lockstep (client-clocked worlds): step numbers sent, and each answer
     * (STEPPED or an error whose ref is "step:SEQ") in a ring by seq */
    int client_clock;
    /* base snapshots (terrad_client_connect_base): asked for in hello (1; 2:
     * slope snapshots offered too, terrad_client_connect_slope), and the world
     * message's answers with the base's twin config */
    int base_asked, base_on, slope_on;
    cJSON *base;
    uint32_t step_seq, step_waiting;
    struct {
        uint32_t seq;
        int answered, code;
        uint64_t tick;
    } steps[CLIENT_STEP_RING];
};

/* ---- small helpers ------------------------------------------------------- */

static int64_t now_us(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000 + ts.tv_nsec / 1000;
}

static void log_line(terrad_client *c, int level, const char *text)
{
    if (c->log && level <= c->log_level)
        c->log(c->user, level, text);
}

/* Keeps the sentence for terrad_client_last_error and logs it at level. */
static void set_err_at(terrad_client *c, int level, const char *fmt, va_list ap)
{
    vsnprintf(c->err, sizeof c->err, fmt, ap);
    log_line(c, level, c->err);
}

static void set_err(terrad_client *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void set_err(terrad_client *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    set_err_at(c, TERRAD_LOG_ERROR, fmt, ap);
    va_end(ap);
}

static void set_warn(terrad_client *c, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void set_warn(terrad_client *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    set_err_at(c, TERRAD_LOG_WARN, fmt, ap);
    va_end(ap);
}

static int grow(void **p, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return 0;
    size_t n = *cap ? *cap : 16;
    while (n < need)
        n *= 2;
    void *q = realloc(*p, n * elem);
    if (!q)
        return -1;
    *p = q;
    *cap = n;
    return 0;
}

static client_sub *find_sub(const terrad_client *c, uint32_t sid)
{
    for (size_t i = 0; i < c->nsubs; i++)
        if (c->subs[i].id == sid)
            return &c->subs[i];
    return NULL;
}

/* ---- outgoing ------------------------------------------------------------ */

static int enqueue(terrad_client *c, const void *data, size_t len, int binary)
{
    if (c->closed || !c->wsi)
        return TERRAD_CLIENT_E_CLOSED;
    out_msg *m = malloc(sizeof *m + LWS_PRE + len);
    if (!m)
        return TERRAD_E_NO_MEMORY;
    m->next = NULL;
    m->len = len;
    m->binary = binary;
    memcpy(m->buf + LWS_PRE, data, len);
    if (c->out_tail)
        c->out_tail->next = m;
    else
        c->out_head = m;
    c->out_tail = m;
    if (c->established)
        lws_callback_on_writable(c->wsi);
    return 0;
}

/* A binary frame its encoder wrote into buf (rc: the encoder's result) queued
 * when it was encoded; buf freed unless it is the caller's stackbuf. */
static int enqueue_encoded(terrad_client *c, int rc, uint8_t *buf, size_t len,
                           const uint8_t *stackbuf)
{
    if (rc == 0)
        rc = enqueue(c, buf, len, 1);
    if (buf != stackbuf)
        free(buf);
    return rc;
}

/* Push queued messages out without blocking for long. */
static void flush(terrad_client *c)
{
    for (int i = 0; i < 8 && c->out_head && !c->closed && c->established; i++)
        lws_service(c->ctx, -1);
}

static void free_queue(terrad_client *c)
{
    while (c->out_head) {
        out_msg *n = c->out_head->next;
        free(c->out_head);
        c->out_head = n;
    }
    c->out_tail = NULL;
}

/* ---- incoming ------------------------------------------------------------ */

static int64_t json_int(const cJSON *o, const char *k, int64_t dflt)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, k);
    return cJSON_IsNumber(v) ? (int64_t)v->valuedouble : dflt;
}

static double json_num(const cJSON *o, const char *k, double dflt)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, k);
    return cJSON_IsNumber(v) ? v->valuedouble : dflt;
}

static void on_world(terrad_client *c, const cJSON *m)
{
    terrad_world_info *w = &c->world;
    w->width = (int)json_int(m, "width", 0);
    w->height = (int)json_int(m, "height", 0);
    w->tile_size = (int)json_int(m, "tile_size", 64);
    w->cell_size_m = json_num(m, "cell_size_m", 0);
    w->tick_hz = json_num(m, "tick_hz", 60);
    w->units_per_m = (int32_t)json_int(m, "units_per_m", 10000);
    w->tick = (uint64_t)json_int(m, "tick", 0);
    const cJSON *r = cJSON_GetObjectItemCaseSensitive(m, "height_range");
    if (cJSON_IsArray(r) && cJSON_GetArraySize(r) == 2) {
        w->height_min = (int64_t)cJSON_GetArrayItem(r, 0)->valuedouble;
        w->height_max = (int64_t)cJSON_GetArrayItem(r, 1)->valuedouble;
    }
    const cJSON *l = cJSON_GetObjectItemCaseSensitive(m, "limits");
    w->max_message_bytes = json_int(l, "max_message_bytes", 1048576);
    w->max_poses_per_batch = json_int(l, "max_poses_per_batch", 64);
    w->max_colliders = json_int(l, "max_colliders", 64);
    w->max_subscriptions = json_int(l, "max_subscriptions", 16);
    w->budget = json_int(m, "budget", 0);
    c->max_resync_tiles = (int)json_int(l, "max_resync_tiles", 64);
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(m, "world");
    snprintf(c->world_name, sizeof c->world_name, "%s",
             cJSON_IsString(name) ? name->valuestring : "");
    const cJSON *clock = cJSON_GetObjectItemCaseSensitive(m, "clock");
    c->client_clock = cJSON_IsString(clock) && strcmp(clock->valuestring, "client") == 0;
    const cJSON *base = cJSON_GetObjectItemCaseSensitive(m, "base");
    c->base_on = c->base_asked &&
                 cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(m, "snapshot_base")) &&
                 cJSON_IsObject(base) && (c->base = cJSON_Duplicate(base, 1)) != NULL;
    c->slope_on = c->base_on && c->base_asked == 2 &&
                  cJSON_IsTrue(cJSON_GetObjectItemCaseSensitive(m, "snapshot_slope"));
    c->got_world = 1;
}

static int add_sub(terrad_client *c, uint32_t sid, int64_t x, int64_t y, int64_t w, int64_t h)
{
    if (w <= 0 || h <= 0 || w > 65536 || h > 65536 || c->world.tile_size <= 0)
        return TERRAD_CLIENT_E_PROTOCOL;
    if (find_sub(c, sid))
        return TERRAD_CLIENT_E_PROTOCOL;
    if (grow((void **)&c->subs, &c->subs_cap, c->nsubs + 1, sizeof *c->subs))
        return TERRAD_E_NO_MEMORY;
    client_sub *s = &c->subs[c->nsubs];
    memset(s, 0, sizeof *s);
    size_t tiles = terrad_mirror_tile_count((int32_t)x, (int32_t)y, (uint32_t)w, (uint32_t)h,
                                            (uint32_t)c->world.tile_size);
    s->heights = calloc((size_t)w * (size_t)h, sizeof *s->heights);
    s->versions = calloc(tiles ? tiles : 1, sizeof *s->versions);
    if (c->base_on)
        s->base = malloc((size_t)w * (size_t)h * sizeof *s->base);
    if (!s->heights || !s->versions || (c->base_on && !s->base) ||
        terrad_mirror_init(&s->m, (int32_t)x, (int32_t)y, (uint32_t)w, (uint32_t)h,
                           (uint32_t)c->world.tile_size, s->heights, s->versions) != 0) {
        free(s->heights);
        free(s->versions);
        free(s->base);
        return TERRAD_E_NO_MEMORY;
    }
    if (c->base_on) { /* before any snapshot of it is read: they come after "subscribed" */
        char why[300];
        if (client_base_fill(c->base, (int)x, (int)y, (int)w, (int)h, s->base, why, sizeof why) !=
            0) {
            set_err(c, "%s", why);
            free(s->heights);
            free(s->versions);
            free(s->base);
            return TERRAD_CLIENT_E_PROTOCOL;
        }
        s->m.base = s->base;
    }
    s->id = sid;
    c->nsubs++;
    return 0;
}

/* Step seq was answered: code 0 (STEPPED at tick) or the error's. */
static void step_answered(terrad_client *c, uint32_t seq, int code, uint64_t tick)
{
    size_t i = seq % CLIENT_STEP_RING;
    c->steps[i].seq = seq;
    c->steps[i].answered = 1;
    c->steps[i].code = code;
    c->steps[i].tick = tick;
}

static void on_text(terrad_client *c, const char *text, size_t len)
{
    cJSON *m = cJSON_ParseWithLength(text, len);
    const cJSON *type = cJSON_GetObjectItemCaseSensitive(m, "type");
    if (!cJSON_IsString(type)) {
        set_err(c, "the server sent a text frame that is not a JSON message");
        c->stats.errors++;
        c->stats.last_error_code = TERRAD_CLIENT_E_PROTOCOL;
        cJSON_Delete(m);
        return;
    }
    const char *t = type->valuestring;
    const cJSON *ref = cJSON_GetObjectItemCaseSensitive(m, "ref");
    int mine = c->wait_ref[0] && cJSON_IsString(ref) && strcmp(ref->valuestring, c->wait_ref) == 0;
    if (strcmp(t, "world") == 0) {
        on_world(c, m);
    } else if (strcmp(t, "error") == 0) {
        int code = (int)json_int(m, "code", TERRAD_E_INTERNAL);
        const cJSON *name = cJSON_GetObjectItemCaseSensitive(m, "name");
        const cJSON *msg = cJSON_GetObjectItemCaseSensitive(m, "message");
        set_err(c, "server error %d %s: %s", code, cJSON_IsString(name) ? name->valuestring : "?",
                cJSON_IsString(msg) ? msg->valuestring : "");
        c->stats.last_error_code = code;
        unsigned step;
        if (cJSON_IsString(ref) && strcmp(ref->valuestring, "seen") == 0) {
            c->no_seen |= code == TERRAD_E_UNKNOWN_TYPE; /* a daemon from before "seen" */
            c->stats.errors++;
        } else if (cJSON_IsString(ref) && sscanf(ref->valuestring, "step:%u", &step) == 1) {
            step_answered(c, step, code > 0 ? code : TERRAD_E_INTERNAL, 0);
        } else if (mine) {
            c->wait_done = 1;
            c->wait_code = code > 0 ? code : TERRAD_E_INTERNAL;
        } else {
            c->stats.errors++;
            if (!c->got_world) { /* the handshake failed */
                c->wait_done = 1;
                c->wait_code = code > 0 ? code : TERRAD_E_INTERNAL;
            }
        }
    } else {
        if (strcmp(t, "subscribed") == 0) {
            int rc = add_sub(c, (uint32_t)json_int(m, "id", 0), json_int(m, "x", -1),
                             json_int(m, "y", -1), json_int(m, "w", 0), json_int(m, "h", 0));
            if (rc && mine) {
                set_err(c, "cannot make a mirror for the subscription (%d)", rc);
                c->wait_done = 1;
                c->wait_code = rc;
                mine = 0;
            }
        }
        if (mine) {
            c->wait_done = 1;
            c->wait_code = 0;
            c->wait_id = json_int(m, "id", 0);
            c->wait_tick = json_int(m, "tick", 0);
            c->wait_volume = json_int(m, "volume_change", 0);
        }
    }
    cJSON_Delete(m);
}

static void bad_frame(terrad_client *c, const char *what, int code)
{
    set_err(c, "the server sent a bad %s frame: %s", what, terrad_err_name(code));
    c->stats.errors++;
    c->stats.last_error_code = code;
}

static int send_resync(terrad_client *c, uint32_t sid);

#define CLIENT_SEEN_INTERVAL_US 100000 /* a "seen" at most every 0.1 s */

/* Tell the server the latest tick handled, at most every 0.1 s; called after
 * each frame and from terrad_client_poll, so the last frames before a pause
 * are said too. */
static void say_seen(terrad_client *c)
{
    int64_t now = now_us();
    if (c->no_seen || c->handled_tick <= c->said_tick || now - c->said_us < CLIENT_SEEN_INTERVAL_US)
        return;
    char text[80]; /* ref: an older daemon's refusal names it */
    int n = snprintf(text, sizeof text, "{\"type\":\"seen\",\"tick\":%llu,\"ref\":\"seen\"}",
                     (unsigned long long)c->handled_tick);
    if (enqueue(c, text, (size_t)n, 0) == 0) {
        c->said_tick = c->handled_tick;
        c->said_us = now;
    }
}

static void on_delta(terrad_client *c, const uint8_t *buf, size_t len, uint64_t *tick)
{
    size_t cap = len >= TERRAD_DELTA_FIXED ? (len - TERRAD_DELTA_FIXED) / TERRAD_RECT_FIXED + 1 : 1;
    if (grow((void **)&c->rects, &c->rects_cap, cap, sizeof *c->rects))
        return bad_frame(c, "DELTA (no memory)", TERRAD_E_NO_MEMORY);
    size_t n = 0;
    int rc = terrad_delta_decode(buf, len, tick, c->rects, c->rects_cap, &n);
    if (rc)
        return bad_frame(c, "DELTA", rc);
    c->stats.delta_frames++;
    c->stats.delta_bytes += len;
    c->stats.delta_tick = *tick;
    size_t most = 1;
    for (size_t i = 0; i < n; i++)
        if ((size_t)c->rects[i].w * c->rects[i].h > most)
            most = (size_t)c->rects[i].w * c->rects[i].h;
    if (most > c->scratch_cells) {
        int32_t *s = realloc(c->scratch, most * sizeof *s);
        if (!s)
            return bad_frame(c, "DELTA (no memory)", TERRAD_E_NO_MEMORY);
        c->scratch = s;
        c->scratch_cells = most;
    }
    for (size_t i = 0; i < c->nsubs; i++) {
        client_sub *s = &c->subs[i];
        rc = terrad_mirror_apply(&s->m, c->codec, c->rects, n, c->scratch, c->scratch_cells);
        if (rc) {
            set_warn(c, "subscription %u: %s, asking for a resync", s->id, terrad_err_name(rc));
            c->stats.last_error_code = rc;
            c->stats.resyncs++;
            send_resync(c, s->id);
        }
    }
}

/* PROTOCOL.md "CHECKSUM": every frame before it is applied, so the mirror
 * holds the frame's tick; each held tile that differs is forgotten (version
 * 0: its deltas skipped) and asked for again, at most max_resync_tiles per
 * request (the rest at the next CHECKSUM). */
static void on_checksum(terrad_client *c, const uint8_t *buf, size_t len, uint64_t *tick)
{
    size_t cap =
        len >= TERRAD_CHECKSUM_FIXED ? (len - TERRAD_CHECKSUM_FIXED) / TERRAD_TILE_SUM_SIZE + 1 : 1;
    terrad_tile_sum *sums = malloc(cap * sizeof *sums);
    uint32_t sid;
    size_t n = 0;
    int rc =
        sums ? terrad_checksum_decode(buf, len, tick, &sid, sums, cap, &n) : TERRAD_E_NO_MEMORY;
    if (rc) {
        free(sums);
        return bad_frame(c, "CHECKSUM", rc);
    }
    c->stats.checksum_frames++;
    c->stats.checksum_tick = *tick;
    client_sub *s = find_sub(c, sid);
    char *text = s ? malloc(64 + n * 24) : NULL;
    size_t at = 0, asked = 0;
    for (size_t i = 0; text && i < n; i++) {
        if (terrad_mirror_tile_differs(&s->m, &sums[i]) != 1)
            continue;
        c->stats.tiles_differing++;
        if ((int)asked == (c->max_resync_tiles > 0 ? c->max_resync_tiles : 64))
            continue;
        int64_t t = (sums[i].tile_x - s->m.tx0) + (sums[i].tile_y - s->m.ty0) * s->m.tiles_x;
        s->m.versions[t] = 0; /* not held: its snapshot makes it equal again */
        at += (size_t)snprintf(text + at, 64 + n * 24 - at, "%s[%d,%d]",
                               asked ? "," : "{\"type\":\"resync\",\"tiles\":[", sums[i].tile_x,
                               sums[i].tile_y);
        asked++;
    }
    if (asked) {
        at += (size_t)snprintf(text + at, 64 + n * 24 - at, "],\"id\":%u}", sid);
        set_warn(c,
                 "subscription %u: %zu tile(s) differ from the server's at tick %llu, asking "
                 "for them again",
                 sid, asked, (unsigned long long)*tick);
        if (enqueue(c, text, at, 0) == 0)
            c->stats.tiles_resynced += asked;
    }
    free(text);
    free(sums);
}

static void on_binary(terrad_client *c, const uint8_t *buf, size_t len)
{
    terrad_header hd;
    int rc = terrad_header_decode(buf, len, &hd);
    if (rc)
        return bad_frame(c, "binary", rc);
    uint64_t tick = 0;
    switch (hd.type) {
    case TERRAD_MSG_DELTA:
        on_delta(c, buf, len, &tick);
        break;
    case TERRAD_MSG_CONTACT: {
        size_t cap =
            len >= TERRAD_CONTACT_FIXED ? (len - TERRAD_CONTACT_FIXED) / TERRAD_CONTACT_SIZE : 0;
        if (grow((void **)&c->contacts, &c->contacts_cap, cap + 1, sizeof *c->contacts))
            return bad_frame(c, "CONTACT (no memory)", TERRAD_E_NO_MEMORY);
        size_t n = 0;
        rc = terrad_contact_decode(buf, len, &tick, c->contacts, c->contacts_cap, &n);
        if (rc) {
            c->ncontacts = 0;
            return bad_frame(c, "CONTACT", rc);
        }
        c->ncontacts = n;
        c->contact_tick = tick;
        c->stats.contact_frames++;
        c->stats.contact_tick = tick;
        break;
    }
    case TERRAD_MSG_COLLIDERS: { /* a subscription made by terrad_client_subscribe_colliders */
        size_t cap = len >= TERRAD_COLLIDERS_FIXED
                         ? (len - TERRAD_COLLIDERS_FIXED) / TERRAD_COLLIDER_STATE_SIZE
                         : 0;
        if (grow((void **)&c->colliders, &c->colliders_cap, cap + 1, sizeof *c->colliders) ||
            grow((void **)&c->collider_lugs, &c->lugs_cap, cap + 1, sizeof *c->collider_lugs))
            return bad_frame(c, "COLLIDERS (no memory)", TERRAD_E_NO_MEMORY);
        size_t n = 0, nl = 0;
        rc = terrad_colliders_decode(buf, len, &tick, c->colliders, c->colliders_cap, &n);
        if (rc == 0)
            rc = terrad_colliders_grousers(buf, len, c->collider_lugs, c->lugs_cap, &nl);
        if (rc) {
            c->ncolliders = 0;
            return bad_frame(c, "COLLIDERS", rc);
        }
        if (nl == 0) /* a frame without the grousers extension: no entry has any */
            memset(c->collider_lugs, 0, n * sizeof *c->collider_lugs);
        c->ncolliders = n;
        c->colliders_tick = tick;
        break;
    }
    case TERRAD_MSG_FORCES: {
        size_t cap =
            len >= TERRAD_FORCES_FIXED ? (len - TERRAD_FORCES_FIXED) / TERRAD_FORCE_SIZE : 0;
        if (grow((void **)&c->forces, &c->forces_cap, cap + 1, sizeof *c->forces) ||
            grow((void **)&c->force_heights, &c->force_heights_cap, cap + 1,
                 sizeof *c->force_heights))
            return bad_frame(c, "FORCES (no memory)", TERRAD_E_NO_MEMORY);
        size_t n = 0, nh = 0;
        rc = terrad_forces_decode(buf, len, &tick, c->forces, cap + 1, &n);
        if (rc == 0)
            rc = terrad_forces_heights(buf, len, c->force_heights, cap + 1, &nh);
        if (rc) {
            c->nforces = c->nforce_heights = 0;
            return bad_frame(c, "FORCES", rc);
        }
        c->nforces = n;
        c->nforce_heights = nh;
        c->forces_tick = tick;
        c->stats.forces_frames++;
        break;
    }
    case TERRAD_MSG_ACK: {
        uint32_t seq;
        rc = terrad_ack_decode(buf, len, &tick, &seq);
        if (rc)
            return bad_frame(c, "ACK", rc);
        c->stats.acks++;
        c->stats.ack_tick = tick;
        c->stats.ack_seq = seq;
        predict_acked(c, tick, seq);
        break;
    }
    case TERRAD_MSG_CHECKSUM:
        on_checksum(c, buf, len, &tick);
        break;
    case TERRAD_MSG_STEPPED: {
        uint32_t seq, ticks;
        rc = terrad_stepped_decode(buf, len, &tick, &seq, &ticks);
        if (rc)
            return bad_frame(c, "STEPPED", rc);
        step_answered(c, seq, 0, tick);
        break;
    }
    case TERRAD_MSG_PING:
    case TERRAD_MSG_PONG: {
        uint8_t type;
        uint64_t nonce;
        rc = terrad_ping_decode(buf, len, &type, &nonce);
        if (rc)
            return bad_frame(c, "PING", rc);
        if (type == TERRAD_MSG_PING) {
            uint8_t out[TERRAD_PING_SIZE];
            size_t n;
            if (terrad_ping_encode(out, sizeof out, &n, TERRAD_MSG_PONG, nonce) == 0)
                enqueue(c, out, n, 1);
        }
        break;
    }
    default:
        return bad_frame(c, "binary (a type clients do not accept)", TERRAD_E_UNKNOWN_TYPE);
    }
    if (c->hook)
        c->hook(c->user, c, hd.type, tick);
    if (tick > c->handled_tick)
        c->handled_tick = tick;
    say_seen(c);
}

static void on_receive(terrad_client *c, struct lws *wsi, const void *in, size_t len)
{
    if (!c->rx_in_msg) {
        c->rx_in_msg = 1;
        c->rx_len = 0;
        c->rx_overflow = 0;
        c->rx_binary = lws_frame_is_binary(wsi);
    }
    if (!c->rx_overflow) {
        if (c->rx_len + len > CLIENT_MAX_MESSAGE ||
            grow((void **)&c->rx, &c->rx_cap, c->rx_len + len + 1, 1))
            c->rx_overflow = 1;
        else {
            memcpy(c->rx + c->rx_len, in, len);
            c->rx_len += len;
        }
    }
    if (!lws_is_final_fragment(wsi))
        return;
    c->rx_in_msg = 0;
    c->stats.messages++;
    if (c->rx_overflow) {
        bad_frame(c, "oversized", TERRAD_E_TOO_LARGE);
        return;
    }
    if (c->rx_binary)
        on_binary(c, c->rx, c->rx_len);
    else
        on_text(c, (const char *)c->rx, c->rx_len);
}

static int callback(struct lws *wsi, enum lws_callback_reasons reason, void *user, void *in,
                    size_t len)
{
    (void)user;
    struct lws_context *ctx = lws_get_context(wsi);
    terrad_client *c = ctx ? lws_context_user(ctx) : NULL;
    if (!c)
        return 0;
    switch (reason) {
    case LWS_CALLBACK_CLIENT_CONNECTION_ERROR:
        set_err(c, "cannot connect: %s", in ? (const char *)in : "connection error");
        c->closed = 1;
        c->wsi = NULL;
        break;
    case LWS_CALLBACK_CLIENT_ESTABLISHED:
        c->established = 1;
        if (c->out_head)
            lws_callback_on_writable(wsi);
        break;
    case LWS_CALLBACK_CLIENT_RECEIVE:
        on_receive(c, wsi, in, len);
        break;
    case LWS_CALLBACK_CLIENT_WRITEABLE: {
        if (c->closing) {
            lws_close_reason(wsi, LWS_CLOSE_STATUS_NORMAL, NULL, 0);
            return -1;
        }
        out_msg *m = c->out_head;
        if (!m)
            break;
        int n =
            lws_write(wsi, m->buf + LWS_PRE, m->len, m->binary ? LWS_WRITE_BINARY : LWS_WRITE_TEXT);
        if (n < (int)m->len) {
            set_err(c, "write failed");
            return -1;
        }
        c->out_head = m->next;
        if (!c->out_head)
            c->out_tail = NULL;
        free(m);
        if (c->out_head)
            lws_callback_on_writable(wsi);
        break;
    }
    case LWS_CALLBACK_WS_PEER_INITIATED_CLOSE:
        if (in && len >= 2) {
            const unsigned char *p = in;
            c->stats.close_code = (p[0] << 8) | p[1];
            if (len > 2)
                set_warn(c, "closed by the server (%d): %.*s", c->stats.close_code, (int)(len - 2),
                         (const char *)p + 2);
        }
        break;
    case LWS_CALLBACK_CLIENT_CLOSED:
        c->closed = 1;
        c->wsi = NULL;
        break;
    case LWS_CALLBACK_WSI_DESTROY:
        if (wsi == c->wsi) {
            c->closed = 1;
            c->wsi = NULL;
        }
        break;
    case LWS_CALLBACK_TIMER:
        break; /* only wakes lws_service */
    default:
        break;
    }
    return 0;
}

static const struct lws_protocols protocols[] = {
    {TERRAD_PROTO_SUBPROTOCOL, callback, 0, CLIENT_RX_CHUNK, 0, NULL, 0},
    {NULL, NULL, 0, 0, 0, NULL, 0},
};

/* Service until done(c), the connection closes or the deadline passes. */
static void service_until(terrad_client *c, int64_t deadline, int (*done)(const terrad_client *))
{
    while (!done(c) && !c->closed) {
        int64_t left = deadline - now_us();
        if (left <= 0)
            break;
        if (c->wsi)
            lws_set_timer_usecs(c->wsi, left);
        lws_service(c->ctx, 0);
    }
    if (c->wsi)
        lws_set_timer_usecs(c->wsi, LWS_SET_TIMER_USEC_CANCEL);
}

static int waited(const terrad_client *c)
{
    return c->wait_done;
}

static int world_or_error(const terrad_client *c)
{
    return c->got_world || c->wait_done;
}

static int never(const terrad_client *c)
{
    (void)c;
    return 0;
}

/* ---- public -------------------------------------------------------------- */

static terrad_client *connect_to(terrad_client_desc d, const char *world, int base, char *err,
                                 size_t err_cap)
{
    if (err && err_cap)
        err[0] = 0;
    if (world && strlen(world) > 64) { /* refused before connecting */
        if (err && err_cap)
            snprintf(err, err_cap, "world: a name of %zu bytes (at most 64)", strlen(world));
        return NULL;
    }
    terrad_client *c = calloc(1, sizeof *c);
    if (!c) {
        if (err && err_cap)
            snprintf(err, err_cap, "out of memory");
        return NULL;
    }
    c->timeout_ms = d.timeout_ms > 0 ? d.timeout_ms : 5000;
    c->base_asked = base;
    c->hook = d.hook;
    c->user = d.user;
    c->log = d.log;
    c->log_level = d.log_level > 0 ? d.log_level : TERRAD_LOG_INFO;
    c->codec = terrad_codec_new(0);
    /* libwebsockets prints a banner and notices to stderr by default: not in the host's
     * stderr unless the host asks for them. */
    if (d.lws_log_levels != TERRAD_CLIENT_LWS_LOG_KEEP)
        lws_set_log_level(d.lws_log_levels, NULL);

    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = CONTEXT_PORT_NO_LISTEN;
    info.protocols = protocols;
    info.gid = -1;
    info.uid = -1;
    info.user = c;
    if (d.tls) {
        info.options |= LWS_SERVER_OPTION_DO_SSL_GLOBAL_INIT;
        info.client_ssl_ca_filepath = d.tls_ca_file; /* NULL: OpenSSL's default CA paths */
    }
    c->ctx = lws_create_context(&info);
    if (!c->ctx || !c->codec) {
        set_err(c, "cannot create the libwebsockets context");
        goto fail;
    }

    const char *host = d.host ? d.host : "127.0.0.1";
    struct lws_client_connect_info ci;
    memset(&ci, 0, sizeof ci);
    ci.context = c->ctx;
    ci.address = host;
    ci.port = d.port > 0 ? d.port : 8081;
    ci.path = "/";
    ci.host = host;
    ci.origin = host;
    ci.protocol = TERRAD_PROTO_SUBPROTOCOL;
    ci.local_protocol_name = TERRAD_PROTO_SUBPROTOCOL;
    ci.pwsi = &c->wsi;
    ci.ssl_connection = d.tls ? LCCSCF_USE_SSL : 0;
    if (!lws_client_connect_via_info(&ci)) {
        if (!c->err[0])
            set_err(c, "cannot connect to %s:%d", host, ci.port);
        goto fail;
    }

    /* hello, queued until the upgrade completes */
    cJSON *h = cJSON_CreateObject();
    cJSON_AddStringToObject(h, "type", "hello");
    cJSON_AddNumberToObject(h, "protocol", TERRAD_PROTO_VERSION);
    cJSON_AddStringToObject(h, "token", d.token ? d.token : "");
    cJSON_AddStringToObject(h, "client", d.name ? d.name : "terrad-c");
    if (world && world[0])
        cJSON_AddStringToObject(h, "world", world);
    if (c->base_asked)
        cJSON_AddBoolToObject(h, "snapshot_base", 1);
    if (c->base_asked == 2) /* the mirror decodes encoding 3 (terrad_rect_decompress_slope) */
        cJSON_AddBoolToObject(h, "snapshot_slope", 1);
    if (d.budget) /* -1: none (0 on the wire); 0: the server's default (not sent) */
        cJSON_AddNumberToObject(h, "budget", d.budget < 0 ? 0 : (double)d.budget);
    char *text = cJSON_PrintUnformatted(h);
    cJSON_Delete(h);
    int rc = text ? enqueue(c, text, strlen(text), 0) : TERRAD_E_NO_MEMORY;
    free(text);
    if (rc) {
        if (!c->err[0])
            set_err(c, "cannot send hello (%d)", rc);
        goto fail;
    }
    service_until(c, now_us() + (int64_t)c->timeout_ms * 1000, world_or_error);
    if (!c->got_world) {
        if (!c->err[0]) {
            if (c->closed)
                set_err(c, "the server closed the connection during the handshake");
            else
                set_err(c, "no world message within %d ms", c->timeout_ms);
        }
        goto fail;
    }
    c->wait_done = 0;
    char line[160];
    snprintf(line, sizeof line, "connected to %s:%d: world %dx%d cells, tick %llu", host, ci.port,
             c->world.width, c->world.height, (unsigned long long)c->world.tick);
    log_line(c, TERRAD_LOG_INFO, line);
    return c;

fail:
    if (err && err_cap)
        snprintf(err, err_cap, "%s", c->err[0] ? c->err : "cannot connect");
    c->closed = 1;
    terrad_client_close(c);
    return NULL;
}

terrad_client *terrad_client_connect(terrad_client_desc d, char *err, size_t err_cap)
{
    return connect_to(d, NULL, 0, err, err_cap);
}

terrad_client *terrad_client_connect_world(terrad_client_desc d, const char *world, char *err,
                                           size_t err_cap)
{
    return connect_to(d, world, 0, err, err_cap);
}

terrad_client *terrad_client_connect_base(terrad_client_desc d, const char *world, char *err,
                                          size_t err_cap)
{
    return connect_to(d, world, 1, err, err_cap);
}

int terrad_client_base_snapshots(const terrad_client *c)
{
    return c->base_on;
}

terrad_client *terrad_client_connect_slope(terrad_client_desc d, const char *world, char *err,
                                           size_t err_cap)
{
    return connect_to(d, world, 2, err, err_cap);
}

int terrad_client_slope_snapshots(const terrad_client *c)
{
    return c->slope_on;
}

const char *terrad_client_world_name(const terrad_client *c)
{
    return c->world_name;
}

void terrad_client_close(terrad_client *c)
{
    if (!c)
        return;
    if (c->ctx && c->wsi && !c->closed && c->established) {
        c->closing = 1;
        lws_callback_on_writable(c->wsi);
        service_until(c, now_us() + 1000000, never); /* until closed, 1 s at most */
        log_line(c, TERRAD_LOG_INFO, "closed");
    }
    if (c->ctx)
        lws_context_destroy(c->ctx);
    predict_free_all(c);
    free(c->own);
    free_queue(c);
    for (size_t i = 0; i < c->nsubs; i++) {
        free(c->subs[i].heights);
        free(c->subs[i].versions);
        free(c->subs[i].base);
    }
    free(c->subs);
    cJSON_Delete(c->base);
    free(c->contacts);
    free(c->forces);
    free(c->force_heights);
    free(c->colliders);
    free(c->collider_lugs);
    free(c->rects);
    free(c->scratch);
    free(c->rx);
    terrad_codec_free(c->codec);
    free(c);
}

const terrad_world_info *terrad_client_world(const terrad_client *c)
{
    return &c->world;
}

const terrad_client_stats *terrad_client_get_stats(const terrad_client *c)
{
    return &c->stats;
}

const char *terrad_client_last_error(const terrad_client *c)
{
    return c->err;
}

int terrad_client_is_open(const terrad_client *c)
{
    return c && !c->closed && c->wsi != NULL;
}

/* Send a JSON request with a fresh ref; wait for its reply or error. */
static int request(terrad_client *c, cJSON *msg, int64_t *id_out)
{
    snprintf(c->wait_ref, sizeof c->wait_ref, "c%u", ++c->ref_counter);
    cJSON_AddStringToObject(msg, "ref", c->wait_ref);
    char *text = cJSON_PrintUnformatted(msg);
    cJSON_Delete(msg);
    if (!text)
        return TERRAD_E_NO_MEMORY;
    c->wait_done = 0;
    c->wait_code = 0;
    c->wait_id = 0;
    int rc = enqueue(c, text, strlen(text), 0);
    free(text);
    if (rc) {
        c->wait_ref[0] = 0;
        return rc;
    }
    service_until(c, now_us() + (int64_t)c->timeout_ms * 1000, waited);
    c->wait_ref[0] = 0;
    if (!c->wait_done) {
        if (c->closed)
            return TERRAD_CLIENT_E_CLOSED;
        set_err(c, "no reply within %d ms", c->timeout_ms);
        return TERRAD_CLIENT_E_TIMEOUT;
    }
    c->wait_done = 0;
    if (c->wait_code == 0 && id_out)
        *id_out = c->wait_id;
    return c->wait_code;
}

static int finite_positive(double v)
{
    return isfinite(v) && v > 0;
}

/* The colliders this client made, for its predictions (terrad_client_predict.c). */
static void remember_own(terrad_client *c, uint32_t id, const terrad_collider_desc *d,
                         const terrad_grousers *lugs, double load_n)
{
    if (grow((void **)&c->own, &c->own_cap, c->nown + 1, sizeof *c->own))
        return; /* out of memory: a prediction will not know this collider */
    client_own *o = &c->own[c->nown++];
    *o = (client_own){.id = id,
                      .shape = d->shape,
                      .radius = d->radius,
                      .half_length = d->half_length,
                      .width = d->width,
                      .default_material = !d->material || strcmp(d->material, "default") == 0,
                      .lugs = lugs ? *lugs : (terrad_grousers){0},
                      .load_n = load_n};
    memcpy(o->half_extents, d->half_extents, sizeof o->half_extents);
    predict_collider(c, o, 1);
}

const client_own *client_own_colliders(const terrad_client *c, size_t *n)
{
    *n = c->nown;
    return c->own;
}

terrad_prediction **client_predictions(terrad_client *c)
{
    return &c->predictions;
}

void client_set_error(terrad_client *c, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    set_err_at(c, TERRAD_LOG_ERROR, fmt, ap);
    va_end(ap);
}

/* load_n 0: the poses' heights (terrad_client_create_collider); lugs NULL: a smooth rim */
static int create_collider(terrad_client *c, terrad_collider_desc d, double load_n,
                           const terrad_grousers *lugs, uint32_t *id_out)
{
    cJSON *m = cJSON_CreateObject();
    if (!m)
        return TERRAD_E_NO_MEMORY;
    cJSON_AddStringToObject(m, "type", "collider_create");
    int ok = 1;
    switch (d.shape) {
    case TERRAD_SHAPE_SPHERE:
        cJSON_AddStringToObject(m, "shape", "sphere");
        cJSON_AddNumberToObject(m, "radius", d.radius);
        ok = finite_positive(d.radius);
        break;
    case TERRAD_SHAPE_BOX: {
        cJSON_AddStringToObject(m, "shape", "box");
        cJSON *a = cJSON_AddArrayToObject(m, "half_extents");
        for (int i = 0; i < 3; i++) {
            cJSON_AddItemToArray(a, cJSON_CreateNumber(d.half_extents[i]));
            ok = ok && finite_positive(d.half_extents[i]);
        }
        break;
    }
    case TERRAD_SHAPE_CAPSULE:
    case TERRAD_SHAPE_CYLINDER:
        cJSON_AddStringToObject(m, "shape",
                                d.shape == TERRAD_SHAPE_CAPSULE ? "capsule" : "cylinder");
        cJSON_AddNumberToObject(m, "radius", d.radius);
        cJSON_AddNumberToObject(m, "half_length", d.half_length);
        ok = finite_positive(d.radius) && finite_positive(d.half_length);
        break;
    case TERRAD_SHAPE_WHEEL:
        cJSON_AddStringToObject(m, "shape", "wheel");
        cJSON_AddNumberToObject(m, "radius", d.radius);
        cJSON_AddNumberToObject(m, "width", d.width);
        ok = finite_positive(d.radius) && finite_positive(d.width);
        break;
    default:
        ok = 0;
    }
    if (!ok) {
        cJSON_Delete(m);
        set_err(c, "collider_create: unknown shape or a size that is not finite and > 0");
        return TERRAD_E_BAD_VALUE;
    }
    cJSON_AddStringToObject(m, "material", d.material ? d.material : "default");
    cJSON_AddBoolToObject(m, "feedback", !d.no_feedback);
    if (load_n != 0.0) { /* the server judges it (and names load_n when it refuses) */
        cJSON_AddNumberToObject(m, "load_n", load_n);
        /* its height is the server's: FORCES tells it (terrad_client_force_height) */
        cJSON_AddBoolToObject(m, "forces_height", 1);
    }
    if (lugs) { /* the server judges the sizes against the rim and names the field */
        cJSON *g = cJSON_AddObjectToObject(m, "grousers");
        cJSON_AddNumberToObject(g, "count", lugs->count);
        cJSON_AddNumberToObject(g, "height", lugs->height);
        cJSON_AddNumberToObject(g, "thickness", lugs->thickness);
    }
    int64_t id = 0;
    int rc = request(c, m, &id);
    if (rc == 0) {
        if (id < 1 || id > UINT32_MAX)
            return TERRAD_CLIENT_E_PROTOCOL;
        if (id_out)
            *id_out = (uint32_t)id;
        remember_own(c, (uint32_t)id, &d, lugs, load_n);
    }
    return rc;
}

int terrad_client_create_collider(terrad_client *c, terrad_collider_desc d, uint32_t *id_out)
{
    return create_collider(c, d, 0.0, NULL, id_out);
}

int terrad_client_create_loaded_collider(terrad_client *c, terrad_collider_desc d, double load_n,
                                         uint32_t *id_out)
{
    return create_collider(c, d, load_n, NULL, id_out);
}

int terrad_client_create_lugged_collider(terrad_client *c, terrad_collider_desc d,
                                         terrad_grousers g, double load_n, uint32_t *id_out)
{
    return create_collider(c, d, load_n, &g, id_out);
}

int terrad_client_delete_collider(terrad_client *c, uint32_t id)
{
    cJSON *m = cJSON_CreateObject();
    if (!m)
        return TERRAD_E_NO_MEMORY;
    cJSON_AddStringToObject(m, "type", "collider_delete");
    cJSON_AddNumberToObject(m, "id", id);
    int rc = request(c, m, NULL);
    for (size_t i = 0; rc == 0 && i < c->nown; i++)
        if (c->own[i].id == id) {
            predict_collider(c, &c->own[i], 0);
            memmove(&c->own[i], &c->own[i + 1], (c->nown - i - 1) * sizeof *c->own);
            c->nown--;
            break;
        }
    return rc;
}

int terrad_client_send_poses(terrad_client *c, const terrad_pose *poses, size_t count,
                             uint32_t *seq_out)
{
    size_t cap = terrad_pose_batch_size(count);
    uint8_t stackbuf[TERRAD_POSE_BATCH_FIXED + 16 * TERRAD_POSE_SIZE];
    uint8_t *buf = cap <= sizeof stackbuf ? stackbuf : malloc(cap);
    if (!buf)
        return TERRAD_E_NO_MEMORY;
    size_t len = 0;
    uint32_t seq = c->seq + 1;
    int rc = terrad_pose_batch_encode(buf, cap, &len, seq, poses, count);
    rc = enqueue_encoded(c, rc, buf, len, stackbuf); /* len: set by the encoder first */
    if (rc) {
        if (rc > 0)
            set_err(c, "pose batch refused locally: %s", terrad_err_name(rc));
        return rc;
    }
    c->seq = seq;
    if (seq_out)
        *seq_out = seq;
    predict_sent(c, seq, poses, count); /* queued, not sent: the rut before the bytes leave */
    flush(c);
    return 0;
}

/* colliders: 0 none, 1 COLLIDERS frames, 2 with their grousers (the extension) */
static int subscribe(terrad_client *c, int32_t x, int32_t y, uint32_t w, uint32_t h, int colliders,
                     uint32_t *sid_out)
{
    cJSON *m = cJSON_CreateObject();
    if (!m)
        return TERRAD_E_NO_MEMORY;
    cJSON_AddStringToObject(m, "type", "subscribe");
    cJSON_AddNumberToObject(m, "x", x);
    cJSON_AddNumberToObject(m, "y", y);
    cJSON_AddNumberToObject(m, "w", w);
    cJSON_AddNumberToObject(m, "h", h);
    if (colliders)
        cJSON_AddTrueToObject(m, "colliders");
    if (colliders > 1)
        cJSON_AddTrueToObject(m, "grousers");
    int64_t id = 0;
    int rc = request(c, m, &id);
    if (rc == 0 && sid_out)
        *sid_out = (uint32_t)id;
    return rc;
}

int terrad_client_subscribe(terrad_client *c, int32_t x, int32_t y, uint32_t w, uint32_t h,
                            uint32_t *sid_out)
{
    return subscribe(c, x, y, w, h, 0, sid_out);
}

int terrad_client_subscribe_colliders(terrad_client *c, int32_t x, int32_t y, uint32_t w,
                                      uint32_t h, int grousers, uint32_t *sid_out)
{
    return subscribe(c, x, y, w, h, grousers ? 2 : 1, sid_out);
}

size_t terrad_client_colliders(const terrad_client *c, terrad_collider_state *states,
                               terrad_collider_grousers *grousers, size_t cap, uint64_t *tick_out)
{
    size_t n = c->ncolliders < cap ? c->ncolliders : cap;
    if (states && n)
        memcpy(states, c->colliders, n * sizeof *states);
    if (grousers && n)
        memcpy(grousers, c->collider_lugs, n * sizeof *grousers);
    if (tick_out)
        *tick_out = c->colliders_tick;
    return c->ncolliders;
}

int terrad_client_edit(terrad_client *c, const char *edit_json, uint64_t *tick_out,
                       int64_t *volume_out)
{
    cJSON *m = cJSON_Parse(edit_json);
    if (!cJSON_IsObject(m)) {
        cJSON_Delete(m);
        set_err(c, "edit: not a JSON object");
        return TERRAD_E_BAD_JSON;
    }
    cJSON_DeleteItemFromObjectCaseSensitive(m, "type");
    cJSON_DeleteItemFromObjectCaseSensitive(m, "ref");
    cJSON_AddStringToObject(m, "type", "edit");
    int rc = request(c, m, NULL);
    if (rc == 0 && tick_out)
        *tick_out = (uint64_t)c->wait_tick;
    if (rc == 0 && volume_out)
        *volume_out = c->wait_volume;
    return rc;
}

int terrad_client_crater(terrad_client *c, int32_t x, int32_t y, int32_t radius, int32_t depth,
                         int rim, uint64_t *tick_out, int64_t *volume_out)
{
    char text[200];
    snprintf(text, sizeof text,
             "{\"op\":\"crater\",\"x\":%d,\"y\":%d,\"radius\":%d,\"depth\":%d,\"rim\":%s}", x, y,
             radius, depth, rim ? "true" : "false");
    return terrad_client_edit(c, text, tick_out, volume_out);
}

int terrad_client_unsubscribe(terrad_client *c, uint32_t sid)
{
    cJSON *m = cJSON_CreateObject();
    if (!m)
        return TERRAD_E_NO_MEMORY;
    cJSON_AddStringToObject(m, "type", "unsubscribe");
    cJSON_AddNumberToObject(m, "id", sid);
    int rc = request(c, m, NULL);
    if (rc == 0) {
        client_sub *s = find_sub(c, sid);
        if (s) {
            free(s->heights);
            free(s->versions);
            free(s->base);
            *s = c->subs[--c->nsubs];
        }
    }
    return rc;
}

static int send_resync(terrad_client *c, uint32_t sid)
{
    char text[64];
    int n = sid ? snprintf(text, sizeof text, "{\"type\":\"resync\",\"id\":%u}", sid)
                : snprintf(text, sizeof text, "{\"type\":\"resync\"}");
    return enqueue(c, text, (size_t)n, 0);
}

int terrad_client_focus(terrad_client *c, int set, double x, double y)
{
    char text[128];
    int n = set ? snprintf(text, sizeof text, "{\"type\":\"focus\",\"x\":%.17g,\"y\":%.17g}", x, y)
                : snprintf(text, sizeof text, "{\"type\":\"focus\"}");
    int rc = enqueue(c, text, (size_t)n, 0);
    flush(c);
    return rc;
}

int terrad_client_resync(terrad_client *c, uint32_t sid)
{
    int rc = send_resync(c, sid);
    flush(c);
    return rc;
}

int terrad_client_ping(terrad_client *c, uint64_t nonce)
{
    uint8_t out[TERRAD_PING_SIZE];
    size_t n;
    int rc = terrad_ping_encode(out, sizeof out, &n, TERRAD_MSG_PING, nonce);
    if (rc == 0)
        rc = enqueue(c, out, n, 1);
    flush(c);
    return rc;
}

const terrad_mirror *terrad_client_mirror(const terrad_client *c, uint32_t sid)
{
    client_sub *s = find_sub(c, sid);
    return s ? &s->m : NULL;
}

int terrad_client_mirror_complete(const terrad_client *c, uint32_t sid)
{
    client_sub *s = find_sub(c, sid);
    if (!s)
        return 0;
    size_t n = (size_t)s->m.tiles_x * s->m.tiles_y;
    for (size_t i = 0; i < n; i++)
        if (s->versions[i] == 0)
            return 0;
    return 1;
}

int terrad_client_contact(const terrad_client *c, uint32_t collider, terrad_contact *out,
                          uint64_t *tick_out)
{
    for (size_t i = 0; i < c->ncontacts; i++)
        if (c->contacts[i].id == collider) {
            if (out)
                *out = c->contacts[i];
            if (tick_out)
                *tick_out = c->contact_tick;
            return 1;
        }
    return 0;
}

int terrad_client_force_height(const terrad_client *c, uint32_t collider, double *z_m)
{
    for (size_t i = 0; i < c->nforce_heights; i++)
        if (c->forces[i].id == collider) {
            if (z_m)
                *z_m = c->force_heights[i];
            return 1;
        }
    return 0;
}

int terrad_client_force(const terrad_client *c, uint32_t collider, terrad_force *out,
                        uint64_t *tick_out)
{
    for (size_t i = 0; i < c->nforces; i++)
        if (c->forces[i].id == collider) {
            if (out)
                *out = c->forces[i];
            if (tick_out)
                *tick_out = c->forces_tick;
            return 1;
        }
    return 0;
}

static int got_message(const terrad_client *c)
{
    return c->stats.messages != c->poll_mark;
}

int terrad_client_poll(terrad_client *c, int timeout_ms)
{
    if (c->closed || !c->wsi)
        return TERRAD_CLIENT_E_CLOSED;
    uint64_t before = c->stats.messages;
    if (timeout_ms <= 0) {
        lws_service(c->ctx, -1);
    } else {
        c->poll_mark = before;
        service_until(c, now_us() + (int64_t)timeout_ms * 1000, got_message);
    }
    say_seen(c);
    uint64_t n = c->stats.messages - before;
    if (n == 0 && c->closed)
        return TERRAD_CLIENT_E_CLOSED;
    return n > 1000000 ? 1000000 : (int)n;
}

int terrad_client_fd(const terrad_client *c)
{
    if (c->closed || !c->wsi)
        return -1;
    return (int)lws_get_socket_fd(c->wsi);
}

/* ---- lockstep (client-clocked worlds) ------------------------------------- */

int terrad_client_world_client_clock(const terrad_client *c)
{
    return c->client_clock;
}

int terrad_client_step_send(terrad_client *c, const terrad_step *s, uint32_t *seq_out)
{
    terrad_step_head h = {
        .seq = c->step_seq + 1, .ticks = s->ticks, .count = s->count, .sets = s->sets};
    size_t cap = terrad_step_size(s->count, s->sets);
    uint8_t stackbuf[TERRAD_STEP_FIXED + 16 * TERRAD_POSE_SIZE];
    uint8_t *buf = cap <= sizeof stackbuf ? stackbuf : malloc(cap);
    if (!buf)
        return TERRAD_E_NO_MEMORY;
    size_t len = 0;
    int rc = terrad_step_encode(buf, cap, &len, &h, s->poses);
    rc = enqueue_encoded(c, rc, buf, len, stackbuf);
    if (rc) {
        if (rc > 0)
            set_err(c,
                    "step refused locally: %s (ticks %u, count %u, sets %u: sets must be 0, 1 "
                    "or ticks, every pose finite with a unit quaternion)",
                    terrad_err_name(rc), (unsigned)s->ticks, (unsigned)s->count, (unsigned)s->sets);
        return rc;
    }
    c->step_seq = h.seq;
    c->steps[h.seq % CLIENT_STEP_RING].answered = 0;
    c->steps[h.seq % CLIENT_STEP_RING].seq = h.seq;
    if (seq_out)
        *seq_out = h.seq;
    flush(c);
    return 0;
}

static int step_done(const terrad_client *c, uint32_t seq)
{
    return c->steps[seq % CLIENT_STEP_RING].seq == seq && c->steps[seq % CLIENT_STEP_RING].answered;
}

static int waited_step(const terrad_client *c)
{
    return step_done(c, c->step_waiting);
}

/* The answer of a step that was answered (0 with its tick, or its error). */
static int step_result(terrad_client *c, uint32_t seq, uint64_t *tick_out)
{
    size_t i = seq % CLIENT_STEP_RING;
    if (tick_out)
        *tick_out = c->steps[i].tick;
    return c->steps[i].code;
}

static int step_unanswered(terrad_client *c, uint32_t seq)
{
    if (c->closed)
        return TERRAD_CLIENT_E_CLOSED;
    set_err(c, "step %u: no STEPPED within %d ms", seq, c->timeout_ms);
    return TERRAD_CLIENT_E_TIMEOUT;
}

int terrad_client_step_wait(terrad_client *c, uint32_t seq, uint64_t *tick_out)
{
    c->step_waiting = seq;
    if (!step_done(c, seq))
        service_until(c, now_us() + (int64_t)c->timeout_ms * 1000, waited_step);
    return step_done(c, seq) ? step_result(c, seq, tick_out) : step_unanswered(c, seq);
}

int terrad_client_step(terrad_client *c, const terrad_step *s, uint64_t *tick_out)
{
    uint32_t seq;
    int rc = terrad_client_step_send(c, s, &seq);
    return rc ? rc : terrad_client_step_wait(c, seq, tick_out);
}

int terrad_client_step_many(terrad_client *const *clients, const terrad_step *steps, size_t k,
                            uint64_t *ticks_out, int *rcs_out)
{
    uint32_t stackseq[64];
    struct pollfd stackfds[64];
    uint32_t *seqs = k <= 64 ? stackseq : malloc(k * sizeof *seqs);
    struct pollfd *fds = k <= 64 ? stackfds : malloc(k * sizeof *fds);
    if (!seqs || !fds) {
        if (seqs != stackseq)
            free(seqs);
        if (fds != stackfds)
            free(fds); /* k > 64: either malloc may have failed alone */
        return TERRAD_E_NO_MEMORY;
    }
    int first = 0, timeout_ms = 0;
    size_t open = 0;
    for (size_t i = 0; i < k; i++) { /* all sent first: the worlds tick at once */
        int rc = terrad_client_step_send(clients[i], &steps[i], &seqs[i]);
        if (rc) {
            seqs[i] = 0;
            if (rcs_out)
                rcs_out[i] = rc;
            first = first ? first : rc;
        } else {
            open++;
        }
        timeout_ms = clients[i]->timeout_ms > timeout_ms ? clients[i]->timeout_ms : timeout_ms;
    }
    int64_t deadline = now_us() + (int64_t)timeout_ms * 1000;
    while (open > 0 && now_us() < deadline) {
        nfds_t n = 0;
        open = 0;
        for (size_t i = 0; i < k; i++) {
            terrad_client *c = clients[i];
            if (!seqs[i] || c->closed)
                continue;
            lws_service(c->ctx, -1); /* what arrived, without waiting */
            if (step_done(c, seqs[i]) || c->closed)
                continue;
            open++;
            fds[n++] = (struct pollfd){.fd = terrad_client_fd(c), .events = POLLIN};
        }
        if (open > 0)
            poll(fds, n, 1);
    }
    for (size_t i = 0; i < k; i++) {
        if (!seqs[i])
            continue;
        terrad_client *c = clients[i];
        uint64_t tick = 0;
        int rc =
            step_done(c, seqs[i]) ? step_result(c, seqs[i], &tick) : step_unanswered(c, seqs[i]);
        if (ticks_out)
            ticks_out[i] = tick;
        if (rcs_out)
            rcs_out[i] = rc;
        first = first ? first : rc;
    }
    if (seqs != stackseq)
        free(seqs);
    if (fds != stackfds)
        free(fds);
    return first;
}
