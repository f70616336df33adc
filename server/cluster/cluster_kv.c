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

/* Parses a head's value; -1 when it is not one. */
static int head_parse(const uint8_t *value, size_t n, snap_head *h)
{
    const char *v = (const char *)value;
    const char *nl = v ? memchr(v, '\n', n) : NULL;
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
    h->inline_data = (const uint8_t *)nl + 1;
    if (h->parts == 0 && (uint64_t)(v + n - (nl + 1)) != h->len)
        return -1;
    return 0;
}

/* 1 found (*value kept for the caller to free; h points into it), 0 none, -1 error. */
static int head_get(cluster *cl, const char *key, uint8_t **value, snap_head *h, error_text *err)
{
    size_t n = 0;
    *value = NULL;
    int found = cluster_kv_read(cl, CLUSTER_BUCKET_TILES, key, value, &n, &h->revision, err);
    if (found <= 0)
        return found;
    if (head_parse(*value, n, h) != 0) {
        free(*value);
        *value = NULL;
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
    uint8_t *head = NULL;
    snap_head old = {0};
    int found = head_get(cl, key, &head, &old, err);
    free(head);
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
        uint8_t *part = NULL;
        size_t n = 0;
        uint64_t rev = 0;
        part_key(world, tx, ty, h->covers_seq, i, key, sizeof key);
        int found = cluster_kv_read(cl, CLUSTER_BUCKET_TILES, key, &part, &n, &rev, err);
        if (found <= 0) {
            if (found == 0)
                error_set(err, "tile snapshot part %s is missing", key);
            return -1;
        }
        if (at + n > h->len) {
            free(part);
            error_set(err, "tile snapshot part %s: longer than its head says", key);
            return -1;
        }
        memcpy(out + at, part, n);
        at += n;
        free(part);
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
    uint8_t *head = NULL;
    snap_head h = {0};
    int found = head_get(cl, key, &head, &h, err);
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
    free(head);
    if (rc != 0) {
        free(out);
        return -1;
    }
    *data = out;
    *len = h.len;
    *covers_seq = h.covers_seq;
    return 1;
}

typedef struct key_list {
    char **keys;
    int64_t count, capacity;
} key_list;

static void key_list_free(key_list *l)
{
    for (int64_t i = 0; i < l->count; i++)
        free(l->keys[i]);
    free(l->keys);
    memset(l, 0, sizeof *l);
}

/* One listing through a watcher (an ordered consumer on the bucket). */
static natsStatus keys_collect(kvStore *kv, const char *pattern, key_list *l, int timeout_ms)
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
        char *copy = strdup(kvEntry_Key(e));
        kvEntry_Destroy(e);
        if (!copy ||
            array_grow((void **)&l->keys, &l->capacity, l->count + 1, sizeof *l->keys) != 0) {
            free(copy);
            s = NATS_NO_MEMORY;
            break;
        }
        l->keys[l->count++] = copy;
    }
    kvWatcher_Destroy(watcher);
    return s;
}

/* Calls on_key for each live key of kv matching pattern; -1 on an error.
 * A listing that fails (a leader being elected after a lost server) is
 * started again for a while unless once; on_key only sees a complete one. */
static int keys_each(kvStore *kv, const char *pattern, void (*on_key)(void *ctx, const char *key),
                     void *ctx, int timeout_ms, int once, error_text *err)
{
    key_list l = {0};
    natsStatus s = NATS_OK;
    /* a stream leader lost with its server is elected again within seconds, more under load */
    double wait_ms = once ? 0 : 4.0 * timeout_ms > 15000 ? 4.0 * timeout_ms : 15000;
    for (double deadline = time_now_ms() + wait_ms;;) {
        s = keys_collect(kv, pattern, &l, timeout_ms);
        if (s == NATS_OK || s == NATS_NO_MEMORY || time_now_ms() > deadline)
            break;
        key_list_free(&l);
        nats_Sleep(200);
    }
    if (s != NATS_OK) {
        key_list_free(&l);
        cluster_error(err, s, "listing %s", pattern);
        return -1;
    }
    for (int64_t i = 0; i < l.count; i++)
        on_key(ctx, l.keys[i]);
    key_list_free(&l);
    return 0;
}

/* ---- the snapshot index: "TIDX1 <covers_seq> <count>\n" then "tx ty\n" per tile ---- */

typedef struct tile_set {
    int (*xy)[2];
    int64_t count, capacity;
} tile_set;

static int tile_set_add(tile_set *t, int tx, int ty)
{
    for (int64_t i = 0; i < t->count; i++)
        if (t->xy[i][0] == tx && t->xy[i][1] == ty)
            return 0;
    if (array_grow((void **)&t->xy, &t->capacity, t->count + 1, sizeof *t->xy) != 0)
        return -1;
    t->xy[t->count][0] = tx;
    t->xy[t->count][1] = ty;
    t->count++;
    return 0;
}

static int index_parse(const char *text, uint64_t *covers, tile_set *t)
{
    int count = 0, at = 0;
    if (sscanf(text, "TIDX1 %" SCNu64 " %d\n%n", covers, &count, &at) != 2 || count < 0)
        return -1;
    for (int i = 0; i < count; i++) {
        int tx, ty, n = 0;
        if (sscanf(text + at, "%d %d\n%n", &tx, &ty, &n) != 2 || tile_set_add(t, tx, ty) != 0)
            return -1;
        at += n;
    }
    return 0;
}

/* 1 found (*rev), 0 none, -1 error; tiles merged into t. */
static int index_read(cluster *cl, const char *key, uint64_t *covers, uint64_t *rev, tile_set *t,
                      error_text *err)
{
    uint8_t *text = NULL;
    size_t len = 0;
    int found = cluster_kv_read(cl, CLUSTER_BUCKET_TILES, key, &text, &len, rev, err);
    if (found == 1 && index_parse((const char *)text, covers, t) != 0) {
        error_set(err, "snapshot index %s is corrupt", key);
        found = -1;
    }
    free(text);
    return found;
}

static char *index_format(uint64_t covers, const tile_set *t, size_t *len)
{
    size_t cap = 64 + (size_t)t->count * 24;
    char *text = malloc(cap);
    if (!text)
        return NULL;
    size_t at = (size_t)snprintf(text, cap, "TIDX1 %" PRIu64 " %" PRId64 "\n", covers, t->count);
    for (int64_t i = 0; i < t->count; i++)
        at += (size_t)snprintf(text + at, cap - at, "%d %d\n", t->xy[i][0], t->xy[i][1]);
    *len = at;
    return text;
}

cluster_status cluster_snapshot_index_put(cluster *cl, const char *world, uint64_t covers_seq,
                                          const int (*tiles)[2], int count, error_text *err)
{
    char key[128];
    snprintf(key, sizeof key, "%s.index", world);
    for (int attempt = 0; attempt < 20; attempt++) {
        tile_set t = {0};
        uint64_t covers = 0, rev = 0;
        int found = index_read(cl, key, &covers, &rev, &t, err);
        int ok = found >= 0;
        for (int i = 0; ok && i < count; i++)
            ok = tile_set_add(&t, tiles[i][0], tiles[i][1]) == 0;
        size_t len = 0;
        char *text = ok ? index_format(covers > covers_seq ? covers : covers_seq, &t, &len) : NULL;
        free(t.xy);
        if (!text) {
            if (found >= 0)
                error_set(err, "out of memory");
            return CLUSTER_ERROR;
        }
        if (len + HEAD_ROOM > (size_t)cl->max_payload) {
            free(text);
            error_set(err, "snapshot index %s: %zu bytes, more than NATS takes", key, len);
            return CLUSTER_ERROR;
        }
        uint64_t new_rev = 0;
        natsStatus s = found ? kvStore_Update(&new_rev, cl->tiles, key, text, (int)len, rev)
                             : kvStore_Create(&new_rev, cl->tiles, key, text, (int)len);
        free(text);
        if (s == NATS_OK)
            return CLUSTER_OK;
        if (s != NATS_ERR) {
            cluster_error(err, s, "snapshot index %s", key);
            return CLUSTER_ERROR;
        }
        /* another writer moved it meanwhile: merge again */
    }
    error_set(err, "snapshot index %s: too many concurrent writers", key);
    return CLUSTER_ERROR;
}

int cluster_snapshot_index_get(cluster *cl, const char *world, uint64_t *covers_seq,
                               int (**tiles)[2], int *count, error_text *err)
{
    char key[128];
    snprintf(key, sizeof key, "%s.index", world);
    tile_set t = {0};
    uint64_t rev = 0;
    *covers_seq = 0;
    int found = index_read(cl, key, covers_seq, &rev, &t, err);
    if (found != 1) {
        free(t.xy);
        *tiles = NULL;
        *count = 0;
        return found;
    }
    *tiles = t.xy;
    *count = (int)t.count;
    return 1;
}

static void purge_key(void *ctx, const char *key)
{
    kvStore_Purge(((cluster *)ctx)->tiles, key, NULL);
}

int cluster_snapshot_delete_all(cluster *cl, const char *world, error_text *err)
{
    char pattern[128];
    snprintf(pattern, sizeof pattern, "%s.>", world);
    return keys_each(cl->tiles, pattern, purge_key, cl, cl->timeout_ms, 0, err);
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
    uint8_t *data = NULL;
    size_t len = 0;
    uint64_t rev = 0;
    int found = cluster_kv_read(cl, CLUSTER_BUCKET_WORLDS, name, &data, &len, &rev, err);
    if (found == 1)
        *scene_json = (char *)data;
    return found;
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

static int world_list(cluster *cl, int once, char ***names, int *count, error_text *err)
{
    name_list l = {0};
    int rc = keys_each(cl->worlds, ">", on_world_key, &l, cl->timeout_ms, once, err);
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

int cluster_world_list(cluster *cl, char ***names, int *count, error_text *err)
{
    return world_list(cl, 0, names, count, err);
}

int cluster_world_list_now(cluster *cl, char ***names, int *count, error_text *err)
{
    return world_list(cl, 1, names, count, err);
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
    /* every message, one by one: not a purge (cluster_log_purge_below says why) */
    if (cluster_log_purge_below(cl, name, UINT64_MAX, err) != CLUSTER_OK)
        return -1;
    kvStore_Purge(cl->leases, name, NULL);
    return cluster_snapshot_delete_all(cl, name, err) == 0 ? 1 : -1;
}
