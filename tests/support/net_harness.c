/*
 * net_harness: the websocket server (server/net) against a hand-driven hub,
 * for tests/integration/service/test_net_server.py. It plays a fake sim thread: it
 * prints every command and pose the net thread queues in the hub, answers
 * subscribe/resync with a marker snapshot frame (bytes 4..5 = 0xEEEE), and
 * publishes tile deltas when told to on stdin ("delta", "flood", "burst",
 * "client", "snapbytes", "noflood", "stats", "quit"). The Python test drives
 * it and checks the protocol's refusals, fan-out, rate limits, slow clients
 * and shutdown. Environment: MAX_PENDING, RATE, HELLO_TIMEOUT override the
 * net limits; argv[1] is the token (default "secret"), an admin in an auth
 * file written here (tokens are never given in clear, docs/security.md).
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "hub/hub.h"
#include "net/net.h"

static hub *H;
static atomic_int quit;
static pthread_mutex_t lk = PTHREAD_MUTEX_INITIALIZER;
static uint64_t tick = 1;
static size_t snapshot_bytes = 1000;
static int flood_tx = -1, flood_ty, flood_bytes, flood_per_tick;

static hub_frame *fake_delta(size_t bytes, int tag)
{
    if (bytes < 8)
        bytes = 8;
    hub_frame *f = hub_frame_new(1, bytes);
    memset(f->data, tag & 0xff, bytes);
    f->data[0] = 0x54;
    f->data[1] = 1;
    f->data[2] = 0x10;
    f->data[3] = 0;
    f->data[4] = (unsigned char)tag;
    f->data[5] = (unsigned char)(tag >> 8);
    return f;
}

static void *sim(void *arg)
{
    (void)arg;
    while (!quit) {
        hub_command cmds[64];
        int n = hub_take_commands(H, cmds, 64);
        pthread_mutex_lock(&lk);
        for (int i = 0; i < n; i++) {
            hub_command *c = &cmds[i];
            printf("CMD kind=%d client=%u collider=%u sub=%u rect=%d,%d,%d,%d shape=%d r=%g hl=%g "
                   "mesh=%d pose=%g,%g,%g/%g,%g,%g,%g mat=%s fb=%d ref=%s\n",
                   c->kind, c->client, c->collider, c->subscription, c->rect.x, c->rect.y,
                   c->rect.w, c->rect.h, c->geometry.shape, c->geometry.radius,
                   c->geometry.half_length, c->mesh ? c->mesh->triangle_count : -1,
                   c->pose.position.x, c->pose.position.y, c->pose.position.z,
                   c->pose.orientation.w, c->pose.orientation.x, c->pose.orientation.y,
                   c->pose.orientation.z, c->material, c->feedback, c->ref);
            if (c->mesh) {
                collider_mesh_free(c->mesh);
                free(c->mesh);
            }
            if (c->kind == HUB_SUBSCRIBE || c->kind == HUB_RESYNC) {
                hub_out o = {.kind = HUB_OUT_CLIENT,
                             .client = c->client,
                             .snapshot_done = 1,
                             .tick = tick,
                             .frame = fake_delta(snapshot_bytes, 0xEEEE)};
                hub_publish(H, &o, 1);
            }
        }
        hub_pose poses[256];
        int np = hub_take_poses(H, poses, 256);
        for (int i = 0; i < np; i++)
            printf("POSE collider=%u client=%u seq=%u p=%g,%g,%g q=%g,%g,%g,%g\n",
                   poses[i].collider, poses[i].client, poses[i].sequence, poses[i].pose.position.x,
                   poses[i].pose.position.y, poses[i].pose.position.z, poses[i].pose.orientation.w,
                   poses[i].pose.orientation.x, poses[i].pose.orientation.y,
                   poses[i].pose.orientation.z);
        if (flood_tx >= 0) {
            for (int k = 0; k < flood_per_tick; k++) {
                hub_out o = {.kind = HUB_OUT_TILE_DELTA,
                             .tile_x = flood_tx,
                             .tile_y = flood_ty,
                             .tick = tick,
                             .frame = fake_delta((size_t)flood_bytes, flood_tx * 256 + flood_ty)};
                hub_publish(H, &o, 1);
            }
        }
        tick++;
        fflush(stdout);
        pthread_mutex_unlock(&lk);
        usleep(16000);
    }
    return NULL;
}

/* The one admin token, through an auth file as the daemon reads one. */
static auth_table *admin_table(const char *token, error_text *err)
{
    char path[] = "/tmp/terrad-net-harness-XXXXXX", hex[65];
    int fd = mkstemp(path);
    if (fd < 0) {
        error_set(err, "mkstemp failed");
        return NULL;
    }
    auth_hash_hex(token, hex);
    dprintf(fd, "admin harness %s\n", hex);
    close(fd);
    auth_table *t = auth_create(path, err);
    unlink(path);
    return t;
}

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    H = hub_create();
    net_config c = {0};
    c.port = 0;
    error_text err = {{0}};
    c.auth = admin_table(argc > 1 ? argv[1] : "secret", &err);
    if (!c.auth) {
        fprintf(stderr, "auth: %s\n", err.message);
        return 1;
    }
    c.limits = net_limits_default();
    if (getenv("MAX_PENDING"))
        c.limits.max_pending_bytes = (size_t)atol(getenv("MAX_PENDING"));
    if (getenv("RATE")) {
        c.limits.max_messages_per_s = atof(getenv("RATE"));
        c.limits.messages_burst = 2 * c.limits.max_messages_per_s;
    }
    if (getenv("HELLO_TIMEOUT"))
        c.limits.hello_timeout_s = atof(getenv("HELLO_TIMEOUT"));
    /* its one world, the default of its table of worlds (a single daemon's shape) */
    net_world_info info = {.width = 300,
                           .height = 200,
                           .cell_size_m = 0.05,
                           .units_per_m = 10000,
                           .tick_hz = 60,
                           .tile_size = 64,
                           .height_min = -(1 << 29),
                           .height_max = 1 << 29,
                           .models_json = "[\"persson-ssbo\"]",
                           .materials_json = "[\"default\",\"sand\"]"};
    hub_worlds *worlds = hub_worlds_create();
    hub_worlds_set_default(worlds, "harness");
    c.worlds = worlds;
    net_server *s = net_server_start(&c, &err);
    hub_world e = {.name = "harness", .h = H, .info = &info};
    if (!s || !hub_worlds_add(worlds, &e, &err)) { /* added: the net thread holds it */
        fprintf(stderr, "start: %s\n", err.message);
        return 1;
    }
    printf("PORT %d\n", net_server_port(s));
    pthread_t t;
    pthread_create(&t, NULL, sim, NULL);
    char line[256];
    while (fgets(line, sizeof line, stdin)) {
        int a, b, d, e;
        pthread_mutex_lock(&lk);
        if (sscanf(line, "delta %d %d %d", &a, &b, &d) == 3) {
            hub_out o = {.kind = HUB_OUT_TILE_DELTA,
                         .tile_x = a,
                         .tile_y = b,
                         .tick = tick,
                         .frame = fake_delta((size_t)d, a * 256 + b)};
            hub_publish(H, &o, 1);
            printf("OK delta\n");
        } else if (sscanf(line, "flood %d %d %d %d", &a, &b, &d, &e) == 4) {
            flood_tx = a;
            flood_ty = b;
            flood_bytes = d;
            flood_per_tick = e;
            printf("OK flood\n");
        } else if (sscanf(line, "burst %d %d %d %d", &a, &b, &d, &e) == 4) {
            hub_out *items = calloc((size_t)e, sizeof *items);
            for (int k = 0; k < e; k++)
                items[k] = (hub_out){.kind = HUB_OUT_TILE_DELTA,
                                     .tile_x = a,
                                     .tile_y = b,
                                     .tick = tick,
                                     .frame = fake_delta((size_t)d, a * 256 + b)};
            int dropped = hub_publish(H, items, e);
            free(items);
            printf("OK burst dropped=%d\n", dropped);
        } else if (strncmp(line, "noflood", 7) == 0) {
            flood_tx = -1;
            printf("OK noflood\n");
        } else if (sscanf(line, "snapbytes %d", &a) == 1) {
            snapshot_bytes = (size_t)a;
            printf("OK snapbytes\n");
        } else if (sscanf(line, "client %d %d", &a, &b) == 2) {
            hub_out o = {.kind = HUB_OUT_CLIENT,
                         .client = (uint32_t)a,
                         .tick = tick,
                         .frame = fake_delta((size_t)b, 0x1111)};
            hub_publish(H, &o, 1);
            printf("OK client\n");
        } else if (strncmp(line, "stats", 5) == 0) {
            FILE *f = fopen("/proc/self/status", "r");
            char l2[256];
            long rss = 0;
            while (f && fgets(l2, sizeof l2, f))
                if (!strncmp(l2, "VmRSS:", 6))
                    rss = atol(l2 + 6);
            if (f)
                fclose(f);
            printf("STATS clients=%d rss_kb=%ld\n", net_server_client_count(s), rss);
        } else if (strncmp(line, "quit", 4) == 0) {
            pthread_mutex_unlock(&lk);
            break;
        }
        fflush(stdout);
        pthread_mutex_unlock(&lk);
    }
    double t0 = time_now_ms();
    net_server_stop(s);
    printf("STOPPED in %.0f ms\n", time_now_ms() - t0);
    hub_worlds_destroy(worlds);
    quit = 1;
    pthread_join(t, NULL);
    hub_destroy(H);
    auth_free(c.auth);
    return 0;
}
