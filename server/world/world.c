/*
 * world.c: the authoritative height field and the rectangle helpers the tick
 * uses around it. The sim engine plans windows with world_clip_rect,
 * world_rects_overlap and world_rect_union, gathers each window's heights out
 * of the world (step 4 of the tick), and scatters the new heights back
 * (step 7). Everything here is plain integer bookkeeping; volumes are summed
 * in int64 so that "Σh is unchanged" can be checked exactly.
 */
#include "world/world.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* An in-memory world above this many cells (4 GiB of heights) is refused:
 * larger terrains need tiles, not one array. */
#define WORLD_CELLS_MAX ((int64_t)1 << 30)

int world_init(world *w, int width, int height, double cell_size_m, int32_t units_per_m,
               int32_t floor, error_text *err)
{
    memset(w, 0, sizeof *w);
    if (width < 1 || width > WORLD_SIDE_MAX) {
        error_set(err, "world.width: must be an integer in [1, %d] (got %d)", WORLD_SIDE_MAX,
                  width);
        return -1;
    }
    if (height < 1 || height > WORLD_SIDE_MAX) {
        error_set(err, "world.height: must be an integer in [1, %d] (got %d)", WORLD_SIDE_MAX,
                  height);
        return -1;
    }
    if ((int64_t)width * height > WORLD_CELLS_MAX) {
        error_set(err,
                  "world: %d x %d = %lld cells is more than the %lld an in-memory world may hold",
                  width, height, (long long)width * height, (long long)WORLD_CELLS_MAX);
        return -1;
    }
    if (!isfinite(cell_size_m) || cell_size_m <= 0.0 || cell_size_m > 1000.0) {
        error_set(err, "world.cell_size_m: must be a finite number > 0 and <= 1000 (got %g)",
                  cell_size_m);
        return -1;
    }
    if (units_per_m < 1 || units_per_m > 1000000) {
        error_set(err, "world.units_per_m: must be an integer in [1, 1000000] (got %d)",
                  (int)units_per_m);
        return -1;
    }
    if (floor < WORLD_HEIGHT_MIN || floor > WORLD_HEIGHT_MAX) {
        error_set(err, "world.floor: must lie in [%d, %d] units (got %d)", WORLD_HEIGHT_MIN,
                  WORLD_HEIGHT_MAX, (int)floor);
        return -1;
    }
    int32_t *h = calloc((size_t)width * (size_t)height, sizeof *h);
    if (!h) {
        error_set(err, "world: out of memory for %d x %d cells", width, height);
        return -1;
    }
    w->width = width;
    w->height = height;
    w->cell_size_m = cell_size_m;
    w->units_per_m = units_per_m;
    w->floor = floor;
    w->heights = h;
    return 0;
}

void world_free(world *w)
{
    if (!w)
        return;
    free(w->heights);
    free(w->base_copy);
    memset(w, 0, sizeof *w);
}

int64_t world_volume(const world *w)
{
    int64_t sum = 0;
    size_t n = (size_t)w->width * (size_t)w->height;
    for (size_t i = 0; i < n; i++)
        sum += w->heights[i];
    return sum;
}

int64_t world_rect_volume(const world *w, world_rect r)
{
    if (!world_clip_rect(w, &r))
        return 0;
    int64_t sum = 0;
    for (int y = r.y; y < r.y + r.h; y++) {
        const int32_t *row = w->heights + (size_t)y * w->width + r.x;
        for (int x = 0; x < r.w; x++)
            sum += row[x];
    }
    return sum;
}

int world_clip_rect(const world *w, world_rect *r)
{
    if (r->w <= 0 || r->h <= 0) {
        *r = (world_rect){0, 0, 0, 0};
        return 0;
    }
    /* int64 so a rectangle near INT_MAX does not wrap while being clipped */
    int64_t x0 = r->x, y0 = r->y;
    int64_t x1 = x0 + r->w, y1 = y0 + r->h;
    if (x0 < 0)
        x0 = 0;
    if (y0 < 0)
        y0 = 0;
    if (x1 > w->width)
        x1 = w->width;
    if (y1 > w->height)
        y1 = w->height;
    if (x1 <= x0 || y1 <= y0) {
        *r = (world_rect){0, 0, 0, 0};
        return 0;
    }
    *r = (world_rect){(int)x0, (int)y0, (int)(x1 - x0), (int)(y1 - y0)};
    return 1;
}

void world_gather_window(const world *w, world_rect r, int32_t *dst)
{
    for (int y = 0; y < r.h; y++)
        memcpy(dst + (size_t)y * r.w, w->heights + (size_t)(r.y + y) * w->width + r.x,
               (size_t)r.w * sizeof *dst);
}

void world_scatter_window(world *w, world_rect r, const int32_t *src)
{
    for (int y = 0; y < r.h; y++)
        memcpy(w->heights + (size_t)(r.y + y) * w->width + r.x, src + (size_t)y * r.w,
               (size_t)r.w * sizeof *src);
}

void world_rect_height_range(const world *w, world_rect r, int32_t *lo, int32_t *hi)
{
    int32_t mn = INT32_MAX, mx = INT32_MIN;
    for (int y = r.y; y < r.y + r.h; y++) {
        const int32_t *row = w->heights + (size_t)y * w->width + r.x;
        for (int x = 0; x < r.w; x++) {
            if (row[x] < mn)
                mn = row[x];
            if (row[x] > mx)
                mx = row[x];
        }
    }
    if (r.w <= 0 || r.h <= 0)
        mn = mx = 0; /* an empty rectangle has no heights; 0 keeps callers' arithmetic sane */
    *lo = mn;
    *hi = mx;
}

int world_rects_overlap(world_rect a, world_rect b)
{
    if (a.w <= 0 || a.h <= 0 || b.w <= 0 || b.h <= 0)
        return 0;
    return (int64_t)a.x < (int64_t)b.x + b.w && (int64_t)b.x < (int64_t)a.x + a.w &&
           (int64_t)a.y < (int64_t)b.y + b.h && (int64_t)b.y < (int64_t)a.y + a.h;
}

world_rect world_rect_union(world_rect a, world_rect b)
{
    if (a.w <= 0 || a.h <= 0)
        return b;
    if (b.w <= 0 || b.h <= 0)
        return a;
    int64_t x0 = a.x < b.x ? a.x : b.x;
    int64_t y0 = a.y < b.y ? a.y : b.y;
    int64_t x1 = (int64_t)a.x + a.w > (int64_t)b.x + b.w ? (int64_t)a.x + a.w : (int64_t)b.x + b.w;
    int64_t y1 = (int64_t)a.y + a.h > (int64_t)b.y + b.h ? (int64_t)a.y + a.h : (int64_t)b.y + b.h;
    return (world_rect){(int)x0, (int)y0, (int)(x1 - x0), (int)(y1 - y0)};
}
