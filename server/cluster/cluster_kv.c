/*
 * cluster_kv.c: tile snapshots and the world registry (cluster.h), two
 * JetStream key-value buckets.
 *
 * TERRAD_TILES holds, per world and tile, a head "<world>.tile.<tx>_<ty>"
 * whose value is "TSNAP1 <covers_seq> <len> <parts>\n" followed by the
 * snapshot itself when it fits one message (parts = 0); a larger one lives in
 * "<world>.part.<tx>_<ty>.<covers_seq>.<i>", written before the head that
 * names them, so a head always names complete parts. The head is written
 * with compare-and-set on its revision and never over one that covers more of
 * the log. Compaction (off the tick) writes these; recovery reads them before
 * replaying the log from the sequence they cover.
 *
 * TERRAD_WORLDS maps a world's name to its scene JSON (`terrad world`).
 */
#include "cluster/cluster_internal.h"

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define SNAP_MAGIC "TSNAP1"
#define HEAD_ROOM 1024 /* the head's text line and protocol overhead within max_payload */

typedef struct snap_head {
    uint64_t revision, covers_seq;
    uint64_t len;
    int parts;
    const uint8_t *inline_data; /* into the entry's value when parts == 0 */
} snap_head;

static void head_key(const char *world, int tx, int ty, char *out, size_t cap)
{
    snprintf(out, cap, "%s.tile.%d_%d", world, tx, ty);
}

static void part_key(const char *world, int tx, int ty, uint64_t covers_seq, int i, char *out,
                     size_t cap)
{
    snprintf(out, cap, "%s.part.%d_%d.%" PRIu64 ".%d", world, tx, ty, covers_seq, i);
}

/* Parses a head entry's value; -1 when it is not one. */
static int head_parse(kvEntry *e, snap_head *h)
{
    const char *v = kvEntry_Value(e);
    int n = kvEntry_ValueLen(e);
    const char *nl = v ? memchr(v, '\n', (size_t)n) : NULL;
    char line[128];
    if (!nl || nl - v >= (int)sizeof line)
        return -1;
    memcpy(line, v, (size_t)(nl - v));
    line[nl - v] = '\0';
    char magic[16];
    if (sscanf(line, "%15s %" SCNu64 " %" SCNu64 " %d", magic, &h->covers_seq, &h->len,
               &h->parts) != 4 ||
        strcmp(magic, SNAP_MAGIC) != 0 || h->parts < 0)
        return -1;
    h->revision = kvEntry_Revision(e);
    h->inline_data = (const uint8_t *)nl + 1;
    if (h->parts == 0 && (uint64_t)(v + n - (nl + 1)) != h->len)
        return -1;
    return 0;
}

/* 1 found (*e kept for the caller to destroy), 0 none, -1 error. */
static int head_get(cluster *cl, const char *key, kvEntry **e, snap_head *h, error_text *err)
{
    natsStatus s = kvStore_Get(e, cl->tiles, key);
    if (s == NATS_NOT_FOUND)
        return 0;
    if (s != NATS_OK) {
        cluster_error(err, s, "tile snapshot %s", key);
        return -1;
    }
    if (head_parse(*e, h) != 0) {
        kvEntry_Destroy(*e);
        *e = NULL;
        error_set(err, "tile snapshot %s: not a snapshot head", key);
        return -1;
    }
    return 1;
}

static size_t part_room(const cluster *cl)
{
    return cl->max_payload > 2 * HEAD_ROOM ? (size_t)cl->max_payload - HEAD_ROOM : HEAD_ROOM;
}

static void parts_purge(cluster *cl, const char *world, int tx, int ty, uint64_t covers_seq,
                        int parts)
{
    for (int i = 0; i < parts; i++) {
        char key[256];
        part_key(world, tx, ty, covers_seq, i, key, sizeof key);
        kvStore_Purge(cl->tiles, key, NULL);
    }
}

static cluster_status parts_put(cluster *cl, const char *world, int tx, int ty, uint64_t covers_seq,
                                const uint8_t *data, size_t len, int parts, error_text *err)
{
    size_t room = part_room(cl);
    for (int i = 0; i < parts; i++) {
        char key[256];
        size_t at = (size_t)i * room, n = len - at < room ? len - at : room;
        part_key(world, tx, ty, covers_seq, i, key, sizeof key);
        natsStatus s = kvStore_Put(NULL, cl->tiles, key, data + at, (int)n);
        if (s != NATS_OK) {
            cluster_error(err, s, "tile snapshot part %s", key);
            return CLUSTER_ERROR;
        }
    }
    return CLUSTER_OK;
}

cluster_status cluster_snapshot_put(cluster *cl, const char *world, int tx, int ty,
                                    uint64_t covers_seq, const void *data, size_t len,
                                    error_text *err)
{
    if (!cluster_name_valid(world, "world", err))
        return CLUSTER_ERROR;
    char key[256];
    head_key(world, tx, ty, key, sizeof key);
    kvEntry *e = NULL;
    snap_head old = {0};
    int found = head_get(cl, key, &e, &old, err);
    kvEntry_Destroy(e);
    if (found < 0)
        return CLUSTER_ERROR;
    if (found && old.covers_seq > covers_seq) {
        error_set(err, "tile snapshot %s: a newer one (log sequence %" PRIu64 ") is stored", key,
                  old.covers_seq);
        return CLUSTER_FENCED;
    }
    size_t room = part_room(cl);
    int parts = len <= room ? 0 : (int)((len + room - 1) / room);
    if (parts > 0 && parts_put(cl, world, tx, ty, covers_seq, data, len, parts, err) != 0)
        return CLUSTER_ERROR;
    char line[128];
    int line_len =
        snprintf(line, sizeof line, "%s %" PRIu64 " %zu %d\n", SNAP_MAGIC, covers_seq, len, parts);
    size_t value_len = (size_t)line_len + (parts ? 0 : len);
    uint8_t *value = malloc(value_len);
    if (!value) {
        error_set(err, "out of memory");
        return CLUSTER_ERROR;
    }
    memcpy(value, line, (size_t)line_len);
    if (!parts && len)
        memcpy(value + line_len, data, len);
    uint64_t rev = 0;
    natsStatus s = found ? kvStore_Update(&rev, cl->tiles, key, value, (int)value_len, old.revision)
                         : kvStore_Create(&rev, cl->tiles, key, value, (int)value_len);
    free(value);
    if (s != NATS_OK) {
        if (parts)
            parts_purge(cl, world, tx, ty, covers_seq, parts);
        if (s == NATS_ERR) {
            error_set(err, "tile snapshot %s: written by another node meanwhile", key);
            return CLUSTER_FENCED;
        }
        cluster_error(err, s, "tile snapshot %s", key);
        return CLUSTER_ERROR;
    }
    if (found && old.parts > 0 && old.covers_seq != covers_seq)
        parts_purge(cl, world, tx, ty, old.covers_seq, old.parts);
    return CLUSTER_OK;
}

static int parts_get(cluster *cl, const char *world, int tx, int ty, const snap_head *h,
                     uint8_t *out, error_text *err)
{
    uint64_t at = 0;
    for (int i = 0; i < h->parts; i++) {
        char key[256];
        kvEntry *e = NULL;
        part_key(world, tx, ty, h->covers_seq, i, key, sizeof key);
        natsStatus s = kvStore_Get(&e, cl->tiles, key);
        if (s != NATS_OK) {
            cluster_error(err, s, "tile snapshot part %s", key);
            return -1;
        }
        uint64_t n = (uint64_t)kvEntry_ValueLen(e);
        if (at + n > h->len) {
            kvEntry_Destroy(e);
            error_set(err, "tile snapshot part %s: longer than its head says", key);
            return -1;
        }
        memcpy(out + at, kvEntry_Value(e), n);
        at += n;
        kvEntry_Destroy(e);
    }
    if (at != h->len) {
        error_set(err, "tile snapshot of %s tile %d,%d: %" PRIu64 " of %" PRIu64 " bytes", world,
                  tx, ty, at, h->len);
        return -1;
    }
    return 0;
}

int cluster_snapshot_get(cluster *cl, const char *world, int tx, int ty, uint8_t **data,
                         size_t *len, uint64_t *covers_seq, error_text *err)
{
    char key[256];
    head_key(world, tx, ty, key, sizeof key);
    kvEntry *e = NULL;
    snap_head h = {0};
    int found = head_get(cl, key, &e, &h, err);
    if (found <= 0)
        return found;
    uint8_t *out = malloc(h.len ? h.len : 1);
    int rc = out ? 0 : -1;
    if (!out)
        error_set(err, "out of memory");
    else if (h.parts == 0)
        memcpy(out, h.inline_data, h.len);
    else
        rc = parts_get(cl, world, tx, ty, &h, out, err);
    kvEntry_Destroy(e);
    if (rc != 0) {
        free(out);
        return -1;
    }
    *data = out;
    *len = h.len;
    *covers_seq = h.covers_seq;
    return 1;
}

/* Calls on_key for each live key of kv matching pattern; -1 on an error. */
static int keys_each(kvStore *kv, const char *pattern, void (*on_key)(void *ctx, const char *key),
                     void *ctx, int timeout_ms, error_text *err)
{
    kvWatchOptions o;
    kvWatchOptions_Init(&o);
    o.IgnoreDeletes = true;
    o.MetaOnly = true;
    kvWatcher *watcher = NULL;
    natsStatus s = kvStore_Watch(&watcher, kv, pattern, &o);
    while (s == NATS_OK) {
        kvEntry *e = NULL;
        s = kvWatcher_Next(&e, watcher, timeout_ms);
        if (s != NATS_OK || !e)
            break; /* NULL: every current value was delivered */
        on_key(ctx, kvEntry_Key(e));
        kvEntry_Destroy(e);
    }
    kvWatcher_Destroy(watcher);
    if (s != NATS_OK) {
        cluster_error(err, s, "listing %s", pattern);
        return -1;
    }
    return 0;
}

typedef struct tile_list_ctx {
    void (*on_tile)(void *ctx, int tx, int ty);
    void *ctx;
} tile_list_ctx;

static void on_head_key(void *ctx, const char *key)
{
    tile_list_ctx *t = ctx;
    const char *tile = strstr(key, ".tile.");
    int tx = 0, ty = 0;
    if (tile && sscanf(tile + 6, "%d_%d", &tx, &ty) == 2)
        t->on_tile(t->ctx, tx, ty);
}

int cluster_snapshot_list(cluster *cl, const char *world,
                          void (*on_tile)(void *ctx, int tx, int ty), void *ctx, error_text *err)
{
    if (!cluster_name_valid(world, "world", err))
        return -1;
    char pattern[128];
    snprintf(pattern, sizeof pattern, "%s.tile.*", world);
    tile_list_ctx t = {on_tile, ctx};
    return keys_each(cl->tiles, pattern, on_head_key, &t, cl->timeout_ms, err);
}

static void purge_key(void *ctx, const char *key)
{
    kvStore_Purge(((cluster *)ctx)->tiles, key, NULL);
}

int cluster_snapshot_delete_all(cluster *cl, const char *world, error_text *err)
{
    char pattern[128];
    snprintf(pattern, sizeof pattern, "%s.>", world);
    return keys_each(cl->tiles, pattern, purge_key, cl, cl->timeout_ms, err);
}

cluster_status cluster_world_add(cluster *cl, const char *name, const char *scene_json,
                                 error_text *err)
{
    if (!cluster_name_valid(name, "world", err))
        return CLUSTER_ERROR;
    size_t len = strlen(scene_json);
    if (len + HEAD_ROOM > (size_t)cl->max_payload) {
        error_set(err, "world %s: the scene is %zu bytes, more than NATS takes (%" PRId64 ")", name,
                  len, cl->max_payload - HEAD_ROOM);
        return CLUSTER_ERROR;
    }
    uint64_t rev = 0;
    natsStatus s = kvStore_Create(&rev, cl->worlds, name, scene_json, (int)len);
    if (s == NATS_ERR) {
        error_set(err, "world %s already exists", name);
        return CLUSTER_FENCED;
    }
    if (s != NATS_OK) {
        cluster_error(err, s, "registering world %s", name);
        return CLUSTER_ERROR;
    }
    return CLUSTER_OK;
}

int cluster_world_get(cluster *cl, const char *name, char **scene_json, error_text *err)
{
    if (!cluster_name_valid(name, "world", err))
        return -1;
    kvEntry *e = NULL;
    natsStatus s = kvStore_Get(&e, cl->worlds, name);
    if (s == NATS_NOT_FOUND)
        return 0;
    if (s != NATS_OK) {
        cluster_error(err, s, "world %s", name);
        return -1;
    }
    int n = kvEntry_ValueLen(e);
    char *out = malloc((size_t)n + 1);
    if (!out) {
        kvEntry_Destroy(e);
        error_set(err, "out of memory");
        return -1;
    }
    memcpy(out, kvEntry_Value(e), (size_t)n);
    out[n] = '\0';
    kvEntry_Destroy(e);
    *scene_json = out;
    return 1;
}

static int compare_names(const void *a, const void *b)
{
    return strcmp(*(char *const *)a, *(char *const *)b);
}

typedef struct name_list {
    char **names;
    int64_t count, capacity;
    int failed;
} name_list;

static void on_world_key(void *ctx, const char *key)
{
    name_list *l = ctx;
    char *copy = strdup(key);
    if (!copy || array_grow((void **)&l->names, &l->capacity, l->count + 1, sizeof *l->names)) {
        free(copy);
        l->failed = 1;
        return;
    }
    l->names[l->count++] = copy;
}

int cluster_world_list(cluster *cl, char ***names, int *count, error_text *err)
{
    name_list l = {0};
    int rc = keys_each(cl->worlds, ">", on_world_key, &l, cl->timeout_ms, err);
    if (rc == 0 && l.failed) {
        error_set(err, "out of memory");
        rc = -1;
    }
    if (rc != 0) {
        for (int64_t i = 0; i < l.count; i++)
            free(l.names[i]);
        free(l.names);
        return -1;
    }
    if (l.count > 1)
        qsort(l.names, (size_t)l.count, sizeof *l.names, compare_names);
    *names = l.names;
    *count = (int)l.count;
    return 0;
}

int cluster_world_remove(cluster *cl, const char *name, error_text *err)
{
    char *scene = NULL;
    int found = cluster_world_get(cl, name, &scene, err);
    free(scene);
    if (found <= 0)
        return found;
    natsStatus s = kvStore_Delete(cl->worlds, name);
    if (s != NATS_OK) {
        cluster_error(err, s, "removing world %s", name);
        return -1;
    }
    char subject[128];
    cluster_wal_subject(name, subject, sizeof subject);
    jsOptions jo;
    jsOptions_Init(&jo);
    jo.Wait = cl->timeout_ms;
    jo.Stream.Purge.Subject = subject;
    jsErrCode code = 0;
    s = js_PurgeStream(cl->js, CLUSTER_STREAM, &jo, &code);
    if (s != NATS_OK) {
        cluster_error(err, s, "purging the log of world %s", name);
        return -1;
    }
    kvStore_Purge(cl->leases, name, NULL);
    return cluster_snapshot_delete_all(cl, name, err) == 0 ? 1 : -1;
}
