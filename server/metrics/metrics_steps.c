/*
 * metrics_steps.c: client-clocked worlds (PROTOCOL.md "STEP"), counted by
 * the net thread as it takes or refuses a STEP and by the sim thread as the
 * step's ticks run: terrad_steps_total (steps whose STEPPED was queued),
 * terrad_stepped_ticks_total, and terrad_steps_refused_total{field}, the
 * field the refusal named. Rendered by metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const fields[] = {METRICS_STEP_FIELDS};
#define FIELDS (int)(sizeof fields / sizeof fields[0])
static atomic_uint_fast64_t steps, ticks, refused[FIELDS];

void metrics_count_steps(uint64_t n)
{
    atomic_fetch_add_explicit(&steps, n, memory_order_relaxed);
}

void metrics_count_stepped_ticks(uint64_t n)
{
    atomic_fetch_add_explicit(&ticks, n, memory_order_relaxed);
}

void metrics_count_step_refused(const char *field)
{
    int i = metrics_label_index(fields, FIELDS, field);
    if (i >= 0)
        atomic_fetch_add_explicit(&refused[i], 1, memory_order_relaxed);
}

void metrics_steps_reset(void)
{
    atomic_store_explicit(&steps, 0, memory_order_relaxed);
    atomic_store_explicit(&ticks, 0, memory_order_relaxed);
    for (int i = 0; i < FIELDS; i++)
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
}

int metrics_steps_text(char *out, size_t cap)
{
    size_t n = 0;
    int rc = metrics_put_counter(
        out, cap, &n, "terrad_steps_total",
        "STEP messages of client-clocked worlds whose ticks all ran (STEPPED queued).", &steps);
    if (rc == 0)
        rc = metrics_put_counter(out, cap, &n, "terrad_stepped_ticks_total",
                                 "Ticks of client-clocked worlds.", &ticks);
    if (rc == 0)
        rc = metrics_put_labelled(out, cap, &n, "terrad_steps_refused_total",
                                  "STEP messages refused, by the field the error named.", "field",
                                  fields, FIELDS, refused);
    return rc == 0 ? (int)n : -1;
}
