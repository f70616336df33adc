/*
 * test_cluster_store.c: a world's store on JetStream (cluster_store.c)
 * against a real nats-server: node a commits ticks (compacting into tile
 * snapshots and purging the log on the way); node b opens the world — a
 * failover — and holds exactly a's heights and tick; a's next commit is then
 * refused as fenced and leaves the log without it; b goes on, and a third
 * opening equals b. The log really is purged (fewer records than ticks) and
 * recovery still equals the live world; two worlds do not mix.
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

#define W 600 /* 3 x 2 tiles of 256, the last column and row partial */
#define H 300

static uint32_t rng = 4242u;

/* A tick: 1..3 random rectangles pushed down by a few units; returns n. */
static int deform(world *w, world_rect *rects)
{
    int n = 1 + (int)(test_next_random(&rng) % 3);
    for (int i = 0; i < n; i++) {
        world_rect r = {
            (int)(test_next_random(&rng) % (W - 40)), (int)(test_next_random(&rng) % (H - 40)),
            1 + (int)(test_next_random(&rng) % 40), 1 + (int)(test_next_random(&rng) % 40)};
        int32_t *v = malloc(4 * (size_t)r.w * r.h);
        world_gather_window(w, r, v);
        for (int k = 0; k < r.w * r.h; k++)
            v[k] -= 1 + (int32_t)(test_next_random(&rng) % 50);
        world_scatter_window(w, r, v);
        free(v);
        rects[i] = r;
    }
    return n;
}

static int same_heights(const world *a, const world *b)
{
    world_rect all = {0, 0, W, H};
    int32_t *va = malloc(4 * (size_t)W * H), *vb = malloc(4 * (size_t)W * H);
    world_gather_window(a, all, va);
    world_gather_window(b, all, vb);
    int same = memcmp(va, vb, 4 * (size_t)W * H) == 0;
    free(va);
    free(vb);
    return same;
}

static int count_record(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    (void)seq, (void)data, (void)len;
    (*(int *)ctx)++;
    return 0;
}

static int log_records(cluster *cl, const char *name)
{
    error_text err = {{0}};
    int n = 0;
    cluster_wal *w = cluster_wal_open(cl, name, &err);
    if (cluster_wal_read(w, 1, count_record, &n, &err) != CLUSTER_OK)
        n = -1;
    cluster_wal_close(w);
    return n;
}

static void test_failover(cluster *a, cluster *b)
{
    error_text err = {{0}};
    world wa, wb, wc;
    test_dunes_world(&wa, W, H, 7);
    store_recovery rec;
    cluster_store_config cfg = {.compact_records = 20};
    cluster_store *sa = cluster_store_open(a, "dunes", &wa, &cfg, &rec, &err);
    CHECK(sa != NULL && rec.tick == 0 && rec.records_replayed == 0, "a opens a new world: %s",
          err.message);
    if (!sa)
        return;
    world_rect rects[3];
    int ok = 1;
    for (uint64_t t = 1; t <= 70; t++) {
        int n = deform(&wa, rects);
        ok &= cluster_store_commit_tick(sa, &wa, t, rects, n, &err) == CLUSTER_OK;
        /* here commits take microseconds; at 60 Hz a compaction is done long
         * before the next boundary: wait, so exactly three run */
        cluster_store_wait_compaction(sa);
    }
    CHECK(ok, "a commits 70 ticks: %s", err.message);
    cluster_store_wait_compaction(sa);
    int64_t compactions = 0, tiles = 0;
    cluster_store_compactions(sa, &compactions, &tiles);
    CHECK(compactions == 3 && tiles > 0, "3 compactions ran (%lld, %lld tiles)",
          (long long)compactions, (long long)tiles);
    int records = log_records(b, "dunes");
    CHECK(records > 0 && records < 70, "the log was purged below the snapshots (%d records)",
          records);
    double p50 = 0, p99 = 0;
    cluster_store_commit_ms(sa, &p50, &p99);
    CHECK(p50 > 0 && p99 >= p50, "commit latency measured (p50 %.2f ms, p99 %.2f ms)", p50, p99);
    printf("commit latency on one server: p50 %.2f ms, p99 %.2f ms\n", p50, p99);

    /* failover: b loads the snapshots and the log */
    test_dunes_world(&wb, W, H, 7);
    cluster_store *sb = cluster_store_open(b, "dunes", &wb, &cfg, &rec, &err);
    CHECK(sb != NULL, "b takes the world over: %s", err.message);
    if (!sb) {
        cluster_store_close(sa);
        world_free(&wa);
        world_free(&wb);
        return;
    }
    CHECK(rec.tick == 70 && cluster_store_tick(sb) == 70, "b continues from tick 70 (%llu)",
          (unsigned long long)rec.tick);
    CHECK(rec.tiles_loaded > 0, "b loaded %d tile snapshots", rec.tiles_loaded);
    CHECK(same_heights(&wa, &wb), "b's heights equal a's");
    printf("recovery: %d tiles, %lld records in %.1f ms\n", rec.tiles_loaded,
           (long long)rec.records_replayed, rec.ms);

    /* a, deposed, tries one more tick */
    int before = log_records(b, "dunes");
    int n = deform(&wa, rects);
    CHECK(cluster_store_commit_tick(sa, &wa, 71, rects, n, &err) == CLUSTER_FENCED,
          "the deposed owner's commit is refused: %s", err.message);
    CHECK(log_records(b, "dunes") == before, "and the log holds nothing of it");
    CHECK(cluster_store_fenced(sa) && !cluster_store_writable(sa) &&
              strstr(cluster_store_failure(sa), "fenced off"),
          "it stays refused and says why: %s", cluster_store_failure(sa));
    CHECK(!cluster_store_writable(sb) && strstr(cluster_store_failure(sb), "lease"),
          "a store whose node holds no lease is not writable: %s", cluster_store_failure(sb));
    cluster_store_close(sa);
    world_free(&wa);

    ok = 1;
    for (uint64_t t = 71; t <= 100; t++) {
        n = deform(&wb, rects);
        ok &= cluster_store_commit_tick(sb, &wb, t, rects, n, &err) == CLUSTER_OK;
    }
    CHECK(ok, "b commits ticks 71..100: %s", err.message);
    cluster_store_wait_compaction(sb);
    test_dunes_world(&wc, W, H, 7);
    cluster_store *sc = cluster_store_open(a, "dunes", &wc, &cfg, &rec, &err);
    CHECK(sc && rec.tick == 100 && same_heights(&wb, &wc),
          "a third opening equals b at tick 100 (%llu): %s", (unsigned long long)rec.tick,
          err.message);
    n = deform(&wb, rects);
    CHECK(cluster_store_commit_tick(sb, &wb, 101, rects, n, &err) == CLUSTER_FENCED,
          "and fences b off in turn");
    cluster_store_close(sb);
    cluster_store_close(sc);
    world_free(&wb);
    world_free(&wc);
}

static void test_two_worlds(cluster *a)
{
    error_text err = {{0}};
    world w1, w2, r1, r2;
    test_dunes_world(&w1, W, H, 1);
    test_dunes_world(&w2, W, H, 2);
    store_recovery rec;
    cluster_store *s1 = cluster_store_open(a, "one", &w1, NULL, &rec, &err);
    cluster_store *s2 = cluster_store_open(a, "two", &w2, NULL, &rec, &err);
    CHECK(s1 && s2, "two worlds open: %s", err.message);
    if (!s1 || !s2)
        return;
    world_rect rects[3];
    for (uint64_t t = 1; t <= 10; t++) {
        int n = deform(&w1, rects);
        cluster_store_commit_tick(s1, &w1, t, rects, n, &err);
        n = deform(&w2, rects);
        cluster_store_commit_tick(s2, &w2, t * 2, rects, n, &err);
    }
    cluster_store_close(s1);
    cluster_store_close(s2);
    test_dunes_world(&r1, W, H, 1);
    test_dunes_world(&r2, W, H, 2);
    s1 = cluster_store_open(a, "one", &r1, NULL, &rec, &err);
    CHECK(s1 && rec.tick == 10 && same_heights(&w1, &r1), "world one recovers alone");
    s2 = cluster_store_open(a, "two", &r2, NULL, &rec, &err);
    CHECK(s2 && rec.tick == 20 && same_heights(&w2, &r2), "world two recovers alone");
    cluster_store_close(s1);
    cluster_store_close(s2);
    world_free(&w1);
    world_free(&w2);
    world_free(&r1);
    world_free(&r2);
}

int main(void)
{
    if (!nats_installed()) {
        printf("nats-server is not installed: skipped\n");
        return 77;
    }
    nats_tmp_root("test_cluster_store");
    nats_proc one[1];
    nats_init(one, 1);
    nats_start_all(one, 1);
    char urls[64];
    urls_of(one, 1, urls, sizeof urls);
    error_text err = {{0}};
    cluster_config ca = {.urls = urls, .node = "a"}, cb = {.urls = urls, .node = "b"};
    cluster *a = cluster_connect(&ca, &err), *b = a ? cluster_connect(&cb, &err) : NULL;
    CHECK(a && b, "two nodes connect: %s", err.message);
    if (a && b) {
        test_failover(a, b);
        test_two_worlds(a);
    }
    cluster_close(a);
    cluster_close(b);
    nats_stop(one, SIGTERM);
    nats_tmp_remove();
    return check_report();
}
