/*
 * metrics_internal.h: the exposition-text helpers the files of metrics/ that
 * render their own families share (metrics_text.c): metrics_auth.c,
 * metrics_edits.c, metrics_room.c, metrics_steps.c and metrics_worlds.c each
 * append to the caller's buffer with these, so a family's HELP/TYPE lines
 * and its samples have one shape. Only inside server/metrics/; rendering
 * runs on the HTTP thread that answers GET /metrics, never in a tick.
 */
#ifndef TERRAD_METRICS_INTERNAL_H
#define TERRAD_METRICS_INTERNAL_H

#include <stdatomic.h>
#include <stddef.h>

/* A relaxed load of a counter, as the text prints it. */
unsigned long long metrics_load(atomic_uint_fast64_t *v);

/* Appends fmt at out + *n (cap in all): 0, or -1 when it does not fit. */
int metrics_put(char *out, size_t cap, size_t *n, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* A counter family without labels: HELP, TYPE and its one sample. 0 or -1. */
int metrics_put_counter(char *out, size_t cap, size_t *n, const char *name, const char *help,
                        atomic_uint_fast64_t *value);

/* Counter families without labels, one per row, in order. 0 or -1. */
typedef struct metrics_counter {
    const char *name, *help;
    atomic_uint_fast64_t *value;
} metrics_counter;
int metrics_put_counters(char *out, size_t cap, size_t *n, const metrics_counter *rows,
                         size_t count);

/* A counter family with one label: HELP, TYPE, then name{label="names[i]"}
 * values[i] for each of the count values, in order. 0 or -1. */
int metrics_put_labelled(char *out, size_t cap, size_t *n, const char *name, const char *help,
                         const char *label, const char *const *names, int count,
                         atomic_uint_fast64_t *values);

#endif
