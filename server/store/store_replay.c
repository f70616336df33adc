/*
 * store_replay.c: the world as of a past tick, rebuilt from a data directory
 * beside the live daemon (GET /v1/heights?tick=N; docs/storage.md "Replay").
 * It runs on an HTTP worker, never in the tick: it reads the files the sim
 * and compaction threads write (every whole file appears by rename, every
 * record is complete before its tick is published), into a world of its own.
 *
 * The rebuild: the base terrain over the requested rectangle, then either the
 * whole log up to the tick (while retention keeps segment 1: every tick since
 * the first can be rebuilt) or the tile snapshots and the log after them (a
 * snapshot newer than the tick means the store no longer holds it: 410).
 * Records hold absolute heights, so replaying every record up to the tick
 * over either start gives the cells as they were at the end of that tick.
 */
#include <stdio.h>
#include <string.h>
#include <unistd.h>

#include "store/store_internal.h"

/* One rebuild; 0, 1 (gone) or -1. */
static int replay_once(const char *dir, const world *base, uint64_t tick, world_rect r,
                       int32_t *dst, error_text *why)
{
    world w;
    if (world_init_tiled(&w, base->width, base->height, base->cell_size_m, base->units_per_m,
                         base->floor, base->tile_cells, why) != 0)
        return -1;
    /* the base under the rectangle (the replay world's own base is flat):
     * cells no record or snapshot names keep it */
    world_base_fill_rect(base, r, dst);
    world_scatter_window(&w, r, dst);
    char first[1100];
    store_segment_path(dir, 1, first, sizeof first);
    int whole = access(first, F_OK) == 0;
    recover_args a = {
        .dir = dir, .w = &w, .upto_tick = tick, .flags = whole ? STORE_RECOVER_NO_TILES : 0};
    uint64_t last_seq;
    store_recovery rec;
    int rc = 0;
    if (store_recover(&a, &last_seq, &rec, why) != 0) {
        /* store_tile_load's refusal of a snapshot newer than the tick */
        rc = strstr(why->message, "compacted away") ? 1 : -1;
    } else {
        world_gather_window(&w, r, dst);
    }
    world_free(&w);
    return rc;
}

int store_replay_rect(const char *dir, const world *base, uint64_t tick, world_rect r, int32_t *dst,
                      error_text *why)
{
    /* a compaction may delete a segment or replace a snapshot between the
     * listing and the read: the next try sees the directory after it */
    int rc = -1;
    for (int attempt = 0; attempt < 3 && rc < 0; attempt++) {
        memset(why, 0, sizeof *why);
        rc = replay_once(dir, base, tick, r, dst, why);
    }
    return rc;
}
