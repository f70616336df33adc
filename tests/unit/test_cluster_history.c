/*
 * test_cluster_history.c: a world's past read back from JetStream
 * (cluster_history.c, through store.h's store_history) against a real
 * nats-server, beside the store that writes it (node a commits, node b
 * reads, as a spectator's thread and ?tick=N do on the owner):
 *
 *   - before any compaction every tick from 0 is rebuilt exactly (the heights
 *     a kept at that tick), for the whole world and for a window, and a
 *     cursor from a middle tick steps through the records one tick at a time,
 *     equal at each;
 *   - after a compaction (snapshots, the log below them purged): a tick
 *     before the snapshots' is refused as gone (1, "compacted"), tick 0 is
 *     still the base, and every tick from the snapshots' on is exact — from
 *     the tile snapshots and the log after them;
 *   - a cursor whose next records a later compaction purges ends with -1
 *     "compacted away" instead of skipping them;
 *   - a cancelled open returns STORE_CANCELLED.
 * Without the reader nothing here opens (store_history_rect needs one).
 *
 * Exit 77 (skipped) when nats-server is not installed.
 */
// ctest-timeout: 240
#include "test_params.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cluster/cluster.h"
#include "world/world.h"
#include "check.h"
#include "nats_test.h"

#define W 300 /* 2 x 1 tiles of 256, the last column partial */
#define H 200
#define TICKS 60
#define COMPACT 20

static uint32_t rng = 777u;
static int32_t *kept[TICKS + 1]; /* the heights a held at the end of each tick */

static void keep(const world *w, uint64_t t)
{
    kept[t] = malloc(4 * (size_t)W * H);
    if (!kept[t])
        exit(2);
    world_gather_window(w, (world_rect){0, 0, W, H}, kept[t]);
}

/* r of the heights kept at tick t equals got. */
static int same_as_kept(uint64_t t, world_rect r, const int32_t *got)
{
    for (int y = 0; y < r.h; y++)
        if (memcmp(kept[t] + (size_t)(r.y + y) * W + r.x, got + (size_t)y * r.w, 4 * (size_t)r.w))
            return 0;
    return 1;
}

/* Commits ticks from..to on s (waiting for each compaction, so they run at
 * every COMPACT records exactly). */
static int commit(cluster_store *s, world *w, uint64_t from, uint64_t to)
{
    world_rect rects[3];
    error_text err = {{0}};
    int ok = 1;
    for (uint64_t t = from; t <= to; t++) {
        int n = test_deform_random(w, &rng, rects);
        ok &= cluster_store_commit_tick(s, w, t, rects, n, &err) == CLUSTER_OK;
        cluster_store_wait_compaction(s);
        keep(w, t);
    }
    return ok;
}

/* Every tick in from..to rebuilt by store_history_rect over r equals the kept heights. */
static int rebuilds_exact(const store_history *h, const world *base, uint64_t from, uint64_t to,
                          world_rect r, error_text *err)
{
    int32_t *got = malloc(4 * (size_t)r.w * r.h);
    int ok = got != NULL;
    for (uint64_t t = from; ok && t <= to; t++)
        ok = store_history_rect(h, base, t, r, got, NULL, err) == 0 && same_as_kept(t, r, got);
    free(got);
    return ok;
}

/* A cursor of r from tick `from`, stepped to `to`: the kept heights at each. */
static int steps_exact(const store_history *h, const world *base, uint64_t from, uint64_t to,
                       world_rect r, error_text *err)
{
    store_cursor *cur = NULL;
    int32_t *got = malloc(4 * (size_t)r.w * r.h);
    int ok = got && store_history_cursor(h, base, from, r, NULL, &cur, err) == 0;
    if (ok) {
        store_cursor_read(cur, r, got);
        ok = same_as_kept(from, r, got);
    }
    for (uint64_t t = from + 1; ok && t <= to; t++) {
        uint64_t rt = 0;
        const world_rect *rects;
        int n;
        ok = store_cursor_next(cur, t, &rt, &rects, &n, err) == 1 && rt == t &&
             store_cursor_apply(cur, err) == 0;
        if (ok) {
            store_cursor_read(cur, r, got);
            ok = same_as_kept(t, r, got);
        }
    }
    store_cursor_close(cur);
    free(got);
    return ok;
}

static int always(void *ctx)
{
    (void)ctx;
    return 1;
}

static void test_history(cluster *a, cluster *b)
{
    error_text err = {{0}};
    world live, base;
    test_dunes_world(&live, W, H, 11);
    test_dunes_world(&base, W, H, 11);
    keep(&live, 0);
    store_recovery rec;
    cluster_store_config cfg = {.compact_records = COMPACT};
    cluster_store *s = cluster_store_open(a, "past", &live, &cfg, &rec, &err);
    CHECK(s != NULL, "a opens a new world: %s", err.message);
    store_history h;
    CHECK(cluster_history_make(b, "past", &h, &err) == 0 && store_history_kept(&h),
          "b makes the world's reader: %s", err.message);
    if (!s)
        return;
    world_rect all = {0, 0, W, H}, window = {230, 50, 60, 80}; /* across the tiles' edge */

    CHECK(commit(s, &live, 1, COMPACT - 1), "ticks 1..%d committed", COMPACT - 1);
    CHECK(rebuilds_exact(&h, &base, 0, COMPACT - 1, all, &err),
          "before a compaction every tick from 0 is rebuilt exactly: %s", err.message);
    CHECK(rebuilds_exact(&h, &base, 0, COMPACT - 1, window, &err), "and a window of it: %s",
          err.message);
    CHECK(steps_exact(&h, &base, 7, COMPACT - 1, window, &err),
          "a cursor from tick 7 steps exactly through the records: %s", err.message);

    CHECK(commit(s, &live, COMPACT, COMPACT + 10), "ticks to %d committed (a compaction at %d)",
          COMPACT + 10, COMPACT);
    int64_t compactions = 0, tiles = 0;
    cluster_store_compactions(s, &compactions, &tiles);
    CHECK(compactions == 1, "one compaction ran (%lld)", (long long)compactions);
    int32_t *got = malloc(4 * (size_t)W * H);
    int rc = store_history_rect(&h, &base, 10, all, got, NULL, &err);
    CHECK(rc == 1 && strstr(err.message, "compacted"),
          "a tick before the snapshots is no longer held (%d: %s)", rc, err.message);
    CHECK(store_history_rect(&h, &base, 0, all, got, NULL, &err) == 0 && same_as_kept(0, all, got),
          "tick 0 is the base, still: %s", err.message);
    CHECK(rebuilds_exact(&h, &base, COMPACT, COMPACT + 10, all, &err),
          "every tick from the snapshots' on is exact (snapshots, then the log): %s", err.message);
    CHECK(steps_exact(&h, &base, COMPACT + 2, COMPACT + 10, window, &err),
          "and a cursor from there steps exactly: %s", err.message);

    /* a cursor at COMPACT + 10, then the log after it compacted away under it */
    store_cursor *cur = NULL;
    rc = store_history_cursor(&h, &base, COMPACT + 10, window, NULL, &cur, &err);
    CHECK(rc == 0, "a cursor at tick %d: %s", COMPACT + 10, err.message);
    CHECK(commit(s, &live, COMPACT + 11, 2 * COMPACT + 5),
          "ticks to %d committed (a compaction at %d)", 2 * COMPACT + 5, 2 * COMPACT);
    uint64_t rt = 0;
    const world_rect *rects;
    int n;
    rc = cur ? store_cursor_next(cur, 2 * COMPACT + 5, &rt, &rects, &n, &err) : -9;
    CHECK(rc == -1 && strstr(err.message, "compacted away"),
          "its next record was purged: -1, never a skipped record (%d, tick %llu: %s)", rc,
          (unsigned long long)rt, err.message);
    store_cursor_close(cur);

    store_cancel cancel = {.cancelled = always};
    rc = store_history_cursor(&h, &base, 2 * COMPACT + 2, window, &cancel, &cur, &err);
    CHECK(rc == STORE_CANCELLED && !cur, "a cancelled open: STORE_CANCELLED (%d, %s)", rc,
          err.message);

    free(got);
    store_history_release(&h);
    cluster_store_close(s);
    world_free(&live);
    world_free(&base);
}

int main(void)
{
    if (!nats_installed()) {
        printf("nats-server is not installed: skipped\n");
        return 77;
    }
    nats_proc one[1];
    cluster *a, *b;
    error_text err = {{0}};
    int up = nats_one_two_nodes("test_cluster_history", one, &a, &b, &err) == 0;
    CHECK(up, "two nodes connect: %s", err.message);
    if (up)
        test_history(a, b);
    cluster_close(a);
    cluster_close(b);
    nats_stop(one, SIGTERM);
    nats_tmp_remove();
    for (int t = 0; t <= TICKS; t++)
        free(kept[t]);
    return check_report();
}
