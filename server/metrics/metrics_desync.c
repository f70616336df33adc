/*
 * metrics_desync.c: desync detection and repair (PROTOCOL.md "CHECKSUM" and
 * "resync" with "tiles"), counted by the net thread as it sends CHECKSUM
 * frames and takes or refuses a client's tile resync, and by the sim thread
 * as it queues a tile's snapshot: terrad_checksum_frames_total,
 * terrad_checksum_bytes_total, terrad_checksum_frames_skipped_total (not sent:
 * the client's deltas were being dropped, its queue would have passed
 * max_pending_bytes or its budget's window was full: net_fanout.c
 * send_checksum), terrad_resync_tiles_requested_total,
 * terrad_tile_resyncs_total and terrad_resync_refused_total{field}, the
 * field the refusal named. Rendered by metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const fields[] = {METRICS_RESYNC_FIELDS};
#define FIELDS (int)(sizeof fields / sizeof fields[0])
static atomic_uint_fast64_t frames, bytes, skipped, requested, resyncs, refused[FIELDS];

void metrics_count_checksums(uint64_t n, uint64_t frame_bytes)
{
    atomic_fetch_add_explicit(&frames, n, memory_order_relaxed);
    atomic_fetch_add_explicit(&bytes, frame_bytes, memory_order_relaxed);
}

void metrics_count_checksums_skipped(uint64_t n)
{
    atomic_fetch_add_explicit(&skipped, n, memory_order_relaxed);
}

void metrics_count_resync_tiles_requested(uint64_t n)
{
    atomic_fetch_add_explicit(&requested, n, memory_order_relaxed);
}

void metrics_count_tile_resyncs(uint64_t n)
{
    atomic_fetch_add_explicit(&resyncs, n, memory_order_relaxed);
}

void metrics_count_resync_refused(const char *field)
{
    int i = metrics_label_index(fields, FIELDS, field);
    if (i >= 0)
        atomic_fetch_add_explicit(&refused[i], 1, memory_order_relaxed);
}

void metrics_desync_reset(void)
{
    atomic_store_explicit(&frames, 0, memory_order_relaxed);
    atomic_store_explicit(&bytes, 0, memory_order_relaxed);
    atomic_store_explicit(&skipped, 0, memory_order_relaxed);
    atomic_store_explicit(&requested, 0, memory_order_relaxed);
    atomic_store_explicit(&resyncs, 0, memory_order_relaxed);
    for (int i = 0; i < FIELDS; i++)
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
}

int metrics_desync_text(char *out, size_t cap)
{
    static const metrics_counter counters[] = {
        {"terrad_checksum_frames_total", "CHECKSUM frames queued for clients.", &frames},
        {"terrad_checksum_bytes_total", "Bytes of CHECKSUM frames queued for clients.", &bytes},
        {"terrad_checksum_frames_skipped_total",
         "CHECKSUM frames not sent: the client's deltas were being dropped (a resync under way), "
         "the frame would have passed max_pending_bytes, or the budget's window was full.",
         &skipped},
        {"terrad_resync_tiles_requested_total",
         "Tiles clients asked for again (resync with tiles).", &requested},
        {"terrad_tile_resyncs_total", "Tile snapshots queued for a resync with tiles.", &resyncs},
    };
    size_t n = 0;
    int rc = metrics_put_counters(out, cap, &n, counters, sizeof counters / sizeof counters[0]);
    if (rc == 0)
        rc = metrics_put_labelled(out, cap, &n, "terrad_resync_refused_total",
                                  "resync requests refused, by the field the error named.", "field",
                                  fields, FIELDS, refused);
    return rc == 0 ? (int)n : -1;
}
