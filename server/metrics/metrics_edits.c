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
#include <stdio.h>
#include <string.h>

#include "metrics/metrics.h"

static const char *const ops[] = {METRICS_EDIT_OPS};
#define OPS (sizeof ops / sizeof ops[0])
static atomic_uint_fast64_t applied[OPS], refused[OPS], added[OPS], removed[OPS];

void metrics_count_edit(const char *op, int ok, int64_t volume_change)
{
    for (size_t i = 0; i < OPS; i++) {
        if (strcmp(op, ops[i]) != 0)
            continue;
        atomic_fetch_add_explicit(ok ? &applied[i] : &refused[i], 1, memory_order_relaxed);
        if (ok && volume_change > 0)
            atomic_fetch_add_explicit(&added[i], (uint64_t)volume_change, memory_order_relaxed);
        if (ok && volume_change < 0)
            atomic_fetch_add_explicit(&removed[i], (uint64_t)-volume_change, memory_order_relaxed);
    }
}

void metrics_edits_reset(void)
{
    for (size_t i = 0; i < OPS; i++) {
        atomic_store_explicit(&applied[i], 0, memory_order_relaxed);
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
        atomic_store_explicit(&added[i], 0, memory_order_relaxed);
        atomic_store_explicit(&removed[i], 0, memory_order_relaxed);
    }
}

static unsigned long long get(atomic_uint_fast64_t *v)
{
    return (unsigned long long)atomic_load_explicit(v, memory_order_relaxed);
}

int metrics_edits_text(char *out, size_t cap)
{
    size_t n = 0;
    int w = snprintf(out, cap,
                     "# HELP terrad_edits_total Terrain edits (the edit message, POST "
                     "/v1/worlds/{name}/edits) by op and result.\n"
                     "# TYPE terrad_edits_total counter\n");
    for (size_t i = 0; i < OPS && w >= 0 && (size_t)w < cap - n; i++) {
        n += (size_t)w;
        w = snprintf(out + n, cap - n,
                     "terrad_edits_total{op=\"%s\",result=\"applied\"} %llu\n"
                     "terrad_edits_total{op=\"%s\",result=\"refused\"} %llu\n",
                     ops[i], get(&applied[i]), ops[i], get(&refused[i]));
    }
    static const char *const families[2][2] = {
        {"terrad_edit_volume_added_units_total", "Height units the applied edits added"},
        {"terrad_edit_volume_removed_units_total", "Height units the applied edits removed"}};
    for (int f = 0; f < 2; f++) {
        if (w < 0 || (size_t)w >= cap - n)
            return -1;
        n += (size_t)w;
        w = snprintf(out + n, cap - n, "# HELP %s %s (cells x units), by op.\n# TYPE %s counter\n",
                     families[f][0], families[f][1], families[f][0]);
        for (size_t i = 0; i < OPS && w >= 0 && (size_t)w < cap - n; i++) {
            n += (size_t)w;
            w = snprintf(out + n, cap - n, "%s{op=\"%s\"} %llu\n", families[f][0], ops[i],
                         get(f ? &removed[i] : &added[i]));
        }
    }
    if (w < 0 || (size_t)w >= cap - n)
        return -1;
    return (int)(n + (size_t)w);
}
