/*
 * world_edit.c: terrain edits from game logic (issue 22) — a crater, a
 * stamped height patch, a rectangle reset to the base terrain, material
 * added or removed over an area — parsed from the protocol's `edit` message
 * (PROTOCOL.md "edit") and applied to the world's heights. The service
 * applies them at the start of a tick, before the colliders deform, in the
 * order they arrived (service_edits.c); the WAL logs and the deltas carry
 * the cells they changed like any other change.
 *
 * Everything here is integer arithmetic on the heights, so an edit gives
 * the same cells on every backend and thread count. An edit is applied
 * whole or not at one: one that would move a cell outside
 * [WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX] changes nothing. The change is
 * returned as per-cell differences; their sum is the exact volume change
 * the reply declares (a crater with its rim keeps Σh exactly: the dug
 * volume is shared out over the rim with the remainder handed out unit by
 * unit in raster order).
 */
#include "world/world.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

static const char *const op_names[] = {"crater", "stamp", "reset", "add", "remove"};
static const char *const mode_names[] = {"set", "add", "min", "max"};

const char *world_edit_op_name(world_edit_op op)
{
    return op >= 0 && op < (int)(sizeof op_names / sizeof op_names[0]) ? op_names[op] : "?";
}

void world_edit_free(world_edit *e)
{
    free(e->values);
    free(e->mask);
    e->values = NULL;
    e->mask = NULL;
}

/* ---- parsing ---- */

typedef struct edit_parser {
    const cJSON *msg;
    int width, height;
    int64_t max_cells;
    world_edit_error *err;
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

int world_edit_parse(const cJSON *msg, int width, int height, int64_t max_cells, world_edit *out,
                     world_edit_error *err)
{
    memset(out, 0, sizeof *out);
    memset(err, 0, sizeof *err);
    edit_parser p = {msg, width, height, max_cells, err};
    const cJSON *op = cJSON_GetObjectItemCaseSensitive(msg, "op");
    int found = -1;
    for (int i = 0; cJSON_IsString(op) && i < (int)(sizeof op_names / sizeof op_names[0]); i++)
        if (strcmp(op->valuestring, op_names[i]) == 0)
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

/* ---- applying ---- */

/* The crater's new heights in h (e->rect, row-major). */
static void crater_heights(const world_edit *e, int64_t *h)
{
    const world_rect r = e->rect;
    const int64_t r2 = (int64_t)e->radius * e->radius;
    int64_t dug = 0, weights = 0, rim_cells = 0;
    for (int y = r.y; y < r.y + r.h; y++)
        for (int x = r.x; x < r.x + r.w; x++) {
            int64_t dx = x - e->cx, dy = y - e->cy, d2 = dx * dx + dy * dy;
            int64_t i = (int64_t)(y - r.y) * r.w + (x - r.x);
            if (d2 < r2) { /* a paraboloid bowl: depth at the centre, 0 at the radius */
                int64_t dig = e->depth * (r2 - d2) / r2;
                h[i] -= dig;
                dug += dig;
            } else if (e->rim && d2 < 4 * r2) {
                weights += 4 * r2 - d2; /* highest at the edge, 0 at twice the radius */
                rim_cells++;
            }
        }
    if (!e->rim || rim_cells == 0 || dug == 0)
        return;
    /* share dug out by weight, exactly: q * w + (rem * w) / W per cell, then
     * what floor division left (fewer units than rim cells) one by one */
    int64_t q = dug / weights, rem = dug % weights, given = 0;
    for (int pass = 0; pass < 2; pass++)
        for (int y = r.y; y < r.y + r.h; y++)
            for (int x = r.x; x < r.x + r.w; x++) {
                int64_t dx = x - e->cx, dy = y - e->cy, d2 = dx * dx + dy * dy;
                if (d2 < r2 || d2 >= 4 * r2)
                    continue;
                int64_t i = (int64_t)(y - r.y) * r.w + (x - r.x);
                if (pass == 0) {
                    int64_t wgt = 4 * r2 - d2, share = q * wgt + rem * wgt / weights;
                    h[i] += share;
                    given += share;
                } else if (given < dug) {
                    h[i] += 1;
                    given++;
                }
            }
}

int world_edit_apply(world *w, const world_edit *e, world_rect *rect, int32_t **diff,
                     int64_t *volume, error_text *err)
{
    const world_rect r = e->rect;
    size_t cells = (size_t)r.w * r.h;
    int32_t *before = malloc(cells * sizeof *before);
    int64_t *h = malloc(cells * sizeof *h);
    if (!before || !h) {
        free(before);
        free(h);
        error_set(err, "edit: out of memory for %zu cells", cells);
        return -1;
    }
    if (e->op == WORLD_EDIT_RESET) {
        world_base_fill_rect(w, r, before);
        for (size_t i = 0; i < cells; i++)
            h[i] = before[i];
    }
    world_gather_window(w, r, before);
    if (e->op != WORLD_EDIT_RESET)
        for (size_t i = 0; i < cells; i++)
            h[i] = before[i];
    if (e->op == WORLD_EDIT_CRATER)
        crater_heights(e, h);
    for (size_t i = 0; i < cells && e->op != WORLD_EDIT_CRATER && e->op != WORLD_EDIT_RESET; i++) {
        if (e->op == WORLD_EDIT_ADD)
            h[i] += e->amount;
        else if (e->op == WORLD_EDIT_REMOVE)
            h[i] -= e->amount;
        else if (!e->mask || e->mask[i]) { /* stamp */
            int64_t v = e->values[i];
            h[i] = e->mode == WORLD_STAMP_SET   ? v
                   : e->mode == WORLD_STAMP_ADD ? h[i] + v
                   : e->mode == WORLD_STAMP_MIN ? (v < h[i] ? v : h[i])
                                                : (v > h[i] ? v : h[i]);
        }
    }
    int64_t sum = 0;
    for (size_t i = 0; i < cells; i++) {
        if (h[i] < WORLD_HEIGHT_MIN || h[i] > WORLD_HEIGHT_MAX) {
            int x = r.x + (int)(i % (size_t)r.w), y = r.y + (int)(i / (size_t)r.w);
            error_set(err,
                      "%s: cell (%d, %d) would be at %lld units, outside the height range "
                      "[%d, %d]; nothing was changed",
                      world_edit_op_name(e->op), x, y, (long long)h[i], WORLD_HEIGHT_MIN,
                      WORLD_HEIGHT_MAX);
            free(before);
            free(h);
            return -1;
        }
        int32_t d = (int32_t)(h[i] - before[i]);
        sum += d;
        before[i] = (int32_t)h[i]; /* before now holds the new heights */
        h[i] = d;
    }
    world_scatter_window(w, r, before);
    /* the differences, narrowed into before's buffer (|d| < 2^30) */
    for (size_t i = 0; i < cells; i++)
        before[i] = (int32_t)h[i];
    free(h);
    *rect = r;
    *diff = before;
    *volume = sum;
    return 0;
}

/* Cell by cell: an undo follows a failed log write and must not itself
 * fail for want of memory; it is rare, so its speed does not matter. */
void world_edit_undo(world *w, world_rect r, const int32_t *diff)
{
    for (int y = r.y; y < r.y + r.h; y++)
        for (int x = r.x; x < r.x + r.w; x++) {
            int32_t d = diff[(int64_t)(y - r.y) * r.w + (x - r.x)];
            if (d)
                world_set_height(w, x, y, world_height_at(w, x, y) - d);
        }
}
