/*
 * metrics_edits.c: terrain edits from game logic (world_edit.c), counted by
 * the sim thread as each is applied or refused at the start of a tick:
 * terrad_edits_total{op,result} and the volume they declared, split into
 * terrad_edit_volume_added_units_total{op} and
 * terrad_edit_volume_removed_units_total{op} (counters only go up; a
 * crater with its rim adds to neither). Rendered by metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const ops[] = {METRICS_EDIT_OPS};
#define OPS (int)(sizeof ops / sizeof ops[0])
static atomic_uint_fast64_t applied[OPS], refused[OPS], added[OPS], removed[OPS];

void metrics_count_edit(const char *op, int ok, int64_t volume_change)
{
    int i = metrics_label_index(ops, OPS, op);
    if (i < 0)
        return;
    atomic_fetch_add_explicit(ok ? &applied[i] : &refused[i], 1, memory_order_relaxed);
    if (ok && volume_change > 0)
        atomic_fetch_add_explicit(&added[i], (uint64_t)volume_change, memory_order_relaxed);
    if (ok && volume_change < 0)
        atomic_fetch_add_explicit(&removed[i], (uint64_t)-volume_change, memory_order_relaxed);
}

void metrics_edits_reset(void)
{
    for (int i = 0; i < OPS; i++) {
        atomic_store_explicit(&applied[i], 0, memory_order_relaxed);
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
        atomic_store_explicit(&added[i], 0, memory_order_relaxed);
        atomic_store_explicit(&removed[i], 0, memory_order_relaxed);
    }
}

int metrics_edits_text(char *out, size_t cap)
{
    size_t n = 0;
    int rc = metrics_put(out, cap, &n,
                         "# HELP terrad_edits_total Terrain edits (the edit message, POST "
                         "/v1/worlds/{name}/edits) by op and result.\n"
                         "# TYPE terrad_edits_total counter\n");
    for (int i = 0; i < OPS && rc == 0; i++)
        rc = metrics_put(out, cap, &n,
                         "terrad_edits_total{op=\"%s\",result=\"applied\"} %llu\n"
                         "terrad_edits_total{op=\"%s\",result=\"refused\"} %llu\n",
                         ops[i], metrics_load(&applied[i]), ops[i], metrics_load(&refused[i]));
    if (rc == 0)
        rc = metrics_put_labelled(out, cap, &n, "terrad_edit_volume_added_units_total",
                                  "Height units the applied edits added (cells x units), by op.",
                                  "op", ops, OPS, added);
    if (rc == 0)
        rc = metrics_put_labelled(out, cap, &n, "terrad_edit_volume_removed_units_total",
                                  "Height units the applied edits removed (cells x units), by op.",
                                  "op", ops, OPS, removed);
    return rc == 0 ? (int)n : -1;
}
