/*
 * service_checksums.c: desync detection and repair on the sim side
 * (PROTOCOL.md "CHECKSUM" and "resync" with "tiles"; issue 32 item 4).
 *
 * A client that misses or misapplies a delta would drift silently. Every
 * checksum_interval ticks (tick % interval == 0) each subscription gets one
 * CHECKSUM frame: for every tile it touches, the tile's version and the hash
 * (terrad_heights_hash) of the tile's part of the subscription as of the end
 * of this tick. It is queued last among the tick's frames, after the tick's
 * deltas, CONTACT, FORCES, ACK, COLLIDERS and FOOTPRINTS, and snapshots are
 * queued at the start of the next tick, so a client that has applied every
 * frame before it holds exactly the tick's heights: the comparison is exact,
 * never racy. The net thread drops the frame for a client whose deltas are
 * being dropped (it would compare a mirror that is known to be behind) and
 * keeps only the tiles that are current for it (net_client_tile_current).
 *
 * A tile that differs is asked for again alone: HUB_RESYNC_TILE queues a
 * quiet snapshot job (no snapshot_done mark, so the client's other tiles'
 * deltas go on) of that tile's part of the subscription; it is framed like
 * any snapshot, carrying the tile's version at its tick, and deltas continue
 * from it. Sim thread only.
 */
#include "service/service_internal.h"

#include <string.h>

#include "metrics/metrics.h"

void service_set_checksum_interval(service *s, int ticks)
{
    s->checksum_interval = ticks > 0 ? ticks : 0;
}

/* One subscription's CHECKSUM frame for its client. */
static void publish_sub(service *s, uint32_t client, const svc_subscription *sub)
{
    world_rect q = sub->rect;
    if (q.w <= 0 || q.h <= 0)
        return;
    int tx0 = q.x / SERVICE_TILE_SIZE, tx1 = (q.x + q.w - 1) / SERVICE_TILE_SIZE;
    int ty0 = q.y / SERVICE_TILE_SIZE, ty1 = (q.y + q.h - 1) / SERVICE_TILE_SIZE;
    int64_t tiles = (int64_t)(tx1 - tx0 + 1) * (ty1 - ty0 + 1);
    if (tiles > TERRAD_MAX_COUNT ||
        array_grow((void **)&s->sums, &s->sum_capacity, tiles, sizeof *s->sums) != 0) {
        service_note_drop(s, "frame", "no room for %lld tile hashes of client %u", (long long)tiles,
                          client);
        return;
    }
    int n = 0;
    for (int ty = ty0; ty <= ty1; ty++) {
        for (int tx = tx0; tx <= tx1; tx++) {
            world_rect part =
                world_rect_meet(q, (world_rect){tx * SERVICE_TILE_SIZE, ty * SERVICE_TILE_SIZE,
                                                SERVICE_TILE_SIZE, SERVICE_TILE_SIZE});
            world_gather_window(s->world, part, s->values); /* a tile's cells at most */
            s->sums[n++] =
                (terrad_tile_sum){.tile_x = tx,
                                  .tile_y = ty,
                                  .version = s->tile_versions[ty * s->tiles_x + tx],
                                  .hash = terrad_heights_hash(s->values, (size_t)part.w,
                                                              (uint32_t)part.w, (uint32_t)part.h)};
        }
    }
    size_t size = terrad_checksum_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (f &&
        terrad_checksum_encode(f->data, size, &f->len, s->tick, sub->id, s->sums, (size_t)n) != 0) {
        hub_frame_unref(f);
        f = NULL; /* counted as dropped by service_queue_client */
    }
    service_queue_client(s, client, f, TERRAD_MSG_CHECKSUM, 0);
}

void service_publish_checksums(service *s)
{
    THREAD_OWNED(&s->owner);
    if (s->checksum_interval <= 0 || s->tick % (uint64_t)s->checksum_interval != 0)
        return;
    for (int i = 0; i < s->client_count; i++)
        for (int k = 0; k < s->clients[i].sub_count; k++)
            publish_sub(s, s->clients[i].id, &s->clients[i].subs[k]);
}

void service_resync_tile(service *s, const hub_command *c)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    snapshot_job job = {.client = c->client, .rect = c->rect, .last = 1, .quiet = 1};
    for (int i = 0; i < b->snapshot_count; i++) /* asked again before it went out: once */
        if (b->snapshots[i].quiet && b->snapshots[i].client == job.client &&
            memcmp(&b->snapshots[i].rect, &job.rect, sizeof job.rect) == 0)
            return;
    if (job.rect.w <= 0 || job.rect.h <= 0 ||
        array_grow((void **)&b->snapshots, &b->snapshot_capacity, (int64_t)b->snapshot_count + 1,
                   sizeof *b->snapshots) != 0) {
        if (job.rect.w > 0)
            service_note_drop(s, "snapshot", "no memory for a tile's resync for client %u",
                              job.client);
        return;
    }
    b->snapshots[b->snapshot_count++] = job;
    metrics_count_tile_resyncs(1);
}
