/*
 * test_net_desync.c: net_checksum_for (server/net/net_desync.c), the net
 * thread's filter of a subscription's CHECKSUM frame down to the tiles a
 * client holds current (PROTOCOL.md "CHECKSUM", "Current tiles only"), on
 * frames of every size the wire allows. A client record alone (no sockets):
 * while its subscribe's snapshot is outstanding no tile is current, with
 * none outstanding (and no budget) every tile is. Trimmed to max_entries (a
 * budget's room), each frame carries the next tiles in turn.
 */
#include <stdint.h>
#include <stdlib.h>

#include "check.h"
#include "net/net_client_internal.h"

/* A CHECKSUM frame of subscription 7 at tick 42 listing n tiles. */
static hub_frame *checksum_frame(size_t n)
{
    terrad_tile_sum *sums = calloc(n ? n : 1, sizeof *sums);
    size_t size = terrad_checksum_size(n);
    hub_frame *f = hub_frame_new(1, size);
    if (!sums || !f) {
        free(sums);
        return f;
    }
    for (size_t i = 0; i < n; i++)
        sums[i] = (terrad_tile_sum){(int32_t)(i % 256), (int32_t)(i / 256), 1, i * 2654435761u};
    CHECK(terrad_checksum_encode(f->data, size, &f->len, 42, 7, sums, n) == 0, "encode %zu", n);
    free(sums);
    return f;
}

/* The number of tiles the frame lists (-1: not a CHECKSUM frame of tick 42,
 * subscription 7); first: the x of its first tile. */
static long listed_from(const hub_frame *f, int32_t *first)
{
    terrad_tile_sum *sums = malloc(TERRAD_MAX_COUNT * sizeof *sums);
    uint64_t tick = 0;
    uint32_t sub = 0;
    size_t n = 0;
    int rc = sums ? terrad_checksum_decode(f->data, f->len, &tick, &sub, sums, TERRAD_MAX_COUNT, &n)
                  : -1;
    if (first)
        *first = rc == 0 && n ? sums[0].tile_x : -1;
    free(sums);
    return rc == 0 && tick == 42 && sub == 7 ? (long)n : -1;
}

static long listed(const hub_frame *f)
{
    return listed_from(f, NULL);
}

int main(void)
{
    net_client *c = calloc(1, sizeof *c);
    if (!c)
        return 1;
    /* every size a subscription's frame may have: one tile, the old decode
     * array's 4096 and one past it (which went out unfiltered), the wire's most */
    static const size_t sizes[] = {1, 4096, 4097, 5000, TERRAD_MAX_COUNT};
    for (size_t k = 0; k < sizeof sizes / sizeof sizes[0]; k++) {
        size_t n = sizes[k];
        c->snapshots_requested = 1; /* a subscribe's snapshot outstanding: nothing current */
        c->snapshots_done = 0;
        hub_frame *f = checksum_frame(n);
        hub_frame *g = f ? net_checksum_for(c, f, SIZE_MAX) : NULL;
        CHECK(g && g != f && listed(g) == 0,
              "%zu tiles, none current: a frame listing none (got %s, %ld tiles)", n,
              !g       ? "none"
              : g == f ? "the frame unfiltered"
                       : "a new frame",
              g ? listed(g) : -1);
        if (g)
            hub_frame_unref(g);

        c->snapshots_done = 1; /* every tile current: the frame goes as it is */
        f = checksum_frame(n);
        g = f ? net_checksum_for(c, f, SIZE_MAX) : NULL;
        CHECK(g && g == f && listed(g) == (long)n, "%zu tiles, all current: the frame itself", n);
        if (g)
            hub_frame_unref(g);
    }

    /* a budget with room for 4 entries, 10 tiles current: 4, 4, then 2 and
     * the first 2 again — every tile within three frames */
    static const int32_t firsts[] = {0, 4, 8, 2};
    for (int k = 0; k < 4; k++) {
        hub_frame *f = checksum_frame(10);
        hub_frame *g = f ? net_checksum_for(c, f, 4) : NULL;
        int32_t first = -1;
        long n = g ? listed_from(g, &first) : -1;
        CHECK(n == 4 && first == firsts[k], "trimmed frame %d: 4 tiles from x=%d (got %ld from %d)",
              k, firsts[k], n, first);
        if (g)
            hub_frame_unref(g);
    }
    free(c);
    return check_report();
}
