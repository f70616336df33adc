/*
 * service.c: one tick of the daemon on the sim thread (see service.h).
 *
 * Tile versions are the protocol's unit of consistency: the world is cut into
 * SERVICE_TILE_SIZE² tiles, each with a u32 version that advances by one in
 * every tick that changes it. A tick's changes are cut along tile edges; the
 * pieces of one tile (a tile may meet several windows) are combined into
 * one rectangle, its differences encoded once (zigzag + zstd) and published
 * once for the network thread to fan out to every subscriber. Σh is kept
 * incrementally from the same differences, so no tick scans the world.
 */
#include "service/service.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

/* A frame never grows past the protocol's max_message_bytes. */
#define SERVICE_FRAME_MAX (1024 * 1024)
#define SERVICE_COMMANDS_PER_TICK 1024
/* COLLIDERS frames: at most one every this many ticks (20 Hz at 60 Hz), and
 * an unchanged list again after COLLIDERS_REFRESH_TICKS, which heals a frame
 * the network dropped for a slow client. */
#define COLLIDERS_EVERY_TICKS 3
#define COLLIDERS_REFRESH_TICKS 60
/* FOOTPRINTS: events per frame so that a frame stays within SERVICE_FRAME_MAX
 * (a tick with more is sent as several frames of the same tick). */
#define FOOTPRINTS_PER_FRAME ((SERVICE_FRAME_MAX - TERRAD_FOOTPRINTS_FIXED) / TERRAD_FOOTPRINT_SIZE)
/* Frames already built this tick that a client's frame is compared with, to
 * share one copy among clients with the same events (whole-world viewers). */
#define FOOTPRINTS_SHARED_MAX 8

typedef struct svc_subscription {
    uint32_t id;
    world_rect rect;
    int colliders;  /* asked for COLLIDERS frames */
    int footprints; /* asked for FOOTPRINTS frames */
} svc_subscription;

typedef struct svc_client {
    uint32_t id;
    uint32_t last_sequence;
    int sequence_pending; /* a batch was used since the last ACK */
    svc_subscription *subs;
    int sub_count, sub_capacity;
    uint64_t colliders_hash;      /* of the last COLLIDERS frame sent, 0: none yet */
    uint64_t colliders_sent_tick; /* when it was sent */
} svc_client;

typedef struct svc_collider {
    uint32_t id, client;
    collider_geometry *geometry; /* on the heap: backends cache by its address */
    collider_mesh *mesh;         /* owned, for mesh shapes */
    collider_pose pose, previous_pose;
    int has_pose; /* created without a pose: inert until its first POSE_BATCH */
    int has_previous, feedback;
} svc_collider;

typedef struct svc_contact {
    terrad_contact contact;
    uint32_t client;
} svc_contact;

typedef struct snapshot_job {
    uint32_t client;
    world_rect rect;
    int last; /* the last job of its request: marks snapshot_done */
} snapshot_job;

/* One piece of a dirty rectangle inside one tile. */
typedef struct tile_piece {
    int tile;   /* tile index */
    int window; /* engine window it came from */
    world_rect rect;
} tile_piece;

struct service {
    sim_engine *engine;
    world *world;
    hub *hub;
    store *store;   /* NULL: memory only */
    int store_down; /* last state told to the hub */
    uint64_t tick;
    int64_t volume;
    int tiles_x, tiles_y;
    uint32_t *tile_versions;
    terrad_codec *codec;

    svc_client *clients;
    int client_count, client_capacity;
    svc_collider *colliders;
    int collider_count, collider_capacity;

    hub_command *commands;
    hub_pose *poses;
    int pose_capacity;
    sim_collider *sim_colliders;
    int sim_capacity;
    snapshot_job *snapshots;
    int snapshot_count, snapshot_capacity;
    tile_piece *pieces;
    int piece_count, piece_capacity;
    hub_out *out;
    int out_count, out_capacity;
    svc_contact *contacts;
    int contact_count, contact_capacity;

    int32_t *values; /* one tile of values */
    uint8_t *packed; /* compressed tile */
    size_t packed_cap;
    double oldest_pose_ms; /* earliest arrival among this tick's poses, 0 if none */
    int32_t *bottom;       /* contact scratch */
    int64_t bottom_cap;
    terrad_collider_state *states; /* COLLIDERS scratch */
    int state_capacity;
    terrad_footprint *events; /* FOOTPRINTS scratch: one client's events */
    int event_capacity;
};

static int grow_array(void **p, int *capacity, int needed, size_t elem)
{
    if (needed <= *capacity)
        return 0;
    int cap = *capacity ? *capacity : 16;
    while (cap < needed)
        cap *= 2;
    void *q = realloc(*p, (size_t)cap * elem);
    if (!q)
        return -1;
    *p = q;
    *capacity = cap;
    return 0;
}

service *service_create(sim_engine *engine, hub *h, error_text *err)
{
    service *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "service: out of memory");
        return NULL;
    }
    s->engine = engine;
    s->world = sim_engine_world(engine);
    s->hub = h;
    s->tiles_x = (s->world->width + SERVICE_TILE_SIZE - 1) / SERVICE_TILE_SIZE;
    s->tiles_y = (s->world->height + SERVICE_TILE_SIZE - 1) / SERVICE_TILE_SIZE;
    s->tile_versions = malloc((size_t)s->tiles_x * s->tiles_y * sizeof *s->tile_versions);
    s->commands = malloc(SERVICE_COMMANDS_PER_TICK * sizeof *s->commands);
    s->values = malloc(SERVICE_TILE_SIZE * SERVICE_TILE_SIZE * sizeof *s->values);
    s->packed_cap = terrad_rect_compress_bound(SERVICE_TILE_SIZE * SERVICE_TILE_SIZE);
    s->packed = malloc(s->packed_cap);
    s->codec = terrad_codec_new(3);
    if (!s->tile_versions || !s->commands || !s->values || !s->packed || !s->codec) {
        service_destroy(s);
        error_set(err, "service: out of memory for %d tiles", s->tiles_x * s->tiles_y);
        return NULL;
    }
    for (int i = 0; i < s->tiles_x * s->tiles_y; i++)
        s->tile_versions[i] = 1;
    s->volume = world_volume(s->world);
    return s;
}

static void collider_release(service *s, svc_collider *c)
{
    sim_backend *backend = sim_engine_backend(s->engine);
    backend->forget_geometry(backend, c->geometry);
    free(c->geometry);
    c->geometry = NULL;
    if (c->mesh) {
        collider_mesh_free(c->mesh);
        free(c->mesh);
        c->mesh = NULL;
    }
}

void service_destroy(service *s)
{
    if (!s)
        return;
    for (int i = 0; i < s->collider_count; i++)
        collider_release(s, &s->colliders[i]);
    for (int i = 0; i < s->client_count; i++)
        free(s->clients[i].subs);
    for (int i = 0; i < s->out_count; i++)
        if (s->out[i].frame)
            hub_frame_unref(s->out[i].frame);
    terrad_codec_free(s->codec);
    free(s->tile_versions);
    free(s->clients);
    free(s->colliders);
    free(s->commands);
    free(s->poses);
    free(s->sim_colliders);
    free(s->snapshots);
    free(s->pieces);
    free(s->out);
    free(s->contacts);
    free(s->values);
    free(s->packed);
    free(s->bottom);
    free(s->states);
    free(s->events);
    free(s);
}

void service_attach_store(service *s, store *st, uint64_t recovered_tick)
{
    s->store = st;
    s->tick = recovered_tick;
    s->volume = world_volume(s->world);
}

/* The store could not log this tick: put every window back as it was, so
 * nothing that is not durable is ever seen. */
static void undo_tick(service *s, sim_tick_report *report)
{
    for (int i = 0; i < report->window_count; i++) {
        const int32_t *before, *after;
        world_rect win = sim_engine_window(s->engine, i, &before, &after);
        world_scatter_window(s->world, win, before);
    }
    report->dirty_count = 0;
}

static void tell_store_state(service *s)
{
    const char *why = store_failure(s->store);
    int down = why[0] != 0;
    if (down != s->store_down)
        hub_set_store_unavailable(s->hub, down ? why : NULL);
    s->store_down = down;
}

uint64_t service_current_tick(const service *s)
{
    return s->tick;
}

int64_t service_volume(const service *s)
{
    return s->volume;
}

uint32_t service_tile_version(const service *s, int tile_x, int tile_y)
{
    return s->tile_versions[tile_y * s->tiles_x + tile_x];
}

static svc_client *find_client(service *s, uint32_t id)
{
    for (int i = 0; i < s->client_count; i++)
        if (s->clients[i].id == id)
            return &s->clients[i];
    return NULL;
}

static int find_collider(const service *s, uint32_t id)
{
    /* colliders stay sorted by id (ids only grow), so a binary search */
    int lo = 0, hi = s->collider_count - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (s->colliders[mid].id == id)
            return mid;
        if (s->colliders[mid].id < id)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

static void remove_collider(service *s, int index)
{
    collider_release(s, &s->colliders[index]);
    memmove(&s->colliders[index], &s->colliders[index + 1],
            (size_t)(s->collider_count - index - 1) * sizeof *s->colliders);
    s->collider_count--;
}

static int queue_out(service *s, hub_out item)
{
    if (!item.frame && item.kind != HUB_OUT_TICK_DONE)
        return -1;
    if (grow_array((void **)&s->out, &s->out_capacity, s->out_count + 1, sizeof *s->out) != 0) {
        hub_frame_unref(item.frame);
        return -1;
    }
    s->out[s->out_count++] = item;
    return 0;
}

static void queue_snapshots(service *s, uint32_t client, const svc_subscription *subs, int n)
{
    for (int i = 0; i < n; i++) {
        if (grow_array((void **)&s->snapshots, &s->snapshot_capacity, s->snapshot_count + 1,
                       sizeof *s->snapshots) != 0)
            return;
        s->snapshots[s->snapshot_count++] =
            (snapshot_job){.client = client, .rect = subs[i].rect, .last = i == n - 1};
    }
}

static void apply_command(service *s, hub_command *c)
{
    svc_client *cl = find_client(s, c->client);
    switch (c->kind) {
    case HUB_CLIENT_JOINED:
        if (!cl && grow_array((void **)&s->clients, &s->client_capacity, s->client_count + 1,
                              sizeof *s->clients) == 0)
            s->clients[s->client_count++] = (svc_client){.id = c->client};
        break;
    case HUB_CLIENT_LEFT:
        for (int i = s->collider_count - 1; i >= 0; i--)
            if (s->colliders[i].client == c->client)
                remove_collider(s, i);
        if (cl) {
            free(cl->subs);
            *cl = s->clients[--s->client_count];
        }
        break;
    case HUB_COLLIDER_CREATE: {
        collider_geometry *g = malloc(sizeof *g);
        if (!g || find_collider(s, c->collider) >= 0 ||
            (s->collider_count && s->colliders[s->collider_count - 1].id > c->collider) ||
            grow_array((void **)&s->colliders, &s->collider_capacity, s->collider_count + 1,
                       sizeof *s->colliders) != 0) {
            free(g);
            if (c->mesh) {
                collider_mesh_free(c->mesh);
                free(c->mesh);
            }
            break;
        }
        *g = c->geometry;
        g->mesh = c->mesh;
        /* the net thread sends an all-zero orientation for "no pose yet" */
        const quatd *q = &c->pose.orientation;
        int has_pose = q->w != 0 || q->x != 0 || q->y != 0 || q->z != 0;
        s->colliders[s->collider_count++] = (svc_collider){.id = c->collider,
                                                           .client = c->client,
                                                           .geometry = g,
                                                           .mesh = c->mesh,
                                                           .pose = c->pose,
                                                           .previous_pose = c->pose,
                                                           .has_pose = has_pose,
                                                           .feedback = c->feedback};
        c->mesh = NULL;
        break;
    }
    case HUB_COLLIDER_DELETE: {
        int i = find_collider(s, c->collider);
        if (i >= 0 && s->colliders[i].client == c->client)
            remove_collider(s, i);
        break;
    }
    case HUB_SUBSCRIBE: {
        /* the net thread pauses nothing for a subscribe, but it counts one
         * snapshot mark per request: send it even when there is nothing */
        svc_subscription sub = {c->subscription, c->rect, c->colliders, c->footprints};
        if (cl && c->colliders)
            cl->colliders_hash = 0; /* a new region: send the list at the next chance */
        if (cl && grow_array((void **)&cl->subs, &cl->sub_capacity, cl->sub_count + 1,
                             sizeof *cl->subs) == 0)
            cl->subs[cl->sub_count++] = sub;
        else
            sub.rect = (world_rect){0, 0, 0, 0};
        queue_snapshots(s, c->client, &sub, 1);
        break;
    }
    case HUB_UNSUBSCRIBE:
        for (int i = 0; cl && i < cl->sub_count; i++)
            if (cl->subs[i].id == c->subscription) {
                cl->subs[i] = cl->subs[--cl->sub_count];
                break;
            }
        break;
    case HUB_RESYNC:
        if (!cl)
            break;
        if (c->subscription == 0) {
            queue_snapshots(s, cl->id, cl->subs, cl->sub_count);
            if (cl->sub_count == 0) /* nothing to send, but the client waits for the mark */
                queue_snapshots(s, cl->id, &(svc_subscription){0, {0, 0, 0, 0}, 0, 0}, 1);
        } else {
            svc_subscription sub = {c->subscription, {0, 0, 0, 0}, 0, 0};
            for (int i = 0; i < cl->sub_count; i++)
                if (cl->subs[i].id == c->subscription)
                    sub = cl->subs[i];
            queue_snapshots(s, cl->id, &sub, 1); /* one mark, even for a gone subscription */
        }
        break;
    }
}

static void apply_poses(service *s, int n)
{
    s->oldest_pose_ms = 0;
    for (int i = 0; i < n; i++) {
        const hub_pose *p = &s->poses[i];
        int k = find_collider(s, p->collider);
        if (k < 0 || s->colliders[k].client != p->client)
            continue; /* deleted meanwhile */
        if (!s->colliders[k].has_pose) {
            s->colliders[k].has_pose = 1;
            s->colliders[k].has_previous = 0; /* no sweep from a pose it never had */
        }
        s->colliders[k].pose = p->pose;
        if (s->oldest_pose_ms == 0 || p->received_ms < s->oldest_pose_ms)
            s->oldest_pose_ms = p->received_ms;
    }
}

/* The batches (empty ones too) this tick answers with an ACK. */
static void apply_batches(service *s)
{
    hub_batch batches[256];
    int n;
    while ((n = hub_take_batches(s->hub, batches, 256)) > 0) {
        for (int i = 0; i < n; i++) {
            svc_client *cl = find_client(s, batches[i].client);
            if (cl) {
                cl->last_sequence = batches[i].sequence;
                cl->sequence_pending = 1;
            }
        }
    }
}

/* ---- contact feedback, against the terrain before the tick ---- */

static double height_m(const world *w, int x, int y)
{
    x = x < 0 ? 0 : x >= w->width ? w->width - 1 : x;
    y = y < 0 ? 0 : y >= w->height ? w->height - 1 : y;
    return (double)world_height_at(w, x, y) / w->units_per_m;
}

static void contact_measure(service *s, const svc_collider *c, terrad_contact *out)
{
    const world *w = s->world;
    memset(out, 0, sizeof *out);
    out->id = c->id;
    vec3d lo, hi;
    collider_bounds(c->geometry, c->pose, &lo, &hi);
    double cs = w->cell_size_m;
    world_rect r = {(int)floor(fmax(fmin(lo.x / cs, 1e9), -1e9)),
                    (int)floor(fmax(fmin(lo.y / cs, 1e9), -1e9)), 0, 0};
    r.w = (int)floor(fmax(fmin(hi.x / cs, 1e9), -1e9)) - r.x + 1;
    r.h = (int)floor(fmax(fmin(hi.y / cs, 1e9), -1e9)) - r.y + 1;
    int cx = (int)floor(c->pose.position.x / cs), cy = (int)floor(c->pose.position.y / cs);
    double nx = 0, ny = 0, nz = 0;
    int64_t deepest = -1;
    if (world_clip_rect(w, &r)) {
        int64_t n = (int64_t)r.w * r.h;
        if (n > s->bottom_cap) {
            int32_t *b = realloc(s->bottom, (size_t)n * sizeof *b);
            if (!b)
                return;
            s->bottom = b;
            s->bottom_cap = n;
        }
        sim_collider one = {.geometry = c->geometry, .pose = c->pose};
        sim_window_job job = {.rect = r,
                              .cell_size_m = cs,
                              .units_per_m = w->units_per_m,
                              .colliders = &one,
                              .collider_count = 1};
        sim_window_depth(&job, s->bottom);
        for (int y = 0; y < r.h; y++) {
            for (int x = 0; x < r.w; x++) {
                int32_t b = s->bottom[(int64_t)y * r.w + x];
                if (b == COLLIDER_BOTTOM_NONE)
                    continue;
                int wx = r.x + x, wy = r.y + y;
                int32_t h = world_height_at(w, wx, wy);
                if (b >= h)
                    continue;
                int64_t pen = (int64_t)h - b;
                out->volume += pen;
                out->cells++;
                if (pen > deepest) { /* row-major scan: ties keep the lowest row, column */
                    deepest = pen;
                    out->deepest[0] = (float)((wx + 0.5) * cs);
                    out->deepest[1] = (float)((wy + 0.5) * cs);
                    out->deepest[2] = (float)((double)b / w->units_per_m);
                }
                double gx = (height_m(w, wx + 1, wy) - height_m(w, wx - 1, wy)) / (2 * cs);
                double gy = (height_m(w, wx, wy + 1) - height_m(w, wx, wy - 1)) / (2 * cs);
                double len = sqrt(gx * gx + gy * gy + 1.0);
                nx += -gx / len;
                ny += -gy / len;
                nz += 1.0 / len;
            }
        }
    }
    if (out->cells == 0) {
        double gx = (height_m(w, cx + 1, cy) - height_m(w, cx - 1, cy)) / (2 * cs);
        double gy = (height_m(w, cx, cy + 1) - height_m(w, cx, cy - 1)) / (2 * cs);
        nx = -gx;
        ny = -gy;
        nz = 1.0;
        out->deepest[0] = (float)c->pose.position.x;
        out->deepest[1] = (float)c->pose.position.y;
        out->deepest[2] = NAN; /* filled with the support height after the tick */
    }
    double len = sqrt(nx * nx + ny * ny + nz * nz);
    out->normal[0] = (float)(nx / len);
    out->normal[1] = (float)(ny / len);
    out->normal[2] = (float)(nz / len);
    out->area_m2 = (float)(out->cells * cs * cs);
}

static void contacts_before_tick(service *s)
{
    s->contact_count = 0;
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (!c->feedback || !c->has_pose)
            continue;
        if (grow_array((void **)&s->contacts, &s->contact_capacity, s->contact_count + 1,
                       sizeof *s->contacts) != 0)
            return;
        contact_measure(s, c, &s->contacts[s->contact_count].contact);
        s->contacts[s->contact_count++].client = c->client;
    }
}

static void contacts_after_tick(service *s)
{
    const world *w = s->world;
    for (int i = 0; i < s->contact_count; i++) {
        terrad_contact *ct = &s->contacts[i].contact;
        int k = find_collider(s, ct->id);
        if (k < 0)
            continue;
        const collider_pose *p = &s->colliders[k].pose;
        int cx = (int)floor(p->position.x / w->cell_size_m);
        int cy = (int)floor(p->position.y / w->cell_size_m);
        ct->support_height_m = (float)height_m(w, cx, cy);
        if (isnan(ct->deepest[2]))
            ct->deepest[2] = ct->support_height_m;
    }
}

/* ---- deltas ---- */

static int compare_pieces(const void *a, const void *b)
{
    const tile_piece *p = a, *q = b;
    if (p->tile != q->tile)
        return (p->tile > q->tile) - (p->tile < q->tile);
    return (p->window > q->window) - (p->window < q->window);
}

static int cut_into_tiles(service *s, const sim_tick_report *report)
{
    s->piece_count = 0;
    for (int d = 0; d < report->dirty_count; d++) {
        world_rect r = report->dirty[d];
        int tx0 = r.x / SERVICE_TILE_SIZE, tx1 = (r.x + r.w - 1) / SERVICE_TILE_SIZE;
        int ty0 = r.y / SERVICE_TILE_SIZE, ty1 = (r.y + r.h - 1) / SERVICE_TILE_SIZE;
        for (int ty = ty0; ty <= ty1; ty++) {
            for (int tx = tx0; tx <= tx1; tx++) {
                world_rect tile = {tx * SERVICE_TILE_SIZE, ty * SERVICE_TILE_SIZE,
                                   SERVICE_TILE_SIZE, SERVICE_TILE_SIZE};
                int x0 = r.x > tile.x ? r.x : tile.x, y0 = r.y > tile.y ? r.y : tile.y;
                int x1 = r.x + r.w < tile.x + tile.w ? r.x + r.w : tile.x + tile.w;
                int y1 = r.y + r.h < tile.y + tile.h ? r.y + r.h : tile.y + tile.h;
                if (grow_array((void **)&s->pieces, &s->piece_capacity, s->piece_count + 1,
                               sizeof *s->pieces) != 0)
                    return -1;
                s->pieces[s->piece_count++] =
                    (tile_piece){ty * s->tiles_x + tx, report->dirty_window[d],
                                 (world_rect){x0, y0, x1 - x0, y1 - y0}};
            }
        }
    }
    if (s->piece_count > 1)
        qsort(s->pieces, (size_t)s->piece_count, sizeof *s->pieces, compare_pieces);
    return 0;
}

/* Encode one rectangle's values into a single-rectangle DELTA frame. */
static hub_frame *encode_rect_frame(service *s, terrad_rect *rect, const int32_t *values)
{
    size_t cells = (size_t)rect->w * rect->h, len = 0;
    if (terrad_rect_compress(s->codec, values, cells, s->packed, s->packed_cap, &len) != 0)
        return NULL;
    rect->data = s->packed;
    rect->data_len = (uint32_t)len;
    size_t size = terrad_delta_size(rect, 1);
    hub_frame *f = hub_frame_new(1, size);
    if (!f)
        return NULL;
    if (terrad_delta_encode(f->data, size, &f->len, s->tick, rect, 1) != 0) {
        hub_frame_unref(f);
        return NULL;
    }
    return f;
}

/* Combine the pieces of each tile, advance its version, encode, publish. */
static void publish_deltas(service *s, service_tick_stats *stats)
{
    int i = 0;
    while (i < s->piece_count) {
        int tile = s->pieces[i].tile, j = i;
        world_rect box = s->pieces[i].rect;
        while (j < s->piece_count && s->pieces[j].tile == tile) {
            box = world_rect_union(box, s->pieces[j].rect);
            j++;
        }
        memset(s->values, 0, (size_t)box.w * box.h * sizeof *s->values);
        int64_t change = 0;
        int any = 0;
        for (int k = i; k < j; k++) {
            const int32_t *before, *after;
            world_rect win = sim_engine_window(s->engine, s->pieces[k].window, &before, &after);
            world_rect p = s->pieces[k].rect;
            for (int y = p.y; y < p.y + p.h; y++) {
                for (int x = p.x; x < p.x + p.w; x++) {
                    int64_t at = (int64_t)(y - win.y) * win.w + (x - win.x);
                    int32_t d = after[at] - before[at];
                    s->values[(y - box.y) * box.w + (x - box.x)] = d;
                    change += d;
                    any |= d != 0;
                }
            }
        }
        if (any) {
            uint32_t base = s->tile_versions[tile];
            s->tile_versions[tile] = base + 1;
            terrad_rect rect = {.x = box.x,
                                .y = box.y,
                                .w = (uint16_t)box.w,
                                .h = (uint16_t)box.h,
                                .base_version = base,
                                .new_version = base + 1,
                                .encoding = TERRAD_ENC_DELTA};
            hub_frame *f = encode_rect_frame(s, &rect, s->values);
            if (f) {
                stats->delta_frames++;
                stats->delta_raw_bytes += (uint64_t)box.w * box.h * 4;
                stats->delta_compressed_bytes += rect.data_len;
                queue_out(s, (hub_out){.kind = HUB_OUT_TILE_DELTA,
                                       .tile_x = tile % s->tiles_x,
                                       .tile_y = tile / s->tiles_x,
                                       .tick = s->tick,
                                       .frame = f});
            }
        }
        s->volume += change;
        i = j;
    }
}

/* Send the rectangles [first, first + count) as one DELTA frame to a client. */
static void send_snapshot_frame(service *s, uint32_t client, const terrad_rect *rects, int count,
                                int done)
{
    size_t size = terrad_delta_size(rects, (size_t)count);
    hub_frame *f = hub_frame_new(1, size);
    if (f && terrad_delta_encode(f->data, size, &f->len, s->tick, rects, (size_t)count) == 0)
        queue_out(s, (hub_out){.kind = HUB_OUT_CLIENT,
                               .client = client,
                               .snapshot_done = done,
                               .tick = s->tick,
                               .frame = f});
    else if (f)
        hub_frame_unref(f);
}

/* Snapshot rectangles, one per tile ∩ subscription, packed into frames under
 * the size limit; the last frame of a request carries snapshot_done (an
 * empty request still sends an empty frame with the mark). */
static void publish_snapshot(service *s, const snapshot_job *job)
{
    world_rect r = job->rect;
    int tiles = 0;
    if (r.w > 0 && r.h > 0)
        tiles = ((r.x + r.w - 1) / SERVICE_TILE_SIZE - r.x / SERVICE_TILE_SIZE + 1) *
                ((r.y + r.h - 1) / SERVICE_TILE_SIZE - r.y / SERVICE_TILE_SIZE + 1);
    terrad_rect *rects = calloc((size_t)tiles + 1, sizeof *rects);
    uint8_t **datas = calloc((size_t)tiles + 1, sizeof *datas);
    int count = 0;
    if (!rects || !datas)
        goto done;
    for (int ty = r.y / SERVICE_TILE_SIZE; tiles && ty <= (r.y + r.h - 1) / SERVICE_TILE_SIZE;
         ty++) {
        for (int tx = r.x / SERVICE_TILE_SIZE; tx <= (r.x + r.w - 1) / SERVICE_TILE_SIZE; tx++) {
            int x0 = r.x > tx * SERVICE_TILE_SIZE ? r.x : tx * SERVICE_TILE_SIZE;
            int y0 = r.y > ty * SERVICE_TILE_SIZE ? r.y : ty * SERVICE_TILE_SIZE;
            int x1 =
                r.x + r.w < (tx + 1) * SERVICE_TILE_SIZE ? r.x + r.w : (tx + 1) * SERVICE_TILE_SIZE;
            int y1 =
                r.y + r.h < (ty + 1) * SERVICE_TILE_SIZE ? r.y + r.h : (ty + 1) * SERVICE_TILE_SIZE;
            world_rect piece = {x0, y0, x1 - x0, y1 - y0};
            world_gather_window(s->world, piece, s->values);
            size_t len = 0;
            if (terrad_rect_compress(s->codec, s->values, (size_t)piece.w * piece.h, s->packed,
                                     s->packed_cap, &len) != 0 ||
                !(datas[count] = malloc(len ? len : 1)))
                continue;
            memcpy(datas[count], s->packed, len);
            rects[count] = (terrad_rect){.x = piece.x,
                                         .y = piece.y,
                                         .w = (uint16_t)piece.w,
                                         .h = (uint16_t)piece.h,
                                         .base_version = 0,
                                         .new_version = s->tile_versions[ty * s->tiles_x + tx],
                                         .encoding = TERRAD_ENC_SNAPSHOT,
                                         .data_len = (uint32_t)len,
                                         .data = datas[count]};
            count++;
        }
    }
    int first = 0;
    size_t size = TERRAD_DELTA_FIXED;
    for (int i = 0; i < count; i++) {
        size_t add = TERRAD_RECT_FIXED + rects[i].data_len;
        if (i > first && (size + add > SERVICE_FRAME_MAX || i - first == TERRAD_MAX_COUNT)) {
            send_snapshot_frame(s, job->client, rects + first, i - first, 0);
            first = i;
            size = TERRAD_DELTA_FIXED;
        }
        size += add;
    }
    if (count > first || job->last)
        send_snapshot_frame(s, job->client, rects + first, count - first, job->last);
done:
    for (int i = 0; datas && i < count; i++)
        free(datas[i]);
    free(rects);
    free(datas);
}

static void publish_feedback(service *s)
{
    for (int c = 0; c < s->client_count; c++) {
        svc_client *cl = &s->clients[c];
        int n = 0;
        for (int i = 0; i < s->contact_count; i++)
            n += s->contacts[i].client == cl->id;
        if (n > 0) {
            terrad_contact *mine = malloc((size_t)n * sizeof *mine);
            if (mine) {
                int k = 0;
                for (int i = 0; i < s->contact_count; i++)
                    if (s->contacts[i].client == cl->id)
                        mine[k++] = s->contacts[i].contact;
                size_t size = terrad_contact_size((size_t)n);
                hub_frame *f = hub_frame_new(1, size);
                if (f &&
                    terrad_contact_encode(f->data, size, &f->len, s->tick, mine, (size_t)n) == 0)
                    queue_out(s, (hub_out){.kind = HUB_OUT_CLIENT,
                                           .client = cl->id,
                                           .tick = s->tick,
                                           .frame = f});
                else if (f)
                    hub_frame_unref(f);
                free(mine);
            }
        }
        if (cl->sequence_pending) {
            hub_frame *f = hub_frame_new(1, TERRAD_ACK_SIZE);
            if (f && terrad_ack_encode(f->data, TERRAD_ACK_SIZE, &f->len, s->tick,
                                       cl->last_sequence) == 0)
                queue_out(
                    s, (hub_out){
                           .kind = HUB_OUT_CLIENT, .client = cl->id, .tick = s->tick, .frame = f});
            else if (f)
                hub_frame_unref(f);
            cl->sequence_pending = 0;
        }
    }
}

/* ---- COLLIDERS: where every collider is, for the viewer ---- */

/* The drawable description of a collider, in the sim's frame (capsule and
 * cylinder axes along y, as PROTOCOL.md's COLLIDERS says). */
static terrad_collider_state collider_state(const collider_geometry *g, collider_pose pose,
                                            uint32_t id, uint8_t owner)
{
    terrad_collider_state st = {.id = id, .owner = owner};
    switch (g->shape) {
    case COLLIDER_SPHERE:
        st.kind = TERRAD_KIND_SPHERE;
        st.dims[0] = (float)g->radius;
        break;
    case COLLIDER_BOX:
        st.kind = TERRAD_KIND_BOX;
        st.dims[0] = (float)g->half_extents.x;
        st.dims[1] = (float)g->half_extents.y;
        st.dims[2] = (float)g->half_extents.z;
        break;
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER:
        st.kind = g->shape == COLLIDER_CAPSULE ? TERRAD_KIND_CAPSULE : TERRAD_KIND_CYLINDER;
        st.dims[0] = (float)g->radius;
        st.dims[1] = (float)g->half_length;
        break;
    case COLLIDER_MESH:
        st.kind = TERRAD_KIND_MESH;
        for (int v = 0; g->mesh && v < g->mesh->vertex_count; v++)
            for (int k = 0; k < 3; k++) {
                float a = fabsf(g->mesh->vertices[3 * v + k]);
                if (a > st.dims[k])
                    st.dims[k] = a;
            }
        break;
    }
    st.p[0] = (float)pose.position.x;
    st.p[1] = (float)pose.position.y;
    st.p[2] = (float)pose.position.z;
    quatd q = quat_normalize(pose.orientation);
    st.q[0] = (float)q.w;
    st.q[1] = (float)q.x;
    st.q[2] = (float)q.y;
    st.q[3] = (float)q.z;
    return st;
}

/* Does the collider's footprint meet one of the client's collider-subscriptions? */
static int collider_in_view(const service *s, const svc_client *cl, const collider_geometry *g,
                            collider_pose pose)
{
    vec3d lo, hi;
    collider_bounds(g, pose, &lo, &hi);
    double cs = s->world->cell_size_m;
    double x0 = floor(lo.x / cs), y0 = floor(lo.y / cs), x1 = floor(hi.x / cs),
           y1 = floor(hi.y / cs);
    for (int i = 0; i < cl->sub_count; i++) {
        const world_rect r = cl->subs[i].rect;
        if (cl->subs[i].colliders && x1 >= r.x && x0 < (double)r.x + r.w && y1 >= r.y &&
            y0 < (double)r.y + r.h)
            return 1;
    }
    return 0;
}

static int push_state(service *s, int *n, terrad_collider_state st)
{
    if (*n >= TERRAD_MAX_COUNT ||
        grow_array((void **)&s->states, &s->state_capacity, *n + 1, sizeof *s->states) != 0)
        return -1;
    s->states[(*n)++] = st;
    return 0;
}

/* FNV-1a over the encoded entries: "did anything change since the last frame". */
static uint64_t states_hash(const uint8_t *p, size_t len)
{
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < len; i++)
        h = (h ^ p[i]) * 1099511628211ull;
    return h | 1; /* never 0: 0 means "nothing sent yet" */
}

/* Per client that asked for it: the colliders meeting its regions, when the
 * list changed (at most every COLLIDERS_EVERY_TICKS ticks) or has not been
 * sent for COLLIDERS_REFRESH_TICKS. */
static void publish_colliders(service *s, const sim_collider *extra, int extra_count)
{
    for (int c = 0; c < s->client_count; c++) {
        svc_client *cl = &s->clients[c];
        int wants = 0;
        for (int i = 0; i < cl->sub_count; i++)
            wants |= cl->subs[i].colliders;
        if (!wants)
            continue;
        uint64_t since = s->tick - cl->colliders_sent_tick;
        if (cl->colliders_hash != 0 && since < COLLIDERS_EVERY_TICKS)
            continue;
        int n = 0;
        for (int i = 0; i < s->collider_count; i++) {
            const svc_collider *k = &s->colliders[i];
            if (k->has_pose && collider_in_view(s, cl, k->geometry, k->pose))
                push_state(
                    s, &n,
                    collider_state(k->geometry, k->pose, k->id,
                                   k->client == cl->id ? TERRAD_OWNER_OWN : TERRAD_OWNER_OTHER));
        }
        for (int i = 0; i < extra_count; i++)
            if (collider_in_view(s, cl, extra[i].geometry, extra[i].pose))
                push_state(s, &n,
                           collider_state(extra[i].geometry, extra[i].pose, (uint32_t)extra[i].id,
                                          TERRAD_OWNER_DEMO));
        size_t size = terrad_colliders_size((size_t)n);
        hub_frame *f = hub_frame_new(1, size);
        if (!f)
            continue;
        if (terrad_colliders_encode(f->data, size, &f->len, s->tick, s->states, (size_t)n) != 0) {
            hub_frame_unref(f);
            continue;
        }
        uint64_t h = states_hash(f->data + TERRAD_COLLIDERS_FIXED, f->len - TERRAD_COLLIDERS_FIXED);
        if (h == cl->colliders_hash && since < COLLIDERS_REFRESH_TICKS) {
            hub_frame_unref(f);
            continue;
        }
        cl->colliders_hash = h;
        cl->colliders_sent_tick = s->tick;
        queue_out(s,
                  (hub_out){.kind = HUB_OUT_CLIENT, .client = cl->id, .tick = s->tick, .frame = f});
    }
}

/* ---- FOOTPRINTS: the decals model's events, for cheap visuals ---- */

/* Is the event's centre inside one of the client's footprint-subscriptions? */
static int footprint_in_view(const service *s, const svc_client *cl, const sim_footprint *e)
{
    double cs = s->world->cell_size_m;
    double cx = floor(e->x_m / cs), cy = floor(e->y_m / cs);
    for (int i = 0; i < cl->sub_count; i++) {
        const world_rect r = cl->subs[i].rect;
        if (cl->subs[i].footprints && cx >= r.x && cx < (double)r.x + r.w && cy >= r.y &&
            cy < (double)r.y + r.h)
            return 1;
    }
    return 0;
}

static terrad_footprint footprint_wire(const sim_footprint *e)
{
    terrad_footprint f = {.collider = (uint32_t)e->collider_id,
                          .x = (float)e->x_m,
                          .y = (float)e->y_m,
                          .yaw = (float)e->yaw_rad,
                          .size_m = (float)e->size_m,
                          .strength_m = (float)e->strength_m};
    /* atan2 is within [-pi, pi] in double; keep the f32 inside the wire's bound */
    if (f.yaw > TERRAD_FOOTPRINT_YAW_MAX)
        f.yaw = TERRAD_FOOTPRINT_YAW_MAX;
    if (f.yaw < -TERRAD_FOOTPRINT_YAW_MAX)
        f.yaw = -TERRAD_FOOTPRINT_YAW_MAX;
    return f;
}

/* One frame of n events; a frame built earlier this tick with the same bytes
 * is shared (one more reference) rather than built again. */
static hub_frame *footprints_frame(service *s, int n, hub_frame **shared, int *shared_count)
{
    size_t size = terrad_footprints_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (!f)
        return NULL;
    if (terrad_footprints_encode(f->data, size, &f->len, s->tick, s->events, (size_t)n) != 0) {
        /* the sim's events are finite with size and strength > 0: never here */
        log_error("service: tick %llu: a footprint event failed its wire checks",
                  (unsigned long long)s->tick);
        hub_frame_unref(f);
        return NULL;
    }
    for (int i = 0; i < *shared_count; i++)
        if (shared[i]->len == f->len && memcmp(shared[i]->data, f->data, f->len) == 0) {
            hub_frame_unref(f);
            hub_frame_ref(shared[i]);
            return shared[i];
        }
    if (*shared_count < FOOTPRINTS_SHARED_MAX)
        shared[(*shared_count)++] = f; /* borrowed: the queue holds the reference */
    return f;
}

/* Per client that asked for them: this tick's events whose centre lies in one
 * of its footprint-subscriptions; no frame when there are none. */
static void publish_footprints(service *s, const sim_tick_report *report)
{
    if (report->footprint_count <= 0)
        return;
    hub_frame *shared[FOOTPRINTS_SHARED_MAX];
    int shared_count = 0;
    for (int c = 0; c < s->client_count; c++) {
        const svc_client *cl = &s->clients[c];
        int wants = 0;
        for (int i = 0; i < cl->sub_count; i++)
            wants |= cl->subs[i].footprints;
        if (!wants)
            continue;
        int n = 0;
        for (int i = 0; i < report->footprint_count; i++) {
            const sim_footprint *e = &report->footprints[i];
            if (!footprint_in_view(s, cl, e))
                continue;
            if (grow_array((void **)&s->events, &s->event_capacity, n + 1, sizeof *s->events) != 0)
                break;
            s->events[n++] = footprint_wire(e);
            if (n == FOOTPRINTS_PER_FRAME) {
                hub_frame *f = footprints_frame(s, n, shared, &shared_count);
                if (f)
                    queue_out(s, (hub_out){.kind = HUB_OUT_CLIENT,
                                           .client = cl->id,
                                           .tick = s->tick,
                                           .frame = f});
                n = 0;
            }
        }
        if (n > 0) {
            hub_frame *f = footprints_frame(s, n, shared, &shared_count);
            if (f)
                queue_out(
                    s, (hub_out){
                           .kind = HUB_OUT_CLIENT, .client = cl->id, .tick = s->tick, .frame = f});
        }
    }
}

int service_tick(service *s, const sim_collider *extra, int extra_count, service_tick_stats *stats,
                 error_text *err)
{
    double t0 = time_now_ms();
    memset(stats, 0, sizeof *stats);
    s->tick++;
    int n = hub_take_commands(s->hub, s->commands, SERVICE_COMMANDS_PER_TICK);
    for (int i = 0; i < n; i++)
        apply_command(s, &s->commands[i]);
    if (grow_array((void **)&s->poses, &s->pose_capacity, s->collider_count + 64,
                   sizeof *s->poses) == 0)
        apply_poses(s, hub_take_poses(s->hub, s->poses, s->pose_capacity));
    apply_batches(s);

    contacts_before_tick(s);

    if (grow_array((void **)&s->sim_colliders, &s->sim_capacity,
                   s->collider_count + extra_count + 1, sizeof *s->sim_colliders) != 0) {
        error_set(err, "service: out of memory for %d colliders", s->collider_count + extra_count);
        return -1;
    }
    int count = 0;
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (!c->has_pose)
            continue;
        s->sim_colliders[count++] = (sim_collider){.id = (int)c->id,
                                                   .geometry = c->geometry,
                                                   .pose = c->pose,
                                                   .previous_pose = c->previous_pose,
                                                   .has_previous = c->has_previous};
    }
    if (extra_count > 0)
        memcpy(s->sim_colliders + count, extra, (size_t)extra_count * sizeof *extra);
    count += extra_count;
    if (s->store && !store_writable(s->store)) {
        memset(&stats->report, 0, sizeof stats->report); /* no deformation that cannot be kept */
    } else {
        if (sim_engine_tick(s->engine, s->sim_colliders, count, &stats->report, err) != 0)
            return -1;
        if (s->store && store_commit_tick(s->store, s->world, s->tick, stats->report.dirty,
                                          stats->report.dirty_count) != 0)
            undo_tick(s, &stats->report);
    }
    for (int i = 0; i < s->collider_count; i++) {
        s->colliders[i].previous_pose = s->colliders[i].pose;
        s->colliders[i].has_previous = s->colliders[i].has_pose;
    }

    /* s->out may still hold earlier ticks' frames waiting for a group commit */
    if (cut_into_tiles(s, &stats->report) == 0)
        publish_deltas(s, stats);
    contacts_after_tick(s);
    publish_feedback(s);
    publish_colliders(s, extra, extra_count);
    publish_footprints(s, &stats->report);
    for (int i = 0; i < s->snapshot_count; i++)
        publish_snapshot(s, &s->snapshots[i]);
    s->snapshot_count = 0;
    queue_out(s, (hub_out){.kind = HUB_OUT_TICK_DONE, .tick = s->tick});
    /* nothing of a tick reaches a client before the store has made it durable */
    if (!s->store || store_settle(s->store)) {
        int dropped = hub_publish(s->hub, s->out, s->out_count);
        /* from the oldest pose this tick used to its deltas being handed to the network */
        if (s->oldest_pose_ms > 0)
            metrics_observe_pose_to_delta_ms(time_now_ms() - s->oldest_pose_ms);
        if (dropped)
            metrics_count_frames_dropped((uint64_t)dropped);
        s->out_count = 0;
    }
    if (s->store)
        tell_store_state(s);
    hub_serve_reads(s->hub, s->world, s->tick);

    stats->clients = s->client_count;
    stats->colliders = s->collider_count + extra_count;
    stats->tick_ms = time_now_ms() - t0;
    if (stats->delta_raw_bytes)
        metrics_count_delta_bytes(stats->delta_raw_bytes, stats->delta_compressed_bytes);
    return 0;
}
