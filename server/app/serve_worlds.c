/*
 * serve_worlds.c: worlds created and ended by API on a single daemon
 * (issue 22; docs/openapi.yaml "worlds"): POST /v1/worlds, GET /v1/worlds,
 * DELETE /v1/worlds/{name}. Each created world lives the one life of
 * host/host_world.c with this file's registry backend (local_world_ops),
 * on the daemon's shared pool of sim workers beside the default world
 * (--scene), as a cluster node's worlds do (the same host_sim, the same
 * entry of the daemon's one table of worlds, hub_worlds_add, which both
 * ports read), so a created world's tick
 * is the same code as the default's and its clients
 * reach it by hello's "world" and its HTTP by ?world=NAME or
 * /v1/worlds/NAME/edits.
 *
 * Storage (with --data DIR): DIR/worlds/NAME.json is the world's scene and
 * the mark that it exists — written (fsynced, renamed into place) before the
 * create is acknowledged, and unlinked before a delete is — and
 * DIR/worlds/NAME/ its data directory (a store of its own: snapshots and
 * log). A start recovers every world whose NAME.json is there, so after
 * kill -9 exactly the acknowledged worlds come back; a directory without its
 * NAME.json is a delete or create cut short, and is removed. ?keep=1 moves
 * both to DIR/worlds-kept/NAME-MS(.json) for replays instead.
 *
 * Creates and deletes run on the HTTP threads, off every tick: a create
 * makes the world there (its scene, store, engine and service) and hands it
 * to the pool; a delete asks the pool to end it and waits until its end ran
 * (on a worker: off the ports, freed). One lock guards the table.
 */
#include <dirent.h>
#include <errno.h>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "app/app.h"
#include "app/serve_internal.h"
#include "metrics/metrics.h"

#define WORLDS_DEFAULT_MAX 16
#define SCENE_MAX_BYTES (1 << 20) /* as serve_worlds_body.c's */
#define PATH_CAP 1200

typedef enum { LW_STARTING, LW_RUNNING, LW_FAILED, LW_ENDED } lw_state;
static const char *const state_names[] = {"starting", "running", "failed", "ended"};

typedef struct local_world {
    host_world hw; /* its life (host/); hw.deleted: its clients are told it was deleted */
    serve_worlds *ws;
    int deleting;   /* a DELETE has it: no other may */
    lw_state state; /* under ws->lock */
    char *scene_text;
    char why[256];
    char told[16]; /* the lifecycle last sent as a world_state event (serve_worlds_watch) */
    char data_dir[PATH_CAP]; /* its store, which /v1/heights?world=NAME&tick=N rebuilds from */
} local_world;

struct serve_worlds {
    serve_options o; /* the daemon's, with no demo actors and no tick limit */
    http_server *http;
    hub_worlds *table; /* the daemon's worlds, which both ports read */
    net_server *net;
    host_ticker *ticker;        /* the daemon's sim workers, which tick every world */
    const host_sim *main_world; /* the default world (its status for the list) */
    char root[PATH_CAP];        /* DATA/worlds; "" without --data */
    char kept[PATH_CAP];        /* DATA/worlds-kept */
    int max;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    local_world *worlds[SERVE_WORLDS_MAX];
    int nworlds;
    int stopping, calls; /* the daemon stops: no new call; calls running now */
    char draining[200];  /* "" or why the daemon drains: no create (serve_worlds_drain) */
    char main_told[16];  /* the default world's told (serve_worlds_watch) */
};

/* ---- answers ---- */

/* An API call begins (0: the daemon is stopping, answer 503) and ends. */
static int enter(serve_worlds *ws)
{
    pthread_mutex_lock(&ws->lock);
    int ok = !ws->stopping;
    ws->calls += ok;
    pthread_mutex_unlock(&ws->lock);
    return ok;
}

static void leave(serve_worlds *ws)
{
    pthread_mutex_lock(&ws->lock);
    ws->calls--;
    pthread_cond_broadcast(&ws->cond);
    pthread_mutex_unlock(&ws->lock);
}

/* A running world's place in a fleet's lifecycle (docs/fleet.md): "draining"
 * once the daemon drains, "driven" while a collider is in it (a client drives:
 * an allocated game server's match), else "ready"; any other state is its own. */
static const char *lifecycle(const char *state, const http_status *st, int draining)
{
    if (strcmp(state, "running") != 0)
        return state;
    return draining ? "draining" : !st->ready ? "starting" : st->colliders > 0 ? "driven" : "ready";
}

/* One world's entry of GET /v1/worlds, from its status block. */
static cJSON *world_entry(const char *name, http_status *st, const char *state, int is_default,
                          int draining)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", name);
    cJSON_AddStringToObject(o, "state", state);
    cJSON_AddBoolToObject(o, "default", is_default);
    pthread_mutex_lock(&st->lock);
    cJSON_AddStringToObject(o, "lifecycle", lifecycle(state, st, draining));
    cJSON_AddStringToObject(o, "scene", st->scene_name);
    cJSON_AddStringToObject(o, "clock", st->client_clock ? "client" : "wall");
    cJSON_AddNumberToObject(o, "width", st->world_width);
    cJSON_AddNumberToObject(o, "height", st->world_height);
    cJSON_AddNumberToObject(o, "tick", (double)st->tick);
    cJSON_AddNumberToObject(o, "clients", st->clients);
    cJSON_AddNumberToObject(o, "colliders", st->colliders);
    cJSON_AddBoolToObject(o, "ready", st->ready);
    pthread_mutex_unlock(&st->lock);
    return o;
}

/* ---- files ---- */

static void world_paths(const serve_worlds *ws, const char *name, char *dir, char *json)
{
    snprintf(dir, PATH_CAP, "%.1000s/%s", ws->root, name);
    snprintf(json, PATH_CAP, "%.1000s/%s.json", ws->root, name);
}

/* A world's data directory and its tiles/ gone (store_remove refuses what is not a store's). */
static int remove_store_dir(const char *dir, error_text *err)
{
    int removed = 0;
    if (store_remove(dir, &removed, err) != 0)
        return -1;
    if (rmdir(dir) != 0 && errno != ENOENT) {
        error_set(err, "cannot remove %s: %s", dir, strerror(errno));
        return -1;
    }
    return 0;
}

/* ---- a world's sim thread ---- */

static void set_state(local_world *lw, lw_state state)
{
    pthread_mutex_lock(&lw->ws->lock);
    lw->state = state;
    pthread_cond_broadcast(&lw->ws->cond);
    pthread_mutex_unlock(&lw->ws->lock);
}

/* The registry backend of a created world (host.h): its scene from the
 * create's body (or DATA/worlds/NAME.json), its store DATA/worlds/NAME/. */
static int world_open(host_world *hw, error_text *err)
{
    local_world *lw = hw->owner;
    serve_worlds *ws = lw->ws;
    host_sim *m = &hw->m;
    const char *base = ws->o.scene_dir ? ws->o.scene_dir : ".";
    if (scene_load_json(lw->scene_text, base, &m->sc, err) != 0)
        return -1;
    if (ws->o.tick_hz > 0)
        m->sc.tick_hz = ws->o.tick_hz;
    m->sc.material.tick_s = 1.0 / m->sc.tick_hz;
    if (scene_create_world(&m->sc, &m->w, err) != 0)
        return -1;
    if (!ws->root[0])
        return 0;
    char dir[PATH_CAP], json[PATH_CAP];
    world_paths(ws, m->name, dir, json);
    store_config stc = {.dir = dir,
                        .segment_bytes = ws->o.wal_segment_bytes,
                        .retain_bytes = ws->o.replay_retain_bytes,
                        .fault_path = ws->o.store_fault};
    if (store_parse_durability(ws->o.durability, &stc, err) != 0 ||
        !(m->st = store_open(&stc, &m->w, &m->recovery, err)))
        return -1;
    snprintf(lw->data_dir, sizeof lw->data_dir, "%s", dir);
    m->status.history.dir = lw->data_dir;
    log_info("worlds: world %s: recovered tick %llu from %d tile snapshots and %lld log records",
             m->name, (unsigned long long)m->recovery.tick, m->recovery.tiles_loaded,
             (long long)m->recovery.records_replayed);
    return 0;
}

/* On the ports: running from now on (before its first tick, which may fail and end it). */
static int world_registered(host_world *hw, error_text *err)
{
    (void)err;
    local_world *lw = hw->owner;
    host_sim *m = &hw->m;
    log_info("worlds: world %s: serving scene \"%s\" (%dx%d cells, %s backend, tick %llu): "
             "hello \"world\": \"%s\", /v1/*?world=%s",
             m->name, m->sc.name, m->w.width, m->w.height, m->backend->name,
             (unsigned long long)service_current_tick(m->svc), m->name, m->name);
    set_state(lw, LW_RUNNING);
    return 0;
}

/* Its end ran on a worker (off the ports, freed): its state final. */
static void world_ended(host_world *hw, int rc)
{
    local_world *lw = hw->owner;
    if (rc != 0)
        snprintf(lw->why, sizeof lw->why, "%s", hw->why);
    log_info("worlds: world %s stopped after tick %llu (%llu overruns)%s%s", hw->m.name,
             hw->last_tick, hw->overruns, rc ? ": " : "", rc ? lw->why : "");
    set_state(lw, rc != 0 ? LW_FAILED : LW_ENDED);
}

static const host_world_ops local_world_ops = {
    .open = world_open,
    .registered = world_registered,
    .ended = world_ended,
    .deleted_why = "was deleted (DELETE /v1/worlds)",
    .stopped_why = "stopped (the daemon stops)",
};

/* The world made on this thread (scene, store, engine, service), on the
 * ports and on the pool: 0, or -1 with why and everything made undone. */
static int world_start(serve_worlds *ws, local_world *lw, char *why, size_t cap)
{
    host_world *hw = &lw->hw;
    host_world_place(hw, &local_world_ops, lw, ws->table, ws->net, ws->ticker);
    hw->config = serve_host_config(&ws->o);
    hw->max_ticks = -1;
    if (host_world_start(hw, why, cap) == 0)
        return 0;
    set_state(lw, LW_STARTING);
    log_error("worlds: world %s did not start: %s", hw->m.name, why);
    return -1;
}

/* ---- the table ---- */

static local_world *find(serve_worlds *ws, const char *name)
{
    for (int i = 0; i < ws->nworlds; i++)
        if (strcmp(ws->worlds[i]->hw.m.name, name) == 0)
            return ws->worlds[i];
    return NULL;
}

static void forget(serve_worlds *ws, local_world *lw)
{
    pthread_mutex_lock(&ws->lock);
    for (int i = 0; i < ws->nworlds; i++)
        if (ws->worlds[i] == lw) {
            memmove(&ws->worlds[i], &ws->worlds[i + 1],
                    (size_t)(ws->nworlds - i - 1) * sizeof *ws->worlds);
            ws->nworlds--;
            break;
        }
    pthread_mutex_unlock(&ws->lock);
    free(lw->scene_text);
    pthread_mutex_destroy(&lw->hw.m.status.lock);
    free(lw);
}

/* Off the pool, its end run (deleted: its clients are told so). */
static void end_world(local_world *lw, int deleted)
{
    serve_worlds *ws = lw->ws;
    lw->hw.deleted = deleted; /* read by its end, after the ticker's lock */
    pthread_mutex_lock(&ws->lock);
    int running = lw->state == LW_RUNNING;
    pthread_mutex_unlock(&ws->lock);
    if (!running)
        return; /* never started, or a failed tick already ended it */
    host_world_end(&lw->hw);
    pthread_mutex_lock(&ws->lock);
    while (lw->state == LW_RUNNING)
        pthread_cond_wait(&ws->cond, &ws->lock);
    pthread_mutex_unlock(&ws->lock);
}

/* A new entry (scene_text taken), in the table as "starting": NULL with
 * *code and why when the name is taken or the table is full. */
static local_world *reserve(serve_worlds *ws, const char *name, char *scene_text, unsigned *code,
                            const char **field, char *why, size_t cap)
{
    local_world *lw = calloc(1, sizeof *lw);
    if (!lw) {
        free(scene_text);
        *code = 500, *field = "body";
        snprintf(why, cap, "out of memory");
        return NULL;
    }
    lw->ws = ws;
    lw->scene_text = scene_text;
    lw->hw.m.metrics_slot = -1;
    snprintf(lw->hw.m.name, sizeof lw->hw.m.name, "%s", name);
    pthread_mutex_init(&lw->hw.m.status.lock, NULL);
    pthread_mutex_lock(&ws->lock);
    int taken = find(ws, name) != NULL, full = ws->nworlds >= ws->max;
    if (!taken && !full)
        ws->worlds[ws->nworlds++] = lw;
    pthread_mutex_unlock(&ws->lock);
    if (!taken && !full)
        return lw;
    *code = 409;
    *field = taken ? "name" : "max_worlds";
    if (taken)
        snprintf(why, cap, "name: a world \"%s\" exists already (DELETE it first)", name);
    else
        snprintf(why, cap,
                 "max_worlds: this daemon already holds %d created worlds, its limit "
                 "(--max-worlds): delete one first",
                 ws->max);
    free(scene_text);
    pthread_mutex_destroy(&lw->hw.m.status.lock);
    free(lw);
    return NULL;
}

/* ---- POST /v1/worlds ---- */

static unsigned create_world(serve_worlds *ws, const char *body, size_t len, char **json)
{
    char name[CLUSTER_WORLD_NAME_MAX + 1] = "", why[640], checked[64];
    char *text = NULL;
    unsigned code = worlds_body_check(body, len, ws->o.scene_dir, ws->main_world->sc.name, name,
                                      &text, checked, sizeof checked, why, sizeof why);
    if (code)
        return worlds_refuse("create", code, checked, why, json);
    const char *field = "body";
    local_world *lw = reserve(ws, name, text, &code, &field, why, sizeof why);
    if (!lw)
        return worlds_refuse("create", code, field, why, json);
    char dir[PATH_CAP], path[PATH_CAP];
    world_paths(ws, name, dir, path);
    error_text err = {{0}};
    if (ws->root[0] &&
        ((mkdir(ws->root, 0755) != 0 && errno != EEXIST) || remove_store_dir(dir, &err) != 0 ||
         file_write_durably(path, lw->scene_text, strlen(lw->scene_text), &err) != 0)) {
        snprintf(why, sizeof why, "storage: %s", err.message[0] ? err.message : strerror(errno));
        forget(ws, lw);
        return worlds_refuse("create", 500, "storage", why, json);
    }
    if (world_start(ws, lw, why, sizeof why) != 0) {
        if (ws->root[0]) {
            unlink(path);
            file_sync_dir(ws->root);
            remove_store_dir(dir, &err);
        }
        forget(ws, lw);
        char message[700];
        snprintf(message, sizeof message, "scene: world %s could not start: %.600s", name, why);
        return worlds_refuse("create", 422, "scene", message, json);
    }
    metrics_count_world_request("create", 1);
    net_server_event(ws->net, "world_created", name);
    log_info("worlds: world %s created (POST /v1/worlds)", name);
    cJSON *o = world_entry(name, &lw->hw.m.status, "running", 0, 0);
    *json = json_print_delete(o);
    return 201;
}

/* ---- GET /v1/worlds ---- */

static unsigned worlds_list(void *ctx, char **json)
{
    serve_worlds *ws = ctx;
    cJSON *doc = cJSON_CreateObject(), *arr = cJSON_AddArrayToObject(doc, "worlds");
    pthread_mutex_lock(&ws->lock);
    int draining = ws->draining[0] != 0;
    cJSON_AddItemToArray(arr, world_entry(ws->main_world->sc.name,
                                          (http_status *)&ws->main_world->status, "running", 1,
                                          draining));
    for (int i = 0; i < ws->nworlds; i++) {
        local_world *lw = ws->worlds[i];
        cJSON *e =
            world_entry(lw->hw.m.name, &lw->hw.m.status, state_names[lw->state], 0, draining);
        if (lw->state == LW_FAILED)
            cJSON_AddStringToObject(e, "error", lw->why);
        cJSON_AddItemToArray(arr, e);
    }
    cJSON_AddNumberToObject(doc, "max_worlds", ws->max);
    pthread_mutex_unlock(&ws->lock);
    *json = json_print_delete(doc);
    return 200;
}

/* ---- DELETE /v1/worlds/{name} ---- */

/* Its storage removed, or moved to worlds-kept/ (*kept: where). */
static void drop_storage(serve_worlds *ws, const char *name, int keep, char *kept, size_t cap)
{
    char dir[PATH_CAP], path[PATH_CAP];
    world_paths(ws, name, dir, path);
    error_text err = {{0}};
    if (keep) {
        snprintf(kept, cap, "%.1000s/%s-%.0f", ws->kept, name, time_now_ms());
        char kept_json[PATH_CAP + 8];
        snprintf(kept_json, sizeof kept_json, "%s.json", kept);
        if ((mkdir(ws->kept, 0755) != 0 && errno != EEXIST) || rename(dir, kept) != 0 ||
            rename(path, kept_json) != 0)
            log_error("worlds: world %s: cannot keep its storage in %s: %s", name, kept,
                      strerror(errno));
        file_sync_dir(ws->root);
        return;
    }
    /* its scene first: once that is gone the world is, whatever else a crash leaves */
    if (unlink(path) != 0 && errno != ENOENT)
        log_error("worlds: cannot remove %s: %s", path, strerror(errno));
    file_sync_dir(ws->root);
    if (remove_store_dir(dir, &err) != 0)
        log_error("worlds: world %s: %s (removed at the next start)", name, err.message);
}

static unsigned delete_world(serve_worlds *ws, const char *name, int keep, char **json)
{
    char why[400];
    pthread_mutex_lock(&ws->lock);
    local_world *lw = find(ws, name);
    int busy = lw && (lw->deleting || lw->state == LW_STARTING);
    if (lw && !busy)
        lw->deleting = 1;
    pthread_mutex_unlock(&ws->lock);
    if (!lw || busy) {
        int main_world = strcmp(name, ws->main_world->sc.name) == 0;
        snprintf(why, sizeof why, "name: %s",
                 busy         ? "the world is starting or being deleted: try again"
                 : main_world ? "the default world (the daemon's --scene) cannot be deleted"
                              : "no such world (GET /v1/worlds lists them)");
        return worlds_refuse("delete", busy || main_world ? 409 : 404, "name", why, json);
    }
    end_world(lw, 1);
    char kept[PATH_CAP] = "";
    if (ws->root[0])
        drop_storage(ws, name, keep, kept, sizeof kept);
    forget(ws, lw);
#ifdef __GLIBC__
    /* A world is made on an HTTP thread and ended on a tick worker, so its
     * memory returns to several of glibc's per-thread arenas, which keep the
     * free pages: without this a create/delete loop holds ~40 MB more (the
     * arenas' high-water mark) than it started with. */
    malloc_trim(0);
#endif
    metrics_count_world_request("delete", 1);
    net_server_event(ws->net, "world_deleted", name);
    log_info("worlds: world %s deleted (DELETE /v1/worlds/%s)%s%s", name, name,
             kept[0] ? ", its storage kept in " : "", kept);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", name);
    cJSON_AddBoolToObject(o, "deleted", 1);
    if (kept[0])
        cJSON_AddStringToObject(o, "kept", kept);
    else
        cJSON_AddNullToObject(o, "kept");
    *json = json_print_delete(o);
    return 200;
}

static unsigned stopping(const char *op, char **json)
{
    return worlds_refuse(op, 503, "name", "name: the daemon is stopping", json);
}

/* A create (body) or a delete (name, keep) while the daemon is not stopping. */
static unsigned worlds_call(serve_worlds *ws, int create, const char *body, size_t len,
                            const char *name, int keep, char **json)
{
    if (!enter(ws))
        return stopping(create ? "create" : "delete", json);
    unsigned code = create ? create_world(ws, body, len, json) : delete_world(ws, name, keep, json);
    leave(ws);
    return code;
}

static unsigned worlds_create(void *ctx, const char *body, size_t len, char **json)
{
    serve_worlds *ws = ctx;
    char draining[sizeof ws->draining], why[300];
    pthread_mutex_lock(&ws->lock);
    snprintf(draining, sizeof draining, "%s", ws->draining);
    pthread_mutex_unlock(&ws->lock);
    if (draining[0]) { /* the orchestrator stops this daemon: the world belongs elsewhere */
        snprintf(why, sizeof why,
                 "name: the daemon is draining (%s) and creates no world: create it on another",
                 draining);
        return worlds_refuse("create", 503, "name", why, json);
    }
    return worlds_call(ctx, 1, body, len, NULL, 0, json);
}

static unsigned worlds_remove(void *ctx, const char *name, int keep, char **json)
{
    return worlds_call(ctx, 0, NULL, 0, name, keep, json);
}

/* ---- the daemon's life ---- */

/* Every world DATA/worlds/NAME.json names, started again; directories
 * without one (a create or delete cut short) and *.tmp removed. */
static void recover_worlds(serve_worlds *ws)
{
    DIR *d = opendir(ws->root);
    struct dirent *e;
    int count = 0;
    while (d && (e = readdir(d))) {
        char name[CLUSTER_WORLD_NAME_MAX + 8], path[PATH_CAP], dir[PATH_CAP];
        size_t n = strlen(e->d_name);
        if (n < 6 || n > CLUSTER_WORLD_NAME_MAX + 5 || strcmp(e->d_name + n - 5, ".json") != 0)
            continue;
        snprintf(name, sizeof name, "%.*s", (int)(n - 5), e->d_name);
        error_text err = {{0}};
        uint8_t *text = NULL;
        size_t len = 0;
        world_paths(ws, name, dir, path);
        unsigned code = 0;
        const char *field = NULL;
        char why[400];
        local_world *lw;
        if (!cluster_name_valid(name, "world", &err) ||
            file_read_all(path, SCENE_MAX_BYTES, &text, &len, &err) != 0) {
            log_error("worlds: %s: %s (left alone)", path, err.message);
        } else if (!(lw = reserve(ws, name, (char *)text, &code, &field, why, sizeof why))) {
            log_error("worlds: %s: %s", path, why);
        } else if (world_start(ws, lw, why, sizeof why) != 0) {
            /* listed as failed: DELETE ends it; its storage stays for a look */
            pthread_mutex_lock(&ws->lock);
            lw->state = LW_FAILED;
            snprintf(lw->why, sizeof lw->why, "%.255s", why);
            pthread_mutex_unlock(&ws->lock);
        } else {
            count++;
        }
    }
    if (d)
        rewinddir(d);
    while (d && (e = readdir(d))) { /* leftovers, after every world was taken */
        char path[PATH_CAP], json[PATH_CAP + 8];
        size_t n = strlen(e->d_name);
        snprintf(path, sizeof path, "%.1000s/%.100s", ws->root, e->d_name);
        snprintf(json, sizeof json, "%s.json", path);
        error_text err = {{0}};
        if (n > 4 && strcmp(e->d_name + n - 4, ".tmp") == 0)
            unlink(path);
        else if (e->d_name[0] != '.' && !strchr(e->d_name, '.') && access(json, F_OK) != 0 &&
                 remove_store_dir(path, &err) != 0)
            log_error("worlds: a left-over world directory: %s", err.message);
    }
    if (d)
        closedir(d);
    if (count)
        log_info("worlds: %d created worlds recovered from %s", count, ws->root);
}

serve_worlds *serve_worlds_start(const serve_options *o, const host_sim *main_world,
                                 http_server *http, hub_worlds *table, net_server *net,
                                 host_ticker *ticker, error_text *err)
{
    serve_worlds *ws = calloc(1, sizeof *ws);
    if (!ws) {
        error_set(err, "worlds: out of memory");
        return NULL;
    }
    ws->o = *o;
    ws->o.demo_actors = 0; /* a created world has only its clients' colliders */
    ws->o.max_ticks = -1;
    ws->http = http;
    ws->table = table;
    ws->net = net;
    ws->main_world = main_world;
    ws->max = o->max_worlds > 0
                  ? (o->max_worlds < SERVE_WORLDS_MAX ? o->max_worlds : SERVE_WORLDS_MAX)
                  : WORLDS_DEFAULT_MAX;
    if (o->data_dir) {
        snprintf(ws->root, sizeof ws->root, "%.1000s/worlds", o->data_dir);
        snprintf(ws->kept, sizeof ws->kept, "%.1000s/worlds-kept", o->data_dir);
    }
    ws->ticker = ticker;
    pthread_mutex_init(&ws->lock, NULL);
    pthread_cond_init(&ws->cond, NULL);
    if (ws->root[0])
        recover_worlds(ws);
    http_world_api api = {worlds_create, worlds_list, worlds_remove, ws};
    http_server_set_world_api(http, &api);
    return ws;
}

/* One world's lifecycle now; a world_state event when it is not what was told. */
static void watch_one(serve_worlds *ws, const char *name, http_status *st, const char *state,
                      char *told, size_t cap)
{
    pthread_mutex_lock(&st->lock);
    const char *now = lifecycle(state, st, ws->draining[0] != 0);
    pthread_mutex_unlock(&st->lock);
    if (strcmp(now, told) == 0)
        return;
    snprintf(told, cap, "%s", now);
    net_server_world_state(ws->net, name, now);
}

void serve_worlds_watch(serve_worlds *ws)
{
    if (!ws)
        return;
    pthread_mutex_lock(&ws->lock);
    watch_one(ws, ws->main_world->sc.name, (http_status *)&ws->main_world->status, "running",
              ws->main_told, sizeof ws->main_told);
    for (int i = 0; i < ws->nworlds; i++) {
        local_world *lw = ws->worlds[i];
        watch_one(ws, lw->hw.m.name, &lw->hw.m.status, state_names[lw->state], lw->told,
                  sizeof lw->told);
    }
    pthread_mutex_unlock(&ws->lock);
}

void serve_worlds_drain(serve_worlds *ws, const char *why)
{
    if (!ws)
        return;
    pthread_mutex_lock(&ws->lock);
    snprintf(ws->draining, sizeof ws->draining, "%s", why);
    pthread_mutex_unlock(&ws->lock);
}

void serve_worlds_stop(serve_worlds *ws)
{
    if (!ws)
        return;
    pthread_mutex_lock(&ws->lock);
    ws->stopping = 1;
    while (ws->calls > 0) /* a create or delete running ends first */
        pthread_cond_wait(&ws->cond, &ws->lock);
    pthread_mutex_unlock(&ws->lock);
    /* every world ends, side by side on the workers (the default world goes on) */
    pthread_mutex_lock(&ws->lock);
    for (int i = 0; i < ws->nworlds; i++)
        if (ws->worlds[i]->state == LW_RUNNING)
            host_world_end(&ws->worlds[i]->hw);
    for (int i = 0; i < ws->nworlds; i++)
        while (ws->worlds[i]->state == LW_RUNNING)
            pthread_cond_wait(&ws->cond, &ws->lock);
    pthread_mutex_unlock(&ws->lock);
    while (ws->nworlds > 0)
        forget(ws, ws->worlds[0]);
    pthread_cond_destroy(&ws->cond);
    pthread_mutex_destroy(&ws->lock);
    free(ws);
}

int serve_worlds_fresh(const char *data_dir, error_text *err)
{
    char root[PATH_CAP];
    snprintf(root, sizeof root, "%.1000s/worlds", data_dir);
    DIR *d = opendir(root);
    if (!d)
        return 0;
    struct dirent *e;
    int rc = 0;
    while (rc == 0 && (e = readdir(d))) {
        char path[PATH_CAP];
        if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0)
            continue;
        snprintf(path, sizeof path, "%.1000s/%.100s", root, e->d_name);
        struct stat sb;
        if (lstat(path, &sb) == 0 && S_ISDIR(sb.st_mode))
            rc = remove_store_dir(path, err);
        else if (unlink(path) != 0)
            error_set(err, "cannot remove %s: %s", path, strerror(errno)), rc = -1;
    }
    closedir(d);
    if (rc == 0 && rmdir(root) != 0 && errno != ENOENT) {
        error_set(err, "cannot remove %s: %s", root, strerror(errno));
        rc = -1;
    }
    return rc;
}
