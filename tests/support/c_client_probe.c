/*
 * c_client_probe: one round trip of the C client library (clients/c/terrad_client.h)
 * against a running daemon, for the Python tests that start the daemon
 * (test_tls.py: over wss:// with a self-signed certificate; test_auth_roles.py
 * could use it for roles). Not a test itself.
 *
 *   c_client_probe HOST PORT CA_FILE|- TOKEN|- [viewer]
 *
 * Connects (TLS with CA_FILE unless it is "-"), says hello with TOKEN,
 * subscribes to 0,0,32,32 and waits for the whole snapshot, then creates a
 * sphere collider and deletes it; with "viewer" the create must be refused
 * with `forbidden` instead. Prints one line per step; exits 0 when all went
 * as expected, 1 otherwise (the line says which step).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "terrad_client.h"
#include "terrad_proto.h"

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int fail(terrad_client *c, const char *step)
{
    printf("FAIL %s: %s\n", step, c ? terrad_client_last_error(c) : "");
    if (c)
        terrad_client_close(c);
    return 1;
}

int main(int argc, char **argv)
{
    if (argc < 5) {
        fprintf(stderr, "usage: c_client_probe HOST PORT CA_FILE|- TOKEN|- [viewer]\n");
        return 2;
    }
    const char *ca = strcmp(argv[3], "-") == 0 ? NULL : argv[3];
    const char *token = strcmp(argv[4], "-") == 0 ? "" : argv[4];
    int viewer = argc > 5 && strcmp(argv[5], "viewer") == 0;
    char err[512] = "";
    terrad_client *c = terrad_client_connect((terrad_client_desc){.host = argv[1],
                                                                  .port = atoi(argv[2]),
                                                                  .token = token,
                                                                  .name = "c_client_probe",
                                                                  .timeout_ms = 20000,
                                                                  .tls = ca != NULL,
                                                                  .tls_ca_file = ca},
                                             err, sizeof err);
    if (!c) {
        printf("FAIL connect: %s\n", err);
        return 1;
    }
    printf("connected: world %dx%d\n", terrad_client_world(c)->width,
           terrad_client_world(c)->height);
    uint32_t sid = 0;
    if (terrad_client_subscribe(c, 0, 0, 32, 32, &sid) != 0)
        return fail(c, "subscribe");
    double deadline = now_s() + 60;
    while (!terrad_client_mirror_complete(c, sid) && now_s() < deadline)
        if (terrad_client_poll(c, 200) < 0)
            return fail(c, "poll");
    if (!terrad_client_mirror_complete(c, sid))
        return fail(c, "snapshot");
    printf("subscribed: snapshot complete\n");
    uint32_t id = 0;
    int rc = terrad_client_create_collider(
        c, (terrad_collider_desc){.shape = TERRAD_SHAPE_SPHERE, .radius = 0.5}, &id);
    if (viewer) {
        if (rc != TERRAD_E_FORBIDDEN)
            return fail(c, "viewer create (expected forbidden)");
        printf("create refused: %s\n", terrad_client_last_error(c));
    } else {
        if (rc != 0)
            return fail(c, "create");
        if (terrad_client_delete_collider(c, id) != 0)
            return fail(c, "delete");
        printf("collider %u created and deleted\n", id);
        /* a load-driven collider in a world without soil: refused, naming load_n */
        rc = terrad_client_create_loaded_collider(
            c, (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL, .radius = 0.3, .width = 0.2},
            80.0, &id);
        if (rc == 0 || !strstr(terrad_client_last_error(c), "load_n"))
            return fail(
                c, "loaded collider on a world without soil (expected a refusal naming load_n)");
        printf("loaded collider refused: %s\n", terrad_client_last_error(c));
        /* a lugged wheel: created and deleted; lugs taller than the rim: refused naming them */
        terrad_collider_desc wheel = {.shape = TERRAD_SHAPE_WHEEL, .radius = 0.3, .width = 0.2};
        if (terrad_client_create_lugged_collider(c, wheel, (terrad_grousers){12, 0.02, 0.01}, 0.0,
                                                 &id) != 0 ||
            terrad_client_delete_collider(c, id) != 0)
            return fail(c, "lugged wheel create and delete");
        rc = terrad_client_create_lugged_collider(c, wheel, (terrad_grousers){12, 0.5, 0.01}, 0.0,
                                                  &id);
        if (rc == 0 || !strstr(terrad_client_last_error(c), "grousers.height"))
            return fail(c, "lugs taller than the rim (expected a refusal naming grousers.height)");
        printf("lugged wheel %u created and deleted; %s\n", id, terrad_client_last_error(c));
    }
    terrad_client_close(c);
    printf("ok\n");
    return 0;
}
