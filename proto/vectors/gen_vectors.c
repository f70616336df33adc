/*
 * gen_vectors.c: writes proto/vectors/vectors.json, the test vectors every
 * terrad codec (C, Python, JavaScript) is checked against.
 *
 * Valid vectors are built with the C encoders; compressed rectangle payloads
 * are the bytes the C encoder produced at zstd level 3 with the libzstd
 * named in the file (other zstd versions may compress differently, so
 * encoders are checked on the packed bytes and by round trip, decoders on
 * these exact bytes). Invalid vectors are valid frames with bytes patched by
 * hand, each with the error a decoder must return. The mirror scenarios are
 * replayed through the C mirror and record what a client must hold after
 * each frame.
 *
 * Regenerate (from the repository root):  sh proto/vectors/regenerate.sh
 */
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>
#include <zstd.h>

#include "terrad_proto.h"

static void die(const char *what)
{
    fprintf(stderr, "gen_vectors: %s\n", what);
    exit(1);
}

static void ok(int rc, const char *what)
{
    if (rc != TERRAD_OK) {
        fprintf(stderr, "gen_vectors: %s: %s\n", what, terrad_err_name(rc));
        exit(1);
    }
}

static char *hex(const uint8_t *p, size_t n)
{
    char *s = malloc(2 * n + 1);
    if (!s)
        die("out of memory");
    for (size_t i = 0; i < n; i++)
        sprintf(s + 2 * i, "%02x", p[i]);
    s[2 * n] = 0;
    return s;
}

static void add_hex(cJSON *o, const char *key, const uint8_t *p, size_t n)
{
    char *s = hex(p, n);
    cJSON_AddStringToObject(o, key, s);
    free(s);
}

static void add_u64(cJSON *o, const char *key, uint64_t v)
{
    char s[32];
    snprintf(s, sizeof s, "%" PRIu64, v);
    cJSON_AddStringToObject(o, key, s);
}

static void add_i64(cJSON *o, const char *key, int64_t v)
{
    char s[32];
    snprintf(s, sizeof s, "%" PRId64, v);
    cJSON_AddStringToObject(o, key, s);
}

static cJSON *int_array(const int32_t *v, size_t n)
{
    cJSON *a = cJSON_CreateArray();
    for (size_t i = 0; i < n; i++)
        cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
    return a;
}

static cJSON *float_array(const float *v, size_t n)
{
    cJSON *a = cJSON_CreateArray();
    for (size_t i = 0; i < n; i++)
        cJSON_AddItemToArray(a, cJSON_CreateNumber(v[i]));
    return a;
}

static cJSON *vectors, *scenarios;
static uint8_t buf[1 << 20];

static cJSON *vector(const char *name, const char *type, const char *about)
{
    cJSON *v = cJSON_CreateObject();
    cJSON_AddStringToObject(v, "name", name);
    cJSON_AddStringToObject(v, "type", type);
    cJSON_AddStringToObject(v, "about", about);
    cJSON_AddItemToArray(vectors, v);
    return v;
}

static void valid(cJSON *v, cJSON *fields, const uint8_t *p, size_t n)
{
    cJSON_AddBoolToObject(v, "valid", 1);
    cJSON_AddItemToObject(v, "fields", fields);
    add_hex(v, "hex", p, n);
}

static void invalid(const char *name, const char *type, const char *about, const uint8_t *p,
                    size_t n, int err)
{
    cJSON *v = vector(name, type, about);
    cJSON_AddBoolToObject(v, "valid", 0);
    cJSON_AddStringToObject(v, "error", terrad_err_name(err));
    add_hex(v, "hex", p, n);
}

/* ---- POSE_BATCH ---- */

static cJSON *pose_fields(uint32_t seq, const terrad_pose *poses, size_t n)
{
    cJSON *f = cJSON_CreateObject();
    cJSON_AddNumberToObject(f, "seq", seq);
    cJSON *a = cJSON_AddArrayToObject(f, "poses");
    for (size_t i = 0; i < n; i++) {
        cJSON *p = cJSON_CreateObject();
        cJSON_AddNumberToObject(p, "id", poses[i].id);
        cJSON_AddNumberToObject(p, "x", poses[i].x);
        cJSON_AddNumberToObject(p, "y", poses[i].y);
        cJSON_AddNumberToObject(p, "z", poses[i].z);
        cJSON_AddNumberToObject(p, "qw", poses[i].qw);
        cJSON_AddNumberToObject(p, "qx", poses[i].qx);
        cJSON_AddNumberToObject(p, "qy", poses[i].qy);
        cJSON_AddNumberToObject(p, "qz", poses[i].qz);
        cJSON_AddItemToArray(a, p);
    }
    return f;
}

static size_t pose_vector(const char *name, const char *about, uint32_t seq,
                          const terrad_pose *poses, size_t n)
{
    size_t len;
    ok(terrad_pose_batch_encode(buf, sizeof buf, &len, seq, poses, n), name);
    valid(vector(name, "POSE_BATCH", about), pose_fields(seq, poses, n), buf, len);
    return len;
}

static void set_f32(uint8_t *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, 4);
    p[0] = (uint8_t)u;
    p[1] = (uint8_t)(u >> 8);
    p[2] = (uint8_t)(u >> 16);
    p[3] = (uint8_t)(u >> 24);
}

static void set_u32(uint8_t *p, uint32_t u)
{
    p[0] = (uint8_t)u;
    p[1] = (uint8_t)(u >> 8);
    p[2] = (uint8_t)(u >> 16);
    p[3] = (uint8_t)(u >> 24);
}

static void set_u16(uint8_t *p, uint16_t u)
{
    p[0] = (uint8_t)u;
    p[1] = (uint8_t)(u >> 8);
}

/* The valid frame in buf (len bytes) with the f32 at offset off set to v: a
 * vector a decoder must refuse as bad_value. */
static void bad_f32(const char *name, const char *type, const char *about, size_t len, size_t off,
                    float v)
{
    uint8_t q[256];
    memcpy(q, buf, len);
    set_f32(q + off, v);
    invalid(name, type, about, q, len, TERRAD_E_BAD_VALUE);
}

/* Likewise with the byte at offset off set to v, refused with err. */
static void bad_byte(const char *name, const char *type, const char *about, size_t len, size_t off,
                     uint8_t v, int err)
{
    uint8_t q[256];
    memcpy(q, buf, len);
    q[off] = v;
    invalid(name, type, about, q, len, err);
}

static void pose_vectors(void)
{
    terrad_pose one = {7, 1.5f, -2.25f, 0.125f, 1, 0, 0, 0};
    pose_vector("pose_batch_empty", "no poses: a keep-alive that still gets an ACK", 0, NULL, 0);
    pose_vector("pose_batch_one", "one pose, identity orientation", 1, &one, 1);
    terrad_pose three[3] = {
        {1, 0, 0, 0, 0.70710677f, 0, 0, 0.70710677f},
        {4294967295u, -1000.5f, 2047.96875f, -0.0078125f, 0.5f, -0.5f, 0.5f, -0.5f},
        {42, 3.4028235e38f, -3.4028235e38f, 1.17549435e-38f, 0.92f, 0, 0, 0},
    };
    pose_vector("pose_batch_extremes",
                "max sequence and id, float extremes, quaternion norms 0.92 and 1", 4294967295u,
                three, 3);

    size_t len;
    uint8_t p[256];
    ok(terrad_pose_batch_encode(p, sizeof p, &len, 1, &one, 1), "pose");
    invalid("empty_frame", "POSE_BATCH", "zero bytes", p, 0, TERRAD_E_BAD_FRAME);
    invalid("truncated_header", "POSE_BATCH", "three bytes of header", p, 3, TERRAD_E_BAD_FRAME);
    invalid("header_only", "POSE_BATCH", "a header and nothing else", p, 4, TERRAD_E_BAD_FRAME);
    uint8_t q[256];
    memcpy(q, p, len);
    q[0] = 0x55;
    invalid("bad_magic", "POSE_BATCH", "magic 0x55", q, len, TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    q[1] = 2;
    invalid("bad_version", "POSE_BATCH", "protocol version 2", q, len, TERRAD_E_BAD_VERSION);
    q[1] = 0;
    invalid("bad_version_zero", "POSE_BATCH", "protocol version 0", q, len, TERRAD_E_BAD_VERSION);
    memcpy(q, p, len);
    q[2] = 0x7f;
    invalid("unknown_type", "POSE_BATCH", "type byte 0x7f", q, len, TERRAD_E_UNKNOWN_TYPE);
    memcpy(q, p, len);
    q[2] = TERRAD_MSG_DELTA;
    invalid("wrong_type_for_decoder", "POSE_BATCH",
            "a DELTA type byte where a POSE_BATCH is expected", q, len, TERRAD_E_UNKNOWN_TYPE);
    memcpy(q, p, len);
    q[3] = 1;
    invalid("flags_nonzero", "POSE_BATCH", "reserved flags set", q, len, TERRAD_E_BAD_FRAME);
    invalid("pose_truncated", "POSE_BATCH", "last byte of the pose missing", p, len - 1,
            TERRAD_E_BAD_FRAME);
    invalid("pose_no_count", "POSE_BATCH", "sequence but no count", p, 9, TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_u16(q + 8, 3);
    invalid("pose_count_too_large", "POSE_BATCH", "count 3, one pose of payload", q, len,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_u16(q + 8, 65535);
    invalid("pose_count_max_no_payload", "POSE_BATCH", "count 65535, one pose of payload", q, len,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    q[len] = 0;
    invalid("pose_trailing_byte", "POSE_BATCH", "one byte after the last pose", q, len + 1,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_f32(q + 14, NAN);
    invalid("pose_nan_x", "POSE_BATCH", "x is NaN", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_f32(q + 22, -INFINITY);
    invalid("pose_inf_z", "POSE_BATCH", "z is -Inf", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_f32(q + 26, INFINITY);
    invalid("pose_inf_qw", "POSE_BATCH", "qw is +Inf", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_f32(q + 26, 0.0f);
    invalid("pose_zero_quaternion", "POSE_BATCH", "all quaternion components zero", q, len,
            TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_f32(q + 26, 2.0f);
    invalid("pose_long_quaternion", "POSE_BATCH", "|q| = 2", q, len, TERRAD_E_BAD_VALUE);
}

/* ---- DELTA ---- */

typedef struct rect_spec {
    terrad_rect r;
    const int32_t *values;        /* what travels: differences or absolute heights */
    const int32_t *old_h, *new_h; /* delta vectors: before and after, optional */
    uint8_t *data;
} rect_spec;

static void compress_spec(rect_spec *s)
{
    size_t cells = (size_t)s->r.w * s->r.h;
    size_t cap = terrad_rect_compress_bound(cells);
    s->data = malloc(cap);
    size_t n;
    ok(terrad_rect_compress(NULL, s->values, cells, s->data, cap, &n), "compress");
    s->r.data = s->data;
    s->r.data_len = (uint32_t)n;
}

static cJSON *rect_json(const rect_spec *s)
{
    size_t cells = (size_t)s->r.w * s->r.h;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "x", s->r.x);
    cJSON_AddNumberToObject(o, "y", s->r.y);
    cJSON_AddNumberToObject(o, "w", s->r.w);
    cJSON_AddNumberToObject(o, "h", s->r.h);
    cJSON_AddNumberToObject(o, "base_version", s->r.base_version);
    cJSON_AddNumberToObject(o, "new_version", s->r.new_version);
    cJSON_AddNumberToObject(o, "encoding", s->r.encoding);
    cJSON_AddItemToObject(o, "values", int_array(s->values, cells));
    if (s->old_h) {
        cJSON_AddItemToObject(o, "old", int_array(s->old_h, cells));
        cJSON_AddItemToObject(o, "new", int_array(s->new_h, cells));
    }
    uint8_t *packed = malloc(cells * 4);
    terrad_rect_pack(s->values, cells, packed);
    add_hex(o, "packed_hex", packed, cells * 4);
    free(packed);
    add_hex(o, "data_hex", s->r.data, s->r.data_len);
    return o;
}

static size_t delta_vector(const char *name, const char *about, uint64_t tick, rect_spec *specs,
                           size_t n)
{
    terrad_rect rects[8];
    cJSON *f = cJSON_CreateObject();
    add_u64(f, "tick", tick);
    cJSON *a = cJSON_AddArrayToObject(f, "rects");
    for (size_t i = 0; i < n; i++) {
        if (!specs[i].r.data)
            compress_spec(&specs[i]);
        rects[i] = specs[i].r;
        cJSON_AddItemToArray(a, rect_json(&specs[i]));
    }
    size_t len;
    ok(terrad_delta_encode(buf, sizeof buf, &len, tick, rects, n), name);
    valid(vector(name, "DELTA", about), f, buf, len);
    return len;
}

static void delta_vectors(void)
{
    delta_vector("delta_empty", "no rectangles", 0, NULL, 0);

    static const int32_t old1[1] = {100}, new1[1] = {105}, d1[1] = {5};
    rect_spec s1 = {{0, 0, 1, 1, 1, 2, TERRAD_ENC_DELTA, 0, NULL}, d1, old1, new1, NULL};
    delta_vector("delta_1x1", "one cell raised by 5 units", 1, &s1, 1);

    /* Differences at the int32 extremes: new - old wraps modulo 2^32. */
    static const int32_t oldx[6] = {INT32_MIN, INT32_MAX, 0, 0, -1, 5};
    static const int32_t newx[6] = {INT32_MAX, INT32_MIN, INT32_MIN, INT32_MAX, INT32_MAX, 5};
    int32_t dx[6];
    terrad_rect_diff(oldx, newx, 6, dx);
    rect_spec sx = {{10, 20, 3, 2, 7, 8, TERRAD_ENC_DELTA, 0, NULL}, dx, oldx, newx, NULL};
    delta_vector("delta_int32_extremes",
                 "differences -1, 1, INT32_MIN, INT32_MAX, INT32_MIN (wrapped), 0", 2, &sx, 1);

    static const int32_t snap[12] = {0,         1,     -1,     2,         -2,         INT32_MAX,
                                     INT32_MIN, 10000, -10000, 536870912, -536870912, 7};
    rect_spec ss = {{-3, 7, 4, 3, 0, 9, TERRAD_ENC_SNAPSHOT, 0, NULL}, snap, NULL, NULL, NULL};
    delta_vector("delta_snapshot", "absolute heights, negative x, extremes", 42, &ss, 1);

    /* A trail: a smooth dip 8 x 4, and a 16 x 16 snapshot of a slope. */
    static int32_t trail[32], slope[256];
    for (int i = 0; i < 32; i++) {
        int x = i % 8, y = i / 8;
        trail[i] = -(int32_t)(250 * (4 - abs(2 * y - 3)) + 13 * x);
    }
    for (int i = 0; i < 256; i++)
        slope[i] = 150000 + 37 * (i % 16) - 11 * (i / 16);
    rect_spec sm[2] = {
        {{64, 128, 8, 4, 3, 4, TERRAD_ENC_DELTA, 0, NULL}, trail, NULL, NULL, NULL},
        {{80, 128, 16, 16, 0, 12, TERRAD_ENC_SNAPSHOT, 0, NULL}, slope, NULL, NULL, NULL},
    };
    delta_vector("delta_two_rects", "a delta and a snapshot, tick 2^64 - 1", UINT64_MAX, sm, 2);

    static const int32_t one[1] = {-7};
    rect_spec se = {
        {INT32_MAX, INT32_MIN, 1, 1, 4294967294u, 4294967295u, TERRAD_ENC_DELTA, 0, NULL},
        one,
        NULL,
        NULL,
        NULL};
    delta_vector("delta_max_coordinates", "x = INT32_MAX, y = INT32_MIN, versions at the top", 3,
                 &se, 1);

    /* ---- invalid DELTA frames ---- */
    size_t len;
    uint8_t p[4096], q[4096];
    terrad_rect r1 = s1.r;
    ok(terrad_delta_encode(p, sizeof p, &len, 1, &r1, 1), "delta");
    /* offsets: header 4, tick 8, count 2 -> rect at 14: x 14, y 18, w 22, h 24,
     * base 26, new 30, enc 34, len 35, data 39 */
    memcpy(q, p, len);
    set_u16(q + 12, 65535);
    invalid("delta_count_too_large", "DELTA", "count 65535, one rectangle of payload", q, len,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_u16(q + 12, 2);
    invalid("delta_count_two_one_rect", "DELTA", "count 2, one rectangle of payload", q, len,
            TERRAD_E_BAD_FRAME);
    invalid("delta_truncated_data", "DELTA", "the compressed bytes cut short", p, len - 1,
            TERRAD_E_BAD_FRAME);
    invalid("delta_truncated_rect", "DELTA", "a rectangle header cut short", p, 30,
            TERRAD_E_BAD_FRAME);
    invalid("delta_truncated_tick", "DELTA", "the tick cut short", p, 9, TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_u32(q + 35, r1.data_len + 1000);
    invalid("delta_length_past_end", "DELTA", "compressed length past the end of the frame", q, len,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    q[len] = 0;
    invalid("delta_trailing_byte", "DELTA", "one byte after the last rectangle", q, len + 1,
            TERRAD_E_BAD_FRAME);
    memcpy(q, p, len);
    set_u16(q + 22, 0);
    invalid("delta_zero_width", "DELTA", "w = 0", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    q[34] = 2;
    invalid("delta_bad_encoding", "DELTA", "encoding 2", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_u32(q + 26, 0);
    invalid("delta_base_zero", "DELTA", "a delta rectangle with base_version 0", q, len,
            TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_u32(q + 30, 1);
    invalid("delta_base_equals_new", "DELTA", "base_version = new_version", q, len,
            TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    q[34] = 1;
    invalid("snapshot_with_base", "DELTA", "a snapshot rectangle with base_version 1", q, len,
            TERRAD_E_BAD_VALUE);
    memcpy(q, p, len);
    set_u32(q + 14, (uint32_t)INT32_MAX);
    set_u16(q + 22, 2);
    invalid("delta_x_overflow", "DELTA", "x = INT32_MAX, w = 2: past the int32 range", q, len,
            TERRAD_E_BAD_VALUE);

    /* Payloads that decode as a frame but not as a rectangle: bad_compression
     * comes from decompressing each rectangle (w * h cells). */
    static const int32_t three[3] = {1, 2, 3};
    uint8_t z[256];
    size_t zn;
    ok(terrad_rect_compress(NULL, three, 3, z, sizeof z, &zn), "compress");
    terrad_rect r4 = {0, 0, 2, 2, 1, 2, TERRAD_ENC_DELTA, (uint32_t)zn, z};
    ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
    invalid("delta_zstd_size_mismatch", "DELTA", "2 x 2 rectangle whose zstd frame holds 3 cells",
            q, len, TERRAD_E_BAD_COMPRESSION);
    static const int32_t five[5] = {1, 2, 3, 4, 5};
    ok(terrad_rect_compress(NULL, five, 5, z, sizeof z, &zn), "compress");
    r4.data_len = (uint32_t)zn;
    ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
    invalid("delta_zstd_too_big", "DELTA", "2 x 2 rectangle whose zstd frame holds 5 cells", q, len,
            TERRAD_E_BAD_COMPRESSION);
    static const int32_t four[4] = {1, 2, 3, 4};
    ok(terrad_rect_compress(NULL, four, 4, z, sizeof z, &zn), "compress");
    z[zn] = 0;
    r4.data_len = (uint32_t)zn + 1;
    ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
    invalid("delta_zstd_trailing", "DELTA", "a byte after the zstd frame", q, len,
            TERRAD_E_BAD_COMPRESSION);
    r4.data_len = (uint32_t)zn - 1;
    ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
    invalid("delta_zstd_truncated", "DELTA", "the zstd frame missing its last byte", q, len,
            TERRAD_E_BAD_COMPRESSION);
    static const uint8_t junk[8] = {'n', 'o', 't', ' ', 'z', 's', 't', 'd'};
    memcpy(z, junk, 8);
    r4.data_len = 8;
    ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
    invalid("delta_zstd_garbage", "DELTA", "eight bytes that are not zstd", q, len,
            TERRAD_E_BAD_COMPRESSION);
    /* A valid zstd frame without a content size in its header. */
    {
        uint8_t packed[16];
        terrad_rect_pack(four, 4, packed);
        ZSTD_CCtx *cc = ZSTD_createCCtx();
        ZSTD_CCtx_setParameter(cc, ZSTD_c_compressionLevel, 3);
        ZSTD_CCtx_setParameter(cc, ZSTD_c_contentSizeFlag, 0);
        size_t n = ZSTD_compress2(cc, z, sizeof z, packed, sizeof packed);
        ZSTD_freeCCtx(cc);
        if (ZSTD_isError(n))
            die("zstd");
        r4.data_len = (uint32_t)n;
        ok(terrad_delta_encode(q, sizeof q, &len, 5, &r4, 1), "delta");
        invalid("delta_zstd_no_content_size", "DELTA",
                "a zstd frame without its content size in the header", q, len,
                TERRAD_E_BAD_COMPRESSION);
    }
}

/* The fields of a tick list (CONTACT, COLLIDERS, FOOTPRINTS, FORCES): the
 * tick and, under key, each of the n entries (elem bytes apart) as entry()
 * writes it. */
static cJSON *tick_list_fields(uint64_t tick, const char *key, const void *entries, size_t elem,
                               size_t n, cJSON *(*entry)(const void *))
{
    cJSON *f = cJSON_CreateObject();
    add_u64(f, "tick", tick);
    cJSON *a = cJSON_AddArrayToObject(f, key);
    for (size_t i = 0; i < n; i++)
        cJSON_AddItemToArray(a, entry((const uint8_t *)entries + i * elem));
    return f;
}

/* ---- CONTACT, ACK, PING, PONG ---- */

static cJSON *contact_json(const void *entry)
{
    const terrad_contact *e = entry;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "id", e->id);
    add_i64(o, "volume", e->volume);
    cJSON_AddNumberToObject(o, "cells", e->cells);
    cJSON_AddNumberToObject(o, "area_m2", e->area_m2);
    cJSON_AddItemToObject(o, "deepest", float_array(e->deepest, 3));
    cJSON_AddItemToObject(o, "normal", float_array(e->normal, 3));
    cJSON_AddNumberToObject(o, "support_height_m", e->support_height_m);
    return o;
}

static cJSON *contact_fields(uint64_t tick, const terrad_contact *c, size_t n)
{
    return tick_list_fields(tick, "contacts", c, sizeof *c, n, contact_json);
}

static void small_vectors(void)
{
    size_t len;
    ok(terrad_contact_encode(buf, sizeof buf, &len, 0, NULL, 0), "contact");
    valid(vector("contact_empty", "CONTACT", "no colliders"), contact_fields(0, NULL, 0), buf, len);
    terrad_contact c[2] = {
        {3, 1234567, 42, 0.105f, {1.25f, 2.5f, -0.0625f}, {0.0f, 0.6f, 0.8f}, -0.03125f},
        {4294967295u,
         INT64_MAX,
         4294967295u,
         0.0f,
         {-5.0f, 6.0f, 7.0f},
         {0.0f, 0.0f, 1.0f},
         3.4028235e38f},
    };
    ok(terrad_contact_encode(buf, sizeof buf, &len, 987654321012345ull, c, 2), "contact");
    valid(vector("contact_two", "CONTACT", "a wheel in contact, then maximum values"),
          contact_fields(987654321012345ull, c, 2), buf, len);
    uint8_t q[256];
    bad_f32("contact_nan_normal", "CONTACT", "normal y is NaN", len, 14 + 32,
            NAN); /* first contact's normal y */
    memcpy(q, buf, len);
    set_u32(q + 14 + 8, 0x80000000u); /* first contact's volume high word: negative */
    invalid("contact_negative_volume", "CONTACT", "volume < 0", q, len, TERRAD_E_BAD_VALUE);
    invalid("contact_truncated", "CONTACT", "the last contact cut short", buf, len - 4,
            TERRAD_E_BAD_FRAME);

    ok(terrad_ack_encode(buf, sizeof buf, &len, 12345, 678), "ack");
    cJSON *f = cJSON_CreateObject();
    add_u64(f, "tick", 12345);
    cJSON_AddNumberToObject(f, "seq", 678);
    valid(vector("ack_basic", "ACK", "tick 12345 applied batch 678"), f, buf, len);
    invalid("ack_short", "ACK", "15 bytes", buf, len - 1, TERRAD_E_BAD_FRAME);
    buf[len] = 0;
    invalid("ack_long", "ACK", "17 bytes", buf, len + 1, TERRAD_E_BAD_FRAME);
    ok(terrad_ack_encode(buf, sizeof buf, &len, UINT64_MAX, UINT32_MAX), "ack");
    f = cJSON_CreateObject();
    add_u64(f, "tick", UINT64_MAX);
    cJSON_AddNumberToObject(f, "seq", UINT32_MAX);
    valid(vector("ack_max", "ACK", "maximum tick and sequence"), f, buf, len);

    ok(terrad_ping_encode(buf, sizeof buf, &len, TERRAD_MSG_PING, 0x0123456789abcdefull), "ping");
    f = cJSON_CreateObject();
    add_u64(f, "nonce", 0x0123456789abcdefull);
    valid(vector("ping", "PING", "a nonce showing the byte order"), f, buf, len);
    invalid("ping_truncated", "PING", "11 bytes", buf, len - 1, TERRAD_E_BAD_FRAME);
    ok(terrad_ping_encode(buf, sizeof buf, &len, TERRAD_MSG_PONG, UINT64_MAX), "pong");
    f = cJSON_CreateObject();
    add_u64(f, "nonce", UINT64_MAX);
    valid(vector("pong_max", "PONG", "maximum nonce"), f, buf, len);
}

/* ---- STEP and STEPPED ---- */

/* fields: seq, ticks, count, sets and the poses (as POSE_BATCH's), set after set */
static void step_vector(const char *name, const char *about, terrad_step_head h,
                        const terrad_pose *poses)
{
    size_t len;
    ok(terrad_step_encode(buf, sizeof buf, &len, &h, poses), name);
    cJSON *f = pose_fields(h.seq, poses, (size_t)h.count * h.sets);
    cJSON_AddNumberToObject(f, "ticks", h.ticks);
    cJSON_AddNumberToObject(f, "count", h.count);
    cJSON_AddNumberToObject(f, "sets", h.sets);
    valid(vector(name, "STEP", about), f, buf, len);
}

static void step_vectors(void)
{
    terrad_pose p[4] = {
        {3, 1.0f, 2.0f, 0.5f, 1, 0, 0, 0},
        {4, 1.5f, 2.0f, 0.5f, 0.70710677f, 0, 0.70710677f, 0},
        {3, 1.25f, 2.0f, 0.5f, 1, 0, 0, 0},
        {4, 1.75f, 2.0f, 0.5f, 0.5f, 0.5f, 0.5f, 0.5f},
    };
    step_vector("step_hold", "five ticks, every collider holds its pose (no sets)",
                (terrad_step_head){.seq = 9, .ticks = 5, .count = 0, .sets = 0}, p);
    step_vector("step_once", "three ticks, two poses at the first and held after",
                (terrad_step_head){.seq = 10, .ticks = 3, .count = 2, .sets = 1}, p);
    step_vector("step_each", "two ticks, one set of two poses per tick",
                (terrad_step_head){.seq = 4294967295u, .ticks = 2, .count = 2, .sets = 2}, p);
    size_t len = 0;
    ok(terrad_step_encode(buf, sizeof buf, &len,
                          &(terrad_step_head){.seq = 1, .ticks = 2, .count = 2, .sets = 2}, p),
       "step");
    uint8_t q[256];
    memcpy(q, buf, len);
    set_u32(q + 8, 0);
    invalid("step_zero_ticks", "STEP", "ticks 0", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, buf, len);
    set_u32(q + 8, 3);
    invalid("step_sets_not_ticks", "STEP", "two sets for three ticks", q, len, TERRAD_E_BAD_VALUE);
    bad_f32("step_nan_pose", "STEP", "the second set's first pose has x NaN", len,
            TERRAD_STEP_FIXED + 2 * TERRAD_POSE_SIZE + 4, NAN);
    invalid("step_truncated", "STEP", "the last pose cut short", buf, len - 1, TERRAD_E_BAD_FRAME);
    invalid("step_no_sets", "STEP", "ticks and count but no sets field", buf, 14,
            TERRAD_E_BAD_FRAME);

    ok(terrad_stepped_encode(buf, sizeof buf, &len, 1234567890123ull, 10, 3), "stepped");
    cJSON *f = cJSON_CreateObject();
    add_u64(f, "tick", 1234567890123ull);
    cJSON_AddNumberToObject(f, "seq", 10);
    cJSON_AddNumberToObject(f, "ticks", 3);
    valid(vector("stepped_basic", "STEPPED", "step 10's three ticks ended at tick 1234567890123"),
          f, buf, len);
    invalid("stepped_short", "STEPPED", "19 bytes", buf, len - 1, TERRAD_E_BAD_FRAME);
    memcpy(q, buf, len);
    set_u32(q + 16, 0);
    invalid("stepped_zero_ticks", "STEPPED", "ticks 0", q, len, TERRAD_E_BAD_VALUE);
}

/* ---- COLLIDERS ---- */

static cJSON *collider_state_json(const void *entry)
{
    const terrad_collider_state *e = entry;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "id", e->id);
    cJSON_AddNumberToObject(o, "owner", e->owner);
    cJSON_AddNumberToObject(o, "kind", e->kind);
    cJSON_AddItemToObject(o, "dims", float_array(e->dims, 3));
    cJSON_AddItemToObject(o, "p", float_array(e->p, 3));
    cJSON_AddItemToObject(o, "q", float_array(e->q, 4));
    return o;
}

static cJSON *colliders_fields(uint64_t tick, const terrad_collider_state *c, size_t n)
{
    return tick_list_fields(tick, "colliders", c, sizeof *c, n, collider_state_json);
}

static void colliders_vectors(void)
{
    size_t len;
    ok(terrad_colliders_encode(buf, sizeof buf, &len, 7, NULL, 0), "colliders");
    valid(vector("colliders_empty", "COLLIDERS", "no collider in view"),
          colliders_fields(7, NULL, 0), buf, len);
    terrad_collider_state c[3] = {
        {5, TERRAD_OWNER_OWN, TERRAD_KIND_SPHERE, {0.3f, 0, 0}, {1.5f, 2.25f, 0.25f}, {1, 0, 0, 0}},
        {9,
         TERRAD_OWNER_OTHER,
         TERRAD_KIND_CYLINDER,
         {0.35f, 0.125f, 0},
         {-3.0f, 40.5f, 1.0f},
         {0.5f, 0.5f, -0.5f, 0.5f}},
        {0x80000001u,
         TERRAD_OWNER_DEMO,
         TERRAD_KIND_BOX,
         {1.0f, 0.5f, 0.25f},
         {100.0f, 200.0f, -0.5f},
         {0.0f, 0.0f, 0.0f, 1.0f}},
    };
    ok(terrad_colliders_encode(buf, sizeof buf, &len, 123456789012ull, c, 3), "colliders");
    valid(vector("colliders_three", "COLLIDERS", "own sphere, another client's wheel, a demo box"),
          colliders_fields(123456789012ull, c, 3), buf, len);
    bad_byte("colliders_bad_owner", "COLLIDERS", "owner 3", len, 14 + 4, 3,
             TERRAD_E_BAD_VALUE); /* first entry's owner */
    bad_byte("colliders_bad_kind", "COLLIDERS", "kind 5", len, 14 + 5, 5,
             TERRAD_E_BAD_VALUE); /* first entry's kind */
    bad_byte("colliders_reserved", "COLLIDERS", "reserved bytes set", len, 14 + 6, 1,
             TERRAD_E_BAD_VALUE); /* reserved u16 */
    bad_f32("colliders_nan", "COLLIDERS", "position y is NaN", len, 14 + 8 + 4 * 4,
            NAN); /* first entry's y */
    bad_f32("colliders_negative_dim", "COLLIDERS", "radius < 0", len, 14 + 8,
            -0.3f); /* first entry's radius */
    bad_f32("colliders_quaternion", "COLLIDERS", "|q| = 2", len, 14 + 8 + 24,
            2.0f); /* first entry's qw: |q|^2 = 4 */
    invalid("colliders_truncated", "COLLIDERS", "the last entry cut short", buf, len - 4,
            TERRAD_E_BAD_FRAME);
    buf[len] = 0;
    invalid("colliders_trailing", "COLLIDERS", "a byte after the last entry", buf, len + 1,
            TERRAD_E_BAD_FRAME);
}

/* The grousers extension (PROTOCOL.md "COLLIDERS"): the fields say "grousers": true and each
 * entry's "grousers", {count, height, thickness} or null for none. */
static cJSON *colliders_grousers_fields(uint64_t tick, const terrad_collider_state *c,
                                        const terrad_collider_grousers *g, size_t n)
{
    cJSON *f = colliders_fields(tick, c, n);
    cJSON_AddBoolToObject(f, "grousers", 1);
    cJSON *a = cJSON_GetObjectItemCaseSensitive(f, "colliders");
    for (size_t i = 0; i < n; i++) {
        cJSON *e = cJSON_GetArrayItem(a, (int)i);
        if (g[i].count == 0) {
            cJSON_AddNullToObject(e, "grousers");
            continue;
        }
        cJSON *o = cJSON_AddObjectToObject(e, "grousers");
        cJSON_AddNumberToObject(o, "count", g[i].count);
        cJSON_AddNumberToObject(o, "height", g[i].height_m);
        cJSON_AddNumberToObject(o, "thickness", g[i].thickness_m);
    }
    return f;
}

static void colliders_grousers_vectors(void)
{
    size_t len;
    ok(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 8, NULL, NULL, 0), "grousers");
    valid(vector("colliders_grousers_empty", "COLLIDERS",
                 "the grousers extension (header flag 0x01) with no collider in view"),
          colliders_grousers_fields(8, NULL, NULL, 0), buf, len);
    terrad_collider_state c[3] = {
        {9,
         TERRAD_OWNER_OTHER,
         TERRAD_KIND_CYLINDER,
         {0.35f, 0.125f, 0},
         {-3.0f, 40.5f, 0.25f},
         {0.96592583f, 0.0f, 0.25881905f, 0.0f}}, /* turned 30 degrees about its axle */
        {5, TERRAD_OWNER_OWN, TERRAD_KIND_SPHERE, {0.3f, 0, 0}, {1.5f, 2.25f, 0.25f}, {1, 0, 0, 0}},
        {10, TERRAD_OWNER_OWN, TERRAD_KIND_CYLINDER, {0.5f, 0.2f, 0}, {4, 5, 0.5f}, {1, 0, 0, 0}},
    };
    terrad_collider_grousers g[3] = {{30, 0.01f, 0.004f}, {0, 0, 0}, {360, 0.5f, 0.5f}};
    ok(terrad_colliders_encode_grousers(buf, sizeof buf, &len, 123456789013ull, c, g, 3),
       "grousers");
    valid(vector("colliders_grousers", "COLLIDERS",
                 "the grousers extension: another client's lugged wheel turned 30 degrees, a "
                 "sphere (none), a wheel of 360 lugs as tall and thick as its radius"),
          colliders_grousers_fields(123456789013ull, c, g, 3), buf, len);
    const size_t e0 = TERRAD_COLLIDERS_FIXED + TERRAD_COLLIDER_STATE_SIZE; /* first grousers */
    const size_t e1 = e0 + TERRAD_COLLIDER_GROUSERS_SIZE + TERRAD_COLLIDER_STATE_SIZE;
    uint8_t q[256];
    memcpy(q, buf, len);
    set_u16(q + e1, 4);
    invalid("colliders_grousers_on_sphere", "COLLIDERS", "4 grousers on a sphere", q, len,
            TERRAD_E_BAD_VALUE);
    memcpy(q, buf, len);
    set_u16(q + e0, 361);
    invalid("colliders_grousers_count", "COLLIDERS", "361 grousers", q, len, TERRAD_E_BAD_VALUE);
    bad_byte("colliders_grousers_reserved", "COLLIDERS", "the grousers' reserved bytes set", len,
             e0 + 2, 1, TERRAD_E_BAD_VALUE);
    bad_f32("colliders_grousers_nan", "COLLIDERS", "grouser height NaN", len, e0 + 4, NAN);
    bad_f32("colliders_grousers_zero", "COLLIDERS", "grouser thickness 0 with 30 grousers", len,
            e0 + 8, 0.0f);
    bad_f32("colliders_grousers_tall", "COLLIDERS", "grousers taller than the wheel's radius", len,
            e0 + 4, 0.375f);
    bad_f32("colliders_grousers_none_sized", "COLLIDERS", "no grousers but a height", len, e1 + 4,
            0.01f);
    invalid("colliders_grousers_truncated", "COLLIDERS", "the last grousers cut short", buf,
            len - 4, TERRAD_E_BAD_FRAME);
    bad_byte("colliders_grousers_unflagged", "COLLIDERS",
             "60-byte entries without the flag: the lengths do not add up", len, 3, 0,
             TERRAD_E_BAD_FRAME);
    bad_byte("colliders_grousers_flag_2", "COLLIDERS", "header flag 0x02, undefined", len, 3, 2,
             TERRAD_E_BAD_FRAME);
    ok(terrad_colliders_encode(buf, sizeof buf, &len, 123456789013ull, c, 3), "colliders");
    bad_byte("colliders_flagged_48", "COLLIDERS",
             "the flag on 48-byte entries: the lengths do not add up", len, 3, 1,
             TERRAD_E_BAD_FRAME);
}

/* ---- FOOTPRINTS ---- */

static cJSON *footprint_json(const void *entry)
{
    const terrad_footprint *e = entry;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "collider", e->collider);
    cJSON_AddNumberToObject(o, "x", e->x);
    cJSON_AddNumberToObject(o, "y", e->y);
    cJSON_AddNumberToObject(o, "yaw", e->yaw);
    cJSON_AddNumberToObject(o, "size_m", e->size_m);
    cJSON_AddNumberToObject(o, "strength_m", e->strength_m);
    return o;
}

static cJSON *footprints_fields(uint64_t tick, const terrad_footprint *e, size_t n)
{
    return tick_list_fields(tick, "footprints", e, sizeof *e, n, footprint_json);
}

static void footprints_vectors(void)
{
    size_t len;
    ok(terrad_footprints_encode(buf, sizeof buf, &len, 11, NULL, 0), "footprints");
    valid(vector("footprints_empty", "FOOTPRINTS", "no event in view"),
          footprints_fields(11, NULL, 0), buf, len);
    terrad_footprint e[3] = {
        {5, 1.5f, 2.25f, 0.0f, 0.5f, 0.0625f},
        {9, -3.0f, 40.5f, -1.5f, 1.25f, 0.001f},
        {0x80000001u, 100.0f, 200.0f, TERRAD_FOOTPRINT_YAW_MAX, 4.0f, 0.75f},
    };
    ok(terrad_footprints_encode(buf, sizeof buf, &len, 123456789012ull, e, 3), "footprints");
    valid(vector("footprints_three", "FOOTPRINTS",
                 "a sphere, another client's wheel turned, a demo box at yaw pi"),
          footprints_fields(123456789012ull, e, 3), buf, len);
    bad_f32("footprints_nan", "FOOTPRINTS", "x is NaN", len, 14 + 4, NAN); /* first event's x */
    bad_f32("footprints_inf", "FOOTPRINTS", "y is +Inf", len, 14 + 8,
            INFINITY); /* first event's y */
    bad_f32("footprints_yaw", "FOOTPRINTS", "yaw 4 > pi", len, 14 + 12,
            4.0f); /* first event's yaw */
    bad_f32("footprints_zero_size", "FOOTPRINTS", "size 0", len, 14 + 16,
            0.0f); /* first event's size */
    bad_f32("footprints_negative_strength", "FOOTPRINTS", "strength < 0", len, 14 + 20,
            -0.25f); /* first event's strength */
    invalid("footprints_truncated", "FOOTPRINTS", "the last event cut short", buf, len - 4,
            TERRAD_E_BAD_FRAME);
    buf[len] = 0;
    invalid("footprints_trailing", "FOOTPRINTS", "a byte after the last event", buf, len + 1,
            TERRAD_E_BAD_FRAME);
    bad_byte("footprints_count", "FOOTPRINTS", "count 4 with three events", len, 12, 4,
             TERRAD_E_BAD_FRAME); /* count 4, three events follow */
}

/* ---- FORCES ---- */

static cJSON *force_json(const void *entry)
{
    const terrad_force *f = entry;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "id", f->id);
    cJSON_AddItemToObject(o, "force", cJSON_CreateFloatArray(f->force, 3));
    cJSON_AddItemToObject(o, "torque", cJSON_CreateFloatArray(f->torque, 3));
    cJSON_AddNumberToObject(o, "sinkage_m", f->sinkage_m);
    cJSON_AddNumberToObject(o, "area_m2", f->area_m2);
    cJSON_AddNumberToObject(o, "patch_width_m", f->patch_width_m);
    cJSON_AddNumberToObject(o, "slip", f->slip);
    cJSON_AddNumberToObject(o, "cells", f->cells);
    return o;
}

static cJSON *forces_fields(uint64_t tick, const terrad_force *f, size_t n)
{
    return tick_list_fields(tick, "forces", f, sizeof *f, n, force_json);
}

static void forces_vectors(void)
{
    size_t len;
    ok(terrad_forces_encode(buf, sizeof buf, &len, 12, NULL, 0), "forces");
    valid(vector("forces_empty", "FORCES", "no collider with feedback"), forces_fields(12, NULL, 0),
          buf, len);
    terrad_force f[2] = {
        {3, {-6.5f, 0.25f, 80.0f}, {0.125f, 5.25f, -0.5f}, 0.0075f, 0.0125f, 0.0625f, 0.2f, 500},
        {0x80000002u, {0.0f, 0.0f, 0.0f}, {0.0f, 0.0f, 0.0f}, 0.0f, 0.0f, 0.0f, -1.0f, 0},
    };
    ok(terrad_forces_encode(buf, sizeof buf, &len, 987654321ull, f, 2), "forces");
    valid(vector("forces_two", "FORCES", "a driven wheel at slip 0.2, a skidding wheel lifted off"),
          forces_fields(987654321ull, f, 2), buf, len);
    bad_f32("forces_nan", "FORCES", "force x is NaN", len, 14 + 4, NAN); /* first entry's force x */
    bad_f32("forces_inf", "FORCES", "slip is +Inf", len, 14 + 40,
            INFINITY); /* first entry's slip */
    bad_f32("forces_negative_sinkage", "FORCES", "sinkage < 0", len, 14 + 28,
            -0.001f); /* first entry's sinkage */
    bad_f32("forces_negative_area", "FORCES", "area < 0", len, 14 + 32,
            -1.0f); /* first entry's area */
    invalid("forces_truncated", "FORCES", "the last entry cut short", buf, len - 4,
            TERRAD_E_BAD_FRAME);
    buf[len] = 0;
    invalid("forces_trailing", "FORCES", "a byte after the last entry", buf, len + 1,
            TERRAD_E_BAD_FRAME);
    bad_byte("forces_count", "FORCES", "count 3 with two entries", len, 12, 3,
             TERRAD_E_BAD_FRAME); /* count 3, two entries follow */
}

/* ---- CHECKSUM and the tile hash ---- */

static cJSON *tile_sum_json(const void *entry)
{
    const terrad_tile_sum *t = entry;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddNumberToObject(o, "tile_x", t->tile_x);
    cJSON_AddNumberToObject(o, "tile_y", t->tile_y);
    cJSON_AddNumberToObject(o, "version", t->version);
    add_u64(o, "hash", t->hash);
    return o;
}

static cJSON *checksum_fields(uint64_t tick, uint32_t sub, const terrad_tile_sum *t, size_t n)
{
    cJSON *f = tick_list_fields(tick, "tiles", t, sizeof *t, n, tile_sum_json);
    cJSON_AddNumberToObject(f, "subscription", sub);
    return f;
}

/* "hashes": heights (row-major, w x h) and their terrad_heights_hash */
static void hash_vector(cJSON *hashes, const char *about, const int32_t *v, uint32_t w, uint32_t h)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "about", about);
    cJSON_AddNumberToObject(o, "w", w);
    cJSON_AddNumberToObject(o, "h", h);
    cJSON_AddItemToObject(o, "heights", int_array(v, (size_t)w * h));
    add_u64(o, "hash", terrad_heights_hash(v, w, w, h));
    cJSON_AddItemToArray(hashes, o);
}

static void checksum_vectors(cJSON *hashes)
{
    hash_vector(hashes, "no heights: the seed", NULL, 0, 0);
    int32_t one[1] = {0};
    hash_vector(hashes, "one height 0", one, 1, 1);
    int32_t small[6] = {1, -1, 2, -2, 10000, -10000};
    hash_vector(hashes, "3 x 2, both signs", small, 3, 2);
    int32_t ext[4] = {INT32_MIN, INT32_MAX, 0x12345678, -0x12345678};
    hash_vector(hashes, "2 x 2 extremes", ext, 2, 2);
    int32_t bumped[6] = {1, -1, 2, -2, 10001, -10000};
    hash_vector(hashes, "the 3 x 2 one with one height one unit up", bumped, 3, 2);
    static int32_t tile[64 * 64];
    for (int i = 0; i < 64 * 64; i++)
        tile[i] = 4000 + (i % 64) * 7 - (i / 64) * 3 + (i % 5 == 0 ? -11 : 0);
    hash_vector(hashes, "a whole 64 x 64 tile: 4000 + 7 x - 3 y - 11 where (64 y + x) % 5 == 0",
                tile, 64, 64);

    size_t len;
    ok(terrad_checksum_encode(buf, sizeof buf, &len, 30, 1, NULL, 0), "checksum");
    valid(vector("checksum_empty", "CHECKSUM", "a subscription with no tile current"),
          checksum_fields(30, 1, NULL, 0), buf, len);
    terrad_tile_sum t[2] = {{0, 0, 1, TERRAD_HASH_SEED},
                            {3, 2, 4294967295u, 0x8000000000000001ull}};
    ok(terrad_checksum_encode(buf, sizeof buf, &len, 1234567890123ull, 7, t, 2), "checksum");
    valid(vector("checksum_two", "CHECKSUM", "two tiles of subscription 7, the largest version"),
          checksum_fields(1234567890123ull, 7, t, 2), buf, len);
    uint8_t q[256];
    memcpy(q, buf, len);
    set_u32(q + 12, 0);
    invalid("checksum_subscription_zero", "CHECKSUM", "subscription 0", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, buf, len);
    set_u32(q + 18 + 8, 0);
    invalid("checksum_version_zero", "CHECKSUM", "a tile of version 0", q, len, TERRAD_E_BAD_VALUE);
    memcpy(q, buf, len);
    set_u32(q + 18 + 20, 0xffffffffu);
    invalid("checksum_negative_tile", "CHECKSUM", "tile x -1", q, len, TERRAD_E_BAD_VALUE);
    invalid("checksum_truncated", "CHECKSUM", "the last entry cut short", buf, len - 1,
            TERRAD_E_BAD_FRAME);
    invalid("checksum_short", "CHECKSUM", "17 bytes", buf, 17, TERRAD_E_BAD_FRAME);
    buf[len] = 0;
    invalid("checksum_trailing", "CHECKSUM", "a byte after the last entry", buf, len + 1,
            TERRAD_E_BAD_FRAME);
    bad_byte("checksum_count", "CHECKSUM", "count 3 with two entries", len, 16, 3,
             TERRAD_E_BAD_FRAME);
}

/* ---- mirror scenarios ---- */

/* World heights of a tiny made-up world, used for snapshots. */
static int32_t world_at(int x, int y)
{
    return 1000 * y + x;
}

typedef struct scenario {
    cJSON *json, *steps;
    terrad_mirror m;
    int32_t heights[64];
    uint32_t versions[16];
} scenario;

static void scenario_begin(scenario *s, const char *name, int32_t x, int32_t y, uint32_t w,
                           uint32_t h, uint32_t tile)
{
    s->json = cJSON_CreateObject();
    cJSON_AddStringToObject(s->json, "name", name);
    cJSON *reg = cJSON_AddObjectToObject(s->json, "region");
    cJSON_AddNumberToObject(reg, "x", x);
    cJSON_AddNumberToObject(reg, "y", y);
    cJSON_AddNumberToObject(reg, "w", w);
    cJSON_AddNumberToObject(reg, "h", h);
    cJSON_AddNumberToObject(s->json, "tile_size", tile);
    s->steps = cJSON_AddArrayToObject(s->json, "steps");
    memset(s->heights, 0, sizeof s->heights);
    ok(terrad_mirror_init(&s->m, x, y, w, h, tile, s->heights, s->versions), "mirror");
    cJSON_AddItemToArray(scenarios, s->json);
}

/* Apply one frame, record it with the error and the state after. */
static void scenario_frame(scenario *s, const char *about, uint64_t tick, rect_spec *specs,
                           size_t n)
{
    terrad_rect rects[16];
    for (size_t i = 0; i < n; i++) {
        if (!specs[i].r.data)
            compress_spec(&specs[i]);
        rects[i] = specs[i].r;
    }
    size_t len;
    ok(terrad_delta_encode(buf, sizeof buf, &len, tick, rects, n), about);
    int32_t scratch[256];
    int rc = terrad_mirror_apply(&s->m, NULL, rects, n, scratch, 256);
    cJSON *st = cJSON_CreateObject();
    cJSON_AddStringToObject(st, "about", about);
    add_hex(st, "frame_hex", buf, len);
    cJSON_AddStringToObject(st, "error", rc ? terrad_err_name(rc) : "");
    cJSON_AddItemToObject(st, "heights", int_array(s->heights, (size_t)s->m.w * s->m.h));
    size_t tiles = (size_t)s->m.tiles_x * s->m.tiles_y;
    cJSON *v = cJSON_CreateArray();
    for (size_t i = 0; i < tiles; i++)
        cJSON_AddItemToArray(v, cJSON_CreateNumber(s->versions[i]));
    cJSON_AddItemToObject(st, "versions", v);
    cJSON_AddItemToArray(s->steps, st);
}

static rect_spec snapshot_spec(int x, int y, int w, int h, uint32_t version, int32_t *store)
{
    for (int j = 0; j < h; j++)
        for (int i = 0; i < w; i++)
            store[j * w + i] = world_at(x + i, y + j);
    rect_spec s = {{x, y, (uint16_t)w, (uint16_t)h, 0, version, TERRAD_ENC_SNAPSHOT, 0, NULL},
                   store,
                   NULL,
                   NULL,
                   NULL};
    return s;
}

static void mirror_scenarios(void)
{
    /* Region (2, 2) 6 x 5 over tiles of 4: tiles (0..1) x (0..1), 4 tiles. */
    scenario s;
    scenario_begin(&s, "subscribe_then_deltas", 2, 2, 6, 5, 4);
    static int32_t st[4][64];
    rect_spec snaps[4] = {
        snapshot_spec(2, 2, 2, 2, 5, st[0]), /* tile (0,0) part */
        snapshot_spec(4, 2, 4, 2, 3, st[1]), /* tile (1,0) part */
        snapshot_spec(2, 4, 2, 3, 1, st[2]), /* tile (0,1) part */
        snapshot_spec(4, 4, 4, 3, 8, st[3]), /* tile (1,1) part */
    };
    static const int32_t dA[2] = {-3, 4}, dB[1] = {-1};
    rect_spec d1[3] = {
        {{4, 2, 2, 1, 3, 4, TERRAD_ENC_DELTA, 0, NULL}, dA, NULL, NULL, NULL},
        {{7, 3, 1, 1, 3, 4, TERRAD_ENC_DELTA, 0, NULL}, dB, NULL, NULL, NULL},
        {{0, 0, 1, 1, 5, 6, TERRAD_ENC_DELTA, 0, NULL}, dB, NULL, NULL, NULL},
    };
    static const int32_t dE[1] = {100};
    rect_spec far = {{40, 40, 1, 1, 1, 2, TERRAD_ENC_DELTA, 0, NULL}, dE, NULL, NULL, NULL};
    scenario_frame(&s, "a delta before any snapshot is skipped", 10, &d1[0], 1);
    scenario_frame(&s, "the snapshot of the subscription, one rectangle per tile", 11, snaps, 4);
    scenario_frame(&s,
                   "two rectangles of one tile (3 -> 4), and one of tile (0,0) whose cell "
                   "(0,0) lies outside the region: no cell changes, the tile still goes 5 -> 6",
                   12, d1, 3);
    static const int32_t dC[4] = {7, 7, 7, 7};
    rect_spec d2 = {{4, 4, 2, 2, 7, 9, TERRAD_ENC_DELTA, 0, NULL}, dC, NULL, NULL, NULL};
    scenario_frame(&s, "a rectangle of a tile the region does not touch is skipped", 13, &far, 1);
    static const int32_t dF[1] = {-50};
    rect_spec mixed[2] = {
        {{2, 5, 1, 1, 1, 2, TERRAD_ENC_DELTA, 0, NULL}, dF, NULL, NULL, NULL},
        d2,
    };
    scenario_frame(&s,
                   "a good delta for tile (0,1) and one from base 7 while tile (1,1) is held "
                   "at 8: stale_base, nothing changes",
                   13, mixed, 2);
    d2.r.base_version = 8;
    scenario_frame(&s, "the same delta from base 8 applies (a coalesced 8 -> 9)", 14, &d2, 1);
    static int32_t pst[64];
    rect_spec partial = snapshot_spec(4, 4, 1, 1, 20, pst);
    scenario_frame(&s, "a snapshot covering part of what the region holds of a tile is ignored", 15,
                   &partial, 1);
    static const int32_t dD[2] = {1, 1};
    rect_spec span = {{3, 2, 2, 1, 5, 6, TERRAD_ENC_DELTA, 0, NULL}, dD, NULL, NULL, NULL};
    scenario_frame(&s, "a rectangle spanning two tiles is refused with bad_value", 16, &span, 1);
    rect_spec resync = snapshot_spec(4, 4, 4, 3, 30, st[3]);
    scenario_frame(&s, "a resync snapshot replaces a held tile", 17, &resync, 1);

    scenario n;
    scenario_begin(&n, "negative_coordinates", -5, -3, 4, 4, 4);
    static int32_t nst[4][64];
    rect_spec nsnaps[4] = {
        snapshot_spec(-5, -3, 1, 3, 2, nst[0]), /* tile (-2,-1) */
        snapshot_spec(-4, -3, 3, 3, 2, nst[1]), /* tile (-1,-1) */
        snapshot_spec(-5, 0, 1, 1, 2, nst[2]),  /* tile (-2, 0) */
        snapshot_spec(-4, 0, 3, 1, 2, nst[3]),  /* tile (-1, 0) */
    };
    scenario_frame(&n, "snapshot of a region straddling the origin", 1, nsnaps, 4);
    static const int32_t dn[9] = {INT32_MAX, 1, -1, INT32_MIN, 0, 2, -2, 3, -3};
    rect_spec ndelta = {{-4, -3, 3, 3, 2, 3, TERRAD_ENC_DELTA, 0, NULL}, dn, NULL, NULL, NULL};
    scenario_frame(&n, "a delta with wrapping differences", 2, &ndelta, 1);
}

/* ---- base snapshot payloads (PROTOCOL.md "Base snapshots") ---- */

/* A payload p (n bytes) every decoder must refuse with bad_compression. */
static void refused_rect(cJSON *arr, const char *about, const uint8_t *p, size_t n, uint32_t w,
                         uint32_t h)
{
    cJSON *q = cJSON_CreateObject();
    cJSON_AddStringToObject(q, "about", about);
    cJSON_AddNumberToObject(q, "w", w);
    cJSON_AddNumberToObject(q, "h", h);
    add_hex(q, "data_hex", p, n);
    cJSON_AddStringToObject(q, "error", terrad_err_name(TERRAD_E_BAD_COMPRESSION));
    cJSON_AddItemToArray(arr, q);
}

/* One coded payload p (n bytes) of w x h values v as a valid vector, and the
 * same cut in half (bad_compression) when it is longer than min_len bytes. */
static void coded_rect(cJSON *a, const char *about, const int32_t *v, uint32_t w, uint32_t h,
                       const uint8_t *p, size_t n, size_t min_len)
{
    size_t cells = (size_t)w * h;
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "about", about);
    cJSON_AddNumberToObject(o, "w", w);
    cJSON_AddNumberToObject(o, "h", h);
    cJSON_AddItemToObject(o, "values", int_array(v, cells));
    add_hex(o, "data_hex", p, n);
    cJSON_AddStringToObject(o, "error", "");
    cJSON_AddItemToArray(a, o);
    if (n > min_len) { /* the same payload cut to half: refused */
        char what[200];
        snprintf(what, sizeof what, "%s, cut to %zu of its %zu bytes", about, n / 2, n);
        refused_rect(a, what, p, n / 2, w, h);
    }
}

/* "base_rects": one encoding 2 payload of w x h values (h - base), coded by the C coder */
static void base_rect(cJSON *a, const char *about, const int32_t *v, uint32_t w, uint32_t h)
{
    size_t cells = (size_t)w * h, cap = terrad_rect_compress_base_bound(cells), n;
    uint8_t *p = malloc(cap);
    if (!p)
        die("out of memory");
    ok(terrad_rect_compress_base(v, w, h, p, cap, &n), about);
    coded_rect(a, about, v, w, h, p, n, 5);
    free(p);
}

static void base_vectors(cJSON *a)
{
    enum { W = 24, H = 20 };
    int32_t v[W * H];
    for (int y = 0; y < H; y++) /* a crater's bowl and rim: small residuals */
        for (int x = 0; x < W; x++) {
            int d2 = (x - 11) * (x - 11) + (y - 9) * (y - 9), r2 = 7 * 7;
            v[y * W + x] = d2 < r2 ? -(900 * (r2 - d2) / r2) : d2 < 4 * r2 ? (4 * r2 - d2) / 3 : 0;
        }
    base_rect(a, "a crater, 24 x 20", v, W, H);
    uint32_t r = 2024;
    for (int i = 0; i < W * H; i++) { /* noise over the whole int32 range */
        r = r * 1664525u + 1013904223u;
        v[i] = (int32_t)r;
    }
    base_rect(a, "noise over the int32 range, 24 x 20", v, W, H);
    for (int i = 0; i < W * H; i++) /* every difference wraps; residuals up to 2^32 - 1 */
        v[i] = (i * 7 + i / W) % 3 == 0 ? INT32_MIN : (i % 5 == 0 ? INT32_MAX : -1);
    base_rect(a, "INT32_MIN, INT32_MAX and -1, 24 x 20", v, W, H);
    base_rect(a, "one row of 40", v, 40, 1);
    base_rect(a, "one column of 40", v, 1, 40);
    int32_t zero[64] = {0};
    base_rect(a, "an undug 8 x 8 tile: all 0", zero, 8, 8);
    int32_t one = INT32_MIN;
    base_rect(a, "one cell, INT32_MIN", &one, 1, 1);
    static const uint8_t four[4] = {0, 1, 2, 3};
    refused_rect(a, "four bytes: fewer than the coder's five", four, 4, 2, 2);
}

/* ---- slope snapshot payloads (PROTOCOL.md "Slope snapshots") ---- */

/* "slope_rects": one encoding 3 payload of w x h values coded by the C coder
 * with limits a and b (auto: the coder's own choice), and the same cut in
 * half (bad_compression). */
static void slope_rect(cJSON *arr, const char *about, const int32_t *v, uint32_t w, uint32_t h,
                       int autolimits, uint32_t a, uint32_t b)
{
    size_t cells = (size_t)w * h, cap = terrad_rect_compress_slope_bound(cells), n;
    uint8_t *p = malloc(cap);
    if (!p)
        die("out of memory");
    ok(autolimits ? terrad_rect_compress_slope(v, w, h, p, cap, &n)
                  : terrad_rect_compress_slope_ab(v, w, h, a, b, p, cap, &n),
       about);
    coded_rect(arr, about, v, w, h, p, n, 13);
    free(p);
}

static void slope_vectors(cJSON *arr)
{
    enum { W = 24, H = 20 };
    int32_t v[W * H];
    /* a sand pile: the lowest of cones of slope 367 a cell axially, 509
     * diagonally (chamfer distance), from a few seeded apexes: most cells sit
     * exactly at a bound of their neighbours, a few one under */
    static const int cx[4] = {3, 17, 9, 21}, cy[4] = {4, 2, 15, 17}, c0[4] = {-800, -500, -650, 0};
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int64_t best = INT64_MAX;
            for (int k = 0; k < 4; k++) {
                int dx = abs(x - cx[k]), dy = abs(y - cy[k]);
                int dg = dx < dy ? dx : dy, ax = (dx > dy ? dx : dy) - dg;
                int64_t z = c0[k] + 367 * ax + 509 * dg - ((x + 2 * y) % 5 == 0);
                best = z < best ? z : best;
            }
            v[y * W + x] = (int32_t)best;
        }
    slope_rect(arr, "a sand pile at its slope limits (a = 367, b = 509), 24 x 20", v, W, H, 0, 367,
               509);
    slope_rect(arr, "the same sand pile, limits of the coder's choice", v, W, H, 1, 0, 0);
    for (int y = 0; y < H; y++) /* a crater's bowl and rim */
        for (int x = 0; x < W; x++) {
            int d2 = (x - 11) * (x - 11) + (y - 9) * (y - 9), r2 = 7 * 7;
            v[y * W + x] = d2 < r2 ? -(900 * (r2 - d2) / r2) : d2 < 4 * r2 ? (4 * r2 - d2) / 3 : 0;
        }
    slope_rect(arr, "a crater, limits of the coder's choice, 24 x 20", v, W, H, 1, 0, 0);
    uint32_t r = 2024;
    for (int i = 0; i < W * H; i++) { /* noise over the whole int32 range */
        r = r * 1664525u + 1013904223u;
        v[i] = (int32_t)r;
    }
    slope_rect(arr, "noise over the int32 range, a = 2^32 - 1, b = 2^31, 24 x 20", v, W, H, 0,
               UINT32_MAX, 1u << 31);
    for (int i = 0; i < W * H; i++) /* bounds past int32 both ways; residuals wrap */
        v[i] = (i * 7 + i / W) % 3 == 0 ? INT32_MIN : (i % 5 == 0 ? INT32_MAX : -1);
    slope_rect(arr, "INT32_MIN, INT32_MAX and -1, a = b = 2^32 - 1, 24 x 20", v, W, H, 0,
               UINT32_MAX, UINT32_MAX);
    slope_rect(arr, "INT32_MIN, INT32_MAX and -1, a = 1, b = 0, 24 x 20", v, W, H, 0, 1, 0);
    slope_rect(arr, "one row of 40, a = 1, b = 0", v, 40, 1, 0, 1, 0);
    slope_rect(arr, "one column of 40, a = 1, b = 0", v, 1, 40, 0, 1, 0);
    int32_t zero[64] = {0};
    slope_rect(arr, "an undug 8 x 8 tile: all 0", zero, 8, 8, 1, 0, 0);
    int32_t one = INT32_MIN;
    slope_rect(arr, "one cell, INT32_MIN", &one, 1, 1, 1, 0, 0);
    /* a cell at its upper bound 0 + 5, then a patched to 2^32 - 16: the bound
     * 2^32 - 16 lies outside int32 */
    int32_t two[2] = {0, 5};
    uint8_t p[64];
    size_t n;
    ok(terrad_rect_compress_slope_ab(two, 2, 1, 5, 0, p, sizeof p, &n), "a = 5");
    p[0] = 0xF0;
    p[1] = p[2] = p[3] = 0xFF;
    refused_rect(arr, "a cell at its upper bound, which lies past INT32_MAX", p, n, 2, 1);
    memset(p, 0, 12);
    refused_rect(arr, "twelve bytes: fewer than the limits and the coder's five", p, 12, 2, 2);
}

int main(void)
{
    cJSON *root = cJSON_CreateObject();
    cJSON_AddNumberToObject(root, "protocol", TERRAD_PROTO_VERSION);
    cJSON_AddStringToObject(root, "generator", "proto/vectors/gen_vectors.c");
    cJSON_AddStringToObject(root, "zstd_version", ZSTD_versionString());
    cJSON_AddNumberToObject(root, "zstd_level", 3);
    cJSON *errs = cJSON_AddArrayToObject(root, "errors");
    for (int i = TERRAD_ERR_FIRST; i <= TERRAD_ERR_LAST; i++) {
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "code", i);
        cJSON_AddStringToObject(e, "name", terrad_err_name(i));
        cJSON_AddItemToArray(errs, e);
    }
    cJSON *types = cJSON_AddArrayToObject(root, "types");
    for (int t = 0; t < 256; t++) {
        if (!terrad_msg_type_name(t))
            continue;
        cJSON *e = cJSON_CreateObject();
        cJSON_AddNumberToObject(e, "code", t);
        cJSON_AddStringToObject(e, "name", terrad_msg_type_name(t));
        cJSON_AddItemToArray(types, e);
    }
    vectors = cJSON_AddArrayToObject(root, "vectors");
    scenarios = cJSON_AddArrayToObject(root, "mirror_scenarios");
    pose_vectors();
    delta_vectors();
    small_vectors();
    colliders_vectors();
    colliders_grousers_vectors();
    footprints_vectors();
    forces_vectors();
    step_vectors();
    checksum_vectors(cJSON_AddArrayToObject(root, "hashes"));
    mirror_scenarios();
    base_vectors(cJSON_AddArrayToObject(root, "base_rects"));
    slope_vectors(cJSON_AddArrayToObject(root, "slope_rects"));
    char *text = cJSON_Print(root);
    if (!text)
        die("print");
    fputs(text, stdout);
    fputc('\n', stdout);
    free(text);
    cJSON_Delete(root);
    return 0;
}
