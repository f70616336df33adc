/*
 * fuzz_delta: libFuzzer target for what a client does with DELTA frames
 * (proto/c/terrad_proto.h): terrad_delta_decode, terrad_rect_decompress of
 * every rectangle and terrad_mirror_apply on a client mirror.
 *
 * Input: one byte choosing the mirror's region and tile size, then frames,
 * each a u32 little-endian length and that many bytes (a short last frame
 * takes what is left). Frames go to the same mirror one after the other, so
 * a snapshot followed by deltas (the mirror scenarios of
 * proto/vectors/vectors.json) reaches the delta path.
 *
 * Oracles besides the sanitizers: a frame that decodes re-encodes to the
 * same bytes; a payload that decompresses is refused under a smaller cell
 * limit and survives compress + decompress; a refused frame leaves the
 * mirror as it was, or (a payload failing part way) with every version 0.
 */
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

#define MAX_CELLS 65536

static terrad_rect rects[TERRAD_MAX_COUNT];
static int32_t scratch[MAX_CELLS], again[MAX_CELLS];
static uint8_t packed[MAX_CELLS * 4 + 1024];
static uint8_t reencoded[1 << 20];

static const struct {
    int32_t x, y;
    uint32_t w, h, tile;
} regions[4] = {
    {2, 2, 6, 5, 4},     /* vectors: subscribe_then_deltas */
    {-5, -3, 4, 4, 4},   /* vectors: negative_coordinates */
    {0, 0, 130, 70, 64}, /* a daemon-like tile size */
    {-40, -20, 80, 60, 16},
};

static int32_t heights[130 * 70], heights_before[130 * 70];
static uint32_t versions[64], versions_before[64];

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_frame(terrad_codec *codec, terrad_mirror *m, const uint8_t *f, size_t n)
{
    uint64_t tick = 0;
    size_t count = 0;
    int rc = terrad_delta_decode(f, n, &tick, rects, TERRAD_MAX_COUNT, &count);
    if (rc != TERRAD_OK)
        return;
    if (n <= sizeof reencoded) {
        size_t len = 0;
        if (terrad_delta_encode(reencoded, sizeof reencoded, &len, tick, rects, count) !=
                TERRAD_OK ||
            len != n || memcmp(reencoded, f, n) != 0)
            abort();
    }
    for (size_t i = 0; i < count; i++) {
        const terrad_rect *r = &rects[i];
        size_t cells = (size_t)r->w * r->h;
        int d = terrad_rect_decompress(codec, r->data, r->data_len, cells, scratch, MAX_CELLS);
        if (cells > MAX_CELLS) {
            if (d != TERRAD_E_TOO_LARGE)
                abort();
            continue;
        }
        if (d != TERRAD_OK)
            continue;
        if (terrad_rect_decompress(codec, r->data, r->data_len, cells, again, cells - 1) !=
            TERRAD_E_TOO_LARGE)
            abort();
        size_t len = 0;
        if (terrad_rect_compress(codec, scratch, cells, packed, sizeof packed, &len) != TERRAD_OK ||
            terrad_rect_decompress(codec, packed, len, cells, again, MAX_CELLS) != TERRAD_OK ||
            memcmp(scratch, again, cells * sizeof *again) != 0)
            abort();
    }

    size_t tiles = (size_t)m->tiles_x * m->tiles_y;
    size_t cells = (size_t)m->w * m->h;
    memcpy(heights_before, heights, cells * sizeof *heights);
    memcpy(versions_before, versions, tiles * sizeof *versions);
    rc = terrad_mirror_apply(m, codec, rects, count, scratch, MAX_CELLS);
    if (rc != TERRAD_OK) {
        int unchanged = memcmp(heights_before, heights, cells * sizeof *heights) == 0 &&
                        memcmp(versions_before, versions, tiles * sizeof *versions) == 0;
        int reset = 1;
        for (size_t t = 0; t < tiles; t++)
            reset &= versions[t] == 0;
        if (!unchanged && !reset)
            abort();
    }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    static terrad_codec *codec;
    if (!codec)
        codec = terrad_codec_new(1);
    if (size < 1)
        return 0;
    unsigned sel = data[0] & 3;
    terrad_mirror m;
    memset(heights, 0, sizeof heights);
    if (terrad_mirror_tile_count(regions[sel].x, regions[sel].y, regions[sel].w, regions[sel].h,
                                 regions[sel].tile) > 64 ||
        terrad_mirror_init(&m, regions[sel].x, regions[sel].y, regions[sel].w, regions[sel].h,
                           regions[sel].tile, heights, versions) != TERRAD_OK)
        abort();
    size_t pos = 1;
    for (int frames = 0; frames < 16 && size - pos >= 4; frames++) {
        uint32_t n = (uint32_t)data[pos] | (uint32_t)data[pos + 1] << 8 |
                     (uint32_t)data[pos + 2] << 16 | (uint32_t)data[pos + 3] << 24;
        pos += 4;
        if (n > size - pos)
            n = (uint32_t)(size - pos);
        check_frame(codec, &m, data + pos, n);
        pos += n;
    }
    return 0;
}
