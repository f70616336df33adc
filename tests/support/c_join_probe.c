/*
 * c_join_probe: a late joiner through the C client library (issue 32 item 2,
 * PROTOCOL.md "Base snapshots"), for test_join_base.py and bench_join.py.
 * Not a test itself.
 *
 *   c_join_probe PORT X Y W H slope|base|plain OUT [WORLD]
 *
 * Connects (terrad_client_connect_slope for "slope": base snapshots in
 * encoding 2 or 3, PROTOCOL.md "Slope snapshots"; terrad_client_connect_base
 * for "base": encoding 2; else terrad_client_connect_world), subscribes to the rectangle and polls
 * until its mirror is complete; writes the mirror's heights to OUT (w * h int32, little-endian,
 * row-major) and prints one JSON line: whether the server agreed to base snapshots (and to slope
 * snapshots), the DELTA bytes and frames received, the milliseconds from the subscribe request to a
 * complete mirror (the base rebuilt on the way included) and the snapshot's tick. Exit 1 on a
 * failure (the line says which step).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "terrad_client.h"

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

int main(int argc, char **argv)
{
    if (argc < 8) {
        fprintf(stderr, "usage: c_join_probe PORT X Y W H slope|base|plain OUT [WORLD]\n");
        return 2;
    }
    int x = atoi(argv[2]), y = atoi(argv[3]), w = atoi(argv[4]), h = atoi(argv[5]);
    int slope = strcmp(argv[6], "slope") == 0, base = slope || strcmp(argv[6], "base") == 0;
    const char *world = argc > 8 ? argv[8] : NULL;
    char err[512] = "";
    terrad_client_desc d = {.port = atoi(argv[1]), .name = "c_join_probe", .timeout_ms = 120000};
    terrad_client *c = slope  ? terrad_client_connect_slope(d, world, err, sizeof err)
                       : base ? terrad_client_connect_base(d, world, err, sizeof err)
                              : terrad_client_connect_world(d, world, err, sizeof err);
    if (!c) {
        printf("FAIL connect: %s\n", err);
        return 1;
    }
    uint64_t bytes0 = terrad_client_get_stats(c)->delta_bytes;
    uint64_t frames0 = terrad_client_get_stats(c)->delta_frames;
    double t0 = now_ms();
    uint32_t sid = 0;
    int rc = terrad_client_subscribe(c, x, y, (uint32_t)w, (uint32_t)h, &sid);
    if (rc != 0) {
        printf("FAIL subscribe: %d %s\n", rc, terrad_client_last_error(c));
        terrad_client_close(c);
        return 1;
    }
    while (!terrad_client_mirror_complete(c, sid) && now_ms() - t0 < 120000)
        if (terrad_client_poll(c, 50) < 0)
            break;
    double ms = now_ms() - t0;
    const terrad_mirror *m = terrad_client_mirror(c, sid);
    if (!terrad_client_mirror_complete(c, sid) || !m) {
        printf("FAIL complete: %s\n", terrad_client_last_error(c));
        terrad_client_close(c);
        return 1;
    }
    const terrad_client_stats *st = terrad_client_get_stats(c);
    FILE *f = fopen(argv[7], "wb");
    int wrote = f && fwrite(m->heights, sizeof *m->heights, (size_t)w * h, f) == (size_t)w * h;
    if (f)
        wrote &= fclose(f) == 0;
    if (!wrote) {
        printf("FAIL write %s\n", argv[7]);
        terrad_client_close(c);
        return 1;
    }
    printf("{\"base_on\": %d, \"slope_on\": %d, \"bytes\": %llu, \"frames\": %llu, "
           "\"ms\": %.1f, \"tick\": %llu, \"resyncs\": %llu}\n",
           terrad_client_base_snapshots(c), terrad_client_slope_snapshots(c),
           (unsigned long long)(st->delta_bytes - bytes0),
           (unsigned long long)(st->delta_frames - frames0), ms, (unsigned long long)st->delta_tick,
           (unsigned long long)st->resyncs);
    terrad_client_close(c);
    return 0;
}
