/*
 * png16.c: 16-bit greyscale PNG in and out (libpng). Heightmap base terrain
 * comes in this way before the first tick, and exports go out this way. Only
 * 16-bit greyscale is accepted: an 8-bit or colour image would silently lose
 * resolution or mix channels into heights, so it is refused with a reason.
 * Samples are converted from PNG's big-endian order by hand, so the code does
 * not depend on the host's byte order. png16_encode is the one writer: the
 * export's files (png16_write) and /v1/heights?format=png16 (http_png.c, off
 * the tick on an HTTP thread) both go through it.
 */
#include "world/world.h"

#include <errno.h>
#include <png.h>
#include <setjmp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct png_error_context {
    char message[200];
} png_error_context;

static void png_error_cb(png_structp png, png_const_charp msg)
{
    png_error_context *ctx = png_get_error_ptr(png);
    snprintf(ctx->message, sizeof ctx->message, "%s", msg);
    png_longjmp(png, 1);
}

static void png_warning_cb(png_structp png, png_const_charp msg)
{
    (void)png;
    (void)msg; /* warnings (odd chunks, gamma) do not change the samples */
}

/* libpng's read or write struct (errors into ctx, warnings ignored) and its
 * info, the reader's and the writer's alike; NULL with err set when out of
 * memory. png_end frees what it made. */
static void png_end(int writing, png_structp *png, png_infop *info)
{
    if (writing)
        png_destroy_write_struct(png, info);
    else
        png_destroy_read_struct(png, info, NULL);
}

static png_structp png_begin(int writing, png_error_context *ctx, png_infop *info, const char *name,
                             error_text *err)
{
    png_structp png =
        writing ? png_create_write_struct(PNG_LIBPNG_VER_STRING, ctx, png_error_cb, png_warning_cb)
                : png_create_read_struct(PNG_LIBPNG_VER_STRING, ctx, png_error_cb, png_warning_cb);
    *info = png ? png_create_info_struct(png) : NULL;
    if (!*info) {
        error_set(err, "%s: out of memory", name);
        png_end(writing, &png, NULL);
        return NULL;
    }
    return png;
}

/* The file, read whole (file_read_all), as libpng's input. */
typedef struct png_source {
    const uint8_t *data;
    size_t len, at;
} png_source;

static void png_read_cb(png_structp png, png_bytep out, png_size_t n)
{
    png_source *src = png_get_io_ptr(png);
    if (n > src->len - src->at)
        png_error(png, "truncated file");
    memcpy(out, src->data + src->at, n);
    src->at += n;
}

int png16_decode(const uint8_t *file, size_t file_len, const char *path, int *width, int *height,
                 uint16_t **pixels, error_text *err)
{
    *pixels = NULL;
    if (file_len < 8 || png_sig_cmp(file, 0, 8) != 0) {
        error_set(err, "%s: not a PNG file", path);
        return -1;
    }
    png_source src = {file, file_len, 8};
    png_error_context ctx = {""};
    png_infop info;
    png_structp png = png_begin(0, &ctx, &info, path, err);
    if (!png)
        return -1;
    /* volatile: these change after setjmp and are freed on the error path */
    unsigned char *volatile bytes = NULL;
    png_bytep *volatile rows = NULL;
    if (setjmp(png_jmpbuf(png))) {
        error_set(err, "%s: invalid PNG: %s", path, ctx.message);
        free(bytes);
        free(rows);
        png_end(0, &png, &info);
        return -1;
    }
    png_set_read_fn(png, &src, png_read_cb);
    png_set_sig_bytes(png, 8);
    png_read_info(png, info);
    png_uint_32 w = png_get_image_width(png, info);
    png_uint_32 h = png_get_image_height(png, info);
    int depth = png_get_bit_depth(png, info);
    int colour = png_get_color_type(png, info);
    const char *problem = NULL;
    if (colour != PNG_COLOR_TYPE_GRAY)
        problem = colour == PNG_COLOR_TYPE_GRAY_ALPHA
                      ? "has an alpha channel; a heightmap must be 16-bit greyscale"
                      : "is a colour image; a heightmap must be 16-bit greyscale";
    else if (depth != 16)
        problem = "is not 16-bit; a heightmap must be 16-bit greyscale";
    if (problem) {
        error_set(err, "%s: image %s (bit depth %d)", path, problem, depth);
        png_end(0, &png, &info);
        return -1;
    }
    if (w < 1 || h < 1 || w > WORLD_SIDE_MAX || h > WORLD_SIDE_MAX) {
        error_set(err, "%s: image is %u x %u; each side must be in [1, %d]", path, (unsigned)w,
                  (unsigned)h, WORLD_SIDE_MAX);
        png_end(0, &png, &info);
        return -1;
    }
    png_set_interlace_handling(png);
    png_read_update_info(png, info);
    size_t stride = (size_t)w * 2;
    bytes = malloc(stride * h);
    rows = malloc(sizeof(png_bytep) * h);
    if (!bytes || !rows) {
        error_set(err, "%s: out of memory for a %u x %u image", path, (unsigned)w, (unsigned)h);
        free(bytes);
        free(rows);
        png_end(0, &png, &info);
        return -1;
    }
    for (png_uint_32 y = 0; y < h; y++)
        rows[y] = bytes + stride * y;
    png_read_image(png, rows);
    png_read_end(png, NULL);
    png_end(0, &png, &info);
    free(rows);

    /* big-endian samples → host order, in place (2 bytes in, 2 bytes out) */
    unsigned char *b = bytes;
    uint16_t *out = (uint16_t *)(void *)b;
    size_t n = (size_t)w * h;
    for (size_t i = 0; i < n; i++)
        out[i] = (uint16_t)((b[2 * i] << 8) | b[2 * i + 1]);
    *width = (int)w;
    *height = (int)h;
    *pixels = out;
    return 0;
}

int png16_read(const char *path, int *width, int *height, uint16_t **pixels, error_text *err)
{
    *pixels = NULL;
    uint8_t *file = NULL;
    size_t file_len = 0;
    if (file_read_all(path, 0, &file, &file_len, err) != 0)
        return -1;
    int rc = png16_decode(file, file_len, path, width, height, pixels, err);
    free(file);
    return rc;
}

/* libpng's output into the caller's png16_memory (grown as needed). */
static void png_memory_write(png_structp png, png_bytep bytes, png_size_t n)
{
    png16_memory *m = png_get_io_ptr(png);
    if (array_grow((void **)&m->data, &m->cap, (int64_t)(m->len + n), 1) != 0)
        png_error(png, "out of memory");
    memcpy(m->data + m->len, bytes, n);
    m->len += n;
}

static void png_memory_flush(png_structp png)
{
    (void)png;
}

int png16_encode(int width, int height, int level, png16_row_fn *row_of, void *arg,
                 const char *name, png16_memory *out, error_text *err)
{
    *out = (png16_memory){0};
    if (width < 1 || height < 1 || width > WORLD_SIDE_MAX || height > WORLD_SIDE_MAX) {
        error_set(err, "%s: cannot write a %d x %d image", name, width, height);
        return -1;
    }
    png_error_context ctx = {""};
    png_infop info;
    png_structp png = png_begin(1, &ctx, &info, name, err);
    if (!png)
        return -1;
    /* a row's samples, turned big-endian in place (2 bytes in, 2 bytes out) */
    uint16_t *samples = malloc((size_t)width * sizeof *samples);
    if (!samples) {
        error_set(err, "%s: out of memory", name);
        png_end(1, &png, &info);
        return -1;
    }
    /* out is the caller's, so what the writes grew is not lost to a longjmp;
     * freed, out is as on entry (a cap left behind would tell a reuse of out
     * that it holds memory it does not) */
    if (setjmp(png_jmpbuf(png))) {
        error_set(err, "%s: cannot write PNG: %s", name, ctx.message);
        free(samples);
        png_end(1, &png, &info);
        free(out->data);
        *out = (png16_memory){0};
        return -1;
    }
    png_set_write_fn(png, out, png_memory_write, png_memory_flush);
    if (level >= 0)
        png_set_compression_level(png, level);
    png_set_IHDR(png, info, (png_uint_32)width, (png_uint_32)height, 16, PNG_COLOR_TYPE_GRAY,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    unsigned char *bytes = (unsigned char *)samples;
    for (int y = 0; y < height; y++) {
        row_of(arg, y, samples);
        for (int x = 0; x < width; x++) {
            uint16_t v = samples[x];
            bytes[2 * x] = (unsigned char)(v >> 8);
            bytes[2 * x + 1] = (unsigned char)(v & 0xff);
        }
        png_write_row(png, bytes);
    }
    png_write_end(png, NULL);
    png_end(1, &png, &info);
    free(samples);
    return 0;
}

/* png16_write's rows: its pixels, row after row. */
typedef struct png_pixels {
    const uint16_t *pixels;
    int width;
} png_pixels;

static void pixels_row(void *arg, int y, uint16_t *out)
{
    const png_pixels *p = arg;
    memcpy(out, p->pixels + (size_t)y * p->width, (size_t)p->width * sizeof *out);
}

int png16_write(const char *path, int width, int height, const uint16_t *pixels, error_text *err)
{
    png_pixels p = {pixels, width};
    png16_memory m;
    if (png16_encode(width, height, -1, pixels_row, &p, path, &m, err) != 0)
        return -1;
    FILE *f = fopen(path, "wb");
    if (!f) {
        error_set(err, "%s: cannot create: %s", path, strerror(errno));
        free(m.data);
        return -1;
    }
    size_t put = fwrite(m.data, 1, m.len, f);
    free(m.data);
    if (fclose(f) != 0 || put != m.len) {
        error_set(err, "%s: cannot write: %s", path, strerror(errno));
        return -1;
    }
    return 0;
}
