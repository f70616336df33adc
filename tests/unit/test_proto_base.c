/*
 * test_proto_base.c: base and slope snapshot rectangles
 * (proto/c/terrad_proto_base.c, PROTOCOL.md "Base snapshots", "Slope
 * snapshots"): every coded rectangle, in encoding 2 and in encoding 3, decodes
 * to exactly its values — smooth craters, a sand pile at its slope limits,
 * noise, the int32 extremes and their wrap-around, one row, one column, one
 * cell, any limits — a payload cut short is bad_compression, a buffer under
 * the bound is refused, the sand pile codes shorter in encoding 3 and the
 * crater in encoding 2 (the server's choice keeps the shorter), and the mirror
 * adds the base back (and refuses a base rectangle when it holds no base).
 */
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "terrad_proto.h"

static uint32_t rng = 12345;
static uint32_t next(void)
{
    rng = rng * 1664525u + 1013904223u;
    return rng;
}

typedef struct coding {
    const char *name;
    size_t (*bound)(size_t cells);
    int (*compress)(const int32_t *, uint32_t, uint32_t, uint8_t *, size_t, size_t *);
    int (*decompress)(const uint8_t *, size_t, uint32_t, uint32_t, int32_t *, size_t);
    size_t min_len; /* shorter payloads are refused unread */
} coding;

static const coding codings[2] = {
    {"encoding 2", terrad_rect_compress_base_bound, terrad_rect_compress_base,
     terrad_rect_decompress_base, 5},
    {"encoding 3", terrad_rect_compress_slope_bound, terrad_rect_compress_slope,
     terrad_rect_decompress_slope, 13},
};

/* Codes w x h values in coding k and decodes them back; returns the coded length (0 on a failure).
 */
static size_t round_trip_k(int k, const int32_t *v, uint32_t w, uint32_t h, const char *what)
{
    const coding *c = &codings[k];
    size_t cells = (size_t)w * h, cap = c->bound(cells), len = 0;
    uint8_t *buf = malloc(cap);
    int32_t *back = malloc(cells * sizeof *back);
    int rc = c->compress(v, w, h, buf, cap, &len);
    CHECK(rc == 0, "%s, %s: compress %d", what, c->name, rc);
    int drc = c->decompress(buf, len, w, h, back, cells);
    CHECK(drc == 0 && memcmp(back, v, cells * sizeof *v) == 0, "%s, %s: decoded values differ (%d)",
          what, c->name, drc);
    if (len > c->min_len) { /* cut short: refused, never a guess */
        CHECK(c->decompress(buf, len / 2, w, h, back, cells) == TERRAD_E_BAD_COMPRESSION,
              "%s, %s: half a payload decoded", what, c->name);
    }
    CHECK(c->decompress(buf, len, w, h, back, cells - 1) == TERRAD_E_TOO_LARGE || cells == 1,
          "%s, %s: out_cap under w * h accepted", what, c->name);
    free(buf);
    free(back);
    return rc == 0 && drc == 0 ? len : 0;
}

/* Both codings; returns encoding 2's length. */
static size_t round_trip(const int32_t *v, uint32_t w, uint32_t h, const char *what)
{
    round_trip_k(1, v, w, h, what);
    return round_trip_k(0, v, w, h, what);
}

/* Encoding 3 with the given limits decodes exactly whatever they are. */
static void slope_limits(const int32_t *v, uint32_t w, uint32_t h, uint32_t a, uint32_t b)
{
    size_t cells = (size_t)w * h, cap = terrad_rect_compress_slope_bound(cells), len = 0;
    uint8_t *buf = malloc(cap);
    int32_t *back = malloc(cells * sizeof *back);
    int rc = terrad_rect_compress_slope_ab(v, w, h, a, b, buf, cap, &len);
    CHECK(rc == 0 && terrad_rect_decompress_slope(buf, len, w, h, back, cells) == 0 &&
              memcmp(back, v, cells * sizeof *v) == 0,
          "slope limits %u, %u: not exact (%d)", a, b, rc);
    free(buf);
    free(back);
}

/* A sand pile: the lowest of cones of slope 367 a cell axially, 509
 * diagonally, with a rut at -800: most cells at a bound of their neighbours. */
static void sand_pile(int32_t *v, int w, int h)
{
    int cx[12], cy[12];
    int64_t c0[12];
    for (int k = 0; k < 12; k++) {
        cx[k] = (int)(next() % (uint32_t)w);
        cy[k] = (int)(next() % (uint32_t)h);
        c0[k] = -800 + (int64_t)(next() % 600);
    }
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int64_t best = INT64_MAX;
            for (int k = 0; k < 12; k++) {
                int dx = abs(x - cx[k]), dy = abs(y - cy[k]);
                int dg = dx < dy ? dx : dy, ax = (dx > dy ? dx : dy) - dg;
                int64_t z = c0[k] + 367 * ax + 509 * dg;
                best = z < best ? z : best;
            }
            v[y * w + x] = (int32_t)(best - ((x * 3 + y) % 4 == 0));
        }
}

int main(void)
{
    enum { W = 64, H = 64 };
    int32_t *v = malloc(W * H * sizeof *v);

    /* a crater's bowl and rim: smooth, so it codes small */
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int d2 = (x - 30) * (x - 30) + (y - 28) * (y - 28), r2 = 18 * 18;
            v[y * W + x] = d2 < r2       ? -(2000 * (r2 - d2) / r2)
                           : d2 < 4 * r2 ? (4 * r2 - d2) / 40
                                         : 0;
        }
    size_t smooth = round_trip(v, W, H, "crater");
    CHECK(smooth > 0 && smooth < W * H, "a crater took %zu bytes for %d cells", smooth, W * H);

    size_t crater3 = round_trip_k(1, v, W, H, "crater");
    CHECK(crater3 > smooth, "a crater: encoding 3 %zu bytes, encoding 2 %zu", crater3, smooth);

    sand_pile(v, W, H);
    size_t pile2 = round_trip(v, W, H, "sand pile"), pile3 = round_trip_k(1, v, W, H, "sand pile");
    CHECK(pile3 > 0 && pile3 < pile2, "a sand pile: encoding 3 %zu bytes, encoding 2 %zu", pile3,
          pile2);
    uint8_t chosen = 0, *best = malloc(terrad_rect_compress_slope_bound(W * H));
    size_t best_len = 0;
    CHECK(terrad_rect_compress_base_smaller(v, W, H, best, terrad_rect_compress_slope_bound(W * H),
                                            &best_len, &chosen) == 0 &&
              chosen == TERRAD_ENC_BASE_SLOPE && best_len == pile3,
          "the shorter of a sand pile: encoding %u, %zu bytes", chosen, best_len);
    /* the coder's limits: the pile's own slopes, each perturbed by one here and
     * there (a limit covers a difference and the one under it) */
    CHECK(terrad_rect_compress_slope(v, W, H, best, terrad_rect_compress_slope_bound(W * H),
                                     &best_len) == 0,
          "a sand pile in encoding 3");
    uint32_t got_a = best[0] | best[1] << 8 | best[2] << 16 | (uint32_t)best[3] << 24;
    uint32_t got_b = best[4] | best[5] << 8 | best[6] << 16 | (uint32_t)best[7] << 24;
    CHECK((got_a == 367 || got_a == 368) && (got_b == 509 || got_b == 510),
          "the coder chose the pile's limits 367 and 509 (or one over: %u, %u)", got_a, got_b);
    static const uint32_t limits[][2] = {
        {0, 0}, {1, 0}, {367, 509}, {UINT32_MAX, UINT32_MAX}, {1u << 31, 7}, {5, UINT32_MAX}};
    for (size_t k = 0; k < sizeof limits / sizeof limits[0]; k++)
        slope_limits(v, W, H, limits[k][0], limits[k][1]);

    for (int i = 0; i < W * H; i++) /* noise over the whole int32 range */
        v[i] = (int32_t)next();
    round_trip(v, W, H, "noise");
    for (size_t k = 0; k < sizeof limits / sizeof limits[0]; k++)
        slope_limits(v, W, H, limits[k][0], limits[k][1]);
    for (int i = 0; i < W * H; i++) /* the extremes, where every difference wraps */
        v[i] = (i * 7 + i / W) % 3 == 0 ? INT32_MIN : (i % 5 == 0 ? INT32_MAX : -1);
    round_trip(v, W, H, "extremes");
    round_trip(v, W * H, 1, "one row");
    round_trip(v, 1, W * H, "one column");
    round_trip(v, 1, 1, "one cell");
    for (size_t k = 0; k < sizeof limits / sizeof limits[0]; k++) {
        slope_limits(v, W, H, limits[k][0], limits[k][1]);
        slope_limits(v, 1, 1, limits[k][0], limits[k][1]);
    }
    CHECK(terrad_rect_compress_base_smaller(v, 8, 8, best, terrad_rect_compress_slope_bound(64),
                                            &best_len, &chosen) == 0,
          "the shorter of 8 x 8 extremes");
    free(best);

    /* a buffer smaller than the payload is refused, not overrun */
    uint8_t small[8];
    size_t len = 0;
    CHECK(terrad_rect_compress_base(v, W, H, small, sizeof small, &len) ==
              TERRAD_E_BUFFER_TOO_SMALL,
          "an 8-byte buffer took %d x %d noisy cells", W, H);
    uint8_t junk[4] = {1, 2, 3, 4};
    int32_t out[4];
    CHECK(terrad_rect_decompress_base(junk, sizeof junk, 2, 2, out, 4) == TERRAD_E_BAD_COMPRESSION,
          "a 4-byte payload decoded");
    CHECK(terrad_rect_compress_slope(v, W, H, small, sizeof small, &len) ==
              TERRAD_E_BUFFER_TOO_SMALL,
          "an 8-byte buffer took %d x %d noisy cells in encoding 3", W, H);
    uint8_t junk12[12] = {0};
    CHECK(terrad_rect_decompress_slope(junk12, sizeof junk12, 2, 2, out, 4) ==
              TERRAD_E_BAD_COMPRESSION,
          "a 12-byte slope payload decoded");

    /* the mirror: base + difference over the region's part of the tile */
    int32_t base[16 * 16], heights[16 * 16], diff[8 * 8];
    uint32_t versions[4];
    for (int i = 0; i < 16 * 16; i++)
        base[i] = 4000 + i;
    for (int i = 0; i < 8 * 8; i++)
        diff[i] = (int32_t)(next() % 200) - 100;
    uint8_t payload[1024];
    CHECK(terrad_rect_compress_base(diff, 8, 8, payload, sizeof payload, &len) == 0,
          "compress 8 x 8");
    terrad_rect r = {.x = 8,
                     .y = 0,
                     .w = 8,
                     .h = 8,
                     .new_version = 3,
                     .encoding = TERRAD_ENC_BASE,
                     .data_len = (uint32_t)len,
                     .data = payload};
    CHECK(terrad_rect_check(&r) == 0, "a base rectangle with base_version 0 is valid");
    terrad_mirror m;
    int32_t scratch[64];
    terrad_mirror_init(&m, 0, 0, 16, 16, 8, heights, versions);
    CHECK(terrad_mirror_apply(&m, NULL, &r, 1, scratch, 64) == TERRAD_E_BAD_VALUE,
          "a base rectangle applied to a mirror without a base");
    m.base = base;
    CHECK(terrad_mirror_apply(&m, NULL, &r, 1, scratch, 64) == 0 && versions[1] == 3,
          "a base rectangle applied");
    int same = 1;
    for (int y = 0; y < 8; y++)
        for (int x = 0; x < 8; x++)
            same &= heights[y * 16 + 8 + x] == base[y * 16 + 8 + x] + diff[y * 8 + x];
    CHECK(same, "the mirror holds base + difference");
    r.base_version = 2;
    CHECK(terrad_rect_check(&r) == TERRAD_E_BAD_VALUE, "a base rectangle with a base_version");
    free(v);
    return check_report();
}
