/*
 * test_proto.c: the C codec of proto/ against the shared test vectors
 * (proto/vectors/vectors.json, read from $TERRAD_SOURCE_DIR), plus what the
 * vectors cannot hold: every prefix of every valid frame is refused, encoders
 * refuse NaN and small buffers, and a randomized round trip of the rectangle
 * codec and the mirror.
 */
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "terrad_proto.h"
#include "check.h"

/* ---- JSON helpers ---- */

static char *read_file(const char *path)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return NULL;
    fseek(f, 0, SEEK_END);
    long n = ftell(f);
    fseek(f, 0, SEEK_SET);
    char *s = malloc((size_t)n + 1);
    if (s && fread(s, 1, (size_t)n, f) != (size_t)n) {
        free(s);
        s = NULL;
    }
    if (s)
        s[n] = 0;
    fclose(f);
    return s;
}

static size_t unhex(const char *s, uint8_t **out)
{
    size_t n = strlen(s) / 2;
    uint8_t *p = malloc(n + 1);
    for (size_t i = 0; i < n; i++) {
        unsigned v;
        sscanf(s + 2 * i, "%2x", &v);
        p[i] = (uint8_t)v;
    }
    *out = p;
    return n;
}

static const cJSON *get(const cJSON *o, const char *key)
{
    return cJSON_GetObjectItemCaseSensitive(o, key);
}
static double num(const cJSON *o, const char *key)
{
    return get(o, key)->valuedouble;
}
static const char *str(const cJSON *o, const char *key)
{
    return get(o, key)->valuestring;
}
static uint64_t u64(const cJSON *o, const char *key)
{
    return strtoull(str(o, key), NULL, 10);
}
static int64_t i64(const cJSON *o, const char *key)
{
    return strtoll(str(o, key), NULL, 10);
}

static int32_t *int_list(const cJSON *a, size_t *n)
{
    size_t k = (size_t)cJSON_GetArraySize(a);
    int32_t *v = malloc((k + 1) * sizeof *v);
    size_t i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, a) v[i++] = (int32_t)e->valuedouble;
    *n = k;
    return v;
}

static int same_float(float a, double b)
{
    return a == (float)b;
}

/* ---- per-type checks of valid vectors ---- */

static void check_pose(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_pose poses[16];
    uint32_t seq;
    size_t count;
    int rc = terrad_pose_batch_decode(b, n, &seq, poses, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "poses");
    CHECK(seq == (uint32_t)num(f, "seq"), "%s: seq", name);
    CHECK(count == (size_t)cJSON_GetArraySize(a), "%s: count", name);
    terrad_pose want[16];
    size_t i = 0;
    const cJSON *p;
    cJSON_ArrayForEach(p, a)
    {
        terrad_pose w = {(uint32_t)num(p, "id"), (float)num(p, "x"),  (float)num(p, "y"),
                         (float)num(p, "z"),     (float)num(p, "qw"), (float)num(p, "qx"),
                         (float)num(p, "qy"),    (float)num(p, "qz")};
        want[i] = w;
        if (i < count)
            CHECK(poses[i].id == w.id && same_float(poses[i].x, w.x) &&
                      same_float(poses[i].y, w.y) && same_float(poses[i].z, w.z) &&
                      same_float(poses[i].qw, w.qw) && same_float(poses[i].qx, w.qx) &&
                      same_float(poses[i].qy, w.qy) && same_float(poses[i].qz, w.qz),
                  "%s: pose %zu", name, i);
        i++;
    }
    uint8_t out[1024];
    size_t len;
    rc = terrad_pose_batch_encode(out, sizeof out, &len, seq, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

static void check_delta(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_rect rects[16];
    uint64_t tick;
    size_t count;
    int rc = terrad_delta_decode(b, n, &tick, rects, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "rects");
    CHECK(tick == u64(f, "tick"), "%s: tick", name);
    CHECK(count == (size_t)cJSON_GetArraySize(a), "%s: count", name);
    terrad_rect want[16];
    uint8_t *datas[16];
    size_t i = 0;
    const cJSON *r;
    cJSON_ArrayForEach(r, a)
    {
        terrad_rect w = {(int32_t)num(r, "x"),
                         (int32_t)num(r, "y"),
                         (uint16_t)num(r, "w"),
                         (uint16_t)num(r, "h"),
                         (uint32_t)num(r, "base_version"),
                         (uint32_t)num(r, "new_version"),
                         (uint8_t)num(r, "encoding"),
                         0,
                         NULL};
        w.data_len = (uint32_t)unhex(str(r, "data_hex"), &datas[i]);
        w.data = datas[i];
        want[i] = w;
        if (i >= count) {
            i++;
            continue;
        }
        const terrad_rect *g = &rects[i];
        CHECK(g->x == w.x && g->y == w.y && g->w == w.w && g->h == w.h &&
                  g->base_version == w.base_version && g->new_version == w.new_version &&
                  g->encoding == w.encoding && g->data_len == w.data_len &&
                  memcmp(g->data, w.data, w.data_len) == 0,
              "%s: rect %zu fields", name, i);
        size_t cells = (size_t)w.w * w.h, nv;
        int32_t *values = int_list(get(r, "values"), &nv);
        CHECK(nv == cells, "%s: rect %zu value count", name, i);
        int32_t *got = malloc(cells * sizeof *got);
        rc = terrad_rect_decompress(NULL, g->data, g->data_len, cells, got, cells);
        CHECK(rc == 0 && memcmp(got, values, cells * 4) == 0, "%s: rect %zu decompress: %s", name,
              i, terrad_err_name(rc));
        rc = terrad_rect_decompress(NULL, g->data, g->data_len, cells, got, cells - 1);
        CHECK(rc == TERRAD_E_TOO_LARGE, "%s: rect %zu: output smaller than w*h", name, i);
        /* The packing is exact; the compression is checked by round trip. */
        uint8_t *packed, *mine = malloc(cells * 4);
        size_t pn = unhex(str(r, "packed_hex"), &packed);
        terrad_rect_pack(values, cells, mine);
        CHECK(pn == cells * 4 && memcmp(packed, mine, pn) == 0, "%s: rect %zu packing", name, i);
        terrad_rect_unpack(packed, cells, got);
        CHECK(memcmp(got, values, cells * 4) == 0, "%s: rect %zu unpack", name, i);
        size_t cap = terrad_rect_compress_bound(cells), zn;
        uint8_t *z = malloc(cap);
        rc = terrad_rect_compress(NULL, values, cells, z, cap, &zn);
        memset(got, 0x55, cells * 4);
        CHECK(rc == 0 && terrad_rect_decompress(NULL, z, zn, cells, got, cells) == 0 &&
                  memcmp(got, values, cells * 4) == 0,
              "%s: rect %zu compress round trip", name, i);
        if (get(r, "old")) {
            size_t k;
            int32_t *oldh = int_list(get(r, "old"), &k), *newh = int_list(get(r, "new"), &k);
            int32_t *d = malloc(cells * sizeof *d);
            terrad_rect_diff(oldh, newh, cells, d);
            CHECK(memcmp(d, values, cells * 4) == 0, "%s: rect %zu diff", name, i);
            size_t touched = terrad_rect_apply_values(g, values, oldh, w.x, w.y, w.w, w.h);
            CHECK(touched == cells && memcmp(oldh, newh, cells * 4) == 0, "%s: rect %zu apply",
                  name, i);
            free(oldh);
            free(newh);
            free(d);
        }
        free(values);
        free(got);
        free(packed);
        free(mine);
        free(z);
        i++;
    }
    uint8_t *out = malloc(n + 1);
    size_t len;
    rc = terrad_delta_encode(out, n, &len, tick, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
    if (n > 0)
        CHECK(terrad_delta_encode(out, n - 1, &len, tick, want, i) == TERRAD_E_BUFFER_TOO_SMALL,
              "%s: encode into a buffer one byte short", name);
    free(out);
    for (size_t k = 0; k < i; k++)
        free(datas[k]);
}

static void check_contact(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_contact cs[16];
    uint64_t tick;
    size_t count;
    int rc = terrad_contact_decode(b, n, &tick, cs, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "contacts");
    CHECK(tick == u64(f, "tick"), "%s: tick", name);
    CHECK(count == (size_t)cJSON_GetArraySize(a), "%s: count", name);
    terrad_contact want[16];
    size_t i = 0;
    const cJSON *c;
    cJSON_ArrayForEach(c, a)
    {
        terrad_contact w;
        memset(&w, 0, sizeof w);
        w.id = (uint32_t)num(c, "id");
        w.volume = i64(c, "volume");
        w.cells = (uint32_t)num(c, "cells");
        w.area_m2 = (float)num(c, "area_m2");
        for (int k = 0; k < 3; k++) {
            w.deepest[k] = (float)cJSON_GetArrayItem(get(c, "deepest"), k)->valuedouble;
            w.normal[k] = (float)cJSON_GetArrayItem(get(c, "normal"), k)->valuedouble;
        }
        w.support_height_m = (float)num(c, "support_height_m");
        want[i] = w;
        if (i < count) {
            const terrad_contact *g = &cs[i];
            int same = g->id == w.id && g->volume == w.volume && g->cells == w.cells &&
                       g->area_m2 == w.area_m2 && g->support_height_m == w.support_height_m;
            for (int k = 0; k < 3; k++)
                same = same && g->deepest[k] == w.deepest[k] && g->normal[k] == w.normal[k];
            CHECK(same, "%s: contact %zu", name, i);
        }
        i++;
    }
    uint8_t out[1024];
    size_t len;
    rc = terrad_contact_encode(out, sizeof out, &len, tick, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

static void check_colliders(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_collider_state cs[16];
    uint64_t tick;
    size_t count;
    int rc = terrad_colliders_decode(b, n, &tick, cs, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "colliders");
    CHECK(tick == u64(f, "tick"), "%s: tick", name);
    CHECK(count == (size_t)cJSON_GetArraySize(a), "%s: count", name);
    terrad_collider_state want[16];
    size_t i = 0;
    const cJSON *c;
    cJSON_ArrayForEach(c, a)
    {
        if (i >= 16)
            break;
        terrad_collider_state w;
        memset(&w, 0, sizeof w);
        w.id = (uint32_t)num(c, "id");
        w.owner = (uint8_t)num(c, "owner");
        w.kind = (uint8_t)num(c, "kind");
        for (int k = 0; k < 3; k++) {
            w.dims[k] = (float)cJSON_GetArrayItem(get(c, "dims"), k)->valuedouble;
            w.p[k] = (float)cJSON_GetArrayItem(get(c, "p"), k)->valuedouble;
        }
        for (int k = 0; k < 4; k++)
            w.q[k] = (float)cJSON_GetArrayItem(get(c, "q"), k)->valuedouble;
        want[i] = w;
        if (i < count) {
            const terrad_collider_state *g = &cs[i];
            int same = g->id == w.id && g->owner == w.owner && g->kind == w.kind;
            for (int k = 0; k < 3; k++)
                same = same && g->dims[k] == w.dims[k] && g->p[k] == w.p[k];
            for (int k = 0; k < 4; k++)
                same = same && g->q[k] == w.q[k];
            CHECK(same, "%s: collider %zu", name, i);
        }
        i++;
    }
    /* the grousers extension: each entry's grousers (null: none), the flag said by the fields */
    terrad_collider_grousers lugs[16], want_lugs[16];
    size_t nl = 99;
    const cJSON *flagged = cJSON_GetObjectItemCaseSensitive(f, "grousers");
    rc = terrad_colliders_grousers(b, n, lugs, 16, &nl);
    CHECK(rc == 0 && nl == (cJSON_IsTrue(flagged) ? count : 0), "%s: grousers: %s, %zu", name,
          terrad_err_name(rc), nl);
    i = 0;
    cJSON_ArrayForEach(c, a)
    {
        if (i >= 16)
            break;
        const cJSON *g = cJSON_GetObjectItemCaseSensitive(c, "grousers");
        terrad_collider_grousers w = {0};
        if (cJSON_IsObject(g))
            w = (terrad_collider_grousers){(uint16_t)num(g, "count"), (float)num(g, "height"),
                                           (float)num(g, "thickness")};
        want_lugs[i] = w;
        if (i < nl)
            CHECK(lugs[i].count == w.count && lugs[i].height_m == w.height_m &&
                      lugs[i].thickness_m == w.thickness_m,
                  "%s: grousers of collider %zu", name, i);
        i++;
    }
    uint8_t out[1024];
    size_t len;
    rc = cJSON_IsTrue(flagged)
             ? terrad_colliders_encode_grousers(out, sizeof out, &len, tick, want, want_lugs, i)
             : terrad_colliders_encode(out, sizeof out, &len, tick, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

static void check_footprints(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_footprint es[16];
    uint64_t tick;
    size_t count;
    int rc = terrad_footprints_decode(b, n, &tick, es, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "footprints");
    CHECK(tick == u64(f, "tick"), "%s: tick", name);
    CHECK(count == (size_t)cJSON_GetArraySize(a), "%s: count", name);
    terrad_footprint want[16];
    size_t i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, a)
    {
        if (i >= 16)
            break;
        terrad_footprint w = {(uint32_t)num(e, "collider"), (float)num(e, "x"),
                              (float)num(e, "y"),           (float)num(e, "yaw"),
                              (float)num(e, "size_m"),      (float)num(e, "strength_m")};
        want[i] = w;
        if (i < count) {
            const terrad_footprint *g = &es[i];
            CHECK(g->collider == w.collider && g->x == w.x && g->y == w.y && g->yaw == w.yaw &&
                      g->size_m == w.size_m && g->strength_m == w.strength_m,
                  "%s: event %zu", name, i);
        }
        i++;
    }
    uint8_t out[1024];
    size_t len;
    rc = terrad_footprints_encode(out, sizeof out, &len, tick, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

/* A float array of three from a vector's field. */
static void floats3(const cJSON *o, const char *key, float *out)
{
    const cJSON *a = get(o, key);
    for (int k = 0; k < 3; k++)
        out[k] = (float)cJSON_GetArrayItem(a, k)->valuedouble;
}

static void check_forces(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_force fs[16], want[16];
    uint64_t tick;
    size_t count;
    int rc = terrad_forces_decode(b, n, &tick, fs, 16, &count);
    CHECK(rc == 0, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    const cJSON *a = get(f, "forces");
    CHECK(tick == u64(f, "tick") && count == (size_t)cJSON_GetArraySize(a), "%s: tick, count",
          name);
    size_t i = 0;
    const cJSON *e;
    cJSON_ArrayForEach(e, a)
    {
        if (i >= 16)
            break;
        terrad_force w = {.id = (uint32_t)num(e, "id"),
                          .sinkage_m = (float)num(e, "sinkage_m"),
                          .area_m2 = (float)num(e, "area_m2"),
                          .patch_width_m = (float)num(e, "patch_width_m"),
                          .slip = (float)num(e, "slip"),
                          .cells = (uint32_t)num(e, "cells")};
        floats3(e, "force", w.force);
        floats3(e, "torque", w.torque);
        want[i] = w;
        if (i < count)
            CHECK(memcmp(&fs[i], &w, sizeof w) == 0, "%s: entry %zu", name, i);
        i++;
    }
    uint8_t out[1024];
    size_t len;
    rc = terrad_forces_encode(out, sizeof out, &len, tick, want, i);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

/* STEP: the head and its poses (fields as POSE_BATCH's, set after set), then encode back. */
static void check_step(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_pose poses[16], want[16];
    terrad_step_head h;
    long bad;
    int rc = terrad_step_decode(b, n, &h, poses, 16, &bad);
    CHECK(rc == 0 && bad == -1, "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    CHECK(h.seq == (uint32_t)num(f, "seq") && h.ticks == (uint32_t)num(f, "ticks") &&
              h.count == (uint16_t)num(f, "count") && h.sets == (uint16_t)num(f, "sets"),
          "%s: head", name);
    size_t i = 0;
    const cJSON *p;
    cJSON_ArrayForEach(p, get(f, "poses"))
    {
        terrad_pose w = {(uint32_t)num(p, "id"), (float)num(p, "x"),  (float)num(p, "y"),
                         (float)num(p, "z"),     (float)num(p, "qw"), (float)num(p, "qx"),
                         (float)num(p, "qy"),    (float)num(p, "qz")};
        CHECK(i < 16 && memcmp(&poses[i], &w, sizeof w) == 0, "%s: pose %zu", name, i);
        want[i++] = w;
    }
    CHECK(i == (size_t)h.count * h.sets, "%s: %zu poses", name, i);
    uint8_t out[1024];
    size_t len;
    rc = terrad_step_encode(out, sizeof out, &len, &h, want);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

static void check_checksum(const char *name, const cJSON *f, const uint8_t *b, size_t n)
{
    terrad_tile_sum sums[16];
    uint64_t tick;
    uint32_t sub;
    size_t count;
    int rc = terrad_checksum_decode(b, n, &tick, &sub, sums, 16, &count);
    CHECK(rc == 0 && tick == u64(f, "tick") && sub == (uint32_t)num(f, "subscription"),
          "%s: decode: %s", name, terrad_err_name(rc));
    if (rc)
        return;
    size_t i = 0;
    const cJSON *t;
    cJSON_ArrayForEach(t, get(f, "tiles"))
    {
        CHECK(i < count && sums[i].tile_x == (int32_t)num(t, "tile_x") &&
                  sums[i].tile_y == (int32_t)num(t, "tile_y") &&
                  sums[i].version == (uint32_t)num(t, "version") && sums[i].hash == u64(t, "hash"),
              "%s: tile %zu", name, i);
        i++;
    }
    CHECK(i == count, "%s: %zu tiles", name, i);
    uint8_t out[1024];
    size_t len;
    rc = terrad_checksum_encode(out, sizeof out, &len, tick, sub, sums, count);
    CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
}

/* The tile hash of each "hashes" entry, and a mirror's view of it: one height
 * changed makes its tile differ. */
static void check_hashes(const cJSON *root)
{
    const cJSON *e;
    int k = 0;
    cJSON_ArrayForEach(e, get(root, "hashes"))
    {
        uint32_t w = (uint32_t)num(e, "w"), h = (uint32_t)num(e, "h");
        int32_t *v = calloc((size_t)w * h + 1, sizeof *v);
        size_t i = 0;
        const cJSON *x;
        cJSON_ArrayForEach(x, get(e, "heights")) v[i++] = (int32_t)x->valuedouble;
        CHECK(i == (size_t)w * h && terrad_heights_hash(v, w, w, h) == u64(e, "hash"), "hash: %s",
              str(e, "about"));
        free(v);
        k++;
    }
    CHECK(k >= 5, "%d hash vectors", k);
    /* a region of 100 x 70 cells at (30, 40) over 64-cell tiles: the part of tile (1, 1) */
    int32_t *heights = calloc(100 * 70, sizeof *heights);
    uint32_t versions[6];
    terrad_mirror m;
    CHECK(terrad_mirror_init(&m, 30, 40, 100, 70, 64, heights, versions) == 0, "mirror init");
    for (int i = 0; i < 100 * 70; i++)
        heights[i] = i * 3;
    versions[4] = 5; /* tile (1, 1): column 1, row 1 of the region's 3 x 2 tiles */
    /* its part: x 64..127, y 64..109 -> region columns 34..97, rows 24..69 */
    uint64_t want = terrad_heights_hash(heights + 24 * 100 + 34, 100, 64, 46);
    terrad_tile_sum sum = {1, 1, 5, want};
    CHECK(terrad_mirror_tile_differs(&m, &sum) == 0, "a mirror agrees with its own hash");
    heights[30 * 100 + 40]++;
    CHECK(terrad_mirror_tile_differs(&m, &sum) == 1, "one height changed: the tile differs");
    heights[30 * 100 + 40]--;
    sum.version = 6;
    CHECK(terrad_mirror_tile_differs(&m, &sum) == 1, "another version: the tile differs");
    sum = (terrad_tile_sum){0, 1, 5, 0};
    CHECK(terrad_mirror_tile_differs(&m, &sum) == 0, "a tile not held is not compared");
    sum = (terrad_tile_sum){3, 1, 5, 0};
    CHECK(terrad_mirror_tile_differs(&m, &sum) == -1, "a tile outside the region");
    free(heights);
}

/* Each "base_rects" payload (encoding 2, PROTOCOL.md "Base snapshots") or
 * "slope_rects" payload (encoding 3, "Slope snapshots") decodes to its
 * values, or is refused with its error. */
static void check_coded_rects(const cJSON *root, const char *key,
                              int (*decode)(const uint8_t *, size_t, uint32_t, uint32_t, int32_t *,
                                            size_t))
{
    const cJSON *e;
    int k = 0;
    cJSON_ArrayForEach(e, get(root, key))
    {
        uint32_t w = (uint32_t)num(e, "w"), h = (uint32_t)num(e, "h");
        size_t cells = (size_t)w * h;
        uint8_t *data;
        size_t len = unhex(str(e, "data_hex"), &data);
        int32_t *out = calloc(cells, sizeof *out);
        int rc = decode(data, len, w, h, out, cells);
        const char *want = str(e, "error");
        if (*want) {
            CHECK(rc != TERRAD_OK && strcmp(terrad_err_name(rc), want) == 0, "%s: %s: got %s", key,
                  str(e, "about"), rc ? terrad_err_name(rc) : "ok");
        } else {
            size_t i = 0;
            int same = rc == TERRAD_OK;
            const cJSON *x;
            cJSON_ArrayForEach(x, get(e, "values"))
            {
                same &= i < cells && out[i] == (int32_t)x->valuedouble;
                i++;
            }
            CHECK(same && i == cells, "%s: %s decodes to its values (%d)", key, str(e, "about"),
                  rc);
        }
        free(out);
        free(data);
        k++;
    }
    CHECK(k >= 8, "%d %s vectors", k, key);
}

static void check_small(const char *name, const char *type, const cJSON *f, const uint8_t *b,
                        size_t n)
{
    if (strcmp(type, "STEPPED") == 0) {
        uint64_t tick;
        uint32_t seq, ticks;
        uint8_t out[64];
        size_t len;
        int rc = terrad_stepped_decode(b, n, &tick, &seq, &ticks);
        CHECK(rc == 0 && tick == u64(f, "tick") && seq == (uint32_t)num(f, "seq") &&
                  ticks == (uint32_t)num(f, "ticks"),
              "%s: decode", name);
        rc = terrad_stepped_encode(out, sizeof out, &len, tick, seq, ticks);
        CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
        return;
    }
    uint8_t out[64];
    size_t len;
    if (strcmp(type, "ACK") == 0) {
        uint64_t tick;
        uint32_t seq;
        int rc = terrad_ack_decode(b, n, &tick, &seq);
        CHECK(rc == 0 && tick == u64(f, "tick") && seq == (uint32_t)num(f, "seq"), "%s: decode",
              name);
        rc = terrad_ack_encode(out, sizeof out, &len, u64(f, "tick"), (uint32_t)num(f, "seq"));
        CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
    } else {
        uint8_t t = strcmp(type, "PING") == 0 ? TERRAD_MSG_PING : TERRAD_MSG_PONG, got;
        uint64_t nonce;
        int rc = terrad_ping_decode(b, n, &got, &nonce);
        CHECK(rc == 0 && got == t && nonce == u64(f, "nonce"), "%s: decode", name);
        rc = terrad_ping_encode(out, sizeof out, &len, t, u64(f, "nonce"));
        CHECK(rc == 0 && len == n && memcmp(out, b, n) == 0, "%s: encode", name);
    }
}

/* Decode with the decoder for type; a DELTA that decodes then has each
 * rectangle decompressed. The first error. */
static int decode_any(const char *type, const uint8_t *b, size_t n)
{
    if (strcmp(type, "POSE_BATCH") == 0) {
        terrad_pose poses[16];
        uint32_t seq;
        size_t count;
        return terrad_pose_batch_decode(b, n, &seq, poses, 16, &count);
    }
    if (strcmp(type, "DELTA") == 0) {
        terrad_rect rects[16];
        uint64_t tick;
        size_t count;
        int rc = terrad_delta_decode(b, n, &tick, rects, 16, &count);
        for (size_t i = 0; rc == 0 && i < count; i++) {
            size_t cells = (size_t)rects[i].w * rects[i].h;
            int32_t *out = malloc(cells * sizeof *out);
            rc = terrad_rect_decompress(NULL, rects[i].data, rects[i].data_len, cells, out, cells);
            free(out);
        }
        return rc;
    }
    if (strcmp(type, "CONTACT") == 0) {
        terrad_contact cs[16];
        uint64_t tick;
        size_t count;
        return terrad_contact_decode(b, n, &tick, cs, 16, &count);
    }
    if (strcmp(type, "ACK") == 0) {
        uint64_t tick;
        uint32_t seq;
        return terrad_ack_decode(b, n, &tick, &seq);
    }
    if (strcmp(type, "COLLIDERS") == 0) {
        terrad_collider_state cs[16];
        uint64_t tick;
        size_t count;
        int rc = terrad_colliders_decode(b, n, &tick, cs, 16, &count);
        if (rc == 0) { /* the extension's reader refuses exactly what the decoder does */
            terrad_collider_grousers lugs[16];
            CHECK(terrad_colliders_grousers(b, n, lugs, 16, &count) == 0, "grousers reader");
        }
        return rc;
    }
    if (strcmp(type, "FOOTPRINTS") == 0) {
        terrad_footprint es[16];
        uint64_t tick;
        size_t count;
        return terrad_footprints_decode(b, n, &tick, es, 16, &count);
    }
    if (strcmp(type, "FORCES") == 0) {
        terrad_force fs[16];
        uint64_t tick;
        size_t count;
        return terrad_forces_decode(b, n, &tick, fs, 16, &count);
    }
    if (strcmp(type, "STEP") == 0) {
        terrad_pose poses[16];
        terrad_step_head h;
        return terrad_step_decode(b, n, &h, poses, 16, NULL);
    }
    if (strcmp(type, "STEPPED") == 0) {
        uint64_t tick;
        uint32_t seq, ticks;
        return terrad_stepped_decode(b, n, &tick, &seq, &ticks);
    }
    if (strcmp(type, "CHECKSUM") == 0) {
        terrad_tile_sum sums[16];
        uint64_t tick;
        uint32_t sub;
        size_t count;
        return terrad_checksum_decode(b, n, &tick, &sub, sums, 16, &count);
    }
    uint8_t t;
    uint64_t nonce;
    return terrad_ping_decode(b, n, &t, &nonce);
}

static void check_vectors(const cJSON *root)
{
    const cJSON *e;
    int k = 0;
    cJSON_ArrayForEach(e, get(root, "errors"))
    {
        int code = (int)num(e, "code");
        CHECK(terrad_err_name(code) && strcmp(terrad_err_name(code), str(e, "name")) == 0 &&
                  terrad_err_from_name(str(e, "name")) == code,
              "error table: %d %s", code, str(e, "name"));
        k++;
    }
    CHECK(k == TERRAD_ERR_LAST, "error table has %d entries", k);
    cJSON_ArrayForEach(e, get(root, "types"))
    {
        const char *nm = terrad_msg_type_name((int)num(e, "code"));
        CHECK(nm && strcmp(nm, str(e, "name")) == 0, "type table: %s", str(e, "name"));
    }

    const cJSON *v;
    cJSON_ArrayForEach(v, get(root, "vectors"))
    {
        const char *name = str(v, "name"), *type = str(v, "type");
        uint8_t *b;
        size_t n = unhex(str(v, "hex"), &b);
        if (cJSON_IsTrue(get(v, "valid"))) {
            const cJSON *f = get(v, "fields");
            if (strcmp(type, "POSE_BATCH") == 0)
                check_pose(name, f, b, n);
            else if (strcmp(type, "DELTA") == 0)
                check_delta(name, f, b, n);
            else if (strcmp(type, "CONTACT") == 0)
                check_contact(name, f, b, n);
            else if (strcmp(type, "COLLIDERS") == 0)
                check_colliders(name, f, b, n);
            else if (strcmp(type, "FOOTPRINTS") == 0)
                check_footprints(name, f, b, n);
            else if (strcmp(type, "FORCES") == 0)
                check_forces(name, f, b, n);
            else if (strcmp(type, "STEP") == 0)
                check_step(name, f, b, n);
            else if (strcmp(type, "CHECKSUM") == 0)
                check_checksum(name, f, b, n);
            else
                check_small(name, type, f, b, n);
            /* Every proper prefix of a valid frame is refused. */
            int prefixes_refused = 1;
            for (size_t cut = 0; cut < n; cut++)
                if (decode_any(type, b, cut) == 0)
                    prefixes_refused = 0;
            CHECK(prefixes_refused, "%s: a prefix decoded", name);
        } else {
            int want = terrad_err_from_name(str(v, "error"));
            int rc = decode_any(type, b, n);
            CHECK(rc == want, "%s: got %s, want %s", name, terrad_err_name(rc), str(v, "error"));
        }
        free(b);
    }
}

static void check_scenarios(const cJSON *root)
{
    const cJSON *s;
    cJSON_ArrayForEach(s, get(root, "mirror_scenarios"))
    {
        const char *name = str(s, "name");
        const cJSON *reg = get(s, "region");
        uint32_t w = (uint32_t)num(reg, "w"), h = (uint32_t)num(reg, "h");
        int32_t x = (int32_t)num(reg, "x"), y = (int32_t)num(reg, "y");
        uint32_t tile = (uint32_t)num(s, "tile_size");
        size_t tiles = terrad_mirror_tile_count(x, y, w, h, tile);
        int32_t *heights = calloc((size_t)w * h, sizeof *heights);
        uint32_t *versions = calloc(tiles, sizeof *versions);
        terrad_mirror m;
        CHECK(terrad_mirror_init(&m, x, y, w, h, tile, heights, versions) == 0, "%s: init", name);
        const cJSON *st;
        int step = 0;
        cJSON_ArrayForEach(st, get(s, "steps"))
        {
            uint8_t *b;
            size_t n = unhex(str(st, "frame_hex"), &b);
            terrad_rect rects[16];
            uint64_t tick;
            size_t count;
            int rc = terrad_delta_decode(b, n, &tick, rects, 16, &count);
            CHECK(rc == 0, "%s step %d: decode", name, step);
            int32_t scratch[4096];
            if (rc == 0)
                rc = terrad_mirror_apply(&m, NULL, rects, count, scratch, 4096);
            const char *want = str(st, "error");
            CHECK(strcmp(rc ? terrad_err_name(rc) : "", want) == 0,
                  "%s step %d: got '%s', want '%s'", name, step, rc ? terrad_err_name(rc) : "",
                  want);
            size_t nh, nv;
            int32_t *wh = int_list(get(st, "heights"), &nh);
            int32_t *wv = int_list(get(st, "versions"), &nv);
            CHECK(nh == (size_t)w * h && memcmp(wh, heights, nh * 4) == 0, "%s step %d: heights",
                  name, step);
            int same = nv == tiles;
            for (size_t i = 0; same && i < nv; i++)
                same = (uint32_t)wv[i] == versions[i];
            CHECK(same, "%s step %d: versions", name, step);
            free(wh);
            free(wv);
            free(b);
            step++;
        }
        free(heights);
        free(versions);
    }
}

/* ---- what the vectors cannot hold ---- */

static uint64_t rng = 0x9e3779b97f4a7c15ull;
static uint32_t next(void)
{
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 16);
}

static void test_encoder_refusals(void)
{
    uint8_t buf[256];
    size_t len;
    terrad_pose p = {1, 0, 0, 0, 1, 0, 0, 0};
    p.y = NAN;
    CHECK(terrad_pose_batch_encode(buf, sizeof buf, &len, 0, &p, 1) == TERRAD_E_BAD_VALUE,
          "encode NaN pose");
    p.y = 0;
    p.qw = INFINITY;
    CHECK(terrad_pose_batch_encode(buf, sizeof buf, &len, 0, &p, 1) == TERRAD_E_BAD_VALUE,
          "encode Inf quaternion");
    p.qw = 1;
    CHECK(terrad_pose_batch_encode(buf, 41, &len, 0, &p, 1) == TERRAD_E_BUFFER_TOO_SMALL,
          "encode pose into 41 bytes");
    CHECK(terrad_pose_batch_encode(buf, 42, &len, 0, &p, 1) == 0 && len == 42,
          "encode pose into 42 bytes");
    terrad_pose two[2] = {p, p};
    size_t count;
    uint32_t seq;
    terrad_pose out[1];
    CHECK(terrad_pose_batch_encode(buf, sizeof buf, &len, 0, two, 2) == 0 &&
              terrad_pose_batch_decode(buf, len, &seq, out, 1, &count) == TERRAD_E_TOO_LARGE,
          "decode two poses into room for one");
    terrad_contact c;
    memset(&c, 0, sizeof c);
    c.normal[2] = 1;
    c.area_m2 = -1;
    CHECK(terrad_contact_encode(buf, sizeof buf, &len, 0, &c, 1) == TERRAD_E_BAD_VALUE,
          "encode negative area");
    c.area_m2 = 0;
    c.support_height_m = NAN;
    CHECK(terrad_contact_encode(buf, sizeof buf, &len, 0, &c, 1) == TERRAD_E_BAD_VALUE,
          "encode NaN support height");
    terrad_footprint fp = {1, 2.0f, 3.0f, 0.5f, 0.25f, 0.01f};
    CHECK(terrad_footprints_encode(buf, 37, &len, 0, &fp, 1) == TERRAD_E_BUFFER_TOO_SMALL &&
              terrad_footprints_encode(buf, 38, &len, 0, &fp, 1) == 0 && len == 38,
          "footprints: one event is 38 bytes");
    terrad_footprint two_fp[2] = {fp, fp}, one_fp[1];
    CHECK(terrad_footprints_encode(buf, sizeof buf, &len, 0, two_fp, 2) == 0 &&
              terrad_footprints_decode(buf, len, NULL, one_fp, 1, &count) == TERRAD_E_TOO_LARGE,
          "decode two footprints into room for one");
    fp.strength_m = 0;
    CHECK(terrad_footprints_encode(buf, sizeof buf, &len, 0, &fp, 1) == TERRAD_E_BAD_VALUE,
          "encode a footprint of strength 0");
    fp.strength_m = 0.01f;
    fp.yaw = -3.2f;
    CHECK(terrad_footprints_encode(buf, sizeof buf, &len, 0, &fp, 1) == TERRAD_E_BAD_VALUE,
          "encode a footprint of yaw < -pi");
    fp.yaw = 0;
    fp.x = NAN;
    CHECK(terrad_footprints_encode(buf, sizeof buf, &len, 0, &fp, 1) == TERRAD_E_BAD_VALUE,
          "encode a footprint at x NaN");
    CHECK(terrad_ping_encode(buf, sizeof buf, &len, TERRAD_MSG_ACK, 1) == TERRAD_E_UNKNOWN_TYPE,
          "ping encode with type ACK");
    CHECK(terrad_ack_encode(buf, 15, &len, 1, 1) == TERRAD_E_BUFFER_TOO_SMALL, "ack in 15 bytes");
    uint8_t z[8] = {1};
    terrad_rect r = {0, 0, 0, 1, 1, 2, TERRAD_ENC_DELTA, 1, z};
    CHECK(terrad_delta_encode(buf, sizeof buf, &len, 0, &r, 1) == TERRAD_E_BAD_VALUE,
          "encode a 0 x 1 rectangle");
    CHECK(terrad_err_name(999) == NULL && terrad_err_from_name("nope") == 0, "unknown names");
    CHECK(terrad_zigzag32(0) == 0 && terrad_zigzag32(-1) == 1 && terrad_zigzag32(1) == 2 &&
              terrad_zigzag32(INT32_MAX) == 0xfffffffeu &&
              terrad_zigzag32(INT32_MIN) == 0xffffffffu,
          "zigzag values");
    CHECK(terrad_unzigzag32(0xffffffffu) == INT32_MIN &&
              terrad_unzigzag32(0xfffffffeu) == INT32_MAX,
          "unzigzag extremes");
}

/* Random rectangles: differences of random heights (small, large and
 * extreme), compressed and decompressed, applied to the old heights. */
static void test_random_round_trip(void)
{
    terrad_codec *c = terrad_codec_new(3);
    CHECK(c != NULL, "codec");
    int bad = 0;
    for (int iter = 0; iter < 200; iter++) {
        uint16_t w = (uint16_t)(1 + next() % (iter < 150 ? 64 : 256));
        uint16_t h = (uint16_t)(1 + next() % (iter < 150 ? 64 : 256));
        size_t cells = (size_t)w * h;
        int32_t *oldh = malloc(cells * 4), *newh = malloc(cells * 4), *d = malloc(cells * 4),
                *back = malloc(cells * 4);
        int mode = iter % 4;
        for (size_t i = 0; i < cells; i++) {
            oldh[i] = (int32_t)next();
            switch (mode) {
            case 0:
                newh[i] = oldh[i];
                break;
            case 1:
                newh[i] = (int32_t)((uint32_t)oldh[i] + (next() % 201) - 100);
                break;
            case 2:
                newh[i] = (int32_t)next();
                break;
            default:
                newh[i] = (next() & 1) ? INT32_MIN : INT32_MAX;
                break;
            }
        }
        terrad_rect_diff(oldh, newh, cells, d);
        size_t cap = terrad_rect_compress_bound(cells), zn;
        uint8_t *z = malloc(cap);
        int rc = terrad_rect_compress(c, d, cells, z, cap, &zn);
        if (rc == 0)
            rc = terrad_rect_decompress(c, z, zn, cells, back, cells);
        if (rc != 0 || memcmp(back, d, cells * 4) != 0)
            bad++;
        terrad_rect r = {-17, 5, w, h, 1, 2, TERRAD_ENC_DELTA, (uint32_t)zn, z};
        terrad_rect_apply_values(&r, back, oldh, -17, 5, w, h);
        if (memcmp(oldh, newh, cells * 4) != 0)
            bad++;
        /* Asking for one cell fewer or more than the frame holds is refused. */
        if (cells > 1 &&
            terrad_rect_decompress(c, z, zn, cells - 1, back, cells) != TERRAD_E_BAD_COMPRESSION)
            bad++;
        free(oldh);
        free(newh);
        free(d);
        free(back);
        free(z);
    }
    CHECK(bad == 0, "random rectangle round trips: %d bad", bad);
    terrad_codec_free(c);
}

/* A server-side world and a client mirror over random ticks of random deltas
 * and snapshots: the mirror equals the world after every frame. */
static void test_random_mirror(void)
{
    enum { W = 40, H = 30, T = 8, TX = 5, TY = 4 };
    static int32_t world[W * H], prev[W * H];
    static uint32_t tver[TX * TY];
    for (int i = 0; i < W * H; i++)
        world[i] = (int32_t)(next() % 100000);
    for (int i = 0; i < TX * TY; i++)
        tver[i] = 1;
    /* The client holds the region (3, 2) 31 x 25. */
    const int32_t rx = 3, ry = 2;
    const uint32_t rw = 31, rh = 25;
    int32_t *mh = calloc(rw * rh, 4);
    uint32_t mv[64];
    terrad_mirror m;
    terrad_mirror_init(&m, rx, ry, rw, rh, T, mh, mv);
    terrad_codec *c = terrad_codec_new(3);
    int bad = 0;
    int32_t scratch[T * T];
    for (int tick = 0; tick < 300; tick++) {
        terrad_rect rects[64];
        uint8_t *payloads[64];
        size_t n = 0;
        memcpy(prev, world, sizeof world);
        if (tick == 0 || tick % 97 == 0) {
            /* Snapshot: tile ∩ region, one rectangle per tile. */
            for (int ty = 0; ty < TY; ty++)
                for (int tx = 0; tx < TX; tx++) {
                    int x0 = tx * T > rx ? tx * T : rx, y0 = ty * T > ry ? ty * T : ry;
                    int x1 = (tx + 1) * T < (int)(rx + rw) ? (tx + 1) * T : (int)(rx + rw);
                    int y1 = (ty + 1) * T < (int)(ry + rh) ? (ty + 1) * T : (int)(ry + rh);
                    if (x0 >= x1 || y0 >= y1)
                        continue;
                    int32_t vals[T * T];
                    int k = 0;
                    for (int y = y0; y < y1; y++)
                        for (int x = x0; x < x1; x++)
                            vals[k++] = world[y * W + x];
                    payloads[n] = malloc(terrad_rect_compress_bound((size_t)k));
                    size_t zn;
                    terrad_rect_compress(c, vals, (size_t)k, payloads[n],
                                         terrad_rect_compress_bound((size_t)k), &zn);
                    terrad_rect r = {x0,
                                     y0,
                                     (uint16_t)(x1 - x0),
                                     (uint16_t)(y1 - y0),
                                     0,
                                     tver[ty * TX + tx],
                                     TERRAD_ENC_SNAPSHOT,
                                     (uint32_t)zn,
                                     payloads[n]};
                    rects[n++] = r;
                }
        } else {
            /* Random edits inside random tiles, one dirty rectangle per tile. */
            int edits = 1 + (int)(next() % 4);
            int done[TX * TY] = {0};
            for (int e = 0; e < edits; e++) {
                int tx = (int)(next() % TX), ty = (int)(next() % TY);
                if (done[ty * TX + tx])
                    continue;
                done[ty * TX + tx] = 1;
                int x0 = tx * T + (int)(next() % T), y0 = ty * T + (int)(next() % T);
                int w = 1 + (int)(next() % (uint32_t)(T - x0 % T));
                int h = 1 + (int)(next() % (uint32_t)(T - y0 % T));
                if (x0 + w > W || y0 + h > H)
                    continue;
                int32_t vals[T * T];
                int k = 0;
                for (int y = y0; y < y0 + h; y++)
                    for (int x = x0; x < x0 + w; x++) {
                        world[y * W + x] += (int32_t)(next() % 2001) - 1000;
                        vals[k++] = world[y * W + x] - prev[y * W + x];
                    }
                payloads[n] = malloc(terrad_rect_compress_bound((size_t)k));
                size_t zn;
                terrad_rect_compress(c, vals, (size_t)k, payloads[n],
                                     terrad_rect_compress_bound((size_t)k), &zn);
                uint32_t base = tver[ty * TX + tx]++;
                terrad_rect r = {x0,         y0,       (uint16_t)w,      (uint16_t)h,
                                 base,       base + 1, TERRAD_ENC_DELTA, (uint32_t)zn,
                                 payloads[n]};
                rects[n++] = r;
            }
        }
        /* Through the wire and into the mirror. */
        static uint8_t frame[1 << 16];
        size_t len, count;
        uint64_t t;
        terrad_rect got[64];
        int rc = terrad_delta_encode(frame, sizeof frame, &len, (uint64_t)tick, rects, n);
        if (rc == 0)
            rc = terrad_delta_decode(frame, len, &t, got, 64, &count);
        if (rc == 0)
            rc = terrad_mirror_apply(&m, c, got, count, scratch, T * T);
        if (rc)
            bad++;
        for (uint32_t y = 0; y < rh; y++)
            if (memcmp(mh + y * rw, world + (ry + (int32_t)y) * W + rx, rw * 4) != 0) {
                bad++;
                break;
            }
        for (size_t i = 0; i < n; i++)
            free(payloads[i]);
    }
    CHECK(bad == 0, "random mirror: %d bad ticks", bad);
    free(mh);
    terrad_codec_free(c);
}

/* FORCES' height extension (PROTOCOL.md "FORCES"): encoded with heights, the
 * header carries TERRAD_FORCES_FLAG_HEIGHT and each entry an f64 after it;
 * terrad_forces_decode reads the entries of both forms alike and
 * terrad_forces_heights the heights (none from a plain frame); the flag on
 * another type, another flag, a length that does not match the flag and a
 * height that is not finite are refused. */
static void test_forces_heights(void)
{
    terrad_force f[2] = {
        {7, {1.5f, -2.0f, 80.0f}, {0.1f, 3.0f, 0.0f}, 0.012f, 0.01f, 0.1f, 0.2f, 400},
        {9, {0.0f, 0.0f, 40.0f}, {0.0f, 0.0f, 0.0f}, 0.0f, 0.0f, 0.0f, 0.0f, 0}};
    double h[2] = {0.6478531234567, -12.25}, got_h[2] = {0, 0};
    uint8_t buf[256], plain[256];
    size_t len = 0, plen = 0, count = 9, nh = 9;
    CHECK(terrad_forces_encode_heights(buf, sizeof buf, &len, 42, f, h, 2) == 0 &&
              len == terrad_forces_heights_size(2) && len == 14 + 2 * 56 &&
              buf[3] == TERRAD_FORCES_FLAG_HEIGHT,
          "FORCES with heights: flagged, 56-byte entries (%zu bytes)", len);
    CHECK(terrad_forces_encode(plain, sizeof plain, &plen, 42, f, 2) == 0 && plain[3] == 0 &&
              plen == 14 + 2 * 48,
          "FORCES without: the frame it always was");
    terrad_force back[2];
    uint64_t tick = 0;
    CHECK(terrad_forces_decode(buf, len, &tick, back, 2, &count) == 0 && tick == 42 && count == 2 &&
              memcmp(back, f, sizeof f) == 0,
          "the entries of a flagged frame decode as a plain one's");
    CHECK(terrad_forces_heights(buf, len, got_h, 2, &nh) == 0 && nh == 2 && got_h[0] == h[0] &&
              got_h[1] == h[1],
          "its heights, bit for bit (%.13f, %g)", got_h[0], got_h[1]);
    CHECK(terrad_forces_heights(plain, plen, got_h, 2, &nh) == 0 && nh == 0,
          "a plain frame has no heights");
    terrad_header hd;
    CHECK(terrad_header_decode(buf, len, &hd) == 0 && hd.flags == TERRAD_FORCES_FLAG_HEIGHT,
          "the header check takes FORCES' flag");
    uint8_t other[256];
    size_t olen = 0;
    terrad_contact none[1];
    CHECK(terrad_contact_encode(other, sizeof other, &olen, 1, none, 0) == 0, "an empty CONTACT");
    other[3] = TERRAD_FORCES_FLAG_HEIGHT;
    CHECK(terrad_header_decode(other, olen, NULL) == TERRAD_E_BAD_FRAME,
          "the flag on another type is bad_frame");
    buf[3] = 0x02;
    CHECK(terrad_forces_decode(buf, len, &tick, back, 2, &count) == TERRAD_E_BAD_FRAME,
          "another FORCES flag is bad_frame");
    plain[3] = TERRAD_FORCES_FLAG_HEIGHT;
    CHECK(terrad_forces_decode(plain, plen, &tick, back, 2, &count) == TERRAD_E_BAD_FRAME,
          "the flag on 48-byte entries is bad_frame (the length does not match)");
    buf[3] = TERRAD_FORCES_FLAG_HEIGHT;
    double nan = NAN;
    memcpy(buf + 14 + 48, &nan, sizeof nan);
    CHECK(terrad_forces_decode(buf, len, &tick, back, 2, &count) == TERRAD_E_BAD_VALUE,
          "a height that is not finite is bad_value");
    h[1] = INFINITY;
    CHECK(terrad_forces_encode_heights(buf, sizeof buf, &len, 42, f, h, 2) == TERRAD_E_BAD_VALUE,
          "and the encoder refuses it");
}

/* COLLIDERS' grousers extension (PROTOCOL.md "COLLIDERS"; its frames and refusals are in the
 * vectors): the entries of a flagged frame decode as a plain one's, and the encoder refuses
 * what a decoder would (grousers on a sphere, taller than the radius, none with a size). */
static void test_colliders_grousers(void)
{
    terrad_collider_state c[2] = {
        {3, TERRAD_OWNER_OTHER, TERRAD_KIND_CYLINDER, {0.3f, 0.1f, 0}, {1, 2, 0.3f}, {1, 0, 0, 0}},
        {4, TERRAD_OWNER_OWN, TERRAD_KIND_SPHERE, {0.2f, 0, 0}, {5, 6, 0.2f}, {1, 0, 0, 0}}};
    terrad_collider_grousers g[2] = {{12, 0.02f, 0.01f}, {0, 0, 0}};
    uint8_t buf[256];
    size_t len = 0, count = 0;
    CHECK(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 5, c, g, 2) == 0 &&
              len == terrad_colliders_grousers_size(2) && len == 14 + 2 * 60 &&
              buf[3] == TERRAD_COLLIDERS_FLAG_GROUSERS,
          "COLLIDERS with grousers: flagged, 60-byte entries (%zu bytes)", len);
    terrad_collider_state back[2];
    uint64_t tick = 0;
    int same =
        terrad_colliders_decode(buf, len, &tick, back, 2, &count) == 0 && tick == 5 && count == 2;
    for (size_t i = 0; same && i < 2; i++) /* field by field: the structs have padding */
        same = back[i].id == c[i].id && back[i].owner == c[i].owner && back[i].kind == c[i].kind &&
               memcmp(back[i].dims, c[i].dims, sizeof c[i].dims) == 0 &&
               memcmp(back[i].p, c[i].p, sizeof c[i].p) == 0 &&
               memcmp(back[i].q, c[i].q, sizeof c[i].q) == 0;
    CHECK(same, "the entries of a flagged frame decode as a plain one's");
    terrad_collider_grousers bad[2] = {{0, 0, 0}, {1, 0.01f, 0.01f}};
    CHECK(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 5, c, bad, 2) ==
              TERRAD_E_BAD_VALUE,
          "the encoder refuses grousers on a sphere");
    bad[0] = (terrad_collider_grousers){12, 0.31f, 0.01f};
    bad[1] = g[1];
    CHECK(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 5, c, bad, 2) ==
              TERRAD_E_BAD_VALUE,
          "and grousers taller than the wheel's radius");
    bad[0] = (terrad_collider_grousers){0, 0.01f, 0};
    CHECK(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 5, c, bad, 2) ==
              TERRAD_E_BAD_VALUE,
          "and no grousers with a height");
    CHECK(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 5, c, NULL, 2) ==
              TERRAD_E_BAD_VALUE,
          "and entries without their grousers");
}

int main(void)
{
    const char *src = getenv("TERRAD_SOURCE_DIR");
    char path[4096];
    snprintf(path, sizeof path, "%s/proto/vectors/vectors.json", src ? src : ".");
    char *text = read_file(path);
    CHECK(text != NULL, "read %s", path);
    cJSON *root = text ? cJSON_Parse(text) : NULL;
    CHECK(root != NULL, "parse %s", path);
    if (root) {
        CHECK((int)num(root, "protocol") == TERRAD_PROTO_VERSION, "protocol version");
        check_vectors(root);
        check_scenarios(root);
        check_hashes(root);
        check_coded_rects(root, "base_rects", terrad_rect_decompress_base);
        check_coded_rects(root, "slope_rects", terrad_rect_decompress_slope);
    }
    test_encoder_refusals();
    test_forces_heights();
    test_colliders_grousers();
    test_random_round_trip();
    test_random_mirror();
    cJSON_Delete(root);
    free(text);
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
