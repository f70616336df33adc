/*
 * test_net_control.c: the JSON control-message parser (server/net/
 * net_control_internal.h) on its own, as a pure function — which error a message
 * gets (code, wording, whether it is the message or a field that is
 * refused, whether it is fatal), in the protocol's order of fields, and what
 * an accepted request carries (the frame turn of z-axis shapes included).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "net/net_control_internal.h"
#include "terrad_proto.h"
#include "check.h"

static net_limits limits;
static cJSON *materials;

static int parse(const char *text, net_control *m, net_control_error *e)
{
    net_control_context ctx = {.limits = &limits,
                               .materials = materials,
                               .world_width = 512,
                               .world_height = 256,
                               .tile_size = 64};
    return net_control_parse(text, strlen(text), &ctx, m, e);
}

/* The message is refused with this code and message. */
static void expect_error(const char *text, int code, int field, const char *message)
{
    net_control m;
    net_control_error e;
    int rc = parse(text, &m, &e);
    CHECK(rc == -1 && e.code == code && e.field == field, "%s: rc %d code %d field %d", text, rc,
          e.code, e.field);
    CHECK(strcmp(e.message, message) == 0, "%s: message \"%s\", wanted \"%s\"", text, e.message,
          message);
    CHECK(e.fatal == (code == TERRAD_E_BAD_VERSION), "%s: fatal %d", text, e.fatal);
    net_control_free(&m);
}

static void test_envelope(void)
{
    expect_error("{\"type\":", TERRAD_E_BAD_JSON, 0, "malformed JSON");
    expect_error("[1]", TERRAD_E_BAD_JSON, 0, "not a JSON object with a string \"type\"");
    expect_error("{\"type\": 3}", TERRAD_E_BAD_JSON, 0, "not a JSON object with a string \"type\"");
    expect_error("{\"type\":\"nope\",\"ref\":[1]}", TERRAD_E_BAD_VALUE, 0,
                 "ref: must be a string of at most 64 bytes or an integer");
    expect_error("{\"type\":\"nope\"}", TERRAD_E_UNKNOWN_TYPE, 0,
                 "type: \"nope\" is not a request");

    /* the kind is known as soon as the type is read (net_requests.c checks
     * hello-first with it), and a valid ref comes back for the reply */
    net_control m;
    net_control_error e;
    CHECK(parse("{\"type\":\"subscribe\",\"ref\":\"r1\",\"x\":1.5}", &m, &e) == -1, "bad x");
    CHECK(m.kind == NET_CONTROL_SUBSCRIBE && e.field == 1, "kind %d field %d", m.kind, e.field);
    CHECK(cJSON_IsString(m.ref) && strcmp(m.ref->valuestring, "r1") == 0, "ref kept");
    net_control_free(&m);
}

static void test_hello(void)
{
    char text[128], message[128];
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d}", TERRAD_PROTO_VERSION + 1);
    snprintf(message, sizeof message, "protocol: this server speaks version %d only (got %d)",
             TERRAD_PROTO_VERSION, TERRAD_PROTO_VERSION + 1);
    expect_error(text, TERRAD_E_BAD_VERSION, 1, message);
    expect_error("{\"type\":\"hello\"}", TERRAD_E_BAD_VALUE, 1,
                 "protocol: missing, an integer in [-2147483648, 2147483647]");
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"client\":7}",
             TERRAD_PROTO_VERSION);
    expect_error(text, TERRAD_E_BAD_VALUE, 1, "client: must be a string of at most 64 bytes");

    net_control m;
    net_control_error e;
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"client\":\"me\",\"ref\":7}",
             TERRAD_PROTO_VERSION);
    CHECK(parse(text, &m, &e) == 0 && e.code == 0, "hello accepted: %s", e.message);
    CHECK(m.kind == NET_CONTROL_HELLO && strcmp(m.client, "me") == 0 && !m.has_token,
          "hello fields");
    CHECK(cJSON_IsNumber(m.ref) && m.ref->valuedouble == 7, "integer ref");
    CHECK(m.budget == -1, "no budget stated: -1 (%lld)", (long long)m.budget);
    net_control_free(&m);
}

/* PROTOCOL.md "Budgets": hello's budget within max_budget_bytes_per_s, and focus */
static void test_budget(void)
{
    char text[160];
    net_control m;
    net_control_error e;
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"budget\":10000}",
             TERRAD_PROTO_VERSION);
    CHECK(parse(text, &m, &e) == 0 && m.budget == 10000, "budget 10000 taken: %s", e.message);
    net_control_free(&m);
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"budget\":100}",
             TERRAD_PROTO_VERSION);
    expect_error(text, TERRAD_E_BAD_VALUE, 1,
                 "budget: 100 bytes/s is under the smallest budget, 1024 (0: none)");
    limits.max_budget_bytes_per_s = 65536;
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"budget\":70000}",
             TERRAD_PROTO_VERSION);
    expect_error(text, TERRAD_E_BAD_VALUE, 1,
                 "budget: 70000 bytes/s is over this server's max_budget_bytes_per_s (65536)");
    snprintf(text, sizeof text, "{\"type\":\"hello\",\"protocol\":%d,\"budget\":0}",
             TERRAD_PROTO_VERSION);
    expect_error(text, TERRAD_E_BAD_VALUE, 1,
                 "budget: 0 bytes/s is over this server's max_budget_bytes_per_s (65536) (0 "
                 "asks for none)");
    limits.max_budget_bytes_per_s = 0;
    CHECK(parse("{\"type\":\"focus\",\"x\":10.5,\"y\":20}", &m, &e) == 0 && m.has_focus &&
              m.focus_x == 10.5 && m.focus_y == 20,
          "focus taken: %s", e.message);
    net_control_free(&m);
    CHECK(parse("{\"type\":\"focus\"}", &m, &e) == 0 && !m.has_focus, "focus cleared");
    net_control_free(&m);
    expect_error("{\"type\":\"focus\",\"x\":10,\"y\":300}", TERRAD_E_BAD_VALUE, 1,
                 "y: must be a number of cells in [0, 256] (x and y both, or neither to clear "
                 "the focus)");
}

static void test_collider_create(void)
{
    /* the protocol's order: shape before material before the dimensions */
    expect_error("{\"type\":\"collider_create\",\"material\":\"mud\"}", TERRAD_E_BAD_VALUE, 1,
                 "shape: missing, a string (sphere, box, capsule, cylinder, wheel or mesh)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"sphere\",\"material\":\"mud\"}",
                 TERRAD_E_UNSUPPORTED_COLLIDER, 1,
                 "material: \"mud\" is not one of world.materials");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"sphere\",\"radius\":51}",
                 TERRAD_E_BAD_VALUE, 1,
                 "radius: must be a number of metres > 0 and <= 50 (max_collider_extent_m)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"cone\"}", TERRAD_E_UNSUPPORTED_COLLIDER,
                 1, "shape: \"cone\" is not one of sphere, box, capsule, cylinder, wheel, mesh");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"sphere\",\"radius\":1,"
                 "\"pose\":{\"p\":[0,0,0],\"q\":[2,0,0,0]}}",
                 TERRAD_E_BAD_VALUE, 1, "pose.q: must be a unit quaternion (|q| within 0.9..1.1)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"mesh\",\"vertices\":[0,0,0],"
                 "\"indices\":[0,0,0]}",
                 TERRAD_E_BAD_VALUE, 1,
                 "mesh: needs at least 3 vertices and 1 triangle (got 1 and 1)");

    /* grousers: a wheel's, an object of three sizes, no taller than the rim's radius */
    expect_error("{\"type\":\"collider_create\",\"shape\":\"wheel\",\"radius\":0.15,"
                 "\"width\":0.16,\"grousers\":{\"count\":30,\"height\":0.2,\"thickness\":0.004}}",
                 TERRAD_E_BAD_VALUE, 1,
                 "grousers.height: must be a finite number > 0 and <= the radius 0.15 m (got 0.2)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"wheel\",\"radius\":0.15,"
                 "\"width\":0.16,\"grousers\":{\"count\":2.5,\"height\":0.01,\"thickness\":0.004}}",
                 TERRAD_E_BAD_VALUE, 1, "grousers.count: must be an integer in [1, 360] (got 2.5)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"wheel\",\"radius\":0.15,"
                 "\"width\":0.16,\"grousers\":{\"count\":30,\"height\":0.01,\"lugs\":1}}",
                 TERRAD_E_BAD_VALUE, 1,
                 "grousers.lugs: unknown key for grousers (count, height, thickness)");
    expect_error("{\"type\":\"collider_create\",\"shape\":\"sphere\",\"radius\":0.15,"
                 "\"grousers\":{\"count\":30,\"height\":0.01,\"thickness\":0.004}}",
                 TERRAD_E_BAD_VALUE, 1,
                 "grousers: only a wheel carries grousers (shape \"wheel\", its axle the "
                 "collider's y axis)");
    net_control m;
    net_control_error e;
    CHECK(parse("{\"type\":\"collider_create\",\"shape\":\"wheel\",\"radius\":0.15735,"
                "\"width\":0.165,\"grousers\":{\"count\":30,\"height\":0.01,\"thickness\":0.004}}",
                &m, &e) == 0,
          "lugged wheel accepted: %s", e.message);
    CHECK(m.geometry.shape == COLLIDER_CYLINDER && m.geometry.grousers.count == 30 &&
              m.geometry.grousers.height == 0.01 && m.geometry.grousers.thickness == 0.004,
          "lugged wheel's grousers read");
    net_control_free(&m);
    CHECK(parse("{\"type\":\"collider_create\",\"shape\":\"capsule\",\"radius\":0.5,"
                "\"half_length\":1,\"material\":\"sand\",\"feedback\":false,"
                "\"pose\":{\"p\":[1,2,3],\"q\":[1,0,0,0]}}",
                &m, &e) == 0,
          "capsule accepted: %s", e.message);
    CHECK(m.geometry.shape == COLLIDER_CAPSULE && m.axis_z && !m.feedback &&
              strcmp(m.material, "sand") == 0,
          "capsule fields");
    /* the client's z axis becomes the module's y: a quarter turn about x */
    CHECK(fabs(m.pose.orientation.w - sqrt(0.5)) < 1e-12 &&
              fabs(m.pose.orientation.x - sqrt(0.5)) < 1e-12 && m.pose.position.z == 3,
          "capsule pose turned: %g %g", m.pose.orientation.w, m.pose.orientation.x);
    net_control_free(&m);

    CHECK(parse("{\"type\":\"collider_create\",\"shape\":\"mesh\",\"vertices\":[0,0,0,1,0,0,0,1,0],"
                "\"indices\":[0,1,2]}",
                &m, &e) == 0,
          "mesh accepted: %s", e.message);
    CHECK(m.mesh && m.geometry.mesh == m.mesh && m.mesh->triangle_count == 1 && m.feedback &&
              strcmp(m.material, "default") == 0 && m.pose.orientation.w == 0,
          "mesh fields (no pose: all-zero orientation)");
    net_control_free(&m);
    CHECK(m.mesh == NULL, "free releases the mesh");
}

static void test_subscriptions(void)
{
    expect_error("{\"type\":\"subscribe\",\"x\":500,\"y\":0,\"w\":64,\"h\":64}",
                 TERRAD_E_OUTSIDE_WORLD, 1,
                 "rectangle x=500 y=0 w=64 h=64 is not inside the world (512 x 256 cells)");
    expect_error("{\"type\":\"subscribe\",\"x\":0,\"y\":0,\"w\":1,\"h\":1,\"colliders\":1}",
                 TERRAD_E_BAD_VALUE, 1, "colliders: must be true or false");
    expect_error("{\"type\":\"unsubscribe\"}", TERRAD_E_BAD_VALUE, 1,
                 "id: missing, an integer in [0, 4294967295]");

    net_control m;
    net_control_error e;
    CHECK(parse("{\"type\":\"subscribe\",\"x\":0,\"y\":192,\"w\":512,\"h\":64,\"footprints\":true}",
                &m, &e) == 0,
          "subscribe accepted: %s", e.message);
    CHECK(m.rect.y == 192 && m.rect.w == 512 && m.footprints && !m.colliders, "subscribe fields");
    net_control_free(&m);
    CHECK(parse("{\"type\":\"resync\"}", &m, &e) == 0 && !m.has_id && m.id == 0, "resync all");
    net_control_free(&m);
    CHECK(parse("{\"type\":\"resync\",\"id\":4}", &m, &e) == 0 && m.has_id && m.id == 4,
          "resync one");
    net_control_free(&m);
    /* resync's tiles lie inside the world (8 x 4 tiles of 64 cells here): a
     * hostile coordinate is refused at parse time, before net_desync.c
     * multiplies it by the tile size (INT32_MAX * 64 overflowed an int) */
    CHECK(parse("{\"type\":\"resync\",\"id\":4,\"tiles\":[[7,3],[0,0]]}", &m, &e) == 0 &&
              m.tile_count == 2 && m.tiles[0] == 7 && m.tiles[1] == 3,
          "resync tiles at the world's far corner: %s", e.message);
    net_control_free(&m);
    expect_error("{\"type\":\"resync\",\"id\":1,\"tiles\":[[2147483647,0]]}",
                 TERRAD_E_OUTSIDE_WORLD, 1,
                 "tiles[0]: tile (2147483647, 0) is outside the world (8 x 4 tiles of 64 cells)");
    expect_error("{\"type\":\"resync\",\"id\":1,\"tiles\":[[0,0],[0,4]]}", TERRAD_E_OUTSIDE_WORLD,
                 1, "tiles[1]: tile (0, 4) is outside the world (8 x 4 tiles of 64 cells)");
    expect_error("{\"type\":\"resync\",\"id\":1,\"tiles\":[[8,0]]}", TERRAD_E_OUTSIDE_WORLD, 1,
                 "tiles[0]: tile (8, 0) is outside the world (8 x 4 tiles of 64 cells)");
    expect_error("{\"type\":\"resync\",\"id\":1,\"tiles\":[[0,9007199254740992]]}",
                 TERRAD_E_OUTSIDE_WORLD, 1,
                 "tiles[0]: tile (0, 9007199254740992) is outside the world (8 x 4 tiles of 64 "
                 "cells)");
    /* seen (issue 28, item 5): the latest tick the client has handled */
    CHECK(parse("{\"type\":\"seen\",\"tick\":9007199254740992}", &m, &e) == 0 &&
              m.kind == NET_CONTROL_SEEN && m.seen_tick == 9007199254740992ull,
          "seen: %s", e.message);
    net_control_free(&m);
    expect_error("{\"type\":\"seen\"}", TERRAD_E_BAD_VALUE, 1,
                 "tick: missing, an integer in [0, 9007199254740992]");
    static const char *const bad[] = {"-1", "1.5", "\"7\"", "9007199254740993e3"};
    for (int i = 0; i < 4; i++) {
        char text[96];
        snprintf(text, sizeof text, "{\"type\":\"seen\",\"tick\":%s}", bad[i]);
        expect_error(text, TERRAD_E_BAD_VALUE, 1,
                     "tick: must be an integer in [0, 9007199254740992]");
    }
}

/* spectate, spectate_step, spectate_stop (PROTOCOL.md "Spectate"): each field by name */
static void test_spectate(void)
{
    expect_error("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":64,\"h\":64}", TERRAD_E_BAD_VALUE, 1,
                 "from_tick: missing, an integer in [0, 9007199254740992]");
    expect_error("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":64,\"h\":64,\"from_tick\":-1}",
                 TERRAD_E_BAD_VALUE, 1, "from_tick: must be an integer in [0, 9007199254740992]");
    expect_error("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":64,\"h\":64,\"from_tick\":5,"
                 "\"speed\":9}",
                 TERRAD_E_BAD_VALUE, 1, "speed: must be an integer in [1, 8]");
    expect_error("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":64,\"h\":64,\"from_tick\":5,"
                 "\"speed\":1.5}",
                 TERRAD_E_BAD_VALUE, 1, "speed: must be an integer in [1, 8]");
    expect_error("{\"type\":\"spectate\",\"x\":500,\"y\":0,\"w\":64,\"h\":64,\"from_tick\":5}",
                 TERRAD_E_OUTSIDE_WORLD, 1,
                 "rectangle x=500 y=0 w=64 h=64 is not inside the world (512 x 256 cells)");
    expect_error("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":64,\"h\":64,\"from_tick\":5,"
                 "\"step\":1}",
                 TERRAD_E_BAD_VALUE, 1, "step: must be true or false");
    expect_error("{\"type\":\"spectate_step\",\"ticks\":0}", TERRAD_E_BAD_VALUE, 1,
                 "ticks: must be an integer in [1, 600]");
    net_control m;
    net_control_error e;
    CHECK(parse("{\"type\":\"spectate\",\"x\":64,\"y\":0,\"w\":128,\"h\":64,\"from_tick\":"
                "1200,\"speed\":8}",
                &m, &e) == 0,
          "spectate accepted: %s", e.message);
    CHECK(m.kind == NET_CONTROL_SPECTATE && m.rect.x == 64 && m.rect.w == 128 &&
              m.from_tick == 1200 && m.speed == 8 && !m.stepping,
          "spectate fields");
    net_control_free(&m);
    CHECK(parse("{\"type\":\"spectate\",\"x\":0,\"y\":0,\"w\":1,\"h\":1,\"from_tick\":0,"
                "\"step\":true}",
                &m, &e) == 0 &&
              m.speed == 1 && m.stepping && m.from_tick == 0,
          "a stepping spectate from tick 0, speed 1 by default: %s", e.message);
    net_control_free(&m);
    CHECK(parse("{\"type\":\"spectate_step\",\"ticks\":600}", &m, &e) == 0 &&
              m.kind == NET_CONTROL_SPECTATE_STEP && m.step_ticks == 600,
          "spectate_step: %s", e.message);
    net_control_free(&m);
    CHECK(parse("{\"type\":\"spectate_stop\",\"ref\":7}", &m, &e) == 0 &&
              m.kind == NET_CONTROL_SPECTATE_STOP,
          "spectate_stop: %s", e.message);
    net_control_free(&m);
}

int main(void)
{
    limits = net_limits_default();
    materials = cJSON_Parse("[\"default\", \"sand\"]");
    test_envelope();
    test_hello();
    test_budget();
    test_collider_create();
    test_subscriptions();
    test_spectate();
    cJSON_Delete(materials);
    return check_report();
}
