/*
 * c_client_probe: one round trip of the C client library (clients/c/terrad_client.h)
 * against a running daemon, for the Python tests that start the daemon
 * (test_tls.py: over wss:// with a self-signed certificate; test_auth_roles.py
 * could use it for roles). Not a test itself.
 *
 *   c_client_probe HOST PORT CA_FILE|- TOKEN|- [viewer]
 *   c_client_probe HOST PORT CA_FILE|- TOKEN|- desync X Y W H OUT
 *
 * Connects (TLS with CA_FILE unless it is "-"), says hello with TOKEN,
 * subscribes to 0,0,32,32 and waits for the whole snapshot, then creates a
 * sphere collider and deletes it; with "viewer" the create must be refused
 * with `forbidden` instead. Prints one line per step; exits 0 when all went
 * as expected, 1 otherwise (the line says which step).
 *
 * desync (PROTOCOL.md "CHECKSUM"; test_desync_c.py): subscribes to X Y W H,
 * waits for the snapshot and a CHECKSUM frame that finds nothing, then
 * corrupts one height of its mirror on purpose (the buffer, behind the
 * library's back) and polls until the library has found the tile differing,
 * asked for it and holds it again, with two more CHECKSUM frames finding
 * nothing; prints the counters and the seconds from corruption to repair
 * and writes the mirror (int32 little-endian, row-major) to OUT.
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

static int poll_until(terrad_client *c, double deadline, int (*done)(terrad_client *, void *),
                      void *arg)
{
    while (!done(c, arg) && now_s() < deadline)
        if (terrad_client_poll(c, 100) < 0)
            return -1;
    return done(c, arg) ? 0 : -1;
}

static int complete(terrad_client *c, void *arg)
{
    return terrad_client_mirror_complete(c, *(uint32_t *)arg);
}

/* at least the frames counted in arg[0] and the mirror held whole (arg[1]: sid) */
static int checksums_after(terrad_client *c, void *arg)
{
    const uint64_t *a = arg;
    return terrad_client_get_stats(c)->checksum_frames >= a[0] &&
           terrad_client_mirror_complete(c, (uint32_t)a[1]);
}

static int desync(terrad_client *c, char **argv)
{
    int32_t x = atoi(argv[0]), y = atoi(argv[1]);
    uint32_t w = (uint32_t)atoi(argv[2]), h = (uint32_t)atoi(argv[3]), sid = 0;
    const terrad_client_stats *st = terrad_client_get_stats(c);
    if (terrad_client_subscribe(c, x, y, w, h, &sid) != 0)
        return fail(c, "subscribe");
    if (poll_until(c, now_s() + 60, complete, &sid) != 0)
        return fail(c, "snapshot");
    uint64_t want[2] = {st->checksum_frames + 2, sid};
    if (poll_until(c, now_s() + 60, checksums_after, want) != 0)
        return fail(c, "two CHECKSUM frames");
    if (st->tiles_differing != 0)
        return fail(c, "a fresh mirror differs from the server's");
    printf("checksums: %llu frames, 0 tiles differ\n", (unsigned long long)st->checksum_frames);
    /* one height, in the middle of the window, off by 7 units: behind the library's back */
    const terrad_mirror *m = terrad_client_mirror(c, sid);
    m->heights[(size_t)(h / 2) * w + w / 2] += 7;
    double t0 = now_s();
    want[0] = st->checksum_frames + 1;
    if (poll_until(c, now_s() + 60, checksums_after, want) != 0 || st->tiles_differing != 1 ||
        st->tiles_resynced != 1)
        return fail(c, "the corrupted tile found and asked for");
    printf("corrupted tile found: %llu differing, %llu asked for\n",
           (unsigned long long)st->tiles_differing, (unsigned long long)st->tiles_resynced);
    if (poll_until(c, now_s() + 60, complete, &sid) != 0)
        return fail(c, "the tile's snapshot");
    double repaired = now_s() - t0;
    want[0] = st->checksum_frames + 2;
    if (poll_until(c, now_s() + 60, checksums_after, want) != 0 || st->tiles_differing != 1)
        return fail(c, "two CHECKSUM frames finding nothing after the repair");
    printf("repaired in %.3f s; checksums: %llu frames, %llu tiles differed, %llu asked for\n",
           repaired, (unsigned long long)st->checksum_frames,
           (unsigned long long)st->tiles_differing, (unsigned long long)st->tiles_resynced);
    FILE *f = fopen(argv[4], "wb");
    if (!f || fwrite(m->heights, sizeof *m->heights, (size_t)w * h, f) != (size_t)w * h) {
        if (f)
            fclose(f);
        return fail(c, "write the mirror");
    }
    fclose(f);
    terrad_client_close(c);
    printf("ok\n");
    return 0;
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
    if (argc > 5 && strcmp(argv[5], "desync") == 0 && argc < 11) {
        fprintf(stderr, "usage: c_client_probe HOST PORT CA_FILE|- TOKEN|- desync X Y W H OUT\n");
        return 2;
    }
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
    if (argc > 5 && strcmp(argv[5], "desync") == 0)
        return desync(c, argv + 6);
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
