/*
 * net_worlds.c: the several worlds on one websocket port (docs/cluster.md).
 * Each world served here has its own state — its hub (the world's sim thread
 * on the other end), world info, collider table and commands waiting for the
 * hub — and the server's own state is the lobby, where a client waits until
 * its hello names a world (net_client_join_world; no name: the default world,
 * an entry like any other). The worlds ticked here are the entries of the
 * daemon's one table of worlds (hub.h, hub_worlds), which each world's host
 * adds it to and removes it from (host/host_world.c; the HTTP threads read
 * the same table); the worlds another node ticks are relayed
 * (net_server_add_relay, net_remote.c) through a queue of their own. The net
 * thread adopts and detaches them between two callbacks (net_worlds_apply),
 * so nothing else of the net thread needs a lock. A detached world's clients
 * are told and closed, and only then does the table's removal return.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "metrics/metrics.h"
#include "net/net_server_internal.h"
#include "terrad_proto.h"

#define NET_REMOVE_DEADLINE_MS 10000.0

net_state *net_state_at(net_server *s, int i)
{
    if (i == 0)
        return &s->st;
    return i - 1 < s->st.nworlds ? s->st.worlds[i - 1] : NULL;
}

void net_state_release(net_state *w)
{
    net_spectate_join_all(w);
    for (int i = 0; i < w->backlog_count; i++)
        if (w->backlog[i].mesh) {
            collider_mesh_free(w->backlog[i].mesh);
            free(w->backlog[i].mesh);
        }
    free(w->backlog);
    free(w->clients);
    free(w->colliders);
    free(w->poses);
    terrad_codec_free(w->budget_codec);
    cJSON_Delete(w->models);
    cJSON_Delete(w->materials);
    cJSON_Delete(w->base);
    free(w->models_json);
    free(w->materials_json);
    free(w->world_name);
}

cJSON *net_parse_base(const char *json)
{
    cJSON *o = json ? cJSON_Parse(json) : NULL;
    if (o && !cJSON_IsObject(o)) {
        cJSON_Delete(o);
        o = NULL;
    }
    return o; /* NULL (none, or out of memory): clients get absolute snapshots */
}

cJSON *net_parse_names(const char *text, const char *fallback, const char *what, error_text *err)
{
    cJSON *a = cJSON_Parse(text ? text : fallback);
    int ok = a && cJSON_IsArray(a);
    const cJSON *it;
    cJSON_ArrayForEach(it, a) if (!cJSON_IsString(it)) ok = 0;
    if (!ok) {
        error_set(err, "net: %s must be a JSON array of strings", what);
        cJSON_Delete(a);
        return NULL;
    }
    return a;
}

void net_default_lag(net_state *w)
{
    if (w->cfg.limits.max_client_lag_ticks <= 0)
        w->cfg.limits.max_client_lag_ticks =
            w->cfg.world.tick_hz > 0 ? (int)ceil(2 * w->cfg.world.tick_hz) : 120;
}

void net_world_state_free(net_state *w)
{
    if (w) {
        net_state_release(w);
        free(w);
    }
}

net_state *net_world_state_new(net_server *s, const char *name, const net_world_info *info, hub *h,
                               error_text *err)
{
    if (!name || !name[0] || info->width < 1 || info->height < 1 || info->tile_size < 1 ||
        !(info->cell_size_m > 0)) {
        error_set(err, "net: a world needs a name, an extent, a cell size and a tile size");
        return NULL;
    }
    net_state *w = calloc(1, sizeof *w);
    if (!w) {
        error_set(err, "net: out of memory");
        return NULL;
    }
    w->cfg = s->st.cfg; /* limits, token and server name: the node's (shared, not copied) */
    w->cfg.world = *info;
    w->models_json = info->models_json ? strdup(info->models_json) : NULL;
    w->materials_json = info->materials_json ? strdup(info->materials_json) : NULL;
    w->world_name = strdup(name);
    w->cfg.world.models_json = w->models_json;
    w->cfg.world.materials_json = w->materials_json;
    w->cfg.world.name = info->name ? w->world_name : NULL; /* NULL: the world message has none */
    net_default_lag(w);
    w->auth = s->st.auth; /* the node's table (net_auth_start), not owned */
    w->auth_generation = s->st.auth_generation;
    w->hub = h;
    w->server = s;
    w->next_collider_id = 1;
    w->hard_pending_bytes = s->st.hard_pending_bytes;
    w->remote_send = s->st.remote_send;
    w->remote_ctx = s->st.remote_ctx;
    snprintf(w->node, sizeof w->node, "%s", s->st.node);
    w->poses = calloc((size_t)w->cfg.limits.max_poses_per_batch, sizeof *w->poses);
    w->base = net_parse_base(info->base_json);
    w->cfg.world.base_json = NULL; /* not kept: w->base is the copy */
    w->models = net_parse_names(w->models_json, "[]", "world.models_json", err);
    w->materials =
        w->models ? net_parse_names(w->materials_json, "[\"default\"]", "world.materials_json", err)
                  : NULL;
    if (!w->world_name || !w->poses || !w->models || !w->materials) {
        if (w->models && w->materials)
            error_set(err, "net: out of memory");
        net_world_state_free(w);
        return NULL;
    }
    return w;
}

int net_world_queue_add(net_server *s, net_state *w, error_text *err)
{
    pthread_mutex_lock(&s->worlds_lock);
    int full = s->nadding + s->st.nworlds >= NET_MAX_WORLDS;
    if (!full)
        s->adding[s->nadding++] = w;
    pthread_mutex_unlock(&s->worlds_lock);
    if (full) {
        error_set(err, "net: this node already serves %d worlds", NET_MAX_WORLDS);
        net_world_state_free(w);
        return -1;
    }
    net_server_wake(s);
    return 0;
}

static int removing_index(const net_server *s, const char *name)
{
    for (int i = 0; i < s->nremoving; i++)
        if (strcmp(s->removing[i].name, name) == 0)
            return i;
    return -1;
}

int net_world_queue_remove(net_server *s, const char *name)
{
    pthread_mutex_lock(&s->worlds_lock);
    for (int i = 0; i < s->nadding; i++)
        if (strcmp(s->adding[i]->world_name, name) == 0) { /* never adopted: no client saw it */
            net_world_state_free(s->adding[i]);
            s->adding[i] = s->adding[--s->nadding];
            pthread_mutex_unlock(&s->worlds_lock);
            return 0;
        }
    if (s->nremoving < NET_MAX_WORLDS) {
        snprintf(s->removing[s->nremoving].name, sizeof s->removing[0].name, "%s", name);
        s->nremoving++;
    }
    double start = time_now_ms();
    while (removing_index(s, name) >= 0 && !atomic_load(&s->thread_done) &&
           time_now_ms() - start < NET_REMOVE_DEADLINE_MS) {
        pthread_mutex_unlock(&s->worlds_lock);
        net_server_wake(s);
        pthread_mutex_lock(&s->worlds_lock);
        struct timespec until = time_after_ms(CLOCK_REALTIME, 50);
        if (removing_index(s, name) >= 0)
            pthread_cond_timedwait(&s->worlds_cond, &s->worlds_lock, &until);
    }
    int left = removing_index(s, name);
    if (left >= 0)
        s->removing[left] = s->removing[--s->nremoving];
    pthread_mutex_unlock(&s->worlds_lock);
    if (left >= 0) {
        log_error("net: the websocket thread did not let go of a world within %.0f s",
                  NET_REMOVE_DEADLINE_MS / 1000);
        return -1;
    }
    return 0;
}

/* The world's clients are told and closed, and wait in the lobby for their
 * close (their colliders and subscriptions went with the world). */
static void detach(net_server *s, net_state *w, int deleted)
{
    net_spectate_leave(w, &s->st); /* never waits: their threads hold the table's entry */
    for (int i = 0; i < w->nclients; i++) {
        net_client *c = w->clients[i];
        if (c->remote) { /* its relay is told; nothing of it stays here */
            if (!c->closing)
                net_remote_close(c, LWS_CLOSE_STATUS_GOINGAWAY, "world moved");
            c->collider_count = 0;
            c->ready = 0;
            c->srv = &s->st;
            net_client_free(s, c);
            continue;
        }
        if (!c->closing && !c->killed && deleted) {
            net_error(c, TERRAD_E_SHUTTING_DOWN, NULL, -1, 1,
                      "world %s was deleted (DELETE /v1/worlds/%s): its terrain is gone",
                      w->world_name, w->world_name);
            net_close_after_flush(c, 4000 + TERRAD_E_SHUTTING_DOWN, "world deleted");
        } else if (!c->closing && !c->killed) {
            net_error(c, TERRAD_E_SHUTTING_DOWN, NULL, -1, 1,
                      "world %s is no longer served here (this server is stopping, or another "
                      "node owns it now): connect again",
                      w->world_name);
            net_close_after_flush(c, LWS_CLOSE_STATUS_GOINGAWAY, "world moved");
        }
        c->collider_count = 0;
        c->sub_count = 0;
        c->ready = 0; /* no HUB_CLIENT_LEFT for a hub that is going */
        c->srv = &s->st;
        if (net_client_add(&s->st, c) != 0)
            net_client_kill(c, "out of memory moving it to the lobby");
    }
    w->nclients = 0;
    if (w->hub) {
        hub_set_waker(w->hub, NULL, NULL);
        hub_release_net_end(w->hub);
    }
    thread_owner_release(&w->owner);
    log_info("net: world %s is no longer served here", w->world_name);
    net_world_state_free(w);
}

/* Net thread: w served here from now on (a relay, or an entry of the table). */
static void adopt(net_server *s, net_state *w)
{
    net_state *lobby = &s->st;
    if (array_grow((void **)&lobby->worlds, &lobby->worlds_cap, (int64_t)lobby->nworlds + 1,
                   sizeof *lobby->worlds) != 0) {
        log_error("net: out of memory adopting world %s", w->world_name);
        net_world_state_free(w);
        return;
    }
    thread_owner_claim(&w->owner, "net");
    if (w->hub) {
        hub_claim_net_end(w->hub);
        hub_set_waker(w->hub, net_server_wake, s);
    }
    lobby->worlds[lobby->nworlds++] = w;
    log_info("net: world %s is served here%s", w->world_name,
             w->relay ? " through its owner (a relay)" : "");
}

/* Net thread: the i-th world leaves (its last frames go out first, then its
 * clients are told and closed). */
static void leave(net_server *s, int i, int deleted)
{
    net_state *lobby = &s->st;
    net_drain_world(s, lobby->worlds[i]);
    detach(s, lobby->worlds[i], deleted);
    memmove(&lobby->worlds[i], &lobby->worlds[i + 1],
            (size_t)(lobby->nworlds - i - 1) * sizeof *lobby->worlds);
    lobby->nworlds--;
}

/* Net thread: the table's entries that left are detached and let go, the
 * new ones get a state (one that cannot stays held without one). */
static void apply_table(net_server *s)
{
    hub_worlds *t = s->st.cfg.worlds;
    unsigned generation = t ? hub_worlds_generation(t) : 0;
    if (!t || generation == s->table_seen)
        return;
    s->table_seen = generation;
    net_state *lobby = &s->st;
    char def[HUB_WORLD_NAME_MAX + 1];
    hub_worlds_default(t, def, sizeof def);
    hub_world *e;
    while ((e = hub_worlds_gone_next(t))) {
        for (int i = 0; i < lobby->nworlds; i++)
            if (lobby->worlds[i]->entry == e) {
                leave(s, i, e->deleted);
                break;
            }
        hub_worlds_let_go(t, e);
    }
    while ((e = hub_worlds_hold_next(t))) {
        error_text err = {{0}};
        net_state *w = net_world_state_new(s, e->name, e->info, e->h, &err);
        if (!w) {
            log_error("net: world %s cannot be served here: %s", e->name, err.message);
            continue;
        }
        w->entry = e;
        adopt(s, w);
        if (strcmp(e->name, def) != 0) /* a world beside a single daemon's default one */
            lobby->hosted_worlds = 1;
    }
}

void net_worlds_apply(net_server *s)
{
    apply_table(s);
    net_state *lobby = &s->st;
    pthread_mutex_lock(&s->worlds_lock);
    for (int i = 0; i < s->nadding; i++)
        adopt(s, s->adding[i]);
    lobby->hosted_worlds |= s->nadding > 0;
    s->nadding = 0;
    for (int r = 0; r < s->nremoving; r++)
        for (int i = 0; i < lobby->nworlds; i++)
            if (lobby->worlds[i]->relay &&
                strcmp(lobby->worlds[i]->world_name, s->removing[r].name) == 0) {
                leave(s, i, 0);
                break;
            }
    if (s->nremoving) {
        s->nremoving = 0;
        pthread_cond_broadcast(&s->worlds_cond);
    }
    pthread_mutex_unlock(&s->worlds_lock);
}

void net_worlds_let_go(net_server *s)
{
    hub_worlds *t = s->st.cfg.worlds;
    for (int i = 0; t && i < s->st.nworlds; i++)
        if (s->st.worlds[i]->entry)
            hub_worlds_let_go(t, s->st.worlds[i]->entry);
}
