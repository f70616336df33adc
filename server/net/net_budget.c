/*
 * net_budget.c: a client's bandwidth budget (issue 32 item 1; PROTOCOL.md
 * "Budgets"). A client whose hello states `budget` (bytes/s), or that gets the
 * daemon's default_budget_bytes_per_s, is sent at most that many bytes in any
 * one-second window, by the server's own accounting of every frame queued for
 * it. It runs on the net thread, between the sim's frames and the client's
 * queue: net_dispatch (net_fanout.c) hands a budgeted client's tile deltas and
 * snapshot frames here instead of queueing them, and once a tick
 * (HUB_OUT_TICK_DONE) and every heartbeat net_budget_flush sends what the
 * window has room for.
 *
 * The window is a log of (time, bytes) per frame queued (net_budget_charge,
 * from net_enqueue): a token bucket whose tokens come back exactly one second
 * after they were spent, so no one-second window ever holds more than the
 * budget (a plain bucket of depth B would allow B + rate in one second).
 * Replies, errors, ACK, CONTACT, FORCES and STEPPED frames are counted but
 * never held: they answer what the client itself did, and an ACK must follow
 * its tick's deltas. Tile data yields to them: it is queued only when the
 * window, plus as many status bytes again as the last second held (what they
 * will likely take in the next), has room.
 *
 * The ledger holds what a budgeted client has not been sent yet, per tile:
 * snapshot pieces (a subscribe's or a resync's frames, split one tile per
 * frame so that each can go when there is room) and the tile deltas it did
 * not get, summed (differences add modulo 2^32) into one delta from the
 * version it holds to the newest — the coalesced delta, against the version
 * the client has, that replaces any number of ticks' deltas. A newer piece
 * replaces a waiting one it covers and an unsubscribe drops the pieces no
 * subscription takes (net_budget_prune), so the pieces stay within one
 * snapshot of the client's subscriptions; summed deltas held between pieces
 * (they must not overtake them) count against max_pending_bytes. So a tile's
 * pending state needs no cap of its own: at most one piece per subscription
 * rectangle, one tile of summed int32s, and held deltas bounded by
 * max_pending_bytes (past it the client goes slow and its ledger is reset
 * with its resync; test_budget_held checks both the order and the bound). A tile in the
 * ledger is not current for the client (net_client_tile_current); a tile out
 * of it is: every delta of it since its snapshot was queued. A delta of a
 * tile near the client's focus (its `focus` point and its colliders' latest
 * poses, else its first subscription's centre: within one tile of one) goes at
 * once while the window has room, a far one while the second stays under
 * half the budget; any other is folded into the ledger, and
 * far tiles are flushed at lower rates (a tile d tiles away waits (d − 1) ×
 * 100 ms, at most 500 ms, so more ticks fold into one delta), nearest first.
 * Once activity stops every ledger entry goes as the window allows: the
 * client's mirror becomes exact.
 *
 * An entry larger than the window will ever have room for (a snapshot piece
 * of a few kB under a 1 kB/s budget) goes once the window holds no tile data,
 * whatever status frames it holds (an overrun, counted): the client's own
 * replies and ACKs cannot be held back, and waiting for a window empty of
 * them could be forever. A spectator's replay frames wait by the same rule
 * (held_may_go, through net_budget_fits_held) and count in the window as
 * tile data. While an entry waits for room (owed), the droppable frames that
 * need room (CHECKSUM, COLLIDERS, FOOTPRINTS: net_budget_fits) yield to it:
 * a CHECKSUM each tick had kept tile data in the window for good, and the
 * pieces of a 1 kB/s client's snapshot never went.
 */
#include "net/net_server_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

#define WINDOW_MS 1000.0
#define NEAR_TILES 1       /* Chebyshev distance in tiles sent every tick */
#define FAR_STEP_MS 100.0  /* a far tile waits this much per tile beyond NEAR_TILES */
#define FAR_MAX_MS 500.0   /* and never longer: the mirror settles within a second */
#define STATUS_SLACK 256.0 /* bytes kept free beyond the last second's status frames */
#define MAX_FOCUS_POSES 16

/* One frame waiting in a tile's ledger entry: a snapshot piece (one
 * rectangle, piece 1, rect what it covers) or a summed delta that must go
 * between the pieces it came between (piece 0). */
typedef struct budget_item {
    hub_frame *f;
    world_rect rect;
    int piece;
} budget_item;

typedef struct budget_tile {
    int tx, ty;
    budget_item *items; /* in arrival order */
    int nitems;
    int64_t items_cap;
    int32_t *acc;       /* tile_size² summed differences, tile-local, NULL: none */
    int x0, y0, x1, y1; /* what acc covers that changed, world cells, [x0, x1) */
    uint32_t base, latest;
    uint64_t tick;
    double since_ms;    /* pending since */
    hub_frame *encoded; /* acc as a DELTA frame, made when first needed */
} budget_tile;

struct net_budget {
    double rate; /* bytes per second */
    /* the window: a ring of frames queued in the last second */
    double *ms;
    uint32_t *bytes;
    unsigned char *held; /* 1: tile data, 0: never held (replies, status) */
    int head, count, cap;
    uint64_t sum, status_sum;
    uint64_t peak, total, coalesced;
    int owed; /* the last flush left an entry waiting for room */
    /* the ledger */
    budget_tile *tiles;
    int ntiles;
    int64_t tiles_cap;
    /* focus: the client's latest colliders' positions, in cells */
    double px[MAX_FOCUS_POSES], py[MAX_FOCUS_POSES];
    int npos;
};

static size_t wire_bytes(size_t len)
{
    return len + (len < 126 ? 2 : len < 65536 ? 4 : 10); /* the websocket header too */
}

/* ---- the window ---- */

static void expire(net_budget *b, double now)
{
    while (b->count && b->ms[b->head] <= now - WINDOW_MS) {
        b->sum -= b->bytes[b->head];
        if (!b->held[b->head])
            b->status_sum -= b->bytes[b->head];
        b->head = (b->head + 1) % b->cap;
        b->count--;
    }
}

void net_budget_charge(net_client *c, size_t len, int tile_data)
{
    net_budget *b = c->budget;
    if (!b)
        return;
    double now = time_now_ms();
    expire(b, now);
    uint32_t n = (uint32_t)wire_bytes(len);
    if (b->count == b->cap) { /* full: the newest entry takes them, counted until later */
        int last = (b->head + b->count - 1) % b->cap;
        /* status_sum sums the bytes of every status entry: one merged into
         * becomes one */
        if (!tile_data && b->held[last]) {
            b->held[last] = 0;
            b->status_sum += b->bytes[last];
        }
        if (!b->held[last])
            b->status_sum += n;
        b->bytes[last] += n;
        b->ms[last] = now;
    } else {
        int at = (b->head + b->count) % b->cap;
        b->ms[at] = now;
        b->bytes[at] = n;
        b->held[at] = (unsigned char)(tile_data != 0);
        b->count++;
        if (!tile_data)
            b->status_sum += n;
    }
    b->sum += n;
    b->total += n;
    if (b->sum > b->peak)
        b->peak = b->sum;
    metrics_count_budget(n, 0, (double)b->sum > b->rate);
}

/* Bytes of tile data the window has room for now. */
static double room(net_budget *b)
{
    expire(b, time_now_ms());
    return b->rate - (double)b->sum - (double)b->status_sum - STATUS_SLACK;
}

/* The one rule for data that waits for room (a ledger entry: flush_tile; a
 * spectator's frame: net_budget_fits_held), need bytes of it with left bytes
 * of room: it goes when it fits, or when the window holds no tile data (its
 * held entries). One the window has no room for while it holds none could
 * never fit (a snapshot piece of a few kB under a 1 kB/s budget): it goes
 * then (an overrun, counted), whatever replies and status frames the window
 * holds; those cannot be held back, and waiting for a window empty of them
 * could be forever. */
static int held_may_go(const net_budget *b, double need, double left)
{
    return need <= left || b->sum <= b->status_sum;
}

/* ---- the client's budget ---- */

int net_budget_start(net_client *c, double rate)
{
    net_budget *b = calloc(1, sizeof *b);
    int cap = 1024;
    if (b) {
        b->ms = malloc((size_t)cap * sizeof *b->ms);
        b->bytes = malloc((size_t)cap * sizeof *b->bytes);
        b->held = malloc((size_t)cap);
    }
    if (!b || !b->ms || !b->bytes || !b->held) {
        if (b) {
            free(b->ms);
            free(b->bytes);
            free(b->held);
        }
        free(b);
        return -1;
    }
    b->cap = cap;
    b->rate = rate;
    c->budget = b;
    return 0;
}

static void tile_clear(budget_tile *t)
{
    for (int i = 0; i < t->nitems; i++)
        hub_frame_unref(t->items[i].f);
    free(t->items);
    free(t->acc);
    if (t->encoded)
        hub_frame_unref(t->encoded);
    memset(t, 0, sizeof *t);
}

void net_budget_reset(net_client *c)
{
    net_budget *b = c->budget;
    if (!b)
        return;
    for (int i = 0; i < b->ntiles; i++)
        tile_clear(&b->tiles[i]);
    b->ntiles = 0;
}

void net_budget_free(net_client *c)
{
    net_budget *b = c->budget;
    if (!b)
        return;
    log_info("net: client %u (%s): budget %.0f bytes/s, %llu bytes sent, the fullest second "
             "held %llu, %llu deltas coalesced",
             c->id, c->peer, b->rate, (unsigned long long)b->total, (unsigned long long)b->peak,
             (unsigned long long)b->coalesced);
    net_budget_reset(c);
    free(b->tiles);
    free(b->ms);
    free(b->bytes);
    free(b->held);
    free(b);
    c->budget = NULL;
}

double net_budget_rate(const net_client *c)
{
    return c->budget ? c->budget->rate : 0;
}

void net_budget_note_poses(net_client *c, const terrad_pose *poses, size_t count)
{
    net_budget *b = c->budget;
    double cell = c->srv->cfg.world.cell_size_m;
    if (!b || count == 0 || !(cell > 0))
        return;
    b->npos = 0;
    for (size_t i = 0; i < count && b->npos < MAX_FOCUS_POSES; i++) {
        b->px[b->npos] = poses[i].x / cell;
        b->py[b->npos] = poses[i].y / cell;
        b->npos++;
    }
}

/* ---- the ledger ---- */

static budget_tile *tile_find(net_budget *b, int tx, int ty)
{
    for (int i = 0; i < b->ntiles; i++)
        if (b->tiles[i].tx == tx && b->tiles[i].ty == ty)
            return &b->tiles[i];
    return NULL;
}

static budget_tile *tile_get(net_budget *b, int tx, int ty)
{
    budget_tile *t = tile_find(b, tx, ty);
    if (t)
        return t;
    if (array_grow((void **)&b->tiles, &b->tiles_cap, (int64_t)b->ntiles + 1, sizeof *b->tiles))
        return NULL;
    t = &b->tiles[b->ntiles++];
    memset(t, 0, sizeof *t);
    t->tx = tx;
    t->ty = ty;
    t->since_ms = time_now_ms();
    return t;
}

static void tile_remove(net_budget *b, budget_tile *t)
{
    tile_clear(t);
    *t = b->tiles[--b->ntiles];
}

/* Distance in tiles (Chebyshev) from the nearest of the client's focus and
 * its colliders' latest poses (else its first subscription's centre) to tile
 * (tx, ty). */
static int tile_distance(const net_client *c, int tx, int ty)
{
    int ts = c->srv->cfg.world.tile_size;
    double fx[MAX_FOCUS_POSES + 1], fy[MAX_FOCUS_POSES + 1];
    int n = 0;
    if (c->has_focus) {
        fx[0] = c->focus_x;
        fy[0] = c->focus_y;
        n = 1;
    }
    /* its own colliders are near whatever its focus: their ruts come every tick */
    for (int i = 0; c->budget && i < c->budget->npos; i++, n++) {
        fx[n] = c->budget->px[i];
        fy[n] = c->budget->py[i];
    }
    if (n == 0 && c->sub_count) {
        fx[0] = c->subs[0].rect.x + c->subs[0].rect.w / 2.0;
        fy[0] = c->subs[0].rect.y + c->subs[0].rect.h / 2.0;
        n = 1;
    }
    int best = n ? INT32_MAX : 0;
    for (int i = 0; i < n; i++) {
        int dx = abs((int)floor(fx[i] / ts) - tx), dy = abs((int)floor(fy[i] / ts) - ty);
        int d = dx > dy ? dx : dy;
        if (d < best)
            best = d;
    }
    return best;
}

/* How many rectangles a DELTA frame can hold: each takes at least its fixed
 * part (a base-coded piece of an untouched tile is little more than that). */
static size_t rects_room(const hub_frame *f)
{
    return (f->len > TERRAD_DELTA_FIXED ? (f->len - TERRAD_DELTA_FIXED) / TERRAD_RECT_FIXED : 0) +
           1;
}

/* Adds one delta frame's differences to tile t's sum. 0, or -1 (memory, a
 * frame that does not decode): the caller resyncs the client. */
static int fold(net_state *w, budget_tile *t, const hub_frame *f)
{
    int ts = w->cfg.world.tile_size;
    size_t max = rects_room(f), count = 0;
    uint64_t tick = 0;
    terrad_rect *rects = malloc(max * sizeof *rects);
    if (!rects || terrad_delta_decode(f->data, f->len, &tick, rects, max, &count) != 0) {
        free(rects);
        return -1;
    }
    if (!t->acc) {
        t->acc = calloc((size_t)ts * (size_t)ts, sizeof *t->acc);
        if (!t->acc) {
            free(rects);
            return -1;
        }
        t->x0 = t->y0 = INT32_MAX;
        t->x1 = t->y1 = INT32_MIN;
    }
    if (!w->budget_codec)
        w->budget_codec = terrad_codec_new(3);
    int32_t *values = malloc((size_t)ts * (size_t)ts * sizeof *values);
    if (!values || !w->budget_codec) {
        free(values);
        free(rects);
        return -1;
    }
    int rc = 0;
    for (size_t i = 0; i < count && rc == 0; i++) {
        const terrad_rect *r = &rects[i];
        size_t cells = (size_t)r->w * r->h;
        if (r->encoding != TERRAD_ENC_DELTA || r->w > ts || r->h > ts ||
            terrad_rect_decompress(w->budget_codec, r->data, r->data_len, cells, values,
                                   (size_t)ts * (size_t)ts) != 0) {
            rc = -1;
            break;
        }
        int ox = r->x - t->tx * ts, oy = r->y - t->ty * ts;
        if (ox < 0 || oy < 0 || ox + r->w > ts || oy + r->h > ts) {
            rc = -1;
            break;
        }
        for (int y = 0; y < r->h; y++)
            for (int x = 0; x < r->w; x++) {
                int32_t *a = &t->acc[(size_t)(oy + y) * (size_t)ts + (size_t)(ox + x)];
                *a = (int32_t)((uint32_t)*a + (uint32_t)values[(size_t)y * r->w + (size_t)x]);
            }
        if (r->x < t->x0)
            t->x0 = r->x;
        if (r->y < t->y0)
            t->y0 = r->y;
        if (r->x + r->w > t->x1)
            t->x1 = r->x + r->w;
        if (r->y + r->h > t->y1)
            t->y1 = r->y + r->h;
        if (!t->base)
            t->base = r->base_version;
        t->latest = r->new_version;
    }
    free(values);
    free(rects);
    t->tick = tick;
    if (t->encoded) {
        hub_frame_unref(t->encoded);
        t->encoded = NULL;
    }
    return rc;
}

/* The summed differences as one DELTA frame (cached until more fold in). */
static hub_frame *encode_acc(net_state *w, budget_tile *t)
{
    if (t->encoded)
        return t->encoded;
    int ts = w->cfg.world.tile_size;
    int rw = t->x1 - t->x0, rh = t->y1 - t->y0;
    size_t cells = (size_t)rw * (size_t)rh;
    int32_t *values = malloc(cells * sizeof *values);
    size_t cap = terrad_rect_compress_bound(cells), len = 0;
    uint8_t *data = malloc(cap);
    hub_frame *f = NULL;
    if (values && data && w->budget_codec) {
        int ox = t->x0 - t->tx * ts, oy = t->y0 - t->ty * ts;
        for (int y = 0; y < rh; y++)
            memcpy(values + (size_t)y * rw, t->acc + (size_t)(oy + y) * ts + ox,
                   (size_t)rw * sizeof *values);
        if (terrad_rect_compress(w->budget_codec, values, cells, data, cap, &len) == 0) {
            terrad_rect r = {.x = t->x0,
                             .y = t->y0,
                             .w = (uint16_t)rw,
                             .h = (uint16_t)rh,
                             .base_version = t->base,
                             .new_version = t->latest,
                             .encoding = TERRAD_ENC_DELTA,
                             .data_len = (uint32_t)len,
                             .data = data};
            size_t size = terrad_delta_size(&r, 1);
            f = hub_frame_new(1, size);
            if (f && terrad_delta_encode(f->data, size, &f->len, t->tick, &r, 1) != 0) {
                hub_frame_unref(f);
                f = NULL;
            }
        }
    }
    free(values);
    free(data);
    t->encoded = f;
    return f;
}

static void resync_for(net_client *c, const char *why)
{
    log_warn("net: client %u (%s): budget ledger: %s: fresh snapshots", c->id, c->peer, why);
    net_request_resync(c, 0);
}

int net_budget_delta(net_client *c, const hub_out *o)
{
    net_budget *b = c->budget;
    budget_tile *t = tile_find(b, o->tile_x, o->tile_y);
    double left = room(b), need = (double)wire_bytes(o->frame->len);
    /* near, and room: the shared frame goes as to any client; a far one only
     * while the second stays under half the budget (the rest is the near
     * tiles'), else it is folded and goes later, at its tile's lower rate */
    if (!t && left >= need &&
        (tile_distance(c, o->tile_x, o->tile_y) <= NEAR_TILES ||
         b->rate - left + need <= b->rate / 2))
        return 0;
    if (!t)
        t = tile_get(b, o->tile_x, o->tile_y);
    if (!t || fold(c->srv, t, o->frame) != 0) {
        resync_for(c, "out of memory, or a delta that does not decode");
        return 1;
    }
    b->coalesced++;
    metrics_count_budget(0, 1, 0);
    return 1;
}

static int sub_meets_tile(const net_client *c, int tx, int ty)
{
    int ts = c->srv->cfg.world.tile_size;
    world_rect tile = {tx * ts, ty * ts, ts, ts};
    for (int i = 0; i < c->sub_count; i++)
        if (world_rects_overlap(c->subs[i].rect, tile))
            return 1;
    return 0;
}

static int item_append(budget_tile *t, hub_frame *f, world_rect rect, int piece)
{
    if (array_grow((void **)&t->items, &t->items_cap, (int64_t)t->nitems + 1, sizeof *t->items))
        return -1;
    t->items[t->nitems++] = (budget_item){f, rect, piece};
    return 0;
}

static void item_remove(budget_tile *t, int i)
{
    hub_frame_unref(t->items[i].f);
    memmove(&t->items[i], &t->items[i + 1], (size_t)(t->nitems - i - 1) * sizeof *t->items);
    t->nitems--;
}

static int rect_within(world_rect in, world_rect out)
{
    return in.x >= out.x && in.y >= out.y && (int64_t)in.x + in.w <= (int64_t)out.x + out.w &&
           (int64_t)in.y + in.h <= (int64_t)out.y + out.h;
}

/* Bytes of the summed deltas waiting between pieces in the whole ledger:
 * what max_pending_bytes bounds (the pieces themselves are at most one per
 * rectangle of the client's subscriptions, a snapshot's worth, as for any
 * client; hard_pending_bytes allows for one). */
static size_t held_delta_bytes(const net_budget *b)
{
    size_t n = 0;
    for (int i = 0; i < b->ntiles; i++)
        for (int k = 0; k < b->tiles[i].nitems; k++)
            if (!b->tiles[i].items[k].piece)
                n += wire_bytes(b->tiles[i].items[k].f->len);
    return n;
}

/* A subscribe's or resync's snapshot frame: one frame per rectangle into the
 * ledger (each tile's piece goes when there is room). A newer piece replaces
 * a waiting one it covers (everything the older would have set, the newer
 * sets to a later version), so that repeated subscribes and resyncs of the
 * same tiles do not pile up. The tile's summed deltas up to the piece's
 * version (for the client's other subscriptions holding the tile) go ahead
 * at once when nothing waits for the tile, else into its list, behind what
 * already waits: a client never sees a delta on a version it has not been
 * sent. Takes f. 0, or 1 when the deltas waiting in the ledger pass
 * max_pending_bytes: the caller treats the client as slow (net_fanout.c). */
int net_budget_snapshot(net_client *c, hub_frame *f)
{
    net_budget *b = c->budget;
    net_state *w = c->srv;
    int ts = w->cfg.world.tile_size;
    size_t max = rects_room(f);
    terrad_rect *rects = malloc(max * sizeof *rects);
    size_t count = 0;
    uint64_t tick = 0;
    int drc = rects ? terrad_delta_decode(f->data, f->len, &tick, rects, max, &count)
                    : TERRAD_E_NO_MEMORY;
    int bad = drc != 0, deltas_held = 0;
    for (size_t i = 0; !bad && i < count; i++) {
        budget_tile *t = tile_get(b, rects[i].x / ts, rects[i].y / ts);
        world_rect rect = {rects[i].x, rects[i].y, rects[i].w, rects[i].h};
        size_t size = terrad_delta_size(&rects[i], 1);
        hub_frame *one = t ? hub_frame_new(1, size) : NULL;
        if (!one || terrad_delta_encode(one->data, size, &one->len, tick, &rects[i], 1) != 0) {
            if (one)
                hub_frame_unref(one);
            bad = 1;
            break;
        }
        for (int k = t->nitems - 1; k >= 0; k--)
            if (t->items[k].piece && rect_within(t->items[k].rect, rect))
                item_remove(t, k);
        if (t->acc && t->latest == rects[i].new_version) {
            hub_frame *d = encode_acc(w, t);
            if (d && t->nitems == 0) { /* nothing waits: the deltas go ahead */
                hub_frame_ref(d);
                net_enqueue(c, d, NET_ITEM_TILE);
            } else if (d) {
                hub_frame_ref(d);
                if (item_append(t, d, (world_rect){0, 0, 0, 0}, 0) != 0) {
                    hub_frame_unref(d);
                    bad = 1;
                }
                deltas_held = 1;
            }
            free(t->acc);
            t->acc = NULL;
            t->base = 0;
            if (t->encoded) {
                hub_frame_unref(t->encoded);
                t->encoded = NULL;
            }
        }
        if (bad || item_append(t, one, rect, 1) != 0) {
            hub_frame_unref(one);
            bad = 1;
        }
    }
    free(rects);
    hub_frame_unref(f);
    if (bad) {
        char why[96];
        snprintf(why, sizeof why, "could not take a snapshot frame (%s)",
                 drc ? terrad_err_name(drc) : "out of memory");
        resync_for(c, why);
        return 0;
    }
    size_t held = deltas_held ? held_delta_bytes(b) : 0;
    if (held && c->droppable_bytes + held > w->cfg.limits.max_pending_bytes) {
        log_info("net: client %u (%s): %zu bytes of deltas wait between snapshot pieces in its "
                 "budget ledger (limit %zu)",
                 c->id, c->peer, held, w->cfg.limits.max_pending_bytes);
        return 1;
    }
    return 0;
}

/* After an unsubscribe: the pieces no remaining subscription would take
 * (a piece sets a mirror whose part of the tile it covers), and the tiles
 * none meets, leave the ledger. */
void net_budget_prune(net_client *c)
{
    net_budget *b = c->budget;
    if (!b)
        return;
    int ts = c->srv->cfg.world.tile_size;
    for (int i = 0; i < b->ntiles; i++) {
        budget_tile *t = &b->tiles[i];
        world_rect tile = {t->tx * ts, t->ty * ts, ts, ts};
        for (int k = t->nitems - 1; k >= 0; k--) {
            int wanted = !t->items[k].piece;
            for (int s = 0; !wanted && s < c->sub_count; s++) {
                world_rect part = world_rect_meet(tile, c->subs[s].rect);
                wanted = part.w > 0 && part.h > 0 && rect_within(part, t->items[k].rect);
            }
            if (!wanted)
                item_remove(t, k);
        }
        if (!sub_meets_tile(c, t->tx, t->ty) || (t->nitems == 0 && !t->acc)) {
            tile_remove(b, t);
            i--;
        }
    }
}

typedef struct flush_order {
    int tile;
    int distance;
} flush_order;

static int by_distance(const void *a, const void *b)
{
    const flush_order *x = a, *y = b;
    return x->distance != y->distance ? (x->distance > y->distance) - (x->distance < y->distance)
                                      : (x->tile > y->tile) - (x->tile < y->tile);
}

/* Sends tile t's ledger entry if it may go whole (held_may_go); 1 when sent.
 * An entry holds at most one piece per rectangle, so one that goes past the
 * budget is at most a snapshot of the tile. */
static int flush_tile(net_client *c, budget_tile *t, double *left)
{
    const net_budget *b = c->budget;
    hub_frame *d = t->acc ? encode_acc(c->srv, t) : NULL;
    if (t->acc && !d)
        return 0;
    double need = d ? (double)wire_bytes(d->len) : 0;
    for (int i = 0; i < t->nitems; i++)
        need += (double)wire_bytes(t->items[i].f->len);
    if (!held_may_go(b, need, *left))
        return 0;
    *left -= need;
    for (int i = 0; i < t->nitems; i++) {
        net_enqueue(c, t->items[i].f, NET_ITEM_TILE); /* the ledger's reference */
        t->items[i].f = NULL;
    }
    t->nitems = 0;
    if (d) {
        t->encoded = NULL;
        net_enqueue(c, d, NET_ITEM_TILE);
    }
    return 1;
}

void net_budget_flush(net_client *c)
{
    net_budget *b = c->budget;
    if (!b || !b->ntiles || c->slow || c->snapshots_done < c->resync_until)
        return;
    double now = time_now_ms(), left = room(b);
    flush_order *order = malloc((size_t)b->ntiles * sizeof *order);
    if (!order)
        return;
    int n = 0;
    for (int i = 0; i < b->ntiles; i++) {
        budget_tile *t = &b->tiles[i];
        if (!sub_meets_tile(c, t->tx, t->ty)) { /* unsubscribed meanwhile */
            tile_remove(b, t);
            i--;
            continue;
        }
        int d = tile_distance(c, t->tx, t->ty);
        double wait = d > NEAR_TILES ? (d - NEAR_TILES) * FAR_STEP_MS : 0;
        if (wait > FAR_MAX_MS)
            wait = FAR_MAX_MS;
        if (t->nitems || now - t->since_ms >= wait)
            order[n++] = (flush_order){i, d};
    }
    qsort(order, (size_t)n, sizeof *order, by_distance);
    int sent = 0, k = 0;
    for (; k < n; k++) {
        budget_tile *t = &b->tiles[order[k].tile];
        if (flush_tile(c, t, &left)) {
            tile_clear(t);
            t->tx = INT32_MIN; /* removed below, after the indices are spent */
            sent++;
        } else {
            break; /* nearest first: a far tile does not pass a near one */
        }
    }
    b->owed = k < n;
    free(order);
    for (int i = 0; sent && i < b->ntiles; i++)
        if (b->tiles[i].tx == INT32_MIN) {
            b->tiles[i] = b->tiles[--b->ntiles];
            i--;
        }
}

void net_budget_flush_state(net_state *w)
{
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (c->budget && c->ready && !c->closing && !c->killed)
            net_budget_flush(c);
    }
}

int net_budget_fits(net_client *c, size_t len)
{
    net_budget *b = c->budget;
    if (b && b->owed && !b->ntiles)
        b->owed = 0; /* pruned or reset since the flush */
    return !b || (!b->owed && room(b) >= (double)wire_bytes(len));
}

int net_budget_fits_held(net_client *c, size_t len)
{
    net_budget *b = c->budget;
    if (!b)
        return 1;
    double left = room(b); /* expires the window first */
    return held_may_go(b, (double)wire_bytes(len), left);
}

size_t net_budget_checksum_entries(net_client *c)
{
    if (!c->budget)
        return SIZE_MAX;
    /* the frame: its fixed part and 20 bytes an entry, and a websocket header
     * of at most 4 bytes (frames under 64 KiB) */
    double fit = (room(c->budget) - 4.0 - TERRAD_CHECKSUM_FIXED) / TERRAD_TILE_SUM_SIZE;
    return fit >= 1.0 ? (size_t)fit : 1; /* 1: it will not fit, net_budget_fits says so */
}

int net_client_tile_current(const net_client *c, int tx, int ty)
{
    if (c->slow || c->snapshots_done < c->snapshots_requested)
        return 0;
    return !c->budget || !tile_find(c->budget, tx, ty);
}
