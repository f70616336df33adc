/*
 * http_png.c: /v1/heights?format=png16 — a rectangle of heights as a 16-bit
 * greyscale PNG (libpng, written to memory). Runs on an HTTP thread after the
 * sim thread has copied the rectangle between two ticks; moved out of http.c
 * so that each file stays under the size limit.
 */
#include "http/http_internal.h"

#include <limits.h>
#include <png.h>
#include <stdlib.h>
#include <string.h>

static void png_memory_write(png_structp png, png_bytep bytes, png_size_t n)
{
    http_png_memory *m = png_get_io_ptr(png);
    if (array_grow((void **)&m->data, &m->cap, (int64_t)(m->len + n), 1) != 0)
        png_error(png, "out of memory");
    memcpy(m->data + m->len, bytes, n);
    m->len += n;
}

static void png_memory_flush(png_structp png)
{
    (void)png;
}

/* Heights → 16-bit greyscale PNG, value = clamp(h - offset, 0, 65535) with
 * offset = the rectangle's minimum, so the image inverts exactly whenever the
 * rectangle's range fits 16 bits (*clipped says whether it did). Returns 0,
 * or -1 with out->data freed. */
int http_png16_encode(const int32_t *heights, int w, int h, int32_t *offset, int *clipped,
                      http_png_memory *out)
{
    /* The offset and the clipped flag live behind the caller's pointers, not
     * in locals, so nothing the rows loop changes is lost to a longjmp. */
    size_t n = (size_t)w * (size_t)h;
    int32_t min = INT32_MAX;
    for (size_t i = 0; i < n; i++)
        if (heights[i] < min)
            min = heights[i];
    *offset = min;
    *clipped = 0;
    out->data = NULL;
    out->len = out->cap = 0;
    unsigned char *row = malloc((size_t)w * 2);
    if (!row)
        return -1;
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, NULL, NULL, NULL);
    png_infop info = png ? png_create_info_struct(png) : NULL;
    if (!png || !info) {
        png_destroy_write_struct(&png, NULL);
        free(row);
        return -1;
    }
    if (setjmp(png_jmpbuf(png))) {
        png_destroy_write_struct(&png, &info);
        free(row);
        free(out->data);
        out->data = NULL;
        return -1;
    }
    png_set_write_fn(png, out, png_memory_write, png_memory_flush);
    /* Speed over size: a 4-Mcell read should cost milliseconds, and height
     * fields are smooth enough that the fastest level still compresses. */
    png_set_compression_level(png, 1);
    png_set_IHDR(png, info, (png_uint_32)w, (png_uint_32)h, 16, PNG_COLOR_TYPE_GRAY,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_write_info(png, info);
    const int32_t lo = *offset;
    for (int y = 0; y < h; y++) {
        const int32_t *src = heights + (size_t)y * (size_t)w;
        for (int x = 0; x < w; x++) {
            int64_t v = (int64_t)src[x] - lo; /* ≥ 0 by the choice of lo */
            if (v > 65535) {
                v = 65535;
                *clipped = 1;
            }
            row[2 * x] = (unsigned char)(v >> 8); /* PNG samples are big-endian */
            row[2 * x + 1] = (unsigned char)(v & 0xff);
        }
        png_write_row(png, row);
    }
    png_write_end(png, NULL);
    png_destroy_write_struct(&png, &info);
    free(row);
    return 0;
}
