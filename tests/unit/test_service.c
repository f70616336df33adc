/*
 * test_service.c: the sim side of the daemon without the network. Commands
 * and poses go into a hub as the websocket thread would put them; ticks run
 * on the CPU backend; the frames that come out are decoded and applied to
 * client mirrors, which must then hold exactly the world's heights. Also:
 * tile versions step by one, Σh is tracked exactly, contacts and acks come
 * in order, deletes and departures remove colliders, height reads work.
 * On a decals world: FOOTPRINTS frames go only to clients that asked, with
 * the events inside their regions, one shared frame for the same events.
 */
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "hub/hub.h"
#include "service/service.h"
#include "terrad_proto.h"
#include "check.h"

typedef struct client_view {
    terrad_mirror mirror;
    int32_t *heights;
    uint32_t *versions;
    int acks, contacts, snapshot_marks, stale;
    int64_t last_contact_volume;
    uint64_t last_tick;
} client_view;

static terrad_codec *codec;
static int32_t scratch[SERVICE_TILE_SIZE * SERVICE_TILE_SIZE];

static void view_init(client_view *v, world_rect r)
{
    memset(v, 0, sizeof *v);
    v->heights = calloc((size_t)r.w * r.h, sizeof *v->heights);
    size_t tiles =
        terrad_mirror_tile_count(r.x, r.y, (uint32_t)r.w, (uint32_t)r.h, SERVICE_TILE_SIZE);
    v->versions = calloc(tiles, sizeof *v->versions);
    terrad_mirror_init(&v->mirror, r.x, r.y, (uint32_t)r.w, (uint32_t)r.h, SERVICE_TILE_SIZE,
                       v->heights, v->versions);
}

static void view_apply(client_view *v, const hub_frame *f)
{
    terrad_header hd;
    if (terrad_header_decode(f->data, f->len, &hd) != 0)
        return;
    if (hd.type == TERRAD_MSG_DELTA) {
        terrad_rect rects[256];
        size_t n = 0;
        uint64_t tick;
        int rc = terrad_delta_decode(f->data, f->len, &tick, rects, 256, &n);
        CHECK(rc == 0, "delta decodes (%d)", rc);
        CHECK(tick >= v->last_tick, "ticks in order");
        v->last_tick = tick;
        rc = terrad_mirror_apply(&v->mirror, codec, rects, n, scratch,
                                 SERVICE_TILE_SIZE * SERVICE_TILE_SIZE);
        if (rc != 0)
            v->stale++;
    } else if (hd.type == TERRAD_MSG_ACK) {
        uint64_t tick;
        uint32_t seq;
        CHECK(terrad_ack_decode(f->data, f->len, &tick, &seq) == 0, "ack decodes");
        v->acks++;
    } else if (hd.type == TERRAD_MSG_CONTACT) {
        terrad_contact c[8];
        size_t n = 0;
        uint64_t tick;
        CHECK(terrad_contact_decode(f->data, f->len, &tick, c, 8, &n) == 0, "contact decodes");
        if (n > 0)
            v->last_contact_volume = c[0].volume;
        v->contacts++;
    }
}

/* Deliver the published frames: client frames to their client, tile deltas
 * to every view whose region meets the tile. */
static void deliver(hub *h, client_view *views, const world_rect *regions, int count)
{
    hub_out out[4096];
    int n;
    while ((n = hub_take_outbound(h, out, 4096)) > 0) {
        for (int i = 0; i < n; i++) {
            if (out[i].kind == HUB_OUT_CLIENT) {
                int c = (int)out[i].client - 1;
                if (c >= 0 && c < count) {
                    view_apply(&views[c], out[i].frame);
                    views[c].snapshot_marks += out[i].snapshot_done;
                }
            } else if (out[i].kind == HUB_OUT_TILE_DELTA) {
                world_rect tile = {out[i].tile_x * SERVICE_TILE_SIZE,
                                   out[i].tile_y * SERVICE_TILE_SIZE, SERVICE_TILE_SIZE,
                                   SERVICE_TILE_SIZE};
                for (int c = 0; c < count; c++)
                    if (world_rects_overlap(tile, regions[c]))
                        view_apply(&views[c], out[i].frame);
            }
            if (out[i].frame)
                hub_frame_unref(out[i].frame);
        }
    }
}

static int view_matches(const client_view *v, const world *w, world_rect r)
{
    int32_t *expect = malloc((size_t)r.w * r.h * sizeof *expect);
    world_gather_window(w, r, expect);
    int same = memcmp(expect, v->heights, (size_t)r.w * r.h * sizeof *expect) == 0;
    free(expect);
    return same;
}

typedef struct reader_args {
    hub *h;
    world_rect r;
    int32_t *out;
    uint64_t tick;
    int rc;
} reader_args;

static void *reader(void *p)
{
    reader_args *a = p;
    a->rc = hub_read_heights(a->h, a->r, a->out, &a->tick, 5000);
    return NULL;
}

/* The FOOTPRINTS frames of one tick, by client (1..4), checked and counted. */
typedef struct footprint_view {
    int frames, events;
    terrad_footprint last;
    const hub_frame *frame; /* this tick's frame */
} footprint_view;

static void take_footprints(hub *h, footprint_view *v, int count)
{
    hub_out out[4096];
    int n;
    while ((n = hub_take_outbound(h, out, 4096)) > 0) {
        for (int i = 0; i < n; i++) {
            const hub_frame *f = out[i].frame;
            int c = (int)out[i].client;
            if (out[i].kind == HUB_OUT_CLIENT && f && f->len > 2 &&
                f->data[2] == TERRAD_MSG_FOOTPRINTS && c >= 1 && c <= count) {
                terrad_footprint e[8];
                size_t k = 0;
                uint64_t tick;
                CHECK(terrad_footprints_decode(f->data, f->len, &tick, e, 8, &k) == 0 && k > 0,
                      "client %d: a FOOTPRINTS frame with events decodes", c);
                v[c - 1].frames++;
                v[c - 1].events += (int)k;
                v[c - 1].last = e[k - 1];
                v[c - 1].frame = f;
            }
            if (out[i].frame)
                hub_frame_unref(out[i].frame);
        }
    }
}

static void test_footprints(void)
{
    error_text err;
    world w;
    world_base_spec base = {.kind = WORLD_BASE_FLAT, .height_m = 0.5};
    CHECK(world_init(&w, 300, 200, 0.05, 10000, 0, &err) == 0, "decals world");
    CHECK(world_generate_base(&w, &base, &err) == 0, "decals base");
    sim_material m = sim_material_default();
    m.model = SIM_MODEL_DECALS;
    sim_params p;
    CHECK(sim_params_from_material(&m, w.cell_size_m, w.units_per_m, w.floor, &p, &err) == 0,
          "decals params: %s", err.message);
    sim_backend *cpu = sim_backend_cpu_create(&err);
    sim_engine *engine = sim_engine_create(&w, &p, cpu, 4, &err);
    hub *h = hub_create();
    service *svc = service_create(engine, h, &err);
    int64_t start_volume = world_volume(&w);

    /* 1: left half with footprints; 2: the same without; 3: right half with;
     * 4: the left half with, like 1 (gets the very same frame) */
    world_rect left = {0, 0, 150, 200}, right = {150, 0, 150, 200};
    const world_rect rects[4] = {left, left, right, left};
    const int wants[4] = {1, 0, 1, 1};
    for (int c = 0; c < 4; c++) {
        hub_command cmd = {.kind = HUB_CLIENT_JOINED, .client = (uint32_t)c + 1};
        hub_push_command(h, &cmd);
        cmd = (hub_command){.kind = HUB_SUBSCRIBE,
                            .client = (uint32_t)c + 1,
                            .subscription = 1,
                            .rect = rects[c],
                            .footprints = wants[c]};
        hub_push_command(h, &cmd);
    }
    /* client 1's sphere pressed 5 cm in at (2, 5) m, cell (40, 100): the left half */
    hub_command cmd = {.kind = HUB_COLLIDER_CREATE,
                       .client = 1,
                       .collider = 7,
                       .geometry = {.shape = COLLIDER_SPHERE, .radius = 0.3}};
    cmd.pose = (collider_pose){{2.0, 5.0, 0.75}, {1, 0, 0, 0}};
    hub_push_command(h, &cmd);
    footprint_view v[4];
    memset(v, 0, sizeof v);
    service_tick_stats st;
    for (int t = 0; t < 5; t++) {
        CHECK(service_tick(svc, NULL, 0, &st, &err) == 0, "decals tick %d: %s", t, err.message);
        take_footprints(h, v, 4);
    }
    CHECK(v[0].frames == 5 && v[0].events == 5, "client 1: one event a tick (%d frames, %d)",
          v[0].frames, v[0].events);
    CHECK(v[0].last.collider == 7 && fabsf(v[0].last.x - 2.0f) < 0.1f &&
              fabsf(v[0].last.y - 5.0f) < 0.1f && fabsf(v[0].last.strength_m - 0.05f) < 0.005f &&
              v[0].last.size_m > 0.1f,
          "client 1: the event is the sphere's (%u at %.3f, %.3f, strength %.4f, size %.3f)",
          v[0].last.collider, v[0].last.x, v[0].last.y, v[0].last.strength_m, v[0].last.size_m);
    CHECK(v[1].frames == 0, "client 2 did not ask: no frame (%d)", v[1].frames);
    CHECK(v[2].frames == 0, "client 3's region is elsewhere: no frame (%d)", v[2].frames);
    CHECK(v[3].frames == 5 && v[3].frame == v[0].frame, "client 4 shares client 1's frame");

    /* a demo actor in the right half: client 3 gets it, clients 1 and 4 do not */
    collider_geometry box = {.shape = COLLIDER_BOX, .half_extents = {0.4, 0.3, 0.2}};
    sim_collider demo = {
        .id = (int)0x40000001, .geometry = &box, .pose = {{11.0, 5.0, 0.68}, {1, 0, 0, 0}}};
    demo.previous_pose = demo.pose;
    memset(v, 0, sizeof v);
    CHECK(service_tick(svc, &demo, 1, &st, &err) == 0, "decals tick with a demo actor");
    take_footprints(h, v, 4);
    CHECK(v[2].frames == 1 && v[2].events == 1 && v[2].last.collider == 0x40000001u &&
              fabsf(v[2].last.x - 11.0f) < 0.1f,
          "client 3: the demo box's event (%d events, %u at %.3f)", v[2].events, v[2].last.collider,
          v[2].last.x);
    CHECK(v[0].events == 1 && v[3].events == 1, "clients 1 and 4: only the sphere's (%d, %d)",
          v[0].events, v[3].events);

    /* lifted: no event, no frame */
    hub_pose up = {
        .collider = 7, .client = 1, .sequence = 1, .pose = {{2.0, 5.0, 2.0}, {1, 0, 0, 0}}};
    hub_set_pose(h, &up);
    memset(v, 0, sizeof v);
    CHECK(service_tick(svc, NULL, 0, &st, &err) == 0, "decals tick, lifted");
    take_footprints(h, v, 4);
    CHECK(v[0].frames == 0 && v[3].frames == 0, "lifted: no FOOTPRINTS (%d)", v[0].frames);
    CHECK(world_volume(&w) == start_volume, "decals: the heights never change");

    service_destroy(svc);
    hub_destroy(h);
    sim_engine_destroy(engine);
    cpu->destroy(cpu);
    world_free(&w);
}

/* A POSE_BATCH reaches the tick whole: its poses and its sequence are taken
 * together (hub_set_batch, hub_take_input), so the tick's ACK names the batch
 * whose poses it used; a later batch waits, whole, for the next take. */
static void test_batch_whole(void)
{
    hub *h = hub_create();
    CHECK(h != NULL, "hub");
    hub_pose poses[3];
    for (int i = 0; i < 3; i++)
        poses[i] = (hub_pose){.collider = (uint32_t)i + 1,
                              .client = 9,
                              .sequence = 5,
                              .pose = {{1.0 + i, 2.0, 0.5}, {1, 0, 0, 0}}};
    CHECK(hub_set_batch(h, 9, 5, poses, 3) == 3, "a batch of 3 poses stored");
    hub_pose got[8];
    hub_batch *batches = calloc(HUB_BATCH_CAPACITY, sizeof *batches);
    CHECK(batches != NULL, "batches");
    int n_poses = -1;
    int n = hub_take_input(h, got, 8, &n_poses, batches);
    CHECK(n == 1 && batches[0].client == 9 && batches[0].sequence == 5 && n_poses == 3,
          "taken together: %d poses, %d batches (sequence %u)", n_poses, n,
          n ? batches[0].sequence : 0);
    poses[0].sequence = 6;
    poses[0].pose.position.x = 7.0;
    CHECK(hub_set_batch(h, 9, 6, poses, 1) == 1, "the next batch");
    CHECK(hub_set_batch(h, 9, 7, NULL, 0) == 0, "an empty batch after it");
    n = hub_take_input(h, got, 8, &n_poses, batches);
    CHECK(n == 1 && batches[0].sequence == 7 && n_poses == 1 && got[0].pose.position.x == 7.0,
          "the latest sequence with the latest poses (%d, %u, %d)", n, n ? batches[0].sequence : 0,
          n_poses);
    n = hub_take_input(h, got, 8, &n_poses, batches);
    CHECK(n == 0 && n_poses == 0, "nothing left (%d, %d)", n, n_poses);
    free(batches);
    hub_destroy(h);
}

int main(void)
{
    test_batch_whole();
    error_text err;
    world w;
    world_base_spec base = {.kind = WORLD_BASE_FLAT, .height_m = 0.5};
    CHECK(world_init(&w, 300, 200, 0.05, 10000, 0, &err) == 0, "world");
    CHECK(world_generate_base(&w, &base, &err) == 0, "base");
    sim_material m = sim_material_default();
    sim_params p;
    sim_params_from_material(&m, w.cell_size_m, w.units_per_m, w.floor, &p, &err);
    sim_backend *cpu = sim_backend_cpu_create(&err);
    sim_engine *engine = sim_engine_create(&w, &p, cpu, 4, &err);
    hub *h = hub_create();
    service *svc = service_create(engine, h, &err);
    codec = terrad_codec_new(3);
    CHECK(svc != NULL, "service");
    int64_t start_volume = world_volume(&w);

    /* two clients, overlapping regions, one wheel each */
    world_rect regions[2] = {{0, 40, 200, 100}, {100, 60, 200, 100}};
    client_view views[2];
    for (int c = 0; c < 2; c++) {
        view_init(&views[c], regions[c]);
        hub_command cmd = {.kind = HUB_CLIENT_JOINED, .client = (uint32_t)c + 1};
        hub_push_command(h, &cmd);
        cmd = (hub_command){
            .kind = HUB_COLLIDER_CREATE,
            .client = (uint32_t)c + 1,
            .collider = (uint32_t)c + 1,
            .feedback = 1,
            .geometry = {.shape = COLLIDER_CYLINDER, .radius = 0.3, .half_length = 0.1}};
        cmd.pose = (collider_pose){{2.0 + 5.0 * c, 5.0, 0.75}, {1, 0, 0, 0}};
        hub_push_command(h, &cmd);
        cmd = (hub_command){.kind = HUB_SUBSCRIBE,
                            .client = (uint32_t)c + 1,
                            .subscription = 1,
                            .rect = regions[c]};
        hub_push_command(h, &cmd);
    }
    service_tick_stats st;
    for (int t = 0; t < 240; t++) {
        for (int c = 0; c < 2; c++) {
            /* the wheels sink 5 cm and drive along x; client 2 crosses client 1's path */
            double x = 2.0 + 5.0 * c + 0.02 * t, y = 5.0 + (c ? 0.01 * t : 0.0);
            hub_pose pose = {.collider = (uint32_t)c + 1,
                             .client = (uint32_t)c + 1,
                             .sequence = (uint32_t)t,
                             .pose = {{x, y, 0.75}, {1, 0, 0, 0}}};
            CHECK(hub_set_pose(h, &pose) == 0, "pose accepted");
            hub_note_batch(h, (uint32_t)c + 1, (uint32_t)t);
        }
        CHECK(service_tick(svc, NULL, 0, &st, &err) == 0, "tick %d: %s", t, err.message);
        deliver(h, views, regions, 2);
        CHECK(service_volume(svc) == world_volume(&w), "tracked volume exact at tick %d", t);
    }
    CHECK(world_volume(&w) == start_volume, "volume preserved: %lld -> %lld",
          (long long)start_volume, (long long)world_volume(&w));
    for (int c = 0; c < 2; c++) {
        CHECK(views[c].snapshot_marks == 1, "client %d got one snapshot mark", c + 1);
        CHECK(views[c].stale == 0, "client %d never went stale", c + 1);
        CHECK(view_matches(&views[c], &w, regions[c]), "client %d mirror == world", c + 1);
        CHECK(views[c].acks == 240, "client %d: an ack per tick with poses (%d)", c + 1,
              views[c].acks);
        CHECK(views[c].contacts == 240, "client %d: contact per tick (%d)", c + 1,
              views[c].contacts);
    }
    int changed = 0;
    for (int ty = 0; ty < 4; ty++)
        for (int tx = 0; tx < 5; tx++)
            changed |= service_tile_version(svc, tx, ty) > 1;
    CHECK(changed, "tile versions advanced");

    /* a wheel held still, pressing in: contact feedback shows its volume */
    hub_pose deep = {
        .collider = 1, .client = 1, .sequence = 999, .pose = {{12.0, 7.5, 0.70}, {1, 0, 0, 0}}};
    hub_set_pose(h, &deep);
    service_tick(svc, NULL, 0, &st, &err);
    deliver(h, views, regions, 2);
    CHECK(views[0].last_contact_volume > 0, "penetrating volume reported (%lld)",
          (long long)views[0].last_contact_volume);

    /* resync of client 2 gives a fresh snapshot that still matches: its cells
     * are copied in the tick that takes the request and framed off the tick,
     * so its frames go out at the start of the next one (service_snapshots.c) */
    hub_command resync = {.kind = HUB_RESYNC, .client = 2, .subscription = 0};
    hub_push_command(h, &resync);
    service_tick(svc, NULL, 0, &st, &err);
    deliver(h, views, regions, 2);
    CHECK(views[1].snapshot_marks == 1, "the resync's frames are not out within its own tick");
    service_tick(svc, NULL, 0, &st, &err);
    deliver(h, views, regions, 2);
    CHECK(views[1].snapshot_marks == 2, "resync marked done");
    CHECK(view_matches(&views[1], &w, regions[1]), "after resync mirror == world");

    /* client 1 leaves: its collider goes */
    hub_command left = {.kind = HUB_CLIENT_LEFT, .client = 1};
    hub_push_command(h, &left);
    service_tick(svc, NULL, 0, &st, &err);
    deliver(h, views, regions, 2);
    CHECK(st.colliders == 1 && st.clients == 1, "departure removed the client's collider (%d, %d)",
          st.colliders, st.clients);

    /* a height read from another thread is served between ticks */
    reader_args ra = {.h = h, .r = {100, 60, 50, 40}};
    ra.out = malloc(50 * 40 * sizeof *ra.out);
    pthread_t th;
    pthread_create(&th, NULL, reader, &ra);
    for (int t = 0; t < 50; t++) {
        service_tick(svc, NULL, 0, &st, &err);
        deliver(h, views, regions, 2);
        struct timespec ts = {0, 2000000};
        nanosleep(&ts, NULL);
    }
    pthread_join(th, NULL);
    int32_t *expect = malloc(50 * 40 * sizeof *expect);
    world_gather_window(&w, ra.r, expect);
    CHECK(ra.rc == 0 && memcmp(expect, ra.out, 50 * 40 * sizeof *expect) == 0,
          "height read equals the world (rc %d)", ra.rc);
    free(expect);
    free(ra.out);

    service_destroy(svc);
    hub_destroy(h);
    sim_engine_destroy(engine);
    cpu->destroy(cpu);
    world_free(&w);
    terrad_codec_free(codec);
    test_footprints();
    for (int c = 0; c < 2; c++) {
        free(views[c].heights);
        free(views[c].versions);
    }
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
