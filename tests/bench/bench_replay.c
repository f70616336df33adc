/*
 * bench_replay.c: seek to a tick of a long match (issue 32 item 3, goal: any
 * tick of a 1-hour match in <= 100 ms; docs/performance.md "Replay").
 *
 * A 1024² dunes world and its data directory (durability none, 1 MiB
 * segments — BENCH_REPLAY_SEGMENT_BYTES; each compaction a keyframe — and the
 * whole log retained: --replay-retain-bytes) take a
 * match of BENCH_REPLAY_TICKS ticks (default 36,000: 10 minutes at 60 Hz,
 * so that make bench stays short; 216000 is the hour of the goal) of 8
 * vehicles, each pressing four 6×10-cell wheel patches a unit deeper every
 * tick along its own lap, logged as the daemon logs a tick
 * (store_commit_tick). Then store_replay_rect — what GET /v1/heights?tick=N
 * runs — rebuilds a 256² window at ticks through the match, and the answer
 * is checked against the heights the world held at that tick (kept while
 * writing). Then the same ticks as a spectator starts at them
 * (store_cursor_open, spectate_seek) and plays the next second, with the
 * cells and bytes its cursor then holds (only the window's tiles: the log's
 * records are clipped to the window; BENCH_REPLAY_SIDE=4096 spreads the laps
 * over a 4096² world to show it), and a spectator that plays the whole match
 * from tick 0 (spectate_play: what its cursor holds at the end). Prints one
 * JSON line per seek (the best of two); never fails on speed (a rebuild that is not exact says so
 * on stderr: the test is tests/integration/store/test_replay_heights.py).
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "store/store.h"
#include "world/world.h"

/* BENCH_REPLAY_SIDE: the world's side (1024; a multiple of it spreads the
 * same laps, scaled, over the larger world, and the window with them) */
static int side = 1024, scale = 1;
#define VEHICLES 8
#define WHEELS 4
#define WIN 256
#define SEEKS 5

static double now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

/* Vehicle v's wheel k at tick t: a lap around its own ring, a cell every 4 ticks. */
static world_rect wheel(int v, int k, uint64_t t)
{
    int cx = (150 + (v % 4) * 240) * scale, cy = (256 + (v / 4) * 512) * scale,
        r = (60 + 8 * v) * scale;
    int step = (int)(t / 4 % (uint64_t)(8 * r));
    int side = step / (2 * r), along = step % (2 * r);
    int x = side == 0 ? cx - r + along : side == 1 ? cx + r : side == 2 ? cx + r - along : cx - r;
    int y = side == 0 ? cy - r : side == 1 ? cy - r + along : side == 2 ? cy + r : cy + r - along;
    return (world_rect){x + (k & 1) * 14, y + (k >> 1) * 20, 6, 10};
}

/* A spectator's start at tick (PROTOCOL.md "Spectate"): store_cursor_open
 * (the window's rebuild and the log position after it) and the window's
 * heights read (its snapshot), then the next second of the match (60
 * records read and applied, as the spectator thread plays them). The best of
 * two; 1 when the start was exact. */
static int spectate_seek(const char *dir, const world *w, uint64_t tick, uint64_t of,
                         world_rect win, const int32_t *want, int32_t *got)
{
    double best = 1e30, second = 1e30;
    int exact = 0;
    int64_t cells = 0;
    uint64_t bytes = 0;
    for (int rep = 0; rep < 2; rep++) {
        error_text err = {{0}};
        store_cursor *cur = NULL;
        double t1 = now_ms();
        int rc = store_cursor_open(dir, w, tick, win, NULL, &cur, &err);
        if (rc == 0)
            store_cursor_read(cur, win, got);
        double ms = now_ms() - t1;
        exact = rc == 0 && memcmp(got, want, sizeof(int32_t) * WIN * WIN) == 0;
        if (rc != 0)
            fprintf(stderr, "bench_replay: spectate at %llu: %s\n", (unsigned long long)tick,
                    err.message);
        uint64_t t;
        const world_rect *rects;
        int n, played = 0;
        while (rc == 0 && played < 60 &&
               store_cursor_next(cur, tick + 60, &t, &rects, &n, &err) == 1 &&
               store_cursor_apply(cur, &err) == 0)
            played++;
        double run = now_ms() - t1 - ms;
        if (rc == 0)
            cells = store_cursor_cells(cur, &bytes);
        store_cursor_close(cur);
        best = ms < best ? ms : best;
        second = run < second ? run : second;
    }
    printf("{\"bench\":\"spectate_seek\",\"tick\":%llu,\"of\":%llu,\"side\":%d,\"window\":%d,"
           "\"ms\":%.1f,\"next_60_ticks_ms\":%.1f,\"cursor_cells\":%lld,\"cursor_mib\":%.2f,"
           "\"exact\":%s,\"goal_ms\":100}\n",
           (unsigned long long)tick, (unsigned long long)of, side, WIN, best, second,
           (long long)cells, bytes / 1048576.0, exact ? "true" : "false");
    fflush(stdout);
    return exact;
}

/* A spectator that watches the whole match from tick 0 (every record read
 * and applied): the cells and bytes its cursor holds at the end. Without the
 * clip to the window, every tile the laps ever touched. */
static int spectate_play(const char *dir, const world *w, uint64_t of, world_rect win,
                         const int32_t *want, int32_t *got)
{
    error_text err = {{0}};
    store_cursor *cur = NULL;
    double t1 = now_ms();
    uint64_t t, played = 0, bytes = 0;
    const world_rect *rects;
    int n;
    if (store_cursor_open(dir, w, 0, win, NULL, &cur, &err) != 0) {
        fprintf(stderr, "bench_replay: spectate from 0: %s\n", err.message);
        return 0;
    }
    while (store_cursor_next(cur, of, &t, &rects, &n, &err) == 1 &&
           store_cursor_apply(cur, &err) == 0)
        played++;
    int64_t cells = store_cursor_cells(cur, &bytes);
    store_cursor_read(cur, win, got);
    int exact = store_cursor_tick(cur) == of && memcmp(got, want, sizeof(int32_t) * WIN * WIN) == 0;
    store_cursor_close(cur);
    printf("{\"bench\":\"spectate_play\",\"from\":0,\"ticks\":%llu,\"side\":%d,\"window\":%d,"
           "\"s\":%.1f,\"cursor_cells\":%lld,\"cursor_mib\":%.2f,\"exact\":%s}\n",
           (unsigned long long)played, side, WIN, (now_ms() - t1) / 1e3, (long long)cells,
           bytes / 1048576.0, exact ? "true" : "false");
    fflush(stdout);
    return exact;
}

int main(void)
{
    const char *env = getenv("BENCH_REPLAY_TICKS");
    uint64_t ticks = env ? strtoull(env, NULL, 10) : 36000;
    char dir[] = "/tmp/terrad-bench-replay-XXXXXX";
    if (!mkdtemp(dir)) {
        perror("bench_replay: mkdtemp");
        return 1;
    }
    world w;
    error_text err = {{0}};
    world_base_spec spec = {.kind = WORLD_BASE_DUNES,
                            .min_height_m = 0.2,
                            .max_height_m = 0.6,
                            .wavelength_m = 20,
                            .octaves = 4,
                            .seed = 7};
    const char *sides = getenv("BENCH_REPLAY_SIDE");
    side = sides && atoi(sides) >= 1024 ? atoi(sides) / 1024 * 1024 : 1024;
    scale = side / 1024;
    if (world_init(&w, side, side, 0.05, 10000, 0, &err) != 0 ||
        world_generate_base(&w, &spec, &err) != 0) {
        fprintf(stderr, "bench_replay: %s\n", err.message);
        return 1;
    }
    const char *seg = getenv("BENCH_REPLAY_SEGMENT_BYTES");
    store_config c = {.dir = dir,
                      .durability = STORE_NONE,
                      .segment_bytes = seg ? strtoll(seg, NULL, 10) : 1 << 20,
                      .retain_bytes = (int64_t)1 << 40};
    store_recovery rec;
    store *st = store_open(&c, &w, &rec, &err);
    if (!st) {
        fprintf(stderr, "bench_replay: %s\n", err.message);
        return 1;
    }
    world_rect win = {384 * scale, 128 * scale, WIN, WIN}; /* crossed by vehicles 0, 1 and 2 */
    uint64_t at[SEEKS];
    int32_t *want[SEEKS];
    for (int s = 0; s < SEEKS; s++) {
        at[s] = s == SEEKS - 1 ? ticks : ticks * (uint64_t)(2 * s + 1) / 10;
        want[s] = malloc(sizeof(int32_t) * WIN * WIN);
    }
    double t0 = now_ms();
    for (uint64_t t = 1; t <= ticks; t++) {
        world_rect rects[VEHICLES * WHEELS];
        int n = 0;
        for (int v = 0; v < VEHICLES; v++)
            for (int k = 0; k < WHEELS; k++) {
                world_rect r = rects[n++] = wheel(v, k, t);
                for (int y = r.y; y < r.y + r.h; y++)
                    for (int x = r.x; x < r.x + r.w; x++)
                        world_set_height(&w, x, y, world_height_at(&w, x, y) - 1);
            }
        if (store_commit_tick(st, &w, t, rects, n) != 0) {
            fprintf(stderr, "bench_replay: commit: %s\n", store_failure(st));
            return 1;
        }
        store_settle(st);
        for (int s = 0; s < SEEKS; s++)
            if (t == at[s])
                world_gather_window(&w, win, want[s]);
    }
    double write_ms = now_ms() - t0;
    store_close(st);
    char cmd[200];
    snprintf(cmd, sizeof cmd, "du -sk %s", dir);
    FILE *du = popen(cmd, "r");
    long kb = 0;
    if (du && fscanf(du, "%ld", &kb) != 1)
        kb = 0;
    if (du)
        pclose(du);
    printf("{\"bench\":\"replay_write\",\"ticks\":%llu,\"vehicles\":%d,\"segment_bytes\":%lld,"
           "\"dir_mib\":%.1f,\"write_s\":%.1f}\n",
           (unsigned long long)ticks, VEHICLES, (long long)c.segment_bytes, kb / 1024.0,
           write_ms / 1e3);
    int32_t *got = malloc(sizeof(int32_t) * WIN * WIN);
    int all_exact = 1;
    for (int s = 0; s < SEEKS; s++) {
        double best = 1e30;
        int exact = 0;
        for (int rep = 0; rep < 2; rep++) {
            double t1 = now_ms();
            int rc = store_replay_rect(dir, &w, at[s], win, got, NULL, &err);
            double ms = now_ms() - t1;
            best = ms < best ? ms : best;
            exact = rc == 0 && memcmp(got, want[s], sizeof(int32_t) * WIN * WIN) == 0;
            if (rc != 0)
                fprintf(stderr, "bench_replay: tick %llu: %s\n", (unsigned long long)at[s],
                        err.message);
        }
        printf("{\"bench\":\"replay_seek\",\"tick\":%llu,\"of\":%llu,\"window\":%d,"
               "\"ms\":%.1f,\"exact\":%s,\"goal_ms\":100}\n",
               (unsigned long long)at[s], (unsigned long long)ticks, WIN, best,
               exact ? "true" : "false");
        fflush(stdout);
        all_exact &= exact;
    }
    for (int s = 0; s < SEEKS; s++)
        all_exact &= spectate_seek(dir, &w, at[s], ticks, win, want[s], got);
    all_exact &= spectate_play(dir, &w, ticks, win, want[SEEKS - 1], got);
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0)
        fprintf(stderr, "bench_replay: could not remove %s\n", dir);
    for (int s = 0; s < SEEKS; s++)
        free(want[s]);
    free(got);
    world_free(&w);
    if (!all_exact)
        fprintf(stderr, "bench_replay: a rebuild was NOT exact (see \"exact\" above)\n");
    return 0; /* a bench prints; it never fails */
}
