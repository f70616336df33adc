/*
 * test_cluster.c: server/cluster against REAL nats-server processes with
 * JetStream on loopback (started here, each with its own store directory
 * under /tmp): NATS unreachable at connect (the error names the URL); lease
 * take / renew / expiry / takeover / release, and a holder cut off from
 * renewing stops claiming by itself; the WAL's read-back equals what was
 * appended, records larger than max_payload included; fencing — after a
 * takeover the deposed writer's append is refused and the log holds nothing
 * of it, and an append with a stale expected sequence is refused; purge below
 * a snapshot's sequence; snapshots put/get (one message and in parts), an
 * older snapshot never replaces a newer one; the world registry; NATS lost
 * while running (append fails as an error, not as fencing) and back (append
 * works again); and a 3-server cluster (3 replicas) that keeps committing
 * with one server killed.
 *
 * Exit 77 (skipped) when nats-server is not installed.
 */
// ctest-timeout: 240
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "cluster/cluster.h"
#include "check.h"
#include "nats_test.h"

/* renew_ms -1: the test renews by hand */
static cluster *connect_node(const char *urls, const char *node, int lease_ms, int renew_ms)
{
    cluster_config c = {.urls = urls,
                        .node = node,
                        .lease_ms = lease_ms,
                        .renew_ms = renew_ms,
                        .timeout_ms = 10000};
    error_text err = {{0}};
    cluster *cl = cluster_connect(&c, &err);
    CHECK(cl != NULL, "node %s connects to %s: %s", node, urls, err.message);
    return cl;
}

/* ---- records kept while reading a log ---- */

typedef struct record_log {
    int count;
    uint64_t seq[64];
    size_t len[64];
    uint32_t sum[64];
} record_log;

static uint32_t checksum(const uint8_t *d, size_t n)
{
    uint32_t h = 2166136261u;
    for (size_t i = 0; i < n; i++)
        h = (h ^ d[i]) * 16777619u;
    return h;
}

static int on_record(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    record_log *l = ctx;
    if (l->count < 64) {
        l->seq[l->count] = seq;
        l->len[l->count] = len;
        l->sum[l->count] = checksum(data, len);
        l->count++;
    }
    return 0;
}

static uint8_t *pattern(size_t n, unsigned seed)
{
    uint8_t *d = malloc(n ? n : 1);
    for (size_t i = 0; i < n; i++)
        d[i] = (uint8_t)((i * 31u + seed * 7u) ^ (i >> 9));
    return d;
}

static void test_unreachable(void)
{
    char urls[64];
    snprintf(urls, sizeof urls, "nats://127.0.0.1:%d", free_port());
    cluster_config c = {.urls = urls, .node = "a", .timeout_ms = 500};
    error_text err = {{0}};
    cluster *cl = cluster_connect(&c, &err);
    CHECK(cl == NULL, "connect to a port nobody listens on fails");
    CHECK(strstr(err.message, urls) != NULL, "the error names the URL: %s", err.message);
    cluster_close(cl);
    c.node = "bad name";
    cl = cluster_connect(&c, &err);
    CHECK(cl == NULL && strstr(err.message, "node name"), "a bad node name: %s", err.message);
}

static void test_lease(cluster *a, cluster *b)
{
    char holder[64];
    error_text err = {{0}};
    CHECK(cluster_lease_acquire(a, "w1", holder, sizeof holder, &err) == 1, "a takes w1: %s",
          err.message);
    CHECK(cluster_lease_held(a, "w1"), "a holds w1");
    CHECK(cluster_lease_acquire(b, "w1", holder, sizeof holder, &err) == 0 &&
              strcmp(holder, "a") == 0,
          "b cannot take w1, held by a (holder %s)", holder);
    /* a renews every 300 ms for 1.5 s (> lease_ms): b never gets it */
    int b_took = 0;
    for (int i = 0; i < 5; i++) {
        usleep(300000);
        CHECK(cluster_lease_renew(a, "w1", &err) == CLUSTER_OK, "a renews: %s", err.message);
        b_took |= cluster_lease_acquire(b, "w1", holder, sizeof holder, &err) == 1;
    }
    CHECK(!b_took, "b never takes a lease a keeps renewing");
    /* a stops renewing: its own view expires, and b takes over */
    double t0 = time_now_ms();
    while (!b_took && time_now_ms() - t0 < 30000) { /* generous: a loaded machine */
        usleep(100000);
        b_took = cluster_lease_acquire(b, "w1", holder, sizeof holder, &err) == 1;
    }
    CHECK(b_took, "b takes w1 once a stops renewing");
    CHECK(!cluster_lease_held(a, "w1"), "a stopped claiming w1 by itself");
    CHECK(cluster_lease_renew(a, "w1", &err) == CLUSTER_FENCED, "a's renewal is refused: %s",
          err.message);
    CHECK(cluster_lease_holder(a, "w1", holder, sizeof holder, &err) == 1 &&
              strcmp(holder, "b") == 0,
          "the lease names b (%s)", holder);
    /* a released lease is free at once */
    cluster_lease_release(b, "w1");
    CHECK(!cluster_lease_held(b, "w1"), "b released w1");
    CHECK(cluster_lease_holder(a, "w1", holder, sizeof holder, &err) == 0, "nobody holds w1");
    CHECK(cluster_lease_acquire(a, "w1", holder, sizeof holder, &err) == 1,
          "a takes a released lease at once");
    CHECK(cluster_lease_acquire(a, "bad.name", holder, sizeof holder, &err) == -1,
          "a world name with a dot is refused: %s", err.message);
    cluster_lease_release(a, "w1");
}

/* The renewal thread keeps a lease without the caller; closing releases it. */
static void test_renewer(const char *urls)
{
    cluster *k = connect_node(urls, "keeper", 600, 200), *t = connect_node(urls, "taker", 600, -1);
    if (!k || !t) {
        cluster_close(k);
        cluster_close(t);
        return;
    }
    error_text err = {{0}};
    char holder[64];
    CHECK(cluster_lease_acquire(k, "kept", holder, sizeof holder, &err) == 1, "keeper takes it");
    int taken = 0;
    for (int i = 0; i < 20; i++) { /* 2 s, more than 3 lease periods */
        usleep(100000);
        taken |= cluster_lease_acquire(t, "kept", holder, sizeof holder, &err) == 1;
    }
    CHECK(!taken && cluster_lease_held(k, "kept"),
          "the renewal thread keeps the lease for 3 lease periods");
    cluster_close(k);
    CHECK(cluster_lease_acquire(t, "kept", holder, sizeof holder, &err) == 1,
          "closing the keeper released it: taken at once");
    cluster_close(t);
}

static void test_wal(cluster *a, cluster *b)
{
    error_text err = {{0}};
    size_t sizes[5] = {10, 0, 70000, (size_t)cluster_max_payload(a) * 2 + 12345, 3};
    uint32_t sums[5];
    uint64_t seqs[5];
    cluster_wal *wa = cluster_wal_open(a, "w2", &err);
    record_log seen = {0};
    CHECK(cluster_wal_take(wa, 1, on_record, &seen, &err) == CLUSTER_OK, "a takes w2's log: %s",
          err.message);
    CHECK(seen.count == 0, "a new world's log is empty (%d)", seen.count);
    for (int i = 0; i < 5; i++) {
        uint8_t *d = pattern(sizes[i], (unsigned)i);
        sums[i] = checksum(d, sizes[i]);
        CHECK(cluster_wal_append(wa, d, sizes[i], &seqs[i], &err) == CLUSTER_OK,
              "append %d (%zu bytes): %s", i, sizes[i], err.message);
        free(d);
    }
    CHECK(seqs[4] > seqs[3] && seqs[3] > seqs[2] + 2, "the large record went out in parts");
    /* read back by another node */
    cluster_wal *wb = cluster_wal_open(b, "w2", &err);
    record_log back = {0};
    CHECK(cluster_wal_read(wb, 1, on_record, &back, &err) == CLUSTER_OK, "b reads w2: %s",
          err.message);
    int same = back.count == 5;
    for (int i = 0; same && i < 5; i++)
        same = back.len[i] == sizes[i] && back.sum[i] == sums[i] && back.seq[i] == seqs[i];
    CHECK(same, "the log read back equals what was appended (%d records)", back.count);
    record_log tail = {0};
    CHECK(cluster_wal_read(wb, seqs[2] + 1, on_record, &tail, &err) == CLUSTER_OK &&
              tail.count == 2 && tail.seq[0] == seqs[3],
          "reading from a sequence gives the records from there (%d)", tail.count);

    /* takeover: b fences a off */
    record_log taken = {0};
    CHECK(cluster_wal_take(wb, 1, on_record, &taken, &err) == CLUSTER_OK && taken.count == 5,
          "b takes w2's log, replaying 5 records (%d): %s", taken.count, err.message);
    uint8_t one = 42;
    uint64_t seq = 0;
    CHECK(cluster_wal_append(wa, &one, 1, &seq, &err) == CLUSTER_FENCED,
          "the deposed owner's append is refused: %s", err.message);
    uint8_t *big = pattern(sizes[3], 9);
    CHECK(cluster_wal_append(wa, big, sizes[3], &seq, &err) == CLUSTER_FENCED,
          "so is a large one (no part of it lands)");
    free(big);
    uint8_t two[2] = {7, 8};
    CHECK(cluster_wal_append(wb, two, 2, &seq, &err) == CLUSTER_OK, "the new owner appends: %s",
          err.message);
    record_log after = {0};
    cluster_wal *wc = cluster_wal_open(a, "w2", &err);
    CHECK(cluster_wal_read(wc, 1, on_record, &after, &err) == CLUSTER_OK && after.count == 6 &&
              after.len[5] == 2 && after.seq[5] == seq,
          "the log holds 5 + 1 records, none from the deposed owner (%d)", after.count);
    /* a stale expected sequence: wc saw the end; wb appends; wc's append is refused */
    CHECK(cluster_wal_append(wb, two, 2, &seq, &err) == CLUSTER_OK, "b appends again");
    CHECK(cluster_wal_append(wc, two, 1, NULL, &err) == CLUSTER_FENCED,
          "an append expecting a stale sequence is refused: %s", err.message);

    /* purge below a snapshot's sequence: records from there stay, appends go on */
    CHECK(cluster_wal_purge_below(wb, seqs[2] + 1, &err) == CLUSTER_OK, "purge: %s", err.message);
    record_log purged = {0};
    CHECK(cluster_wal_read(wc, 1, on_record, &purged, &err) == CLUSTER_OK && purged.count == 4 &&
              purged.seq[0] == seqs[3] && purged.len[0] == sizes[3],
          "after the purge the log starts at the snapshot's sequence (%d records)", purged.count);
    CHECK(cluster_wal_purge_below(wb, seq + 1000, &err) == CLUSTER_OK, "purge everything");
    CHECK(cluster_wal_append(wb, two, 2, NULL, &err) == CLUSTER_OK,
          "the writer still appends after purging everything (its last record stays): %s",
          err.message);
    cluster_wal_close(wa);
    cluster_wal_close(wb);
    cluster_wal_close(wc);
}

static void test_snapshots(cluster *a, cluster *b)
{
    error_text err = {{0}};
    size_t small = 1000, large = (size_t)cluster_max_payload(a) * 2 + 777;
    uint8_t *d1 = pattern(small, 1), *d2 = pattern(large, 2), *got = NULL;
    size_t len = 0;
    uint64_t covers = 0;
    CHECK(cluster_snapshot_get(a, "w3", 1, 2, &got, &len, &covers, &err) == 0, "no snapshot yet");
    CHECK(cluster_snapshot_put(a, "w3", 1, 2, 10, d1, small, &err) == CLUSTER_OK, "put: %s",
          err.message);
    CHECK(cluster_snapshot_get(b, "w3", 1, 2, &got, &len, &covers, &err) == 1 && len == small &&
              covers == 10 && memcmp(got, d1, small) == 0,
          "get returns what was put");
    free(got);
    CHECK(cluster_snapshot_put(a, "w3", 1, 2, 20, d2, large, &err) == CLUSTER_OK,
          "put a snapshot larger than max_payload: %s", err.message);
    got = NULL;
    CHECK(cluster_snapshot_get(b, "w3", 1, 2, &got, &len, &covers, &err) == 1 && len == large &&
              covers == 20 && got && memcmp(got, d2, large) == 0,
          "get returns the large one whole (%zu bytes, covers %llu): %s", len,
          (unsigned long long)covers, err.message);
    free(got);
    CHECK(cluster_snapshot_put(b, "w3", 1, 2, 15, d1, small, &err) == CLUSTER_FENCED,
          "an older snapshot is refused: %s", err.message);
    CHECK(cluster_snapshot_put(a, "w3", 1, 2, 30, d1, small, &err) == CLUSTER_OK,
          "a newer small one replaces the large one");
    got = NULL;
    CHECK(cluster_snapshot_get(b, "w3", 1, 2, &got, &len, &covers, &err) == 1 && len == small &&
              covers == 30,
          "get returns the newest");
    free(got);
    CHECK(cluster_snapshot_put(a, "w3", 3, 0, 30, d1, 0, &err) == CLUSTER_OK, "an empty one");
    int(*tiles)[2] = NULL;
    int count = 0;
    CHECK(cluster_snapshot_index_get(b, "w3", &covers, &tiles, &count, &err) == 0, "no index yet");
    const int first[1][2] = {{1, 2}}, second[2][2] = {{3, 0}, {1, 2}};
    CHECK(cluster_snapshot_index_put(a, "w3", 30, first, 1, &err) == CLUSTER_OK, "index put: %s",
          err.message);
    CHECK(cluster_snapshot_index_put(b, "w3", 20, second, 2, &err) == CLUSTER_OK,
          "an index put covering less merges its tiles");
    CHECK(cluster_snapshot_index_get(b, "w3", &covers, &tiles, &count, &err) == 1 && covers == 30 &&
              count == 2 && tiles[0][0] == 1 && tiles[0][1] == 2 && tiles[1][0] == 3 &&
              tiles[1][1] == 0,
          "the index names both tiles once and covers 30 (%llu, %d)", (unsigned long long)covers,
          count);
    free(tiles);
    free(d1);
    free(d2);
}

static void test_registry(cluster *a, cluster *b)
{
    error_text err = {{0}};
    char **names = NULL, *scene = NULL;
    int count = -1;
    CHECK(cluster_world_list(a, &names, &count, &err) == 0 && count == 0, "no worlds yet (%d): %s",
          count, err.message);
    free(names);
    CHECK(cluster_world_add(a, "dunes", "{\"a\":1}", &err) == CLUSTER_OK, "add: %s", err.message);
    CHECK(cluster_world_add(b, "canyon", "{\"b\":2}", &err) == CLUSTER_OK, "add another");
    CHECK(cluster_world_add(b, "dunes", "{}", &err) == CLUSTER_FENCED &&
              strstr(err.message, "already exists"),
          "a taken name is refused: %s", err.message);
    CHECK(cluster_world_add(b, "no such", "{}", &err) == CLUSTER_ERROR, "a bad name is refused");
    CHECK(cluster_world_list(b, &names, &count, &err) == 0 && count == 2 &&
              strcmp(names[0], "canyon") == 0 && strcmp(names[1], "dunes") == 0,
          "list: both, sorted");
    for (int i = 0; i < count; i++)
        free(names[i]);
    free(names);
    CHECK(cluster_world_get(b, "dunes", &scene, &err) == 1 && strcmp(scene, "{\"a\":1}") == 0,
          "get returns the scene");
    free(scene);
    /* remove deletes the world's log and snapshots too */
    cluster_wal *w = cluster_wal_open(a, "dunes", &err);
    CHECK(cluster_wal_take(w, 1, NULL, NULL, &err) == CLUSTER_OK, "take dunes");
    CHECK(cluster_wal_append(w, "x", 1, NULL, &err) == CLUSTER_OK, "append to dunes");
    CHECK(cluster_snapshot_put(a, "dunes", 0, 0, 1, "y", 1, &err) == CLUSTER_OK, "snapshot");
    CHECK(cluster_world_remove(b, "dunes", &err) == 1, "remove: %s", err.message);
    CHECK(cluster_world_remove(b, "dunes", &err) == 0, "remove an unknown world: 0");
    CHECK(cluster_world_get(b, "dunes", &scene, &err) == 0, "a removed world is unknown");
    uint8_t *got = NULL;
    size_t len = 0;
    uint64_t covers = 0;
    CHECK(cluster_snapshot_get(b, "dunes", 0, 0, &got, &len, &covers, &err) == 0,
          "its snapshots are gone");
    CHECK(cluster_wal_append(w, "z", 1, NULL, &err) == CLUSTER_FENCED,
          "its old writer is fenced off (its log was deleted)");
    record_log l = {0};
    cluster_wal *r = cluster_wal_open(b, "dunes", &err);
    CHECK(cluster_wal_read(r, 1, on_record, &l, &err) == CLUSTER_OK && l.count == 0,
          "its log is empty");
    CHECK(cluster_world_add(a, "dunes", "{\"c\":3}", &err) == CLUSTER_OK,
          "the name can be added again: %s", err.message);
    cluster_wal_close(w);
    cluster_wal_close(r);
}

/* The only server dies and comes back (same store directory). */
static void test_nats_lost(nats_proc *n, cluster *a)
{
    error_text err = {{0}};
    cluster_wal *w = cluster_wal_open(a, "w4", &err);
    CHECK(cluster_wal_take(w, 1, NULL, NULL, &err) == CLUSTER_OK, "take w4");
    CHECK(cluster_wal_append(w, "1", 1, NULL, &err) == CLUSTER_OK, "append before the loss");
    nats_stop(n, SIGKILL);
    usleep(300000);
    CHECK(!cluster_connected(a), "the node sees the connection lost");
    cluster_status r = cluster_wal_append(w, "2", 1, NULL, &err);
    CHECK(r == CLUSTER_ERROR, "an append while NATS is down fails as an error (%d): %s", r,
          err.message);
    nats_start(n, 0, 1);
    double t0 = time_now_ms();
    while (!cluster_connected(a) && time_now_ms() - t0 < 10000)
        usleep(50000);
    CHECK(cluster_connected(a), "the node reconnects when NATS is back");
    r = CLUSTER_ERROR;
    for (int i = 0; i < 50 && r == CLUSTER_ERROR; i++) { /* JetStream recovers its store */
        r = cluster_wal_append(w, "3", 1, NULL, &err);
        if (r == CLUSTER_ERROR)
            usleep(100000);
    }
    CHECK(r == CLUSTER_OK, "appends work again: %s", err.message);
    record_log l = {0};
    CHECK(cluster_wal_read(w, 1, on_record, &l, &err) == CLUSTER_OK && l.count == 2,
          "the log holds the records acknowledged (%d)", l.count);
    cluster_wal_close(w);
}

static void test_three_servers(void)
{
    nats_proc n[3];
    nats_init(n, 3);
    nats_start_all(n, 3);
    char urls[256];
    urls_of(n, 3, urls, sizeof urls);
    cluster *a = connect_node(urls, "a", 1000, 0);
    if (!a)
        goto out;
    CHECK(cluster_replicas(a) == 3, "3 replicas on 3 servers (%d)", cluster_replicas(a));
    error_text err = {{0}};
    cluster_wal *w = cluster_wal_open(a, "r3", &err);
    CHECK(cluster_wal_take(w, 1, NULL, NULL, &err) == CLUSTER_OK, "take r3: %s", err.message);
    CHECK(cluster_wal_append(w, "abc", 3, NULL, &err) == CLUSTER_OK, "append on R3: %s",
          err.message);
    nats_stop(&n[1], SIGKILL);
    cluster_status r = CLUSTER_ERROR;
    for (int i = 0; i < 100 && r == CLUSTER_ERROR; i++) { /* a new stream leader may be elected */
        r = cluster_wal_append(w, "def", 3, NULL, &err);
        if (r == CLUSTER_ERROR)
            usleep(100000);
    }
    CHECK(r == CLUSTER_OK, "appends go on with one of three servers killed: %s", err.message);
    record_log l = {0};
    CHECK(cluster_wal_read(w, 1, on_record, &l, &err) == CLUSTER_OK && l.count == 2,
          "both records read back (%d): %s", l.count, err.message);
    int got = -1; /* the bucket's leader may be re-elected first: polled, as nodes do */
    for (double t0 = time_now_ms(); got != 1 && time_now_ms() - t0 < 20000; usleep(100000))
        got = cluster_lease_acquire(a, "r3", NULL, 0, &err);
    CHECK(got == 1, "leases work on two of three: %s", err.message);
    cluster_wal_close(w);
    cluster_close(a);
out:
    for (int i = 0; i < 3; i++)
        nats_stop(&n[i], SIGTERM);
}

int main(void)
{
    if (!nats_installed()) {
        printf("nats-server is not installed: skipped\n");
        return 77;
    }
    nats_tmp_root("test_cluster");
    test_unreachable();
    nats_proc one[1];
    nats_init(one, 1);
    nats_start_all(one, 1);
    char urls[64];
    urls_of(one, 1, urls, sizeof urls);
    cluster *a = connect_node(urls, "a", 1000, -1), *b = connect_node(urls, "b", 1000, -1);
    if (a && b) {
        CHECK(cluster_replicas(a) == 1, "1 replica on one server");
        test_lease(a, b);
        test_renewer(urls);
        test_wal(a, b);
        test_snapshots(a, b);
        test_registry(a, b);
        cluster_close(b);
        b = NULL;
        test_nats_lost(one, a);
    }
    cluster_close(a);
    cluster_close(b);
    nats_stop(one, SIGTERM);
    test_three_servers();
    nats_tmp_remove();
    return check_report();
}
