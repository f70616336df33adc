/*
 * metrics_text.c: the shared shape of the families the small files of
 * metrics/ render into GET /metrics (metrics_internal.h): appending to a
 * bounded buffer, a counter's HELP/TYPE/sample lines, and a counter with one
 * label over a fixed list of values (a bounded label set: an unknown value
 * is dropped by metrics_label_index, never a new series). Runs on the HTTP
 * thread that renders /metrics, never in a tick.
 */
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

int metrics_label_index(const char *const *names, int count, const char *name)
{
    for (int i = 0; name && i < count; i++)
        if (strcmp(name, names[i]) == 0)
            return i;
    return -1;
}

unsigned long long metrics_load(atomic_uint_fast64_t *v)
{
    return (unsigned long long)atomic_load_explicit(v, memory_order_relaxed);
}

int metrics_put(char *out, size_t cap, size_t *n, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    int k = vsnprintf(out + *n, cap - *n, fmt, ap);
    va_end(ap);
    if (k < 0 || (size_t)k >= cap - *n)
        return -1;
    *n += (size_t)k;
    return 0;
}

int metrics_put_counter(char *out, size_t cap, size_t *n, const char *name, const char *help,
                        atomic_uint_fast64_t *value)
{
    return metrics_put(out, cap, n, "# HELP %s %s\n# TYPE %s counter\n%s %llu\n", name, help, name,
                       name, metrics_load(value));
}

int metrics_put_counters(char *out, size_t cap, size_t *n, const metrics_counter *rows,
                         size_t count)
{
    int rc = 0;
    for (size_t i = 0; i < count && rc == 0; i++)
        rc = metrics_put_counter(out, cap, n, rows[i].name, rows[i].help, rows[i].value);
    return rc;
}

int metrics_put_labelled(char *out, size_t cap, size_t *n, const char *name, const char *help,
                         const char *label, const char *const *names, int count,
                         atomic_uint_fast64_t *values)
{
    int rc = metrics_put(out, cap, n, "# HELP %s %s\n# TYPE %s counter\n", name, help, name);
    for (int i = 0; i < count && rc == 0; i++)
        rc = metrics_put(out, cap, n, "%s{%s=\"%s\"} %llu\n", name, label, names[i],
                         metrics_load(&values[i]));
    return rc;
}
