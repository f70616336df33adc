/*
 * terrad_proto_base.c: base snapshot rectangles (PROTOCOL.md "Base
 * snapshots", issue 32 item 2): a late joiner's snapshot coded against the
 * scene's base terrain, which the client rebuilds itself with the twin
 * library. The server codes each tile piece of a snapshot this way for a
 * client whose hello asked (server/service/service_snapshots.c); the C
 * mirror (terrad_mirror_apply) and the Python client decode it.
 *
 * Why this coding: only the digging is news, so the cells are d = h - base;
 * craters and ruts are smooth surfaces, so a cell is predicted from its
 * decoded neighbours (left + up - up-left, exact for any plane and any sum of
 * x- and y-quadratics such as a crater's bowl) and only the residual travels;
 * residuals are small where the surface is smooth and large along a crater's
 * rim or a rut's edge, so each is coded with probabilities adapted per
 * context (how large the left and upper residuals were): an LZMA-style binary
 * range coder over the residual's Elias-gamma form. On 2,000 craters in a
 * 1024² world it takes a 256² window from 139,693 bytes (absolute heights,
 * zstd 3) to 44,094, where the same prediction as varints through zstd 3
 * takes 50,931 (docs/performance.md "Late join": its table of codings). Every
 * step is integer arithmetic modulo 2^32: exact for any int32 heights.
 *
 * The format, exactly (PROTOCOL.md "Base snapshots"): cells row-major; r the
 * residual (d - prediction, wrapping), u = zigzag(r), v = u + 1 (33 bits),
 * n = bit length of v less one (0..32). Context c: s = |left residual| +
 * |upper residual| (the first row: the left one twice; the first column: the
 * upper one twice; the first cell: 0), c = 0 when s = 0, else min(11, bit
 * length of s). Coded: n in unary (n bits 1, then a 0 unless n = 32) with
 * probability unary[c][i] for the i-th bit; then v's bits below its top one,
 * highest first, the first two of them with probability mant[c][n][k], the
 * rest direct (probability one half). Probabilities are 11-bit (1024 at the
 * start), moved by a 16th towards each bit seen; the range coder is LZMA's.
 */
#include "terrad_proto.h"

#include <stdlib.h>
#include <string.h>

#define CTX 12
#define PROB_BITS 11
#define PROB_INIT (1u << (PROB_BITS - 1))
#define PROB_SHIFT 4
#define TOP (1u << 24)

typedef struct models {
    uint16_t unary[CTX][33];
    uint16_t mant[CTX][33][2];
} models;

static void models_init(models *m)
{
    for (int c = 0; c < CTX; c++)
        for (int i = 0; i < 33; i++)
            m->unary[c][i] = m->mant[c][i][0] = m->mant[c][i][1] = PROB_INIT;
}

static int32_t as_i32(uint32_t u)
{
    int32_t s;
    memcpy(&s, &u, sizeof s); /* two's complement, no UB */
    return s;
}

/* The prediction of cell (x, y) from the decoded values d (row-major, w wide). */
static uint32_t predict(const uint32_t *d, size_t w, size_t x, size_t y)
{
    if (y == 0)
        return x ? d[x - 1] : 0u;
    if (x == 0)
        return d[(y - 1) * w];
    return d[y * w + x - 1] + d[(y - 1) * w + x] - d[(y - 1) * w + x - 1];
}

static int bit_length(uint64_t v) /* 0 for 0 */
{
    return v ? 64 - __builtin_clzll(v) : 0;
}

static uint64_t mag(uint32_t u) /* |r| of a zigzagged residual */
{
    return ((uint64_t)u + 1) >> 1;
}

/* The context of cell (x, y) from the zigzagged residuals z seen so far. */
static int context(const uint32_t *z, size_t w, size_t x, size_t y)
{
    uint64_t a = x ? mag(z[y * w + x - 1]) : y ? mag(z[(y - 1) * w]) : 0;
    uint64_t b = y ? mag(z[(y - 1) * w + x]) : a;
    int bits = bit_length(a + b);
    return bits < CTX - 1 ? bits : CTX - 1;
}

/* ---- the range encoder (LZMA's) ---- */

typedef struct enc {
    uint64_t low;
    uint32_t range;
    uint8_t cache;
    uint64_t cache_size;
    uint8_t *out;
    size_t n, cap;
    int full;
} enc;

static void put(enc *e, uint8_t b)
{
    if (e->n < e->cap)
        e->out[e->n++] = b;
    else
        e->full = 1;
}

static void shift_low(enc *e)
{
    if ((uint32_t)e->low < 0xFF000000u || (e->low >> 32) != 0) {
        uint8_t carry = (uint8_t)(e->low >> 32);
        uint8_t temp = e->cache;
        do {
            put(e, (uint8_t)(temp + carry));
            temp = 0xFF;
        } while (--e->cache_size != 0);
        e->cache = (uint8_t)(e->low >> 24);
    }
    e->cache_size++;
    e->low = (e->low & 0x00FFFFFFu) << 8;
}

static void enc_bit(enc *e, uint16_t *p, unsigned bit)
{
    uint32_t bound = (e->range >> PROB_BITS) * *p;
    if (!bit) {
        e->range = bound;
        *p = (uint16_t)(*p + (((1u << PROB_BITS) - *p) >> PROB_SHIFT));
    } else {
        e->low += bound;
        e->range -= bound;
        *p = (uint16_t)(*p - (*p >> PROB_SHIFT));
    }
    while (e->range < TOP) {
        e->range <<= 8;
        shift_low(e);
    }
}

static void enc_direct(enc *e, unsigned bit)
{
    e->range >>= 1;
    if (bit)
        e->low += e->range;
    while (e->range < TOP) {
        e->range <<= 8;
        shift_low(e);
    }
}

/* ---- the range decoder ---- */

typedef struct dec {
    uint32_t range, code;
    const uint8_t *in;
    size_t at, len;
    int short_input;
} dec;

static uint8_t get(dec *d)
{
    if (d->at < d->len)
        return d->in[d->at++];
    d->short_input = 1;
    return 0;
}

static void dec_norm(dec *d)
{
    while (d->range < TOP) {
        d->range <<= 8;
        d->code = (d->code << 8) | get(d);
    }
}

static unsigned dec_bit(dec *d, uint16_t *p)
{
    uint32_t bound = (d->range >> PROB_BITS) * *p;
    unsigned bit;
    if (d->code < bound) {
        d->range = bound;
        *p = (uint16_t)(*p + (((1u << PROB_BITS) - *p) >> PROB_SHIFT));
        bit = 0;
    } else {
        d->code -= bound;
        d->range -= bound;
        *p = (uint16_t)(*p - (*p >> PROB_SHIFT));
        bit = 1;
    }
    dec_norm(d);
    return bit;
}

static unsigned dec_direct(dec *d)
{
    d->range >>= 1;
    unsigned bit = d->code >= d->range;
    if (bit)
        d->code -= d->range;
    dec_norm(d);
    return bit;
}

/* A decoder over in[0..len), its first 5 bytes read. */
static dec dec_start(const uint8_t *in, size_t len)
{
    dec r = {.range = 0xFFFFFFFFu, .in = in, .len = len};
    for (int k = 0; k < 5; k++)
        r.code = (r.code << 8) | get(&r);
    return r;
}

/* The encoder's last 5 shift_lows; its length plus extra bytes (a header) in
 * *len_out, or buffer_too_small when it ran out of room. */
static int enc_finish(enc *e, size_t extra, size_t *len_out)
{
    for (int k = 0; k < 5; k++)
        shift_low(e);
    if (e->full)
        return TERRAD_E_BUFFER_TOO_SMALL;
    if (len_out)
        *len_out = e->n + extra;
    return TERRAD_OK;
}

/* A decoder's first checks: too_large past out_cap, bad_compression under min_len bytes. */
static int dec_check(size_t cells, size_t out_cap, const uint8_t *data, size_t len, size_t min_len)
{
    if (cells == 0 || cells > out_cap || cells > SIZE_MAX / 16)
        return TERRAD_E_TOO_LARGE;
    if (!data || len < min_len)
        return TERRAD_E_BAD_COMPRESSION;
    return TERRAD_OK;
}

/* ---- a residual: u = zigzag(r) as v = u + 1 in Elias-gamma form ---- */

static void enc_residual(enc *e, models *m, int c, uint32_t u)
{
    uint64_t v = (uint64_t)u + 1;
    int n = bit_length(v) - 1;
    for (int k = 0; k < n; k++)
        enc_bit(e, &m->unary[c][k], 1);
    if (n < 32)
        enc_bit(e, &m->unary[c][n], 0);
    for (int k = n - 1; k >= 0; k--) {
        unsigned bit = (unsigned)(v >> k) & 1u;
        if (k >= n - 2)
            enc_bit(e, &m->mant[c][n][n - 1 - k], bit);
        else
            enc_direct(e, bit);
    }
}

/* 0, or -1 for a value past 2^32 - 1 or a payload that ended early. */
static int dec_residual(dec *r, models *m, int c, uint32_t *u)
{
    int n = 0;
    while (n < 32 && dec_bit(r, &m->unary[c][n]))
        n++;
    uint64_t v = 1;
    for (int k = n - 1; k >= 0; k--)
        v = (v << 1) | (k >= n - 2 ? dec_bit(r, &m->mant[c][n][n - 1 - k]) : dec_direct(r));
    if (v - 1 > 0xFFFFFFFFu || r->short_input)
        return -1;
    *u = (uint32_t)(v - 1);
    return 0;
}

/* ---- rectangles ---- */

/* The models (at their start) and the residuals of one rectangle: -1 without memory. */
static int coder_alloc(size_t cells, models **m, uint32_t **z)
{
    *m = malloc(sizeof **m);
    *z = malloc(cells * sizeof **z);
    if (!*m || !*z) {
        free(*m);
        free(*z);
        return -1;
    }
    models_init(*m);
    return 0;
}

size_t terrad_rect_compress_base_bound(size_t cells)
{
    if (cells == 0 || cells > SIZE_MAX / 16)
        return 0;
    return cells * 9 + 16; /* at most 65 coded bits a cell, and the coder's 5 */
}

int terrad_rect_compress_base(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out, size_t cap,
                              size_t *len_out)
{
    size_t cells = (size_t)w * h;
    if (cells == 0 || cells > SIZE_MAX / 16)
        return TERRAD_E_TOO_LARGE;
    models *m;
    uint32_t *z;
    if (coder_alloc(cells, &m, &z) != 0)
        return TERRAD_E_NO_MEMORY;
    enc e = {.range = 0xFFFFFFFFu, .cache_size = 1, .out = out, .cap = cap};
    const uint32_t *d = (const uint32_t *)(const void *)diff; /* int32 and uint32 alias */
    for (size_t y = 0; y < h; y++) {
        for (size_t x = 0; x < w; x++) {
            size_t i = y * w + x;
            int c = context(z, w, x, y);
            enc_residual(&e, m, c, z[i] = terrad_zigzag32(as_i32(d[i] - predict(d, w, x, y))));
        }
    }
    int rc = enc_finish(&e, 0, len_out);
    free(m);
    free(z);
    return rc;
}

int terrad_rect_decompress_base(const uint8_t *data, size_t len, uint32_t w, uint32_t h,
                                int32_t *out, size_t out_cap)
{
    size_t cells = (size_t)w * h;
    int rc = dec_check(cells, out_cap, data, len, 5);
    if (rc != TERRAD_OK)
        return rc;
    models *m;
    uint32_t *z;
    if (coder_alloc(cells, &m, &z) != 0)
        return TERRAD_E_NO_MEMORY;
    dec r = dec_start(data, len);
    uint32_t *d = (uint32_t *)(void *)out;
    for (size_t y = 0; y < h && rc == TERRAD_OK; y++) {
        for (size_t x = 0; x < w; x++) {
            size_t i = y * w + x;
            int c = context(z, w, x, y);
            if (dec_residual(&r, m, c, &z[i]) != 0) {
                rc = TERRAD_E_BAD_COMPRESSION; /* past 2^32, or the payload ended early */
                break;
            }
            d[i] = (uint32_t)terrad_unzigzag32(z[i]) + predict(d, w, x, y);
        }
    }
    free(m);
    free(z);
    return rc;
}

size_t terrad_rect_apply_base(const terrad_rect *r, const int32_t *diff, const int32_t *base,
                              int32_t *heights, int32_t hx, int32_t hy, uint32_t hw, uint32_t hh)
{
    int64_t x0 = r->x > hx ? r->x : hx, y0 = r->y > hy ? r->y : hy;
    int64_t x1 = (int64_t)r->x + r->w < (int64_t)hx + hw ? (int64_t)r->x + r->w : (int64_t)hx + hw;
    int64_t y1 = (int64_t)r->y + r->h < (int64_t)hy + hh ? (int64_t)r->y + r->h : (int64_t)hy + hh;
    size_t touched = 0;
    for (int64_t y = y0; y < y1; y++) {
        for (int64_t x = x0; x < x1; x++) {
            size_t at = (size_t)(y - hy) * hw + (size_t)(x - hx);
            uint32_t d = (uint32_t)diff[(size_t)(y - r->y) * r->w + (size_t)(x - r->x)];
            heights[at] = as_i32((uint32_t)base[at] + d);
        }
        touched += x1 > x0 ? (size_t)(x1 - x0) : 0;
    }
    return touched;
}

/* ---- slope snapshots (encoding 3; PROTOCOL.md "Slope snapshots") ----
 *
 * Why: ground driven over for an hour is a sand pile at its angle of repose
 * (the slope stage leaves |h - h'| at or just under a material's axial and
 * diagonal thresholds), rough from cell to cell, so encoding 2's residuals
 * cost ~8.3 bits a cell. But the thresholds bound every cell by its decoded
 * neighbours: d <= lo = min(n + limit) and d >= hi = max(n - limit) over the
 * left, upper, upper-left and upper-right neighbours (limit a axial, b
 * diagonal), and on an hour of 8 vehicles 45 % of the cells sit exactly at
 * (or one under) a bound. So each cell first says whether it sits at the
 * upper bound, at the lower one (and which of the two values), with
 * probabilities adapted per context (the classes of its left, upper and
 * upper-right neighbours); only the others code a residual as encoding 2
 * does, against encoding 2's prediction clamped into [hi, lo], in a context
 * of how wide [hi, lo] is. On bench_join's hour of 8 vehicles, the 256²
 * window's 16 tiles (+ 25 bytes of rectangle header each) take 67,930 bytes in
 * encoding 2 and 55,317 in encoding 3; on 2,000 craters, whose rims are
 * steeper than any limit, encoding 2 stays shorter (44,080 against 46,442),
 * so the server sends whichever is shorter.
 *
 * Payload: a and b (u32, little-endian), then the range coder's bytes. */

#define CLASS_CTX 64

typedef struct slope_models {
    models res;
    uint16_t cls[CLASS_CTX][4]; /* at upper?, at lower?, upper one under?, lower one over? */
} slope_models;

enum { AT_NONE = 0, AT_UPPER = 1, AT_LOWER = 2, ABSENT = 3 };

/* The bounds of cell (x, y) from its decoded neighbours d (as int32), and the
 * context of its class from theirs (k); 0 for the first cell (no neighbour). */
static int slope_bounds(const uint32_t *d, const uint8_t *k, size_t w, size_t x, size_t y,
                        int64_t a, int64_t b, int64_t *lo, int64_t *hi, int *cc)
{
    int kl = ABSENT, ku = ABSENT, kur = ABSENT, any = 0;
    *lo = INT64_MAX;
    *hi = INT64_MIN;
    struct {
        int ok;
        size_t at;
        int64_t lim;
    } nb[4] = {{x > 0, y * w + x - 1, a},
               {y > 0, (y - 1) * w + x, a},
               {x > 0 && y > 0, (y - 1) * w + x - 1, b},
               {y > 0 && x + 1 < w, (y - 1) * w + x + 1, b}};
    for (int j = 0; j < 4; j++) {
        if (!nb[j].ok)
            continue;
        int64_t n = as_i32(d[nb[j].at]);
        if (n + nb[j].lim < *lo)
            *lo = n + nb[j].lim;
        if (n - nb[j].lim > *hi)
            *hi = n - nb[j].lim;
        any = 1;
    }
    if (x > 0)
        kl = k[y * w + x - 1];
    if (y > 0)
        ku = k[(y - 1) * w + x];
    if (y > 0 && x + 1 < w)
        kur = k[(y - 1) * w + x + 1];
    *cc = kl * 16 + ku * 4 + kur;
    return any;
}

/* Encoding 2's prediction, clamped into [hi, lo] when that is not empty. */
static int64_t slope_predict(const uint32_t *d, size_t w, size_t x, size_t y, int any, int64_t lo,
                             int64_t hi)
{
    int64_t p = as_i32(predict(d, w, x, y));
    if (any && hi <= lo)
        p = p < hi ? hi : p > lo ? lo : p;
    return p;
}

/* A residual's context: how wide [hi, lo] is (bit length of lo - hi, at most
 * 11), or encoding 2's context when the bounds are empty or absent. Between
 * bounds a cell's value is spread about evenly (a sand pile's crests and
 * troughs), so the width says more than the neighbours' residuals. */
static int slope_context(const uint32_t *z, size_t w, size_t x, size_t y, int any, int64_t lo,
                         int64_t hi)
{
    if (!any || lo < hi)
        return context(z, w, x, y);
    int bits = bit_length((uint64_t)(lo - hi));
    return bits < CTX - 1 ? bits : CTX - 1;
}

static uint32_t slope_zigzag(uint32_t value, int64_t p)
{
    return terrad_zigzag32(as_i32(value - (uint32_t)(uint64_t)p)); /* wrapping */
}

static void put_u32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}

static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The work memory of one slope rectangle: models, residuals, classes. */
static int slope_alloc(size_t cells, slope_models **m, uint32_t **z, uint8_t **k)
{
    *m = malloc(sizeof **m);
    *z = malloc(cells * sizeof **z);
    *k = malloc(cells);
    if (!*m || !*z || !*k) {
        free(*m);
        free(*z);
        free(*k);
        return -1;
    }
    models_init(&(*m)->res);
    for (int c = 0; c < CLASS_CTX; c++)
        for (int j = 0; j < 4; j++)
            (*m)->cls[c][j] = PROB_INIT;
    return 0;
}

size_t terrad_rect_compress_slope_bound(size_t cells)
{
    size_t n = terrad_rect_compress_base_bound(cells);
    return n && n <= SIZE_MAX - cells - 8 ? n + cells + 8 : 0; /* + class bits, + a and b */
}

int terrad_rect_compress_slope_ab(const int32_t *diff, uint32_t w, uint32_t h, uint32_t a,
                                  uint32_t b, uint8_t *out, size_t cap, size_t *len_out)
{
    size_t cells = (size_t)w * h;
    if (cells == 0 || cells > SIZE_MAX / 16)
        return TERRAD_E_TOO_LARGE;
    if (cap < 8)
        return TERRAD_E_BUFFER_TOO_SMALL;
    slope_models *m;
    uint32_t *z;
    uint8_t *k;
    if (slope_alloc(cells, &m, &z, &k) != 0)
        return TERRAD_E_NO_MEMORY;
    put_u32(out, a);
    put_u32(out + 4, b);
    enc e = {.range = 0xFFFFFFFFu, .cache_size = 1, .out = out + 8, .cap = cap - 8};
    const uint32_t *d = (const uint32_t *)(const void *)diff;
    for (size_t y = 0; y < h; y++) {
        for (size_t x = 0; x < w; x++) {
            size_t i = y * w + x;
            int64_t lo, hi, v = diff[i];
            int cc, any = slope_bounds(d, k, w, x, y, a, b, &lo, &hi, &cc);
            int64_t p = slope_predict(d, w, x, y, any, lo, hi);
            k[i] = AT_NONE;
            if (any) {
                k[i] = v == lo || v == lo - 1   ? AT_UPPER
                       : v == hi || v == hi + 1 ? AT_LOWER
                                                : AT_NONE;
                enc_bit(&e, &m->cls[cc][0], k[i] == AT_UPPER);
                if (k[i] != AT_UPPER)
                    enc_bit(&e, &m->cls[cc][1], k[i] == AT_LOWER);
                if (k[i] == AT_UPPER)
                    enc_bit(&e, &m->cls[cc][2], v == lo - 1);
                if (k[i] == AT_LOWER)
                    enc_bit(&e, &m->cls[cc][3], v == hi + 1);
            }
            z[i] = slope_zigzag(d[i], p);
            if (k[i] == AT_NONE)
                enc_residual(&e, &m->res, slope_context(z, w, x, y, any, lo, hi), z[i]);
        }
    }
    int rc = enc_finish(&e, 8, len_out);
    free(m);
    free(z);
    free(k);
    return rc;
}

/* Limits the coder considers: neighbour differences under 2^16 units (6.5 m
 * in 0.1 mm units), counted in a histogram rather than sorted. */
#define LIMIT_CANDIDATES 65536u

/* The limit v > 0, a difference that occurs, that most differences equal or
 * sit one under (count: a histogram of differences); 0 when there is none. */
static uint32_t most_common_limit(const uint32_t *count)
{
    uint32_t best = 0;
    uint64_t best_count = 0;
    for (uint32_t v = 1; v < LIMIT_CANDIDATES; v++) {
        uint64_t c = (uint64_t)count[v] + count[v - 1];
        if (count[v] > 0 && c > best_count) { /* a difference that occurs */
            best_count = c;
            best = v;
        }
    }
    return best;
}

static void count_diff(uint32_t *count, int32_t p, int32_t q)
{
    int64_t v = (int64_t)p - q;
    v = v < 0 ? -v : v;
    if (v < (int64_t)LIMIT_CANDIDATES)
        count[v]++;
}

int terrad_rect_compress_slope(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out,
                               size_t cap, size_t *len_out)
{
    size_t cells = (size_t)w * h;
    if (cells == 0 || cells > SIZE_MAX / 16)
        return TERRAD_E_TOO_LARGE;
    /* counts of at most 2 * cells < 2^32 differences each (w, h < 2^16) */
    uint32_t *ax = calloc(LIMIT_CANDIDATES, sizeof *ax), *dg = calloc(LIMIT_CANDIDATES, sizeof *dg);
    if (!ax || !dg) {
        free(ax);
        free(dg);
        return TERRAD_E_NO_MEMORY;
    }
    for (size_t y = 0; y < h; y++) {
        for (size_t x = 0; x < w; x++) {
            int32_t v = diff[y * w + x];
            if (x > 0)
                count_diff(ax, v, diff[y * w + x - 1]);
            if (y > 0)
                count_diff(ax, v, diff[(y - 1) * w + x]);
            if (x > 0 && y > 0)
                count_diff(dg, v, diff[(y - 1) * w + x - 1]);
            if (y > 0 && x + 1 < w)
                count_diff(dg, v, diff[(y - 1) * w + x + 1]);
        }
    }
    uint32_t a = most_common_limit(ax), b = most_common_limit(dg);
    free(ax);
    free(dg);
    return terrad_rect_compress_slope_ab(diff, w, h, a, b, out, cap, len_out);
}

int terrad_rect_compress_base_smaller(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out,
                                      size_t cap, size_t *len_out, uint8_t *encoding_out)
{
    size_t cells = (size_t)w * h, base_cap = terrad_rect_compress_base_bound(cells), n = 0;
    int rc = terrad_rect_compress_slope(diff, w, h, out, cap, &n);
    if (rc != TERRAD_OK && rc != TERRAD_E_BUFFER_TOO_SMALL)
        return rc;
    uint8_t *base = malloc(base_cap ? base_cap : 1);
    size_t nb = 0;
    int brc =
        base ? terrad_rect_compress_base(diff, w, h, base, base_cap, &nb) : TERRAD_E_NO_MEMORY;
    if (brc == TERRAD_OK && (rc != TERRAD_OK || nb < n) && nb <= cap) {
        memcpy(out, base, nb);
        n = nb;
        rc = TERRAD_OK;
        *encoding_out = TERRAD_ENC_BASE;
    } else if (rc == TERRAD_OK) {
        *encoding_out = TERRAD_ENC_BASE_SLOPE;
    }
    free(base);
    if (rc == TERRAD_OK && len_out)
        *len_out = n;
    return rc;
}

int terrad_rect_decompress_slope(const uint8_t *data, size_t len, uint32_t w, uint32_t h,
                                 int32_t *out, size_t out_cap)
{
    size_t cells = (size_t)w * h;
    int rc = dec_check(cells, out_cap, data, len, 13);
    if (rc != TERRAD_OK)
        return rc;
    slope_models *m;
    uint32_t *z;
    uint8_t *k;
    if (slope_alloc(cells, &m, &z, &k) != 0)
        return TERRAD_E_NO_MEMORY;
    int64_t a = get_u32(data), b = get_u32(data + 4);
    dec r = dec_start(data + 8, len - 8);
    uint32_t *d = (uint32_t *)(void *)out;
    for (size_t y = 0; y < h && rc == TERRAD_OK; y++) {
        for (size_t x = 0; x < w; x++) {
            size_t i = y * w + x;
            int64_t lo, hi, v = 0;
            int cc, any = slope_bounds(d, k, w, x, y, a, b, &lo, &hi, &cc);
            int64_t p = slope_predict(d, w, x, y, any, lo, hi);
            k[i] = AT_NONE;
            if (any) {
                if (dec_bit(&r, &m->cls[cc][0]))
                    k[i] = AT_UPPER;
                else if (dec_bit(&r, &m->cls[cc][1]))
                    k[i] = AT_LOWER;
                if (k[i] == AT_UPPER)
                    v = lo - dec_bit(&r, &m->cls[cc][2]);
                else if (k[i] == AT_LOWER)
                    v = hi + dec_bit(&r, &m->cls[cc][3]);
            }
            if (k[i] == AT_NONE) {
                uint32_t u;
                if (dec_residual(&r, &m->res, slope_context(z, w, x, y, any, lo, hi), &u) != 0) {
                    rc = TERRAD_E_BAD_COMPRESSION; /* past 2^32, or the payload ended early */
                    break;
                }
                d[i] = (uint32_t)(uint64_t)p + (uint32_t)terrad_unzigzag32(u);
                z[i] = u;
            } else if (v < INT32_MIN || v > INT32_MAX || r.short_input) {
                rc = TERRAD_E_BAD_COMPRESSION; /* a bound outside int32, or ended early */
                break;
            } else {
                d[i] = (uint32_t)(int32_t)v;
                z[i] = slope_zigzag(d[i], p);
            }
        }
    }
    free(m);
    free(z);
    free(k);
    return rc;
}
