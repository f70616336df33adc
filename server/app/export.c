/*
 * export.c: `terrad export` — the world as a data directory holds it (scene
 * base terrain, then tile snapshots, then the log: store_load_readonly), or a
 * region of it, written as little-endian int32 (raw32) or a 16-bit greyscale
 * PNG (png16). Offline: it reads the directory without locking or repairing
 * it, so it can run beside a live daemon and sees every tick the daemon has
 * written so far.
 *
 * PNG16 maps heights to 16 bits as height = value * scale + offset (units);
 * offset is the region's lowest height and scale the smallest integer that
 * fits the region's range in 65535 steps, so a range under 65536 units is
 * exact. Both are logged and written to FILE.json beside the PNG.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "scene/scene.h"
#include "store/store.h"
#include "world/world.h"

static int write_raw32(const char *path, const int32_t *v, size_t n)
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

int app_export(int argc, char **argv)
{
    const char *data = "./data", *scene_path = NULL, *out = NULL, *format = "raw32";
    world_rect region = {0, 0, 0, 0};
    long long upto_tick = 0;
    int have_region = 0;
    for (int i = 0; i < argc; i++) {
        const char *a = argv[i], *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (!v) {
            fprintf(stderr, "terrad export: %s needs a value (see terrad --help)\n", a);
            return 2;
        }
        i++;
        if (strcmp(a, "--data") == 0)
            data = v;
        else if (strcmp(a, "--scene") == 0)
            scene_path = v;
        else if (strcmp(a, "--out") == 0)
            out = v;
        else if (strcmp(a, "--format") == 0)
            format = v;
        else if (strcmp(a, "--tick") == 0) {
            char *end;
            upto_tick = strtoll(v, &end, 10);
            if (!*v || *end || upto_tick < 1) {
                fprintf(stderr, "terrad export: --tick must be a tick number >= 1 (got %s)\n", v);
                return 2;
            }
        } else if (strcmp(a, "--region") == 0) {
            char tail;
            if (sscanf(v, "%d,%d,%d,%d%c", &region.x, &region.y, &region.w, &region.h, &tail) !=
                    4 ||
                region.w <= 0 || region.h <= 0) {
                fprintf(stderr, "terrad export: --region must be x,y,w,h with w, h > 0 (got %s)\n",
                        v);
                return 2;
            }
            have_region = 1;
        } else {
            fprintf(stderr, "terrad export: unknown option %s (see terrad --help)\n", a);
            return 2;
        }
    }
    if (!out) {
        fprintf(stderr, "terrad export: --out FILE is required\n");
        return 2;
    }
    if (strcmp(format, "raw32") != 0 && strcmp(format, "png16") != 0) {
        fprintf(stderr, "terrad export: --format must be png16 or raw32 (got %s)\n", format);
        return 2;
    }
    error_text err = {{0}};
    scene sc;
    if ((scene_path ? scene_load_file(scene_path, &sc, &err) : scene_load_default(&sc, &err)) !=
        0) {
        log_error("%s", err.message);
        return 1;
    }
    world w;
    int rc = 1;
    int32_t *values = NULL;
    uint16_t *pixels = NULL;
    if (scene_create_world(&sc, &w, &err) != 0) {
        log_error("%s", err.message);
        scene_free(&sc);
        return 1;
    }
    store_recovery rec;
    if (store_load_readonly(data, &w, (uint64_t)upto_tick, &rec, &err) != 0) {
        log_error("%s", err.message);
        goto done;
    }
    if (!have_region)
        region = (world_rect){0, 0, w.width, w.height};
    world_rect clipped = region;
    if (!world_clip_rect(&w, &clipped) || clipped.x != region.x || clipped.y != region.y ||
        clipped.w != region.w || clipped.h != region.h) {
        log_error("terrad export: --region %d,%d,%d,%d is not inside the %dx%d world", region.x,
                  region.y, region.w, region.h, w.width, w.height);
        goto done;
    }
    size_t n = (size_t)region.w * region.h;
    values = malloc(n * sizeof *values);
    if (!values) {
        log_error("terrad export: out of memory for %zu cells", n);
        goto done;
    }
    world_gather_window(&w, region, values);
    if (strcmp(format, "raw32") == 0) {
        if (write_raw32(out, values, n) != 0) {
            log_error("terrad export: cannot write %s", out);
            goto done;
        }
    } else {
        int32_t lo, hi;
        world_rect_height_range(&w, region, &lo, &hi);
        int64_t range = (int64_t)hi - lo;
        int64_t scale = range <= 65535 ? 1 : (range + 65534) / 65535;
        pixels = malloc(n * sizeof *pixels);
        if (!pixels) {
            log_error("terrad export: out of memory for %zu pixels", n);
            goto done;
        }
        for (size_t i = 0; i < n; i++)
            pixels[i] = (uint16_t)(((int64_t)values[i] - lo) / scale);
        if (png16_write(out, region.w, region.h, pixels, &err) != 0) {
            log_error("%s", err.message);
            goto done;
        }
        char side[1100];
        snprintf(side, sizeof side, "%s.json", out);
        FILE *f = fopen(side, "w");
        if (!f ||
            fprintf(f,
                    "{\"x\":%d,\"y\":%d,\"width\":%d,\"height\":%d,\"tick\":%llu,"
                    "\"offset_units\":%d,\"scale_units\":%lld,\"units_per_m\":%d,"
                    "\"height_units\":\"value * scale_units + offset_units\"}\n",
                    region.x, region.y, region.w, region.h, (unsigned long long)rec.tick, lo,
                    (long long)scale, (int)w.units_per_m) < 0 ||
            fclose(f) != 0) {
            log_error("terrad export: cannot write %s", side);
            goto done;
        }
        log_info("export: png16 height = value * %lld + %d units (%s)%s", (long long)scale, lo,
                 side, scale > 1 ? "; the range is over 65535 units, so it is quantised" : "");
    }
    log_info("export: %s %dx%d at %d,%d as of tick %llu (%d tile snapshots, %lld log records)", out,
             region.w, region.h, region.x, region.y, (unsigned long long)rec.tick, rec.tiles_loaded,
             (long long)rec.records_replayed);
    rc = 0;
done:
    free(values);
    free(pixels);
    world_free(&w);
    scene_free(&sc);
    return rc;
}
