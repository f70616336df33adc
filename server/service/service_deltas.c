/*
 * service_deltas.c: what a tick changed, as the protocol's tile deltas, and
 * snapshots for new subscriptions and resyncs (PROTOCOL.md "DELTA").
 *
 * After the deformation, the tick's edits' rectangles (service_edits.c) and
 * the engine's dirty rectangles are cut along tile edges; the pieces of one tile are combined into
 * one rectangle, the tile's version advances, and its differences are encoded once (zigzag + zstd)
 * and queued for the net thread to fan out. Σh follows from the same
 * differences. Snapshot requests are chosen here, within a per-tick budget;
 * their cells are copied and framed off the tick (service_snapshots.c).
 * Sim thread only.
 */
#include "service/service_internal.h"

#include "metrics/metrics.h"

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
    for (int d = -s->edit_count; d < report->dirty_count; d++) {
        world_rect r = d < 0 ? s->edits[-1 - d].rect : report->dirty[d];
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
                    (tile_piece){ty * s->tiles_x + tx, d < 0 ? d : report->dirty_window[d],
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
            /* an edit's differences, or an engine window's after - before:
             * added up, since edits may overlap each other and the windows
             * (the edits came first, so the windows' before is after them) */
            const int32_t *before = NULL, *after;
            world_rect win;
            if (pieces[k].window < 0) {
                const svc_edit *e = &s->edits[-1 - pieces[k].window];
                win = e->rect;
                after = e->diff;
            } else {
                win = sim_engine_window(s->engine, pieces[k].window, &before, &after);
            }
            world_rect p = pieces[k].rect;
            for (int y = p.y; y < p.y + p.h; y++) {
                for (int x = p.x; x < p.x + p.w; x++) {
                    int64_t at = (int64_t)(y - win.y) * win.w + (x - win.x);
                    int32_t d = before ? after[at] - before[at] : after[at];
                    s->values[(y - box.y) * box.w + (x - box.x)] += d;
                    change += d;
                }
            }
        }
        for (int64_t c = 0; c < (int64_t)box.w * box.h && !any; c++)
            any = s->values[c] != 0;
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

/* The cells a request's jobs [start, end] compress. */
static int64_t request_cells(const service_batch *b, int start, int end)
{
    int64_t cells = 0;
    for (int i = start; i <= end; i++)
        cells += (int64_t)b->snapshots[i].rect.w * b->snapshots[i].rect.h;
    return cells;
}

/*
 * Answer pending snapshot requests within SERVICE_SNAPSHOT_CELLS_PER_TICK:
 * in arrival order, one request per client per tick (so one client's flood
 * cannot hold back another's subscribe), whole requests only (all of one
 * request's frames carry this tick's tile versions, queued after its deltas
 * as before), at least one request per tick. The rest wait, in order, and
 * are counted in terrad_snapshot_requests_deferred_total.
 */
void service_publish_snapshots(service *s)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    int64_t budget = SERVICE_SNAPSHOT_CELLS_PER_TICK, spent = 0;
    uint32_t *served = calloc((size_t)b->snapshot_count + 1, sizeof *served);
    int nserved = 0, kept = 0, start = 0;
    uint64_t deferred = 0;
    for (int i = 0; i < b->snapshot_count; i++) {
        if (!b->snapshots[i].last)
            continue;
        uint32_t client = b->snapshots[i].client;
        int again = 0, quiet = b->snapshots[i].quiet; /* a tile's resync: not the client's one */
        for (int k = 0; k < nserved && !again && !quiet; k++)
            again = served[k] == client;
        int64_t cells = request_cells(b, start, i);
        int go = served && !again && (nserved == 0 || spent + cells <= budget);
        if (!served && nserved == 0)
            go = 1; /* no memory for the bookkeeping: at least one request */
        if (go) {
            for (int j = start; j <= i; j++) /* framed, with its marks, by the worker */
                service_snapshot_stage(s, &b->snapshots[j]);
            spent += cells;
            if (served && !quiet)
                served[nserved] = client;
            nserved += !quiet || nserved == 0;
        } else {
            for (int j = start; j <= i; j++)
                b->snapshots[kept++] = b->snapshots[j];
            deferred++;
        }
        start = i + 1;
    }
    /* an unfinished request (no memory for its last job) is kept as it is */
    for (int j = start; j < b->snapshot_count; j++)
        b->snapshots[kept++] = b->snapshots[j];
    b->snapshot_count = kept;
    free(served);
    if (deferred)
        metrics_count_snapshots_deferred(deferred);
}

void service_drop_snapshots(service *s, uint32_t client)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    int kept = 0;
    uint64_t dropped = 0;
    for (int i = 0; i < b->snapshot_count; i++) {
        if (b->snapshots[i].client == client)
            dropped += b->snapshots[i].last;
        else
            b->snapshots[kept++] = b->snapshots[i];
    }
    b->snapshot_count = kept;
    if (dropped)
        metrics_count_snapshots_dropped(dropped);
}
