/*
 * test_proto_base.c: base snapshot rectangles (proto/c/terrad_proto_base.c,
 * PROTOCOL.md "Base snapshots"): every coded rectangle decodes to exactly its
 * values — smooth craters, noise, the int32 extremes and their wrap-around,
 * one row, one column, one cell — a payload cut short is bad_compression,
 * a buffer under the bound is refused, and the mirror adds the base back
 * (and refuses a base rectangle when it holds no base).
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

/* Codes w x h values and decodes them back; returns the coded length (0 on a failure). */
static size_t round_trip(const int32_t *v, uint32_t w, uint32_t h, const char *what)
{
    size_t cells = (size_t)w * h, cap = terrad_rect_compress_base_bound(cells), len = 0;
    uint8_t *buf = malloc(cap);
    int32_t *back = malloc(cells * sizeof *back);
    int rc = terrad_rect_compress_base(v, w, h, buf, cap, &len);
    CHECK(rc == 0, "%s: compress %d", what, rc);
    int drc = terrad_rect_decompress_base(buf, len, w, h, back, cells);
    CHECK(drc == 0 && memcmp(back, v, cells * sizeof *v) == 0, "%s: decoded values differ (%d)",
          what, drc);
    if (len > 5) { /* cut short: refused, never a guess */
        CHECK(terrad_rect_decompress_base(buf, len / 2, w, h, back, cells) ==
                  TERRAD_E_BAD_COMPRESSION,
              "%s: half a payload decoded", what);
    }
    CHECK(terrad_rect_decompress_base(buf, len, w, h, back, cells - 1) == TERRAD_E_TOO_LARGE ||
              cells == 1,
          "%s: out_cap under w * h accepted", what);
    free(buf);
    free(back);
    return rc == 0 && drc == 0 ? len : 0;
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

    for (int i = 0; i < W * H; i++) /* noise over the whole int32 range */
        v[i] = (int32_t)next();
    round_trip(v, W, H, "noise");
    for (int i = 0; i < W * H; i++) /* the extremes, where every difference wraps */
        v[i] = (i * 7 + i / W) % 3 == 0 ? INT32_MIN : (i % 5 == 0 ? INT32_MAX : -1);
    round_trip(v, W, H, "extremes");
    round_trip(v, W * H, 1, "one row");
    round_trip(v, 1, W * H, "one column");
    round_trip(v, 1, 1, "one cell");

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
