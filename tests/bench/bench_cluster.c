/*
 * bench_cluster.c: what the JetStream store costs (docs/cluster.md), on
 * real nats-server processes on loopback — commit latency (publish to
 * acknowledgement) at 60 Hz on 1 server (1 replica) and on 3 servers (3
 * replicas), and the commit rate each of 1, 2 and 6 worlds gets when one
 * process commits them all back to back (the ceiling NATS puts on a node's
 * tick rate). A tick here is 3 rectangles of 40×40 cells, compressed.
 * Every process shares this machine's cores: the figures say so.
 */
#include "test_params.h"
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "cluster/cluster.h"
#include "world/world.h"
#include "../support/nats_test.h"

#define W 1024
#define H 1024

static int deform(world *w, uint64_t t, world_rect *rects)
{
    uint32_t rng = (uint32_t)(t * 2654435761u) ^ 0x5bd1e995u;
    for (int i = 0; i < 3; i++) {
        rng = rng * 1664525u + 1013904223u;
        world_rect r = {(int)((rng >> 8) % (W - 40)), (int)((rng >> 4) % (H - 40)), 40, 40};
        int32_t v[40 * 40];
        world_gather_window(w, r, v);
        for (int k = 0; k < 40 * 40; k++)
            v[k] -= 1 + (int32_t)((k * 7 + t) % 30);
        world_scatter_window(w, r, v);
        rects[i] = r;
    }
    return 3;
}

/* 300 ticks at 60 Hz into one world: commit p50 / p99. */
static void bench_latency(cluster *cl, const char *label)
{
    error_text err = {{0}};
    world w;
    test_dunes_world(&w, W, H, 5);
    store_recovery rec;
    cluster_store *st = cluster_store_open(cl, label, &w, NULL, &rec, &err);
    if (!st) {
        printf("%s: %s\n", label, err.message);
        world_free(&w);
        return;
    }
    world_rect rects[3];
    double next = time_now_ms();
    int failed = 0;
    for (uint64_t t = 1; t <= 300; t++) {
        int n = deform(&w, t, rects);
        failed += cluster_store_commit_tick(st, &w, t, rects, n, &err) != CLUSTER_OK;
        next += 1000.0 / 60;
        double wait = next - time_now_ms();
        if (wait > 0)
            usleep((useconds_t)(wait * 1000));
    }
    double p50, p99;
    cluster_store_commit_ms(st, &p50, &p99);
    printf("| %s | 60 Hz, 300 ticks | %.2f | %.2f | %d |\n", label, p50, p99, failed);
    cluster_store_close(st);
    world_free(&w);
}

/* n worlds committed back to back for 3 s: ticks per second per world. */
static void bench_rate(cluster *cl, int n, const char *label)
{
    error_text err = {{0}};
    world w[6];
    cluster_store *st[6] = {0};
    store_recovery rec;
    for (int i = 0; i < n; i++) {
        char name[32];
        snprintf(name, sizeof name, "rate%d-%s-%d", n, label, i);
        test_dunes_world(&w[i], W, H, 5);
        st[i] = cluster_store_open(cl, name, &w[i], NULL, &rec, &err);
        if (!st[i])
            printf("%s: %s\n", name, err.message);
    }
    world_rect rects[3];
    uint64_t ticks = 0;
    double t0 = time_now_ms();
    while (time_now_ms() - t0 < 3000) {
        ticks++;
        for (int i = 0; i < n; i++) {
            int k = deform(&w[i], ticks, rects);
            if (st[i])
                cluster_store_commit_tick(st[i], &w[i], ticks, rects, k, &err);
        }
    }
    double s = (time_now_ms() - t0) / 1000.0;
    printf("| %s | %d world%s | %.0f ticks/s per world |\n", label, n, n > 1 ? "s" : "",
           (double)ticks / s);
    for (int i = 0; i < n; i++) {
        cluster_store_close(st[i]);
        world_free(&w[i]);
    }
}

static void bench_servers(int servers)
{
    nats_proc nats[3];
    nats_init(nats, servers);
    nats_start_all(nats, servers);
    char urls[256], label[32];
    urls_of(nats, servers, urls, sizeof urls);
    error_text err = {{0}};
    cluster_config cc = {.urls = urls, .node = "bench", .timeout_ms = 10000};
    cluster *cl = cluster_connect(&cc, &err);
    if (!cl) {
        printf("%d servers: %s\n", servers, err.message);
    } else {
        snprintf(label, sizeof label, "%d-server-R%d", servers, cluster_replicas(cl));
        printf(
            "\n| NATS | load | commit p50 ms | commit p99 ms | failed |\n|---|---|---|---|---|\n");
        bench_latency(cl, label);
        printf("\n| NATS | worlds | rate |\n|---|---|---|\n");
        bench_rate(cl, 1, label);
        bench_rate(cl, 2, label);
        bench_rate(cl, 6, label);
        cluster_close(cl);
    }
    for (int i = 0; i < servers; i++)
        nats_stop(&nats[i], SIGTERM);
}

int main(void)
{
    if (!nats_installed()) {
        printf("bench_cluster: nats-server is not installed: skipped\n");
        return 0;
    }
    log_set_quiet(1);
    nats_tmp_root("bench_cluster");
    printf("bench_cluster: JetStream store on loopback; terrad and every nats-server share this "
           "machine's cores (nproc: %ld)\n",
           sysconf(_SC_NPROCESSORS_ONLN));
    bench_servers(1);
    bench_servers(3);
    nats_tmp_remove();
    return 0;
}
