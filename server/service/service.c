/*
 * service.c: one tick of the daemon on the sim thread (see service.h), and
 * the service's life cycle. service_tick is the tick's table of contents
 * (docs/design.md); each step lives in the file named in service_internal.h.
 *
 * Tile versions are the protocol's unit of consistency: the world is cut into
 * SERVICE_TILE_SIZE² tiles, each with a u32 version that advances by one in
 * every tick that changes it. A tick's changes are cut along tile edges; the
 * pieces of one tile (a tile may meet several windows) are combined into
 * one rectangle, its differences encoded once (zigzag + zstd) and published
 * once for the network thread to fan out to every subscriber. Σh is kept
 * incrementally from the same differences, so no tick scans the world.
 *
 * Nothing the tick meant to send is dropped silently: a frame, snapshot,
 * command or pose set it cannot handle is counted in
 * terrad_service_dropped_total{reason} and logged (at most once a second).
 */
#include "service/service_internal.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"

service *service_create(sim_engine *engine, hub *h, error_text *err)
{
    service *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "service: out of memory");
        return NULL;
    }
    /* the sim thread creates the service and ticks it */
    thread_owner_claim(&s->owner, "sim");
    hub_claim_sim_end(h);
    s->engine = engine;
    s->world = sim_engine_world(engine);
    s->hub = h;
    s->tiles_x = (s->world->width + SERVICE_TILE_SIZE - 1) / SERVICE_TILE_SIZE;
    s->tiles_y = (s->world->height + SERVICE_TILE_SIZE - 1) / SERVICE_TILE_SIZE;
    s->tile_versions = malloc((size_t)s->tiles_x * s->tiles_y * sizeof *s->tile_versions);
    s->batch.commands = malloc(SERVICE_COMMANDS_PER_TICK * sizeof *s->batch.commands);
    s->batch.batches = malloc(HUB_BATCH_CAPACITY * sizeof *s->batch.batches);
    s->values = malloc(SERVICE_TILE_SIZE * SERVICE_TILE_SIZE * sizeof *s->values);
    s->packed_cap = terrad_rect_compress_bound(SERVICE_TILE_SIZE * SERVICE_TILE_SIZE);
    s->packed = malloc(s->packed_cap);
    /* zstd level 1 for the tick's deltas: on the deltas of loadgen's
     * wheels, thesis-car's and the spheres' (docs/performance.md, issue 32)
     * it takes 10-20 % less CPU than level 3 and its frames are 1.5-3.4 %
     * smaller; any zstd decoder reads either. Snapshots keep level 3. */
    s->codec = terrad_codec_new(1);
    if (!s->tile_versions || !s->batch.commands || !s->batch.batches || !s->values || !s->packed ||
        !s->codec || service_snapshots_start(s) != 0) {
        service_destroy(s);
        error_set(err, "service: out of memory for %d tiles", s->tiles_x * s->tiles_y);
        return NULL;
    }
    for (int i = 0; i < s->tiles_x * s->tiles_y; i++)
        s->tile_versions[i] = 1;
    s->volume = world_volume(s->world);
    return s;
}

void service_destroy(service *s)
{
    if (!s)
        return;
    service_batch *b = &s->batch;
    service_snapshots_stop(s);
    for (int i = 0; i < s->collider_count; i++)
        service_release_collider(s, &s->colliders[i]);
    for (int i = 0; i < s->client_count; i++)
        free(s->clients[i].subs);
    for (int i = 0; i < b->out_count; i++)
        if (b->out[i].frame)
            hub_frame_unref(b->out[i].frame);
    terrad_codec_free(s->codec);
    free(s->tile_versions);
    free(s->clients);
    free(s->colliders);
    free(b->commands);
    free(b->batches);
    free(b->poses);
    free(b->colliders);
    free(b->snapshots);
    free(b->pieces);
    free(b->out);
    free(b->contacts);
    free(s->values);
    free(s->packed);
    free(s->bottom);
    free(s->states);
    free(s->lugs);
    free(s->events);
    free(s->sums);
    service_edits_free(s);
    hub_step_free(&s->step.step);
    free(s);
}

void service_claim(service *s)
{
    thread_owner_claim(&s->owner, "sim");
    hub_claim_sim_end(s->hub);
    sim_engine_claim(s->engine);
    if (s->store)
        store_claim(s->store);
}

void service_attach_store(service *s, store *st, uint64_t recovered_tick)
{
    s->store = st;
    s->tick = recovered_tick;
    hub_publish_tick(s->hub, recovered_tick);
    s->volume = world_volume(s->world);
}

uint64_t service_current_tick(const service *s)
{
    return s->tick;
}

int64_t service_volume(const service *s)
{
    return s->volume;
}

uint32_t service_tile_version(const service *s, int tile_x, int tile_y)
{
    return s->tile_versions[tile_y * s->tiles_x + tile_x];
}

/* ---- the tick ---- */

/* The store could not log this tick: put every window back as it was, so
 * nothing that is not durable is ever seen. */
static void undo_tick(service *s, sim_tick_report *report)
{
    for (int i = 0; i < report->window_count; i++) {
        const int32_t *before, *after;
        world_rect win = sim_engine_window(s->engine, i, &before, &after);
        world_scatter_window(s->world, win, before);
    }
    sim_engine_undo_state(s->engine);
    report->dirty_count = 0;
    report->state_dirty_count = 0;
}

static void tell_store_state(service *s)
{
    const char *why = store_failure(s->store);
    int down = why[0] != 0;
    if (down != s->store_down)
        hub_set_store_unavailable(s->hub, down ? why : NULL);
    s->store_down = down;
}

/* The colliders the engine deforms with: every posed client collider, then
 * the daemon's own. */
static int gather_colliders(service *s, const sim_collider *extra, int extra_count, int *count,
                            error_text *err)
{
    service_batch *b = &s->batch;
    if (array_grow((void **)&b->colliders, &b->collider_capacity,
                   (int64_t)s->collider_count + extra_count + 1, sizeof *b->colliders) != 0) {
        error_set(err, "service: out of memory for %d colliders", s->collider_count + extra_count);
        return -1;
    }
    int n = 0;
    service_shed(s); /* whose colliders wait this tick */
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (!c->has_pose || c->held)
            continue;
        b->colliders[n++] = sim_collider_for_tick((int)c->id, c->geometry, c->pose,
                                                  c->previous_pose, c->has_previous, c->load_n);
    }
    if (extra_count > 0)
        memcpy(b->colliders + n, extra, (size_t)extra_count * sizeof *extra);
    *count = n + extra_count;
    return 0;
}

/* Deform (the engine's tick) and log the change in the store; a change the
 * store cannot keep is undone, and none is made while it cannot write. */
static int deform_and_commit(service *s, int count, sim_tick_report *report, error_text *err)
{
    s->tick_logged = 0;
    if (s->store && !store_writable(s->store)) {
        memset(report, 0, sizeof *report); /* no deformation that cannot be kept */
        service_edits_undo(s, TERRAD_E_STORE_UNAVAILABLE, "storage unavailable");
    } else {
        if (sim_engine_tick(s->engine, s->batch.colliders, count, report, err) != 0) {
            service_edits_undo(s, TERRAD_E_INTERNAL, "the deformation backend failed");
            return -1;
        }
        const world_rect *rects;
        int n;
        if (s->store && (service_edits_commit_rects(s, report, &rects, &n) != 0 ||
                         store_commit_tick(s->store, s->world, s->tick, rects, n) != 0)) {
            undo_tick(s, report);
            service_edits_undo(s, TERRAD_E_STORE_UNAVAILABLE, "the log could not take the tick");
        } else {
            s->tick_logged = 1;
        }
    }
    for (int i = 0, k = 0; i < s->collider_count && report->contact_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (!c->has_pose || c->held)
            continue; /* as gather_colliders: the tick's colliders in its order */
        if (c->load_n > 0.0 && k < report->contact_count)
            c->pose.position.z = report->contacts[k].pose_z_m; /* where the soil carried it */
        k++;
    }
    for (int i = 0; i < s->collider_count; i++) {
        if (s->colliders[i].held)
            continue; /* it waited: the next tick sweeps from where it was */
        s->colliders[i].previous_pose = s->colliders[i].pose;
        s->colliders[i].has_previous = s->colliders[i].has_pose;
    }
    return 0;
}

int service_settle(service *s)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    if (b->out_count == 0) {
        service_edits_answer_held(s);
        return 1;
    }
    if (s->store && !store_settle(s->store))
        return 0;
    int dropped = hub_publish(s->hub, b->out, b->out_count);
    if (dropped)
        metrics_count_frames_dropped((uint64_t)dropped);
    b->out_count = 0;
    service_edits_answer_held(s); /* HTTP edits of the ticks now durable */
    return 1;
}

/* Hand the tick's frames to the network, once the store has made the tick
 * durable (earlier ticks' frames wait in the batch until then). */
static void publish(service *s)
{
    service_batch *b = &s->batch;
    service_queue_out(s, (hub_out){.kind = HUB_OUT_TICK_DONE, .tick = s->tick});
    /* from the oldest pose this tick used to its deltas being handed to the network */
    if (service_settle(s) && b->oldest_pose_ms > 0)
        metrics_observe_pose_to_delta_ms(time_now_ms() - b->oldest_pose_ms);
    if (s->store)
        tell_store_state(s);
}

int service_tick(service *s, const sim_collider *extra, int extra_count, service_tick_stats *stats,
                 error_text *err)
{
    THREAD_OWNED(&s->owner);
    double t0 = time_now_ms();
    memset(stats, 0, sizeof *stats);
    service_snapshots_collect(s); /* last tick's snapshots, framed meanwhile: ahead of this tick */
    s->tick++;

    service_take_input(s);           /* commands, poses, batch sequences from the hub */
    service_contacts_before_tick(s); /* contact feedback against the terrain before */
    int count = 0;
    if (gather_colliders(s, extra, extra_count, &count, err) != 0 ||
        deform_and_commit(s, count, &stats->report, err) != 0)
        return -1;

    if (service_cut_into_tiles(s, &stats->report) == 0) /* deltas: versions, Σh, frames */
        service_publish_deltas(s, stats);
    service_edits_finish(s); /* each websocket edit's sender: its tick and volume change */
    service_contacts_after_tick(s, &stats->report);
    service_publish_feedback(s, &stats->report); /* CONTACT, FORCES, ACK */
    service_publish_colliders(s, extra, extra_count);
    service_publish_footprints(s, &stats->report);
    service_publish_checksums(s); /* every checksum_interval ticks: tile hashes, last */
    service_publish_snapshots(s); /* new subscriptions and resyncs: cells copied */
    service_step_finish(s);       /* a client-clocked world: STEPPED after the step's last tick */

    /* The tick is published, in the hub and in its status first: nothing
     * names it outside the sim thread (a frame, a read's tick) before they do. */
    stats->clients = s->client_count;
    stats->colliders = s->collider_count + extra_count;
    stats->tick_ms = time_now_ms() - t0;
    if (stats->delta_raw_bytes)
        metrics_count_delta_bytes(stats->delta_raw_bytes, stats->delta_compressed_bytes);
    hub_publish_tick(s->hub, s->tick); /* the net thread's "is it in the future" */
    if (s->publisher)
        s->publisher(s->publisher_arg, stats);
    publish(s);
    service_snapshots_hand_over(s); /* framed while the sim thread waits for the next tick */
    service_edits_answer(s);        /* HTTP edits: their tick, published */
    hub_serve_reads(s->hub, s->world, s->tick);
    return 0;
}

void service_set_publisher(service *s, service_publish_fn fn, void *arg)
{
    s->publisher = fn;
    s->publisher_arg = arg;
}
