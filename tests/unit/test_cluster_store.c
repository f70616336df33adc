/*
 * test_cluster_store.c: a world's store on JetStream (cluster_store.c)
 * against a real nats-server: node a commits ticks (compacting into tile
 * snapshots and purging the log on the way); node b opens the world — a
 * failover — and holds exactly a's heights and tick; a's next commit is then
 * refused as fenced and leaves the log without it; b goes on, and a third
 * opening equals b. The log really is purged (fewer records than ticks) and
 * recovery still equals the live world; two worlds do not mix. A world with
 * soil state (the bekker model's) gets it back exactly, from snapshots and
 * records; so does a world's compaction memory (issue 28), its log going
 * on from records without it; a log and snapshots of format 1 (heights only,
 * written by hand here as older nodes wrote them) still load. A log that
 * lacks the record the snapshot index covers is refused, not replayed. On
 * three servers killed and started again, a world keeps its records when
 * another world's compaction removed its log below them.
 *
 * Exit 77 (skipped) when nats-server is not installed.
 */
// ctest-timeout: 240
#include "test_params.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <zstd.h>

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
    return test_deform_random(w, &rng, rects);
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

/* A stream whose answer lacks the record the snapshot index covers (as a
 * NATS leader answered in a chaos run, right after servers were killed and
 * started again: its log "ended" before the world's records) is not
 * recovered from: the opening fails, to be tried again, rather than
 * replaying what is there and going on from a tick that was already used. */
static void test_index_ahead_of_log(cluster *a)
{
    error_text err = {{0}};
    world w, r;
    test_dunes_world(&w, W, H, 3);
    store_recovery rec;
    cluster_store_config cfg = {.compact_records = 10};
    cluster_store *s = cluster_store_open(a, "gap", &w, &cfg, &rec, &err);
    CHECK(s != NULL, "a opens world gap: %s", err.message);
    if (!s)
        return;
    world_rect rects[3];
    for (uint64_t t = 1; t <= 15; t++) {
        int n = deform(&w, rects);
        cluster_store_commit_tick(s, &w, t, rects, n, &err);
        cluster_store_wait_compaction(s);
    }
    cluster_store_close(s);
    uint64_t covers = 0;
    int(*tiles)[2] = NULL;
    int count = 0;
    CHECK(cluster_snapshot_index_get(a, "gap", &covers, &tiles, &count, &err) == 1 && covers > 0,
          "a compaction wrote the index (covers %llu)", (unsigned long long)covers);
    free(tiles);
    CHECK(cluster_log_purge_below(a, "gap", covers + 1, &err) == CLUSTER_OK,
          "the record the index covers is gone: %s", err.message);
    test_dunes_world(&r, W, H, 3);
    err.message[0] = '\0';
    s = cluster_store_open(a, "gap", &r, &cfg, &rec, &err);
    CHECK(s == NULL && strstr(err.message, "that the snapshot index covers is not there"),
          "not recovered from a log without it: %s", err.message);
    cluster_store_close(s);
    world_free(&w);
    world_free(&r);
}

/* Opens world name on urls, trying for up to 60 s (a NATS cluster just
 * started elects its leaders first); NULL if it never opened. */
static cluster_store *open_when_ready(const char *urls, cluster **cl, const char *name, world *w,
                                      store_recovery *rec, error_text *err)
{
    cluster_config cc = {.urls = urls, .node = "late"};
    for (int i = 0; i < 120; i++) {
        if (!*cl)
            *cl = cluster_connect(&cc, err);
        cluster_store *s = *cl ? cluster_store_open(*cl, name, w, NULL, rec, err) : NULL;
        if (s)
            return s;
        usleep(500000);
    }
    return NULL;
}

/* Three NATS servers (clustered: raft): one world compacts, which removes its
 * log below the covered record, while another world's records sit below that
 * sequence; then every server is killed (-9) and started again, so each
 * replays its stream's raft log. nats-server before 2.9.18 replayed a purge
 * filtered by subject as a purge of the whole stream (nats-server #4196):
 * the other world's records were gone after the restart. Removed message by
 * message (cluster_log_purge_below), they stay. */
static void test_restart_keeps_other_worlds(void)
{
    nats_proc three[3];
    nats_init(three, 3);
    nats_start_all(three, 3);
    char urls[256];
    urls_of(three, 3, urls, sizeof urls);
    error_text err = {{0}};
    cluster_config cc = {.urls = urls, .node = "a"};
    cluster *cl = cluster_connect(&cc, &err);
    CHECK(cl != NULL, "connects to three servers: %s", err.message);
    world keep, busy, back;
    test_dunes_world(&keep, W, H, 5);
    test_dunes_world(&busy, W, H, 6);
    store_recovery rec;
    cluster_store_config quiet = {.compact_records = 1000}, often = {.compact_records = 10};
    cluster_store *sk = cl ? cluster_store_open(cl, "keep", &keep, &quiet, &rec, &err) : NULL;
    cluster_store *sb = cl ? cluster_store_open(cl, "busy", &busy, &often, &rec, &err) : NULL;
    CHECK(sk && sb, "two worlds open: %s", err.message);
    world_rect rects[3];
    for (uint64_t t = 1; sk && sb && t <= 30; t++) {
        int n = deform(&keep, rects);
        cluster_store_commit_tick(sk, &keep, t, rects, n, &err);
    }
    for (uint64_t t = 1; sk && sb && t <= 25; t++) {
        int n = deform(&busy, rects);
        cluster_store_commit_tick(sb, &busy, t, rects, n, &err);
        cluster_store_wait_compaction(sb);
    }
    int64_t compactions = 0, tiles = 0;
    if (sb)
        cluster_store_compactions(sb, &compactions, &tiles);
    CHECK(compactions >= 2, "busy compacted past keep's records (%lld)", (long long)compactions);
    cluster_store_close(sk);
    cluster_store_close(sb);
    cluster_close(cl);
    for (int i = 0; i < 3; i++)
        nats_stop(&three[i], SIGKILL);
    for (int i = 0; i < 3; i++)
        nats_start(three, i, 3);
    cl = NULL;
    test_dunes_world(&back, W, H, 5);
    sk = open_when_ready(urls, &cl, "keep", &back, &rec, &err);
    CHECK(sk && rec.tick == 30 && rec.records_replayed == 30 && same_heights(&keep, &back),
          "after every server restarted, keep has its 30 records (tick %llu, %lld replayed): %s",
          (unsigned long long)rec.tick, (long long)rec.records_replayed, err.message);
    cluster_store_close(sk);
    cluster_close(cl);
    for (int i = 0; i < 3; i++)
        nats_stop(&three[i], SIGTERM);
    world_free(&keep);
    world_free(&busy);
    world_free(&back);
}

/* Random soil state in the rectangles deform() chose (as the bekker model
 * leaves beside its heights). */
static void press_soil(world *w, const world_rect *rects, int n)
{
    for (int i = 0; i < n; i++) {
        size_t k = (size_t)rects[i].w * rects[i].h * WORLD_SOIL_FIELDS;
        int32_t *v = malloc(4 * k);
        for (size_t j = 0; j < k; j++)
            v[j] = (int32_t)(test_next_random(&rng) % 1000);
        world_layer_scatter(w, WORLD_LAYER_SOIL, rects[i], v);
        free(v);
    }
}

/* 1 when a's layer equals b's, cell for cell and in every field's kept sum. */
static int same_layer(const world *a, const world *b, world_layer_id layer)
{
    world_rect all = {0, 0, W, H};
    int fields = world_layer_fields(layer);
    size_t k = (size_t)W * H * (size_t)fields;
    int32_t *va = malloc(4 * k), *vb = malloc(4 * k);
    world_layer_gather(a, layer, all, va);
    world_layer_gather(b, layer, all, vb);
    int same = memcmp(va, vb, 4 * k) == 0;
    for (int f = 0; f < fields; f++)
        same &= world_layer_sum(a, layer, f) == world_layer_sum(b, layer, f);
    free(va);
    free(vb);
    return same;
}

/* A bekker world's soil state: committed with the heights, compacted into
 * snapshots, and recovered exactly by another node. */
static void test_soil(cluster *a, cluster *b)
{
    error_text err = {{0}};
    world wa, wb;
    test_dunes_world(&wa, W, H, 3);
    world_layer_enable(&wa, WORLD_LAYER_SOIL);
    store_recovery rec;
    cluster_store_config cfg = {.compact_records = 15};
    cluster_store *sa = cluster_store_open(a, "soil", &wa, &cfg, &rec, &err);
    CHECK(sa != NULL, "a opens a world with soil state: %s", err.message);
    if (!sa) {
        world_free(&wa);
        return;
    }
    world_rect rects[3];
    int ok = 1;
    for (uint64_t t = 1; t <= 40; t++) {
        int n = deform(&wa, rects);
        press_soil(&wa, rects, n);
        ok &= cluster_store_commit_tick(sa, &wa, t, rects, n, &err) == CLUSTER_OK;
        cluster_store_wait_compaction(sa);
    }
    CHECK(ok && world_layer_sum(&wa, WORLD_LAYER_SOIL, 0) > 0,
          "a commits 40 ticks of heights and soil: %s", err.message);
    test_dunes_world(&wb, W, H, 3); /* fresh soil: recovery alone must bring it */
    cluster_store *sb = cluster_store_open(b, "soil", &wb, &cfg, &rec, &err);
    CHECK(sb && rec.tick == 40 && rec.tiles_loaded > 0 && rec.records_replayed > 0,
          "b takes it over from %d snapshots and %lld records: %s", rec.tiles_loaded,
          (long long)rec.records_replayed, err.message);
    CHECK(sb && same_heights(&wa, &wb) && same_layer(&wa, &wb, WORLD_LAYER_SOIL),
          "b's heights and soil state (every cell, every field) equal a's");
    cluster_store_close(sa);
    cluster_store_close(sb);
    world_free(&wa);
    world_free(&wb);
}

/* Random compaction memory in the rectangles deform() chose (as the persson
 * models and sumner leave beside their heights). */
static void press_memory(world *w, const world_rect *rects, int n)
{
    for (int i = 0; i < n; i++) {
        size_t k = (size_t)rects[i].w * rects[i].h;
        int32_t *v = malloc(4 * k);
        world_layer_gather(w, WORLD_LAYER_COMPACTION, rects[i], v);
        for (size_t j = 0; j < k; j++)
            v[j] = (v[j] + (int32_t)(test_next_random(&rng) % 900)) % (WORLD_COMPACTION_MAX + 1);
        world_layer_scatter(w, WORLD_LAYER_COMPACTION, rects[i], v);
        free(v);
    }
}

/* Counts the log's records by magic: [0] TRC2, [1] TRC3. */
static int count_magic(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    int *n = ctx;
    (void)seq;
    if (len >= 4)
        n[memcmp(data, "TRC3", 4) == 0 ? 1 : 0]++;
    return 0;
}

/* The compaction memory (issue 28): a world written as nodes before it wrote
 * a persson world (TRC2 records and TRS2 snapshots without the memory) goes
 * on with the memory (TRC3, TRS3), and another node recovers every cell's
 * memory exactly, from snapshots and records. */
static void test_compaction_memory(cluster *a, cluster *b)
{
    error_text err = {{0}};
    world wa, wb;
    test_dunes_world(&wa, W, H, 4);
    store_recovery rec;
    cluster_store_config cfg = {.compact_records = 15};
    cluster_store *sa = cluster_store_open(a, "memory", &wa, &cfg, &rec, &err);
    CHECK(sa != NULL, "a opens a world: %s", err.message);
    if (!sa) {
        world_free(&wa);
        return;
    }
    world_rect rects[3];
    int ok = 1;
    for (uint64_t t = 1; t <= 50; t++) {
        if (t == 21) /* the old records first: a world without the layer */
            ok &= world_layer_enable(&wa, WORLD_LAYER_COMPACTION) == 0;
        int n = deform(&wa, rects);
        if (t > 20)
            press_memory(&wa, rects, n);
        ok &= cluster_store_commit_tick(sa, &wa, t, rects, n, &err) == CLUSTER_OK;
        cluster_store_wait_compaction(sa);
    }
    int magic[2] = {0, 0};
    cluster_wal *wal = cluster_wal_open(a, "memory", &err);
    cluster_wal_read(wal, 1, count_magic, magic, &err);
    cluster_wal_close(wal);
    CHECK(ok && world_layer_sum(&wa, WORLD_LAYER_COMPACTION, 0) > 0 && magic[1] > 0,
          "a commits 20 ticks without and 30 with memory (the log holds %d TRC2, %d TRC3): %s",
          magic[0], magic[1], err.message);
    test_dunes_world(&wb, W, H, 4); /* no memory: recovery alone must bring it */
    cluster_store *sb = cluster_store_open(b, "memory", &wb, &cfg, &rec, &err);
    CHECK(sb && rec.tick == 50 && rec.tiles_loaded > 0 && rec.records_replayed > 0,
          "b takes it over from %d snapshots and %lld records: %s", rec.tiles_loaded,
          (long long)rec.records_replayed, err.message);
    CHECK(sb && same_heights(&wa, &wb) && same_layer(&wa, &wb, WORLD_LAYER_COMPACTION),
          "b's heights and compaction memory (every cell, Σ %lld) equal a's",
          (long long)world_layer_sum(&wb, WORLD_LAYER_COMPACTION, 0));
    cluster_store_close(sa);
    cluster_store_close(sb);
    world_free(&wa);
    world_free(&wb);
}

/* Format 1 as nodes before the soil state wrote it, by hand: records
 * "TRC1" | tick | rects | raw bytes | CRC32C | zstd(x, y, w, h, heights...),
 * snapshots "TRS1" | tx, ty, w, h | raw bytes | CRC32C | zstd(heights). */
static size_t v1_record(const world *w, uint64_t tick, const world_rect *rects, int n,
                        uint8_t **out)
{
    size_t raw = 0;
    for (int i = 0; i < n; i++)
        raw += 16 + 4 * (size_t)rects[i].w * rects[i].h;
    uint8_t *r = malloc(raw), *p = r;
    for (int i = 0; i < n; i++) {
        int32_t hdr[4] = {rects[i].x, rects[i].y, rects[i].w, rects[i].h};
        memcpy(p, hdr, 16);
        world_gather_window(w, rects[i], (int32_t *)(void *)(p + 16));
        p += 16 + 4 * (size_t)rects[i].w * rects[i].h;
    }
    size_t bound = ZSTD_compressBound(raw);
    *out = malloc(24 + bound);
    size_t z = ZSTD_compress(*out + 24, bound, r, raw, 1);
    uint32_t words[3] = {(uint32_t)n, (uint32_t)raw, store_crc32c(0, r, raw)};
    memcpy(*out, "TRC1", 4);
    memcpy(*out + 4, &tick, 8);
    memcpy(*out + 12, words, 12);
    free(r);
    return 24 + z;
}

static size_t v1_snapshot(const world *w, int tx, int ty, uint8_t **out)
{
    world_rect r = world_tile_rect(w, tx, ty);
    size_t raw = 4 * (size_t)r.w * r.h, bound = ZSTD_compressBound(raw);
    int32_t *v = malloc(raw);
    world_gather_window(w, r, v);
    *out = malloc(28 + bound);
    size_t z = ZSTD_compress(*out + 28, bound, v, raw, 1);
    int32_t hdr[4] = {tx, ty, r.w, r.h};
    uint32_t words[2] = {(uint32_t)raw, store_crc32c(0, v, raw)};
    memcpy(*out, "TRS1", 4);
    memcpy(*out + 4, hdr, 16);
    memcpy(*out + 20, words, 8);
    free(v);
    return 28 + z;
}

static void test_format1(cluster *a)
{
    error_text err = {{0}};
    world we, wr;
    test_dunes_world(&we, W, H, 5);
    cluster_wal *wal = cluster_wal_open(a, "old", &err);
    world_rect rects[3];
    uint64_t seq = 0, first = 0;
    int ok = wal != NULL;
    for (uint64_t t = 1; ok && t <= 6; t++) {
        int n = deform(&we, rects);
        uint8_t *rec = NULL;
        size_t len = v1_record(&we, t, rects, n, &rec);
        ok = cluster_wal_append(wal, rec, len, &seq, &err) == CLUSTER_OK;
        free(rec);
        if (t == 3) { /* every tile as of record 3 (records 1, 2 then purgeable) */
            int tiles[6][2], count = 0;
            first = seq;
            for (int ty = 0; ty < we.tiles_y; ty++)
                for (int tx = 0; ok && tx < we.tiles_x; tx++) {
                    uint8_t *snap = NULL;
                    size_t slen = v1_snapshot(&we, tx, ty, &snap);
                    ok =
                        cluster_snapshot_put(a, "old", tx, ty, seq, snap, slen, &err) == CLUSTER_OK;
                    tiles[count][0] = tx;
                    tiles[count++][1] = ty;
                    free(snap);
                }
            ok = ok && cluster_snapshot_index_put(a, "old", seq, (const int(*)[2])tiles, count,
                                                  &err) == CLUSTER_OK;
        }
    }
    cluster_wal_close(wal);
    CHECK(ok && first > 0, "6 records and a snapshot of format 1 written: %s", err.message);
    test_dunes_world(&wr, W, H, 5);
    store_recovery rec;
    cluster_store *s = cluster_store_open(a, "old", &wr, NULL, &rec, &err);
    CHECK(s && rec.tick == 6 && rec.tiles_loaded == 6 && same_heights(&we, &wr),
          "format 1 records and snapshots still load (tick %llu, %d tiles): %s",
          (unsigned long long)rec.tick, rec.tiles_loaded, err.message);
    int n = deform(&we, rects);
    CHECK(s && cluster_store_commit_tick(s, &we, 7, rects, n, &err) == CLUSTER_OK,
          "a format 2 record follows them: %s", err.message);
    cluster_store_close(s);
    world_free(&wr);
    test_dunes_world(&wr, W, H, 5);
    s = cluster_store_open(a, "old", &wr, NULL, &rec, &err);
    CHECK(s && rec.tick == 7 && same_heights(&we, &wr), "and the mixed log loads: %s", err.message);
    cluster_store_close(s);
    world_free(&we);
    world_free(&wr);
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
    int up = nats_one_two_nodes("test_cluster_store", one, &a, &b, &err) == 0;
    CHECK(up, "two nodes connect: %s", err.message);
    if (up) {
        test_failover(a, b);
        test_two_worlds(a);
        test_soil(a, b);
        test_compaction_memory(a, b);
        test_format1(a);
        test_index_ahead_of_log(a);
    }
    cluster_close(a);
    cluster_close(b);
    nats_stop(one, SIGTERM);
    test_restart_keeps_other_worlds();
    nats_tmp_remove();
    return check_report();
}
