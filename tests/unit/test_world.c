/*
 * test_world.c: the world's bookkeeping and its base terrain — refused
 * sizes, exact volumes, gather/scatter round trips, rectangle helpers, the
 * dune noise's determinism (a pinned checksum, so a change to the noise is a
 * deliberate act), and heightmap files (16-bit PNG, raw int16/int32) written
 * to /tmp and read back, including every way such a file can be wrong.
 */
#include "test_params.h"
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "world/world.h"
#include "check.h"

static int has(const error_text *e, const char *needle)
{
    return strstr(e->message, needle) != NULL;
}

/* Cell i (row-major) of a world, read through the public accessor. */
static int32_t cell(const world *w, int i)
{
    return world_height_at(w, i % w->width, i / w->width);
}

/* The whole world as one dense array (callers free it). */
static int32_t *dense(const world *w)
{
    int32_t *d = malloc((size_t)w->width * w->height * sizeof *d);
    if (!d)
        exit(2);
    world_gather_window(w, (world_rect){0, 0, w->width, w->height}, d);
    return d;
}

static void temp_path(char *out, size_t size, const char *suffix)
{
    char tmpl[] = "/tmp/terrad_test_world_XXXXXX";
    int fd = mkstemp(tmpl);
    if (fd < 0) {
        perror("mkstemp");
        exit(2);
    }
    close(fd);
    unlink(tmpl);
    snprintf(out, size, "%s%s", tmpl, suffix);
}

static void test_init(void)
{
    world w;
    error_text e = {{0}};
    CHECK(world_init(&w, 0, 10, 1, 10000, 0, &e) != 0 && has(&e, "world.width"),
          "width 0 refused: %s", e.message);
    CHECK(world_init(&w, 10, WORLD_SIDE_MAX + 1, 1, 10000, 0, &e) != 0 && has(&e, "world.height"),
          "height above WORLD_SIDE_MAX refused: %s", e.message);
    CHECK(world_init(&w, 65536, 65536, 1, 10000, 0, &e) == 0 &&
              world_resident_bytes(&w) < (8u << 20),
          "65536^2 cells fit: only the tile table is allocated (%llu bytes)",
          (unsigned long long)world_resident_bytes(&w));
    world_free(&w);
    CHECK(world_init_tiled(&w, 65536, 65536, 1, 10000, 0, 16, &e) != 0 &&
              has(&e, "world.tile_cells"),
          "a tile table too large refused: %s", e.message);
    CHECK(world_init_tiled(&w, 100, 100, 1, 10000, 0, 48, &e) != 0 && has(&e, "world.tile_cells"),
          "tile_cells not a power of two refused: %s", e.message);
    CHECK(world_init(&w, 10, 10, NAN, 10000, 0, &e) != 0 && has(&e, "world.cell_size_m"),
          "NaN cell size refused: %s", e.message);
    CHECK(world_init(&w, 10, 10, 0.0, 10000, 0, &e) != 0 && has(&e, "world.cell_size_m"),
          "zero cell size refused: %s", e.message);
    CHECK(world_init(&w, 10, 10, 1000.5, 10000, 0, &e) != 0, "cell size > 1000 refused");
    CHECK(world_init(&w, 10, 10, INFINITY, 10000, 0, &e) != 0, "infinite cell size refused");
    CHECK(world_init(&w, 10, 10, 1, 0, 0, &e) != 0 && has(&e, "world.units_per_m"),
          "units_per_m 0 refused: %s", e.message);
    CHECK(world_init(&w, 10, 10, 1, 1000001, 0, &e) != 0, "units_per_m > 1e6 refused");
    CHECK(world_init(&w, 10, 10, 1, 10000, WORLD_HEIGHT_MAX + 1, &e) != 0 && has(&e, "world.floor"),
          "floor above WORLD_HEIGHT_MAX refused: %s", e.message);
    CHECK(world_init(&w, 10, 10, 1, 10000, WORLD_HEIGHT_MIN - 1, &e) != 0,
          "floor below WORLD_HEIGHT_MIN refused");
    int ok = world_init(&w, 7, 5, 0.25, 10000, 0, &e) == 0;
    CHECK(ok && w.width == 7 && w.height == 5 && w.store, "7 x 5 world set up");
    int zero = 1;
    for (int i = 0; ok && i < 35; i++)
        zero &= cell(&w, i) == 0;
    CHECK(ok && zero && world_volume(&w) == 0, "heights start at 0");
    world_free(&w);
    CHECK(w.store == NULL, "world_free clears the pointer");
    CHECK(world_init(&w, 1, 1, 1e-3, 1, WORLD_HEIGHT_MIN, &e) == 0, "1 x 1 world is fine");
    world_free(&w);
}

static void test_flat_and_limits(void)
{
    world w;
    error_text e = {{0}};
    world_init(&w, 16, 9, 0.05, 10000, 0, &e);
    world_base_spec s = {.kind = WORLD_BASE_FLAT, .height_m = 0.4};
    CHECK(world_generate_base(&w, &s, &e) == 0 && cell(&w, 0) == 4000 && cell(&w, 143) == 4000,
          "flat 0.4 m is 4000 units everywhere");
    CHECK(world_volume(&w) == 16 * 9 * 4000LL, "world volume is the exact sum");
    s.height_m = 0.12345;
    world_generate_base(&w, &s, &e);
    CHECK(cell(&w, 5) == 1235, "heights are rounded to nearest (0.12345 m -> %d)", cell(&w, 5));
    s.height_m = 60000.0; /* 6e8 units > 2^29 */
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, "terrain.height_m") &&
              has(&e, "600000000") && has(&e, "536870912"),
          "too high flat terrain refused with value and limit: %s", e.message);
    s.height_m = NAN;
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, "terrain.height_m"),
          "NaN flat height refused: %s", e.message);
    s.height_m = -0.1;
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, "floor"),
          "terrain below the floor refused: %s", e.message);
    world_free(&w);

    world_init(&w, 4, 4, 0.05, 10000, -5000, &e);
    s.height_m = -0.4;
    CHECK(world_generate_base(&w, &s, &e) == 0 && cell(&w, 0) == -4000,
          "negative terrain above a negative floor is fine");
    world_free(&w);
}

static uint64_t fnv1a(const int32_t *h, size_t n)
{
    uint64_t x = 1469598103934665603ull;
    for (size_t i = 0; i < n; i++) {
        uint32_t v = (uint32_t)h[i];
        for (int b = 0; b < 4; b++) {
            x ^= (v >> (8 * b)) & 0xff;
            x *= 1099511628211ull;
        }
    }
    return x;
}

static void test_dunes(void)
{
    world a, b, c;
    error_text e = {{0}};
    world_init(&a, 64, 48, 0.05, 10000, 0, &e);
    world_init(&b, 128, 96, 0.05, 10000, 0, &e);
    world_init(&c, 64, 48, 0.05, 10000, 0, &e);
    world_base_spec s = {.kind = WORLD_BASE_DUNES,
                         .min_height_m = 0.3,
                         .max_height_m = 0.7,
                         .wavelength_m = 1.5,
                         .octaves = 4,
                         .seed = 7};
    CHECK(world_generate_base(&a, &s, &e) == 0, "dunes generate: %s", e.message);
    world_generate_base(&b, &s, &e);
    int32_t *da = dense(&a), *db = dense(&b);
    int32_t lo = INT32_MAX, hi = INT32_MIN;
    int same_in_bigger = 1;
    for (int y = 0; y < 48; y++)
        for (int x = 0; x < 64; x++) {
            int32_t v = da[y * 64 + x];
            lo = v < lo ? v : lo;
            hi = v > hi ? v : hi;
            same_in_bigger &= v == db[y * 128 + x];
        }
    CHECK(lo >= 3000 && hi <= 7000, "dunes stay in [min, max] (%d..%d)", lo, hi);
    CHECK(hi - lo > 1200, "dunes actually vary (spread %d units)", hi - lo);
    CHECK(same_in_bigger, "a cell's height does not depend on the world's extent");
    world_generate_base(&c, &s, &e);
    int32_t *dc = dense(&c);
    CHECK(memcmp(da, dc, 64 * 48 * 4) == 0, "same seed, same heights");
    uint64_t sum = fnv1a(da, 64 * 48);
    /* pinned: the noise must give these heights on every machine and compiler;
     * change the constant only when the dunes are meant to change */
    CHECK(sum == 0xa5de59410c17e554ull, "dunes checksum pinned (got %016llx)",
          (unsigned long long)sum);
    s.seed = 8;
    world_generate_base(&c, &s, &e);
    free(dc);
    dc = dense(&c);
    CHECK(memcmp(da, dc, 64 * 48 * 4) != 0, "another seed, other heights");
    free(dc);
    s.octaves = 1;
    world_generate_base(&c, &s, &e);
    int smooth = 1;
    for (int i = 1; i < 64; i++)
        smooth &= abs(cell(&c, i) - cell(&c, i - 1)) < 400;
    CHECK(smooth, "one octave is smooth from cell to cell");

    world_base_spec bad = s;
    bad.max_height_m = 0.2;
    CHECK(world_generate_base(&c, &bad, &e) != 0 && has(&e, "terrain.max_height_m"),
          "max < min refused: %s", e.message);
    bad = s;
    bad.octaves = 0;
    CHECK(world_generate_base(&c, &bad, &e) != 0 && has(&e, "terrain.octaves"),
          "octaves 0 refused: %s", e.message);
    bad = s;
    bad.wavelength_m = 0;
    CHECK(world_generate_base(&c, &bad, &e) != 0 && has(&e, "terrain.wavelength_m"),
          "wavelength 0 refused: %s", e.message);
    bad = s;
    bad.max_height_m = 1e5;
    CHECK(world_generate_base(&c, &bad, &e) != 0 && has(&e, "terrain.max_height_m") &&
              has(&e, "536870912"),
          "dunes above WORLD_HEIGHT_MAX refused: %s", e.message);
    free(da);
    free(db);
    world_free(&a);
    world_free(&b);
    world_free(&c);
}

static void test_rects(void)
{
    world w;
    error_text e = {{0}};
    world_init(&w, 10, 8, 1, 10000, 0, &e);
    for (int i = 0; i < 80; i++)
        world_set_height(&w, i % 10, i / 10, i * 3 - 50);
    world_rect r = {-3, -2, 5, 4};
    CHECK(world_clip_rect(&w, &r) && r.x == 0 && r.y == 0 && r.w == 2 && r.h == 2,
          "clip at the low corner -> %d,%d %dx%d", r.x, r.y, r.w, r.h);
    r = (world_rect){8, 6, 100, 100};
    CHECK(world_clip_rect(&w, &r) && r.w == 2 && r.h == 2, "clip at the high corner");
    r = (world_rect){10, 0, 3, 3};
    CHECK(!world_clip_rect(&w, &r) && r.w == 0, "a rectangle beside the world clips to nothing");
    r = (world_rect){2, 2, 0, 3};
    CHECK(!world_clip_rect(&w, &r), "an empty rectangle clips to nothing");
    r = (world_rect){2147483000, 0, 2000, 3};
    CHECK(!world_clip_rect(&w, &r), "a rectangle near INT_MAX does not wrap");

    int64_t expect = 0;
    for (int y = 1; y < 4; y++)
        for (int x = 2; x < 7; x++)
            expect += cell(&w, y * 10 + x);
    CHECK(world_rect_volume(&w, (world_rect){2, 1, 5, 3}) == expect, "rect volume");
    CHECK(world_rect_volume(&w, (world_rect){-5, -5, 100, 100}) == world_volume(&w),
          "rect volume clips to the world");

    int32_t buf[15], lo, hi;
    world_rect g = {2, 1, 5, 3};
    world_gather_window(&w, g, buf);
    CHECK(buf[0] == cell(&w, 12) && buf[14] == cell(&w, 36), "gather is row-major");
    world_rect_height_range(&w, g, &lo, &hi);
    CHECK(lo == cell(&w, 12) && hi == cell(&w, 36), "height range of a window");
    int64_t before = world_volume(&w);
    buf[0] += 5; /* moves material around inside the window, net 0 */
    buf[14] -= 5;
    buf[7] += 3;
    buf[3] -= 3;
    world_scatter_window(&w, g, buf);
    int32_t back[15];
    world_gather_window(&w, g, back);
    CHECK(memcmp(buf, back, sizeof buf) == 0, "scatter then gather round-trips");
    CHECK(world_volume(&w) == before, "volume-neutral edit keeps the exact sum");
    CHECK(cell(&w, 11) == 11 * 3 - 50 && cell(&w, 37) == 37 * 3 - 50,
          "scatter leaves cells outside the window alone");

    CHECK(world_rects_overlap((world_rect){0, 0, 2, 2}, (world_rect){1, 1, 2, 2}),
          "overlapping rectangles");
    CHECK(!world_rects_overlap((world_rect){0, 0, 2, 2}, (world_rect){2, 0, 2, 2}),
          "touching rectangles do not overlap");
    CHECK(!world_rects_overlap((world_rect){0, 0, 0, 2}, (world_rect){0, 0, 2, 2}),
          "an empty rectangle overlaps nothing");
    world_rect u = world_rect_union((world_rect){0, 0, 2, 2}, (world_rect){5, -1, 1, 1});
    CHECK(u.x == 0 && u.y == -1 && u.w == 6 && u.h == 3, "union");
    u = world_rect_union((world_rect){0, 0, 0, 0}, (world_rect){5, 4, 1, 2});
    CHECK(u.x == 5 && u.y == 4 && u.w == 1 && u.h == 2, "union with an empty rectangle");

    /* a big world's volume does not overflow 32 bits */
    world big;
    world_init(&big, 1024, 1024, 1, 10000, 0, &e);
    world_base_spec s = {.kind = WORLD_BASE_FLAT, .height_m = 50000};
    world_generate_base(&big, &s, &e);
    CHECK(world_volume(&big) == 1024LL * 1024 * 500000000, "volume sums in int64");
    world_free(&big);
    world_free(&w);
}

/* An 8-bit or colour PNG, which png16_read must refuse. */
static void write_png_raw(const char *path, int depth, int colour, int w, int h)
{
    FILE *f = fopen(path, "wb");
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png_create_info_struct(png);
    png_init_io(png, f);
    png_set_IHDR(png, info, w, h, depth, colour, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
                 PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    unsigned char row[64 * 8] = {0};
    for (int y = 0; y < h; y++)
        png_write_row(png, row);
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    fclose(f);
}

/* png16_encode's rows: a ramp. */
static void ramp_row(void *arg, int y, uint16_t *samples)
{
    for (int x = 0; x < *(const int *)arg; x++)
        samples[x] = (uint16_t)(y * 100 + x);
}

/* png16_encode's errors leave its output as on entry, nothing held: one
 * refused before libpng starts (a side out of range), one from inside libpng
 * after its first bytes were written (zlib refuses level 10 when the first
 * row is compressed, after the signature and IHDR grew the buffer). */
static void test_png16_encode_errors(void)
{
    int width = 8;
    error_text e = {{0}};
    png16_memory m = {(unsigned char *)&width, 99, 99}; /* the caller's garbage */
    CHECK(png16_encode(0, 4, 1, ramp_row, &width, "img", &m, &e) != 0 && has(&e, "img") &&
              m.data == NULL && m.len == 0 && m.cap == 0,
          "a 0 x 4 image refused, out zeroed (len %zu cap %lld): %s", m.len, (long long)m.cap,
          e.message);
    CHECK(png16_encode(width, 4, 10, ramp_row, &width, "img", &m, &e) != 0 && has(&e, "img") &&
              has(&e, "cannot write PNG") && m.data == NULL && m.len == 0 && m.cap == 0,
          "a libpng error (level 10) leaves out zeroed (len %zu cap %lld): %s", m.len,
          (long long)m.cap, e.message);
    /* and the same struct serves the next image */
    CHECK(png16_encode(width, 4, 1, ramp_row, &width, "img", &m, &e) == 0 && m.data && m.len > 8 &&
              (int64_t)m.len <= m.cap,
          "then an image encodes into it (%zu bytes)", m.len);
    int back_w = 0, back_h = 0;
    uint16_t *back = NULL;
    CHECK(m.data && png16_decode(m.data, m.len, "img", &back_w, &back_h, &back, &e) == 0 &&
              back_w == width && back_h == 4 && back[3 * width + 5] == 305,
          "and decodes to its rows");
    free(back);
    free(m.data);
}

static void test_png16(void)
{
    char path[256];
    temp_path(path, sizeof path, ".png");
    error_text e = {{0}};
    uint16_t px[6 * 4];
    for (int i = 0; i < 24; i++)
        px[i] = (uint16_t)(i * 2731 + (i == 23 ? 3 : 0)); /* up to 65 k, both bytes used */
    px[0] = 65535;
    CHECK(png16_write(path, 6, 4, px, &e) == 0, "png16 written: %s", e.message);
    int w = 0, h = 0;
    uint16_t *back = NULL;
    CHECK(png16_read(path, &w, &h, &back, &e) == 0 && w == 6 && h == 4, "png16 read back");
    CHECK(back && memcmp(px, back, sizeof px) == 0, "png16 samples round-trip exactly");
    free(back);

    world wd;
    world_init(&wd, 6, 4, 0.1, 10000, -1000000, &e);
    world_base_spec s = {
        .kind = WORLD_BASE_PNG16, .value_scale_units = 2.0, .value_offset_units = -1000.0};
    snprintf(s.path, sizeof s.path, "%s", path);
    CHECK(world_generate_base(&wd, &s, &e) == 0 && cell(&wd, 0) == 65535 * 2 - 1000 &&
              cell(&wd, 5) == 5 * 2731 * 2 - 1000,
          "png16 base: value * scale + offset");
    world_free(&wd);

    world_init(&wd, 5, 4, 0.1, 10000, 0, &e);
    CHECK(world_generate_base(&wd, &s, &e) != 0 && has(&e, path) && has(&e, "6 x 4") &&
              has(&e, "5 x 4"),
          "png16 of the wrong size refused: %s", e.message);
    world_free(&wd);

    world_init(&wd, 6, 4, 0.1, 10000, 0, &e);
    s.value_offset_units = -1e6; /* everything below the floor */
    CHECK(world_generate_base(&wd, &s, &e) != 0 && has(&e, path) && has(&e, "below"),
          "png16 heights below the floor refused: %s", e.message);
    world_free(&wd);

    write_png_raw(path, 8, PNG_COLOR_TYPE_GRAY, 6, 4);
    CHECK(png16_read(path, &w, &h, &back, &e) != 0 && has(&e, path) && has(&e, "16-bit"),
          "8-bit PNG refused: %s", e.message);
    write_png_raw(path, 16, PNG_COLOR_TYPE_RGB, 6, 4);
    CHECK(png16_read(path, &w, &h, &back, &e) != 0 && has(&e, "colour"), "colour PNG refused: %s",
          e.message);
    FILE *f = fopen(path, "wb");
    fputs("not a png at all", f);
    fclose(f);
    CHECK(png16_read(path, &w, &h, &back, &e) != 0 && has(&e, path), "garbage refused: %s",
          e.message);
    /* a truncated real PNG */
    png16_write(path, 6, 4, px, &e);
    if (truncate(path, 60) != 0)
        perror("truncate");
    CHECK(png16_read(path, &w, &h, &back, &e) != 0 && has(&e, path), "truncated PNG refused: %s",
          e.message);
    unlink(path);
    CHECK(png16_read("/nonexistent/terrad.png", &w, &h, &back, &e) != 0 &&
              has(&e, "/nonexistent/terrad.png"),
          "missing file named: %s", e.message);
}

static void test_raw(void)
{
    char path[256];
    temp_path(path, sizeof path, ".raw");
    error_text e = {{0}};
    /* int16 little-endian, negative values included */
    const int16_t v16[6] = {0, 1, -1, 32767, -32768, 1234};
    unsigned char b16[12];
    for (int i = 0; i < 6; i++) {
        b16[2 * i] = (unsigned char)((uint16_t)v16[i] & 0xff);
        b16[2 * i + 1] = (unsigned char)((uint16_t)v16[i] >> 8);
    }
    FILE *f = fopen(path, "wb");
    fwrite(b16, 1, sizeof b16, f);
    fclose(f);
    world w;
    world_init(&w, 3, 2, 0.1, 10000, WORLD_HEIGHT_MIN, &e);
    world_base_spec s = {.kind = WORLD_BASE_RAW_INT16, .value_scale_units = 1.0};
    snprintf(s.path, sizeof s.path, "%s", path);
    int ok = world_generate_base(&w, &s, &e) == 0;
    int same = ok;
    for (int i = 0; ok && i < 6; i++)
        same &= cell(&w, i) == v16[i];
    CHECK(same, "raw int16 round-trips (little-endian, signed)");
    world_free(&w);

    world_init(&w, 4, 2, 0.1, 10000, WORLD_HEIGHT_MIN, &e);
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, path) && has(&e, "12 bytes") &&
              has(&e, "16"),
          "raw int16 of the wrong size refused: %s", e.message);
    world_free(&w);

    const int32_t v32[4] = {-7, 100000, WORLD_HEIGHT_MAX, WORLD_HEIGHT_MIN};
    f = fopen(path, "wb");
    for (int i = 0; i < 4; i++)
        for (int b = 0; b < 4; b++)
            fputc((int)(((uint32_t)v32[i] >> (8 * b)) & 0xff), f);
    fclose(f);
    world_init(&w, 2, 2, 0.1, 10000, WORLD_HEIGHT_MIN, &e);
    s.kind = WORLD_BASE_RAW_INT32;
    ok = world_generate_base(&w, &s, &e) == 0;
    int32_t *dw = ok ? dense(&w) : NULL;
    CHECK(ok && memcmp(dw, v32, sizeof v32) == 0, "raw int32 round-trips, extremes included");
    free(dw);
    s.value_offset_units = 1;
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, path) && has(&e, "536870912") &&
              has(&e, "(0, 1)"),
          "raw int32 above WORLD_HEIGHT_MAX refused, not wrapped: %s", e.message);
    s.value_offset_units = 0;
    s.value_scale_units = NAN;
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, "terrain.scale_units"),
          "NaN scale refused: %s", e.message);
    world_free(&w);
    unlink(path);
    s.value_scale_units = 1;
    world_init(&w, 2, 2, 0.1, 10000, 0, &e);
    CHECK(world_generate_base(&w, &s, &e) != 0 && has(&e, path), "missing raw file named: %s",
          e.message);
    world_free(&w);
}

typedef struct stored_list {
    int count, last_tx, last_ty;
    uint64_t generation_sum;
} stored_list;

static void note_stored(void *ctx, int tx, int ty, world_rect cells, uint64_t generation)
{
    (void)cells;
    stored_list *l = ctx;
    l->count++;
    l->last_tx = tx;
    l->last_ty = ty;
    l->generation_sum += generation;
}

/* Tiled and one-tile worlds agree on every read after the same writes:
 * random rectangles (many straddling tile edges and corners) are scattered
 * into both and everything observable is compared. */
static void test_tiled_equals_dense(world_base_kind kind)
{
    error_text e = {{0}};
    world tiled, whole;
    int W = 300, H = 200;
    CHECK(world_init_tiled(&tiled, W, H, 0.05, 10000, 0, 16, &e) == 0, "tiled world: %s",
          e.message);
    CHECK(world_init_tiled(&whole, W, H, 0.05, 10000, 0, 512, &e) == 0, "one-tile world: %s",
          e.message);
    CHECK(tiled.tiles_x == 19 && tiled.tiles_y == 13 && whole.tiles_x == 1 && whole.tiles_y == 1,
          "tile counts %dx%d and %dx%d", tiled.tiles_x, tiled.tiles_y, whole.tiles_x,
          whole.tiles_y);
    world_base_spec s = {.kind = kind, .height_m = 0.4};
    if (kind == WORLD_BASE_DUNES)
        s = (world_base_spec){.kind = WORLD_BASE_DUNES,
                              .min_height_m = 0.3,
                              .max_height_m = 0.7,
                              .wavelength_m = 1.5,
                              .octaves = 4,
                              .seed = 11};
    CHECK(world_generate_base(&tiled, &s, &e) == 0 && world_generate_base(&whole, &s, &e) == 0,
          "base: %s", e.message);
    CHECK(world_stored_tiles(&tiled) == 0, "a fresh tiled world stores no tile");
    int32_t *a = dense(&tiled), *b = dense(&whole);
    CHECK(memcmp(a, b, (size_t)W * H * 4) == 0,
          "kind %d: the base of every tile equals the dense base", (int)kind);
    CHECK(world_stored_tiles(&tiled) == 0, "reading does not store tiles");
    CHECK(world_volume(&tiled) == world_volume(&whole), "same base volume");
    free(a);
    free(b);

    uint32_t rng = 12345;
    int32_t *buf = malloc((size_t)W * H * sizeof *buf), *buf2 = malloc((size_t)W * H * 4);
    int same = 1, same_volume = 1, same_range = 1, same_rect_volume = 1, same_reach = 1;
    CHECK(!world_rect_reaches(&tiled, (world_rect){3, 3, 0, 5}, INT32_MIN),
          "an empty rectangle reaches no level");
    for (int round = 0; round < 200; round++) {
        world_rect r = {(int)(test_next_random(&rng) % W), (int)(test_next_random(&rng) % H),
                        1 + (int)(test_next_random(&rng) % 40),
                        1 + (int)(test_next_random(&rng) % 40)};
        world_clip_rect(&tiled, &r);
        world_gather_window(&tiled, r, buf);
        world_gather_window(&whole, r, buf2);
        same &= memcmp(buf, buf2, (size_t)r.w * r.h * 4) == 0;
        for (int i = 0; i < r.w * r.h; i++)
            buf[i] += (int32_t)(test_next_random(&rng) % 2001) - 1000;
        world_scatter_window(&tiled, r, buf);
        world_scatter_window(&whole, r, buf);
        same_volume &= world_volume(&tiled) == world_volume(&whole);
        world_rect q = {(int)(test_next_random(&rng) % W) - 10,
                        (int)(test_next_random(&rng) % H) - 10, 60, 50};
        int32_t lo1, hi1, lo2, hi2;
        world_rect qc = q;
        world_clip_rect(&tiled, &qc);
        world_rect_height_range(&tiled, qc, &lo1, &hi1);
        world_rect_height_range(&whole, qc, &lo2, &hi2);
        same_range &= lo1 == lo2 && hi1 == hi2;
        /* reaches a level iff the greatest height does: at, just above and
         * below it, and a level every cell passes */
        for (int k = 0; k < 2; k++) {
            const world *v = k ? &whole : &tiled;
            same_reach &= world_rect_reaches(v, qc, (int64_t)hi1) &&
                          !world_rect_reaches(v, qc, (int64_t)hi1 + 1) &&
                          world_rect_reaches(v, qc, (int64_t)hi1 - 1) &&
                          world_rect_reaches(v, qc, (int64_t)lo1) &&
                          world_rect_reaches(v, qc, (int64_t)INT32_MIN - 1);
        }
        same_rect_volume &= world_rect_volume(&tiled, q) == world_rect_volume(&whole, q);
    }
    a = dense(&tiled);
    b = dense(&whole);
    CHECK(same && memcmp(a, b, (size_t)W * H * 4) == 0,
          "kind %d: 200 random scatters across tile edges: tiled == one tile, bit for bit",
          (int)kind);
    CHECK(same_volume && same_range && same_rect_volume,
          "volume, rect volume and height range agree after every scatter");
    CHECK(same_reach, "world_rect_reaches a level iff the height range's greatest does");
    int64_t sum = 0;
    for (int i = 0; i < W * H; i++)
        sum += a[i];
    CHECK(world_volume(&tiled) == sum, "tracked volume == Σh of the cells (%lld vs %lld)",
          (long long)world_volume(&tiled), (long long)sum);
    free(a);
    free(b);
    free(buf);
    free(buf2);
    world_free(&tiled);
    world_free(&whole);
}

/* A window straddling a tile corner stores exactly the four tiles it
 * touches, bumps their generations, and leaves the rest of a big world
 * unallocated. */
static void test_sparse(void)
{
    error_text e = {{0}};
    world w;
    CHECK(world_init_tiled(&w, 16384, 16384, 0.05, 10000, 0, 64, &e) == 0, "16384^2 world: %s",
          e.message);
    world_base_spec s = {.kind = WORLD_BASE_DUNES,
                         .min_height_m = 0.3,
                         .max_height_m = 0.7,
                         .wavelength_m = 1.5,
                         .octaves = 4,
                         .seed = 7};
    CHECK(world_generate_base(&w, &s, &e) == 0, "dunes base on a 16384^2 world");
    uint64_t empty = world_resident_bytes(&w);
    CHECK(empty < (16u << 20), "untouched 16384^2 world holds %llu bytes, not 1 GiB",
          (unsigned long long)empty);
    world_rect r = {64 * 100 - 5, 64 * 200 - 7, 12, 14}; /* around the corner of tile (100, 200) */
    int32_t buf[12 * 14], back[12 * 14];
    world_gather_window(&w, r, buf);
    CHECK(world_stored_tiles(&w) == 0, "gather stores nothing");
    /* (world_volume of a 16384^2 dune world would walk all its noise once,
     * about a minute here: the rectangle's volume says the same) */
    int64_t before = world_rect_volume(&w, r);
    for (int i = 0; i < 12 * 14; i++)
        buf[i] += (i & 1) ? 50 : -50; /* volume-neutral */
    world_scatter_window(&w, r, buf);
    CHECK(world_stored_tiles(&w) == 4, "a window over a tile corner stores 4 tiles (%zu)",
          world_stored_tiles(&w));
    uint64_t after = world_resident_bytes(&w);
    CHECK(after - empty <= 4u * 64 * 64 * 4 + 64u * 64 * 64 * 4,
          "resident bytes grow by the stored tiles (plus the clean-tile cache): %llu",
          (unsigned long long)(after - empty));
    world_gather_window(&w, r, back);
    CHECK(memcmp(buf, back, sizeof buf) == 0, "scatter then gather across the corner round-trips");
    CHECK(world_rect_volume(&w, r) == before, "volume exact after a neutral edit over 4 tiles");
    CHECK(world_tile_generation(&w, 99, 199) == 1 && world_tile_generation(&w, 100, 200) == 1 &&
              world_tile_generation(&w, 101, 200) == 0 && world_tile_generation(&w, -1, 0) == 0,
          "generations: written tiles 1, others 0");
    world_set_height(&w, 64 * 100, 64 * 200, 4242);
    CHECK(world_height_at(&w, 64 * 100, 64 * 200) == 4242 &&
              world_tile_generation(&w, 100, 200) == 2,
          "world_set_height writes and bumps the generation");
    stored_list l = {0, -1, -1, 0};
    world_for_each_stored_tile(&w, note_stored, &l);
    CHECK(l.count == 4 && l.last_tx == 100 && l.last_ty == 200 && l.generation_sum == 5,
          "iteration visits the 4 stored tiles in row-major order (%d, last %d,%d, gens %llu)",
          l.count, l.last_tx, l.last_ty, (unsigned long long)l.generation_sum);
    world_rect t = world_tile_rect(&w, 255, 255);
    CHECK(t.x == 16320 && t.w == 64 && t.h == 64, "tile rect");
    CHECK(world_generate_base(&w, &s, &e) == 0 && world_stored_tiles(&w) == 0 &&
              world_tile_generation(&w, 100, 200) == 0,
          "a new base drops every stored tile");
    world_free(&w);

    /* a flat 65536^2 world: closed-form volume, tracked exactly through edits */
    CHECK(world_init(&w, 65536, 65536, 0.05, 10000, 0, &e) == 0, "65536^2 world");
    world_base_spec flat = {.kind = WORLD_BASE_FLAT, .height_m = 0.4};
    world_generate_base(&w, &flat, &e);
    CHECK(world_volume(&w) == 4000LL * 65536 * 65536, "flat volume in closed form");
    world_rect edge = {65536 - 3, 65536 - 2, 3, 2};
    int32_t six[6] = {1, 2, 3, 4, 5, 6};
    world_scatter_window(&w, edge, six);
    CHECK(world_volume(&w) == 4000LL * 65536 * 65536 + 21 - 6 * 4000 &&
              world_stored_tiles(&w) == 1 && world_height_at(&w, 65535, 65535) == 6,
          "an edit in the far corner: exact volume, one tile stored");
    world_free(&w);

    /* partial edge tiles: 100 x 70 in tiles of 64 */
    CHECK(world_init_tiled(&w, 100, 70, 0.05, 10000, 0, 64, &e) == 0, "100x70 world");
    t = world_tile_rect(&w, 1, 1);
    CHECK(t.x == 64 && t.y == 64 && t.w == 36 && t.h == 6, "edge tile clipped to 36x6");
    world_set_height(&w, 99, 69, -7);
    CHECK(world_height_at(&w, 99, 69) == -7 && world_volume(&w) == -7, "last cell of an edge tile");
    world_free(&w);
}

int main(void)
{
    test_init();
    test_flat_and_limits();
    test_dunes();
    test_rects();
    test_png16();
    test_png16_encode_errors();
    test_raw();
    test_tiled_equals_dense(WORLD_BASE_FLAT);
    test_tiled_equals_dense(WORLD_BASE_DUNES);
    test_sparse();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
