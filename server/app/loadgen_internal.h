/*
 * loadgen_internal.h: the parts of `terrad loadgen` (app/loadgen.c) that talk HTTP to the daemon
 * (GET /v1/stats, /metrics, /v1/heights; app/loadgen_http.c) and print its report.
 */
#ifndef TERRAD_LOADGEN_INTERNAL_H
#define TERRAD_LOADGEN_INTERNAL_H

#include <stdint.h>
#include <stdio.h>

typedef struct lg_http {
    char host[256];
    int port;
} lg_http;

/* The server's counters at one moment. */
typedef struct lg_stats {
    uint64_t tick, overruns, frames_dropped;
    double tick_seconds, tick_count; /* terrad_tick_duration_seconds_sum and _count */
} lg_stats;

/* What `terrad loadgen` measured. */
typedef struct lg_report {
    long clients, wheels_per_client;
    double hz, drive_s, ticks_per_s;
    uint64_t ticks, overruns, frames_dropped, resyncs, poses_sent;
    uint64_t delta_bytes, delta_frames, changed_cells;
    int64_t lat_n;
    double p50_ms, p99_ms, max_ms;
    double tick_mean_ms; /* the server's mean tick time while driving */
    long mirrors_checked, mirrors_equal, failed_clients;
} lg_report;

/* url: "http://HOST:PORT" or NULL (ws_host, port 8080). */
int lg_http_init(lg_http *h, const char *url, const char *ws_host);
/* GET /v1/stats (tick, overruns) and /metrics (terrad_frames_dropped_total). */
int lg_http_stats(const lg_http *h, lg_stats *out);
/* GET /v1/heights of a region of world (?world=; "" the default) into out (w * h int32). */
int lg_http_heights(const lg_http *h, const char *world, int x, int y, int w, int hh, int32_t *out);
/* The table, or one JSON object. */
void lg_print_report(FILE *f, const lg_report *r, int json);

#endif
