/*
 * base: the small pieces every subsystem uses — logging, monotonic time,
 * per-stage timing series (mean and p99) and the process's peak memory.
 * Nothing here knows about terrain; it exists so that each subsystem does not
 * grow its own copy of these helpers.
 */
#ifndef TERRAD_BASE_H
#define TERRAD_BASE_H

#include <stddef.h>
#include <stdint.h>

/* Log lines go to stderr, one line each, prefixed with the level. */
void log_info(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void log_warn(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void log_error(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
/* Quiet mode drops info lines (used by `terrad simulate`, whose stdout is JSON). */
void log_set_quiet(int quiet);

/* Milliseconds from a monotonic clock. */
double time_now_ms(void);

/* A growing series of samples, for per-stage mean and p99. */
typedef struct stat_series {
    double *samples;
    size_t count, capacity;
} stat_series;

void stat_series_add(stat_series *s, double value);
double stat_series_mean(const stat_series *s);
double stat_series_percentile(const stat_series *s, double p); /* p in [0,100] */
void stat_series_free(stat_series *s);

/* Peak resident set size of this process in bytes (VmHWM), 0 if unknown. */
uint64_t proc_peak_rss_bytes(void);
/* Current resident set size in bytes (VmRSS), 0 if unknown. */
uint64_t proc_rss_bytes(void);

/* Error text carried out of a failing call: one line, names the cause. */
typedef struct error_text {
    char message[256];
} error_text;

void error_set(error_text *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#endif
