/*
 * metrics.c: the process-wide counters, gauges and histograms behind
 * GET /metrics.
 *
 * Every thread counts here: the websocket thread (bytes, messages, refusals),
 * the sim thread once per tick (tick and stage durations, Σh, active cells)
 * and the fan-out (frames, delta bytes). Counters and gauges are relaxed
 * atomics: a scrape needs each value to be a value that was true at some
 * moment, not a consistent cut across all of them, and relaxed updates cost
 * the tick nothing. Histograms hold several words that must agree (buckets,
 * sum, count), so each has a small mutex, held only for an increment.
 *
 * Durations arrive in milliseconds (what the tick measures) and leave in
 * seconds, the Prometheus base unit. Σh leaves as an exact integer: a double
 * would round it above 2^53, and volume conservation is checked bit for bit.
 */
#include "metrics/metrics.h"

#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "base/base.h"
#include "terrad_proto.h"

/* ---- histograms ---- */

#define HIST_MAX_BUCKETS 12

typedef struct histogram {
    pthread_mutex_t lock;
    int nbounds;                           /* finite upper bounds; +Inf is implicit */
    const double *bounds_ms;               /* ascending */
    const char *const *labels;             /* the same bounds in seconds, as printed */
    uint64_t counts[HIST_MAX_BUCKETS + 1]; /* per bucket, not cumulative; last is +Inf */
    double sum_ms;
    uint64_t count;
} histogram;

/* Tick durations: 60 Hz is 16.7 ms, so the buckets straddle one, two, four
 * and eight periods. */
static const double tick_bounds_ms[] = {0.5, 1, 2, 4, 8, 16, 33, 66, 133};
static const char *const tick_labels[] = {"0.0005", "0.001", "0.002", "0.004", "0.008",
                                          "0.016",  "0.033", "0.066", "0.133"};

/* Stages are fractions of a tick: finer buckets at the low end. */
static const double stage_bounds_ms[] = {0.05, 0.1, 0.25, 0.5, 1, 2, 4, 8, 16, 33};
static const char *const stage_labels[] = {"0.00005", "0.0001", "0.00025", "0.0005", "0.001",
                                           "0.002",   "0.004",  "0.008",   "0.016",  "0.033"};

/* Pose-to-delta latency spans network and one or two ticks. */
static const double latency_bounds_ms[] = {1, 2, 5, 10, 17, 33, 50, 100, 250, 500, 1000};
static const char *const latency_labels[] = {"0.001", "0.002", "0.005", "0.01", "0.017", "0.033",
                                             "0.05",  "0.1",   "0.25",  "0.5",  "1"};

/* Log fsyncs: from a page-cache flush on tmpfs to a slow disk. */
static const double fsync_bounds_ms[] = {0.05, 0.1, 0.25, 0.5, 1, 2, 5, 10, 25, 50, 100, 250};
static const char *const fsync_labels[] = {"0.00005", "0.0001", "0.00025", "0.0005",
                                           "0.001",   "0.002",  "0.005",   "0.01",
                                           "0.025",   "0.05",   "0.1",     "0.25"};

#define COUNT_OF(a) ((int)(sizeof(a) / sizeof((a)[0])))

static const char *const stage_names[] = {METRICS_STAGES};
#define STAGE_COUNT COUNT_OF(stage_names)
static const char *const memory_stage_names[] = {METRICS_MEMORY_STAGES};
#define MEMORY_STAGE_COUNT COUNT_OF(memory_stage_names)
static _Atomic uint64_t stage_memory[MEMORY_STAGE_COUNT];

static histogram tick_hist = {.lock = PTHREAD_MUTEX_INITIALIZER,
                              .nbounds = COUNT_OF(tick_bounds_ms),
                              .bounds_ms = tick_bounds_ms,
                              .labels = tick_labels};
static histogram latency_hist = {.lock = PTHREAD_MUTEX_INITIALIZER,
                                 .nbounds = COUNT_OF(latency_bounds_ms),
                                 .bounds_ms = latency_bounds_ms,
                                 .labels = latency_labels};
static histogram fsync_hist = {.lock = PTHREAD_MUTEX_INITIALIZER,
                               .nbounds = COUNT_OF(fsync_bounds_ms),
                               .bounds_ms = fsync_bounds_ms,
                               .labels = fsync_labels};
static histogram stage_hist[STAGE_COUNT];
static const char *const store_error_kinds[] = {METRICS_STORE_ERROR_KINDS};
#define STORE_ERROR_KINDS COUNT_OF(store_error_kinds)
static const char *const service_drop_reasons[] = {METRICS_SERVICE_DROP_REASONS};
#define SERVICE_DROP_REASONS COUNT_OF(service_drop_reasons)
static pthread_once_t stage_once = PTHREAD_ONCE_INIT;

static void stage_hist_init(void)
{
    for (int i = 0; i < STAGE_COUNT; i++) {
        pthread_mutex_init(&stage_hist[i].lock, NULL);
        stage_hist[i].nbounds = COUNT_OF(stage_bounds_ms);
        stage_hist[i].bounds_ms = stage_bounds_ms;
        stage_hist[i].labels = stage_labels;
    }
}

static void histogram_observe(histogram *hg, double ms)
{
    /* A NaN would poison the sum for the life of the process; a negative
     * duration is a clock hiccup. Neither is worth a sample. */
    if (!(ms >= 0) || isinf(ms))
        return;
    int b = 0;
    while (b < hg->nbounds && ms > hg->bounds_ms[b])
        b++;
    pthread_mutex_lock(&hg->lock);
    hg->counts[b]++;
    hg->sum_ms += ms;
    hg->count++;
    pthread_mutex_unlock(&hg->lock);
}

static void histogram_reset(histogram *hg)
{
    pthread_mutex_lock(&hg->lock);
    memset(hg->counts, 0, sizeof hg->counts);
    hg->sum_ms = 0;
    hg->count = 0;
    pthread_mutex_unlock(&hg->lock);
}

/* ---- counters and gauges ---- */

static atomic_uint_fast64_t bytes_in, bytes_out, messages_in, frames_out;
static atomic_uint_fast64_t frames_coalesced, frames_dropped, tick_overruns, refused_windows;
static atomic_uint_fast64_t snapshots_coalesced, snapshots_deferred, snapshots_dropped;
static atomic_uint_fast64_t budget_refusals;
static atomic_uint_fast64_t clients_stale, heights_refused, http_cut, tick_shed;
/* the GL backend's tile cache, copied from its own totals each tick */
static atomic_uint_fast64_t gpu_tile_uploads, gpu_tile_upload_bytes, gpu_tile_evictions;
static atomic_int_fast64_t gpu_tiles_resident;
static atomic_uint_fast64_t delta_raw, delta_compressed;
static atomic_uint_fast64_t footprint_frames, footprint_events, footprint_frames_dropped;
static atomic_uint_fast64_t refused[TERRAD_ERR_LAST + 1]; /* by wire error code; [0] unused */
static atomic_uint_fast64_t tick_now;
static atomic_int_fast64_t sim_threads_in_use;
static atomic_int_fast64_t volume, active_cells, colliders, clients;
static atomic_uint_fast64_t store_wal_bytes, store_durable_tick, store_compactions;
static atomic_uint_fast64_t store_errors[STORE_ERROR_KINDS];
static atomic_uint_fast64_t service_dropped[SERVICE_DROP_REASONS];
static atomic_int_fast64_t store_available, store_records_replayed, store_bytes_cut;
static atomic_int_fast64_t store_recovery_us, store_compaction_us;

#define ADD(v, n) atomic_fetch_add_explicit(&(v), (n), memory_order_relaxed)
#define SET(v, n) atomic_store_explicit(&(v), (n), memory_order_relaxed)
#define GET(v) atomic_load_explicit(&(v), memory_order_relaxed)

/* Memory parts: a short table of names, written rarely (once per tick with
 * the same names), so one mutex is simpler than anything lock-free. */
#define MEMORY_PARTS_MAX 32
#define MEMORY_PART_NAME 48

static pthread_mutex_t memory_lock = PTHREAD_MUTEX_INITIALIZER;
static struct {
    char name[MEMORY_PART_NAME];
    uint64_t bytes;
} memory_parts[MEMORY_PARTS_MAX];
static int memory_part_count;

void metrics_reset(void)
{
    pthread_once(&stage_once, stage_hist_init);
    metrics_auth_reset();
    SET(bytes_in, 0);
    SET(bytes_out, 0);
    SET(messages_in, 0);
    SET(frames_out, 0);
    SET(frames_coalesced, 0);
    SET(snapshots_coalesced, 0);
    SET(snapshots_deferred, 0);
    SET(snapshots_dropped, 0);
    SET(budget_refusals, 0);
    SET(clients_stale, 0);
    SET(heights_refused, 0);
    SET(http_cut, 0);
    SET(tick_shed, 0);
    SET(frames_dropped, 0);
    SET(tick_overruns, 0);
    SET(footprint_frames, 0);
    SET(footprint_events, 0);
    SET(footprint_frames_dropped, 0);
    SET(refused_windows, 0);
    SET(gpu_tile_uploads, 0);
    SET(gpu_tile_upload_bytes, 0);
    SET(gpu_tile_evictions, 0);
    SET(gpu_tiles_resident, 0);
    SET(delta_raw, 0);
    SET(delta_compressed, 0);
    for (int i = 0; i <= TERRAD_ERR_LAST; i++)
        SET(refused[i], 0);
    SET(tick_now, 0);
    SET(volume, 0);
    SET(active_cells, 0);
    SET(colliders, 0);
    SET(clients, 0);
    SET(store_wal_bytes, 0);
    SET(store_durable_tick, 0);
    SET(store_compactions, 0);
    for (int i = 0; i < STORE_ERROR_KINDS; i++)
        SET(store_errors[i], 0);
    for (int i = 0; i < SERVICE_DROP_REASONS; i++)
        SET(service_dropped[i], 0);
    SET(store_available, 0);
    SET(store_records_replayed, 0);
    SET(store_bytes_cut, 0);
    SET(store_recovery_us, 0);
    SET(store_compaction_us, 0);
    histogram_reset(&fsync_hist);
    histogram_reset(&tick_hist);
    histogram_reset(&latency_hist);
    for (int i = 0; i < STAGE_COUNT; i++)
        histogram_reset(&stage_hist[i]);
    pthread_mutex_lock(&memory_lock);
    memory_part_count = 0;
    pthread_mutex_unlock(&memory_lock);
    for (int i = 0; i < MEMORY_STAGE_COUNT; i++)
        SET(stage_memory[i], 0);
}

void metrics_set_stage_memory_bytes(const char *stage, uint64_t bytes)
{
    for (int i = 0; stage && i < MEMORY_STAGE_COUNT; i++) {
        if (strcmp(stage, memory_stage_names[i]) == 0) {
            SET(stage_memory[i], bytes);
            return;
        }
    }
}

void metrics_count_store_wal_bytes(uint64_t bytes)
{
    ADD(store_wal_bytes, bytes);
}

void metrics_observe_store_fsync_ms(double ms)
{
    histogram_observe(&fsync_hist, ms);
}

void metrics_set_store_durable_tick(uint64_t tick)
{
    SET(store_durable_tick, tick);
}

void metrics_count_store_compaction(double ms)
{
    ADD(store_compactions, 1);
    SET(store_compaction_us, (int64_t)(ms * 1000.0));
}

void metrics_count_store_error(const char *kind)
{
    for (int i = 0; i < STORE_ERROR_KINDS; i++)
        if (strcmp(kind, store_error_kinds[i]) == 0)
            ADD(store_errors[i], 1);
}

void metrics_count_service_dropped(const char *reason)
{
    for (int i = 0; i < SERVICE_DROP_REASONS; i++)
        if (strcmp(reason, service_drop_reasons[i]) == 0)
            ADD(service_dropped[i], 1);
}

void metrics_set_store_available(int available)
{
    SET(store_available, available ? 1 : 0);
}

void metrics_set_store_recovery(double ms, int64_t records_replayed, int64_t bytes_cut)
{
    SET(store_recovery_us, (int64_t)(ms * 1000.0));
    SET(store_records_replayed, records_replayed);
    SET(store_bytes_cut, bytes_cut);
}

void metrics_count_bytes_in(uint64_t n)
{
    ADD(bytes_in, n);
}

void metrics_count_bytes_out(uint64_t n)
{
    ADD(bytes_out, n);
}

void metrics_count_messages_in(uint64_t n)
{
    ADD(messages_in, n);
}

void metrics_count_frames_out(uint64_t n)
{
    ADD(frames_out, n);
}

void metrics_count_refused(int error_code)
{
    /* One series per wire error name keeps the label set bounded; a code
     * outside the table is our bug, not the client's, hence "internal". */
    if (error_code < TERRAD_ERR_FIRST || error_code > TERRAD_ERR_LAST)
        error_code = TERRAD_E_INTERNAL;
    ADD(refused[error_code], 1);
}

void metrics_count_snapshots_coalesced(uint64_t n)
{
    ADD(snapshots_coalesced, n);
}

void metrics_count_budget_refusal(void)
{
    ADD(budget_refusals, 1);
}

void metrics_count_snapshots_deferred(uint64_t n)
{
    ADD(snapshots_deferred, n);
}

void metrics_count_snapshots_dropped(uint64_t n)
{
    ADD(snapshots_dropped, n);
}

void metrics_count_frames_coalesced(uint64_t n)
{
    ADD(frames_coalesced, n);
}

void metrics_count_client_stale(void)
{
    ADD(clients_stale, 1);
}

void metrics_count_heights_refused(void)
{
    ADD(heights_refused, 1);
}

void metrics_count_http_cut(uint64_t n)
{
    ADD(http_cut, n);
}

void metrics_count_tick_shed(uint64_t colliders)
{
    ADD(tick_shed, colliders);
}

void metrics_count_frames_dropped(uint64_t n)
{
    ADD(frames_dropped, n);
}

void metrics_count_footprints_sent(uint64_t frames, uint64_t events)
{
    ADD(footprint_frames, frames);
    ADD(footprint_events, events);
}

void metrics_count_footprints_dropped(uint64_t frames)
{
    ADD(footprint_frames_dropped, frames);
}

void metrics_count_tick_overrun(void)
{
    ADD(tick_overruns, 1);
}

void metrics_set_gpu_tile_cache(uint64_t uploads, uint64_t upload_bytes, uint64_t evictions,
                                int64_t resident_tiles)
{
    SET(gpu_tile_uploads, uploads);
    SET(gpu_tile_upload_bytes, upload_bytes);
    SET(gpu_tile_evictions, evictions);
    SET(gpu_tiles_resident, resident_tiles);
}

void metrics_count_refused_windows(uint64_t n)
{
    ADD(refused_windows, n);
}

void metrics_count_delta_bytes(uint64_t raw_bytes, uint64_t compressed_bytes)
{
    ADD(delta_raw, raw_bytes);
    ADD(delta_compressed, compressed_bytes);
}

void metrics_observe_tick_ms(double ms)
{
    histogram_observe(&tick_hist, ms);
}

void metrics_observe_stage_ms(const char *stage, double ms)
{
    pthread_once(&stage_once, stage_hist_init);
    if (!stage)
        return;
    /* Unknown stage names are dropped rather than added: a label value made
     * up at run time would grow the series without bound. */
    for (int i = 0; i < STAGE_COUNT; i++) {
        if (strcmp(stage, stage_names[i]) == 0) {
            histogram_observe(&stage_hist[i], ms);
            return;
        }
    }
}

void metrics_observe_pose_to_delta_ms(double ms)
{
    histogram_observe(&latency_hist, ms);
}

void metrics_set_tick(uint64_t tick)
{
    SET(tick_now, tick);
}

void metrics_set_volume(int64_t v)
{
    SET(volume, v);
}

void metrics_set_active_cells(int64_t cells)
{
    SET(active_cells, cells);
}

void metrics_set_colliders(int64_t n)
{
    SET(colliders, n);
}

void metrics_set_clients(int64_t n)
{
    SET(clients, n);
}

void metrics_set_memory_bytes(const char *part, uint64_t bytes)
{
    if (!part || !*part)
        return;
    pthread_mutex_lock(&memory_lock);
    int i = 0;
    while (i < memory_part_count && strncmp(memory_parts[i].name, part, MEMORY_PART_NAME - 1) != 0)
        i++;
    if (i == memory_part_count) {
        if (memory_part_count == MEMORY_PARTS_MAX) { /* full: further parts are not shown */
            pthread_mutex_unlock(&memory_lock);
            return;
        }
        snprintf(memory_parts[i].name, sizeof memory_parts[i].name, "%s", part);
        memory_part_count++;
    }
    memory_parts[i].bytes = bytes;
    pthread_mutex_unlock(&memory_lock);
}

/* ---- exposition ---- */

typedef struct text {
    char *data;
    size_t len;
    int64_t cap;
    int failed;
} text;

static void text_printf(text *t, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

static void text_printf(text *t, const char *fmt, ...)
{
    if (t->failed)
        return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int n = vsnprintf(t->data + t->len, (size_t)t->cap - t->len, fmt, ap);
        va_end(ap);
        if (n < 0) {
            t->failed = 1;
            return;
        }
        if ((size_t)n < (size_t)t->cap - t->len) {
            t->len += (size_t)n;
            return;
        }
        if (array_grow((void **)&t->data, &t->cap, (int64_t)(t->len + (size_t)n + 1), 1) != 0) {
            t->failed = 1;
            return;
        }
    }
}

/* A label value as the text format wants it: backslash, double quote and
 * newline escaped. Written into out (bounded; long values are cut). */
static void escape_label(const char *in, char *out, size_t cap)
{
    size_t o = 0;
    for (; *in && o + 3 < cap; in++) {
        char c = *in;
        if (c == '\\' || c == '"') {
            out[o++] = '\\';
            out[o++] = c;
        } else if (c == '\n') {
            out[o++] = '\\';
            out[o++] = 'n';
        } else {
            out[o++] = c;
        }
    }
    out[o] = '\0';
}

static void header(text *t, const char *name, const char *type, const char *help)
{
    text_printf(t, "# HELP %s %s\n# TYPE %s %s\n", name, help, name, type);
}

static void counter(text *t, const char *name, const char *help, uint64_t v)
{
    header(t, name, "counter", help);
    text_printf(t, "%s %llu\n", name, (unsigned long long)v);
}

static void gauge_int(text *t, const char *name, const char *help, int64_t v)
{
    header(t, name, "gauge", help);
    text_printf(t, "%s %lld\n", name, (long long)v);
}

/* The samples of one histogram (no HELP/TYPE); labels is "" or `k="v",`. */
static void histogram_samples(text *t, const char *name, const char *labels, histogram *hg)
{
    uint64_t counts[HIST_MAX_BUCKETS + 1];
    pthread_mutex_lock(&hg->lock);
    memcpy(counts, hg->counts, sizeof counts);
    double sum_ms = hg->sum_ms;
    uint64_t count = hg->count;
    pthread_mutex_unlock(&hg->lock);
    uint64_t cumulative = 0;
    for (int b = 0; b < hg->nbounds; b++) {
        cumulative += counts[b];
        text_printf(t, "%s_bucket{%sle=\"%s\"} %llu\n", name, labels, hg->labels[b],
                    (unsigned long long)cumulative);
    }
    text_printf(t, "%s_bucket{%sle=\"+Inf\"} %llu\n", name, labels, (unsigned long long)count);
    /* Labels without the trailing comma for _sum and _count. */
    size_t n = strlen(labels);
    if (n) {
        text_printf(t, "%s_sum{%.*s} %.9g\n", name, (int)(n - 1), labels, sum_ms / 1000.0);
        text_printf(t, "%s_count{%.*s} %llu\n", name, (int)(n - 1), labels,
                    (unsigned long long)count);
    } else {
        text_printf(t, "%s_sum %.9g\n", name, sum_ms / 1000.0);
        text_printf(t, "%s_count %llu\n", name, (unsigned long long)count);
    }
}

/* Tick, stage and pose-to-delta histograms. */
static void render_timings(text *t)
{
    header(t, "terrad_tick_duration_seconds", "histogram",
           "Wall time of one simulation tick, all stages included.");
    histogram_samples(t, "terrad_tick_duration_seconds", "", &tick_hist);

    header(t, "terrad_stage_duration_seconds", "histogram",
           "Wall time of one stage of a tick, by stage.");
    for (int i = 0; i < STAGE_COUNT; i++) {
        char labels[64];
        snprintf(labels, sizeof labels, "stage=\"%s\",", stage_names[i]);
        histogram_samples(t, "terrad_stage_duration_seconds", labels, &stage_hist[i]);
    }

    header(t, "terrad_pose_to_delta_latency_seconds", "histogram",
           "Time from a pose batch's arrival to the delta frames of the tick that used it.");
    histogram_samples(t, "terrad_pose_to_delta_latency_seconds", "", &latency_hist);
}

/* The world, the clients and what went over the websocket. */
static void render_clients(text *t)
{
    gauge_int(t, "terrad_tick", "The last completed tick.", (int64_t)GET(tick_now));
    /* %lld of an int64: exact, unlike any double formatting above 2^53. */
    gauge_int(t, "terrad_volume_units", "Sum of all heights in height units (exact integer).",
              (int64_t)GET(volume));
    gauge_int(t, "terrad_active_cells", "Cells inside the last tick's active windows.",
              (int64_t)GET(active_cells));
    gauge_int(t, "terrad_colliders", "Live colliders.", (int64_t)GET(colliders));
    gauge_int(t, "terrad_clients", "Connected websocket clients.", (int64_t)GET(clients));

    counter(t, "terrad_bytes_in_total", "Websocket payload bytes received.", GET(bytes_in));
    counter(t, "terrad_bytes_out_total", "Websocket payload bytes sent.", GET(bytes_out));
    counter(t, "terrad_messages_in_total", "Websocket messages received.", GET(messages_in));
    counter(t, "terrad_frames_out_total", "Websocket frames sent.", GET(frames_out));

    uint64_t raw = GET(delta_raw), comp = GET(delta_compressed);
    counter(t, "terrad_delta_raw_bytes_total", "Delta payload bytes before compression.", raw);
    counter(t, "terrad_delta_compressed_bytes_total", "Delta payload bytes after compression.",
            comp);
    header(t, "terrad_delta_compression_ratio", "gauge",
           "Raw over compressed delta bytes over the process's life (0 before any delta).");
    text_printf(t, "terrad_delta_compression_ratio %.6g\n",
                comp ? (double)raw / (double)comp : 0.0);

    counter(t, "terrad_colliders_refused_budget_total",
            "collider_create refused by a client's max_active_cells or max_mesh_triangles.",
            GET(budget_refusals));
    counter(t, "terrad_snapshot_requests_coalesced_total",
            "Snapshot requests (subscribe, resync) answered by an identical pending one.",
            GET(snapshots_coalesced));
    counter(t, "terrad_snapshot_requests_deferred_total",
            "Snapshot requests left for a later tick by the per-tick snapshot budget.",
            GET(snapshots_deferred));
    counter(t, "terrad_snapshot_requests_dropped_total",
            "Snapshot requests never built because their client left.", GET(snapshots_dropped));
    counter(t, "terrad_frames_coalesced_total",
            "Delta frames replaced by a fresh snapshot for a slow client.", GET(frames_coalesced));
    counter(t, "terrad_frames_dropped_total", "Frames never sent (slow client or overflow).",
            GET(frames_dropped));
    counter(t, "terrad_clients_stale_total",
            "Clients switched to snapshots for being more than max_client_lag_ticks behind.",
            GET(clients_stale));
    counter(t, "terrad_http_heights_refused_total",
            "/v1/heights requests refused (429): their address had too many bytes in flight.",
            GET(heights_refused));
    counter(t, "terrad_http_connections_cut_total",
            "HTTP connections closed while sending their headers: past the header deadline, "
            "or to make room for a newer one past a connection limit.",
            GET(http_cut));
    header(t, "terrad_tick_shed_total", "counter",
           "Colliders that waited a tick: the tick's footprint cells were over max_tick_cells.");
    text_printf(t, "terrad_tick_shed_total{reason=\"max_tick_cells\"} %llu\n",
                (unsigned long long)GET(tick_shed));

    counter(t, "terrad_footprint_frames_total",
            "FOOTPRINTS frames queued to clients (decals model).", GET(footprint_frames));
    counter(t, "terrad_footprint_events_total", "Footprint events in those frames.",
            GET(footprint_events));
    counter(t, "terrad_footprint_frames_dropped_total",
            "FOOTPRINTS frames not sent to a slow client.", GET(footprint_frames_dropped));

    header(t, "terrad_refused_messages_total", "counter",
           "Client messages refused, by wire error name (proto/PROTOCOL.md).");
    for (int code = TERRAD_ERR_FIRST; code <= TERRAD_ERR_LAST; code++) {
        const char *name = terrad_err_name(code);
        char esc[64];
        escape_label(name ? name : "internal", esc, sizeof esc);
        text_printf(t, "terrad_refused_messages_total{reason=\"%s\"} %llu\n", esc,
                    (unsigned long long)GET(refused[code]));
    }
}

/* Overruns, refused windows and the GL tile cache. */
void metrics_set_sim_threads(int n)
{
    atomic_store(&sim_threads_in_use, n);
}

static void render_backend(text *t)
{
    gauge_int(
        t, "terrad_sim_threads",
        "Threads the CPU twin's stages run on (serve --threads; heights do not depend on it).",
        (int64_t)atomic_load(&sim_threads_in_use));
    counter(t, "terrad_tick_overruns_total", "Ticks that took longer than the tick period.",
            GET(tick_overruns));
    counter(t, "terrad_refused_windows_total",
            "Active windows refused because their heights would leave the height limits.",
            GET(refused_windows));
    counter(t, "terrad_gpu_tile_uploads_total",
            "World tiles uploaded into the GL backend's tile cache.", GET(gpu_tile_uploads));
    counter(t, "terrad_gpu_tile_upload_bytes_total", "Bytes of those uploads.",
            GET(gpu_tile_upload_bytes));
    counter(t, "terrad_gpu_tile_evictions_total",
            "Resident tiles the GL tile cache replaced by others (LRU).", GET(gpu_tile_evictions));
    gauge_int(t, "terrad_gpu_tiles_resident", "World tiles resident in the GL tile cache.",
              GET(gpu_tiles_resident));
}

/* The store (server/store). */
static void render_store(text *t)
{
    counter(t, "terrad_store_wal_bytes_total", "Bytes appended to the write-ahead log.",
            GET(store_wal_bytes));
    header(t, "terrad_store_fsync_duration_seconds", "histogram",
           "Wall time of one fdatasync of the write-ahead log.");
    histogram_samples(t, "terrad_store_fsync_duration_seconds", "", &fsync_hist);
    gauge_int(t, "terrad_store_durable_tick",
              "The last tick as durable as the durability policy promises.",
              (int64_t)GET(store_durable_tick));
    gauge_int(t, "terrad_store_available",
              "1 while ticks can be made durable; 0 while deformation is refused.",
              (int64_t)GET(store_available));
    counter(t, "terrad_store_compactions_total", "Log compactions into tile snapshots.",
            GET(store_compactions));
    header(t, "terrad_store_last_compaction_seconds", "gauge",
           "Wall time of the last compaction (its own thread).");
    text_printf(t, "terrad_store_last_compaction_seconds %.6f\n",
                (double)GET(store_compaction_us) / 1e6);
    header(t, "terrad_store_errors_total", "counter", "Storage errors, by kind.");
    for (int i = 0; i < STORE_ERROR_KINDS; i++)
        text_printf(t, "terrad_store_errors_total{kind=\"%s\"} %llu\n", store_error_kinds[i],
                    (unsigned long long)GET(store_errors[i]));
    header(t, "terrad_store_recovery_seconds", "gauge",
           "Wall time of the recovery at start (snapshots and log replay).");
    text_printf(t, "terrad_store_recovery_seconds %.6f\n", (double)GET(store_recovery_us) / 1e6);
    gauge_int(t, "terrad_store_recovery_records", "Log records replayed at start.",
              (int64_t)GET(store_records_replayed));
    gauge_int(t, "terrad_store_cut_tail_bytes",
              "Bytes of a torn or corrupt log tail cut at start (0: none).",
              (int64_t)GET(store_bytes_cut));
}

/* Work the service dropped (server/service). */
static void render_service(text *t)
{
    header(t, "terrad_service_dropped_total", "counter",
           "Work a tick could not do (a frame, snapshot, poses or command dropped), by reason.");
    for (int i = 0; i < SERVICE_DROP_REASONS; i++)
        text_printf(t, "terrad_service_dropped_total{reason=\"%s\"} %llu\n",
                    service_drop_reasons[i], (unsigned long long)GET(service_dropped[i]));
}

/* Memory by part and the models' scratch by stage. */
static void render_memory(text *t)
{
    header(t, "terrad_memory_bytes", "gauge", "Memory held by a part of the daemon, by part.");
    pthread_mutex_lock(&memory_lock);
    for (int i = 0; i < memory_part_count; i++) {
        char esc[2 * MEMORY_PART_NAME + 4];
        escape_label(memory_parts[i].name, esc, sizeof esc);
        text_printf(t, "terrad_memory_bytes{part=\"%s\"} %llu\n", esc,
                    (unsigned long long)memory_parts[i].bytes);
    }
    pthread_mutex_unlock(&memory_lock);

    header(t, "terrad_sim_scratch_bytes", "gauge",
           "Scratch memory the deformation models hold, by stage.");
    for (int i = 0; i < MEMORY_STAGE_COUNT; i++)
        text_printf(t, "terrad_sim_scratch_bytes{stage=\"%s\"} %llu\n", memory_stage_names[i],
                    (unsigned long long)GET(stage_memory[i]));
}

char *metrics_render(size_t *len)
{
    pthread_once(&stage_once, stage_hist_init);
    text t = {malloc(8192), 0, 8192, 0};
    if (!t.data)
        return NULL;
    render_timings(&t);
    render_clients(&t);
    render_backend(&t);
    render_store(&t);
    render_service(&t);
    render_memory(&t);
    char process[2048];
    if (metrics_auth_text(process, sizeof process) > 0)
        text_printf(&t, "%s", process);
    if (metrics_process_text(process, sizeof process) > 0)
        text_printf(&t, "%s", process);
    char *worlds = malloc(65536); /* 64 worlds x 8 families fit */
    if (worlds && metrics_worlds_text(worlds, 65536) > 0)
        text_printf(&t, "%s", worlds);
    free(worlds);
    if (t.failed) {
        free(t.data);
        return NULL;
    }
    if (len)
        *len = t.len;
    return t.data;
}
