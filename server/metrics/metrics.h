/*
 * metrics: the daemon's process-wide counters, gauges and histograms, and
 * their Prometheus text exposition for GET /metrics. Any thread may count;
 * every update is a relaxed atomic (or a short lock for histograms), so
 * counting never stalls a tick or the network.
 */
#ifndef TERRAD_METRICS_H
#define TERRAD_METRICS_H

#include <stddef.h>
#include <stdint.h>

#include "base/base.h"

/* Stage names for metrics_observe_stage_ms: the sim's stages (base.h's
 * list, the simulate report's names), then the engine's own two. */
#define METRICS_STAGES SIM_STAGE_LIST(SIM_STAGE_NAME) "gather_scatter", "model"

void metrics_reset(void); /* zero everything (tests) */

/* terrad_build_info and the standard process_* metrics (CPU, start time,
 * memory, file descriptors, from /proc/self) as exposition text into out.
 * Its length, or -1 when it does not fit. metrics_render includes it. */
int metrics_process_text(char *out, size_t cap);

void metrics_count_bytes_in(uint64_t bytes);
void metrics_count_bytes_out(uint64_t bytes);
void metrics_count_messages_in(uint64_t n);
void metrics_count_frames_out(uint64_t n);
/* A refused client message, by its wire error code (proto/PROTOCOL.md). */
void metrics_count_refused(int error_code);
/* snapshot requests (service): coalesced into an identical pending one,
 * deferred to a later tick by the per-tick budget, dropped (client gone) */
void metrics_count_snapshots_coalesced(uint64_t n);
/* a collider_create refused by max_active_cells or max_mesh_triangles (net) */
void metrics_count_budget_refusal(void);
void metrics_count_snapshots_deferred(uint64_t n);
void metrics_count_snapshots_dropped(uint64_t n);
void metrics_count_frames_coalesced(uint64_t n); /* replaced by a snapshot for a slow client */
void metrics_count_frames_dropped(uint64_t n);   /* never sent (slow client, overflow) */
/* a client switched to snapshots for being more than max_client_lag_ticks behind (net) */
void metrics_count_client_stale(void);
/* bandwidth budgets (net/net_budget.c): bytes queued to budgeted clients,
 * deltas folded into their pending tiles, frames past a client's budget */
void metrics_count_budget(uint64_t bytes, uint64_t coalesced, uint64_t overruns);
/* a /v1/heights request refused: its address (or everyone) has too many bytes in flight (http) */
void metrics_count_heights_refused(void);
/* HTTP connections cut for sending no whole request within the header deadline (http) */
void metrics_count_http_cut(uint64_t n);
/* An HTTP request answered 503 for want of a connection slot: 0 past the
 * per-address limit, 1 past the overall one (terrad_http_refused_total). */
void metrics_count_http_refused(int reason);
/* An HTTP request answered 400, the parameter named in the answer (terrad_http_bad_requests_total).
 */
void metrics_count_http_bad_request(void);
/* colliders left out of one tick by the tick's cell budget, max_tick_cells (service) */
void metrics_count_tick_shed(uint64_t colliders);
/* FOOTPRINTS frames (and their events) queued to clients; frames not sent to a slow client. */
void metrics_count_footprints_sent(uint64_t frames, uint64_t events);
void metrics_count_footprints_dropped(uint64_t frames);
void metrics_count_tick_overrun(void);
void metrics_count_refused_windows(uint64_t n);
/* The GL tile cache's totals since the backend started (0 on the CPU backend). */
void metrics_set_gpu_tile_cache(uint64_t uploads, uint64_t upload_bytes, uint64_t evictions,
                                int64_t resident_tiles); /* windows refused at the height limit */
void metrics_count_delta_bytes(uint64_t raw_bytes, uint64_t compressed_bytes);

void metrics_observe_tick_ms(double ms);
void metrics_observe_stage_ms(const char *stage, double ms);
void metrics_observe_pose_to_delta_ms(double ms);

void metrics_set_tick(uint64_t tick);
/* gauge terrad_sim_threads: threads of the CPU twin's stages */
void metrics_set_sim_threads(int n);
void metrics_set_volume(int64_t volume); /* Σh, exact integer */
void metrics_set_active_cells(int64_t cells);
void metrics_set_colliders(int64_t n);
void metrics_set_clients(int64_t n);
/* Memory held by a part of the daemon ("world", "sim_scratch", ...). */
void metrics_set_memory_bytes(const char *part, uint64_t bytes);

/* ---- storage (server/store) ---- */
/* Error kinds: "enospc", "write", "fsync", "compress", "memory", "compaction". */
#define METRICS_STORE_ERROR_KINDS "enospc", "write", "fsync", "compress", "memory", "compaction"
void metrics_count_store_wal_bytes(uint64_t bytes);
void metrics_observe_store_fsync_ms(double ms);
void metrics_set_store_durable_tick(uint64_t tick);
void metrics_count_store_compaction(double ms);
void metrics_count_store_error(const char *kind);
void metrics_set_store_available(int available);
void metrics_set_store_recovery(double ms, int64_t records_replayed, int64_t bytes_cut);

/* ---- the service's dropped work (server/service) ----
 * terrad_service_dropped_total{reason=...}: something a tick meant to send or
 * take that it could not (each also logged, at most once a second):
 *   frame     an outbound frame not queued (no memory, or encoding failed);
 *   snapshot  a snapshot piece or request that could not be built;
 *   poses     the tick's poses left in the hub (no memory for its buffer);
 *   command   a client command the sim could not apply (no memory);
 *   contact   a collider's contact feedback not measured (no memory);
 *   deltas    a tick's deltas not cut into tiles (no memory). */
#define METRICS_SERVICE_DROP_REASONS "frame", "snapshot", "poses", "command", "contact", "deltas"
void metrics_count_service_dropped(const char *reason);

/* terrad_auth_refused_total{reason} (metrics_auth.c): bad_token (hello or HTTP
 * without a known token), forbidden (a role without the right), revoked (an
 * open connection whose token a reload removed). */
#define METRICS_AUTH_REASONS "bad_token", "forbidden", "revoked"
/* Within metrics/ (metrics_text.c): the index of name among a label's count
 * values, or -1 (NULL or unknown: dropped, never a new series). */
int metrics_label_index(const char *const *names, int count, const char *name);
void metrics_count_auth_refused(const char *reason);
void metrics_auth_reset(void);
int metrics_auth_text(char *out, size_t cap); /* its length, or -1 when it does not fit */

/* Told to come back or to catch up (metrics_room.c):
 * terrad_http_refused_total{reason="connections_per_address"|"connections"}
 * (overall 0 or 1: which limit) and terrad_clients_behind_total. */
void metrics_count_http_refused(int overall);
void metrics_count_client_behind(void);
void metrics_room_reset(void);
int metrics_room_text(char *out, size_t cap); /* its length, or -1 when it does not fit */

/* Terrain edits (metrics_edits.c): terrad_edits_total{op,result} and the
 * volume they declared, terrad_edit_volume_added_units_total{op} and
 * terrad_edit_volume_removed_units_total{op}. ok 0: refused. */
#define METRICS_EDIT_OPS "crater", "stamp", "reset", "add", "remove"
void metrics_count_edit(const char *op, int ok, int64_t volume_change);
void metrics_edits_reset(void);
int metrics_edits_text(char *out, size_t cap); /* its length, or -1 when it does not fit */

/* Client-clocked worlds (metrics_steps.c): terrad_steps_total,
 * terrad_stepped_ticks_total and terrad_steps_refused_total{field}: the
 * field a refused STEP's error named (PROTOCOL.md "STEP"). */
#define METRICS_STEP_FIELDS                                                                        \
    "ticks", "sets", "count", "poses", "clock", "driver", "queue", "frame", "store"
void metrics_count_steps(uint64_t n);
void metrics_count_stepped_ticks(uint64_t n);
void metrics_count_step_refused(const char *field);
void metrics_steps_reset(void);
int metrics_steps_text(char *out, size_t cap); /* its length, or -1 when it does not fit */

/* Desync detection and repair (metrics_desync.c; PROTOCOL.md "CHECKSUM"):
 * CHECKSUM frames and bytes sent, frames skipped (a client being
 * resynced, past max_pending_bytes or past its budget's window), tiles asked
 * for again and their snapshots, and terrad_resync_refused_total{field}: the
 * field a refused resync named. */
#define METRICS_RESYNC_FIELDS "id", "tiles"
void metrics_count_checksums(uint64_t frames, uint64_t bytes);
void metrics_count_checksums_skipped(uint64_t n);
void metrics_count_resync_tiles_requested(uint64_t n);
void metrics_count_tile_resyncs(uint64_t n);
void metrics_count_resync_refused(const char *field);
void metrics_desync_reset(void);
int metrics_desync_text(char *out, size_t cap); /* its length, or -1 when it does not fit */
/* Spectators (metrics_spectate.c; PROTOCOL.md "Spectate"): replay threads
 * alive, start-tick rebuilds and their milliseconds, ticks, frames and bytes
 * played, frames dropped (not made, or no memory to keep them: the spectate
 * ends "failed"), and terrad_spectate_refused_total{field}: the field a
 * refused spectate named ("state": the connection's state, "busy": no room). */
#define METRICS_SPECTATE_FIELDS                                                                    \
    "from_tick", "speed", "step", "ticks", "x", "y", "w", "h", "state", "busy"
void metrics_set_spectators(int n);
void metrics_observe_spectate_seek_ms(double ms);
void metrics_count_spectate_ticks(uint64_t n);
void metrics_count_spectate_frames(uint64_t n, uint64_t bytes);
void metrics_count_spectate_dropped(uint64_t n);
void metrics_count_spectate_refused(const char *field);
/* The cells a spectator's store cursor holds (store_cursor_cells): the most
 * any held, terrad_spectate_cursor_cells_max. */
void metrics_observe_spectate_cursor_cells(int64_t cells);
void metrics_spectate_reset(void);
int metrics_spectate_text(char *out, size_t cap); /* its length, or -1 when it does not fit */
/* metrics_cluster.c: terrad_cluster_takes_redone_total, takes of a world's log
 * (cluster_wal_take) that found another writer's message after the point they
 * recovered to and were made again. */
void metrics_count_cluster_take_redone(void);
void metrics_cluster_reset(void);
int metrics_cluster_text(char *out, size_t cap); /* its length, or -1 when it does not fit */

/* Scratch memory the sim holds per stage (METRICS_MEMORY_STAGES), as the
 * gauge terrad_sim_scratch_bytes{stage=...}; unknown stages are ignored. */
#define METRICS_MEMORY_STAGES SIM_MEMORY_STAGE_LIST(SIM_STAGE_NAME)
void metrics_set_stage_memory_bytes(const char *stage, uint64_t bytes);

/* ---- a cluster node's worlds (metrics_worlds.c) ----
 * Series labelled world="NAME" (terrad_world_*), one set per world this node
 * ticks now. A world's sim thread takes a slot when it starts, sets the
 * figures each tick and drops the slot when it stops ticking the world. */
#define METRICS_MAX_WORLDS 320 /* a node's or daemon's 256 worlds, with room for those leaving */
typedef struct metrics_world_figures {
    uint64_t tick;
    int64_t volume, colliders;
    int64_t clients; /* the world's websocket clients (joined to its service) */
    int store_available;
    double tick_ms, commit_p50_ms, commit_p99_ms;
} metrics_world_figures;
/* The slot of world name (-1 when all are taken: its figures are not shown). */
int metrics_world_slot(const char *name);
void metrics_world_tick(int slot, const metrics_world_figures *f);
void metrics_world_drop(int slot);
/* The per-world families as exposition text into out; its length or -1. */
int metrics_worlds_text(char *out, size_t cap);
/* terrad_http_forwarded_total{result}: a request for a world another node
 * ticks, asked of its owner (any node serves any world): answered,
 * no_owner (no node ticks it now), no_answer (none in time, or unreadable),
 * not_relayed (no such world here: 404). Unknown results are ignored. */
#define METRICS_FORWARD_RESULTS "answered", "no_owner", "no_answer", "not_relayed"
void metrics_count_http_forwarded(const char *result);

/* terrad_world_requests_total{op,result}: the world lifecycle API on a
 * single daemon, op "create" (POST /v1/worlds) or "delete" (DELETE
 * /v1/worlds/NAME), result "ok" or "refused" (ok 0). Unknown ops ignored. */
void metrics_count_world_request(const char *op, int ok);

/* terrad_world_readers_overdue_total: readers (HTTP requests, spectators'
 * replay threads) still using a removed world's table entry at the readers'
 * deadline of its removal (hub_worlds_remove: it waits on for them). */
void metrics_count_world_readers_overdue(uint64_t n);

/* The text exposition (text/plain; version=0.0.4); caller frees. */
char *metrics_render(size_t *len);

#endif
