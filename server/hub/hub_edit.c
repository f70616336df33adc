/*
 * hub_edit.c: a terrain edit's wire form (PROTOCOL.md "edit": the websocket's
 * `edit` message, and POST /v1/worlds/{name}/edits' body, the same object)
 * checked and parsed into a world_edit, for both its senders (net/, http/),
 * which then hand it to the hub (hub_edit_submit). Every refusal names the
 * field, with the protocol's error code (TERRAD_E_*); nothing here touches a
 * world. The sim thread applies the parsed edit (world_edit_apply,
 * world/world_edit.c) at the start of a tick.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hub/hub.h"
#include "terrad_proto.h"

static const char *const mode_names[] = {"set", "add", "min", "max"};

typedef struct edit_parser {
    const cJSON *msg;
    int width, height;
    int64_t max_cells;
    hub_edit_error *err;
} edit_parser;

static int refuse(edit_parser *p, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static int refuse(edit_parser *p, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(p->err->message, sizeof p->err->message, fmt, ap);
    va_end(ap);
    p->err->code = code;
    return -1;
}

/* 1 found, 0 absent and optional, -1 refused: an integer in [lo, hi]. */
static int edit_int(edit_parser *p, const char *name, int required, int64_t lo, int64_t hi,
                    int64_t *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(p->msg, name);
    if (!v && !required)
        return 0;
    if (!v || !cJSON_IsNumber(v) || !isfinite(v->valuedouble) ||
        floor(v->valuedouble) != v->valuedouble || v->valuedouble < (double)lo ||
        v->valuedouble > (double)hi)
        return refuse(p, TERRAD_E_BAD_VALUE, "%s: %s an integer in [%lld, %lld]", name,
                      v ? "must be" : "missing,", (long long)lo, (long long)hi);
    *out = (int64_t)v->valuedouble;
    return 1;
}

/* x, y, w, h: a rectangle inside the world, at most max_cells. */
static int edit_rect(edit_parser *p, world_rect *r)
{
    int64_t x, y, w, h;
    if (edit_int(p, "x", 1, 0, INT32_MAX, &x) < 0 || edit_int(p, "y", 1, 0, INT32_MAX, &y) < 0 ||
        edit_int(p, "w", 1, 1, INT32_MAX, &w) < 0 || edit_int(p, "h", 1, 1, INT32_MAX, &h) < 0)
        return -1;
    if (x + w > p->width || y + h > p->height)
        return refuse(p, TERRAD_E_OUTSIDE_WORLD,
                      "x, y, w, h: the rectangle (%lld, %lld) %lld x %lld is not inside the "
                      "world (%d x %d cells)",
                      (long long)x, (long long)y, (long long)w, (long long)h, p->width, p->height);
    if (w * h > p->max_cells)
        return refuse(p, TERRAD_E_TOO_LARGE, "w, h: %lld cells, over max_edit_cells (%lld)",
                      (long long)(w * h), (long long)p->max_cells);
    *r = (world_rect){(int)x, (int)y, (int)w, (int)h};
    return 0;
}

static int parse_crater(edit_parser *p, world_edit *e)
{
    int64_t x, y, radius, depth;
    if (edit_int(p, "x", 1, INT32_MIN, INT32_MAX, &x) < 0 ||
        edit_int(p, "y", 1, INT32_MIN, INT32_MAX, &y) < 0)
        return -1;
    if (x < 0 || y < 0 || x >= p->width || y >= p->height)
        return refuse(p, TERRAD_E_OUTSIDE_WORLD,
                      "x, y: the centre (%lld, %lld) is not inside the world (%d x %d cells)",
                      (long long)x, (long long)y, p->width, p->height);
    if (edit_int(p, "radius", 1, 1, WORLD_EDIT_RADIUS_MAX, &radius) < 0 ||
        edit_int(p, "depth", 1, 1, WORLD_HEIGHT_MAX, &depth) < 0)
        return -1;
    const cJSON *rim = cJSON_GetObjectItemCaseSensitive(p->msg, "rim");
    if (rim && !cJSON_IsBool(rim))
        return refuse(p, TERRAD_E_BAD_VALUE, "rim: must be true or false");
    e->rim = rim ? cJSON_IsTrue(rim) : 1;
    e->cx = (int)x;
    e->cy = (int)y;
    e->radius = (int)radius;
    e->depth = depth;
    /* the square the crater (and its rim, out to twice the radius) can touch */
    int reach = e->rim ? 2 * e->radius : e->radius;
    world_rect r = {e->cx - reach, e->cy - reach, 2 * reach + 1, 2 * reach + 1};
    int x0 = r.x < 0 ? 0 : r.x, y0 = r.y < 0 ? 0 : r.y;
    int x1 = r.x + r.w > p->width ? p->width : r.x + r.w;
    int y1 = r.y + r.h > p->height ? p->height : r.y + r.h;
    e->rect = (world_rect){x0, y0, x1 - x0, y1 - y0};
    if ((int64_t)e->rect.w * e->rect.h > p->max_cells)
        return refuse(p, TERRAD_E_TOO_LARGE,
                      "radius: the crater%s covers %lld cells, over max_edit_cells (%lld)",
                      e->rim ? " and its rim" : "", (long long)e->rect.w * e->rect.h,
                      (long long)p->max_cells);
    return 0;
}

/* data (and mask): base64 of exactly `need` bytes. */
static int decode_bytes(edit_parser *p, const char *name, int required, size_t need, uint8_t **out,
                        size_t *got)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(p->msg, name);
    if (!v && !required)
        return 0;
    if (!cJSON_IsString(v))
        return refuse(p, TERRAD_E_BAD_VALUE, "%s: %s a base64 string", name,
                      v ? "must be" : "missing,");
    size_t len = strlen(v->valuestring);
    uint8_t *bytes = malloc(len * 3 / 4 + 4);
    if (!bytes)
        return refuse(p, TERRAD_E_INTERNAL, "%s: out of memory", name);
    int64_t n = base64_decode(v->valuestring, bytes);
    if (n < 0) {
        free(bytes);
        return refuse(p, TERRAD_E_BAD_VALUE, "%s: not base64", name);
    }
    if (need && (size_t)n != need) {
        free(bytes);
        return refuse(p, TERRAD_E_BAD_VALUE, "%s: %lld bytes, but w x h needs exactly %zu", name,
                      (long long)n, need);
    }
    *out = bytes;
    *got = (size_t)n;
    return 1;
}

/* The stamp's heights: int32 little-endian, or a 16-bit greyscale PNG of
 * w x h pixels mapped to units as offset + value * scale. */
static int stamp_values(edit_parser *p, world_edit *e)
{
    const cJSON *f = cJSON_GetObjectItemCaseSensitive(p->msg, "format");
    if (f && (!cJSON_IsString(f) ||
              (strcmp(f->valuestring, "int32") != 0 && strcmp(f->valuestring, "png16") != 0)))
        return refuse(p, TERRAD_E_BAD_VALUE, "format: must be \"int32\" or \"png16\"");
    size_t cells = (size_t)e->rect.w * e->rect.h, got = 0;
    uint8_t *bytes = NULL;
    int png = f && strcmp(f->valuestring, "png16") == 0;
    if (decode_bytes(p, "data", 1, png ? 0 : cells * 4, &bytes, &got) < 0)
        return -1;
    e->values = malloc(cells * sizeof *e->values);
    if (!e->values) {
        free(bytes);
        return refuse(p, TERRAD_E_INTERNAL, "data: out of memory");
    }
    if (!png) {
        for (size_t i = 0; i < cells; i++)
            e->values[i] =
                (int32_t)((uint32_t)bytes[4 * i] | (uint32_t)bytes[4 * i + 1] << 8 |
                          (uint32_t)bytes[4 * i + 2] << 16 | (uint32_t)bytes[4 * i + 3] << 24);
        free(bytes);
        return 0;
    }
    int64_t scale = 1, offset = 0;
    if (edit_int(p, "scale", 0, -16384, 16384, &scale) < 0 ||
        edit_int(p, "offset", 0, WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX, &offset) < 0) {
        free(bytes);
        return -1;
    }
    int pw = 0, ph = 0;
    uint16_t *pixels = NULL;
    error_text why = {{0}};
    int rc = png16_decode(bytes, got, "data", &pw, &ph, &pixels, &why);
    free(bytes);
    if (rc != 0)
        return refuse(p, TERRAD_E_BAD_VALUE, "%s", why.message);
    if (pw != e->rect.w || ph != e->rect.h) {
        free(pixels);
        return refuse(p, TERRAD_E_BAD_VALUE,
                      "data: the PNG is %d x %d pixels, but w x h is %d x %d", pw, ph, e->rect.w,
                      e->rect.h);
    }
    for (size_t i = 0; i < cells; i++) {
        int64_t v = offset + (int64_t)pixels[i] * scale;
        e->values[i] = (int32_t)(v < INT32_MIN ? INT32_MIN : v > INT32_MAX ? INT32_MAX : v);
    }
    free(pixels);
    return 0;
}

static int parse_stamp(edit_parser *p, world_edit *e)
{
    if (edit_rect(p, &e->rect) < 0)
        return -1;
    const cJSON *m = cJSON_GetObjectItemCaseSensitive(p->msg, "mode");
    e->mode = WORLD_STAMP_SET;
    if (m) {
        int found = -1;
        for (int i = 0; cJSON_IsString(m) && i < 4; i++)
            if (strcmp(m->valuestring, mode_names[i]) == 0)
                found = i;
        if (found < 0)
            return refuse(p, TERRAD_E_BAD_VALUE, "mode: must be set, add, min or max");
        e->mode = (world_stamp_mode)found;
    }
    if (stamp_values(p, e) < 0)
        return -1;
    size_t got = 0;
    return decode_bytes(p, "mask", 0, (size_t)e->rect.w * e->rect.h, &e->mask, &got) < 0 ? -1 : 0;
}

static int parse_reset(edit_parser *p, world_edit *e)
{
    int any = 0;
    static const char *const keys[] = {"x", "y", "w", "h"};
    for (int i = 0; i < 4; i++)
        any |= cJSON_GetObjectItemCaseSensitive(p->msg, keys[i]) != NULL;
    if (any)
        return edit_rect(p, &e->rect);
    e->rect = (world_rect){0, 0, p->width, p->height};
    if ((int64_t)p->width * p->height > p->max_cells)
        return refuse(p, TERRAD_E_TOO_LARGE,
                      "x, y, w, h: absent, so the whole world (%lld cells), over max_edit_cells "
                      "(%lld): reset it in rectangles",
                      (long long)p->width * p->height, (long long)p->max_cells);
    return 0;
}

int hub_edit_parse(const cJSON *msg, int width, int height, int64_t max_cells, world_edit *out,
                   hub_edit_error *err)
{
    memset(out, 0, sizeof *out);
    memset(err, 0, sizeof *err);
    edit_parser p = {msg, width, height, max_cells, err};
    const cJSON *op = cJSON_GetObjectItemCaseSensitive(msg, "op");
    int found = -1;
    for (int i = 0; cJSON_IsString(op) && i <= WORLD_EDIT_REMOVE; i++)
        if (strcmp(op->valuestring, world_edit_op_name((world_edit_op)i)) == 0)
            found = i;
    if (found < 0)
        return refuse(&p, TERRAD_E_BAD_VALUE, "op: %s crater, stamp, reset, add or remove",
                      op ? "must be" : "missing,");
    out->op = (world_edit_op)found;
    int rc;
    int64_t amount = 0;
    switch (out->op) {
    case WORLD_EDIT_CRATER:
        rc = parse_crater(&p, out);
        break;
    case WORLD_EDIT_STAMP:
        rc = parse_stamp(&p, out);
        break;
    case WORLD_EDIT_RESET:
        rc = parse_reset(&p, out);
        break;
    default: /* add, remove */
        rc = edit_rect(&p, &out->rect) < 0 ||
                     edit_int(&p, "amount", 1, 1, WORLD_HEIGHT_MAX, &amount) < 0
                 ? -1
                 : 0;
        out->amount = (int32_t)amount;
        break;
    }
    if (rc != 0)
        world_edit_free(out);
    return rc;
}
