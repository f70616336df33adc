/*
 * http_png.c: /v1/heights?format=png16 — a rectangle of heights as a 16-bit
 * greyscale PNG in memory, by the daemon's one PNG writer (png16_encode,
 * world/png16.c); this file chooses the offset and the clamp. Runs on an HTTP
 * thread after the sim thread has copied the rectangle between two ticks.
 */
#include "http/http_internal.h"

#include <limits.h>
#include <stdint.h>

/* The rectangle's rows, each height less the offset, clamped to 16 bits. */
typedef struct heights_rows {
    const int32_t *heights;
    int w;
    int32_t offset;
    int *clipped;
} heights_rows;

static void heights_row(void *arg, int y, uint16_t *samples)
{
    heights_rows *r = arg;
    const int32_t *src = r->heights + (size_t)y * (size_t)r->w;
    for (int x = 0; x < r->w; x++) {
        int64_t v = (int64_t)src[x] - r->offset; /* ≥ 0 by the choice of offset */
        if (v > 65535) {
            v = 65535;
            *r->clipped = 1;
        }
        samples[x] = (uint16_t)v;
    }
}

/* Heights → 16-bit greyscale PNG, value = clamp(h - offset, 0, 65535) with
 * offset = the rectangle's minimum, so the image inverts exactly whenever the
 * rectangle's range fits 16 bits (*clipped says whether it did). Returns 0,
 * or -1 with out->data freed. */
int http_png16_encode(const int32_t *heights, int w, int h, int32_t *offset, int *clipped,
                      png16_memory *out)
{
    size_t n = (size_t)w * (size_t)h;
    int32_t min = INT32_MAX;
    for (size_t i = 0; i < n; i++)
        if (heights[i] < min)
            min = heights[i];
    *offset = min;
    *clipped = 0;
    heights_rows rows = {heights, w, min, clipped};
    error_text err = {{0}};
    /* Speed over size: a 4-Mcell read should cost milliseconds, and height
     * fields are smooth enough that the fastest level still compresses. */
    return png16_encode(w, h, 1, heights_row, &rows, "heights", out, &err);
}
