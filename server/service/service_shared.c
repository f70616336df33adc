/*
 * service_shared.c: the helpers every step of a tick uses (the leaf of
 * service/: it calls nothing else of the folder): finding a client or a
 * collider of the sim's view, queueing a frame for the net thread
 * (service_queue_out / service_queue_client: the tick's frames wait in
 * s->batch until step 9 hands them to the hub; service_reply_json for a
 * JSON reply or error to one client), and counting what could not be sent. Nothing the tick meant
 * to send is dropped silently: it is counted in terrad_service_dropped_total{reason} and logged at
 * most once a second. Sim thread only.
 */
#include "service/service_internal.h"

#include <cjson/cJSON.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "metrics/metrics.h"

svc_client *service_find_client(service *s, uint32_t id)
{
    for (int i = 0; i < s->client_count; i++)
        if (s->clients[i].id == id)
            return &s->clients[i];
    return NULL;
}

int service_find_collider(const service *s, uint32_t id)
{
    /* colliders stay sorted by id (ids only grow), so a binary search */
    int lo = 0, hi = s->collider_count - 1;
    while (lo <= hi) {
        int mid = (lo + hi) / 2;
        if (s->colliders[mid].id == id)
            return mid;
        if (s->colliders[mid].id < id)
            lo = mid + 1;
        else
            hi = mid - 1;
    }
    return -1;
}

void service_note_drop(service *s, const char *reason, const char *fmt, ...)
{
    metrics_count_service_dropped(reason);
    double now = time_now_ms();
    if (s->last_drop_log_ms > 0 && now - s->last_drop_log_ms < 1000.0) {
        s->drops_unlogged++;
        return;
    }
    char what[200];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    log_warn("service: tick %llu: dropped (%s): %s (and %llu more drops not logged)",
             (unsigned long long)s->tick, reason, what, (unsigned long long)s->drops_unlogged);
    s->drops_unlogged = 0;
    s->last_drop_log_ms = now;
}

int service_queue_out(service *s, hub_out item)
{
    service_batch *b = &s->batch;
    if (!item.frame && item.kind != HUB_OUT_TICK_DONE && !item.snapshot_done) {
        service_note_drop(s, "frame", "a frame for %s could not be built",
                          item.kind == HUB_OUT_TILE_DELTA ? "a tile" : "a client");
        return -1;
    }
    if (array_grow((void **)&b->out, &b->out_capacity, (int64_t)b->out_count + 1, sizeof *b->out) !=
        0) {
        if (item.frame)
            hub_frame_unref(item.frame);
        service_note_drop(s, item.snapshot_done ? "snapshot" : "frame",
                          "no memory to queue a frame%s",
                          item.snapshot_done ? " (and its snapshot mark)" : "");
        return -1;
    }
    b->out[b->out_count++] = item;
    return 0;
}

int service_queue_client(service *s, uint32_t client, hub_frame *f, int msg, int snapshot_done)
{
    hub_out item = {.kind = HUB_OUT_CLIENT,
                    .client = client,
                    .snapshot_done = snapshot_done,
                    .msg = msg,
                    .tick = s->tick,
                    .frame = f};
    if (!f && snapshot_done) {
        /* the net thread holds the client's deltas until the mark arrives:
         * the mark goes out even when its frame could not be built */
        service_note_drop(s, "snapshot", "the last snapshot frame for client %u", client);
    }
    return service_queue_out(s, item);
}

void service_reply_json(service *s, uint32_t client, const char *ref, cJSON *obj)
{
    cJSON *r = ref[0] ? cJSON_Parse(ref) : NULL;
    cJSON_AddItemToObject(obj, "ref", r ? r : cJSON_CreateNull());
    char *text = json_print_delete(obj);
    service_queue_client(s, client, text ? hub_frame_from_text(text) : NULL, 0, 0); /* JSON */
    free(text);
}
