/*
 * test_cluster_take_race.c: the fencing race of nats-server 2.9 made to
 * happen on purpose, against three real nats-server processes, and the
 * confirmed take that closes it (cluster_wal_take, docs/cluster.md "The
 * fencing race"). nats-server 2.9 checks Nats-Expected-Last-Subject-Sequence
 * of a clustered stream only on the leader before proposing, against what it
 * has applied: two publishes proposed before either is applied, both
 * expecting the same last sequence, are both stored and both acknowledged.
 * Here the two servers that are not the stream's leader are stopped
 * (SIGSTOP, waited for until every thread of each has stopped: nats_pause),
 * so the leader can propose but not commit; meanwhile node a (the
 * owner) appends a record and node b takes the world, in both orders, and the
 * followers stay stopped until a plain subscriber on the leader has seen both
 * publishes arrive there (not a fixed pause: on a loaded machine a thread may
 * start late). Then both servers go on: both publishes are acknowledged
 * (the race), and b's take must still have replayed a's record — without the
 * confirm record and the read after it, b's take returned at its marker and
 * its replay lacked a's acknowledged record (7 checks failed so, in both
 * orders). After the take, a is fenced and the log is one history. Whether
 * the publishes crossed is read from the log itself (two stored messages that
 * expected the same sequence), not from the code under test. Nothing should
 * be applied before the followers go on, so once both publishes reached the
 * leader they should cross; yet nats-server sometimes serializes them all
 * the same, so each order is tried up to ATTEMPTS times and must cross once.
 *
 * Exit 77 (skipped) when nats-server is not installed.
 */
// ctest-timeout: 240
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "base/base.h"
#include "cluster/cluster.h"
#include "check.h"
#include "nats_test.h"

/* Tries per order. Even with both publishes at the leader before the followers go on,
 * nats-server 2.9.10 sometimes serializes them (measured: 1 order in 8 needed a second
 * try, never a third; Intel Xeon 2 cores, load 9-17); a longer stop made that more
 * frequent, not less. */
#define ATTEMPTS 10

/* The records a read handed over, as text. */
typedef struct seen {
    int count;
    char text[16][32];
} seen;

static int keep(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    (void)seq;
    seen *s = ctx;
    if (s->count < 16)
        snprintf(s->text[s->count++], sizeof s->text[0], "%.*s", (int)len, (const char *)data);
    return 0;
}

static int seen_has(const seen *s, const char *text)
{
    for (int i = 0; i < s->count; i++)
        if (strcmp(s->text[i], text) == 0)
            return 1;
    return 0;
}

/* One call on its own thread: a's append or b's take. */
typedef struct call {
    cluster_wal *w;
    const char *data; /* NULL: take */
    seen *replayed;
    cluster_status r;
    error_text err;
    pthread_t thread;
} call;

static void *call_main(void *arg)
{
    call *c = arg;
    c->r = c->data ? cluster_wal_append(c->w, c->data, strlen(c->data), NULL, &c->err)
                   : cluster_wal_take(c->w, 1, keep, c->replayed, &c->err);
    return NULL;
}

/* The index (0..2) of the server that leads TERRAD_WAL, -1 if none yet. */
static int stream_leader(cluster *cl)
{
    void *answer = NULL;
    size_t len = 0;
    error_text err = {{0}};
    int leader = -1;
    if (cluster_request(cl, "$JS.API.STREAM.INFO.TERRAD_WAL", "", 0, 5000, &answer, &len, &err) ==
        1) {
        cJSON *doc = cJSON_ParseWithLength(answer, len);
        const cJSON *c = cJSON_GetObjectItemCaseSensitive(doc, "cluster");
        const cJSON *l = cJSON_GetObjectItemCaseSensitive(c, "leader");
        if (cJSON_IsString(l) && l->valuestring[0] == 'n')
            leader = atoi(l->valuestring + 1);
        cJSON_Delete(doc);
    }
    free(answer);
    return leader >= 0 && leader < 3 ? leader : -1;
}

/* The race's mark, whatever the code under test does: two messages stored on
 * world's subject that both expected the same last sequence (each message's
 * Nats-Expected-Last-Subject-Sequence, read back from the stream's leader).
 * 1: crossed, 0: not, -1: the log could not be read. */
static int crossed(cluster *cl, const char *world)
{
    uint64_t expected[32];
    int count = 0, rc = 0;
    for (uint64_t from = 1; count < 32;) {
        char req[160];
        snprintf(req, sizeof req, "{\"seq\":%llu,\"next_by_subj\":\"terrad.wal.%s\"}",
                 (unsigned long long)from, world);
        void *answer = NULL;
        size_t len = 0;
        error_text err = {{0}};
        if (cluster_request(cl, "$JS.API.STREAM.MSG.GET.TERRAD_WAL", req, strlen(req), 5000,
                            &answer, &len, &err) != 1)
            return -1;
        cJSON *doc = cJSON_ParseWithLength(answer, len);
        free(answer);
        const cJSON *m = cJSON_GetObjectItemCaseSensitive(doc, "message");
        const cJSON *seq = cJSON_GetObjectItemCaseSensitive(m, "seq");
        const cJSON *hdrs = cJSON_GetObjectItemCaseSensitive(m, "hdrs");
        if (!cJSON_IsNumber(seq) || !cJSON_IsString(hdrs)) {
            rc = cJSON_GetObjectItemCaseSensitive(doc, "error") ? 0 : -1; /* none after */
            cJSON_Delete(doc);
            break;
        }
        char text[512] = "";
        if (strlen(hdrs->valuestring) < sizeof text * 3 / 4 - 4) {
            int64_t n = base64_decode(hdrs->valuestring, (uint8_t *)text);
            text[n > 0 ? n : 0] = '\0';
        }
        const char *at = strstr(text, "Nats-Expected-Last-Subject-Sequence:");
        if (at)
            expected[count++] =
                strtoull(at + strlen("Nats-Expected-Last-Subject-Sequence:"), NULL, 10);
        from = (uint64_t)seq->valuedouble + 1;
        cJSON_Delete(doc);
    }
    for (int i = 0; rc == 0 && i < count; i++)
        for (int j = i + 1; j < count; j++)
            if (expected[i] == expected[j])
                rc = 1;
    return rc;
}

/* The race's two publishes seen on the world's subject by a plain subscriber (a NATS
 * thread counts): a's record "late" and b's owner marker (its node name, "b"); a's own
 * marker, confirm and records before them say "a", "r1", "r2". */
static void count_msg(void *ctx, const char *subject, const void *data, size_t len)
{
    (void)subject;
    if ((len == 4 && memcmp(data, "late", 4) == 0) || (len == 1 && memcmp(data, "b", 1) == 0))
        atomic_fetch_add((atomic_int *)ctx, 1);
}

/* 1 once *n reaches want, 0 when ms passed first. */
static int wait_count(atomic_int *n, int want, int ms)
{
    for (int i = 0; i < ms / 5 && atomic_load(n) < want; i++)
        usleep(5000);
    return atomic_load(n) >= want;
}

static cluster *node(const char *url, const char *name)
{
    /* generous: a publish waits for its acknowledgement while the followers are stopped */
    cluster_config c = {.urls = url, .node = name, .renew_ms = -1, .timeout_ms = 30000};
    error_text err = {{0}};
    cluster *cl = cluster_connect(&c, &err);
    CHECK(cl != NULL, "node %s connects to %s: %s", name, url, err.message);
    return cl;
}

static void check_take(const char *name, cluster *a, cluster_wal *wa, cluster_wal *wb,
                       const call *take, const seen *replayed);

/* a owns world name with two records; the followers stop; a appends "late"
 * and b takes the world (take_first: b's marker is sent first); the followers
 * go on. 1 when the two publishes crossed (then b's take is checked), 0 when
 * they did not (on a loaded machine the first may be applied before the
 * second is proposed: the caller tries again), -1 when nothing could be
 * tried. */
static int race(nats_proc *n, cluster *setup, const char *name, int take_first)
{
    int leader = -1;
    for (int i = 0; i < 100 && leader < 0; i++) {
        leader = stream_leader(setup);
        if (leader < 0)
            usleep(200000);
    }
    CHECK(leader >= 0, "%s: the stream has a leader (n%d)", name, leader);
    if (leader < 0)
        return -1;
    /* both nodes talk to the leader, so a publish reaches it while the others are stopped */
    char url[64];
    snprintf(url, sizeof url, "nats://127.0.0.1:%d", n[leader].port);
    cluster *a = node(url, "a"), *b = node(url, "b"), *watch = node(url, "watch");
    atomic_int arrived = 0;
    char subject[128];
    snprintf(subject, sizeof subject, "terrad.wal.%s", name); /* cluster_wal.c's subject */
    error_text serr = {{0}};
    cluster_sub *sub = watch ? cluster_subscribe(watch, subject, count_msg, &arrived, &serr) : NULL;
    CHECK(sub != NULL, "%s: a plain subscriber on the leader watches %s: %s", name, subject,
          serr.message);
    if (!a || !b || !sub) {
        cluster_unsubscribe(sub);
        cluster_close(watch);
        cluster_close(a);
        cluster_close(b);
        return -1;
    }
    error_text err = {{0}};
    cluster_wal *wa = cluster_wal_open(a, name, &err), *wb = cluster_wal_open(b, name, &err);
    CHECK(cluster_wal_take(wa, 1, NULL, NULL, &err) == CLUSTER_OK &&
              cluster_wal_append(wa, "r1", 2, NULL, &err) == CLUSTER_OK &&
              cluster_wal_append(wa, "r2", 2, NULL, &err) == CLUSTER_OK,
          "%s: a takes the world and appends two records: %s", name, err.message);
    seen replayed = {0};
    call append = {.w = wa, .data = "late"}, take = {.w = wb, .replayed = &replayed};
    call *first = take_first ? &take : &append, *second = take_first ? &append : &take;
    /* stopped, not only signalled: a follower that still runs (a loaded machine stops
     * its threads late) may commit the first publish before the second is proposed */
    int paused = 1;
    for (int i = 0; i < 3; i++)
        if (i != leader)
            paused &= nats_pause(&n[i], 30000);
    CHECK(paused, "%s: every thread of both followers stops on SIGSTOP", name);
    /* The first publish reaches the leader (proposed, not committed: no quorum) before
     * the second is sent; the followers go on only once both have arrived. Each wait
     * stays under nats-server's 10 s without quorum, after which the leader steps down
     * (then the publishes may not cross: crossed() tells, and the caller tries again). */
    pthread_create(&first->thread, NULL, call_main, first);
    int both = wait_count(&arrived, 1, 4000);
    pthread_create(&second->thread, NULL, call_main, second);
    both = both && wait_count(&arrived, 2, 4000);
    usleep(300000); /* arrived at the leader's server: a moment for its stream to propose them */
    if (!both)
        printf("# %s: %d of the two publishes reached the leader in time\n", name,
               atomic_load(&arrived));
    for (int i = 0; i < 3; i++)
        if (i != leader)
            nats_resume(&n[i]);
    pthread_join(first->thread, NULL);
    pthread_join(second->thread, NULL);
    int raced = crossed(setup, name);
    CHECK(raced >= 0, "%s: the log can be read back", name);
    if (raced == 1) {
        CHECK(append.r == CLUSTER_OK,
              "%s: a's append, in flight with b's marker, was "
              "acknowledged (%d): %s",
              name, append.r, append.err.message);
        check_take(name, a, wa, wb, &take, &replayed);
    } else {
        printf("# %s: the two publishes did not cross (a's append %d, b's take %d; leader n%d, "
               "now n%d): again\n",
               name, append.r, take.r, leader, stream_leader(setup));
    }
    cluster_wal_close(wa);
    cluster_wal_close(wb);
    cluster_unsubscribe(sub);
    cluster_close(watch);
    cluster_close(a);
    cluster_close(b);
    return raced;
}

/* After the race: b's take holds a's acknowledged record, a is fenced, the
 * log is one history. */
static void check_take(const char *name, cluster *a, cluster_wal *wa, cluster_wal *wb,
                       const call *take, const seen *replayed)
{
    error_text err = {{0}};
    CHECK(take->r == CLUSTER_OK, "%s: b took the world (%d): %s", name, take->r, take->err.message);
    CHECK(replayed->count == 3 && seen_has(replayed, "late"),
          "%s: b's take replayed a's acknowledged record \"late\" (%d records replayed)", name,
          replayed->count);
    CHECK(cluster_wal_takes_redone(wb) >= 1, "%s: the take was redone (%lld)", name,
          (long long)cluster_wal_takes_redone(wb));
    CHECK(cluster_wal_append(wb, "b1", 2, NULL, &err) == CLUSTER_OK, "%s: b appends: %s", name,
          err.message);
    CHECK(cluster_wal_append(wa, "a3", 2, NULL, &err) == CLUSTER_FENCED,
          "%s: a's next append is refused as fenced: %s", name, err.message);
    seen log = {0};
    cluster_wal *wr = cluster_wal_open(a, name, &err);
    CHECK(cluster_wal_read(wr, 1, keep, &log, &err) == CLUSTER_OK && log.count == 4 &&
              strcmp(log.text[0], "r1") == 0 && strcmp(log.text[1], "r2") == 0 &&
              strcmp(log.text[2], "late") == 0 && strcmp(log.text[3], "b1") == 0,
          "%s: the log is one history: r1 r2 late b1 (%d records): %s", name, log.count,
          err.message);
    cluster_wal_close(wr);
}

int main(void)
{
    if (!nats_installed()) {
        printf("nats-server is not installed: skipped\n");
        return 77;
    }
    nats_tmp_root("test_cluster_take_race");
    nats_proc n[3];
    nats_init(n, 3);
    nats_start_all(n, 3);
    char urls[256];
    urls_of(n, 3, urls, sizeof urls);
    cluster *setup = NULL;
    for (int i = 0; i < 60 && !setup; i++) { /* a cluster just started elects its leaders */
        cluster_config c = {.urls = urls, .node = "setup", .renew_ms = -1};
        error_text err = {{0}};
        setup = cluster_connect(&c, &err);
        if (!setup)
            usleep(500000);
    }
    CHECK(setup != NULL, "the stream is created on three servers");
    for (int order = 0; setup && order < 2; order++) {
        int raced = 0;
        for (int attempt = 1; attempt <= ATTEMPTS && raced == 0; attempt++) {
            char name[32];
            snprintf(name, sizeof name, "%s%d", order ? "take_first" : "append_first", attempt);
            raced = race(n, setup, name, order);
        }
        CHECK(raced == 1, "%s: the two publishes crossed in one of %d attempts",
              order ? "take_first" : "append_first", ATTEMPTS);
    }
    cluster_close(setup);
    for (int i = 0; i < 3; i++)
        nats_stop(&n[i], SIGTERM);
    nats_tmp_remove();
    return check_report();
}
