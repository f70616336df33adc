/*
 * c_predict_drive: the C client's prediction and its hello into a named world
 * (terrad_client.h, docs/engines.md), driven against a real daemon for
 * tests/integration/clients/test_predict_c.py, linked to the shared libterrad-client
 * (and through it libterrad-twin) as a game would be.
 *
 *   c_predict_drive predict PORT X Y W H CONFIG OUT   the Python test's drive, in C
 *   c_predict_drive world PORT NAME W H OUT            hello into world NAME
 *   c_predict_drive loaded PORT X Y W H CONFIG         a load-driven wheel (bekker)
 *
 * predict: client A subscribes the window, predicts it with CONFIG (the
 * scene's twin keys) and drives a sphere, a rolling wheel, a capsule (a
 * quaternion of norm 1.04) and a rolling wheel with grousers (its lugs
 * deeper than its rim) through it for 600 ticks; client B then ploughs it
 * with its own sphere. Checks, each a CHECK line: bad input to the new calls
 * is refused naming the field (grousers out of range among it, by the
 * server); the rut is in the prediction before the
 * server's ACK of its batch; every compared ACK's replay has 0 cells
 * differing; B's rut makes replays differ and every reconciliation with
 * nothing pending equals the mirror. At the end both clients delete their
 * colliders and OUT gets the mirror's heights (int32, little-endian) for the
 * test to compare with GET /v1/heights.
 *
 * world: connects into NAME (checks the world message's name and size),
 * refuses an unknown and an over-long name naming "world", presses a sphere
 * into the world and writes the mirror of (0, 0, W, H) to OUT.
 *
 * loaded: on a bekker world, predicts the window with CONFIG and rolls a
 * load-driven wheel (terrad_client_create_loaded_collider: its height is
 * the server's, found where the soil carries the load) through it with slip
 * for 300 ticks. Checks: every compared ACK's replay has 0 cells differing
 * (the twin runs the server's search from the state its replay reached);
 * the server found heights below the posed one (terrad_client_force_height).
 * Then it rolls the wheel back with the next soil-state restore failing
 * (terrad_twin_fault_restores, the twin library's test hook: out of memory
 * for it cannot be provoked): the prediction's stats count one error with
 * the twin's sentence, and the client goes on: the later ACKs are taken and
 * compared, and with nothing pending the prediction is the mirror at each.
 *
 * Prints "N passed, N failed"; exit 1 on a failure.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L
#endif
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "check.h"
#include "terrad_client.h"
#include "terrad_twin.h"

#define WAIT_S 120.0 /* generous: the machine may be loaded */

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Services both clients until t (b may be NULL). */
static void pump_until(terrad_client *a, terrad_client *b, double t)
{
    do {
        double left = t - now_s();
        int ms = left > 0.002 ? 2 : 0;
        terrad_client_poll(a, ms);
        if (b)
            terrad_client_poll(b, 0);
    } while (now_s() < t);
}

static int wait_ack(terrad_client *c, terrad_client *other, uint32_t seq)
{
    double end = now_s() + WAIT_S;
    while (now_s() < end && terrad_client_is_open(c)) {
        if ((int32_t)(terrad_client_get_stats(c)->ack_seq - seq) >= 0)
            return 1;
        terrad_client_poll(c, 20);
        if (other)
            terrad_client_poll(other, 0);
    }
    return 0;
}

static int wait_complete(terrad_client *c, uint32_t sid)
{
    double end = now_s() + WAIT_S;
    while (now_s() < end && !terrad_client_mirror_complete(c, sid))
        terrad_client_poll(c, 20);
    return terrad_client_mirror_complete(c, sid);
}

static terrad_client *open_client(int port, const char *world, const char *name,
                                  terrad_client_hook hook, void *user)
{
    char err[256];
    terrad_client_desc d = {
        .port = port, .name = name, .timeout_ms = (int)(WAIT_S * 1000), .hook = hook, .user = user};
    terrad_client *c = terrad_client_connect_world(d, world, err, sizeof err);
    if (!c)
        printf("cannot connect %s: %s\n", name, err);
    return c;
}

static int write_heights(const char *path, const int32_t *h, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (!f)
        return -1;
    size_t w = fwrite(h, sizeof *h, n, f);
    return fclose(f) == 0 && w == n ? 0 : -1;
}

/* ---- predict --------------------------------------------------------------- */

typedef struct drive {
    int32_t x, y;
    uint32_t w, h;
    double cell, hz;
    terrad_prediction *pred;
    const terrad_mirror *mirror;
    int resets, resets_bad; /* reconciliations with nothing pending, and those != the mirror */
} drive;

/* Along x through the window, leaving a 24-cell halo at both ends. */
static terrad_pose pose_at(const drive *d, uint32_t id, int i, int n, int y_cell, double z)
{
    double x0 = (d->x + 24) * d->cell, x1 = (d->x + (int)d->w - 24) * d->cell;
    return (terrad_pose){id,
                         (float)(x0 + (x1 - x0) * i / (n - 1)),
                         (float)((y_cell + 0.5) * d->cell),
                         (float)z,
                         1,
                         0,
                         0,
                         0};
}

/* Runs after A's prediction reconciled each ACK (the client calls the hook last). */
static void on_frame(void *user, terrad_client *c, int type, uint64_t tick)
{
    (void)c, (void)tick;
    drive *d = user;
    if (type != TERRAD_MSG_ACK || !d->pred || terrad_prediction_get_stats(d->pred)->pending)
        return;
    d->resets++;
    size_t n = (size_t)d->w * d->h;
    d->resets_bad += memcmp(terrad_prediction_heights(d->pred), d->mirror->heights, n * 4) != 0;
}

static void bad_input(terrad_client *a, uint32_t sid, const char *cfg)
{
    terrad_prediction *p = NULL;
    int rc = terrad_client_predict(a, 9999, cfg, &p);
    CHECK(rc == TERRAD_E_BAD_VALUE && !p && strstr(terrad_client_last_error(a), "sid"),
          "an unknown subscription is refused naming sid (%d: %s)", rc,
          terrad_client_last_error(a));
    const char *bad[][2] = {{"model=nope", "model"},
                            {"compression=nan", "compression"},
                            {"shape_of_things=1", "shape_of_things"},
                            {"margin_cells", "config"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        char text[4096];
        snprintf(text, sizeof text, "%s %s", cfg, bad[i][0]);
        rc = terrad_client_predict(a, sid, text, &p);
        CHECK(rc == TERRAD_E_BAD_VALUE && !p && strstr(terrad_client_last_error(a), bad[i][1]),
              "'%s' is refused naming %s (%d: %s)", bad[i][0], bad[i][1], rc,
              terrad_client_last_error(a));
    }
    rc = terrad_client_predict(a, sid, cfg, NULL);
    CHECK(rc == TERRAD_E_BAD_VALUE && strstr(terrad_client_last_error(a), "out"),
          "a NULL out is refused naming it (%s)", terrad_client_last_error(a));
}

/* 12 lugs a cell tall: each its own dent */
static const terrad_grousers LUGS = {12, 0.05, 0.04};

/* Lugs out of range while predicting: the server refuses them naming the
 * field, and the prediction has nothing new to tick. */
static void bad_lugs(terrad_client *a, const drive *d, terrad_collider_desc wheel)
{
    const struct {
        terrad_grousers g;
        const char *field;
    } bad[] = {{{-2, 0.05, 0.04}, "grousers.count"},
               {{400, 0.05, 0.04}, "grousers.count"},
               {{12, 0.5, 0.04}, "grousers.height"},
               {{12, 0.05, -0.01}, "grousers.thickness"}};
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        uint32_t id = 0;
        int rc = terrad_client_create_lugged_collider(a, wheel, bad[i].g, 0.0, &id);
        CHECK(rc != 0 && strstr(terrad_client_last_error(a), bad[i].field),
              "grousers {%d, %g, %g} refused naming %s (%d: %s)", bad[i].g.count, bad[i].g.height,
              bad[i].g.thickness, bad[i].field, rc, terrad_client_last_error(a));
    }
    CHECK(terrad_prediction_get_stats(d->pred)->predicted == 0, "the refusals ticked nothing");
}

static uint32_t make(terrad_client *c, terrad_collider_desc d)
{
    uint32_t id = 0;
    int rc = terrad_client_create_collider(c, d, &id);
    CHECK(rc == 0, "collider created (%d: %s)", rc, terrad_client_last_error(c));
    return id;
}

enum { OWN = 4 }; /* A's colliders: sphere, wheel, capsule, lugged wheel */

/* A's 600 ticks: its own colliders, one pose batch a tick. */
static void drive_own(terrad_client *a, drive *d, const uint32_t ids[OWN], const int rows[OWN],
                      double z)
{
    const int n = 600;
    int early_seq = -1, early_acked = -1;
    double next = now_s();
    size_t cells = (size_t)d->w * d->h;
    for (int i = 0; i <= n; i++) {
        int k = i < n ? i : n - 1;
        double lift = i < n ? 0 : 5.0;
        terrad_pose p[OWN] = {pose_at(d, ids[0], k, n, rows[0], z + lift),
                              pose_at(d, ids[1], k, n, rows[1], z + lift),
                              pose_at(d, ids[2], k, n, rows[2], 0.4 + 0.12 - 0.04 + lift),
                              pose_at(d, ids[3], k, n, rows[3], z + lift)};
        for (int w = 1; w < OWN; w += 2) { /* the wheels roll */
            double angle = p[w].x / 0.3;
            p[w].qw = (float)cos(angle / 2), p[w].qy = (float)sin(angle / 2);
        }
        p[2].qw = p[2].qy = (float)(1.04 * sqrt(0.5)); /* norm 1.04, turned from axis z */
        uint32_t seq = 0;
        CHECK(terrad_client_send_poses(a, p, OWN, &seq) == 0, "poses sent");
        if (early_seq < 0) { /* the rut in the prediction, not yet in the mirror */
            const int32_t *mine = terrad_prediction_heights(d->pred);
            for (size_t c = 0; c < cells; c++)
                if (mine[c] < d->mirror->heights[c]) {
                    early_seq = (int)seq;
                    early_acked = (int)terrad_client_get_stats(a)->ack_seq;
                    break;
                }
        }
        if (i == n)
            CHECK(wait_ack(a, NULL, seq), "the last batch is acknowledged");
        next += 1.0 / d->hz;
        pump_until(a, NULL, next);
    }
    const terrad_prediction_stats *s = terrad_prediction_get_stats(d->pred);
    printf("drove %d ticks: %llu predicted, %llu reconciled, %llu compared (%llu exact), %llu on "
           "time, %llu not compared; rut first seen at batch %d with batch %d acknowledged\n",
           n, (unsigned long long)s->predicted, (unsigned long long)s->reconciled,
           (unsigned long long)s->replayed, (unsigned long long)s->exact,
           (unsigned long long)s->on_time, (unsigned long long)s->skipped, early_seq, early_acked);
    CHECK(early_seq > 0 && early_acked < early_seq,
          "the prediction shows the rut before the server's ACK of its batch");
    CHECK(s->replayed >= 10 && s->exact == s->replayed,
          "every compared ACK: the replay equals the server's heights (%llu of %llu exact, last "
          "differing %llu)",
          (unsigned long long)s->exact, (unsigned long long)s->replayed,
          (unsigned long long)s->last_differing);
    CHECK(s->pending == 0 &&
              memcmp(terrad_prediction_heights(d->pred), d->mirror->heights, cells * 4) == 0,
          "with nothing pending, the prediction is the server's state");
    int units = terrad_client_world(a)->units_per_m;
    int32_t deepest[OWN];
    for (int r = 0; r < OWN; r++) {
        const int32_t *row = terrad_prediction_heights(d->pred) + (size_t)(rows[r] - d->y) * d->w;
        int32_t lo = row[0];
        for (uint32_t c = 1; c < d->w; c++)
            lo = row[c] < lo ? row[c] : lo;
        deepest[r] = lo;
        CHECK(lo < (int32_t)(0.38 * units), "collider %d left a rut (%d units at the deepest)", r,
              lo);
    }
    CHECK(deepest[3] < deepest[1] - (int32_t)(0.02 * units),
          "the lugs dent deeper than the smooth wheel's rim (%d < %d)", deepest[3], deepest[1]);
}

/* B ploughs A's window: only the server knows its rut. */
static void drive_other(terrad_client *a, terrad_client *b, drive *d, uint32_t ball, int row_a,
                        double z)
{
    uint32_t ball_b = make(b, (terrad_collider_desc){.shape = TERRAD_SHAPE_SPHERE, .radius = 0.3});
    const terrad_prediction_stats *s = terrad_prediction_get_stats(d->pred);
    uint64_t replayed0 = s->replayed, exact0 = s->exact;
    int row_b = d->y + 80, n = 240;
    terrad_pose still = pose_at(d, ball, 599, 600, row_a, z + 5.0);
    double next = now_s();
    uint32_t seq = 0;
    for (int i = 0; i <= n; i++) {
        terrad_pose p = pose_at(d, ball_b, i < n ? i : n - 1, n, row_b, z + (i < n ? 0 : 5.0));
        CHECK(terrad_client_send_poses(b, &p, 1, &seq) == 0, "B's poses sent");
        if (i % 2 == 0) /* a still sphere of A's own, so that ACKs come to A */
            terrad_client_send_poses(a, &still, 1, NULL);
        next += 1.0 / d->hz;
        pump_until(a, b, next);
    }
    CHECK(wait_ack(b, a, seq), "B's last batch is acknowledged");
    terrad_client_send_poses(a, &still, 1, &seq);
    CHECK(wait_ack(a, b, seq), "an ACK with nothing pending after all of B's rut");
    CHECK(s->replayed - replayed0 > s->exact - exact0,
          "another client's rut makes the replay differ (%llu of %llu exact)",
          (unsigned long long)(s->exact - exact0), (unsigned long long)(s->replayed - replayed0));
    CHECK(d->resets > 0 && d->resets_bad == 0,
          "after every reconciliation the prediction is the server's (%d of %d not)", d->resets_bad,
          d->resets);
    CHECK(terrad_client_delete_collider(b, ball_b) == 0, "B's sphere deleted");
}

static int run_predict(int port, drive *d, const char *cfg, const char *out)
{
    terrad_client *a = open_client(port, NULL, "predict-a", on_frame, d);
    terrad_client *b = open_client(port, "", "predict-b", NULL, NULL);
    CHECK(a && b, "two clients connected");
    if (!a || !b)
        return check_report();
    d->cell = terrad_client_world(a)->cell_size_m;
    d->hz = terrad_client_world(a)->tick_hz;
    uint32_t sid = 0;
    CHECK(terrad_client_subscribe(a, d->x, d->y, d->w, d->h, &sid) == 0, "subscribed");
    CHECK(wait_complete(a, sid), "the snapshot came");
    d->mirror = terrad_client_mirror(a, sid);
    bad_input(a, sid, cfg);
    int rc = terrad_client_predict(a, sid, cfg, &d->pred);
    CHECK(rc == 0 && d->pred, "predict (%d: %s)", rc, terrad_client_last_error(a));
    if (!d->pred)
        return check_report();
    rc = terrad_client_predict(a, sid, cfg, &(terrad_prediction *){NULL});
    CHECK(rc == TERRAD_E_BAD_VALUE, "a second prediction of one subscription is refused (%s)",
          terrad_client_last_error(a));
    const terrad_collider_desc wheel = {.shape = TERRAD_SHAPE_WHEEL, .radius = 0.3, .width = 0.2};
    bad_lugs(a, d, wheel);
    uint32_t ids[OWN] = {
        make(a, (terrad_collider_desc){.shape = TERRAD_SHAPE_SPHERE, .radius = 0.3}),
        make(a, wheel),
        make(a, (terrad_collider_desc){.shape = TERRAD_SHAPE_CAPSULE,
                                       .radius = 0.12,
                                       .half_length = 0.25}),
        0};
    int rc_lugged = terrad_client_create_lugged_collider(a, wheel, LUGS, 0.0, &ids[3]);
    CHECK(rc_lugged == 0, "a lugged wheel created (%d: %s)", rc_lugged,
          terrad_client_last_error(a));
    int rows[OWN] = {d->y + 20, d->y + 40, d->y + 60, d->y + 50};
    double z = 0.4 + 0.3 - 0.06;
    drive_own(a, d, ids, rows, z);
    drive_other(a, b, d, ids[0], rows[0], z);
    for (int i = 0; i < OWN; i++)
        CHECK(terrad_client_delete_collider(a, ids[i]) == 0, "A's collider %d deleted", i);
    uint32_t seq = 0;
    terrad_client_send_poses(a, NULL, 0, &seq); /* an ACK after the deletions */
    CHECK(wait_ack(a, b, seq), "an ACK after the deletions");
    const terrad_prediction_stats *s = terrad_prediction_get_stats(d->pred);
    size_t cells = (size_t)d->w * d->h;
    CHECK(s->pending == 0 &&
              memcmp(terrad_prediction_heights(d->pred), d->mirror->heights, cells * 4) == 0,
          "the prediction equals the mirror at the end");
    CHECK(write_heights(out, d->mirror->heights, cells) == 0, "the mirror written to %s", out);
    CHECK(terrad_client_get_stats(a)->errors == 0, "no errors reached A (%s)",
          terrad_client_last_error(a));
    terrad_prediction_stop(d->pred);
    terrad_client_close(a);
    terrad_client_close(b);
    return check_report();
}

/* ---- loaded ---------------------------------------------------------------- */

/* The load-driven wheel from x0 to x1 in n batches, one a tick, turning faster
 * than it travels (slip 0.2), until the last is acknowledged; *lowest: the
 * lowest height the server found (FORCES). */
static void roll(terrad_client *a, drive *d, uint32_t wheel, double x0, double x1, int n, double z,
                 double radius, double *lowest)
{
    double next = now_s();
    uint32_t seq = 0;
    for (int i = 0; i < n; i++) {
        double x = x0 + (x1 - x0) * i / (n - 1), angle = (x - x0) / (radius * (1 - 0.2));
        terrad_pose p = {wheel,
                         (float)x,
                         (float)((d->y + d->h / 2.0) * d->cell),
                         (float)z,
                         (float)cos(angle / 2),
                         0,
                         (float)sin(angle / 2),
                         0};
        CHECK(terrad_client_send_poses(a, &p, 1, &seq) == 0, "poses sent");
        double found = 0;
        if (terrad_client_force_height(a, wheel, &found) == 1 && found < *lowest)
            *lowest = found;
        next += 1.0 / d->hz;
        pump_until(a, NULL, next);
    }
    CHECK(wait_ack(a, NULL, seq), "the last batch is acknowledged");
}

/* Back over the last third with the next restore of the soil state failing:
 * counted with the twin's sentence, and the client goes on. */
static void restore_fails(terrad_client *a, drive *d, uint32_t wheel, double x0, double x1,
                          double z, double radius)
{
    const terrad_prediction_stats *s = terrad_prediction_get_stats(d->pred);
    uint64_t reconciled0 = s->reconciled, replayed0 = s->replayed, exact0 = s->exact;
    int resets0 = d->resets;
    double lowest = z;
    terrad_twin_fault_restores(1); /* this process's next restore: the next ACK's */
    roll(a, d, wheel, x1, x1 - (x1 - x0) / 3, 100, z, radius, &lowest);
    terrad_twin_fault_restores(0);
    printf("restore failed: %llu errors (%s); then %llu reconciled, %llu compared (%llu exact)\n",
           (unsigned long long)s->errors, terrad_prediction_last_error(d->pred),
           (unsigned long long)(s->reconciled - reconciled0),
           (unsigned long long)(s->replayed - replayed0), (unsigned long long)(s->exact - exact0));
    CHECK(s->errors == 1 && strstr(terrad_prediction_last_error(d->pred), "soil state"),
          "the failed restore is counted with the twin's sentence (%llu: %s)",
          (unsigned long long)s->errors, terrad_prediction_last_error(d->pred));
    CHECK(s->reconciled - reconciled0 >= 10 && s->replayed - replayed0 >= 10,
          "the ACKs after it are taken and compared (%llu, %llu)",
          (unsigned long long)(s->reconciled - reconciled0),
          (unsigned long long)(s->replayed - replayed0));
    CHECK(s->pending == 0 && d->resets > resets0 + 10 && d->resets_bad == 0,
          "with nothing pending, the prediction is the server's state at every ACK after it (%d "
          "of %d not)",
          d->resets_bad, d->resets - resets0);
}

static int run_loaded(int port, drive *d, const char *cfg)
{
    terrad_client *a = open_client(port, NULL, "predict-loaded", on_frame, d);
    CHECK(a != NULL, "connected");
    if (!a)
        return check_report();
    d->cell = terrad_client_world(a)->cell_size_m;
    d->hz = terrad_client_world(a)->tick_hz;
    uint32_t sid = 0, wheel = 0;
    CHECK(terrad_client_subscribe(a, d->x, d->y, d->w, d->h, &sid) == 0, "subscribed");
    CHECK(wait_complete(a, sid), "the snapshot came");
    d->mirror = terrad_client_mirror(a, sid);
    int rc = terrad_client_predict(a, sid, cfg, &d->pred);
    CHECK(rc == 0 && d->pred, "predict (%d: %s)", rc, terrad_client_last_error(a));
    if (!d->pred)
        return check_report();
    const double radius = 0.1, z = 0.4 + radius; /* the search starts there, once */
    rc = terrad_client_create_loaded_collider(
        a, (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL, .radius = radius, .width = 0.08},
        40.0, &wheel);
    CHECK(rc == 0, "a load-driven wheel created (%d: %s)", rc, terrad_client_last_error(a));
    const int n = 300;
    double x0 = (d->x + 16) * d->cell, x1 = (d->x + (int)d->w - 16) * d->cell, lowest = z;
    roll(a, d, wheel, x0, x1, n, z, radius, &lowest);
    const terrad_prediction_stats *s = terrad_prediction_get_stats(d->pred);
    printf("load-driven: %llu predicted, %llu compared (%llu exact), %llu on time, %llu not "
           "compared; lowest found height %.6f m\n",
           (unsigned long long)s->predicted, (unsigned long long)s->replayed,
           (unsigned long long)s->exact, (unsigned long long)s->on_time,
           (unsigned long long)s->skipped, lowest);
    CHECK(lowest < z - 0.005, "the server found the wheel's height below the posed %.3f m (%.6f)",
          z, lowest);
    CHECK(s->replayed >= 10 && s->exact == s->replayed,
          "load-driven wheel: every compared ACK's replay equals the server's heights (%llu of "
          "%llu exact, last differing %llu)",
          (unsigned long long)s->exact, (unsigned long long)s->replayed,
          (unsigned long long)s->last_differing);
    /* judged at each ACK (on_frame), not after: a load-driven wheel at rest may go on
     * settling for a few ticks, and the frames of those ticks can be read in the same poll
     * as the last ACK, moving the mirror past the tick the prediction stands at */
    CHECK(s->pending == 0 && d->resets > 0 && d->resets_bad == 0,
          "with nothing pending, the prediction is the server's state at every ACK (%d of %d "
          "not)",
          d->resets_bad, d->resets);
    CHECK(s->errors == 0 && !*terrad_prediction_last_error(d->pred), "no prediction errors (%s)",
          terrad_prediction_last_error(d->pred));
    restore_fails(a, d, wheel, x0, x1, z, radius);
    CHECK(terrad_client_get_stats(a)->errors == 0, "no errors reached the client (%s)",
          terrad_client_last_error(a));
    terrad_prediction_stop(d->pred);
    terrad_client_close(a);
    return check_report();
}

/* ---- world ----------------------------------------------------------------- */

static int run_world(int port, const char *name, uint32_t w, uint32_t h, const char *out)
{
    char err[256], longname[80];
    terrad_client_desc desc = {.port = port, .name = "world-c", .timeout_ms = (int)(WAIT_S * 1000)};
    terrad_client *c = terrad_client_connect_world(desc, "no-such-world", err, sizeof err);
    CHECK(!c && strstr(err, "world"), "an unknown world is refused naming it (%s)", err);
    memset(longname, 'w', 65);
    longname[65] = 0;
    c = terrad_client_connect_world(desc, longname, err, sizeof err);
    CHECK(!c && strstr(err, "world"), "a 65-byte name is refused naming world (%s)", err);
    c = open_client(port, name, "world-c", NULL, NULL);
    CHECK(c != NULL, "connected into world %s", name);
    if (!c)
        return check_report();
    const terrad_world_info *wi = terrad_client_world(c);
    CHECK(strcmp(terrad_client_world_name(c), name) == 0, "the world message names %s (%s)", name,
          terrad_client_world_name(c));
    CHECK((uint32_t)wi->width == w && (uint32_t)wi->height == h, "the world is %ux%u (%dx%d)", w, h,
          wi->width, wi->height);
    uint32_t sid = 0, ball = 0;
    CHECK(terrad_client_subscribe(c, 0, 0, w, h, &sid) == 0, "subscribed");
    CHECK(wait_complete(c, sid), "the snapshot came");
    const terrad_mirror *m = terrad_client_mirror(c, sid);
    int32_t before = m->heights[(h / 2) * w + w / 2];
    CHECK(terrad_client_create_collider(
              c, (terrad_collider_desc){.shape = TERRAD_SHAPE_SPHERE, .radius = 0.3}, &ball) == 0,
          "a sphere in world %s", name);
    double cell = wi->cell_size_m;
    terrad_pose p = {
        ball, (float)(w / 2 * cell), (float)(h / 2 * cell), 0.5f + 0.3f - 0.06f, 1, 0, 0, 0};
    uint32_t seq = 0;
    for (int i = 0; i < 5; i++) {
        terrad_client_send_poses(c, &p, 1, &seq);
        terrad_client_poll(c, 20);
    }
    CHECK(wait_ack(c, NULL, seq), "the sphere's batches are acknowledged");
    CHECK(terrad_client_delete_collider(c, ball) == 0, "the sphere deleted");
    terrad_client_send_poses(c, NULL, 0, &seq);
    CHECK(wait_ack(c, NULL, seq), "an ACK after the deletion");
    CHECK(m->heights[(h / 2) * w + w / 2] < before, "the sphere pressed world %s (%d -> %d)", name,
          before, m->heights[(h / 2) * w + w / 2]);
    CHECK(write_heights(out, m->heights, (size_t)w * h) == 0, "the mirror written to %s", out);
    terrad_client_close(c);
    return check_report();
}

int main(int argc, char **argv)
{
    setvbuf(stdout, NULL, _IOLBF, 0);
    if (argc == 9 && strcmp(argv[1], "predict") == 0) {
        drive d = {.x = atoi(argv[3]),
                   .y = atoi(argv[4]),
                   .w = (uint32_t)atoi(argv[5]),
                   .h = (uint32_t)atoi(argv[6])};
        return run_predict(atoi(argv[2]), &d, argv[7], argv[8]);
    }
    if (argc == 8 && strcmp(argv[1], "loaded") == 0) {
        drive d = {.x = atoi(argv[3]),
                   .y = atoi(argv[4]),
                   .w = (uint32_t)atoi(argv[5]),
                   .h = (uint32_t)atoi(argv[6])};
        return run_loaded(atoi(argv[2]), &d, argv[7]);
    }
    if (argc == 7 && strcmp(argv[1], "world") == 0)
        return run_world(atoi(argv[2]), argv[3], (uint32_t)atoi(argv[4]), (uint32_t)atoi(argv[5]),
                         argv[6]);
    fprintf(stderr, "usage: c_predict_drive predict PORT X Y W H CONFIG OUT\n"
                    "       c_predict_drive world PORT NAME W H OUT\n"
                    "       c_predict_drive loaded PORT X Y W H CONFIG\n");
    return 2;
}
