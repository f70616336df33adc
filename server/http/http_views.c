/*
 * http_views.c: the answers of /v1/world, /v1/stats and /v1/heights, built as
 * an http_answer (status, type, headers, body) rather than straight into a
 * libmicrohttpd response, so that one code path serves a request on this
 * node's port and one that came from another node over NATS (docs/cluster.md,
 * "any node serves any world": a relay hands the request of a world it does
 * not tick to its owner, which answers with the bytes its own port would
 * send). Nothing here runs on the sim thread: the views read the status
 * snapshot, heights come through the hub between two ticks.
 *
 * Bytes between nodes: a request is "TRQ1\0" path "\0" then key "\0" value
 * "\0" per query argument (already unescaped: a value holds no NUL); an
 * answer is "TAN1", the status (4 bytes, little-endian), type "\0",
 * header lines "\0", then the body.
 */
#include "http/http_internal.h"

#include <limits.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "sim/sim.h"
#include "store/store.h"
#include "terrad_version.h"
#include "world/world.h"

/* ---- answers ---- */

void http_json_escape(const char *s, char *out, size_t cap)
{
    size_t o = 0;
    for (; *s && o + 7 < cap; s++) {
        unsigned char ch = (unsigned char)*s;
        if (ch == '"' || ch == '\\') {
            out[o++] = '\\';
            out[o++] = (char)ch;
        } else if (ch < 0x20) {
            o += (size_t)snprintf(out + o, cap - o, "\\u%04x", ch);
        } else {
            out[o++] = (char)ch;
        }
    }
    out[o] = '\0';
}

void http_answer_free(http_answer *a)
{
    free(a->body);
    a->body = NULL;
    a->len = 0;
}

/* A text body (copied); out of memory leaves code 0, which queues as MHD_NO. */
static void answer_text(http_answer *a, unsigned code, const char *type, const char *body)
{
    http_answer_free(a);
    size_t n = strlen(body);
    a->body = malloc(n + 1);
    a->code = a->body ? code : 0;
    snprintf(a->type, sizeof a->type, "%s", type);
    a->extra[0] = '\0';
    if (a->body) {
        memcpy(a->body, body, n + 1);
        a->len = n;
    }
}

void http_answer_error(http_answer *a, unsigned code, const char *fmt, ...)
{
    char message[512], escaped[1100], body[1200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(message, sizeof message, fmt, ap);
    va_end(ap);
    http_json_escape(message, escaped, sizeof escaped);
    snprintf(body, sizeof body, "{\"error\":\"%s\"}\n", escaped);
    answer_text(a, code, "application/json", body);
    if (code == MHD_HTTP_BAD_REQUEST)
        metrics_count_http_bad_request();
}

static void add_header(http_answer *a, const char *name, const char *value)
{
    size_t n = strlen(a->extra);
    snprintf(a->extra + n, sizeof a->extra - n, "%s: %s\n", name, value);
}

enum MHD_Result http_answer_queue(struct MHD_Connection *c, http_answer *a)
{
    if (!a->code) {
        http_answer_free(a);
        return MHD_NO;
    }
    struct MHD_Response *r =
        MHD_create_response_from_buffer(a->len, a->body, MHD_RESPMEM_MUST_FREE);
    if (!r) {
        http_answer_free(a);
        return MHD_NO;
    }
    a->body = NULL; /* the response owns it now */
    MHD_add_response_header(r, "Content-Type", a->type);
    MHD_add_response_header(r, "Cache-Control", "no-store");
    for (char *line = a->extra; *line;) {
        char *end = strchr(line, '\n'), *colon = strstr(line, ": ");
        if (!end || !colon || colon > end)
            break;
        *end = *colon = '\0';
        MHD_add_response_header(r, line, colon + 2);
        line = end + 1;
    }
    return http_queue(c, a->code, r);
}

/* ---- query arguments: of this request, or of one another node sent ---- */

static const char *arg(const http_args *a, const char *name)
{
    if (a->c)
        return MHD_lookup_connection_value(a->c, MHD_GET_ARGUMENT_KIND, name);
    for (const char *p = a->packed, *end = a->packed + a->len; p < end;) {
        const char *value = p + strlen(p) + 1;
        if (value >= end)
            return NULL;
        if (strcmp(p, name) == 0)
            return value;
        p = value + strlen(value) + 1;
    }
    return NULL;
}

/* A query parameter as an int: 0, or -1 (missing) / -2 (not an integer). */
static int arg_int(const http_args *a, const char *name, int *out)
{
    const char *v = arg(a, name);
    if (!v || !*v)
        return -1;
    const char *p = v;
    int negative = 0;
    if (*p == '-') {
        negative = 1;
        p++;
    }
    if (!*p)
        return -2;
    long long x = 0;
    for (; *p; p++) {
        if (*p < '0' || *p > '9')
            return -2;
        x = x * 10 + (*p - '0');
        if (x > INT_MAX)
            return -2;
    }
    *out = (int)(negative ? -x : x);
    return 0;
}

/* Query parameter `name`: 0 when absent or "0", 1 when "1", -1 otherwise. */
static int arg_is_one(const http_args *a, const char *name)
{
    const char *v = arg(a, name);
    if (!v || strcmp(v, "0") == 0)
        return 0;
    return strcmp(v, "1") == 0 ? 1 : -1;
}

/* ---- the views ---- */

void http_view_stats(const http_status *st, http_answer *a)
{
    char body[512];
    snprintf(body, sizeof body,
             "{\"tick\":%llu,\"volume\":%lld,\"compacted\":%lld,\"soil_compacted\":%lld,"
             "\"clients\":%d,\"colliders\":%d,\"last_tick_ms\":%.3f,\"overruns\":%llu,"
             "\"ready\":%s}\n",
             (unsigned long long)st->tick, (long long)st->volume, (long long)st->compacted,
             (long long)st->soil_compacted, st->clients, st->colliders, st->last_tick_ms,
             (unsigned long long)st->overruns, st->ready ? "true" : "false");
    answer_text(a, MHD_HTTP_OK, "application/json", body);
}

/* The shortest decimal that reads back as the same double ("0.05", not
 * "0.050000000000000003"), so JSON readers see what the scene said. */
static const char *json_double(double v, char *out, size_t cap)
{
    for (int digits = 15; digits <= 17; digits++) {
        snprintf(out, cap, "%.*g", digits, v);
        if (strtod(out, NULL) == v)
            break;
    }
    return out;
}

void http_view_world(const http_status *st, http_answer *a)
{
    char renderer[600], backend[40], method[40], metric[40], body[2400], name[160] = "";
    char reason[700];
    char width_m[32], height_m[32], cell[32], hz[32];
    if (st->world_name[0]) { /* cluster mode only: a single daemon's answer is unchanged */
        char escaped[132];
        http_json_escape(st->world_name, escaped, sizeof escaped);
        snprintf(name, sizeof name, ",\"world\":\"%s\"", escaped);
    }
    http_json_escape(st->renderer, renderer, sizeof renderer);
    http_json_escape(st->backend, backend, sizeof backend);
    http_json_escape(st->backend_reason, reason, sizeof reason);
    http_json_escape(st->method, method, sizeof method);
    http_json_escape(st->metric, metric, sizeof metric);
    /* width/height stay at the top level for existing clients; extent
     * repeats them with the size in metres. */
    snprintf(body, sizeof body,
             "{\"width\":%d,\"height\":%d,"
             "\"extent\":{\"width_cells\":%d,\"height_cells\":%d,\"width_m\":%s,"
             "\"height_m\":%s},"
             "\"cell_size_m\":%s,\"units_per_m\":%d,\"tick\":%llu,\"tick_hz\":%s,"
             "\"tile_size\":%d,\"models\":[%s%s%s],\"metric\":\"%s\","
             "\"renderer\":\"%s\",\"backend\":\"%s\",\"backend_reason\":\"%s\",\"ready\":%s,"
             "\"version\":\"%s\"%s}\n",
             st->world_width, st->world_height, st->world_width, st->world_height,
             json_double(st->world_width * st->cell_size_m, width_m, sizeof width_m),
             json_double(st->world_height * st->cell_size_m, height_m, sizeof height_m),
             json_double(st->cell_size_m, cell, sizeof cell), st->units_per_m,
             (unsigned long long)st->tick, json_double(st->tick_hz, hz, sizeof hz), st->tile_size,
             method[0] ? "\"" : "", method, method[0] ? "\"" : "", metric, renderer, backend,
             reason, st->ready ? "true" : "false", TERRAD_VERSION, name);
    answer_text(a, MHD_HTTP_OK, "application/json", body);
}

/* One rebuild at a time per process: each holds a world's worth of tiles
 * at most and replays up to a segment of log (more without keyframes), so a
 * second ?tick= request meanwhile is refused with 503 instead of multiplying
 * that (docs/storage.md "Replay"). */
static pthread_mutex_t replay_lock = PTHREAD_MUTEX_INITIALIZER;

/* ?tick=N's N: 0, or the status and why naming the parameter. The status's
 * tick is the world's: its host publishes it inside the tick before the
 * tick's frames go out and its height reads are served (publish_tick,
 * host/host_sim.c), so a tick a client was told of (X-Terrad-Tick, an ACK)
 * is never "in the future" here. */
static unsigned past_tick(const world *base_world, const http_status *st, const char *text,
                          uint64_t *tick, char *why, size_t cap)
{
    char *end = NULL;
    unsigned long long n = 0;
    if (text[0] >= '0' && text[0] <= '9')
        n = strtoull(text, &end, 10);
    if (!end || *end || end - text > 19) {
        snprintf(why, cap, "parameter tick must be a decimal integer (a past tick)");
        return MHD_HTTP_BAD_REQUEST;
    }
    if (!store_history_kept(&st->history)) {
        snprintf(why, cap, "parameter tick: this world keeps no log to replay (memory only)");
        return MHD_HTTP_NOT_FOUND;
    }
    if (n > st->tick) {
        snprintf(why, cap, "parameter tick: %llu is in the future (the world is at tick %llu)", n,
                 (unsigned long long)st->tick);
        return MHD_HTTP_BAD_REQUEST;
    }
    if (!base_world) {
        snprintf(why, cap, "the base terrain is not available");
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    }
    *tick = n;
    return 0;
}

/* A rebuild's cancel (store_cancel): the world's reads were closed, it is
 * leaving, and its removal waits for this request (hub_worlds_remove). */
static int world_leaving(void *h)
{
    return h && hub_reads_closed(h);
}

/* One rebuild of r as of tick on this worker, kept as a world (layer or
 * stats) or only its heights into dst (w NULL): 0, or the status and why.
 * It stops between two records once the world's reads are closed. */
static unsigned rebuild_past(const world *base_world, const http_status *st, hub *h, uint64_t n,
                             world_rect r, world *w, int32_t *dst, char *why, size_t cap)
{
    store_cancel leaving = {.cancelled = world_leaving, .ctx = h};
    error_text err = {{0}};
    /* refused, not queued: a queue of slow rebuilds would hold every HTTP
     * worker (four) and starve the live reads and the probes */
    if (pthread_mutex_trylock(&replay_lock) != 0) {
        snprintf(why, cap,
                 "parameter tick: another past-tick rebuild is running (one at a time "
                 "per daemon); retry");
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    }
    int rc = w ? store_history_world(&st->history, base_world, n, r, w, &leaving, &err)
               : store_history_rect(&st->history, base_world, n, r, dst, &leaving, &err);
    pthread_mutex_unlock(&replay_lock);
    if (rc == STORE_CANCELLED) {
        snprintf(why, cap,
                 "parameter tick: the rebuild of tick %llu stopped: the world is leaving this "
                 "server (deleted, or stopping)",
                 (unsigned long long)n);
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    }
    if (rc == 1) {
        snprintf(why, cap,
                 "parameter tick: tick %llu is no longer held (the log before a newer tile "
                 "snapshot was compacted away%s): %.300s",
                 (unsigned long long)n,
                 st->history.dir ? "; keep more with --replay-retain-bytes" : "", err.message);
        return MHD_HTTP_GONE;
    }
    if (rc != 0) {
        snprintf(why, cap, "parameter tick: rebuilding tick %llu failed: %.400s",
                 (unsigned long long)n, err.message);
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    }
    return 0;
}

/* ?tick=N: the rectangle (its heights, or with layer=compaction its
 * compaction memory) as of the end of tick N, rebuilt from the world's data
 * directory on this worker (store_replay_rect, store_replay_world), never
 * from the sim thread's world. 0, or the status and why naming the parameter. */
static unsigned read_past(const world *base_world, const http_status *st, hub *h,
                          const http_args *args, const char *text, world_rect r, int32_t *dst,
                          uint64_t *tick, char *why, size_t cap)
{
    const char *layer = arg(args, "layer");
    int compaction = layer && strcmp(layer, "compaction") == 0;
    if (arg(args, "base") || (layer && !compaction && strcmp(layer, "heights") != 0)) {
        snprintf(why, cap,
                 "parameter tick: a past tick serves heights or layer=compaction (no base=, "
                 "layer=heights|compaction)");
        return MHD_HTTP_BAD_REQUEST;
    }
    unsigned status = past_tick(base_world, st, text, tick, why, cap);
    if (status)
        return status;
    if (*tick == 0) { /* before the first tick: the base, remembering nothing */
        if (compaction)
            memset(dst, 0, (size_t)r.w * r.h * sizeof *dst);
        else
            world_base_fill_rect(base_world, r, dst);
        return 0;
    }
    if (!compaction)
        return rebuild_past(base_world, st, h, *tick, r, NULL, dst, why, cap);
    world w;
    status = rebuild_past(base_world, st, h, *tick, r, &w, NULL, why, cap);
    if (!status) {
        world_layer_gather(&w, WORLD_LAYER_COMPACTION, r, dst);
        world_free(&w);
    }
    return status;
}

/* GET /v1/stats?tick=N: what the store can rebuild of a past tick — the
 * world whole as of N (its Σh, its compaction memory and the bekker soil's
 * compaction summed as the live answer sums them); the live-only fields
 * (clients, colliders, tick time, overruns, ready) are left out. */
static void stats_past(const world *base_world, const http_status *st, hub *h, const char *text,
                       http_answer *a)
{
    char why[512], body[256];
    uint64_t n = 0;
    unsigned status = past_tick(base_world, st, text, &n, why, sizeof why);
    world w;
    world_rect all = {0, 0, st->world_width, st->world_height};
    if (!status)
        status = rebuild_past(base_world, st, h, n, all, &w, NULL, why, sizeof why);
    if (status)
        return http_answer_error(a, status, "%s", why);
    snprintf(body, sizeof body,
             "{\"tick\":%llu,\"volume\":%lld,\"compacted\":%lld,\"soil_compacted\":%lld,"
             "\"past\":true}\n",
             (unsigned long long)n, (long long)world_volume(&w), (long long)sim_world_compacted(&w),
             (long long)world_layer_sum(&w, WORLD_LAYER_SOIL, SIM_SOIL_COMPACTED));
    world_free(&w);
    answer_text(a, MHD_HTTP_OK, "application/json", body);
}

/* The rectangle's heights into dst: the live world through the hub (at the
 * end of *tick), or with base=1 the scene's base terrain (tick 0). 0, or the
 * HTTP status to answer with and why. */
static unsigned read_rect(http_server *s, hub *heights, const world *base_world,
                          const http_status *st, const http_args *args, world_rect r, int32_t *dst,
                          uint64_t *tick, char *why, size_t cap)
{
    const char *past = arg(args, "tick");
    if (past)
        return read_past(base_world, st, heights, args, past, r, dst, tick, why, cap);
    int base = arg_is_one(args, "base");
    if (base < 0) {
        snprintf(why, cap, "parameter base must be 0 or 1");
        return MHD_HTTP_BAD_REQUEST;
    }
    const char *layer_name = arg(args, "layer");
    hub_layer layer = HUB_LAYER_HEIGHTS;
    if (layer_name && strcmp(layer_name, "compaction") == 0)
        layer = HUB_LAYER_COMPACTION;
    else if (layer_name && strcmp(layer_name, "heights") != 0) {
        snprintf(why, cap, "parameter layer must be heights or compaction");
        return MHD_HTTP_BAD_REQUEST;
    }
    if (base && layer != HUB_LAYER_HEIGHTS) {
        snprintf(why, cap, "parameter layer: the base terrain has heights only (base=1)");
        return MHD_HTTP_BAD_REQUEST;
    }
    if (base) { /* immutable once the world is made: read here without the sim thread */
        const world *w = base_world;
        if (!w) {
            snprintf(why, cap, "the base terrain is not available");
            return MHD_HTTP_SERVICE_UNAVAILABLE;
        }
        world_base_fill_rect(w, r, dst);
        *tick = 0;
        return 0;
    }
    if (hub_read_layer(heights, layer, r, dst, tick, s->limits.heights_timeout_ms) != 0) {
        snprintf(why, cap,
                 "the simulation did not serve the height read within %d ms (busy or shutting "
                 "down); retry",
                 s->limits.heights_timeout_ms);
        return MHD_HTTP_SERVICE_UNAVAILABLE;
    }
    return 0;
}

void http_view_heights(http_server *s, hub *from, const world *base, const http_args *args,
                       const http_status *st, http_answer *a)
{
    static const char *const names[4] = {"x", "y", "w", "h"};
    int v[4];
    for (int i = 0; i < 4; i++) {
        int rc = arg_int(args, names[i], &v[i]);
        if (rc == -1)
            return http_answer_error(a, MHD_HTTP_BAD_REQUEST,
                                     "parameter %s is required (integer cells; "
                                     "/v1/heights?x=&y=&w=&h=)",
                                     names[i]);
        if (rc == -2)
            return http_answer_error(a, MHD_HTTP_BAD_REQUEST,
                                     "parameter %s must be a decimal integer", names[i]);
    }
    world_rect r = {v[0], v[1], v[2], v[3]};
    const char *format = arg(args, "format");
    int png = 0;
    if (format && strcmp(format, "png16") == 0)
        png = 1;
    else if (format && strcmp(format, "int32") != 0)
        return http_answer_error(a, MHD_HTTP_BAD_REQUEST,
                                 "parameter format must be int32 or png16");
    if (r.w < 1)
        return http_answer_error(a, MHD_HTTP_BAD_REQUEST, "parameter w must be at least 1");
    if (r.h < 1)
        return http_answer_error(a, MHD_HTTP_BAD_REQUEST, "parameter h must be at least 1");
    int64_t cells = (int64_t)r.w * r.h;
    if (cells > s->limits.heights_max_cells)
        return http_answer_error(a, MHD_HTTP_CONTENT_TOO_LARGE,
                                 "rectangle of %d x %d = %lld cells exceeds the limit of %lld "
                                 "cells per request (heights_max_cells); read it in pieces",
                                 r.w, r.h, (long long)cells,
                                 (long long)s->limits.heights_max_cells);
    if (!from || st->world_width <= 0 || st->world_height <= 0)
        return http_answer_error(a, MHD_HTTP_SERVICE_UNAVAILABLE, "heights are not available yet");
    if (r.x < 0 || (int64_t)r.x + r.w > st->world_width)
        return http_answer_error(a, MHD_HTTP_BAD_REQUEST,
                                 "parameters x and w: columns %d..%lld are outside the world "
                                 "(columns 0..%d)",
                                 r.x, (long long)r.x + r.w - 1, st->world_width - 1);
    if (r.y < 0 || (int64_t)r.y + r.h > st->world_height)
        return http_answer_error(a, MHD_HTTP_BAD_REQUEST,
                                 "parameters y and h: rows %d..%lld are outside the world "
                                 "(rows 0..%d)",
                                 r.y, (long long)r.y + r.h - 1, st->world_height - 1);

    /* freed when the request ends, read or not (MHD's idle timeout ends an
     * unread one); a request from another node is held by that node's guard */
    if (args->c && http_guard_reserve(s->guard, args->c, (size_t)cells * 4) != 0)
        return http_answer_error(a, MHD_HTTP_TOO_MANY_REQUESTS,
                                 "too many /v1/heights bytes in flight for this address (at most "
                                 "%zu per address, %zu in all): read the answers already asked "
                                 "for",
                                 s->limits.heights_bytes_per_address,
                                 s->limits.heights_bytes_total);
    int32_t *heights = malloc((size_t)cells * sizeof *heights);
    if (!heights)
        return http_answer_error(a, MHD_HTTP_SERVICE_UNAVAILABLE,
                                 "out of memory for %lld cells; try a smaller rectangle",
                                 (long long)cells);
    uint64_t tick = 0;
    char why[512];
    unsigned status = read_rect(s, from, base, st, args, r, heights, &tick, why, sizeof why);
    if (status) {
        free(heights);
        return http_answer_error(a, status, "%s", why);
    }
    http_answer_free(a);
    a->code = MHD_HTTP_OK;
    a->extra[0] = '\0';
    if (png) {
        int32_t offset;
        int clipped;
        png16_memory m;
        int rc = http_png16_encode(heights, r.w, r.h, &offset, &clipped, &m);
        free(heights);
        if (rc != 0)
            return http_answer_error(a, MHD_HTTP_INTERNAL_SERVER_ERROR,
                                     "PNG encoding failed (out of memory?)");
        a->body = m.data;
        a->len = m.len;
        snprintf(a->type, sizeof a->type, "image/png");
        char offset_text[32];
        snprintf(offset_text, sizeof offset_text, "%d", offset);
        add_header(a, "X-Terrad-Offset", offset_text);
        add_header(a, "X-Terrad-Clipped", clipped ? "1" : "0");
    } else {
        /* Little-endian on the wire whatever the host: rewrite in place
         * (a no-op the compiler removes on x86 and arm64). */
        unsigned char *b = (unsigned char *)heights;
        for (int64_t i = 0; i < cells; i++) {
            uint32_t u = (uint32_t)heights[i];
            b[4 * i] = (unsigned char)u;
            b[4 * i + 1] = (unsigned char)(u >> 8);
            b[4 * i + 2] = (unsigned char)(u >> 16);
            b[4 * i + 3] = (unsigned char)(u >> 24);
        }
        a->body = heights;
        a->len = (size_t)cells * 4;
        snprintf(a->type, sizeof a->type, "application/octet-stream");
    }
    char text[64];
    snprintf(text, sizeof text, "%llu", (unsigned long long)tick);
    add_header(a, "X-Terrad-Tick", text);
    snprintf(text, sizeof text, "%d,%d,%d,%d", r.x, r.y, r.w, r.h);
    add_header(a, "X-Terrad-Rect", text);
    snprintf(text, sizeof text, "%d", st->units_per_m);
    add_header(a, "X-Terrad-Units-Per-Metre", text);
}

void http_view_hosted(http_server *s, hub_world *w, http_view view, const http_args *args,
                      http_answer *a)
{
    http_status snap;
    http_status *st = w->status;
    pthread_mutex_lock(&st->lock);
    snap = *st; /* the copied lock is never used */
    pthread_mutex_unlock(&st->lock);
    const char *past = view == HTTP_VIEW_STATS ? arg(args, "tick") : NULL;
    if (past)
        stats_past(w->base, &snap, w->h, past, a);
    else if (view == HTTP_VIEW_STATS)
        http_view_stats(&snap, a);
    else if (view == HTTP_VIEW_WORLD)
        http_view_world(&snap, a);
    else
        http_view_heights(s, w->h, w->base, args, &snap, a);
}

/* ---- any node serves any world: the bytes between nodes ---- */

static const char *const view_paths[3] = {"/v1/world", "/v1/stats", "/v1/heights"};

typedef struct packer {
    char *data;
    size_t len, cap;
    int failed;
} packer;

static void pack(packer *p, const void *bytes, size_t n)
{
    if (p->failed)
        return;
    if (p->len + n > p->cap) {
        size_t cap = p->cap ? p->cap * 2 : 256;
        while (cap < p->len + n)
            cap *= 2;
        char *grown = realloc(p->data, cap);
        if (!grown) {
            p->failed = 1;
            return;
        }
        p->data = grown;
        p->cap = cap;
    }
    if (n)
        memcpy(p->data + p->len, bytes, n);
    p->len += n;
}

static void pack_string(packer *p, const char *s)
{
    pack(p, s, strlen(s) + 1);
}

static enum MHD_Result pack_argument(void *cls, enum MHD_ValueKind kind, const char *key,
                                     const char *value)
{
    (void)kind;
    pack_string(cls, key);
    pack_string(cls, value ? value : "");
    return MHD_YES;
}

/* The answer of a relayed request: the owner's bytes back into *a. */
static int answer_unpack(const char *in, size_t len, http_answer *a)
{
    if (len < 8 || memcmp(in, "TAN1", 4) != 0)
        return -1;
    const unsigned char *u = (const unsigned char *)in + 4;
    unsigned code = u[0] | (unsigned)u[1] << 8 | (unsigned)u[2] << 16 | (unsigned)u[3] << 24;
    const char *type = in + 8, *end = in + len;
    const char *type_end = memchr(type, '\0', (size_t)(end - type));
    const char *extra = type_end ? type_end + 1 : NULL;
    const char *extra_end = extra ? memchr(extra, '\0', (size_t)(end - extra)) : NULL;
    if (!extra_end || code < 100 || code > 599 || (size_t)(type_end - type) >= sizeof a->type ||
        (size_t)(extra_end - extra) >= sizeof a->extra)
        return -1;
    http_answer_free(a);
    size_t n = (size_t)(end - (extra_end + 1));
    if (!(a->body = malloc(n ? n : 1)))
        return -1;
    if (n)
        memcpy(a->body, extra_end + 1, n);
    a->len = n;
    a->code = code;
    memcpy(a->type, type, (size_t)(type_end - type) + 1);
    memcpy(a->extra, extra, (size_t)(extra_end - extra) + 1);
    return 0;
}

static int forward_request(http_server *s, struct MHD_Connection *c, const char *world,
                           http_view view, http_forward_fn forward, void *ctx, http_answer *a)
{
    packer p = {0};
    pack(&p, "TRQ1", 5);
    pack_string(&p, view_paths[view]);
    MHD_get_connection_values(c, MHD_GET_ARGUMENT_KIND, pack_argument, &p);
    if (p.failed) {
        free(p.data);
        http_answer_error(a, MHD_HTTP_SERVICE_UNAVAILABLE, "out of memory");
        return 1;
    }
    void *bytes = NULL;
    size_t len = 0;
    unsigned code = MHD_HTTP_SERVICE_UNAVAILABLE;
    char why[320] = "";
    int rc = forward(ctx, world, p.data, p.len, &bytes, &len, &code, why, sizeof why);
    free(p.data);
    if (rc == 0) {
        metrics_count_http_forwarded("not_relayed");
        return 0;
    }
    if (rc < 0) {
        metrics_count_http_forwarded(code == MHD_HTTP_GATEWAY_TIMEOUT ? "no_answer" : "no_owner");
        http_answer_error(a, code, "%s", why);
    } else if (answer_unpack(bytes, len, a) != 0) {
        metrics_count_http_forwarded("no_answer");
        http_answer_error(a, MHD_HTTP_BAD_GATEWAY,
                          "the owner of world \"%.64s\" sent an answer this node cannot read "
                          "(%zu bytes; nodes of different versions?)",
                          world, len);
    } else if (http_guard_reserve(s->guard, c, a->len) != 0) {
        metrics_count_http_forwarded("answered");
        http_answer_error(a, MHD_HTTP_TOO_MANY_REQUESTS,
                          "too many /v1/heights bytes in flight for this address (at most %zu "
                          "per address, %zu in all): read the answers already asked for",
                          s->limits.heights_bytes_per_address, s->limits.heights_bytes_total);
    } else {
        metrics_count_http_forwarded("answered");
    }
    free(bytes);
    return 1;
}

int http_forward_request(http_server *s, struct MHD_Connection *c, const char *world,
                         http_view view, http_answer *a)
{
    pthread_mutex_lock(&s->worlds_lock);
    http_forward_fn forward = s->forward;
    void *ctx = s->forward_ctx;
    s->forward_calls += forward != NULL;
    pthread_mutex_unlock(&s->worlds_lock);
    if (!forward)
        return 0;
    int rc = forward_request(s, c, world, view, forward, ctx, a);
    pthread_mutex_lock(&s->worlds_lock);
    s->forward_calls--;
    pthread_cond_broadcast(&s->worlds_cond);
    pthread_mutex_unlock(&s->worlds_lock);
    return rc;
}

void http_server_set_forward(http_server *s, http_forward_fn fn, void *ctx)
{
    pthread_mutex_lock(&s->worlds_lock);
    s->forward = fn;
    s->forward_ctx = ctx;
    while (!fn && s->forward_calls > 0) /* its owner may free ctx once this returns */
        pthread_cond_wait(&s->worlds_cond, &s->worlds_lock);
    pthread_mutex_unlock(&s->worlds_lock);
}

int http_server_answer(http_server *s, const char *world, const void *request, size_t len,
                       size_t max_len, void **answer, size_t *answer_len)
{
    const char *in = request, *end = in + len;
    http_answer a = {0};
    http_args args = {0};
    int view = -1;
    if (len >= 5 && memcmp(in, "TRQ1", 5) == 0 && end[-1] == '\0') {
        const char *path = in + 5;
        for (int i = 0; i < 3; i++)
            if (strcmp(path, view_paths[i]) == 0)
                view = i;
        args.packed = path + strlen(path) + 1;
        args.len = (size_t)(end - args.packed);
    }
    unsigned code = 0;
    char why[512];
    hub_world *w = view >= 0 ? http_world_acquire(s, world, &code, why, sizeof why) : NULL;
    if (view < 0) {
        http_answer_error(&a, MHD_HTTP_BAD_REQUEST,
                          "a request from another node this node cannot read (%zu bytes)", len);
    } else if (!w) {
        http_answer_error(&a, code, "%s", why);
    } else {
        http_view_hosted(s, w, (http_view)view, &args, &a);
        http_world_release(s, w);
    }
    if (a.code && a.len + 8 + strlen(a.type) + strlen(a.extra) + 2 > max_len)
        http_answer_error(&a, MHD_HTTP_CONTENT_TOO_LARGE,
                          "an answer of %zu bytes does not fit one NATS message between nodes "
                          "(max_payload %zu bytes): read a smaller rectangle, or ask the node "
                          "that ticks the world",
                          a.len, max_len);
    if (!a.code)
        return -1;
    packer p = {0};
    unsigned char head[8] = {
        'T', 'A', 'N', '1', (unsigned char)a.code, (unsigned char)(a.code >> 8), 0, 0};
    pack(&p, head, sizeof head);
    pack_string(&p, a.type);
    pack_string(&p, a.extra);
    pack(&p, a.body, a.len);
    http_answer_free(&a);
    if (p.failed) {
        free(p.data);
        return -1;
    }
    *answer = p.data;
    *answer_len = p.len;
    return 0;
}
