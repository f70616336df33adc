/*
 * net_requests.c: what a client may ask for (PROTOCOL.md "Control messages",
 * "POSE_BATCH"), the middle layer of the net thread (see net_client_internal.h).
 *
 * Every request is either refused with one error to its sender (and a
 * metric), or turned into a hub command / hub pose and answered at once.
 * The sim never sees a bad value: net_control.c settles shapes, sizes,
 * meshes, poses and rectangles; this file settles what depends on the
 * client — hello once, its limits, ownership — and applies the request.
 */
#include "net/net_requests_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "net/net_control_internal.h"
#include "terrad_proto.h"

/* ---- replies ---- */

static cJSON *reply(const char *type, const cJSON *ref)
{
    cJSON *r = cJSON_CreateObject();
    cJSON_AddStringToObject(r, "type", type);
    cJSON_AddItemToObject(r, "ref", net_ref_copy(ref));
    return r;
}

/* The ref as JSON text for hub_command.ref ("" if none or too long). */
static void ref_text(const cJSON *ref, char *out, size_t cap)
{
    out[0] = 0;
    if (!ref)
        return;
    char *t = cJSON_PrintUnformatted(ref);
    if (t && strlen(t) < cap)
        memcpy(out, t, strlen(t) + 1);
    free(t);
}

/* ---- hello ---- */

static cJSON *world_message(net_state *s, const net_client *c)
{
    const net_world_info *w = &s->cfg.world;
    const net_limits *l = &s->cfg.limits;
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "world");
    cJSON_AddNumberToObject(m, "protocol", TERRAD_PROTO_VERSION);
    cJSON_AddStringToObject(m, "server", s->cfg.server_name); /* the lobby's, shared */
    if (w->name) /* a named world: none for a single daemon's default world, as always */
        cJSON_AddStringToObject(m, "world", w->name);
    cJSON_AddNumberToObject(m, "client_id", c->id);
    cJSON_AddStringToObject(m, "role", auth_role_name(c->role));
    cJSON_AddNumberToObject(m, "budget", net_budget_rate(c)); /* bytes/s in force, 0: none */
    cJSON_AddNumberToObject(m, "width", w->width);
    cJSON_AddNumberToObject(m, "height", w->height);
    cJSON_AddNumberToObject(m, "cell_size_m", w->cell_size_m);
    cJSON_AddNumberToObject(m, "units_per_m", w->units_per_m);
    cJSON *range = cJSON_AddArrayToObject(m, "height_range");
    cJSON_AddItemToArray(range, cJSON_CreateNumber(w->height_min));
    cJSON_AddItemToArray(range, cJSON_CreateNumber(w->height_max));
    cJSON_AddNumberToObject(m, "tick_hz", w->tick_hz);
    cJSON_AddStringToObject(m, "clock", w->client_clock ? "client" : "wall");
    if (w->client_clock)
        cJSON_AddNumberToObject(m, "driver", s->driver);
    cJSON_AddNumberToObject(m, "tick", (double)s->tick);
    cJSON_AddNumberToObject(m, "tile_size", w->tile_size);
    cJSON_AddItemToObject(m, "models", cJSON_Duplicate(s->models, 1));
    cJSON_AddItemToObject(m, "materials", cJSON_Duplicate(s->materials, 1));
    static const char *const shapes[] = {"sphere", "box", "capsule", "cylinder", "wheel", "mesh"};
    cJSON_AddItemToObject(m, "shapes", cJSON_CreateStringArray(shapes, 6));
    if (c->snapshot_base) /* asked for and possible: the twin config to rebuild the base */
        cJSON_AddItemToObject(m, "base", cJSON_Duplicate(s->base, 1));
    cJSON *lim = cJSON_AddObjectToObject(m, "limits");
    for (const net_limit_spec *t = net_limit_table; t->name; t++) /* net_limits.c */
        if (t->flags & NET_LIMIT_TOLD)
            cJSON_AddNumberToObject(lim, t->name, net_limit_get(l, t));
    return m;
}

static void handle_hello(net_client *c, const net_control *m)
{
    net_state *s = c->srv;
    if (net_auth_hello(c, m->token, m->ref) != 0)
        return;
    const char *draining = net_draining(s);
    if (draining) { /* a load balancer that has not yet seen /readyz fail sent it here */
        net_error(c, TERRAD_E_SHUTTING_DOWN, m->ref, -1, 1,
                  "hello: this server is draining (%s) and takes no new clients: connect to "
                  "another",
                  draining);
        net_close_after_flush(c, 4000 + TERRAD_E_SHUTTING_DOWN, "draining");
        return;
    }
    char why[400];
    if (s->lobby && net_client_join_world(c, m->world, why, sizeof why) != 0) {
        /* a cluster node serves the worlds it owns: the client is sent to another node */
        net_error(c, TERRAD_E_BAD_VALUE, m->ref, -1, 1, "%s", why);
        net_close_after_flush(c, 4000 + TERRAD_E_BAD_VALUE, "another world");
        return;
    }
    s = c->srv; /* the world's own state from here on */
    /* its budget: stated, else the daemon's default (else the limit, if any);
     * the relay, which holds its socket, keeps it for a relayed world */
    double budget = m->budget >= 0 ? (double)m->budget : s->cfg.limits.default_budget_bytes_per_s;
    if (m->budget < 0 && budget <= 0)
        budget = s->cfg.limits.max_budget_bytes_per_s;
    if (budget > 0 && !c->budget && net_budget_start(c, budget) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0, "hello: out of memory for its budget");
        return;
    }
    if (s->relay) { /* its owner answers the hello (net_handle_text forwards it) */
        c->ready = 1;
        lws_set_timer_usecs(c->wsi, LWS_SET_TIMER_USEC_CANCEL);
        snprintf(c->name, sizeof c->name, "%s", m->client);
        log_info("net: client %u (%s) said hello for world %s, served through its owner", c->id,
                 c->peer, s->world_name);
        return;
    }
    c->ready = 1;
    if (c->wsi)
        lws_set_timer_usecs(c->wsi, LWS_SET_TIMER_USEC_CANCEL);
    snprintf(c->name, sizeof c->name, "%s", m->client);
    for (char *p = c->name; *p; p++) /* for log lines */
        if ((unsigned char)*p < 0x20 || *p == 0x7f)
            *p = '?';
    /* base snapshots (PROTOCOL.md): only where the twin can rebuild the base */
    c->snapshot_base = m->snapshot_base && s->base != NULL ? 1 + (m->snapshot_slope != 0) : 0;
    cJSON *w = world_message(s, c);
    if (m->snapshot_base)
        cJSON_AddBoolToObject(w, "snapshot_base", c->snapshot_base != 0);
    if (m->snapshot_slope) /* slope snapshots: only with base snapshots (PROTOCOL.md) */
        cJSON_AddBoolToObject(w, "snapshot_slope", c->snapshot_base == 2);
    cJSON_AddItemToObject(w, "ref", net_ref_copy(m->ref));
    net_send_json(c, w);
    hub_command cmd = {
        .kind = HUB_CLIENT_JOINED, .client = c->id, .snapshot_base = c->snapshot_base};
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    net_push_must(s, &cmd);
    if (auth_enabled(s->auth))
        log_info("net: client %u (%s) said hello as \"%s\", token \"%s\" (role %s)", c->id, c->peer,
                 c->name, c->auth_name, auth_role_name(c->role));
    else
        log_info("net: client %u (%s) said hello as \"%s\"", c->id, c->peer, c->name);
}

/* ---- collider_create ---- */

/* Refuse a collider that would take its client past a cost budget; 1 when refused. */
static int over_budget(net_client *c, const net_control *m, int64_t cells, int triangles)
{
    const net_limits *l = &c->srv->cfg.limits;
    if (c->active_cells + cells > l->max_active_cells) {
        net_error(c, TERRAD_E_LIMIT_COLLIDERS, m->ref, -1, 0,
                  "collider_create: its cost of %lld cells (its window, a pose's depth, "
                  "feedback's) would take this client's colliders "
                  "to %lld active cells, over max_active_cells (%lld)",
                  (long long)cells, (long long)(c->active_cells + cells),
                  (long long)l->max_active_cells);
        return 1;
    }
    if (c->mesh_triangles + triangles > l->max_mesh_triangles) {
        net_error(c, TERRAD_E_LIMIT_COLLIDERS, m->ref, -1, 0,
                  "collider_create: %d triangles would take this client's meshes to %lld, over "
                  "max_mesh_triangles (%d)",
                  triangles, (long long)(c->mesh_triangles + triangles), l->max_mesh_triangles);
        return 1;
    }
    return 0;
}

/* Takes over m->mesh. */
static void handle_collider_create(net_client *c, net_control *m)
{
    net_state *s = c->srv;
    collider_geometry g = m->geometry; /* the mesh may still be the message's */
    g.mesh = m->mesh ? m->mesh : m->geometry.mesh;
    /* one pose at rest, its feedback included: the sweep is charged per tick (service_shed.c) */
    collider_cost cost = collider_cost_of(&g, s->cfg.world.cell_size_m);
    int64_t cells = collider_cost_cells(&cost, 1, m->feedback);
    const collider_mesh *mesh = g.mesh;
    int triangles = m->geometry.shape == COLLIDER_MESH && mesh ? mesh->triangle_count : 0;
    if (over_budget(c, m, cells, triangles)) {
        metrics_count_budget_refusal();
        return;
    }
    uint32_t id = s->next_collider_id;
    if (id == 0 || net_collider_insert(s, id, c->id, m->axis_z) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0,
                  id == 0 ? "collider ids exhausted" : "out of memory");
        return;
    }
    hub_command cmd;
    memset(&cmd, 0, sizeof cmd);
    cmd.kind = HUB_COLLIDER_CREATE;
    cmd.client = c->id;
    cmd.collider = id;
    cmd.geometry = m->geometry;
    cmd.mesh = m->mesh;
    cmd.pose = m->pose;
    snprintf(cmd.material, sizeof cmd.material, "%s", m->material);
    cmd.feedback = m->feedback;
    cmd.load_n = m->load_n;
    cmd.forces_height = m->forces_height;
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    int grown = array_grow((void **)&c->colliders, &c->collider_capacity,
                           (int64_t)c->collider_count + 1, sizeof *c->colliders) == 0;
    if (!grown || net_push_refusable(s, &cmd) != 0) {
        net_collider_remove(s, id);
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0,
                  grown ? "server busy: the simulation's command queue is full, try again"
                        : "out of memory");
        return; /* the mesh stays m's */
    }
    m->mesh = NULL; /* the command's, then the sim's */
    m->geometry.mesh = NULL;
    c->colliders[c->collider_count++] = id;
    s->next_collider_id = id + 1;
    net_collider_slot *slot = net_collider_find(s, id);
    if (slot) {
        slot->cells = cells;
        slot->triangles = triangles;
    }
    c->active_cells += cells;
    c->mesh_triangles += triangles;
    cJSON *rep = reply("collider_created", m->ref);
    cJSON_AddNumberToObject(rep, "id", id);
    net_send_json(c, rep);
}

/* ---- collider_delete ---- */

/* The slot of one of c's colliders (any client's when any_owner), or NULL
 * after an error was sent. */
static net_collider_slot *owned(net_client *c, uint32_t id, const cJSON *ref)
{
    return net_collider_owned(c, id, ref, 0);
}

/* With "any_owner" (an admin's, refused for other roles before this) another
 * client's collider is deleted in its owner's name (the sim removes a collider
 * for its owner only); the owner's budgets get it back. */
static void handle_collider_delete(net_client *c, const net_control *m)
{
    uint32_t id = m->id;
    net_collider_slot *slot = net_collider_owned(c, id, m->ref, m->any_owner);
    if (!slot)
        return;
    int64_t cells = slot->cells;
    int triangles = slot->triangles;
    net_client *owner = slot->owner == c->id ? c : net_find_client(c->srv, slot->owner);
    hub_command cmd = {.kind = HUB_COLLIDER_DELETE, .client = slot->owner, .collider = id};
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(c->srv, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, id, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    net_collider_remove(c->srv, id);
    hub_forget_pose(c->srv->hub, id);
    if (owner) {
        if (owner != c)
            log_info("net: client %u (admin \"%s\") deleted collider %u of client %u", c->id,
                     c->auth_name, id, owner->id);
        owner->active_cells -= cells;
        owner->mesh_triangles -= triangles;
        for (int i = 0; i < owner->collider_count; i++)
            if (owner->colliders[i] == id) {
                owner->colliders[i] = owner->colliders[--owner->collider_count];
                break;
            }
    }
    cJSON *rep = reply("collider_deleted", m->ref);
    cJSON_AddNumberToObject(rep, "id", (double)id);
    net_send_json(c, rep);
}

/* ---- subscriptions ---- */

static int sub_index(const net_client *c, uint32_t id)
{
    for (int i = 0; i < c->sub_count; i++)
        if (c->subs[i].id == id)
            return i;
    return -1;
}

static void handle_subscribe(net_client *c, const net_control *m)
{
    net_state *s = c->srv;
    const net_limits *l = &s->cfg.limits;
    world_rect rect = m->rect;
    int64_t cells = (int64_t)rect.w * rect.h;
    if (net_spectating(c)) { /* its mirror is at a past tick (PROTOCOL.md "Spectate") */
        metrics_count_spectate_refused("state");
        net_error(c, TERRAD_E_BAD_VALUE, m->ref, -1, 0,
                  "type: this connection is spectating; spectate_stop (or its spectate_end) "
                  "first, or subscribe on another connection");
        return;
    }
    if (c->sub_count >= l->max_subscriptions) {
        net_error(c, TERRAD_E_LIMIT_SUBSCRIPTIONS, m->ref, -1, 0,
                  "this client already has max_subscriptions (%d) subscriptions",
                  l->max_subscriptions);
        return;
    }
    if (c->sub_cells + cells > l->max_subscribed_cells) {
        net_error(c, TERRAD_E_LIMIT_SUBSCRIPTIONS, m->ref, -1, 0,
                  "%lld more cells would pass max_subscribed_cells (%lld; %lld subscribed)",
                  (long long)cells, (long long)l->max_subscribed_cells, (long long)c->sub_cells);
        return;
    }
    if (array_grow((void **)&c->subs, &c->sub_capacity, (int64_t)c->sub_count + 1,
                   sizeof *c->subs) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0, "out of memory");
        return;
    }
    hub_command cmd = {.kind = HUB_SUBSCRIBE,
                       .client = c->id,
                       .subscription = c->next_sub_id,
                       .rect = rect,
                       .colliders = m->colliders,
                       .grousers = m->grousers,
                       .footprints = m->footprints};
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(s, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    c->subs[c->sub_count++] = (net_sub){c->next_sub_id, rect};
    c->sub_cells += cells;
    c->snapshots_requested++; /* the sim ends the subscription's snapshot with a marker */
    cJSON *rep = reply("subscribed", m->ref);
    cJSON_AddNumberToObject(rep, "id", c->next_sub_id);
    cJSON_AddNumberToObject(rep, "x", (double)rect.x);
    cJSON_AddNumberToObject(rep, "y", (double)rect.y);
    cJSON_AddNumberToObject(rep, "w", (double)rect.w);
    cJSON_AddNumberToObject(rep, "h", (double)rect.h);
    net_send_json(c, rep);
    c->next_sub_id++;
}

static void handle_unsubscribe(net_client *c, const net_control *m)
{
    int i = sub_index(c, m->id);
    if (i < 0) {
        net_error(c, TERRAD_E_UNKNOWN_SUBSCRIPTION, m->ref, -1, 0,
                  "subscription %lld does not exist", (long long)m->id);
        return;
    }
    hub_command cmd = {
        .kind = HUB_UNSUBSCRIBE, .client = c->id, .subscription = m->id, .rect = c->subs[i].rect};
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(c->srv, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    c->sub_cells -= (int64_t)c->subs[i].rect.w * c->subs[i].rect.h;
    c->subs[i] = c->subs[--c->sub_count];
    net_budget_prune(c); /* its snapshot pieces not sent yet go with it */
    cJSON *rep = reply("unsubscribed", m->ref);
    cJSON_AddNumberToObject(rep, "id", (double)m->id);
    net_send_json(c, rep);
}

/* The edit goes to the sim with the commands; the sim answers `edited` (or
 * an error) once its tick is committed. */
static void handle_edit(net_client *c, net_control *m)
{
    hub_command cmd = {.kind = HUB_EDIT, .client = c->id, .edit = m->edit};
    ref_text(m->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(c->srv, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, m->ref, -1, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    m->edit = NULL; /* the command has it */
}

static void handle_resync(net_client *c, const net_control *m)
{
    if (m->has_id && sub_index(c, m->id) < 0) {
        if (m->tile_count)
            metrics_count_resync_refused("id");
        net_error(c, TERRAD_E_UNKNOWN_SUBSCRIPTION, m->ref, -1, 0,
                  "id: subscription %lld does not exist", (long long)m->id);
        return;
    }
    if (m->tile_count)
        net_request_resync_tiles(c, &c->subs[sub_index(c, m->id)], m->tiles, m->tile_count, m->ref);
    else
        net_request_resync(c, m->id);
}

/* seen: the latest tick the client has handled (PROTOCOL.md "seen"); judged
 * against what was written to it once a tick (net_fanout.c net_drop_stale). A
 * client waiting to catch up before its snapshots is woken when it has. */
static void handle_seen(net_client *c, const net_control *m)
{
    if (m->seen_tick > c->written_tick && m->seen_tick > c->srv->tick) {
        net_error(
            c, TERRAD_E_BAD_VALUE, m->ref, -1, 0,
            "tick: %llu is later than any tick this server has sent (%llu)",
            (unsigned long long)m->seen_tick,
            (unsigned long long)(c->written_tick > c->srv->tick ? c->written_tick : c->srv->tick));
        return;
    }
    c->seen_said = 1;
    if (m->seen_tick > c->seen_tick)
        c->seen_tick = m->seen_tick;
    net_seen_handled(c);
    if (c->slow && c->seen_wait && c->seen_tick >= c->seen_wait && c->wsi)
        lws_callback_on_writable(c->wsi);
}

/* subscribe_events (admin): the events this connection gets from now on. */
static void handle_subscribe_events(net_client *c, const net_control *m)
{
    static const char *const names[] = {NET_EVENT_NAMES};
    c->events = m->events;
    cJSON *rep = reply("events_subscribed", m->ref);
    cJSON *arr = cJSON_AddArrayToObject(rep, "events");
    for (int k = 0; k < NET_EVENT_COUNT; k++)
        if (m->events & (1u << k))
            cJSON_AddItemToArray(arr, cJSON_CreateString(names[k]));
    net_send_json(c, rep);
}

/* ---- text messages ---- */

/* A refusal that depends on the client, not on the message, and comes
 * before any problem with the request's fields; 1 when one was sent. */
static int refused_by_state(net_client *c, const net_control *m)
{
    const net_limits *l = &c->srv->cfg.limits;
    if (m->kind == NET_CONTROL_HELLO && c->ready) {
        net_error(c, TERRAD_E_BAD_VALUE, m->ref, -1, 0, "hello: already received");
        return 1;
    }
    if (m->kind == NET_CONTROL_COLLIDER_CREATE &&
        !net_auth_allows(c, AUTH_DRIVER, "collider_create", m->ref))
        return 1;
    if (m->kind == NET_CONTROL_EDIT && !net_auth_allows(c, AUTH_DRIVER, "edit", m->ref))
        return 1;
    if (m->kind == NET_CONTROL_SUBSCRIBE_EVENTS &&
        !net_auth_allows(c, AUTH_ADMIN, "subscribe_events", m->ref))
        return 1;
    if (m->kind == NET_CONTROL_COLLIDER_DELETE &&
        !net_auth_allows(c, m->any_owner ? AUTH_ADMIN : AUTH_DRIVER,
                         m->any_owner ? "collider_delete with any_owner" : "collider_delete",
                         m->ref))
        return 1;
    if (m->kind == NET_CONTROL_COLLIDER_CREATE && c->collider_count >= l->max_colliders) {
        net_error(c, TERRAD_E_LIMIT_COLLIDERS, m->ref, -1, 0,
                  "this client already has max_colliders (%d) colliders", l->max_colliders);
        return 1;
    }
    return 0;
}

/* A relay's client asks for snapshots (a subscribe the owner will answer,
 * or a resync of subscriptions it holds): the relay counts the snapshot marks
 * to come, so that it pauses the client's deltas as the owner would. */
static void relay_text(net_client *c, const net_control *m, int rc)
{
    if (rc != 0 || m->kind != NET_CONTROL_RESYNC || m->tile_count || c->sub_count == 0 ||
        (m->has_id && sub_index(c, m->id) < 0))
        return;
    c->snapshots_requested++;
    c->resync_until = c->snapshots_requested;
}

/* A resync or spectate the parser refused, counted under the field its
 * message names first ("tiles[3]: ..." under tiles); a message naming none is
 * not counted. */
static void count_refused(const char *message, void (*count)(const char *field))
{
    char field[16];
    size_t n = strcspn(message, "[:");
    if (message[n] && n < sizeof field) {
        memcpy(field, message, n);
        field[n] = 0;
        count(field);
    }
}

void net_handle_text(net_client *c, const char *text, size_t len)
{
    THREAD_OWNED(&c->srv->owner);
    net_state *s = c->srv;
    net_control_context ctx = {.limits = &s->cfg.limits,
                               .materials = s->materials,
                               .world_width = s->cfg.world.width,
                               .world_height = s->cfg.world.height,
                               .tile_size = s->cfg.world.tile_size,
                               .loads = s->cfg.world.loads};
    net_control m;
    net_control_error err;
    int rc = net_control_parse(text, len, &ctx, &m, &err);
    /* checked and answered by the world's owner; events are this node's */
    /* seen: the relay holds the client's socket and bounds its lag */
    if (s->relay && c->ready && m.kind != NET_CONTROL_SUBSCRIBE_EVENTS &&
        m.kind != NET_CONTROL_SEEN && m.kind != NET_CONTROL_FOCUS) {
        relay_text(c, &m, rc);
        net_relay_forward(c, 0, text, len);
        net_control_free(&m);
        return;
    }
    if (!c->ready && m.kind != NET_CONTROL_HELLO) {
        net_error(c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1, "the first message must be hello");
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "no hello");
    } else if (rc != 0 && !err.field) {
        net_error(c, err.code, m.ref, -1, 0, "%s", err.message);
    } else if (refused_by_state(c, &m)) {
        /* answered */
    } else if (rc != 0) {
        if (m.kind == NET_CONTROL_RESYNC)
            count_refused(err.message, metrics_count_resync_refused);
        else if (m.kind == NET_CONTROL_SPECTATE || m.kind == NET_CONTROL_SPECTATE_STEP)
            count_refused(err.message, metrics_count_spectate_refused);
        net_error(c, err.code, m.ref, -1, err.fatal, "%s", err.message);
        if (err.code == TERRAD_E_BAD_VERSION)
            net_close_after_flush(c, 4000 + TERRAD_E_BAD_VERSION, "bad protocol version");
    } else {
        switch (m.kind) {
        case NET_CONTROL_HELLO:
            handle_hello(c, &m);
            if (c->srv->relay && c->ready)
                net_relay_forward(c, 0, text, len);
            break;
        case NET_CONTROL_COLLIDER_CREATE:
            handle_collider_create(c, &m);
            break;
        case NET_CONTROL_COLLIDER_DELETE:
            handle_collider_delete(c, &m);
            break;
        case NET_CONTROL_SUBSCRIBE:
            handle_subscribe(c, &m);
            break;
        case NET_CONTROL_UNSUBSCRIBE:
            handle_unsubscribe(c, &m);
            break;
        case NET_CONTROL_RESYNC:
            handle_resync(c, &m);
            break;
        case NET_CONTROL_EDIT:
            handle_edit(c, &m);
            break;
        case NET_CONTROL_SUBSCRIBE_EVENTS:
            handle_subscribe_events(c, &m);
            break;
        case NET_CONTROL_SEEN:
            handle_seen(c, &m);
            break;
        case NET_CONTROL_SPECTATE:
            net_spectate_request(c, &m);
            break;
        case NET_CONTROL_SPECTATE_STEP:
            net_spectate_step(c, &m);
            break;
        case NET_CONTROL_SPECTATE_STOP:
            net_spectate_stop(c, &m);
            break;
        case NET_CONTROL_FOCUS: /* no reply: the budget's nearest tiles move (net_budget.c) */
            c->has_focus = m.has_focus;
            c->focus_x = m.focus_x;
            c->focus_y = m.focus_y;
            break;
        case NET_CONTROL_NONE:
            break;
        }
    }
    net_control_free(&m);
}

/* ---- binary messages ---- */

static uint32_t rd_u32le(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The id of the first pose the decoder would refuse as bad_value, -1 if none found. */
static int64_t first_bad_pose(const unsigned char *data, size_t len)
{
    size_t count = (size_t)data[8] | (size_t)data[9] << 8;
    for (size_t i = 0; i < count && TERRAD_POSE_BATCH_FIXED + (i + 1) * TERRAD_POSE_SIZE <= len;
         i++) {
        const unsigned char *p = data + TERRAD_POSE_BATCH_FIXED + i * TERRAD_POSE_SIZE;
        float v[7];
        for (int k = 0; k < 7; k++) {
            uint32_t u = rd_u32le(p + 4 + 4 * k);
            memcpy(&v[k], &u, sizeof u);
        }
        int ok = 1;
        for (int k = 0; k < 7; k++)
            ok &= isfinite(v[k]) != 0;
        if (!ok || !net_control_quat_norm_ok(v[3], v[4], v[5], v[6]))
            return rd_u32le(p);
    }
    return -1;
}

static void handle_pose_batch(net_client *c, const unsigned char *data, size_t len)
{
    net_state *s = c->srv;
    uint32_t seq = 0;
    size_t count = 0;
    char store_reason[256];
    cJSON *ref = len >= 8 ? cJSON_CreateNumber(rd_u32le(data + 4)) : NULL;
    int rc = terrad_pose_batch_decode(data, len, &seq, s->poses,
                                      (size_t)s->cfg.limits.max_poses_per_batch, &count);
    if (rc == TERRAD_E_TOO_LARGE) {
        net_error(c, rc, ref, -1, 0, "POSE_BATCH of %u poses is over max_poses_per_batch (%d)",
                  (unsigned)(data[8] | data[9] << 8), s->cfg.limits.max_poses_per_batch);
    } else if (rc == TERRAD_E_BAD_VALUE) {
        net_error(c, rc, ref, first_bad_pose(data, len), 0,
                  "POSE_BATCH: a pose is not finite or its quaternion is not unit length "
                  "(|q| within 0.9..1.1): batch dropped");
    } else if (rc) {
        net_error(c, rc, ref, -1, 0, "POSE_BATCH: %s (%zu bytes)", terrad_err_name(rc), len);
    } else if (hub_store_unavailable(s->hub, store_reason, sizeof store_reason)) {
        net_error(c, TERRAD_E_STORE_UNAVAILABLE, ref, -1, 0,
                  "POSE_BATCH refused: storage cannot make ticks durable (%s); retry later",
                  store_reason);
    } else {
        for (size_t i = 0; i < count; i++) {
            const terrad_pose *p = &s->poses[i];
            if (!owned(c, p->id, ref))
                goto done;
            collider_pose cp = {{p->x, p->y, p->z}, {p->qw, p->qx, p->qy, p->qz}};
            error_text err;
            if (collider_pose_validate(&cp, &err)) {
                net_error(c, TERRAD_E_BAD_VALUE, ref, p->id, 0, "collider %u: %s", p->id,
                          err.message);
                goto done;
            }
        }
        hub_pose *hp = malloc((count ? count : 1) * sizeof *hp);
        if (!hp) {
            net_error(c, TERRAD_E_INTERNAL, ref, -1, 0, "POSE_BATCH: out of memory");
            goto done;
        }
        for (size_t i = 0; i < count; i++) {
            const terrad_pose *p = &s->poses[i];
            net_collider_slot *slot = net_collider_find(s, p->id);
            hp[i] = (hub_pose){
                .collider = p->id,
                .client = c->id,
                .sequence = seq,
                .pose = {{p->x, p->y, p->z},
                         collider_wire_orientation((quatd){p->qw, p->qx, p->qy, p->qz},
                                                   slot->axis_z)},
            };
        }
        /* every accepted batch, empty ones too, is acknowledged by the next tick;
         * its poses and its sequence reach the tick together (hub_set_batch) */
        int stored = hub_set_batch(s->hub, c->id, seq, hp, (int)count);
        net_budget_note_poses(c, s->poses, count); /* near its focus too (tile_distance) */
        if (stored < (int)count)
            net_error(c, TERRAD_E_INTERNAL, ref, hp[stored].collider, 0,
                      "the pose table is full: pose of collider %u dropped", hp[stored].collider);
        free(hp);
    }
done:
    cJSON_Delete(ref);
}

void net_handle_binary(net_client *c, const unsigned char *data, size_t len)
{
    THREAD_OWNED(&c->srv->owner);
    if (!c->ready) {
        net_error(c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1, "the first message must be hello");
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "no hello");
        return;
    }
    if (c->srv->relay) { /* pose batches are checked and applied by the world's owner */
        net_relay_forward(c, 1, data, len);
        return;
    }
    terrad_header h;
    int rc = terrad_header_decode(data, len, &h);
    if (rc) {
        net_error(c, rc, NULL, -1, 0, "binary frame refused: %s", terrad_err_name(rc));
        return;
    }
    switch (h.type) {
    case TERRAD_MSG_POSE_BATCH:
        if (net_auth_allows(c, AUTH_DRIVER, "POSE_BATCH", NULL))
            handle_pose_batch(c, data, len);
        return;
    case TERRAD_MSG_STEP:
        net_handle_step(c, data, len); /* checks the role itself: its refusal names "step:SEQ" */
        return;
    case TERRAD_MSG_PING:
    case TERRAD_MSG_PONG: {
        uint8_t type;
        uint64_t nonce;
        rc = terrad_ping_decode(data, len, &type, &nonce);
        if (rc) {
            net_error(c, rc, NULL, -1, 0, "%s: %s", terrad_msg_type_name(h.type),
                      terrad_err_name(rc));
            return;
        }
        if (type == TERRAD_MSG_PONG)
            return;
        hub_frame *f = hub_frame_new(1, TERRAD_PING_SIZE);
        size_t n;
        if (!f || terrad_ping_encode(f->data, f->len, &n, TERRAD_MSG_PONG, nonce) != 0) {
            hub_frame_unref(f);
            return;
        }
        net_enqueue(c, f, NET_ITEM_REPLY);
        return;
    }
    default:
        net_error(c, TERRAD_E_UNKNOWN_TYPE, NULL, -1, 0, "a %s frame is not accepted by the server",
                  terrad_msg_type_name(h.type));
        return;
    }
}
