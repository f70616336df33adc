/*
 * net_desync.c: desync detection and repair on the net thread (PROTOCOL.md
 * "CHECKSUM" and "resync" with "tiles"; the sim's half is
 * service/service_checksums.c). In a tick's terms: the sim queues a
 * subscription's CHECKSUM frame last among tick t's frames; net_fanout.c
 * hands it here for each client (net_checksum_for), which keeps only the
 * tiles current for that client; a client whose mirror differs asks for
 * those tiles (net_request_resync_tiles), each becoming one HUB_RESYNC_TILE
 * for the next tick, whose snapshot goes out ahead of the tick after.
 *
 * Whether a client holds a tile's latest version is net_client_tile_current's
 * to say (net_budget.c: a bandwidth budget lets far tiles go stale for a
 * client, a tile in its ledger is not current): the checksums cover only the
 * tiles it keeps current.
 */
#include "net/net_client_internal.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

hub_frame *net_checksum_for(net_client *c, hub_frame *f, size_t max_entries)
{
    /* as many entries as the frame can hold (up to TERRAD_MAX_COUNT): every
     * one is filtered, none sent through unfiltered */
    size_t cap = f->len > TERRAD_CHECKSUM_FIXED
                     ? (f->len - TERRAD_CHECKSUM_FIXED) / TERRAD_TILE_SUM_SIZE
                     : 0;
    uint64_t tick;
    uint32_t sub;
    size_t n = 0, kept = 0;
    terrad_tile_sum *sums = malloc((cap ? cap : 1) * sizeof *sums);
    if (!sums || terrad_checksum_decode(f->data, f->len, &tick, &sub, sums, cap, &n) != 0) {
        free(sums); /* the sim's own frame: sent as it is */
        return f;
    }
    for (size_t i = 0; i < n; i++)
        if (net_client_tile_current(c, sums[i].tile_x, sums[i].tile_y))
            sums[kept++] = sums[i];
    if (kept > max_entries) { /* the next max_entries of them, in turn */
        size_t start = c->checksum_next % kept;
        terrad_tile_sum *turn = malloc(max_entries * sizeof *turn);
        if (!turn) {
            free(sums);
            hub_frame_unref(f);
            return NULL;
        }
        for (size_t i = 0; i < max_entries; i++)
            turn[i] = sums[(start + i) % kept];
        memcpy(sums, turn, max_entries * sizeof *turn);
        free(turn);
        c->checksum_next = start + max_entries;
        kept = max_entries;
    }
    if (kept == n) {
        free(sums);
        return f;
    }
    size_t size = terrad_checksum_size(kept);
    hub_frame *g = hub_frame_new(1, size);
    if (g && terrad_checksum_encode(g->data, size, &g->len, tick, sub, sums, kept) != 0) {
        hub_frame_unref(g);
        g = NULL;
    }
    free(sums);
    hub_frame_unref(f);
    return g;
}

/* Tile i's cells. net_control.c keeps tiles inside the world, so the
 * products fit an int; they are taken in int64 and checked all the same, a
 * tile past INT32_MAX standing for one that meets no subscription. */
static int tile_rect(const int32_t *tiles, int i, int ts, world_rect *out)
{
    int64_t x = (int64_t)tiles[2 * i] * ts, y = (int64_t)tiles[2 * i + 1] * ts;
    if (x < 0 || y < 0 || x > INT32_MAX - ts || y > INT32_MAX - ts)
        return -1;
    *out = (world_rect){(int)x, (int)y, ts, ts};
    return 0;
}

void net_request_resync_tiles(net_client *c, const net_sub *sub, const int32_t *tiles, int n,
                              const cJSON *ref)
{
    int ts = c->srv->cfg.world.tile_size;
    world_rect tile;
    for (int i = 0; i < n; i++) {
        if (tile_rect(tiles, i, ts, &tile) != 0 || !world_rects_overlap(tile, sub->rect)) {
            metrics_count_resync_refused("tiles");
            net_error(c, TERRAD_E_OUTSIDE_WORLD, ref, -1, 0,
                      "tiles[%d]: tile (%d, %d) does not meet subscription %u (x=%d y=%d w=%d "
                      "h=%d, tiles of %d cells)",
                      i, tiles[2 * i], tiles[2 * i + 1], sub->id, sub->rect.x, sub->rect.y,
                      sub->rect.w, sub->rect.h, ts);
            return;
        }
    }
    for (int i = 0; i < n && tile_rect(tiles, i, ts, &tile) == 0; i++) {
        hub_command cmd = {.kind = HUB_RESYNC_TILE,
                           .client = c->id,
                           .subscription = sub->id,
                           .rect = world_rect_meet(tile, sub->rect)}; /* tile ∩ subscription */
        net_push_must(c->srv, &cmd);
    }
    metrics_count_resync_tiles_requested((uint64_t)n);
}
