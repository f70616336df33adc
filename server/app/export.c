/*
 * export.c: `terrad export` — the world as a data directory holds it (scene
 * base terrain, then tile snapshots, then the log: store_load_readonly), or a
 * region of it, written as little-endian int32 (int32, the name GET
 * /v1/heights uses; raw32 is accepted as an alias) or a 16-bit greyscale PNG
 * (png16). Offline: it reads the directory without locking or repairing
 * it, so it can run beside a live daemon and sees every tick the daemon has
 * written so far.
 *
 * PNG16 maps the region's actual range [lo, hi] onto the full 16 bits, so the
 * picture opens with full contrast: height = value * scale + offset (units),
 * offset = lo, scale = (hi - lo) / 65535 (a fraction; 1 for a flat region),
 * value = lround((height - lo) / scale). Reading back with the sidecar gives
 * every height within half a step. Both are logged and written to FILE.json.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "scene/scene.h"
#include "store/store.h"
#include "world/world.h"

static int write_int32(const char *path, const int32_t *v, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    size_t ok = 1;
    for (size_t i = 0; i < n && ok; i++) {
        uint32_t u = (uint32_t)v[i];
        unsigned char b[4] = {(unsigned char)u, (unsigned char)(u >> 8), (unsigned char)(u >> 16),
                              (unsigned char)(u >> 24)};
        ok = fwrite(b, 4, 1, f);
    }
    return fclose(f) == 0 && ok ? 0 : -1;
}

typedef struct export_options {
    const char *data, *scene_path, *out, *format;
    world_rect region;
    long long upto_tick;
    int have_region;
} export_options;

static int tick_option(void *ctx, const char *v, error_text *err)
{
    export_options *o = ctx;
    char *end;
    o->upto_tick = strtoll(v, &end, 10);
    if (!*v || *end || o->upto_tick < 1) {
        error_set(err, "must be a tick number >= 1 (got %s)", v);
        return -1;
    }
    return 0;
}

static int region_option(void *ctx, const char *v, error_text *err)
{
    export_options *o = ctx;
    world_rect *r = &o->region;
    char tail;
    if (sscanf(v, "%d,%d,%d,%d%c", &r->x, &r->y, &r->w, &r->h, &tail) != 4 || r->w <= 0 ||
        r->h <= 0) {
        error_set(err, "must be x,y,w,h with w, h > 0 (got %s)", v);
        return -1;
    }
    o->have_region = 1;
    return 0;
}

static const cli_option export_table[] = {
    {"data", "DIR", "data directory (default ./data); read only, never repaired",
     CLI_AT_STRING(export_options, data)},
    APP_OPTION_SCENE_RAN(export_options, scene_path),
    {"out", "FILE", "output file (required)", CLI_AT_STRING(export_options, out)},
    {"format", "F",
     "int32 (little-endian, row-major, as GET /v1/heights; default;\n"
     "raw32 is an alias) or png16 (the region's range stretched over\n"
     "0..65535: height = value * scale + offset, written to FILE.json)",
     CLI_AT_STRING(export_options, format)},
    {"region", "x,y,w,h", "a region in cells (default: the whole world)", CLI_CALLS(region_option)},
    {"tick", "T", "the world as of tick T (default: the last logged tick)", CLI_CALLS(tick_option)},
    {0},
};

static const char export_usage[] = "--out FILE [options]";

void app_export_usage(FILE *out)
{
    cli_print_help(out, "export", export_usage, export_table);
}

/* The region as a 16-bit PNG, and its scale and offset in FILE.json. */
static int export_png16(const export_options *o, const world *w, world_rect region,
                        const int32_t *values, uint64_t tick)
{
    error_text err = {{0}};
    size_t n = (size_t)region.w * region.h;
    int32_t lo, hi;
    world_rect_height_range(w, region, &lo, &hi);
    /* the range over the full 16 bits; a flat region keeps scale 1 (all 0) */
    double scale = hi > lo ? ((double)hi - lo) / 65535.0 : 1.0;
    uint16_t *pixels = malloc(n * sizeof *pixels);
    if (!pixels) {
        log_error("terrad export: out of memory for %zu pixels", n);
        return -1;
    }
    for (size_t i = 0; i < n; i++) {
        long p = lround(((double)values[i] - lo) / scale);
        pixels[i] = (uint16_t)(p < 0 ? 0 : p > 65535 ? 65535 : p);
    }
    int rc = png16_write(o->out, region.w, region.h, pixels, &err);
    free(pixels);
    if (rc != 0) {
        log_error("%s", err.message);
        return -1;
    }
    char side[1100];
    snprintf(side, sizeof side, "%s.json", o->out);
    FILE *f = fopen(side, "w");
    if (!f ||
        fprintf(f,
                "{\"x\":%d,\"y\":%d,\"width\":%d,\"height\":%d,\"tick\":%llu,"
                "\"offset_units\":%d,\"scale_units\":%.17g,\"units_per_m\":%d,"
                "\"height_units\":\"value * scale_units + offset_units\"}\n",
                region.x, region.y, region.w, region.h, (unsigned long long)tick, lo, scale,
                (int)w->units_per_m) < 0 ||
        fclose(f) != 0) {
        log_error("terrad export: cannot write %s", side);
        return -1;
    }
    log_info("export: png16 height = value * %.9g + %d units (%s; heights %d..%d over 0..65535)",
             scale, lo, side, lo, hi);
    return 0;
}

/* The recovered world's region to o->out. 0, or -1 (logged). */
static int export_region(const export_options *o, const world *w, const store_recovery *rec)
{
    world_rect region = o->have_region ? o->region : (world_rect){0, 0, w->width, w->height};
    world_rect clipped = region;
    if (!world_clip_rect(w, &clipped) || clipped.x != region.x || clipped.y != region.y ||
        clipped.w != region.w || clipped.h != region.h) {
        log_error("terrad export: --region %d,%d,%d,%d is not inside the %dx%d world", region.x,
                  region.y, region.w, region.h, w->width, w->height);
        return -1;
    }
    size_t n = (size_t)region.w * region.h;
    int32_t *values = malloc(n * sizeof *values);
    if (!values) {
        log_error("terrad export: out of memory for %zu cells", n);
        return -1;
    }
    world_gather_window(w, region, values);
    int rc = 0;
    if (strcmp(o->format, "int32") == 0) {
        if (write_int32(o->out, values, n) != 0) {
            log_error("terrad export: cannot write %s", o->out);
            rc = -1;
        }
    } else {
        rc = export_png16(o, w, region, values, rec->tick);
    }
    free(values);
    if (rc == 0)
        log_info("export: %s %dx%d at %d,%d as of tick %llu (%d tile snapshots, %lld log records)",
                 o->out, region.w, region.h, region.x, region.y, (unsigned long long)rec->tick,
                 rec->tiles_loaded, (long long)rec->records_replayed);
    return rc;
}

/* The world as the directory holds it up to the tick asked for, then the region out. */
static int export_run(void *ctx, world *w)
{
    const export_options *o = ctx;
    error_text err = {{0}};
    store_recovery rec;
    if (store_load_readonly(o->data, w, (uint64_t)o->upto_tick, &rec, &err) != 0) {
        log_error("%s", err.message);
        return 1;
    }
    return export_region(o, w, &rec) == 0 ? 0 : 1;
}

int app_export(int argc, char **argv)
{
    export_options o = {.data = "./data", .format = "int32"};
    cli_result parsed = cli_parse("export", export_usage, export_table, argc, argv, &o, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    if (!o.out) {
        fprintf(stderr, "terrad export: --out FILE is required\n");
        return 2;
    }
    if (strcmp(o.format, "raw32") == 0)
        o.format = "int32"; /* the old name */
    if (strcmp(o.format, "int32") != 0 && strcmp(o.format, "png16") != 0) {
        fprintf(stderr, "terrad export: --format must be int32 or png16 (got %s)\n", o.format);
        return 2;
    }
    return app_offline_world(o.scene_path, export_run, &o);
}
