/*
 * service_deltas.c: what a tick changed, as the protocol's tile deltas, and
 * snapshots for new subscriptions and resyncs (PROTOCOL.md "DELTA").
 *
 * After the deformation, the engine's dirty rectangles are cut along tile
 * edges; the pieces of one tile are combined into one rectangle, the tile's
 * version advances, and its differences are encoded once (zigzag + zstd)
 * and queued for the net thread to fan out. Σh follows from the same
 * differences. Snapshots carry whole tiles at their current version, the
 * last frame of a request marked snapshot_done. Sim thread only.
 */
#include "service/service_internal.h"

#include <stdlib.h>
#include <string.h>

static int compare_pieces(const void *a, const void *b)
{
    const tile_piece *p = a, *q = b;
    if (p->tile != q->tile)
        return (p->tile > q->tile) - (p->tile < q->tile);
    return (p->window > q->window) - (p->window < q->window);
}

int service_cut_into_tiles(service *s, const sim_tick_report *report)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    b->piece_count = 0;
    for (int d = 0; d < report->dirty_count; d++) {
        world_rect r = report->dirty[d];
        int tx0 = r.x / SERVICE_TILE_SIZE, tx1 = (r.x + r.w - 1) / SERVICE_TILE_SIZE;
        int ty0 = r.y / SERVICE_TILE_SIZE, ty1 = (r.y + r.h - 1) / SERVICE_TILE_SIZE;
        for (int ty = ty0; ty <= ty1; ty++) {
            for (int tx = tx0; tx <= tx1; tx++) {
                world_rect tile = {tx * SERVICE_TILE_SIZE, ty * SERVICE_TILE_SIZE,
                                   SERVICE_TILE_SIZE, SERVICE_TILE_SIZE};
                int x0 = r.x > tile.x ? r.x : tile.x, y0 = r.y > tile.y ? r.y : tile.y;
                int x1 = r.x + r.w < tile.x + tile.w ? r.x + r.w : tile.x + tile.w;
                int y1 = r.y + r.h < tile.y + tile.h ? r.y + r.h : tile.y + tile.h;
                if (array_grow((void **)&b->pieces, &b->piece_capacity, (int64_t)b->piece_count + 1,
                               sizeof *b->pieces) != 0) {
                    /* tile versions and Σh do not follow this tick's change */
                    service_note_drop(s, "deltas", "no memory to cut %d dirty rectangles",
                                      report->dirty_count);
                    return -1;
                }
                b->pieces[b->piece_count++] =
                    (tile_piece){ty * s->tiles_x + tx, report->dirty_window[d],
                                 (world_rect){x0, y0, x1 - x0, y1 - y0}};
            }
        }
    }
    if (b->piece_count > 1)
        qsort(b->pieces, (size_t)b->piece_count, sizeof *b->pieces, compare_pieces);
    return 0;
}

/* Encode one rectangle's values into a single-rectangle DELTA frame. */
static hub_frame *encode_rect_frame(service *s, terrad_rect *rect, const int32_t *values)
{
    size_t cells = (size_t)rect->w * rect->h, len = 0;
    if (terrad_rect_compress(s->codec, values, cells, s->packed, s->packed_cap, &len) != 0)
        return NULL;
    rect->data = s->packed;
    rect->data_len = (uint32_t)len;
    size_t size = terrad_delta_size(rect, 1);
    hub_frame *f = hub_frame_new(1, size);
    if (!f)
        return NULL;
    if (terrad_delta_encode(f->data, size, &f->len, s->tick, rect, 1) != 0) {
        hub_frame_unref(f);
        return NULL;
    }
    return f;
}

/* Combine the pieces of each tile, advance its version, encode, publish. */
void service_publish_deltas(service *s, service_tick_stats *stats)
{
    THREAD_OWNED(&s->owner);
    const tile_piece *pieces = s->batch.pieces;
    int piece_count = s->batch.piece_count;
    int i = 0;
    while (i < piece_count) {
        int tile = pieces[i].tile, j = i;
        world_rect box = pieces[i].rect;
        while (j < piece_count && pieces[j].tile == tile) {
            box = world_rect_union(box, pieces[j].rect);
            j++;
        }
        memset(s->values, 0, (size_t)box.w * box.h * sizeof *s->values);
        int64_t change = 0;
        int any = 0;
        for (int k = i; k < j; k++) {
            const int32_t *before, *after;
            world_rect win = sim_engine_window(s->engine, pieces[k].window, &before, &after);
            world_rect p = pieces[k].rect;
            for (int y = p.y; y < p.y + p.h; y++) {
                for (int x = p.x; x < p.x + p.w; x++) {
                    int64_t at = (int64_t)(y - win.y) * win.w + (x - win.x);
                    int32_t d = after[at] - before[at];
                    s->values[(y - box.y) * box.w + (x - box.x)] = d;
                    change += d;
                    any |= d != 0;
                }
            }
        }
        if (any) {
            uint32_t base = s->tile_versions[tile];
            s->tile_versions[tile] = base + 1;
            terrad_rect rect = {.x = box.x,
                                .y = box.y,
                                .w = (uint16_t)box.w,
                                .h = (uint16_t)box.h,
                                .base_version = base,
                                .new_version = base + 1,
                                .encoding = TERRAD_ENC_DELTA};
            hub_frame *f = encode_rect_frame(s, &rect, s->values);
            if (f) {
                stats->delta_frames++;
                stats->delta_raw_bytes += (uint64_t)box.w * box.h * 4;
                stats->delta_compressed_bytes += rect.data_len;
            }
            /* a NULL frame (no memory, or the codec failed) is counted as dropped */
            service_queue_out(s, (hub_out){.kind = HUB_OUT_TILE_DELTA,
                                           .tile_x = tile % s->tiles_x,
                                           .tile_y = tile / s->tiles_x,
                                           .tick = s->tick,
                                           .frame = f});
        }
        s->volume += change;
        i = j;
    }
}

/* Send the rectangles [first, first + count) as one DELTA frame to a client. */
static void send_snapshot_frame(service *s, uint32_t client, const terrad_rect *rects, int count,
                                int done)
{
    size_t size = terrad_delta_size(rects, (size_t)count);
    hub_frame *f = hub_frame_new(1, size);
    if (f && terrad_delta_encode(f->data, size, &f->len, s->tick, rects, (size_t)count) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    service_queue_client(s, client, f, done);
}

/* Snapshot rectangles, one per tile ∩ subscription, packed into frames under
 * the size limit; the last frame of a request carries snapshot_done (an
 * empty request still sends an empty frame with the mark). */
static void publish_snapshot(service *s, const snapshot_job *job)
{
    world_rect r = job->rect;
    int tiles = 0;
    if (r.w > 0 && r.h > 0)
        tiles = ((r.x + r.w - 1) / SERVICE_TILE_SIZE - r.x / SERVICE_TILE_SIZE + 1) *
                ((r.y + r.h - 1) / SERVICE_TILE_SIZE - r.y / SERVICE_TILE_SIZE + 1);
    terrad_rect *rects = calloc((size_t)tiles + 1, sizeof *rects);
    uint8_t **datas = calloc((size_t)tiles + 1, sizeof *datas);
    int count = 0;
    if (!rects || !datas) {
        service_note_drop(s, "snapshot", "no memory for a snapshot of %d tiles for client %u",
                          tiles, job->client);
        if (job->last) /* the client still gets its mark, without a frame */
            service_queue_out(s, (hub_out){.kind = HUB_OUT_CLIENT,
                                           .client = job->client,
                                           .snapshot_done = 1,
                                           .tick = s->tick});
        goto done;
    }
    for (int ty = r.y / SERVICE_TILE_SIZE; tiles && ty <= (r.y + r.h - 1) / SERVICE_TILE_SIZE;
         ty++) {
        for (int tx = r.x / SERVICE_TILE_SIZE; tx <= (r.x + r.w - 1) / SERVICE_TILE_SIZE; tx++) {
            int x0 = r.x > tx * SERVICE_TILE_SIZE ? r.x : tx * SERVICE_TILE_SIZE;
            int y0 = r.y > ty * SERVICE_TILE_SIZE ? r.y : ty * SERVICE_TILE_SIZE;
            int x1 =
                r.x + r.w < (tx + 1) * SERVICE_TILE_SIZE ? r.x + r.w : (tx + 1) * SERVICE_TILE_SIZE;
            int y1 =
                r.y + r.h < (ty + 1) * SERVICE_TILE_SIZE ? r.y + r.h : (ty + 1) * SERVICE_TILE_SIZE;
            world_rect piece = {x0, y0, x1 - x0, y1 - y0};
            world_gather_window(s->world, piece, s->values);
            size_t len = 0;
            if (terrad_rect_compress(s->codec, s->values, (size_t)piece.w * piece.h, s->packed,
                                     s->packed_cap, &len) != 0 ||
                !(datas[count] = malloc(len ? len : 1))) {
                service_note_drop(s, "snapshot", "tile (%d, %d) of a snapshot for client %u", tx,
                                  ty, job->client);
                continue;
            }
            memcpy(datas[count], s->packed, len);
            rects[count] = (terrad_rect){.x = piece.x,
                                         .y = piece.y,
                                         .w = (uint16_t)piece.w,
                                         .h = (uint16_t)piece.h,
                                         .base_version = 0,
                                         .new_version = s->tile_versions[ty * s->tiles_x + tx],
                                         .encoding = TERRAD_ENC_SNAPSHOT,
                                         .data_len = (uint32_t)len,
                                         .data = datas[count]};
            count++;
        }
    }
    int first = 0;
    size_t size = TERRAD_DELTA_FIXED;
    for (int i = 0; i < count; i++) {
        size_t add = TERRAD_RECT_FIXED + rects[i].data_len;
        if (i > first && (size + add > SERVICE_FRAME_MAX || i - first == TERRAD_MAX_COUNT)) {
            send_snapshot_frame(s, job->client, rects + first, i - first, 0);
            first = i;
            size = TERRAD_DELTA_FIXED;
        }
        size += add;
    }
    if (count > first || job->last)
        send_snapshot_frame(s, job->client, rects + first, count - first, job->last);
done:
    for (int i = 0; datas && i < count; i++)
        free(datas[i]);
    free(rects);
    free(datas);
}

void service_publish_snapshots(service *s)
{
    THREAD_OWNED(&s->owner);
    for (int i = 0; i < s->batch.snapshot_count; i++)
        publish_snapshot(s, &s->batch.snapshots[i]);
    s->batch.snapshot_count = 0;
}
