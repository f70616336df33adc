/*
 * test_twin_predict: the twin library's prediction (terrad_twin.h,
 * terrad_twin_prediction_*; server/twin/twin_predict.c) against a second twin
 * that plays the server tick by tick: one batch per tick is predicted on
 * time and every ACK's replay is exact; batches acknowledged together after a
 * gap are not compared; a resyncing mirror skips the comparison and the next
 * ACK resets; a pose goes through the server's arithmetic (float32,
 * collider_wire_orientation); a wheel with grousers is predicted as exactly
 * as the smooth shapes; on bekker a load-driven wheel (its height the one
 * the twin's search finds) stays exact, also after two batches acknowledged
 * together after a gap (the prediction finds the order the server took them
 * in: its soil state and found height stay the server's); a soil state that
 * cannot be restored (terrad_twin_fault_restores) is the ACK's -1 with its
 * sentence, and the ACKs after it are taken as before. Bad input is refused
 * with the field named and
 * the prediction goes on. The clients' own tests (test_predict_c,
 * test_predict_python, test_predict_js, ...) drive it against a real daemon.
 */
#include <math.h>
#include <string.h>

#include "check.h"
#include "collider/collider.h"
#include "twin/terrad_twin.h"

enum { X = 16, Y = 16, W = 32, H = 32, ID = 7 };

static terrad_twin_config *config(void)
{
    terrad_twin_config *c = terrad_twin_config_new();
    terrad_twin_config_set(c, "width", 64, NULL);
    terrad_twin_config_set(c, "height", 64, NULL);
    terrad_twin_config_set(c, "terrain.height_m", 0.4, NULL); /* soil above the floor to press */
    return c;
}

/* The server's tick: the pose as net_requests takes it from the wire. */
static void server_tick(terrad_twin *server, const double pose[7], int axis_z, int32_t *out)
{
    if (pose) {
        float f[7];
        for (int i = 0; i < 7; i++)
            f[i] = (float)pose[i];
        quatd q = collider_wire_orientation((quatd){f[3], f[4], f[5], f[6]}, axis_z);
        terrad_twin_set_pose(server, ID, f[0], f[1], f[2], q.w, q.x, q.y, q.z, NULL);
    }
    terrad_twin_tick(server, NULL);
    terrad_twin_read(server, X, Y, W, H, out, NULL);
}

static void pose_at(double pose[7], int k)
{
    /* 5 cm into the soil; the numbers are not float32's, the quaternion not a unit one */
    const double p[7] = {1.3 + 0.031 * k, 1.4, 0.61 - 0.001 * k, 0.9, 0.1, 0.3, 0.2};
    memcpy(pose, p, sizeof p);
}

/* A twin playing the server and a prediction of its window (heights: its
 * heights, W * H), both of config c, which is freed. */
static terrad_twin_prediction *open_pair(terrad_twin_config *c, terrad_twin **server,
                                         int32_t *heights, const char *what)
{
    *server = terrad_twin_create(c, X, Y, W, H, NULL, NULL);
    terrad_twin_read(*server, X, Y, W, H, heights, NULL);
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_prediction *p = terrad_twin_prediction_create(c, X, Y, W, H, heights, 0, err);
    terrad_twin_config_free(c);
    CHECK(p != NULL, "%s: created (%s)", what, err);
    return p;
}

static void test_drive(const char *shape, int axis_z)
{
    terrad_twin *server;
    static int32_t heights[W * H];
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_prediction *p = open_pair(config(), &server, heights, shape);
    if (strcmp(shape, "lugged") == 0) { /* the server's lugged rim (net_control's grousers) */
        terrad_twin_add_wheel(server, ID, 0.3, 0.1, 12, 0.05, 0.03, NULL);
        CHECK(terrad_twin_prediction_add_wheel(p, ID, 0.3, 0.1, 12, 0.05, 0.03, err) == 0,
              "%s: an own wheel with grousers (%s)", shape, err);
    } else {
        terrad_twin_add_collider(server, ID, strcmp(shape, "wheel") == 0 ? "cylinder" : shape, 0.3,
                                 0.1, 0, 0, 0, NULL);
        CHECK(terrad_twin_prediction_add_collider(p, ID, shape, 0.3, 0.1, 0, 0, 0, err) == 0,
              "%s: an own collider (%s)", shape, err);
    }
    const uint32_t id = ID;
    double pose[7];
    uint64_t tick = 100;
    for (int k = 1; k <= 12; k++) { /* one batch a tick */
        pose_at(pose, k);
        terrad_twin_prediction_sent(p, (uint32_t)k, &id, pose, 1, err);
        server_tick(server, pose, axis_z, heights);
        terrad_twin_prediction_acked(p, ++tick, (uint32_t)k, heights, err);
    }
    const terrad_twin_prediction_stats *s = terrad_twin_prediction_get_stats(p);
    CHECK(s->predicted == 12 && s->reconciled == 12 && s->replayed == 12 && s->exact == 12 &&
              s->on_time == 12 && s->pending == 0,
          "%s: one batch a tick: every ACK on time and exact (%llu of %llu exact, %llu on time)",
          shape, (unsigned long long)s->exact, (unsigned long long)s->replayed,
          (unsigned long long)s->on_time);
    CHECK(memcmp(terrad_twin_prediction_heights(p), heights, sizeof heights) == 0,
          "%s: the prediction is the server's heights", shape);
    int32_t lowest = heights[0];
    for (int i = 0; i < W * H; i++)
        lowest = heights[i] < lowest ? heights[i] : lowest;
    CHECK(lowest < 4000 - 100, "%s: the collider pressed a rut (lowest %d units)", shape, lowest);

    /* two batches, two ticks, one ACK (a slow client's ACKs coalesced): not compared */
    for (int k = 13; k <= 14; k++) {
        pose_at(pose, k);
        terrad_twin_prediction_sent(p, (uint32_t)k, &id, pose, 1, err);
        server_tick(server, pose, axis_z, heights);
    }
    uint32_t seqs[4];
    CHECK(terrad_twin_prediction_pending(p, seqs, 4) == 2 && seqs[0] == 13 && seqs[1] == 14,
          "%s: two batches pending, oldest first", shape);
    tick += 2;
    terrad_twin_prediction_acked(p, tick, 14, heights, err);
    CHECK(s->skipped == 1 && s->replayed == 12 && s->pending == 0,
          "%s: batches acknowledged together after a gap are not compared", shape);
    /* an idle tick (the poses stand still), then one batch: the replay covers both */
    server_tick(server, NULL, axis_z, heights);
    pose_at(pose, 15);
    terrad_twin_prediction_sent(p, 15, &id, pose, 1, err);
    server_tick(server, pose, axis_z, heights);
    tick += 2;
    terrad_twin_prediction_acked(p, tick, 15, heights, err);
    CHECK(s->replayed == 13 && s->exact == 13 && s->last_differing == 0,
          "%s: an idle tick replayed with the poses standing still (%llu cells differ)", shape,
          (unsigned long long)s->last_differing);
    /* a resyncing mirror: no comparison; the next ACK with heights resets */
    pose_at(pose, 16);
    terrad_twin_prediction_sent(p, 16, &id, pose, 1, err);
    server_tick(server, pose, axis_z, heights);
    terrad_twin_prediction_acked(p, ++tick, 16, NULL, err);
    CHECK(s->skipped == 2 && s->pending == 0, "%s: resyncing: skipped, forgotten", shape);
    server_tick(server, NULL, axis_z, heights);
    terrad_twin_prediction_acked(p, ++tick, 16, heights, err);
    CHECK(memcmp(terrad_twin_prediction_heights(p), heights, sizeof heights) == 0,
          "%s: the ACK after the resync resets to the server", shape);
    terrad_twin_prediction_destroy(p);
    terrad_twin_destroy(server);
}

/* open_pair on a bekker world, each with wheel ID (the server's cylinder,
 * the prediction's own wheel). */
static terrad_twin_prediction *open_bekker(terrad_twin **server, int32_t *heights, const char *what)
{
    terrad_twin_config *c = config();
    terrad_twin_config_set_name(c, "model", "bekker", NULL);
    terrad_twin_prediction *p = open_pair(c, server, heights, what);
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_add_collider(*server, ID, "cylinder", 0.3, 0.1, 0, 0, 0, NULL);
    CHECK(terrad_twin_prediction_add_collider(p, ID, "wheel", 0.3, 0.1, 0, 0, 0, err) == 0,
          "%s: an own wheel (%s)", what, err);
    return p;
}

/* bekker: a load-driven wheel predicted against a twin playing the server */
static void test_loaded(void)
{
    terrad_twin *server;
    static int32_t heights[W * H];
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_prediction *p = open_bekker(&server, heights, "loaded");
    terrad_twin_set_load(server, ID, 150.0, NULL);
    CHECK(terrad_twin_prediction_set_load(p, ID, 150.0, err) == 0,
          "loaded: an own load-driven wheel (%s)", err);
    CHECK(terrad_twin_prediction_set_load(p, ID, NAN, err) == -1 && strstr(err, "load_n"),
          "loaded: a NaN load names load_n (%s)", err);
    CHECK(terrad_twin_prediction_set_load(p, ID, -1, err) == -1 && strstr(err, "load_n"),
          "loaded: a negative load names load_n (%s)", err);
    CHECK(terrad_twin_prediction_set_load(p, ID + 1, 10, err) == -1 && strstr(err, "id"),
          "loaded: a collider it does not predict names the id (%s)", err);
    const uint32_t id = ID;
    double pose[7];
    uint64_t tick = 100;
    for (int k = 1; k <= 24; k++) {
        pose_at(pose, k);
        pose[2] = 0.9; /* high above: only the load decides the height */
        terrad_twin_prediction_sent(p, (uint32_t)k, &id, pose, 1, err);
        server_tick(server, pose, 0, heights);
        tick++;
        if (k != 13) /* 13's ACK replaced by 14's (a slow client's): acknowledged together */
            terrad_twin_prediction_acked(p, tick, (uint32_t)k, heights, err);
    }
    const terrad_twin_prediction_stats *s = terrad_twin_prediction_get_stats(p);
    CHECK(s->replayed == 22 && s->exact == 22 && s->skipped == 1,
          "loaded: every ACK compared is exact, before and after the coalesced one (%llu of %llu, "
          "%llu not compared, last differing %llu)",
          (unsigned long long)s->exact, (unsigned long long)s->replayed,
          (unsigned long long)s->skipped, (unsigned long long)s->last_differing);
    int32_t lowest = heights[0];
    for (int i = 0; i < W * H; i++)
        lowest = heights[i] < lowest ? heights[i] : lowest;
    CHECK(lowest < 4000 - 50, "loaded: the load sank the wheel from 0.9 m into a rut (%d units)",
          lowest);
    terrad_twin_prediction_destroy(p);
    terrad_twin_destroy(server);

    terrad_twin_config *c = config(); /* not bekker: no soil to carry a load */
    terrad_twin *t = terrad_twin_create(c, X, Y, W, H, NULL, NULL);
    terrad_twin_config_free(c);
    terrad_twin_add_collider(t, 1, "sphere", 0.3, 0, 0, 0, 0, NULL);
    CHECK(terrad_twin_set_load(t, 1, 10, err) == -1 && strstr(err, "load_n") &&
              strstr(err, "bekker"),
          "a load on a world without soil forces names load_n (%s)", err);
    CHECK(terrad_twin_set_load(t, 1, 0, err) == 0, "load 0: pose-driven, accepted (%s)", err);
    terrad_twin_destroy(t);
}

/* bekker: a soil state that cannot be restored (the test hook makes the
 * restore fail as out of memory does) is -1 with the sentence, after the ACK
 * was taken; the next ACK is taken, compared and reset as any other. */
static void test_restore_fails(void)
{
    terrad_twin *server;
    static int32_t heights[W * H];
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    terrad_twin_prediction *p = open_bekker(&server, heights, "restore");
    const terrad_twin_prediction_stats *s = terrad_twin_prediction_get_stats(p);
    const uint32_t id = ID;
    double pose[7];
    uint64_t tick = 100;
    int rc[8];
    for (int k = 1; k <= 8; k++) {
        pose_at(pose, k);
        terrad_twin_prediction_sent(p, (uint32_t)k, &id, pose, 1, err);
        server_tick(server, pose, 0, heights);
        terrad_twin_fault_restores(k == 4); /* the next restore fails: the replay's at ACK 4 */
        err[0] = 0;
        rc[k - 1] = terrad_twin_prediction_acked(p, ++tick, (uint32_t)k, heights, err);
        if (k == 4) {
            CHECK(rc[3] == -1 && strstr(err, "acked") && strstr(err, "soil state"),
                  "restore: the ACK whose restore failed is -1 naming the soil state (%d: %s)",
                  rc[3], err);
            CHECK(s->reconciled == 4 && s->replayed == 4 && s->pending == 0,
                  "restore: that ACK was taken all the same (%llu reconciled, %llu pending)",
                  (unsigned long long)s->reconciled, (unsigned long long)s->pending);
        }
    }
    terrad_twin_fault_restores(0);
    CHECK(rc[0] == 0 && rc[1] == 0 && rc[2] == 0 && rc[4] == 0 && rc[5] == 0 && rc[6] == 0 &&
              rc[7] == 0,
          "restore: every other ACK is 0");
    CHECK(s->reconciled == 8 && s->replayed == 8 && s->pending == 0,
          "restore: the ACKs after it are taken and compared (%llu reconciled, %llu compared, %llu "
          "exact)",
          (unsigned long long)s->reconciled, (unsigned long long)s->replayed,
          (unsigned long long)s->exact);
    CHECK(memcmp(terrad_twin_prediction_heights(p), heights, sizeof heights) == 0,
          "restore: with nothing pending, the prediction is the server's heights");
    terrad_twin_prediction_destroy(p);
    terrad_twin_destroy(server);
}

static void test_refusals(void)
{
    terrad_twin_config *c = config();
    static int32_t heights[W * H];
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    CHECK(!terrad_twin_prediction_create(c, X, Y, W, H, NULL, 0, err) && strstr(err, "heights"),
          "no heights: refused (%s)", err);
    CHECK(!terrad_twin_prediction_create(c, 60, Y, W, H, heights, 0, err) && strstr(err, "window"),
          "a window outside the world: refused (%s)", err);
    terrad_twin_prediction *p = terrad_twin_prediction_create(c, X, Y, W, H, heights, 0, err);
    terrad_twin_config_free(c);
    CHECK(terrad_twin_prediction_add_collider(p, 1, "cone", 0.3, 0, 0, 0, 0, err) == -1 &&
              strstr(err, "shape"),
          "an unknown shape names the field (%s)", err);
    CHECK(terrad_twin_prediction_add_collider(p, 1, "sphere", -1, 0, 0, 0, 0, err) == -1 &&
              strstr(err, "radius"),
          "a bad size names the field (%s)", err);
    CHECK(terrad_twin_prediction_add_collider(p, 1, "sphere", 0.3, 0, 0, 0, 0, err) == 0,
          "then a good one (%s)", err);
    CHECK(terrad_twin_prediction_add_collider(p, 1, "box", 0, 0, 1, 1, 1, err) == -1 &&
              strstr(err, "id"),
          "the same id twice names the id (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 2, 0.3, 0.1, -3, 0.05, 0.03, err) == -1 &&
              strstr(err, "grousers.count"),
          "a negative grouser count names the field (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 2, 0.3, 0.1, 12.5, 0.05, 0.03, err) == -1 &&
              strstr(err, "grousers.count"),
          "a fractional grouser count names the field (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 2, 0.3, 0.1, 12, 0.5, 0.03, err) == -1 &&
              strstr(err, "grousers.height"),
          "grousers taller than the radius name the field (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 2, 0.3, 0.1, 12, 0.05, -0.03, err) == -1 &&
              strstr(err, "grousers.thickness"),
          "a negative grouser thickness names the field (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 1, 0.3, 0.1, 12, 0.05, 0.03, err) == -1 &&
              strstr(err, "id"),
          "a wheel on an own collider's id names the id (%s)", err);
    CHECK(terrad_twin_prediction_add_wheel(p, 2, 0.3, 0.1, 12, 0.05, 0.03, err) == 0 &&
              terrad_twin_prediction_remove_collider(p, 2, err) == 0,
          "then a good lugged wheel (%s)", err);
    CHECK(terrad_twin_prediction_sent(p, 1, NULL, NULL, 2, err) == -1 && strstr(err, "poses"),
          "poses without their numbers are refused (%s)", err);
    CHECK(terrad_twin_prediction_get_stats(p)->predicted == 0, "a refused batch is not ticked");
    const uint32_t other = 99;
    const double pose[7] = {2, 2, 0.5, 1, 0, 0, 0};
    CHECK(terrad_twin_prediction_sent(p, 2, &other, pose, 1, err) == 0 &&
              memcmp(terrad_twin_prediction_heights(p), heights, sizeof heights) == 0,
          "another client's collider's pose is left out (%s)", err);
    CHECK(terrad_twin_prediction_remove_collider(p, 99, err) == 0 &&
              terrad_twin_prediction_remove_collider(p, 1, err) == 0,
          "removing a collider it does not hold, then its own (%s)", err);
    terrad_twin_prediction_destroy(p);
}

int main(void)
{
    test_drive("sphere", 0);
    test_drive("capsule", 1);
    test_drive("wheel", 0);
    test_drive("lugged", 0);
    test_loaded();
    test_restore_fails();
    test_refusals();
    return check_report();
}
