/*
 * base.c: logging, monotonic time, timing series and memory readings shared
 * by every subsystem (see base.h), and base64 decoding.
 */
#include "base/base.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static int log_quiet;

void log_set_quiet(int quiet)
{
    log_quiet = quiet;
}

/* One line: an ISO-8601 UTC timestamp with milliseconds (so lines from
 * several threads and files can be put in order), the level, the message. */
static void log_line(const char *level, const char *fmt, va_list ap)
{
    char line[1024], stamp[32] = "";
    vsnprintf(line, sizeof line, fmt, ap);
    struct timespec ts;
    struct tm tm;
    clock_gettime(CLOCK_REALTIME, &ts);
    if (gmtime_r(&ts.tv_sec, &tm))
        strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%S", &tm);
    fprintf(stderr, "%s.%03dZ terrad %s: %s\n", stamp, (int)(ts.tv_nsec / 1000000), level, line);
}

void log_info(const char *fmt, ...)
{
    if (log_quiet)
        return;
    va_list ap;
    va_start(ap, fmt);
    log_line("info", fmt, ap);
    va_end(ap);
}

void log_warn(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    log_line("warn", fmt, ap);
    va_end(ap);
}

void log_error(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    log_line("error", fmt, ap);
    va_end(ap);
}

double time_now_ms(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec * 1e3 + (double)ts.tv_nsec * 1e-6;
}

struct timespec time_after_ms(clockid_t clock, double ms)
{
    struct timespec t;
    clock_gettime(clock, &t);
    long long ns = (long long)t.tv_nsec + llround(ms * 1e6);
    long long sec = ns / 1000000000LL, rest = ns % 1000000000LL;
    if (rest < 0) { /* a moment in the past: tv_nsec stays in [0, 1e9) */
        sec--;
        rest += 1000000000LL;
    }
    t.tv_sec += (time_t)sec;
    t.tv_nsec = (long)rest;
    return t;
}

void stat_series_add(stat_series *s, double value)
{
    if (s->count == s->capacity) {
        size_t cap = s->capacity ? s->capacity * 2 : 256;
        double *grown = realloc(s->samples, cap * sizeof *grown);
        if (!grown)
            return; /* a lost timing sample is not worth failing a tick */
        s->samples = grown;
        s->capacity = cap;
    }
    s->samples[s->count++] = value;
}

double stat_series_mean(const stat_series *s)
{
    if (!s->count)
        return 0.0;
    double sum = 0.0;
    for (size_t i = 0; i < s->count; i++)
        sum += s->samples[i];
    return sum / (double)s->count;
}

static int compare_doubles(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

double stat_series_percentile(const stat_series *s, double p)
{
    if (!s->count)
        return 0.0;
    double *sorted = malloc(s->count * sizeof *sorted);
    if (!sorted)
        return 0.0;
    memcpy(sorted, s->samples, s->count * sizeof *sorted);
    qsort(sorted, s->count, sizeof *sorted, compare_doubles);
    /* nearest-rank percentile */
    size_t rank = (size_t)ceil(p / 100.0 * (double)s->count);
    if (rank < 1)
        rank = 1;
    if (rank > s->count)
        rank = s->count;
    double v = sorted[rank - 1];
    free(sorted);
    return v;
}

void stat_series_free(stat_series *s)
{
    free(s->samples);
    s->samples = NULL;
    s->count = s->capacity = 0;
}

static uint64_t proc_status_kib(const char *key)
{
    FILE *f = fopen("/proc/self/status", "r");
    if (!f)
        return 0;
    char line[256];
    uint64_t kib = 0;
    size_t keylen = strlen(key);
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, key, keylen) == 0) {
            kib = strtoull(line + keylen, NULL, 10);
            break;
        }
    }
    fclose(f);
    return kib * 1024u;
}

uint64_t proc_peak_rss_bytes(void)
{
    return proc_status_kib("VmHWM:");
}

void error_set(error_text *err, const char *fmt, ...)
{
    if (!err)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err->message, sizeof err->message, fmt, ap);
    va_end(ap);
}

void error_prefix(error_text *err, const char *prefix, const char *sep)
{
    if (!err)
        return;
    char inner[sizeof err->message];
    snprintf(inner, sizeof inner, "%s", err->message);
    error_set(err, "%s%s%s", prefix, sep, inner);
}

int64_t base64_decode(const char *in, uint8_t *out)
{
    int64_t n = 0;
    uint32_t acc = 0;
    int bits = 0;
    for (const char *p = in; *p && *p != '='; p++) {
        int v = *p >= 'A' && *p <= 'Z'   ? *p - 'A'
                : *p >= 'a' && *p <= 'z' ? *p - 'a' + 26
                : *p >= '0' && *p <= '9' ? *p - '0' + 52
                : *p == '+'              ? 62
                : *p == '/'              ? 63
                                         : -1;
        if (v < 0)
            return -1;
        acc = (acc << 6) | (uint32_t)v;
        bits += 6;
        if (bits >= 8) {
            bits -= 8;
            out[n++] = (uint8_t)(acc >> bits);
        }
    }
    return n;
}
