/*
 * terrad_proto.c: encoders and decoders of the binary frames, the rectangle
 * payload codec (zigzag, little-endian packing, zstd) and the client-side
 * mirror. PROTOCOL.md is the specification; this file follows it field by
 * field.
 *
 * Reading and writing go through a cursor (buf, len, pos) whose getters
 * check the remaining length before touching a byte, so no decoder can read
 * past its buffer whatever the counts in the frame say. Counts are checked
 * against the remaining length before any element is read, so a frame that
 * claims 65535 poses in 20 bytes costs one comparison.
 */
#include "terrad_proto.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <zstd.h>
#include <zstd_errors.h>

/* ---- names --------------------------------------------------------------- */

static const char *const err_names[] = {
    "ok",
    "bad_frame",
    "unknown_type",
    "bad_version",
    "too_large",
    "bad_value",
    "unknown_collider",
    "not_owner",
    "limit_colliders",
    "limit_subscriptions",
    "rate_limited",
    "outside_world",
    "bad_json",
    "unauthorized",
    "refused_height_limit",
    "store_unavailable",
    "bad_compression",
    "stale_base",
    "unsupported_collider",
    "unknown_subscription",
    "shutting_down",
    "internal",
    "forbidden",
};

const char *terrad_err_name(int code)
{
    if (code >= 0 && code <= TERRAD_ERR_LAST)
        return err_names[code];
    if (code == TERRAD_E_BUFFER_TOO_SMALL)
        return "buffer_too_small";
    if (code == TERRAD_E_NO_MEMORY)
        return "no_memory";
    return NULL;
}

int terrad_err_from_name(const char *name)
{
    if (!name)
        return 0;
    for (int i = TERRAD_ERR_FIRST; i <= TERRAD_ERR_LAST; i++)
        if (strcmp(err_names[i], name) == 0)
            return i;
    if (strcmp(name, "buffer_too_small") == 0)
        return TERRAD_E_BUFFER_TOO_SMALL;
    if (strcmp(name, "no_memory") == 0)
        return TERRAD_E_NO_MEMORY;
    return 0;
}

const char *terrad_msg_type_name(int type)
{
    switch (type) {
    case TERRAD_MSG_POSE_BATCH:
        return "POSE_BATCH";
    case TERRAD_MSG_PING:
        return "PING";
    case TERRAD_MSG_PONG:
        return "PONG";
    case TERRAD_MSG_STEP:
        return "STEP";
    case TERRAD_MSG_DELTA:
        return "DELTA";
    case TERRAD_MSG_CONTACT:
        return "CONTACT";
    case TERRAD_MSG_ACK:
        return "ACK";
    case TERRAD_MSG_COLLIDERS:
        return "COLLIDERS";
    case TERRAD_MSG_FOOTPRINTS:
        return "FOOTPRINTS";
    case TERRAD_MSG_FORCES:
        return "FORCES";
    case TERRAD_MSG_STEPPED:
        return "STEPPED";
    case TERRAD_MSG_CHECKSUM:
        return "CHECKSUM";
    default:
        return NULL;
    }
}

/* ---- little-endian cursor ------------------------------------------------ */

typedef struct rd {
    const uint8_t *p;
    size_t len, pos;
} rd;

static size_t rd_left(const rd *r)
{
    return r->len - r->pos;
}

static uint8_t rd_u8(rd *r)
{
    return r->p[r->pos++];
}

static uint16_t rd_u16(rd *r)
{
    const uint8_t *p = r->p + r->pos;
    r->pos += 2;
    return (uint16_t)(p[0] | (p[1] << 8));
}

static uint32_t rd_u32(rd *r)
{
    const uint8_t *p = r->p + r->pos;
    r->pos += 4;
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}

static uint64_t rd_u64(rd *r)
{
    uint64_t lo = rd_u32(r);
    uint64_t hi = rd_u32(r);
    return lo | (hi << 32);
}

static float rd_f32(rd *r)
{
    uint32_t u = rd_u32(r);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

static double rd_f64(rd *r)
{
    uint64_t u = rd_u64(r);
    double d;
    memcpy(&d, &u, sizeof d);
    return d;
}

static uint8_t *wr_u8(uint8_t *p, uint8_t v)
{
    *p = v;
    return p + 1;
}

static uint8_t *wr_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    return p + 2;
}

static uint8_t *wr_u32(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
    p[2] = (uint8_t)(v >> 16);
    p[3] = (uint8_t)(v >> 24);
    return p + 4;
}

static uint8_t *wr_u64(uint8_t *p, uint64_t v)
{
    p = wr_u32(p, (uint32_t)v);
    return wr_u32(p, (uint32_t)(v >> 32));
}

static uint8_t *wr_f32(uint8_t *p, float f)
{
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return wr_u32(p, u);
}

static uint8_t *wr_f64(uint8_t *p, double d)
{
    uint64_t u;
    memcpy(&u, &d, sizeof u);
    return wr_u64(p, u);
}

static uint8_t *wr_header(uint8_t *p, uint8_t type)
{
    p = wr_u8(p, TERRAD_PROTO_MAGIC);
    p = wr_u8(p, TERRAD_PROTO_VERSION);
    p = wr_u8(p, type);
    return wr_u8(p, 0);
}

static int finite_all(const float *v, size_t n)
{
    for (size_t i = 0; i < n; i++)
        if (!isfinite(v[i]))
            return 0;
    return 1;
}

/* ---- header -------------------------------------------------------------- */

int terrad_header_decode(const uint8_t *buf, size_t len, terrad_header *out)
{
    if (!buf || len < TERRAD_HEADER_SIZE)
        return TERRAD_E_BAD_FRAME;
    if (buf[0] != TERRAD_PROTO_MAGIC)
        return TERRAD_E_BAD_FRAME;
    if (buf[1] != TERRAD_PROTO_VERSION)
        return TERRAD_E_BAD_VERSION;
    if (!terrad_msg_type_name(buf[2]))
        return TERRAD_E_UNKNOWN_TYPE;
    /* the flags defined, each an extension a client asks for: FORCES' heights,
     * COLLIDERS' grousers; any other bit, or a bit on another type, is refused */
    uint8_t defined = buf[2] == TERRAD_MSG_FORCES      ? TERRAD_FORCES_FLAG_HEIGHT
                      : buf[2] == TERRAD_MSG_COLLIDERS ? TERRAD_COLLIDERS_FLAG_GROUSERS
                                                       : 0;
    if (buf[3] & ~defined)
        return TERRAD_E_BAD_FRAME;
    if (out) {
        out->magic = buf[0];
        out->version = buf[1];
        out->type = buf[2];
        out->flags = buf[3];
    }
    return TERRAD_OK;
}

/* Header of the one type a decoder reads; another known type is
 * unknown_type (the receiver does not take it here). */
static int expect_header(const uint8_t *buf, size_t len, uint8_t type, rd *r)
{
    terrad_header h;
    int rc = terrad_header_decode(buf, len, &h);
    if (rc)
        return rc;
    if (h.type != type)
        return TERRAD_E_UNKNOWN_TYPE;
    r->p = buf;
    r->len = len;
    r->pos = TERRAD_HEADER_SIZE;
    return TERRAD_OK;
}

/* ---- POSE_BATCH ---------------------------------------------------------- */

static int pose_check(const terrad_pose *p)
{
    const float v[7] = {p->x, p->y, p->z, p->qw, p->qx, p->qy, p->qz};
    if (!finite_all(v, 7))
        return TERRAD_E_BAD_VALUE;
    double n2 = (double)p->qw * p->qw + (double)p->qx * p->qx + (double)p->qy * p->qy +
                (double)p->qz * p->qz;
    if (n2 < 0.81 || n2 > 1.21) /* |q| within [0.9, 1.1]; the server normalises */
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

static uint8_t *wr_pose(uint8_t *p, const terrad_pose *q)
{
    p = wr_u32(p, q->id);
    p = wr_f32(p, q->x);
    p = wr_f32(p, q->y);
    p = wr_f32(p, q->z);
    p = wr_f32(p, q->qw);
    p = wr_f32(p, q->qx);
    p = wr_f32(p, q->qy);
    return wr_f32(p, q->qz);
}

static terrad_pose rd_pose(rd *r)
{
    terrad_pose q;
    q.id = rd_u32(r);
    q.x = rd_f32(r);
    q.y = rd_f32(r);
    q.z = rd_f32(r);
    q.qw = rd_f32(r);
    q.qx = rd_f32(r);
    q.qy = rd_f32(r);
    q.qz = rd_f32(r);
    return q;
}

size_t terrad_pose_batch_size(size_t count)
{
    return TERRAD_POSE_BATCH_FIXED + count * TERRAD_POSE_SIZE;
}

int terrad_pose_batch_encode(uint8_t *buf, size_t cap, size_t *len_out, uint32_t seq,
                             const terrad_pose *poses, size_t count)
{
    if (count > TERRAD_MAX_COUNT)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++)
        if (pose_check(&poses[i]))
            return TERRAD_E_BAD_VALUE;
    size_t need = terrad_pose_batch_size(count);
    if (!buf || cap < need)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_POSE_BATCH);
    p = wr_u32(p, seq);
    p = wr_u16(p, (uint16_t)count);
    for (size_t i = 0; i < count; i++)
        p = wr_pose(p, &poses[i]);
    if (len_out)
        *len_out = need;
    return TERRAD_OK;
}

int terrad_pose_batch_decode(const uint8_t *buf, size_t len, uint32_t *seq_out, terrad_pose *poses,
                             size_t cap, size_t *count_out)
{
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_POSE_BATCH, &r);
    if (rc)
        return rc;
    if (rd_left(&r) < 6)
        return TERRAD_E_BAD_FRAME;
    uint32_t seq = rd_u32(&r);
    size_t count = rd_u16(&r);
    if (rd_left(&r) != count * TERRAD_POSE_SIZE)
        return TERRAD_E_BAD_FRAME;
    if (count > cap)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++) {
        terrad_pose q = rd_pose(&r);
        if (pose_check(&q))
            return TERRAD_E_BAD_VALUE;
        poses[i] = q;
    }
    if (seq_out)
        *seq_out = seq;
    if (count_out)
        *count_out = count;
    return TERRAD_OK;
}

/* ---- DELTA --------------------------------------------------------------- */

int terrad_rect_check(const terrad_rect *r)
{
    if (r->w == 0 || r->h == 0)
        return TERRAD_E_BAD_VALUE;
    if ((int64_t)r->x + r->w - 1 > INT32_MAX || (int64_t)r->y + r->h - 1 > INT32_MAX)
        return TERRAD_E_BAD_VALUE;
    if (r->new_version == 0)
        return TERRAD_E_BAD_VALUE;
    if (r->encoding == TERRAD_ENC_DELTA) {
        if (r->base_version == 0 || r->base_version == r->new_version)
            return TERRAD_E_BAD_VALUE;
    } else if (r->encoding == TERRAD_ENC_SNAPSHOT || r->encoding == TERRAD_ENC_BASE ||
               r->encoding == TERRAD_ENC_BASE_SLOPE) {
        if (r->base_version != 0)
            return TERRAD_E_BAD_VALUE;
    } else {
        return TERRAD_E_BAD_VALUE;
    }
    if (r->data_len == 0)
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

size_t terrad_delta_size(const terrad_rect *rects, size_t count)
{
    size_t n = TERRAD_DELTA_FIXED;
    for (size_t i = 0; i < count; i++)
        n += TERRAD_RECT_FIXED + rects[i].data_len;
    return n;
}

int terrad_delta_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                        const terrad_rect *rects, size_t count)
{
    if (count > TERRAD_MAX_COUNT)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++)
        if (terrad_rect_check(&rects[i]) || !rects[i].data)
            return TERRAD_E_BAD_VALUE;
    size_t need = terrad_delta_size(rects, count);
    if (!buf || cap < need)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_DELTA);
    p = wr_u64(p, tick);
    p = wr_u16(p, (uint16_t)count);
    for (size_t i = 0; i < count; i++) {
        const terrad_rect *q = &rects[i];
        p = wr_u32(p, (uint32_t)q->x);
        p = wr_u32(p, (uint32_t)q->y);
        p = wr_u16(p, q->w);
        p = wr_u16(p, q->h);
        p = wr_u32(p, q->base_version);
        p = wr_u32(p, q->new_version);
        p = wr_u8(p, q->encoding);
        p = wr_u32(p, q->data_len);
        memcpy(p, q->data, q->data_len);
        p += q->data_len;
    }
    if (len_out)
        *len_out = need;
    return TERRAD_OK;
}

int terrad_delta_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, terrad_rect *rects,
                        size_t cap, size_t *count_out)
{
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_DELTA, &r);
    if (rc)
        return rc;
    if (rd_left(&r) < 10)
        return TERRAD_E_BAD_FRAME;
    uint64_t tick = rd_u64(&r);
    size_t count = rd_u16(&r);
    if (rd_left(&r) / TERRAD_RECT_FIXED < count)
        return TERRAD_E_BAD_FRAME;
    if (count > cap)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++) {
        terrad_rect q;
        if (rd_left(&r) < TERRAD_RECT_FIXED)
            return TERRAD_E_BAD_FRAME;
        q.x = (int32_t)rd_u32(&r);
        q.y = (int32_t)rd_u32(&r);
        q.w = rd_u16(&r);
        q.h = rd_u16(&r);
        q.base_version = rd_u32(&r);
        q.new_version = rd_u32(&r);
        q.encoding = rd_u8(&r);
        q.data_len = rd_u32(&r);
        if (rd_left(&r) < q.data_len)
            return TERRAD_E_BAD_FRAME;
        q.data = r.p + r.pos;
        r.pos += q.data_len;
        if (terrad_rect_check(&q))
            return TERRAD_E_BAD_VALUE;
        rects[i] = q;
    }
    if (rd_left(&r) != 0)
        return TERRAD_E_BAD_FRAME;
    if (tick_out)
        *tick_out = tick;
    if (count_out)
        *count_out = count;
    return TERRAD_OK;
}

/* ---- tick lists: CONTACT, COLLIDERS, FOOTPRINTS, FORCES -------------------
 * One outline: the header, the tick (u64), a count (u16), then count entries
 * of one fixed size. Each frame gives its entry's check (the values a codec
 * refuses as bad_value), its writer and its reader; encode checks every entry
 * before writing any byte, decode stores an entry only once it is checked.
 *
 * An extension a client asks for (FORCES' heights, COLLIDERS' grousers) is a
 * header flag and a fixed number of bytes after every entry of the flagged
 * frame: the frame's tick_ext says which flag, its size and how it is
 * checked (with its entry), written and read. */

typedef struct tick_ext {
    uint8_t flag;
    size_t size, elem_size; /* wire; memory */
    int (*check)(const void *entry, const void *ext);
    uint8_t *(*write)(uint8_t *p, const void *ext);
    int (*read)(rd *r, void *ext); /* TERRAD_OK, or the extension's error (a reserved field) */
} tick_ext;

typedef struct tick_list {
    uint8_t type;
    size_t fixed, entry_size, elem_size; /* wire: frame fixed part, entry; memory: entry */
    int (*check)(const void *e);
    uint8_t *(*write)(uint8_t *p, const void *e);
    int (*read)(rd *r, void *e); /* TERRAD_OK, or the entry's error (a reserved field) */
    const tick_ext *ext;         /* NULL: the frame has no extension */
} tick_list;

/* Any entry of a tick list, for decoding one before it is checked. */
typedef union tick_entry {
    terrad_contact contact;
    terrad_collider_state collider;
    terrad_footprint footprint;
    terrad_force force;
} tick_entry;

/* Any extension of an entry, likewise. */
typedef union tick_entry_ext {
    double height;
    terrad_collider_grousers grousers;
} tick_entry_ext;

/* exts: NULL, or (t->ext) one extension per entry written after it, with the
 * frame's extension flag set */
static int tick_list_encode(const tick_list *t, uint8_t *buf, size_t cap, size_t *len_out,
                            uint64_t tick, const void *entries, const void *exts, size_t count)
{
    const uint8_t *e = entries, *x = exts;
    const tick_ext *xt = exts ? t->ext : NULL;
    if (exts && !xt)
        return TERRAD_E_BAD_VALUE;
    if (count > TERRAD_MAX_COUNT)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++)
        if (t->check(e + i * t->elem_size) ||
            (xt && xt->check(e + i * t->elem_size, x + i * xt->elem_size)))
            return TERRAD_E_BAD_VALUE;
    size_t need = t->fixed + count * (t->entry_size + (xt ? xt->size : 0));
    if (!buf || cap < need)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, t->type);
    if (xt)
        buf[3] = xt->flag;
    p = wr_u64(p, tick);
    p = wr_u16(p, (uint16_t)count);
    for (size_t i = 0; i < count; i++) {
        p = t->write(p, e + i * t->elem_size);
        if (xt)
            p = xt->write(p, x + i * xt->elem_size);
    }
    if (len_out)
        *len_out = need;
    return TERRAD_OK;
}

/* exts: NULL, or where the extension after each entry goes when the frame's
 * flag is set (entries' memory may then be NULL); *has_ext, when given, says
 * whether it was set */
static int tick_list_decode(const tick_list *t, const uint8_t *buf, size_t len, uint64_t *tick_out,
                            void *entries, void *exts, int *has_ext, size_t cap, size_t *count_out)
{
    rd r;
    int rc = expect_header(buf, len, t->type, &r);
    if (rc)
        return rc;
    const tick_ext *xt = t->ext && (buf[3] & t->ext->flag) ? t->ext : NULL;
    size_t size = t->entry_size + (xt ? xt->size : 0);
    if (rd_left(&r) < 10)
        return TERRAD_E_BAD_FRAME;
    uint64_t tick = rd_u64(&r);
    size_t count = rd_u16(&r);
    if (rd_left(&r) != count * size)
        return TERRAD_E_BAD_FRAME;
    if (count > cap)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++) {
        tick_entry one;
        rc = t->read(&r, &one);
        if (rc || t->check(&one))
            return rc ? rc : TERRAD_E_BAD_VALUE;
        if (entries)
            memcpy((uint8_t *)entries + i * t->elem_size, &one, t->elem_size);
        if (xt) {
            tick_entry_ext more;
            rc = xt->read(&r, &more);
            if (rc || xt->check(&one, &more))
                return rc ? rc : TERRAD_E_BAD_VALUE;
            if (exts)
                memcpy((uint8_t *)exts + i * xt->elem_size, &more, xt->elem_size);
        }
    }
    if (has_ext)
        *has_ext = xt != NULL;
    if (tick_out)
        *tick_out = tick;
    if (count_out)
        *count_out = count;
    return TERRAD_OK;
}

static uint8_t *wr_f32s(uint8_t *p, const float *v, int n)
{
    for (int k = 0; k < n; k++)
        p = wr_f32(p, v[k]);
    return p;
}

static void rd_f32s(rd *r, float *v, int n)
{
    for (int k = 0; k < n; k++)
        v[k] = rd_f32(r);
}

/* CONTACT */

static int contact_check(const void *e)
{
    const terrad_contact *c = e;
    const float v[9] = {c->area_m2,    c->deepest[0],       c->deepest[1],
                        c->deepest[2], c->normal[0],        c->normal[1],
                        c->normal[2],  c->support_height_m, 0.0f};
    if (!finite_all(v, 8))
        return TERRAD_E_BAD_VALUE;
    if (c->volume < 0 || c->area_m2 < 0.0f)
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

static uint8_t *contact_write(uint8_t *p, const void *e)
{
    const terrad_contact *c = e;
    p = wr_u32(p, c->id);
    p = wr_u64(p, (uint64_t)c->volume);
    p = wr_u32(p, c->cells);
    p = wr_f32(p, c->area_m2);
    p = wr_f32s(p, c->deepest, 3);
    p = wr_f32s(p, c->normal, 3);
    return wr_f32(p, c->support_height_m);
}

static int contact_read(rd *r, void *e)
{
    terrad_contact *c = e;
    c->id = rd_u32(r);
    c->volume = (int64_t)rd_u64(r);
    c->cells = rd_u32(r);
    c->area_m2 = rd_f32(r);
    rd_f32s(r, c->deepest, 3);
    rd_f32s(r, c->normal, 3);
    c->support_height_m = rd_f32(r);
    return TERRAD_OK;
}

static const tick_list contact_list = {
    TERRAD_MSG_CONTACT, TERRAD_CONTACT_FIXED, TERRAD_CONTACT_SIZE, sizeof(terrad_contact),
    contact_check,      contact_write,        contact_read,        NULL};

size_t terrad_contact_size(size_t count)
{
    return TERRAD_CONTACT_FIXED + count * TERRAD_CONTACT_SIZE;
}

int terrad_contact_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                          const terrad_contact *contacts, size_t count)
{
    return tick_list_encode(&contact_list, buf, cap, len_out, tick, contacts, NULL, count);
}

int terrad_contact_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                          terrad_contact *contacts, size_t cap, size_t *count_out)
{
    return tick_list_decode(&contact_list, buf, len, tick_out, contacts, NULL, NULL, cap,
                            count_out);
}

/* COLLIDERS */

static int collider_state_check(const void *e)
{
    const terrad_collider_state *c = e;
    const float v[10] = {c->dims[0], c->dims[1], c->dims[2], c->p[0], c->p[1],
                         c->p[2],    c->q[0],    c->q[1],    c->q[2], c->q[3]};
    if (!finite_all(v, 10))
        return TERRAD_E_BAD_VALUE;
    if (c->owner > TERRAD_OWNER_DEMO || c->kind > TERRAD_KIND_LAST)
        return TERRAD_E_BAD_VALUE;
    if (c->dims[0] < 0.0f || c->dims[1] < 0.0f || c->dims[2] < 0.0f)
        return TERRAD_E_BAD_VALUE;
    double n = 0;
    for (int k = 0; k < 4; k++)
        n += (double)c->q[k] * (double)c->q[k];
    if (n < 0.81 || n > 1.21)
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

static uint8_t *collider_state_write(uint8_t *p, const void *e)
{
    const terrad_collider_state *c = e;
    p = wr_u32(p, c->id);
    p = wr_u8(p, c->owner);
    p = wr_u8(p, c->kind);
    p = wr_u16(p, 0);
    p = wr_f32s(p, c->dims, 3);
    p = wr_f32s(p, c->p, 3);
    return wr_f32s(p, c->q, 4);
}

static int collider_state_read(rd *r, void *e)
{
    terrad_collider_state *c = e;
    c->id = rd_u32(r);
    c->owner = rd_u8(r);
    c->kind = rd_u8(r);
    if (rd_u16(r) != 0) /* reserved */
        return TERRAD_E_BAD_VALUE;
    rd_f32s(r, c->dims, 3);
    rd_f32s(r, c->p, 3);
    rd_f32s(r, c->q, 4);
    return TERRAD_OK;
}

/* The grousers extension of an entry: none (count 0, all zero), or lugs on a
 * cylinder's rim, each height and thickness > 0 and at most its radius (as
 * collider_create refuses otherwise; f32 rounding keeps the order). */
static int collider_grousers_check(const void *entry, const void *ext)
{
    const terrad_collider_state *c = entry;
    const terrad_collider_grousers *g = ext;
    if (g->count == 0)
        return g->height_m == 0.0f && g->thickness_m == 0.0f ? TERRAD_OK : TERRAD_E_BAD_VALUE;
    if (g->count > TERRAD_GROUSERS_MAX || c->kind != TERRAD_KIND_CYLINDER)
        return TERRAD_E_BAD_VALUE;
    if (!(g->height_m > 0.0f && g->height_m <= c->dims[0]) ||
        !(g->thickness_m > 0.0f && g->thickness_m <= c->dims[0]))
        return TERRAD_E_BAD_VALUE; /* NaN fails both */
    return TERRAD_OK;
}

static uint8_t *collider_grousers_write(uint8_t *p, const void *ext)
{
    const terrad_collider_grousers *g = ext;
    p = wr_u16(p, g->count);
    p = wr_u16(p, 0);
    p = wr_f32(p, g->height_m);
    return wr_f32(p, g->thickness_m);
}

static int collider_grousers_read(rd *r, void *ext)
{
    terrad_collider_grousers *g = ext;
    g->count = rd_u16(r);
    if (rd_u16(r) != 0) /* reserved */
        return TERRAD_E_BAD_VALUE;
    g->height_m = rd_f32(r);
    g->thickness_m = rd_f32(r);
    return TERRAD_OK;
}

static const tick_ext colliders_grousers_ext = {
    TERRAD_COLLIDERS_FLAG_GROUSERS, TERRAD_COLLIDER_GROUSERS_SIZE, sizeof(terrad_collider_grousers),
    collider_grousers_check,        collider_grousers_write,       collider_grousers_read};

static const tick_list colliders_list = {TERRAD_MSG_COLLIDERS,       TERRAD_COLLIDERS_FIXED,
                                         TERRAD_COLLIDER_STATE_SIZE, sizeof(terrad_collider_state),
                                         collider_state_check,       collider_state_write,
                                         collider_state_read,        &colliders_grousers_ext};

size_t terrad_colliders_size(size_t count)
{
    return TERRAD_COLLIDERS_FIXED + count * TERRAD_COLLIDER_STATE_SIZE;
}

int terrad_colliders_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                            const terrad_collider_state *states, size_t count)
{
    return tick_list_encode(&colliders_list, buf, cap, len_out, tick, states, NULL, count);
}

int terrad_colliders_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                            terrad_collider_state *states, size_t cap, size_t *count_out)
{
    return tick_list_decode(&colliders_list, buf, len, tick_out, states, NULL, NULL, cap,
                            count_out);
}

size_t terrad_colliders_grousers_size(size_t count)
{
    return TERRAD_COLLIDERS_FIXED +
           count * (TERRAD_COLLIDER_STATE_SIZE + TERRAD_COLLIDER_GROUSERS_SIZE);
}

int terrad_colliders_encode_grousers(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                                     const terrad_collider_state *states,
                                     const terrad_collider_grousers *grousers, size_t count)
{
    if (!grousers && count > 0)
        return TERRAD_E_BAD_VALUE;
    static const terrad_collider_grousers none; /* a frame of no entries still carries the flag */
    return tick_list_encode(&colliders_list, buf, cap, len_out, tick, states,
                            grousers ? grousers : &none, count);
}

int terrad_colliders_grousers(const uint8_t *buf, size_t len, terrad_collider_grousers *grousers,
                              size_t cap, size_t *count_out)
{
    int flagged = 0;
    size_t count = 0;
    int rc =
        tick_list_decode(&colliders_list, buf, len, NULL, NULL, grousers, &flagged, cap, &count);
    if (rc)
        return rc;
    if (count_out)
        *count_out = flagged ? count : 0;
    return TERRAD_OK;
}

/* FOOTPRINTS */

static int footprint_check(const void *e)
{
    const terrad_footprint *f = e;
    const float v[5] = {f->x, f->y, f->yaw, f->size_m, f->strength_m};
    if (!finite_all(v, 5))
        return TERRAD_E_BAD_VALUE;
    if (f->yaw < -TERRAD_FOOTPRINT_YAW_MAX || f->yaw > TERRAD_FOOTPRINT_YAW_MAX)
        return TERRAD_E_BAD_VALUE;
    /* an event is a press into the ground: no area or no depth is no event */
    if (!(f->size_m > 0.0f) || !(f->strength_m > 0.0f))
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

static uint8_t *footprint_write(uint8_t *p, const void *e)
{
    const terrad_footprint *f = e;
    p = wr_u32(p, f->collider);
    p = wr_f32(p, f->x);
    p = wr_f32(p, f->y);
    p = wr_f32(p, f->yaw);
    p = wr_f32(p, f->size_m);
    return wr_f32(p, f->strength_m);
}

static int footprint_read(rd *r, void *e)
{
    terrad_footprint *f = e;
    f->collider = rd_u32(r);
    f->x = rd_f32(r);
    f->y = rd_f32(r);
    f->yaw = rd_f32(r);
    f->size_m = rd_f32(r);
    f->strength_m = rd_f32(r);
    return TERRAD_OK;
}

static const tick_list footprints_list = {
    TERRAD_MSG_FOOTPRINTS, TERRAD_FOOTPRINTS_FIXED, TERRAD_FOOTPRINT_SIZE, sizeof(terrad_footprint),
    footprint_check,       footprint_write,         footprint_read,        NULL};

size_t terrad_footprints_size(size_t count)
{
    return TERRAD_FOOTPRINTS_FIXED + count * TERRAD_FOOTPRINT_SIZE;
}

int terrad_footprints_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                             const terrad_footprint *events, size_t count)
{
    return tick_list_encode(&footprints_list, buf, cap, len_out, tick, events, NULL, count);
}

int terrad_footprints_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                             terrad_footprint *events, size_t cap, size_t *count_out)
{
    return tick_list_decode(&footprints_list, buf, len, tick_out, events, NULL, NULL, cap,
                            count_out);
}

/* FORCES */

static int force_check(const void *e)
{
    const terrad_force *f = e;
    const float v[10] = {f->force[0],  f->force[1],  f->force[2], f->torque[0],     f->torque[1],
                         f->torque[2], f->sinkage_m, f->area_m2,  f->patch_width_m, f->slip};
    if (!finite_all(v, 10))
        return TERRAD_E_BAD_VALUE;
    if (f->sinkage_m < 0.0f || f->area_m2 < 0.0f || f->patch_width_m < 0.0f)
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

static uint8_t *force_write(uint8_t *p, const void *e)
{
    const terrad_force *f = e;
    p = wr_u32(p, f->id);
    p = wr_f32s(p, f->force, 3);
    p = wr_f32s(p, f->torque, 3);
    p = wr_f32(p, f->sinkage_m);
    p = wr_f32(p, f->area_m2);
    p = wr_f32(p, f->patch_width_m);
    p = wr_f32(p, f->slip);
    return wr_u32(p, f->cells);
}

static int force_read(rd *r, void *e)
{
    terrad_force *f = e;
    f->id = rd_u32(r);
    rd_f32s(r, f->force, 3);
    rd_f32s(r, f->torque, 3);
    f->sinkage_m = rd_f32(r);
    f->area_m2 = rd_f32(r);
    f->patch_width_m = rd_f32(r);
    f->slip = rd_f32(r);
    f->cells = rd_u32(r);
    return TERRAD_OK;
}

/* The height extension: one f64 (m), finite. */
static int force_height_check(const void *entry, const void *ext)
{
    (void)entry;
    return isfinite(*(const double *)ext) ? TERRAD_OK : TERRAD_E_BAD_VALUE;
}

static uint8_t *force_height_write(uint8_t *p, const void *ext)
{
    return wr_f64(p, *(const double *)ext);
}

static int force_height_read(rd *r, void *ext)
{
    *(double *)ext = rd_f64(r);
    return TERRAD_OK;
}

static const tick_ext forces_height_ext = {
    TERRAD_FORCES_FLAG_HEIGHT, TERRAD_FORCE_HEIGHT_SIZE, sizeof(double),
    force_height_check,        force_height_write,       force_height_read};

static const tick_list forces_list = {TERRAD_MSG_FORCES,    TERRAD_FORCES_FIXED, TERRAD_FORCE_SIZE,
                                      sizeof(terrad_force), force_check,         force_write,
                                      force_read,           &forces_height_ext};

size_t terrad_forces_size(size_t count)
{
    return TERRAD_FORCES_FIXED + count * TERRAD_FORCE_SIZE;
}

int terrad_forces_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                         const terrad_force *forces, size_t count)
{
    return tick_list_encode(&forces_list, buf, cap, len_out, tick, forces, NULL, count);
}

size_t terrad_forces_heights_size(size_t count)
{
    return TERRAD_FORCES_FIXED + count * (TERRAD_FORCE_SIZE + TERRAD_FORCE_HEIGHT_SIZE);
}

int terrad_forces_encode_heights(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                                 const terrad_force *forces, const double *heights_m, size_t count)
{
    if (!heights_m && count > 0)
        return TERRAD_E_BAD_VALUE;
    static const double none = 0.0; /* a frame of no entries still carries the flag */
    return tick_list_encode(&forces_list, buf, cap, len_out, tick, forces,
                            heights_m ? heights_m : &none, count);
}

int terrad_forces_heights(const uint8_t *buf, size_t len, double *heights_m, size_t cap,
                          size_t *count_out)
{
    int flagged = 0;
    size_t count = 0;
    int rc = tick_list_decode(&forces_list, buf, len, NULL, NULL, heights_m, &flagged, cap, &count);
    if (rc)
        return rc;
    if (count_out)
        *count_out = flagged ? count : 0;
    return TERRAD_OK;
}

int terrad_forces_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, terrad_force *forces,
                         size_t cap, size_t *count_out)
{
    return tick_list_decode(&forces_list, buf, len, tick_out, forces, NULL, NULL, cap, count_out);
}

/* ---- STEP and STEPPED ----------------------------------------------------- */

size_t terrad_step_size(size_t count, size_t sets)
{
    return TERRAD_STEP_FIXED + count * sets * TERRAD_POSE_SIZE;
}

static int step_head_check(const terrad_step_head *h)
{
    if (h->ticks == 0 || (h->sets > 1 && h->sets != h->ticks))
        return TERRAD_E_BAD_VALUE;
    return TERRAD_OK;
}

int terrad_step_encode(uint8_t *buf, size_t cap, size_t *len_out, const terrad_step_head *h,
                       const terrad_pose *poses)
{
    if (step_head_check(h))
        return TERRAD_E_BAD_VALUE;
    size_t n = (size_t)h->count * h->sets;
    for (size_t i = 0; i < n; i++)
        if (pose_check(&poses[i]))
            return TERRAD_E_BAD_VALUE;
    size_t need = terrad_step_size(h->count, h->sets);
    if (!buf || cap < need)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_STEP);
    p = wr_u32(p, h->seq);
    p = wr_u32(p, h->ticks);
    p = wr_u16(p, h->count);
    p = wr_u16(p, h->sets);
    for (size_t i = 0; i < n; i++)
        p = wr_pose(p, &poses[i]);
    if (len_out)
        *len_out = need;
    return TERRAD_OK;
}

int terrad_step_decode(const uint8_t *buf, size_t len, terrad_step_head *head_out,
                       terrad_pose *poses, size_t cap, long *bad_pose_out)
{
    if (bad_pose_out)
        *bad_pose_out = -1;
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_STEP, &r);
    if (rc)
        return rc;
    if (rd_left(&r) < TERRAD_STEP_FIXED - TERRAD_HEADER_SIZE)
        return TERRAD_E_BAD_FRAME;
    terrad_step_head h;
    h.seq = rd_u32(&r);
    h.ticks = rd_u32(&r);
    h.count = rd_u16(&r);
    h.sets = rd_u16(&r);
    size_t n = (size_t)h.count * h.sets;
    if (rd_left(&r) != n * TERRAD_POSE_SIZE)
        return TERRAD_E_BAD_FRAME;
    if (head_out)
        *head_out = h;
    if (step_head_check(&h))
        return TERRAD_E_BAD_VALUE;
    if (n > cap)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < n; i++) {
        terrad_pose q = rd_pose(&r);
        if (pose_check(&q)) {
            if (bad_pose_out)
                *bad_pose_out = (long)i;
            return TERRAD_E_BAD_VALUE;
        }
        poses[i] = q;
    }
    return TERRAD_OK;
}

int terrad_stepped_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick, uint32_t seq,
                          uint32_t ticks)
{
    if (ticks == 0)
        return TERRAD_E_BAD_VALUE;
    if (!buf || cap < TERRAD_STEPPED_SIZE)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_STEPPED);
    p = wr_u64(p, tick);
    p = wr_u32(p, seq);
    wr_u32(p, ticks);
    if (len_out)
        *len_out = TERRAD_STEPPED_SIZE;
    return TERRAD_OK;
}

int terrad_stepped_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, uint32_t *seq_out,
                          uint32_t *ticks_out)
{
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_STEPPED, &r);
    if (rc)
        return rc;
    if (len != TERRAD_STEPPED_SIZE)
        return TERRAD_E_BAD_FRAME;
    uint64_t tick = rd_u64(&r);
    uint32_t seq = rd_u32(&r);
    uint32_t ticks = rd_u32(&r);
    if (ticks == 0)
        return TERRAD_E_BAD_VALUE;
    if (tick_out)
        *tick_out = tick;
    if (seq_out)
        *seq_out = seq;
    if (ticks_out)
        *ticks_out = ticks;
    return TERRAD_OK;
}

/* ---- CHECKSUM -------------------------------------------------------------- */

uint64_t terrad_heights_hash(const int32_t *heights, size_t stride, uint32_t w, uint32_t h)
{
    uint64_t x = TERRAD_HASH_SEED;
    for (uint32_t j = 0; j < h; j++) {
        const int32_t *row = heights + (size_t)j * stride;
        for (uint32_t i = 0; i < w; i++)
            x = (x ^ (uint32_t)row[i]) * TERRAD_HASH_PRIME;
    }
    return x;
}

size_t terrad_checksum_size(size_t count)
{
    return TERRAD_CHECKSUM_FIXED + count * TERRAD_TILE_SUM_SIZE;
}

static int tile_sum_check(const terrad_tile_sum *s)
{
    return s->tile_x < 0 || s->tile_y < 0 || s->version == 0 ? TERRAD_E_BAD_VALUE : TERRAD_OK;
}

int terrad_checksum_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                           uint32_t subscription, const terrad_tile_sum *sums, size_t count)
{
    if (count > TERRAD_MAX_COUNT || subscription == 0)
        return TERRAD_E_BAD_VALUE;
    for (size_t i = 0; i < count; i++)
        if (tile_sum_check(&sums[i]))
            return TERRAD_E_BAD_VALUE;
    size_t need = terrad_checksum_size(count);
    if (!buf || cap < need)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_CHECKSUM);
    p = wr_u64(p, tick);
    p = wr_u32(p, subscription);
    p = wr_u16(p, (uint16_t)count);
    for (size_t i = 0; i < count; i++) {
        p = wr_u32(p, (uint32_t)sums[i].tile_x);
        p = wr_u32(p, (uint32_t)sums[i].tile_y);
        p = wr_u32(p, sums[i].version);
        p = wr_u64(p, sums[i].hash);
    }
    if (len_out)
        *len_out = need;
    return TERRAD_OK;
}

int terrad_checksum_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                           uint32_t *subscription_out, terrad_tile_sum *sums, size_t cap,
                           size_t *count_out)
{
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_CHECKSUM, &r);
    if (rc)
        return rc;
    if (rd_left(&r) < TERRAD_CHECKSUM_FIXED - TERRAD_HEADER_SIZE)
        return TERRAD_E_BAD_FRAME;
    uint64_t tick = rd_u64(&r);
    uint32_t subscription = rd_u32(&r);
    size_t count = rd_u16(&r);
    if (rd_left(&r) != count * TERRAD_TILE_SUM_SIZE)
        return TERRAD_E_BAD_FRAME;
    if (subscription == 0)
        return TERRAD_E_BAD_VALUE;
    if (count > cap)
        return TERRAD_E_TOO_LARGE;
    for (size_t i = 0; i < count; i++) {
        terrad_tile_sum s;
        s.tile_x = (int32_t)rd_u32(&r);
        s.tile_y = (int32_t)rd_u32(&r);
        s.version = rd_u32(&r);
        s.hash = rd_u64(&r);
        if (tile_sum_check(&s))
            return TERRAD_E_BAD_VALUE;
        sums[i] = s;
    }
    if (tick_out)
        *tick_out = tick;
    if (subscription_out)
        *subscription_out = subscription;
    if (count_out)
        *count_out = count;
    return TERRAD_OK;
}

/* ---- ACK, PING, PONG ----------------------------------------------------- */

int terrad_ack_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick, uint32_t seq)
{
    if (!buf || cap < TERRAD_ACK_SIZE)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, TERRAD_MSG_ACK);
    p = wr_u64(p, tick);
    wr_u32(p, seq);
    if (len_out)
        *len_out = TERRAD_ACK_SIZE;
    return TERRAD_OK;
}

int terrad_ack_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, uint32_t *seq_out)
{
    rd r;
    int rc = expect_header(buf, len, TERRAD_MSG_ACK, &r);
    if (rc)
        return rc;
    if (len != TERRAD_ACK_SIZE)
        return TERRAD_E_BAD_FRAME;
    uint64_t tick = rd_u64(&r);
    uint32_t seq = rd_u32(&r);
    if (tick_out)
        *tick_out = tick;
    if (seq_out)
        *seq_out = seq;
    return TERRAD_OK;
}

int terrad_ping_encode(uint8_t *buf, size_t cap, size_t *len_out, uint8_t type, uint64_t nonce)
{
    if (type != TERRAD_MSG_PING && type != TERRAD_MSG_PONG)
        return TERRAD_E_UNKNOWN_TYPE;
    if (!buf || cap < TERRAD_PING_SIZE)
        return TERRAD_E_BUFFER_TOO_SMALL;
    uint8_t *p = wr_header(buf, type);
    wr_u64(p, nonce);
    if (len_out)
        *len_out = TERRAD_PING_SIZE;
    return TERRAD_OK;
}

int terrad_ping_decode(const uint8_t *buf, size_t len, uint8_t *type_out, uint64_t *nonce_out)
{
    terrad_header h;
    int rc = terrad_header_decode(buf, len, &h);
    if (rc)
        return rc;
    if (h.type != TERRAD_MSG_PING && h.type != TERRAD_MSG_PONG)
        return TERRAD_E_UNKNOWN_TYPE;
    if (len != TERRAD_PING_SIZE)
        return TERRAD_E_BAD_FRAME;
    rd r = {buf, len, TERRAD_HEADER_SIZE};
    uint64_t nonce = rd_u64(&r);
    if (type_out)
        *type_out = h.type;
    if (nonce_out)
        *nonce_out = nonce;
    return TERRAD_OK;
}

/* ---- rectangle payloads -------------------------------------------------- */

uint32_t terrad_zigzag32(int32_t v)
{
    uint32_t u = (uint32_t)v;
    return (u << 1) ^ (0u - (u >> 31));
}

int32_t terrad_unzigzag32(uint32_t u)
{
    uint32_t v = (u >> 1) ^ (0u - (u & 1u));
    int32_t s;
    memcpy(&s, &v, sizeof s); /* two's complement reinterpretation, no UB */
    return s;
}

static int32_t wrap_i32(uint32_t u)
{
    int32_t s;
    memcpy(&s, &u, sizeof s);
    return s;
}

void terrad_rect_diff(const int32_t *old_h, const int32_t *new_h, size_t cells, int32_t *out)
{
    for (size_t i = 0; i < cells; i++)
        out[i] = wrap_i32((uint32_t)new_h[i] - (uint32_t)old_h[i]);
}

void terrad_rect_pack(const int32_t *values, size_t cells, uint8_t *out)
{
    for (size_t i = 0; i < cells; i++)
        wr_u32(out + 4 * i, terrad_zigzag32(values[i]));
}

void terrad_rect_unpack(const uint8_t *in, size_t cells, int32_t *out)
{
    /* in may alias out: each 4-byte group is read before it is written. */
    for (size_t i = 0; i < cells; i++) {
        const uint8_t *p = in + 4 * i;
        uint32_t u = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
                     ((uint32_t)p[3] << 24);
        out[i] = terrad_unzigzag32(u);
    }
}

struct terrad_codec {
    int level;
    ZSTD_CCtx *cctx;
    ZSTD_DCtx *dctx;
    uint8_t *scratch; /* packing buffer for compression */
    size_t scratch_cap;
};

terrad_codec *terrad_codec_new(int level)
{
    terrad_codec *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->level = level > 0 ? level : 3;
    c->cctx = ZSTD_createCCtx();
    c->dctx = ZSTD_createDCtx();
    if (!c->cctx || !c->dctx) {
        terrad_codec_free(c);
        return NULL;
    }
    return c;
}

void terrad_codec_free(terrad_codec *c)
{
    if (!c)
        return;
    ZSTD_freeCCtx(c->cctx);
    ZSTD_freeDCtx(c->dctx);
    free(c->scratch);
    free(c);
}

size_t terrad_rect_compress_bound(size_t cells)
{
    if (cells > SIZE_MAX / 8)
        return 0;
    return ZSTD_compressBound(cells * 4);
}

int terrad_rect_compress(terrad_codec *c, const int32_t *values, size_t cells, uint8_t *out,
                         size_t cap, size_t *len_out)
{
    if (cells == 0 || cells > SIZE_MAX / 8)
        return TERRAD_E_TOO_LARGE;
    terrad_codec *own = NULL;
    if (!c) {
        own = c = terrad_codec_new(3);
        if (!c)
            return TERRAD_E_NO_MEMORY;
    }
    int rc = TERRAD_OK;
    size_t raw = cells * 4;
    if (c->scratch_cap < raw) {
        uint8_t *p = realloc(c->scratch, raw);
        if (!p) {
            rc = TERRAD_E_NO_MEMORY;
            goto done;
        }
        c->scratch = p;
        c->scratch_cap = raw;
    }
    terrad_rect_pack(values, cells, c->scratch);
    /* ZSTD_compressCCtx writes the content size into the frame header. */
    size_t n = ZSTD_compressCCtx(c->cctx, out, cap, c->scratch, raw, c->level);
    if (ZSTD_isError(n)) {
        rc = ZSTD_getErrorCode(n) == ZSTD_error_dstSize_tooSmall ? TERRAD_E_BUFFER_TOO_SMALL
                                                                 : TERRAD_E_INTERNAL;
        goto done;
    }
    if (len_out)
        *len_out = n;
done:
    terrad_codec_free(own);
    return rc;
}

int terrad_rect_decompress(terrad_codec *c, const uint8_t *data, size_t len, size_t cells,
                           int32_t *out, size_t out_cap)
{
    if (cells == 0 || cells > out_cap || cells > SIZE_MAX / 8)
        return TERRAD_E_TOO_LARGE;
    size_t raw = cells * 4;
    if (!data || len == 0)
        return TERRAD_E_BAD_COMPRESSION;
    /* Exactly one frame, nothing after it. */
    size_t frame = ZSTD_findFrameCompressedSize(data, len);
    if (ZSTD_isError(frame) || frame != len)
        return TERRAD_E_BAD_COMPRESSION;
    unsigned long long declared = ZSTD_getFrameContentSize(data, len);
    if (declared == ZSTD_CONTENTSIZE_UNKNOWN || declared == ZSTD_CONTENTSIZE_ERROR ||
        declared != (unsigned long long)raw)
        return TERRAD_E_BAD_COMPRESSION;
    terrad_codec *own = NULL;
    if (!c) {
        own = c = terrad_codec_new(3);
        if (!c)
            return TERRAD_E_NO_MEMORY;
    }
    int rc = TERRAD_OK;
    size_t n = ZSTD_decompressDCtx(c->dctx, out, raw, data, len);
    if (ZSTD_isError(n) || n != raw)
        rc = TERRAD_E_BAD_COMPRESSION;
    else
        terrad_rect_unpack((const uint8_t *)out, cells, out);
    terrad_codec_free(own);
    return rc;
}

/* Intersection of two rectangles in int64; 0 when empty. */
typedef struct box {
    int64_t x0, y0, x1, y1; /* half-open */
} box;

static int box_meet(box a, box b, box *out)
{
    out->x0 = a.x0 > b.x0 ? a.x0 : b.x0;
    out->y0 = a.y0 > b.y0 ? a.y0 : b.y0;
    out->x1 = a.x1 < b.x1 ? a.x1 : b.x1;
    out->y1 = a.y1 < b.y1 ? a.y1 : b.y1;
    return out->x0 < out->x1 && out->y0 < out->y1;
}

static box rect_box(const terrad_rect *r)
{
    box b = {r->x, r->y, (int64_t)r->x + r->w, (int64_t)r->y + r->h};
    return b;
}

size_t terrad_rect_apply_values(const terrad_rect *r, const int32_t *values, int32_t *heights,
                                int32_t hx, int32_t hy, uint32_t hw, uint32_t hh)
{
    box region = {hx, hy, (int64_t)hx + hw, (int64_t)hy + hh}, m;
    if (!box_meet(rect_box(r), region, &m))
        return 0;
    size_t touched = 0;
    for (int64_t y = m.y0; y < m.y1; y++) {
        const int32_t *src = values + (size_t)(y - r->y) * r->w + (size_t)(m.x0 - r->x);
        int32_t *dst = heights + (size_t)(y - hy) * hw + (size_t)(m.x0 - hx);
        size_t n = (size_t)(m.x1 - m.x0);
        if (r->encoding == TERRAD_ENC_SNAPSHOT) {
            memcpy(dst, src, n * sizeof *dst);
        } else {
            for (size_t i = 0; i < n; i++)
                dst[i] = wrap_i32((uint32_t)dst[i] + (uint32_t)src[i]);
        }
        touched += n;
    }
    return touched;
}

/* ---- client-side mirror -------------------------------------------------- */

static int64_t floor_div(int64_t a, int64_t b)
{
    int64_t q = a / b;
    if ((a % b != 0) && ((a < 0) != (b < 0)))
        q--;
    return q;
}

size_t terrad_mirror_tile_count(int32_t x, int32_t y, uint32_t w, uint32_t h, uint32_t tile_size)
{
    if (w == 0 || h == 0 || tile_size == 0)
        return 0;
    int64_t tx = floor_div((int64_t)x + w - 1, tile_size) - floor_div(x, tile_size) + 1;
    int64_t ty = floor_div((int64_t)y + h - 1, tile_size) - floor_div(y, tile_size) + 1;
    return (size_t)tx * (size_t)ty;
}

int terrad_mirror_init(terrad_mirror *m, int32_t x, int32_t y, uint32_t w, uint32_t h,
                       uint32_t tile_size, int32_t *heights, uint32_t *versions)
{
    size_t tiles = terrad_mirror_tile_count(x, y, w, h, tile_size);
    if (tiles == 0 || !heights || !versions || (int64_t)x + w - 1 > INT32_MAX ||
        (int64_t)y + h - 1 > INT32_MAX)
        return TERRAD_E_BAD_VALUE;
    memset(m, 0, sizeof *m);
    m->x = x;
    m->y = y;
    m->w = w;
    m->h = h;
    m->tile_size = tile_size;
    m->heights = heights;
    m->versions = versions;
    m->tx0 = floor_div(x, tile_size);
    m->ty0 = floor_div(y, tile_size);
    m->tiles_x = (uint32_t)(floor_div((int64_t)x + w - 1, tile_size) - m->tx0 + 1);
    m->tiles_y = (uint32_t)(floor_div((int64_t)y + h - 1, tile_size) - m->ty0 + 1);
    memset(versions, 0, tiles * sizeof *versions);
    return TERRAD_OK;
}

/* What one rectangle means for the mirror: skip it, or apply it to tile t. */
enum { RECT_SKIP, RECT_APPLY };

static int mirror_classify(const terrad_mirror *m, const terrad_rect *r, size_t *tile_out)
{
    int64_t T = m->tile_size;
    int64_t tx = floor_div(r->x, T), ty = floor_div(r->y, T);
    if (floor_div((int64_t)r->x + r->w - 1, T) != tx ||
        floor_div((int64_t)r->y + r->h - 1, T) != ty)
        return -TERRAD_E_BAD_VALUE; /* spans tiles */
    /* Rectangles of a tile the region does not touch are not ours. */
    if (tx < m->tx0 || ty < m->ty0 || tx >= m->tx0 + m->tiles_x || ty >= m->ty0 + m->tiles_y)
        return RECT_SKIP;
    size_t t = (size_t)(tx - m->tx0) + (size_t)(ty - m->ty0) * m->tiles_x;
    *tile_out = t;
    if (r->encoding != TERRAD_ENC_DELTA) { /* a snapshot, absolute or against the base */
        box region = {m->x, m->y, (int64_t)m->x + m->w, (int64_t)m->y + m->h};
        box tile = {tx * T, ty * T, tx * T + T, ty * T + T}, part, tpart;
        box_meet(tile, region, &tpart);
        if (!box_meet(rect_box(r), region, &part) || part.x0 != tpart.x0 || part.y0 != tpart.y0 ||
            part.x1 != tpart.x1 || part.y1 != tpart.y1)
            return RECT_SKIP; /* covers only some of what the mirror holds of the tile */
        return RECT_APPLY;
    }
    /* A delta rectangle of a held tile advances its version even when none
     * of its cells lie in the region. */
    uint32_t held = m->versions[t];
    if (held == 0)
        return RECT_SKIP; /* no snapshot yet */
    if (held != r->base_version)
        return -TERRAD_E_STALE_BASE;
    return RECT_APPLY;
}

int terrad_mirror_apply(terrad_mirror *m, terrad_codec *c, const terrad_rect *rects, size_t count,
                        int32_t *scratch, size_t scratch_cells)
{
    size_t t;
    for (size_t i = 0; i < count; i++) {
        int k = mirror_classify(m, &rects[i], &t);
        if (k < 0)
            return -k;
        if (k == RECT_APPLY && (size_t)rects[i].w * rects[i].h > scratch_cells)
            return TERRAD_E_TOO_LARGE;
    }
    terrad_codec *own = NULL;
    if (!c) {
        own = c = terrad_codec_new(3);
        if (!c)
            return TERRAD_E_NO_MEMORY;
    }
    int rc = TERRAD_OK;
    for (size_t i = 0; i < count; i++) {
        const terrad_rect *r = &rects[i];
        /* Classified against the versions before this frame: a tile's
         * rectangles in one frame share base and new version. */
        if (r->encoding == TERRAD_ENC_DELTA) {
            int k = mirror_classify(m, r, &t);
            if (k == RECT_SKIP)
                continue;
            if (k < 0 && m->versions[t] != r->new_version) {
                rc = -k;
                break;
            }
        } else if (mirror_classify(m, r, &t) != RECT_APPLY) {
            continue;
        }
        if (r->encoding == TERRAD_ENC_BASE || r->encoding == TERRAD_ENC_BASE_SLOPE) {
            /* the client asked for them: it has the base */
            rc = !m->base ? TERRAD_E_BAD_VALUE
                 : r->encoding == TERRAD_ENC_BASE
                     ? terrad_rect_decompress_base(r->data, r->data_len, r->w, r->h, scratch,
                                                   scratch_cells)
                     : terrad_rect_decompress_slope(r->data, r->data_len, r->w, r->h, scratch,
                                                    scratch_cells);
            if (rc)
                break;
            terrad_rect_apply_base(r, scratch, m->base, m->heights, m->x, m->y, m->w, m->h);
            m->versions[t] = r->new_version;
            continue;
        }
        rc = terrad_rect_decompress(c, r->data, r->data_len, (size_t)r->w * r->h, scratch,
                                    scratch_cells);
        if (rc)
            break;
        terrad_rect_apply_values(r, scratch, m->heights, m->x, m->y, m->w, m->h);
        m->versions[t] = r->new_version;
    }
    if (rc)
        memset(m->versions, 0, (size_t)m->tiles_x * m->tiles_y * sizeof *m->versions);
    terrad_codec_free(own);
    return rc;
}

int terrad_mirror_tile_differs(const terrad_mirror *m, const terrad_tile_sum *sum)
{
    int64_t T = m->tile_size;
    if (sum->tile_x < m->tx0 || sum->tile_y < m->ty0 || sum->tile_x >= m->tx0 + m->tiles_x ||
        sum->tile_y >= m->ty0 + m->tiles_y)
        return -1;
    size_t t = (size_t)(sum->tile_x - m->tx0) + (size_t)(sum->tile_y - m->ty0) * m->tiles_x;
    if (m->versions[t] == 0)
        return 0;
    if (m->versions[t] != sum->version)
        return 1;
    box region = {m->x, m->y, (int64_t)m->x + m->w, (int64_t)m->y + m->h}, part;
    box tile = {sum->tile_x * T, sum->tile_y * T, sum->tile_x * T + T, sum->tile_y * T + T};
    box_meet(tile, region, &part);
    const int32_t *first = m->heights + (size_t)(part.y0 - m->y) * m->w + (size_t)(part.x0 - m->x);
    uint64_t h = terrad_heights_hash(first, m->w, (uint32_t)(part.x1 - part.x0),
                                     (uint32_t)(part.y1 - part.y0));
    return h != sum->hash;
}
