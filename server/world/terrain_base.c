/*
 * terrain_base.c: the base terrain a world starts from — flat, seeded dunes,
 * or a heightmap file (16-bit PNG, raw little-endian int16/int32). The spec
 * is checked once, before the first tick (world_base_build); after that
 * world.c asks for the base heights of any rectangle whenever it reads a tile
 * that has never been written (world_base_fill), so the result must depend
 * only on the spec and the cell's coordinates: never on the world's extent,
 * the rectangle asked for, the machine or the run.
 *
 * Every height is formed in double, rounded once (llround) and range-checked
 * against [max(floor, WORLD_HEIGHT_MIN), WORLD_HEIGHT_MAX]; a value outside is
 * refused with the value and the limit in the message, never wrapped or
 * clamped, because a silently changed terrain is worse than none.
 */
#include "world/world_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The dune noise must be bit-identical everywhere: no fused multiply-adds. */
#ifdef __clang__
#pragma STDC FP_CONTRACT OFF
#endif

typedef struct height_check {
    int32_t lo, hi;   /* allowed range, units */
    const char *what; /* "terrain.height_m", a file name, ... */
} height_check;

static height_check height_check_make(const world *w, const char *what)
{
    height_check c = {w->floor > WORLD_HEIGHT_MIN ? w->floor : WORLD_HEIGHT_MIN, WORLD_HEIGHT_MAX,
                      what};
    return c;
}

/* Round and range-check one height; x < 0 means "not a particular cell". */
static int height_from_units(const height_check *c, double units, int x, int y, int32_t *out,
                             error_text *err)
{
    char where[48] = "";
    if (x >= 0)
        snprintf(where, sizeof where, " at cell (%d, %d)", x, y);
    if (!isfinite(units)) {
        error_set(err, "%s: height%s is not a finite number", c->what, where);
        return -1;
    }
    /* compare before llround so huge values cannot overflow long long */
    if (units < (double)c->lo - 0.5) {
        error_set(err, "%s: height %.0f units%s is below the limit %d (%s)", c->what, units, where,
                  (int)c->lo, c->lo == WORLD_HEIGHT_MIN ? "WORLD_HEIGHT_MIN" : "the world's floor");
        return -1;
    }
    if (units >= (double)c->hi + 0.5) {
        error_set(err, "%s: height %.0f units%s is above the limit %d (WORLD_HEIGHT_MAX)", c->what,
                  units, where, (int)c->hi);
        return -1;
    }
    long long v = llround(units);
    if (v < c->lo || v > c->hi) {
        error_set(err, "%s: height %lld units%s is outside [%d, %d]", c->what, v, where, (int)c->lo,
                  (int)c->hi);
        return -1;
    }
    *out = (int32_t)v;
    return 0;
}

/* ---- Dunes: seeded 2D gradient noise, fBm ---- */

static uint32_t lattice_hash(int64_t ix, int64_t iy, uint32_t seed)
{
    uint32_t h = hash_lowbias32((uint32_t)ix ^ hash_lowbias32(seed));
    return hash_lowbias32(h ^ hash_lowbias32((uint32_t)iy + 0x9e3779b9u));
}

/* Eight unit gradients: axes and diagonals. Written as constants so nothing
 * depends on a libm's cos/sin. */
static const double gradients[8][2] = {
    {1.0, 0.0},
    {-1.0, 0.0},
    {0.0, 1.0},
    {0.0, -1.0},
    {0.70710678118654752, 0.70710678118654752},
    {-0.70710678118654752, 0.70710678118654752},
    {0.70710678118654752, -0.70710678118654752},
    {-0.70710678118654752, -0.70710678118654752},
};

static double fade(double t)
{
    return t * t * t * (t * (t * 6.0 - 15.0) + 10.0);
}

static double corner(int64_t ix, int64_t iy, uint32_t seed, double dx, double dy)
{
    const double *g = gradients[lattice_hash(ix, iy, seed) & 7u];
    return g[0] * dx + g[1] * dy;
}

/* Perlin gradient noise in [-sqrt(0.5), sqrt(0.5)]. */
static double gradient_noise(double px, double py, uint32_t seed)
{
    double fx = floor(px), fy = floor(py);
    int64_t ix = (int64_t)fx, iy = (int64_t)fy;
    double dx = px - fx, dy = py - fy;
    double n00 = corner(ix, iy, seed, dx, dy);
    double n10 = corner(ix + 1, iy, seed, dx - 1.0, dy);
    double n01 = corner(ix, iy + 1, seed, dx, dy - 1.0);
    double n11 = corner(ix + 1, iy + 1, seed, dx - 1.0, dy - 1.0);
    double u = fade(dx), v = fade(dy);
    double a = n00 + (n10 - n00) * u;
    double b = n01 + (n11 - n01) * u;
    return a + (b - a) * v;
}

/* fBm in [0, 1]: octaves at doubling frequency and halving amplitude, scaled
 * by the theoretical bound (not the world's own extremes, so a tile's heights
 * never depend on the size of the world around it). */
static double dune_value(double px, double py, int octaves, uint32_t seed)
{
    double sum = 0.0, amplitude = 1.0, total = 0.0, frequency = 1.0;
    for (int o = 0; o < octaves; o++) {
        sum += amplitude *
               gradient_noise(px * frequency, py * frequency, seed + (uint32_t)o * 0x632be5abu);
        total += amplitude;
        amplitude *= 0.5;
        frequency *= 2.0;
    }
    double v = sum / total * 1.4142135623730951; /* now in [-1, 1] */
    /* fBm rarely strays far from 0, so the raw value would use only the
     * middle of [min, max]; a soft gain g·v / sqrt(1 + (g·v)²), scaled so
     * that ±1 stays ±1, spreads it out without flat clipped plateaus
     * (sqrt is correctly rounded everywhere, so this stays deterministic). */
    const double gain = 2.5, norm = 1.0770329614269007; /* sqrt(1 + gain²) / gain */
    double g = gain * v;
    v = g / sqrt(1.0 + g * g) * norm;
    if (v < -1.0)
        v = -1.0;
    if (v > 1.0)
        v = 1.0;
    return v * 0.5 + 0.5;
}

static int check_dunes(const world *w, const world_base_spec *s, error_text *err)
{
    if (!isfinite(s->min_height_m) || !isfinite(s->max_height_m)) {
        error_set(err, "terrain.min_height_m/max_height_m: must be finite numbers");
        return -1;
    }
    if (s->max_height_m < s->min_height_m) {
        error_set(err, "terrain.max_height_m: must be >= min_height_m (got %g < %g)",
                  s->max_height_m, s->min_height_m);
        return -1;
    }
    if (!isfinite(s->wavelength_m) || s->wavelength_m <= 0.0 || s->wavelength_m > 1e6) {
        error_set(err, "terrain.wavelength_m: must be a finite number > 0 and <= 1e6 (got %g)",
                  s->wavelength_m);
        return -1;
    }
    if (s->octaves < 1 || s->octaves > 8) {
        error_set(err, "terrain.octaves: must be an integer in [1, 8] (got %d)", s->octaves);
        return -1;
    }
    height_check c = height_check_make(w, "terrain.min_height_m");
    double lo_units = s->min_height_m * w->units_per_m;
    double hi_units = s->max_height_m * w->units_per_m;
    int32_t probe;
    /* The noise value t lies in [0, 1], so every cell's height lies between
     * these two endpoints: checking them here is what lets world_base_fill
     * compute any rectangle later without a way to fail. */
    if (height_from_units(&c, lo_units, -1, 0, &probe, err) != 0)
        return -1;
    c.what = "terrain.max_height_m";
    if (height_from_units(&c, hi_units, -1, 0, &probe, err) != 0)
        return -1;
    return 0;
}

static void fill_dunes(const world *w, const world_base_spec *s, world_rect r, int32_t *dst,
                       size_t dst_stride)
{
    double inv_wavelength = 1.0 / s->wavelength_m;
    for (int y = r.y; y < r.y + r.h; y++) {
        double py = ((double)y + 0.5) * w->cell_size_m * inv_wavelength;
        int32_t *row = dst + (size_t)(y - r.y) * dst_stride;
        for (int x = r.x; x < r.x + r.w; x++) {
            double px = ((double)x + 0.5) * w->cell_size_m * inv_wavelength;
            double t = dune_value(px, py, s->octaves, s->seed);
            double metres = s->min_height_m + (s->max_height_m - s->min_height_m) * t;
            /* the same llround height_from_units does; the range is checked */
            row[x - r.x] = (int32_t)llround(metres * w->units_per_m);
        }
    }
}

/* ---- Heightmap files ---- */

static int check_scale(const world_base_spec *s, error_text *err)
{
    if (!isfinite(s->value_scale_units) || fabs(s->value_scale_units) > 1e9) {
        error_set(err, "terrain.scale_units: must be a finite number with |x| <= 1e9 (got %g)",
                  s->value_scale_units);
        return -1;
    }
    if (!isfinite(s->value_offset_units) || fabs(s->value_offset_units) > 1e10) {
        error_set(err, "terrain.offset_units: must be a finite number with |x| <= 1e10 (got %g)",
                  s->value_offset_units);
        return -1;
    }
    return 0;
}

static int load_png16(const world *w, const world_base_spec *s, int32_t *cells, error_text *err)
{
    int pw, ph;
    uint16_t *pixels = NULL;
#ifdef TERRAD_TWIN_LIB
    /* The twin library has no libpng (docs/engines.md): its bases are flat or
     * dunes, which a client configures by value, not by file. */
    (void)w, (void)pw, (void)ph, (void)pixels, (void)cells;
    error_set(err, "%s: PNG bases are not part of the twin library", s->path);
    return -1;
#else
    if (png16_read(s->path, &pw, &ph, &pixels, err) != 0)
        return -1;
    if (pw != w->width || ph != w->height) {
        error_set(err, "%s: image is %d x %d but the world is %d x %d cells", s->path, pw, ph,
                  w->width, w->height);
        free(pixels);
        return -1;
    }
    height_check c = height_check_make(w, s->path);
    for (int y = 0; y < ph; y++)
        for (int x = 0; x < pw; x++) {
            size_t i = (size_t)y * pw + x;
            double units = (double)pixels[i] * s->value_scale_units + s->value_offset_units;
            if (height_from_units(&c, units, x, y, &cells[i], err) != 0) {
                free(pixels);
                return -1;
            }
        }
    free(pixels);
    return 0;
#endif
}

static int load_raw(const world *w, const world_base_spec *s, int bytes, int32_t *cells,
                    error_text *err)
{
    uint64_t expected = (uint64_t)w->width * (uint64_t)w->height * (uint64_t)bytes;
    uint8_t *data = NULL;
    size_t size = 0;
    if (file_read_all(s->path, (size_t)expected, &data, &size, err) != 0)
        return -1;
    if ((uint64_t)size != expected) {
        error_set(err, "%s: file is %lld bytes but a %d x %d world of int%d needs %llu", s->path,
                  (long long)size, w->width, w->height, bytes * 8, (unsigned long long)expected);
        free(data);
        return -1;
    }
    height_check c = height_check_make(w, s->path);
    int rc = 0;
    for (int y = 0; y < w->height && rc == 0; y++) {
        const unsigned char *row = data + (size_t)y * w->width * bytes;
        for (int x = 0; x < w->width; x++) {
            const unsigned char *p = row + (size_t)x * bytes;
            double value;
            if (bytes == 2)
                value = (double)(int16_t)(uint16_t)(p[0] | (p[1] << 8));
            else
                value = (double)(int32_t)((uint32_t)p[0] | ((uint32_t)p[1] << 8) |
                                          ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24));
            double units = value * s->value_scale_units + s->value_offset_units;
            if (height_from_units(&c, units, x, y, &cells[(size_t)y * w->width + x], err) != 0) {
                rc = -1;
                break;
            }
        }
    }
    free(data);
    return rc;
}

int world_base_build(const world *w, const world_base_spec *spec, world_base *b, error_text *err)
{
    memset(b, 0, sizeof *b);
    b->kind = spec->kind;
    b->spec = *spec;
    int64_t cells_n = (int64_t)w->width * w->height;
    switch (spec->kind) {
    case WORLD_BASE_FLAT: {
        if (!isfinite(spec->height_m)) {
            error_set(err, "terrain.height_m: must be a finite number");
            return -1;
        }
        height_check c = height_check_make(w, "terrain.height_m");
        if (height_from_units(&c, spec->height_m * w->units_per_m, -1, 0, &b->flat_units, err) != 0)
            return -1;
        b->volume = (int64_t)b->flat_units * cells_n; /* |h| < 2^29, cells <= 2^32 */
        b->volume_known = 1;
        return 0;
    }
    case WORLD_BASE_DUNES:
        return check_dunes(w, spec, err);
    case WORLD_BASE_PNG16:
    case WORLD_BASE_RAW_INT16:
    case WORLD_BASE_RAW_INT32: {
        if (check_scale(spec, err) != 0)
            return -1;
        /* a file is bounded by memory anyway: keep it as one dense array */
        b->cells = malloc((size_t)cells_n * sizeof *b->cells);
        if (!b->cells) {
            error_set(err, "%s: out of memory for a %d x %d base", spec->path, w->width, w->height);
            return -1;
        }
        int rc = spec->kind == WORLD_BASE_PNG16
                     ? load_png16(w, spec, b->cells, err)
                     : load_raw(w, spec, spec->kind == WORLD_BASE_RAW_INT16 ? 2 : 4, b->cells, err);
        if (rc != 0) {
            world_base_free(b);
            return -1;
        }
        for (int64_t i = 0; i < cells_n; i++)
            b->volume += b->cells[i];
        b->volume_known = 1;
        return 0;
    }
    }
    error_set(err, "terrain.kind: unknown kind %d", (int)spec->kind);
    return -1;
}

void world_base_free(world_base *b)
{
    free(b->cells);
    memset(b, 0, sizeof *b);
}

void world_base_fill(const world *w, const world_base *b, world_rect r, int32_t *dst,
                     size_t dst_stride)
{
    switch (b->kind) {
    case WORLD_BASE_DUNES:
        fill_dunes(w, &b->spec, r, dst, dst_stride);
        return;
    case WORLD_BASE_PNG16:
    case WORLD_BASE_RAW_INT16:
    case WORLD_BASE_RAW_INT32:
        for (int y = 0; y < r.h; y++)
            memcpy(dst + (size_t)y * dst_stride, b->cells + (size_t)(r.y + y) * w->width + r.x,
                   (size_t)r.w * sizeof *dst);
        return;
    case WORLD_BASE_FLAT:
        break;
    }
    for (int y = 0; y < r.h; y++)
        for (int x = 0; x < r.w; x++)
            dst[(size_t)y * dst_stride + x] = b->flat_units;
}
