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
            uint32_t u = z[i] = terrad_zigzag32(as_i32(d[i] - predict(d, w, x, y)));
            uint64_t v = (uint64_t)u + 1;
            int n = bit_length(v) - 1;
            for (int k = 0; k < n; k++)
                enc_bit(&e, &m->unary[c][k], 1);
            if (n < 32)
                enc_bit(&e, &m->unary[c][n], 0);
            for (int k = n - 1; k >= 0; k--) {
                unsigned bit = (unsigned)(v >> k) & 1u;
                if (k >= n - 2)
                    enc_bit(&e, &m->mant[c][n][n - 1 - k], bit);
                else
                    enc_direct(&e, bit);
            }
        }
    }
    for (int k = 0; k < 5; k++)
        shift_low(&e);
    free(m);
    free(z);
    if (e.full)
        return TERRAD_E_BUFFER_TOO_SMALL;
    if (len_out)
        *len_out = e.n;
    return TERRAD_OK;
}

int terrad_rect_decompress_base(const uint8_t *data, size_t len, uint32_t w, uint32_t h,
                                int32_t *out, size_t out_cap)
{
    size_t cells = (size_t)w * h;
    if (cells == 0 || cells > out_cap || cells > SIZE_MAX / 16)
        return TERRAD_E_TOO_LARGE;
    if (!data || len < 5)
        return TERRAD_E_BAD_COMPRESSION;
    models *m;
    uint32_t *z;
    if (coder_alloc(cells, &m, &z) != 0)
        return TERRAD_E_NO_MEMORY;
    dec r = {.range = 0xFFFFFFFFu, .in = data, .len = len};
    for (int k = 0; k < 5; k++)
        r.code = (r.code << 8) | get(&r);
    uint32_t *d = (uint32_t *)(void *)out;
    int rc = TERRAD_OK;
    for (size_t y = 0; y < h && rc == TERRAD_OK; y++) {
        for (size_t x = 0; x < w; x++) {
            size_t i = y * w + x;
            int c = context(z, w, x, y);
            int n = 0;
            while (n < 32 && dec_bit(&r, &m->unary[c][n]))
                n++;
            uint64_t v = 1;
            for (int k = n - 1; k >= 0; k--)
                v = (v << 1) |
                    (k >= n - 2 ? dec_bit(&r, &m->mant[c][n][n - 1 - k]) : dec_direct(&r));
            if (v - 1 > 0xFFFFFFFFu || r.short_input) {
                rc = TERRAD_E_BAD_COMPRESSION; /* past 2^32, or the payload ended early */
                break;
            }
            z[i] = (uint32_t)(v - 1);
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
