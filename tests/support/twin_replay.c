/*
 * twin_replay.c: replays a twin_trace.c trace (its header says the format)
 * through the twin library's C API alone — it links libterrad-twin.so and
 * nothing of the daemon — and writes the window's final heights as
 * little-endian int32, row-major, the format of `terrad simulate --out`
 * (tests/integration/clients/test_twin.py compares the two). twin_wasm.mjs does the
 * same through the WebAssembly module.
 *
 * Usage: twin_replay OUT < TRACE. Exit 1 with the library's error.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_twin.h"

static char err[TERRAD_TWIN_ERROR_MAX];

static int die(const char *what)
{
    fprintf(stderr, "twin_replay: %s: %s\n", what, err);
    return 1;
}

static double num(void)
{
    double v = 0;
    if (scanf("%lf", &v) != 1) {
        fprintf(stderr, "twin_replay: a number expected\n");
        exit(1);
    }
    return v;
}

static int read_mesh(terrad_twin *t)
{
    int id = (int)num(), nv = (int)num(), nt = (int)num();
    float *v = malloc((size_t)nv * 3 * sizeof *v);
    uint32_t *ix = malloc((size_t)nt * 3 * sizeof *ix);
    if (!v || !ix)
        return -1;
    for (int i = 0; i < nv * 3; i++)
        v[i] = (float)num();
    for (int i = 0; i < nt * 3; i++)
        ix[i] = (uint32_t)num();
    int rc = terrad_twin_add_mesh(t, id, v, nv, ix, nt, err);
    free(v);
    free(ix);
    return rc;
}

int main(int argc, char **argv)
{
    if (argc != 2) {
        fprintf(stderr, "usage: twin_replay OUT < TRACE\n");
        return 2;
    }
    terrad_twin_config *c = terrad_twin_config_new();
    terrad_twin *t = NULL;
    int wx = 0, wy = 0, ww = 0, wh = 0;
    char word[64], key[64], value[64];
    while (scanf("%63s", word) == 1) {
        if (strcmp(word, "set") == 0) {
            if (scanf("%63s", key) != 1 || terrad_twin_config_set(c, key, num(), err) != 0)
                return die("set");
        } else if (strcmp(word, "name") == 0) {
            if (scanf("%63s %63s", key, value) != 2 ||
                terrad_twin_config_set_name(c, key, value, err) != 0)
                return die("name");
        } else if (strcmp(word, "window") == 0) {
            wx = (int)num(), wy = (int)num(), ww = (int)num(), wh = (int)num();
        } else if (strcmp(word, "heights") == 0) {
            int32_t *h = malloc((size_t)ww * wh * sizeof *h);
            for (long i = 0; h && i < (long)ww * wh; i++)
                h[i] = (int32_t)num();
            t = h ? terrad_twin_create(c, wx, wy, ww, wh, h, err) : NULL;
            free(h);
            if (!t)
                return die("create");
        } else if (strcmp(word, "base") == 0) {
            if (!(t = terrad_twin_create(c, wx, wy, ww, wh, NULL, err)))
                return die("create");
        } else if (strcmp(word, "collider") == 0) {
            int id = (int)num();
            char shape[16];
            if (scanf("%15s", shape) != 1)
                return die("collider");
            double r = num(), hl = num(), hx = num(), hy = num(), hz = num();
            if (terrad_twin_add_collider(t, id, shape, r, hl, hx, hy, hz, err) != 0)
                return die("collider");
        } else if (strcmp(word, "wheel") == 0) {
            int id = (int)num();
            double r = num(), hl = num(), count = num(), height = num(), thickness = num();
            if (terrad_twin_add_wheel(t, id, r, hl, count, height, thickness, err) != 0)
                return die("wheel");
        } else if (strcmp(word, "mesh") == 0) {
            if (read_mesh(t) != 0)
                return die("mesh");
        } else if (strcmp(word, "pose") == 0) {
            int id = (int)num();
            double p[7];
            for (int i = 0; i < 7; i++)
                p[i] = num();
            if (terrad_twin_set_pose(t, id, p[0], p[1], p[2], p[3], p[4], p[5], p[6], err) != 0)
                return die("pose");
        } else if (strcmp(word, "tick") == 0) {
            if (terrad_twin_tick(t, err) != 0)
                return die("tick");
        } else {
            fprintf(stderr, "twin_replay: unknown line \"%s\"\n", word);
            return 1;
        }
    }
    int32_t *out = t ? malloc((size_t)ww * wh * sizeof *out) : NULL;
    if (!out || terrad_twin_read(t, wx, wy, ww, wh, out, err) != 0)
        return die("read");
    FILE *f = fopen(argv[1], "wb");
    if (!f || fwrite(out, sizeof *out, (size_t)ww * wh, f) != (size_t)ww * wh || fclose(f) != 0)
        return die("write");
    free(out);
    terrad_twin_destroy(t);
    terrad_twin_config_free(c);
    return 0;
}
