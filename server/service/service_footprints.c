/*
 * service_footprints.c: FOOTPRINTS frames (PROTOCOL.md "FOOTPRINTS") — the
 * decals model's events of this tick, for viewers that subscribed with
 * "footprints": true; cheap visuals, no resync when one is lost. Built after
 * the tick's deltas, per client, a frame shared among clients that would
 * get the same bytes. Sim thread only.
 */
#include "service/service_internal.h"

#include <math.h>
#include <string.h>

/* FOOTPRINTS: events per frame so that a frame stays within SERVICE_FRAME_MAX
 * (a tick with more is sent as several frames of the same tick). */
#define FOOTPRINTS_PER_FRAME ((SERVICE_FRAME_MAX - TERRAD_FOOTPRINTS_FIXED) / TERRAD_FOOTPRINT_SIZE)
/* Frames already built this tick that a client's frame is compared with, to
 * share one copy among clients with the same events (whole-world viewers). */
#define FOOTPRINTS_SHARED_MAX 8

/* Is the event's centre inside one of the client's footprint-subscriptions? */
static int footprint_in_view(const service *s, const svc_client *cl, const sim_footprint *e)
{
    double cs = s->world->cell_size_m;
    double cx = floor(e->x_m / cs), cy = floor(e->y_m / cs);
    for (int i = 0; i < cl->sub_count; i++) {
        const world_rect r = cl->subs[i].rect;
        if (cl->subs[i].footprints && cx >= r.x && cx < (double)r.x + r.w && cy >= r.y &&
            cy < (double)r.y + r.h)
            return 1;
    }
    return 0;
}

static terrad_footprint footprint_wire(const sim_footprint *e)
{
    terrad_footprint f = {.collider = (uint32_t)e->collider_id,
                          .x = (float)e->x_m,
                          .y = (float)e->y_m,
                          .yaw = (float)e->yaw_rad,
                          .size_m = (float)e->size_m,
                          .strength_m = (float)e->strength_m};
    /* atan2 is within [-pi, pi] in double; keep the f32 inside the wire's bound */
    if (f.yaw > TERRAD_FOOTPRINT_YAW_MAX)
        f.yaw = TERRAD_FOOTPRINT_YAW_MAX;
    if (f.yaw < -TERRAD_FOOTPRINT_YAW_MAX)
        f.yaw = -TERRAD_FOOTPRINT_YAW_MAX;
    return f;
}

/* One frame of n events; a frame built earlier this tick with the same bytes
 * is shared (one more reference) rather than built again. */
static hub_frame *footprints_frame(service *s, int n, hub_frame **shared, int *shared_count)
{
    size_t size = terrad_footprints_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (!f)
        return NULL;
    if (terrad_footprints_encode(f->data, size, &f->len, s->tick, s->events, (size_t)n) != 0) {
        /* the sim's events are finite with size and strength > 0: never here */
        log_error("service: tick %llu: a footprint event failed its wire checks",
                  (unsigned long long)s->tick);
        hub_frame_unref(f);
        return NULL;
    }
    for (int i = 0; i < *shared_count; i++)
        if (shared[i]->len == f->len && memcmp(shared[i]->data, f->data, f->len) == 0) {
            hub_frame_unref(f);
            hub_frame_ref(shared[i]);
            return shared[i];
        }
    if (*shared_count < FOOTPRINTS_SHARED_MAX) {
        /* its own reference: a frame the out queue refuses is freed there */
        hub_frame_ref(f);
        shared[(*shared_count)++] = f;
    }
    return f;
}

/* Per client that asked for them: this tick's events whose centre lies in one
 * of its footprint-subscriptions; no frame when there are none. */
void service_publish_footprints(service *s, const sim_tick_report *report)
{
    THREAD_OWNED(&s->owner);
    if (report->footprint_count <= 0)
        return;
    hub_frame *shared[FOOTPRINTS_SHARED_MAX];
    int shared_count = 0;
    for (int c = 0; c < s->client_count; c++) {
        const svc_client *cl = &s->clients[c];
        int wants = 0;
        for (int i = 0; i < cl->sub_count; i++)
            wants |= cl->subs[i].footprints;
        if (!wants)
            continue;
        int n = 0;
        for (int i = 0; i < report->footprint_count; i++) {
            const sim_footprint *e = &report->footprints[i];
            if (!footprint_in_view(s, cl, e))
                continue;
            if (array_grow((void **)&s->events, &s->event_capacity, (int64_t)n + 1,
                           sizeof *s->events) != 0) {
                service_note_drop(s, "frame", "no memory for the footprints of client %u", cl->id);
                break;
            }
            s->events[n++] = footprint_wire(e);
            if (n == FOOTPRINTS_PER_FRAME) {
                service_queue_client(s, cl->id, footprints_frame(s, n, shared, &shared_count),
                                     TERRAD_MSG_FOOTPRINTS, 0);
                n = 0;
            }
        }
        if (n > 0)
            service_queue_client(s, cl->id, footprints_frame(s, n, shared, &shared_count),
                                 TERRAD_MSG_FOOTPRINTS, 0);
    }
    for (int i = 0; i < shared_count; i++)
        hub_frame_unref(shared[i]);
}
