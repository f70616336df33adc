/*
 * metrics.c: the process-wide counters, gauges and histograms behind GET /metrics.
 *
 * Every thread counts here: the websocket thread (bytes, messages, refusals),
 * the sim thread once per tick (tick and stage durations, Σh, active cells)
 * and the fan-out (frames, delta bytes). Counters and gauges are relaxed
 * atomics: a scrape needs each value to be a value that was true at some
 * moment, not a consistent cut across all of them, and relaxed updates cost
 * the tick nothing. Histograms hold several words that must agree (buckets,
 * sum, count), so each has a small mutex, held only for an increment.
 *
 * Every family is one row of one list (METRIC_FAMILIES: name, type, help,
 * label), from which both the slot enum and the table `families` are made:
 * metrics_reset zeroes the slots, the update functions write them,
 * metrics_render walks the rows in order. Families with files of their
 * own: metrics_worlds.c, _auth, _process, _room, _edits, _steps, _cluster.
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

static const char *refused_names[TERRAD_ERR_LAST - TERRAD_ERR_FIRST + 1];

/* Once: the stage histograms' locks and bounds, the wire error names. */
static void stage_hist_init(void)
{
    for (int code = TERRAD_ERR_FIRST; code <= TERRAD_ERR_LAST; code++) {
        const char *name = terrad_err_name(code);
        refused_names[code - TERRAD_ERR_FIRST] = name ? name : "internal";
    }
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

/* ---- the table: every family /metrics shows ---- */

/* A family's values live in one array of relaxed atomics, indexed by slot: a
 * scalar has one slot, a labelled family one per label value. METRIC_FAMILIES
 * is every family, once, in the order /metrics shows them; the slot enum and
 * the family table are both made from it, so a new metric is one row here
 * (and the update function that writes its slot). metrics_reset and
 * metrics_render walk the table. A row is one of:
 *   SCALAR(ID, name, kind, help): one series, in slot S_ID;
 *   LABELLED(ID, name, kind, label, values, count, help): count series, one
 *     per label value, in the slots from S_ID on;
 *   FAMILY(.field = value, ...): a family with no slots of its own, written
 *     out as its table row (the histograms, the ratio, the memory parts). */
#define METRIC_FAMILIES(SCALAR, LABELLED, FAMILY)                                                  \
    FAMILY(.name = "terrad_tick_duration_seconds", .kind = F_HISTOGRAM,                            \
           .help = "Wall time of one simulation tick up to its publication: every stage, not "     \
                   "the frames' hand-over or the height reads served after it.",                   \
           .hist = &tick_hist)                                                                     \
    FAMILY(.name = "terrad_stage_duration_seconds", .kind = F_HISTOGRAM,                           \
           .help = "Wall time of one stage of a tick, by stage.", .label = "stage",                \
           .label_values = stage_names, .series = STAGE_COUNT, .hist = stage_hist)                 \
    FAMILY(.name = "terrad_pose_to_delta_latency_seconds", .kind = F_HISTOGRAM,                    \
           .help =                                                                                 \
               "Time from a pose batch's arrival to the delta frames of the tick that used it.",   \
           .hist = &latency_hist)                                                                  \
    /* the world, the clients and what went over the websocket */                                  \
    SCALAR(TICK, "terrad_tick", F_GAUGE, "The last completed tick.")                               \
    /* %lld of an int64: exact, unlike any double formatting above 2^53. */                        \
    SCALAR(VOLUME, "terrad_volume_units", F_GAUGE,                                                 \
           "Sum of all heights in height units (exact integer).")                                  \
    SCALAR(ACTIVE_CELLS, "terrad_active_cells", F_GAUGE,                                           \
           "Cells inside the last tick's active windows.")                                         \
    SCALAR(COLLIDERS, "terrad_colliders", F_GAUGE, "Live colliders.")                              \
    SCALAR(CLIENTS, "terrad_clients", F_GAUGE, "Connected websocket clients.")                     \
    SCALAR(BYTES_IN, "terrad_bytes_in_total", F_COUNTER, "Websocket payload bytes received.")      \
    SCALAR(BYTES_OUT, "terrad_bytes_out_total", F_COUNTER, "Websocket payload bytes sent.")        \
    SCALAR(MESSAGES_IN, "terrad_messages_in_total", F_COUNTER, "Websocket messages received.")     \
    SCALAR(FRAMES_OUT, "terrad_frames_out_total", F_COUNTER, "Websocket frames sent.")             \
    SCALAR(DELTA_RAW, "terrad_delta_raw_bytes_total", F_COUNTER,                                   \
           "Delta payload bytes before compression.")                                              \
    SCALAR(DELTA_COMPRESSED, "terrad_delta_compressed_bytes_total", F_COUNTER,                     \
           "Delta payload bytes after compression.")                                               \
    FAMILY(.name = "terrad_delta_compression_ratio", .kind = F_RATIO,                              \
           .help =                                                                                 \
               "Raw over compressed delta bytes over the process's life (0 before any delta).",    \
           .slot = S_DELTA_RAW, .slot2 = S_DELTA_COMPRESSED)                                       \
    SCALAR(BUDGET_REFUSALS, "terrad_colliders_refused_budget_total", F_COUNTER,                    \
           "collider_create refused by a client's max_active_cells or max_mesh_triangles.")        \
    SCALAR(SNAPSHOTS_COALESCED, "terrad_snapshot_requests_coalesced_total", F_COUNTER,             \
           "Snapshot requests (subscribe, resync) answered by an identical pending one.")          \
    SCALAR(SNAPSHOTS_DEFERRED, "terrad_snapshot_requests_deferred_total", F_COUNTER,               \
           "Snapshot requests left for a later tick by the per-tick snapshot budget.")             \
    SCALAR(SNAPSHOTS_DROPPED, "terrad_snapshot_requests_dropped_total", F_COUNTER,                 \
           "Snapshot requests never built because their client left.")                             \
    SCALAR(FRAMES_COALESCED, "terrad_frames_coalesced_total", F_COUNTER,                           \
           "Delta frames replaced by a fresh snapshot for a slow client.")                         \
    SCALAR(FRAMES_DROPPED, "terrad_frames_dropped_total", F_COUNTER,                               \
           "Frames never sent (slow client or overflow).")                                         \
    SCALAR(CLIENTS_STALE, "terrad_clients_stale_total", F_COUNTER,                                 \
           "Clients switched to snapshots for being more than max_client_lag_ticks behind.")       \
    SCALAR(BUDGET_BYTES, "terrad_budget_bytes_total", F_COUNTER,                                   \
           "Bytes queued to clients with a bandwidth budget (websocket headers included).")        \
    SCALAR(BUDGET_COALESCED, "terrad_budget_deltas_coalesced_total", F_COUNTER,                    \
           "Tile deltas folded into a budgeted client's pending tiles, sent later as one.")        \
    SCALAR(BUDGET_OVERRUNS, "terrad_budget_overruns_total", F_COUNTER,                             \
           "Frames that took a budgeted client's last second past its budget (replies and "        \
           "status frames, which are never held, or a piece larger than the budget).")             \
    SCALAR(HEIGHTS_REFUSED, "terrad_http_heights_refused_total", F_COUNTER,                        \
           "/v1/heights requests refused (429): their address had too many bytes in flight.")      \
    SCALAR(HTTP_CUT, "terrad_http_connections_cut_total", F_COUNTER,                               \
           "HTTP connections closed while sending their headers: past the header deadline, "       \
           "or to make room for a newer one past a connection limit.")                             \
    LABELLED(TICK_SHED, "terrad_tick_shed_total", F_COUNTER, "reason", shed_reasons, 1,            \
             "Colliders that waited a tick: the tick's footprint cells were over max_tick_cells.") \
    SCALAR(FOOTPRINT_FRAMES, "terrad_footprint_frames_total", F_COUNTER,                           \
           "FOOTPRINTS frames queued to clients (decals model).")                                  \
    SCALAR(FOOTPRINT_EVENTS, "terrad_footprint_events_total", F_COUNTER,                           \
           "Footprint events in those frames.")                                                    \
    SCALAR(FOOTPRINT_FRAMES_DROPPED, "terrad_footprint_frames_dropped_total", F_COUNTER,           \
           "FOOTPRINTS frames not sent to a slow client.")                                         \
    LABELLED(REFUSED, "terrad_refused_messages_total", F_COUNTER, "reason", refused_names,         \
             TERRAD_ERR_LAST - TERRAD_ERR_FIRST + 1,                                               \
             "Client messages refused, by wire error name (proto/PROTOCOL.md).")                   \
    /* the backend: threads, overruns, refused windows and the GL tile cache */                    \
    SCALAR(SIM_THREADS, "terrad_sim_threads", F_GAUGE,                                             \
           "Threads the CPU twin's stages run on (serve --threads; heights do not depend on it).") \
    SCALAR(TICK_OVERRUNS, "terrad_tick_overruns_total", F_COUNTER,                                 \
           "Ticks that took longer than the tick period.")                                         \
    SCALAR(REFUSED_WINDOWS, "terrad_refused_windows_total", F_COUNTER,                             \
           "Active windows refused because their heights would leave the height limits.")          \
    SCALAR(GPU_TILE_UPLOADS, "terrad_gpu_tile_uploads_total", F_COUNTER,                           \
           "World tiles uploaded into the GL backend's tile cache.")                               \
    SCALAR(GPU_TILE_UPLOAD_BYTES, "terrad_gpu_tile_upload_bytes_total", F_COUNTER,                 \
           "Bytes of those uploads.")                                                              \
    SCALAR(GPU_TILE_EVICTIONS, "terrad_gpu_tile_evictions_total", F_COUNTER,                       \
           "Resident tiles the GL tile cache replaced by others (LRU).")                           \
    SCALAR(GPU_TILES_RESIDENT, "terrad_gpu_tiles_resident", F_GAUGE,                               \
           "World tiles resident in the GL tile cache.")                                           \
    /* the store (server/store) */                                                                 \
    SCALAR(STORE_WAL_BYTES, "terrad_store_wal_bytes_total", F_COUNTER,                             \
           "Bytes appended to the write-ahead log.")                                               \
    FAMILY(.name = "terrad_store_fsync_duration_seconds", .kind = F_HISTOGRAM,                     \
           .help = "Wall time of one fdatasync of the write-ahead log.", .hist = &fsync_hist)      \
    SCALAR(STORE_DURABLE_TICK, "terrad_store_durable_tick", F_GAUGE,                               \
           "The last tick as durable as the durability policy promises.")                          \
    SCALAR(STORE_AVAILABLE, "terrad_store_available", F_GAUGE,                                     \
           "1 while ticks can be made durable; 0 while deformation is refused.")                   \
    SCALAR(STORE_COMPACTIONS, "terrad_store_compactions_total", F_COUNTER,                         \
           "Log compactions into tile snapshots.")                                                 \
    SCALAR(STORE_COMPACTION_US, "terrad_store_last_compaction_seconds", F_SECONDS,                 \
           "Wall time of the last compaction (its own thread).")                                   \
    LABELLED(STORE_ERRORS, "terrad_store_errors_total", F_COUNTER, "kind", store_error_kinds,      \
             STORE_ERROR_KINDS, "Storage errors, by kind.")                                        \
    SCALAR(STORE_RECOVERY_US, "terrad_store_recovery_seconds", F_SECONDS,                          \
           "Wall time of the recovery at start (snapshots and log replay).")                       \
    SCALAR(STORE_RECORDS_REPLAYED, "terrad_store_recovery_records", F_GAUGE,                       \
           "Log records replayed at start.")                                                       \
    SCALAR(STORE_BYTES_CUT, "terrad_store_cut_tail_bytes", F_GAUGE,                                \
           "Bytes of a torn or corrupt log tail cut at start (0: none).")                          \
    /* work the service dropped (server/service) */                                                \
    LABELLED(SERVICE_DROPPED, "terrad_service_dropped_total", F_COUNTER, "reason",                 \
             service_drop_reasons, SERVICE_DROP_REASONS,                                           \
             "Work a tick could not do (a frame, snapshot, poses or command dropped), by reason.") \
    /* memory by part and the models' scratch by stage */                                          \
    FAMILY(.name = "terrad_memory_bytes", .kind = F_PARTS,                                         \
           .help = "Memory held by a part of the daemon, by part.", .label = "part", .series = 1)  \
    LABELLED(SCRATCH, "terrad_sim_scratch_bytes", F_GAUGE, "stage", memory_stage_names,            \
             MEMORY_STAGE_COUNT, "Scratch memory the deformation models hold, by stage.")

/* The slots: S_ID for a scalar; S_ID to S_ID_LAST for a labelled family. */
#define SLOT_SCALAR(id, ...) S_##id,
#define SLOT_LABELLED(id, name, kind, label, values, count, help)                                  \
    S_##id, S_##id##_LAST = S_##id - 1 + (count),
#define SLOT_NONE(...)
enum slot { METRIC_FAMILIES(SLOT_SCALAR, SLOT_LABELLED, SLOT_NONE) S_COUNT };

/* Gauges are stored as the bits of an int64, counters as a uint64. */
static atomic_uint_fast64_t value[S_COUNT];

#define ADD(s, n) atomic_fetch_add_explicit(&value[s], (uint64_t)(n), memory_order_relaxed)
#define SET(s, n) atomic_store_explicit(&value[s], (uint64_t)(n), memory_order_relaxed)
#define GET(s) atomic_load_explicit(&value[s], memory_order_relaxed)

typedef enum family_kind {
    F_COUNTER,
    F_GAUGE,
    F_SECONDS,   /* a gauge kept in microseconds, shown in seconds */
    F_RATIO,     /* a gauge: slot over slot2 (0 while slot2 is 0) */
    F_HISTOGRAM, /* hist[0..series) */
    F_PARTS,     /* the memory-part table (its own mutex) */
} family_kind;

typedef struct family {
    const char *name;
    family_kind kind;
    const char *help;
    int slot, slot2;
    const char *label;               /* NULL: one unlabelled series */
    const char *const *label_values; /* the label's values, one per series */
    int series;                      /* with a label: how many */
    histogram *hist;                 /* F_HISTOGRAM */
} family;

static const char *const shed_reasons[] = {"max_tick_cells"};

#define ROW_FAMILY(...) {__VA_ARGS__},
#define ROW_SCALAR(id, n, k, h) ROW_FAMILY(.name = n, .kind = k, .help = h, .slot = S_##id)
#define ROW_LABELLED(id, n, k, l, v, count, h)                                                     \
    ROW_FAMILY(.name = n, .kind = k, .help = h, .slot = S_##id, .label = l, .label_values = v,     \
               .series = count)
static const family families[] = {METRIC_FAMILIES(ROW_SCALAR, ROW_LABELLED, ROW_FAMILY)};

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
    metrics_edits_reset();
    metrics_room_reset();
    metrics_steps_reset();
    metrics_desync_reset();
    metrics_spectate_reset();
    metrics_cluster_reset();
    for (int i = 0; i < S_COUNT; i++)
        SET(i, 0);
    for (int f = 0; f < COUNT_OF(families); f++)
        for (int i = 0;
             families[f].kind == F_HISTOGRAM && i < (families[f].label ? families[f].series : 1);
             i++)
            histogram_reset(&families[f].hist[i]);
    pthread_mutex_lock(&memory_lock);
    memory_part_count = 0;
    pthread_mutex_unlock(&memory_lock);
}

/* The slot of name among a labelled family's values, or -1 (an unknown name
 * is dropped rather than added: a label value made up at run time would grow
 * the series without bound). */
static int slot_of(int first, const char *const *names, int count, const char *name)
{
    int i = metrics_label_index(names, count, name);
    return i < 0 ? -1 : first + i;
}

void metrics_set_stage_memory_bytes(const char *stage, uint64_t bytes)
{
    int s = slot_of(S_SCRATCH, memory_stage_names, MEMORY_STAGE_COUNT, stage);
    if (s >= 0)
        SET(s, bytes);
}

void metrics_count_store_wal_bytes(uint64_t bytes)
{
    ADD(S_STORE_WAL_BYTES, bytes);
}

void metrics_observe_store_fsync_ms(double ms)
{
    histogram_observe(&fsync_hist, ms);
}

void metrics_set_store_durable_tick(uint64_t tick)
{
    SET(S_STORE_DURABLE_TICK, tick);
}

void metrics_count_store_compaction(double ms)
{
    ADD(S_STORE_COMPACTIONS, 1);
    SET(S_STORE_COMPACTION_US, (int64_t)(ms * 1000.0));
}

void metrics_count_store_error(const char *kind)
{
    int s = slot_of(S_STORE_ERRORS, store_error_kinds, STORE_ERROR_KINDS, kind);
    if (s >= 0)
        ADD(s, 1);
}

void metrics_count_service_dropped(const char *reason)
{
    int s = slot_of(S_SERVICE_DROPPED, service_drop_reasons, SERVICE_DROP_REASONS, reason);
    if (s >= 0)
        ADD(s, 1);
}

void metrics_set_store_available(int available)
{
    SET(S_STORE_AVAILABLE, available ? 1 : 0);
}

void metrics_set_store_recovery(double ms, int64_t records_replayed, int64_t bytes_cut)
{
    SET(S_STORE_RECOVERY_US, (int64_t)(ms * 1000.0));
    SET(S_STORE_RECORDS_REPLAYED, records_replayed);
    SET(S_STORE_BYTES_CUT, bytes_cut);
}

/* A counter's one-line adder: void NAME(uint64_t n). */
#define COUNTER(name, slot)                                                                        \
    void name(uint64_t n)                                                                          \
    {                                                                                              \
        ADD(slot, n);                                                                              \
    }
COUNTER(metrics_count_bytes_in, S_BYTES_IN)
COUNTER(metrics_count_bytes_out, S_BYTES_OUT)
COUNTER(metrics_count_messages_in, S_MESSAGES_IN)
COUNTER(metrics_count_frames_out, S_FRAMES_OUT)
COUNTER(metrics_count_snapshots_coalesced, S_SNAPSHOTS_COALESCED)
COUNTER(metrics_count_snapshots_deferred, S_SNAPSHOTS_DEFERRED)
COUNTER(metrics_count_snapshots_dropped, S_SNAPSHOTS_DROPPED)
COUNTER(metrics_count_frames_coalesced, S_FRAMES_COALESCED)
COUNTER(metrics_count_http_cut, S_HTTP_CUT)
COUNTER(metrics_count_frames_dropped, S_FRAMES_DROPPED)

void metrics_count_refused(int error_code)
{
    /* One series per wire error name keeps the label set bounded; a code
     * outside the table is our bug, not the client's, hence "internal". */
    if (error_code < TERRAD_ERR_FIRST || error_code > TERRAD_ERR_LAST)
        error_code = TERRAD_E_INTERNAL;
    ADD(S_REFUSED + error_code - TERRAD_ERR_FIRST, 1);
}

void metrics_count_budget_refusal(void)
{
    ADD(S_BUDGET_REFUSALS, 1);
}

void metrics_count_client_stale(void)
{
    ADD(S_CLIENTS_STALE, 1);
}

void metrics_count_budget(uint64_t bytes, uint64_t coalesced, uint64_t overruns)
{
    ADD(S_BUDGET_BYTES, bytes);
    ADD(S_BUDGET_COALESCED, coalesced);
    ADD(S_BUDGET_OVERRUNS, overruns);
}

void metrics_count_heights_refused(void)
{
    ADD(S_HEIGHTS_REFUSED, 1);
}

void metrics_count_tick_shed(uint64_t colliders)
{
    ADD(S_TICK_SHED, colliders);
}

void metrics_count_footprints_sent(uint64_t frames, uint64_t events)
{
    ADD(S_FOOTPRINT_FRAMES, frames);
    ADD(S_FOOTPRINT_EVENTS, events);
}

void metrics_count_footprints_dropped(uint64_t frames)
{
    ADD(S_FOOTPRINT_FRAMES_DROPPED, frames);
}

void metrics_count_tick_overrun(void)
{
    ADD(S_TICK_OVERRUNS, 1);
}

void metrics_set_gpu_tile_cache(uint64_t uploads, uint64_t upload_bytes, uint64_t evictions,
                                int64_t resident_tiles)
{
    SET(S_GPU_TILE_UPLOADS, uploads);
    SET(S_GPU_TILE_UPLOAD_BYTES, upload_bytes);
    SET(S_GPU_TILE_EVICTIONS, evictions);
    SET(S_GPU_TILES_RESIDENT, resident_tiles);
}

void metrics_count_refused_windows(uint64_t n)
{
    ADD(S_REFUSED_WINDOWS, n);
}

void metrics_count_delta_bytes(uint64_t raw_bytes, uint64_t compressed_bytes)
{
    ADD(S_DELTA_RAW, raw_bytes);
    ADD(S_DELTA_COMPRESSED, compressed_bytes);
}

void metrics_observe_tick_ms(double ms)
{
    histogram_observe(&tick_hist, ms);
}

void metrics_observe_stage_ms(const char *stage, double ms)
{
    pthread_once(&stage_once, stage_hist_init);
    int s = slot_of(0, stage_names, STAGE_COUNT, stage);
    if (s >= 0)
        histogram_observe(&stage_hist[s], ms);
}

void metrics_observe_pose_to_delta_ms(double ms)
{
    histogram_observe(&latency_hist, ms);
}

void metrics_set_tick(uint64_t tick)
{
    SET(S_TICK, tick);
}

void metrics_set_volume(int64_t v)
{
    SET(S_VOLUME, v);
}

void metrics_set_active_cells(int64_t cells)
{
    SET(S_ACTIVE_CELLS, cells);
}

void metrics_set_colliders(int64_t n)
{
    SET(S_COLLIDERS, n);
}

void metrics_set_clients(int64_t n)
{
    SET(S_CLIENTS, n);
}

void metrics_set_sim_threads(int n)
{
    SET(S_SIM_THREADS, n);
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

static void render_parts(text *t)
{
    pthread_mutex_lock(&memory_lock);
    for (int i = 0; i < memory_part_count; i++) {
        char esc[2 * MEMORY_PART_NAME + 4];
        escape_label(memory_parts[i].name, esc, sizeof esc);
        text_printf(t, "terrad_memory_bytes{part=\"%s\"} %llu\n", esc,
                    (unsigned long long)memory_parts[i].bytes);
    }
    pthread_mutex_unlock(&memory_lock);
}

/* One family: HELP and TYPE, then its samples. Gauges print as signed
 * integers (%lld of an int64 is exact, unlike a double above 2^53). */
static void render_family(text *t, const family *f)
{
    static const char *const types[] = {"counter", "gauge", "gauge", "gauge", "histogram", "gauge"};
    header(t, f->name, types[f->kind], f->help);
    int series = f->label ? f->series : 1;
    for (int i = 0; i < series; i++) {
        char labels[160] = "";
        if (f->label && f->kind != F_PARTS) {
            char esc[128];
            escape_label(f->label_values[i], esc, sizeof esc);
            snprintf(labels, sizeof labels, "%s=\"%s\",", f->label, esc);
        }
        int n = (int)strlen(labels);
        char head[256]; /* name{labels}, without the histograms' trailing comma */
        snprintf(head, sizeof head, "%s%s%.*s%s", f->name, n ? "{" : "", n ? n - 1 : 0, labels,
                 n ? "}" : "");
        uint64_t v = GET(f->slot + i);
        switch (f->kind) {
        case F_COUNTER:
            text_printf(t, "%s %llu\n", head, (unsigned long long)v);
            break;
        case F_GAUGE:
            text_printf(t, "%s %lld\n", head, (long long)(int64_t)v);
            break;
        case F_SECONDS:
            text_printf(t, "%s %.6f\n", f->name, (double)(int64_t)v / 1e6);
            break;
        case F_RATIO: {
            uint64_t below = GET(f->slot2);
            text_printf(t, "%s %.6g\n", f->name, below ? (double)v / (double)below : 0.0);
            break;
        }
        case F_HISTOGRAM:
            histogram_samples(t, f->name, labels, &f->hist[i]);
            break;
        case F_PARTS:
            render_parts(t);
            break;
        }
    }
}

char *metrics_render(size_t *len)
{
    pthread_once(&stage_once, stage_hist_init);
    text t = {malloc(8192), 0, 8192, 0};
    if (!t.data)
        return NULL;
    for (int f = 0; f < COUNT_OF(families); f++)
        render_family(&t, &families[f]);
    char process[4096];
    /* the families rendered by the other files of metrics/, in this order */
    int (*const parts[])(char *, size_t) = {
        metrics_auth_text,    metrics_edits_text,  metrics_room_text,     metrics_steps_text,
        metrics_cluster_text, metrics_desync_text, metrics_spectate_text, metrics_process_text};
    for (size_t i = 0; i < sizeof parts / sizeof parts[0]; i++)
        if (parts[i](process, sizeof process) > 0)
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
