/*
 * c_cosim_drive: a lockstep co-simulation driver over the C client library
 * (terrad_client_step / terrad_client_step_many, PROTOCOL.md "STEP"), for the
 * Python tests that start the daemon (test_cosim_lockstep.py). Not a test
 * itself.
 *
 *   c_cosim_drive PORT WORLDS STEPS OUT [many|alone|pause]
 *
 * WORLDS is a comma-separated list of client-clocked worlds (created by the
 * test, bekker soil, COSIM_W x COSIM_H cells). In each: four wheels of a
 * rover (two load-driven, two pose-driven), a subscription of the whole
 * world, then STEPS steps of a fixed, deterministic script: most steps one
 * tick with one pose set, every 7th three ticks with a pose set per tick,
 * every 11th two ticks holding. "many" steps all worlds as one
 * (terrad_client_step_many); "alone" steps each world to the end in turn;
 * "pause" steps like "many", then prints PAUSED and waits to be killed.
 *
 * OUT.<world> gets every FORCES entry of every tick (wheel index, not id:
 * ids differ between runs; floats as %a, so bit for bit), each STEPPED tick,
 * and at the end (or at PAUSED) the mirror's heights. Lines "ACKED <world>
 * <tick>" go to stdout as each step is answered (flushed: a test may kill the
 * daemon at any moment). Exits 0 when every step was answered, 1 otherwise.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "terrad_client.h"
#include "terrad_proto.h"

#define COSIM_W 96
#define COSIM_H 64
#define COSIM_CELL 0.05
#define COSIM_GROUND 0.4
#define WHEELS 4
#define MAX_WORLDS 64
#define RADIUS 0.2

typedef struct drive {
    const char *world;
    terrad_client *c;
    uint32_t wheel[WHEELS], sid;
    FILE *out;
} drive;

static void on_frame(void *user, terrad_client *c, int msg_type, uint64_t tick)
{
    drive *d = user;
    if (msg_type != TERRAD_MSG_FORCES)
        return;
    for (int w = 0; w < WHEELS; w++) {
        terrad_force f;
        uint64_t at;
        if (!terrad_client_force(c, d->wheel[w], &f, &at) || at != tick)
            continue;
        fprintf(d->out, "F %llu %d %a %a %a %a %a %a %a %a %a %a %u\n", (unsigned long long)tick, w,
                f.force[0], f.force[1], f.force[2], f.torque[0], f.torque[1], f.torque[2],
                f.sinkage_m, f.area_m2, f.patch_width_m, f.slip, f.cells);
    }
}

/* Wheel w's pose at tick t: a rover crawling along x, wheels turning with 30 % slip. */
static terrad_pose wheel_pose(const drive *d, int w, long t)
{
    double x0 = 1.0 + (w % 2) * 0.9, y = 1.1 + (w / 2) * 1.0;
    double x = x0 + 0.012 * (double)t; /* 0.72 m/s at 60 Hz, under a cell a tick */
    double angle = 0.012 * (double)t / (RADIUS * 0.7);
    double z = COSIM_GROUND + RADIUS - 0.02;
    return (terrad_pose){
        d->wheel[w],           (float)x, (float)y, (float)z, (float)cos(angle / 2), 0.0f,
        (float)sin(angle / 2), 0.0f};
}

/* Step k of the script, its poses in buf (starting at tick t); returns its ticks. */
static terrad_step script(const drive *d, long k, long t, terrad_pose *buf)
{
    terrad_step s = {.ticks = 1, .poses = buf, .count = WHEELS, .sets = 1};
    if (k % 11 == 10) {
        s.ticks = 2;
        s.sets = 0; /* hold: the load-driven wheels settle, nothing else moves */
        s.count = 0;
    } else if (k % 7 == 6) {
        s.ticks = s.sets = 3;
    }
    for (uint32_t i = 0; i < s.sets; i++)
        for (int w = 0; w < WHEELS; w++)
            buf[i * WHEELS + (uint32_t)w] = wheel_pose(d, w, t + (long)i);
    return s;
}

static int open_drive(drive *d, int port, const char *out_prefix)
{
    char err[512] = "", path[512];
    snprintf(path, sizeof path, "%s.%s", out_prefix, d->world);
    if (!(d->out = fopen(path, "w")))
        return fprintf(stderr, "cannot write %s\n", path), -1;
    d->c = terrad_client_connect_world((terrad_client_desc){.port = port,
                                                            .name = "c_cosim_drive",
                                                            .timeout_ms = 60000,
                                                            .hook = on_frame,
                                                            .user = d},
                                       d->world, err, sizeof err);
    if (!d->c)
        return fprintf(stderr, "connect %s: %s\n", d->world, err), -1;
    if (!terrad_client_world_client_clock(d->c))
        return fprintf(stderr, "%s: not a client-clocked world\n", d->world), -1;
    for (int w = 0; w < WHEELS; w++) {
        terrad_collider_desc wd = {.shape = TERRAD_SHAPE_WHEEL, .radius = RADIUS, .width = 0.12};
        int rc = w < 2 ? terrad_client_create_loaded_collider(d->c, wd, 120.0, &d->wheel[w])
                       : terrad_client_create_collider(d->c, wd, &d->wheel[w]);
        if (rc)
            return fprintf(stderr, "%s: wheel %d: %s\n", d->world, w,
                           terrad_client_last_error(d->c)),
                   -1;
    }
    if (terrad_client_subscribe(d->c, 0, 0, COSIM_W, COSIM_H, &d->sid))
        return fprintf(stderr, "%s: subscribe: %s\n", d->world, terrad_client_last_error(d->c)), -1;
    return 0;
}

static void dump_mirror(drive *d)
{
    const terrad_mirror *m = terrad_client_mirror(d->c, d->sid);
    fprintf(d->out, "MIRROR %d complete\n", terrad_client_mirror_complete(d->c, d->sid));
    for (int y = 0; m && y < COSIM_H; y++) {
        for (int x = 0; x < COSIM_W; x++)
            fprintf(d->out, "%d ", m->heights[y * COSIM_W + x]);
        fputc('\n', d->out);
    }
    fflush(d->out);
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: c_cosim_drive PORT WORLDS STEPS OUT [many|alone|pause]\n");
        return 2;
    }
    int port = atoi(argv[1]);
    long steps = atol(argv[3]);
    const char *mode = argc > 5 ? argv[5] : "many";
    static drive d[MAX_WORLDS];
    int k = 0;
    char *list = strdup(argv[2]);
    for (char *tok = strtok(list, ","); tok && k < MAX_WORLDS; tok = strtok(NULL, ","))
        d[k++].world = tok;
    for (int i = 0; i < k; i++)
        if (open_drive(&d[i], port, argv[4]) != 0)
            return 1;
    static terrad_pose buf[MAX_WORLDS][3 * WHEELS];
    terrad_step st[MAX_WORLDS];
    terrad_client *cs[MAX_WORLDS];
    uint64_t ticks[MAX_WORLDS];
    int rcs[MAX_WORLDS];
    long t = 0; /* the script's tick count: the same in every world */
    int alone = strcmp(mode, "alone") == 0;
    for (int first = 0; first < k; first += alone ? 1 : k) {
        int n = alone ? 1 : k;
        t = 0;
        for (long s = 0; s < steps; s++) {
            for (int i = 0; i < n; i++) {
                st[i] = script(&d[first + i], s, t, buf[i]);
                cs[i] = d[first + i].c;
            }
            t += st[0].ticks;
            terrad_client_step_many(cs, st, (size_t)n, ticks, rcs);
            for (int i = 0; i < n; i++) {
                drive *di = &d[first + i];
                if (rcs[i] != 0) {
                    fprintf(stderr, "%s: step %ld: %s\n", di->world, s,
                            terrad_client_last_error(di->c));
                    return 1;
                }
                fprintf(di->out, "STEPPED %llu\n", (unsigned long long)ticks[i]);
                printf("ACKED %s %llu\n", di->world, (unsigned long long)ticks[i]);
            }
            fflush(stdout);
        }
    }
    for (int i = 0; i < k; i++)
        dump_mirror(&d[i]);
    if (strcmp(mode, "pause") == 0) {
        printf("PAUSED\n");
        fflush(stdout);
        for (;;)
            pause();
    }
    for (int i = 0; i < k; i++) {
        terrad_client_close(d[i].c);
        fclose(d[i].out);
    }
    free(list);
    printf("ok\n");
    return 0;
}
