/*
 * bench_cosim.c: lockstep co-simulation through the C client (issue 30, item 5). Starts its own
 * daemon (TERRAD_BIN, or terrad beside this binary) on loopback, creates client-clocked worlds of
 * a thesis-car-like scene (flat 0.4 m of ding2011 bekker soil, 2 cm cells), and drives in each a
 * four-wheeled rover (thesis-car's wheels: r 0.33 m, 0.2 m wide, wheelbase 2.6 m, track 1.5 m,
 * 8 cm deep, 0.55 m/s) with terrad_client_step / terrad_client_step_many:
 *
 *   - one rover, n ticks per STEP (n = 1, 4, 16): steps/s and rover-ticks/s, the p50/p99 of one
 *     step's round trip, and its split: the daemon's tick (terrad_tick_duration_seconds: the
 *     engine, deltas and the log, up to the tick's publication), the client's CPU (this process:
 *     encoding, libwebsockets, decoding) and the rest (the protocol: the hand-over of the tick's
 *     frames, the daemon's net thread, wake-ups, the kernel);
 *   - K = 1, 8, 64 worlds stepped as one: aggregate rover-ticks/s;
 *   - the in-process cost of the same tick: `terrad simulate` on the same scene with the same
 *     four wheels scripted (no service, net or store);
 *   - beside Chrono SCM's published 0.351 ms a step (HMMWV, i7-13700K, 4 threads;
 *     projectchrono/chrono src/tests/benchmark_tests/vehicle/SCM_benchmarks.md).
 *
 * --durability none (every tick written before it is published: kill -9 loses nothing
 * acknowledged; a power loss may lose the last seconds), and the one-rover n = 1 figure again
 * with every-tick (an fdatasync per tick). Prints; never fails on a figure (exit 1 only when the
 * daemon or a step fails). Goals (issue 30): one rover >= 3,000 steps/s, 64 batched >= 8,000
 * rover-steps/s on the 2-core machine.
 */
#include <arpa/inet.h>
#include <math.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "terrad_client.h"
#include "terrad_proto.h"

#define WORLD_W 1600 /* 32 m of 2 cm cells */
#define WORLD_H 400  /* 8 m */
#define CELL 0.02
#define GROUND 0.4
#define RADIUS 0.33
#define DEPTH 0.08
#define SPEED 0.55
#define HZ 60.0
#define KMAX 64

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static double cpu_self_s(void)
{
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + (double)ru.ru_stime.tv_sec +
           ru.ru_stime.tv_usec * 1e-6;
}

/* ---- the daemon ---- */

typedef struct daemon_proc {
    pid_t pid;
    int http, ws;
    char log[300], data[256];
} daemon_proc;

static int daemon_start(daemon_proc *d, const char *bin, const char *durability)
{
    snprintf(d->data, sizeof d->data, "/tmp/terrad-bench-cosim-XXXXXX");
    if (!mkdtemp(d->data))
        return -1;
    snprintf(d->log, sizeof d->log, "%s.log", d->data);
    /* its default world: tiny and client-clocked, so it never ticks beside the bench's */
    char scene[300];
    snprintf(scene, sizeof scene, "%s/idle.json", d->data);
    FILE *sf = fopen(scene, "w");
    if (!sf)
        return -1;
    fputs("{\"name\":\"idle\",\"clock\":\"client\",\"world\":{\"width\":8,\"height\":8,"
          "\"cell_size_m\":0.02},\"terrain\":{\"kind\":\"flat\",\"height_m\":0.4}}",
          sf);
    fclose(sf);
    d->pid = fork();
    if (d->pid == 0) {
        FILE *f = freopen(d->log, "w", stderr);
        (void)f;
        execl(bin, bin, "serve", "--http-port", "0", "--ws-port", "0", "--no-demo", "--backend",
              "cpu", "--data", d->data, "--durability", durability, "--scene", scene,
              "--max-worlds", "100", (char *)NULL);
        _exit(127);
    }
    for (double end = now_s() + 60; now_s() < end; usleep(50000)) {
        FILE *f = fopen(d->log, "r");
        char line[1024];
        while (f && fgets(line, sizeof line, f)) {
            const char *p = strstr(line, "http://127.0.0.1:");
            const char *q = strstr(line, "ws://127.0.0.1:");
            if (strstr(line, "serving scene") && p && q) {
                d->http = atoi(p + 17);
                d->ws = atoi(q + 15);
                fclose(f);
                return 0;
            }
        }
        if (f)
            fclose(f);
    }
    return -1;
}

static void daemon_stop(daemon_proc *d)
{
    if (d->pid > 0) {
        kill(d->pid, SIGTERM);
        waitpid(d->pid, NULL, 0);
    }
    char cmd[600];
    snprintf(cmd, sizeof cmd, "rm -rf '%s' '%s'", d->data, d->log);
    if (system(cmd) != 0)
        fprintf(stderr, "bench_cosim: could not remove %s\n", d->data);
}

/* One HTTP/1.0 request; the answer (status line and body) in out. */
static int http_call(int port, const char *method, const char *path, const char *body, char *out,
                     size_t cap)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (fd < 0 || connect(fd, (struct sockaddr *)&a, sizeof a) != 0) {
        if (fd >= 0)
            close(fd);
        return -1;
    }
    char head[512];
    int n = snprintf(head, sizeof head,
                     "%s %s HTTP/1.0\r\nContent-Type: application/json\r\nContent-Length: %zu"
                     "\r\n\r\n",
                     method, path, body ? strlen(body) : 0);
    if (write(fd, head, (size_t)n) != n ||
        (body && write(fd, body, strlen(body)) != (ssize_t)strlen(body))) {
        close(fd);
        return -1;
    }
    size_t len = 0;
    ssize_t r;
    while (len + 1 < cap && (r = read(fd, out + len, cap - 1 - len)) > 0)
        len += (size_t)r;
    out[len] = 0;
    close(fd);
    return atoi(out + 9); /* "HTTP/1.1 201" */
}

static const char *scene_json(int with_wheels, char *buf, size_t cap);

static int create_world(const daemon_proc *d, const char *name)
{
    static char body[4096], out[8192];
    char scene[2048];
    snprintf(body, sizeof body, "{\"name\":\"%s\",\"clock\":\"client\",\"scene\":%s}", name,
             scene_json(0, scene, sizeof scene));
    return http_call(d->http, "POST", "/v1/worlds", body, out, sizeof out) == 201 ? 0 : -1;
}

/* From /metrics: terrad_tick_duration_seconds' sum and count, and the engine's part of the
 * ticks (terrad_stage_duration_seconds of the model and of gather/scatter: the rest of a tick is
 * the service's — input, contacts, deltas, the log, up to the tick's publication). */
static void tick_seconds(const daemon_proc *d, double *sum, double *count, double *engine)
{
    static char out[1 << 20];
    *sum = *count = *engine = 0;
    if (http_call(d->http, "GET", "/metrics", NULL, out, sizeof out) != 200)
        return;
    static const char *const keys[] = {
        "\nterrad_tick_duration_seconds_sum ", "\nterrad_tick_duration_seconds_count ",
        "\nterrad_stage_duration_seconds_sum{stage=\"model\"} ",
        "\nterrad_stage_duration_seconds_sum{stage=\"gather_scatter\"} "};
    double v[4] = {0, 0, 0, 0};
    for (int i = 0; i < 4; i++) {
        const char *p = strstr(out, keys[i]);
        if (p)
            v[i] = atof(p + strlen(keys[i]));
    }
    *sum = v[0];
    *count = v[1];
    *engine = v[2] + v[3];
}

static double daemon_cpu_s(const daemon_proc *d)
{
    char path[64], buf[1024];
    snprintf(path, sizeof path, "/proc/%d/stat", (int)d->pid);
    FILE *f = fopen(path, "r");
    if (!f)
        return 0;
    size_t n = fread(buf, 1, sizeof buf - 1, f);
    fclose(f);
    buf[n] = 0;
    const char *p = strrchr(buf, ')');
    unsigned long ut = 0, st = 0;
    if (p)
        sscanf(p + 2, "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %lu %lu", &ut, &st);
    return (double)(ut + st) / (double)sysconf(_SC_CLK_TCK);
}

/* ---- the rover ---- */

/* The scene: without wheels for the daemon's worlds, with them scripted for terrad simulate. */
static const char *scene_json(int with_wheels, char *buf, size_t cap)
{
    int n = snprintf(buf, cap,
                     "{\"name\":\"cosim-rover\",\"world\":{\"width\":%d,\"height\":%d,"
                     "\"cell_size_m\":%g},\"terrain\":{\"kind\":\"flat\",\"height_m\":%g},"
                     "\"material\":{\"model\":\"bekker\",\"compression\":0.5,\"soil\":{\"preset\":"
                     "\"ding2011\"}},\"tick_hz\":%g,\"colliders\":[",
                     WORLD_W, WORLD_H, CELL, GROUND, HZ);
    for (int w = 0; with_wheels && w < 4; w++)
        n += snprintf(buf + n, cap - (size_t)n,
                      "%s{\"name\":\"w%d\",\"shape\":\"wheel\",\"radius\":%g,\"half_length\":0.1,"
                      "\"position\":[%g,%g,%g],\"motion\":{\"velocity\":[%g,0,0],\"spin_axis\":"
                      "[0,1,0],\"spin_deg_per_s\":%.9g}}",
                      w ? "," : "", w, RADIUS, 2.0 + (w % 2) * 2.6, 3.25 + (w / 2) * 1.5,
                      GROUND + RADIUS - DEPTH, SPEED, SPEED / RADIUS * 180.0 / M_PI);
    snprintf(buf + n, cap - (size_t)n, "]}");
    return buf;
}

typedef struct rover {
    terrad_client *c;
    uint32_t wheel[4];
    long tick; /* the script's */
    terrad_pose poses[16 * 4];
} rover;

static int rover_open(rover *r, const daemon_proc *d, const char *world)
{
    char err[256];
    r->c = terrad_client_connect_world(
        (terrad_client_desc){.port = d->ws, .name = "bench_cosim", .timeout_ms = 60000}, world, err,
        sizeof err);
    if (!r->c)
        return fprintf(stderr, "bench_cosim: %s: %s\n", world, err), -1;
    for (int w = 0; w < 4; w++)
        if (terrad_client_create_collider(
                r->c,
                (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL, .radius = RADIUS, .width = 0.2},
                &r->wheel[w]) != 0)
            return fprintf(stderr, "bench_cosim: wheel: %s\n", terrad_client_last_error(r->c)), -1;
    r->tick = 0;
    return 0;
}

/* The next STEP of n ticks: each tick's four poses, as the scene's scripted motion. */
static terrad_step rover_step(rover *r, uint32_t n)
{
    for (uint32_t i = 0; i < n; i++, r->tick++) {
        double t = (double)r->tick / HZ, angle = SPEED / RADIUS * t;
        for (int w = 0; w < 4; w++)
            r->poses[i * 4 + (uint32_t)w] = (terrad_pose){r->wheel[w],
                                                          (float)(2.0 + (w % 2) * 2.6 + SPEED * t),
                                                          (float)(3.25 + (w / 2) * 1.5),
                                                          (float)(GROUND + RADIUS - DEPTH),
                                                          (float)cos(angle / 2),
                                                          0.0f,
                                                          (float)sin(angle / 2),
                                                          0.0f};
    }
    return (terrad_step){.ticks = n, .poses = r->poses, .count = 4, .sets = (uint16_t)n};
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* One rover, steps of n ticks: prints its figures; returns its rover-ticks/s (0 on failure). */
static double one_rover(const daemon_proc *d, const char *world, uint32_t n, long steps,
                        const char *label)
{
    rover r;
    if (create_world(d, world) != 0 || rover_open(&r, d, world) != 0)
        return fprintf(stderr, "bench_cosim: world %s not made\n", world), 0;
    double *rt = malloc((size_t)steps * sizeof *rt);
    for (int i = 0; i < 20; i++) { /* warm-up: the wheels' first windows */
        terrad_step s = rover_step(&r, n);
        if (terrad_client_step(r.c, &s, NULL) != 0)
            return fprintf(stderr, "%s\n", terrad_client_last_error(r.c)), 0;
    }
    double sum0, count0, eng0, sum1, count1, eng1;
    tick_seconds(d, &sum0, &count0, &eng0);
    double dcpu0 = daemon_cpu_s(d), ccpu0 = cpu_self_s(), t0 = now_s();
    for (long i = 0; i < steps; i++) {
        terrad_step s = rover_step(&r, n);
        double a = now_s();
        if (terrad_client_step(r.c, &s, NULL) != 0)
            return fprintf(stderr, "%s\n", terrad_client_last_error(r.c)), 0;
        rt[i] = now_s() - a;
    }
    double wall = now_s() - t0, ccpu = cpu_self_s() - ccpu0, dcpu = daemon_cpu_s(d) - dcpu0;
    tick_seconds(d, &sum1, &count1, &eng1);
    qsort(rt, (size_t)steps, sizeof *rt, cmp_double);
    double step_ms = wall / (double)steps * 1e3;
    double tick_ms = count1 > count0 ? (sum1 - sum0) / (count1 - count0) * 1e3 : 0;
    double engine_ms = count1 > count0 ? (eng1 - eng0) / (count1 - count0) * 1e3 : 0;
    double server_ms = tick_ms * n, client_ms = ccpu / (double)steps * 1e3;
    printf("%s: n = %u tick%s a step, %ld steps: %.0f steps/s, %.0f rover-ticks/s; round trip "
           "p50 %.3f ms, p99 %.3f ms; a step = %.3f ms: the daemon's ticks %.3f ms (%.3f a tick: "
           "engine %.3f, service %.3f), client CPU %.3f ms, protocol and wake-ups %.3f ms "
           "(daemon CPU %.3f ms a step)\n",
           label, n, n > 1 ? "s" : "", steps, steps / wall, steps * (double)n / wall,
           rt[steps / 2] * 1e3, rt[steps * 99 / 100] * 1e3, step_ms, server_ms, tick_ms, engine_ms,
           tick_ms - engine_ms, client_ms, step_ms - server_ms - client_ms,
           dcpu / (double)steps * 1e3);
    free(rt);
    terrad_client_close(r.c);
    return steps * (double)n / wall;
}

/* K rovers in K worlds stepped as one (terrad_client_step_many). */
static double batched(const daemon_proc *d, int k, long steps, const char *prefix)
{
    static rover r[KMAX];
    terrad_client *cs[KMAX];
    terrad_step st[KMAX];
    for (int i = 0; i < k; i++) {
        char name[64];
        snprintf(name, sizeof name, "%s-%d", prefix, i);
        if (create_world(d, name) != 0 || rover_open(&r[i], d, name) != 0)
            return fprintf(stderr, "bench_cosim: world %s not made\n", name), 0;
        cs[i] = r[i].c;
    }
    double t0 = 0;
    for (long s = -10; s < steps; s++) {
        if (s == 0)
            t0 = now_s();
        for (int i = 0; i < k; i++)
            st[i] = rover_step(&r[i], 1);
        if (terrad_client_step_many(cs, st, (size_t)k, NULL, NULL) != 0)
            return fprintf(stderr, "step_many: %s\n", terrad_client_last_error(cs[0])), 0;
    }
    double wall = now_s() - t0, rate = k * (double)steps / wall;
    printf("K = %d worlds stepped as one, n = 1, %ld steps: %.0f rover-steps/s aggregate (%.3f ms "
           "a batch)\n",
           k, steps, rate, wall / (double)steps * 1e3);
    for (int i = 0; i < k; i++)
        terrad_client_close(r[i].c);
    return rate;
}

/* terrad simulate on the same scene with the four wheels scripted: ms per tick in process. */
static double in_process_ms(const char *bin)
{
    char path[] = "/tmp/terrad-bench-cosim-scene-XXXXXX", scene[4096], cmd[1024];
    int fd = mkstemp(path);
    if (fd < 0)
        return 0;
    scene_json(1, scene, sizeof scene);
    if (write(fd, scene, strlen(scene)) != (ssize_t)strlen(scene)) {
        close(fd);
        return 0;
    }
    close(fd);
    snprintf(cmd, sizeof cmd, "'%s' simulate --scene '%s' --ticks 600 --backend cpu 2>/dev/null",
             bin, path);
    FILE *p = popen(cmd, "r");
    static char out[1 << 16];
    size_t n = p ? fread(out, 1, sizeof out - 1, p) : 0;
    if (p)
        pclose(p);
    unlink(path);
    out[n] = 0;
    cJSON *j = cJSON_Parse(out);
    cJSON *ms = cJSON_GetObjectItem(cJSON_GetObjectItem(cJSON_GetObjectItem(j, "stages"), "tick"),
                                    "mean_ms");
    double v = cJSON_IsNumber(ms) ? ms->valuedouble : 0;
    cJSON_Delete(j);
    return v;
}

int main(int argc, char **argv)
{
    char bin[512];
    const char *env = getenv("TERRAD_BIN");
    if (env)
        snprintf(bin, sizeof bin, "%s", env);
    else {
        snprintf(bin, sizeof bin, "%s", argv[0]);
        char *slash = strrchr(bin, '/');
        snprintf(slash ? slash + 1 : bin, sizeof bin - (size_t)(slash ? slash + 1 - bin : 0),
                 "terrad");
    }
    double scale = argc > 1 ? atof(argv[1]) : 1.0; /* fewer steps for a quick look */
    char cpu[128] = "?", load[64] = "?";
    FILE *f = fopen("/proc/cpuinfo", "r");
    char line[256];
    while (f && fgets(line, sizeof line, f))
        if (!strncmp(line, "model name", 10)) {
            snprintf(cpu, sizeof cpu, "%s", strchr(line, ':') + 2);
            cpu[strcspn(cpu, "\n")] = 0;
            break;
        }
    if (f)
        fclose(f);
    f = fopen("/proc/loadavg", "r");
    if (f && fgets(load, sizeof load, f))
        load[strcspn(load, "\n")] = 0;
    if (f)
        fclose(f);
    printf("bench_cosim: %s, %ld cores, load %s; a four-wheeled rover (thesis-car's wheels) on "
           "ding2011 bekker soil, 2 cm cells, %dx%d cells\n",
           cpu, sysconf(_SC_NPROCESSORS_ONLN), load, WORLD_W, WORLD_H);
    double inproc = in_process_ms(bin);
    printf("in process (terrad simulate, the same four wheels): %.3f ms a tick; Chrono SCM "
           "(HMMWV, i7-13700K, 4 threads, SCM_benchmarks.md): 0.351 ms a step\n",
           inproc);
    daemon_proc d = {0};
    if (daemon_start(&d, bin, "none") != 0) {
        fprintf(stderr, "bench_cosim: the daemon did not start (%s)\n", bin);
        return 1;
    }
    double one = one_rover(&d, "one-1", 1, (long)(1500 * scale), "one rover");
    one_rover(&d, "one-4", 4, (long)(400 * scale), "one rover");
    one_rover(&d, "one-16", 16, (long)(100 * scale), "one rover");
    double b1 = batched(&d, 1, (long)(600 * scale), "k1");
    double b8 = batched(&d, 8, (long)(200 * scale), "k8");
    double b64 = batched(&d, 64, (long)(40 * scale) + 1, "k64");
    daemon_stop(&d);
    printf("goals (issue 30): one rover >= 3000 steps/s: %.0f (%s); 64 batched >= 8000 "
           "rover-steps/s: %.0f (%s); K = 1 batched %.0f, K = 8 %.0f\n",
           one, one >= 3000 ? "met" : "NOT met", b64, b64 >= 8000 ? "met" : "NOT met", b1, b8);
    if (daemon_start(&d, bin, "every-tick") == 0) {
        one_rover(&d, "sync-1", 1, (long)(300 * scale), "one rover, --durability every-tick");
        daemon_stop(&d);
    }
    return 0;
}
