/*
 * metrics_spectate.c: spectators (PROTOCOL.md "Spectate"), counted by their
 * replay threads as they rebuild a start tick and play ticks forward, and by
 * the net thread as it refuses a spectate: terrad_spectators (replay threads
 * alive), terrad_spectate_seeks_total and terrad_spectate_seek_seconds_total (the
 * rebuilds of a start tick and the seconds they took: their quotient is
 * the mean seek), terrad_spectate_ticks_total, terrad_spectate_frames_total,
 * terrad_spectate_bytes_total, terrad_spectate_frames_dropped_total (frames a
 * replay thread could not make or keep: out of memory; each ends its
 * spectate "failed"), terrad_spectate_refused_total{field}, the field the
 * refusal named, and terrad_spectate_cursor_cells_max (the most cells a
 * replay thread's store cursor held). Rendered by metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const fields[] = {METRICS_SPECTATE_FIELDS};
#define FIELDS (int)(sizeof fields / sizeof fields[0])
static atomic_uint_fast64_t spectators, seeks, seek_us, ticks, frames, bytes, dropped,
    refused[FIELDS];
static atomic_uint_fast64_t held_max; /* terrad_spectate_cursor_cells_max */

void metrics_set_spectators(int n)
{
    atomic_store_explicit(&spectators, (uint64_t)(n > 0 ? n : 0), memory_order_relaxed);
}

void metrics_observe_spectate_seek_ms(double ms)
{
    atomic_fetch_add_explicit(&seeks, 1, memory_order_relaxed);
    atomic_fetch_add_explicit(&seek_us, (uint64_t)(ms > 0 ? ms * 1e3 + 0.5 : 0),
                              memory_order_relaxed);
}

void metrics_observe_spectate_cursor_cells(int64_t cells)
{
    uint_fast64_t v = (uint_fast64_t)(cells > 0 ? cells : 0),
                  old = atomic_load_explicit(&held_max, memory_order_relaxed);
    while (v > old && !atomic_compare_exchange_weak_explicit(
                          &held_max, &old, v, memory_order_relaxed, memory_order_relaxed))
        ;
}

void metrics_count_spectate_ticks(uint64_t n)
{
    atomic_fetch_add_explicit(&ticks, n, memory_order_relaxed);
}

void metrics_count_spectate_frames(uint64_t n, uint64_t frame_bytes)
{
    atomic_fetch_add_explicit(&frames, n, memory_order_relaxed);
    atomic_fetch_add_explicit(&bytes, frame_bytes, memory_order_relaxed);
}

void metrics_count_spectate_dropped(uint64_t n)
{
    atomic_fetch_add_explicit(&dropped, n, memory_order_relaxed);
}

void metrics_count_spectate_refused(const char *field)
{
    int i = metrics_label_index(fields, FIELDS, field);
    if (i >= 0)
        atomic_fetch_add_explicit(&refused[i], 1, memory_order_relaxed);
}

void metrics_spectate_reset(void)
{
    atomic_uint_fast64_t *all[] = {&seeks, &seek_us, &ticks, &frames, &bytes, &dropped, &held_max};
    for (size_t i = 0; i < sizeof all / sizeof all[0]; i++)
        atomic_store_explicit(all[i], 0, memory_order_relaxed);
    for (int i = 0; i < FIELDS; i++)
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
}

int metrics_spectate_text(char *out, size_t cap)
{
    static const metrics_counter counters[] = {
        {"terrad_spectate_seeks_total", "Start ticks rebuilt for spectators.", &seeks},
        {"terrad_spectate_ticks_total", "Ticks played forward to spectators.", &ticks},
        {"terrad_spectate_frames_total", "Frames made for spectators.", &frames},
        {"terrad_spectate_bytes_total", "Bytes of the frames made for spectators.", &bytes},
        {"terrad_spectate_frames_dropped_total",
         "Spectators' frames not made or not kept (out of memory); each ends its spectate.",
         &dropped},
    };
    size_t n = 0;
    int rc = metrics_put(out, cap, &n,
                         "# HELP terrad_spectators Spectators' replay threads alive.\n"
                         "# TYPE terrad_spectators gauge\nterrad_spectators %llu\n"
                         "# HELP terrad_spectate_seek_seconds_total Seconds the spectators' "
                         "start-tick rebuilds took, in all.\n"
                         "# TYPE terrad_spectate_seek_seconds_total counter\n"
                         "terrad_spectate_seek_seconds_total %.6f\n"
                         "# HELP terrad_spectate_cursor_cells_max The most cells a spectator's "
                         "store cursor held (only its window's tiles').\n"
                         "# TYPE terrad_spectate_cursor_cells_max gauge\n"
                         "terrad_spectate_cursor_cells_max %llu\n",
                         metrics_load(&spectators), (double)metrics_load(&seek_us) / 1e6,
                         metrics_load(&held_max));
    if (rc == 0)
        rc = metrics_put_counters(out, cap, &n, counters, sizeof counters / sizeof counters[0]);
    if (rc == 0)
        rc = metrics_put_labelled(out, cap, &n, "terrad_spectate_refused_total",
                                  "spectate requests refused, by the field the error named.",
                                  "field", fields, FIELDS, refused);
    return rc == 0 ? (int)n : -1;
}
