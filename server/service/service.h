/*
 * service: the sim thread's side of the daemon — clients, their colliders
 * and subscriptions as the sim sees them, tile versions, and one tick of the
 * service (docs/design.md, "One tick", all of it; service_tick reads as its
 * table of contents):
 *
 *   take commands, the latest poses and batch sequences from the hub →
 *   contact feedback against the terrain before the tick → gather the
 *   colliders → deformation (sim_engine_tick) → commit the change to the
 *   store (undone if it cannot be logged) → split the dirty rectangles by
 *   tile, advance tile versions, encode each (rectangle, version) once →
 *   contacts after the tick, CONTACT and ACK frames, COLLIDERS, FOOTPRINTS,
 *   snapshots for new subscriptions and resyncs → the tick is published:
 *   first its status (the host's publisher), then its frames to the hub once
 *   the store has made the tick durable, then the height reads it answers.
 *
 * Only the sim thread calls into it (asserted in debug and sanitizer
 * builds: the thread that creates the service owns it).
 */
#ifndef TERRAD_SERVICE_H
#define TERRAD_SERVICE_H

#include <stdint.h>

#include "base/base.h"
#include "hub/hub.h"
#include "sim/sim.h"
#include "store/store.h"
#include "world/world.h"

#define SERVICE_TILE_SIZE 64

typedef struct service service;

/* The engine and the world stay the caller's; the service reads and ticks them. */
service *service_create(sim_engine *engine, hub *h, error_text *err);
void service_destroy(service *s);
/* This thread is the service's sim thread from now on: the service, its
 * hub's sim end, its engine and its store are handed over to it (a pool of
 * sim workers ticks a world on whichever worker is free; the hand-over is
 * ordered by the pool's lock). */
void service_claim(service *s);

typedef struct service_tick_stats {
    sim_tick_report report;
    int clients, colliders;
    int delta_frames;
    uint64_t delta_raw_bytes, delta_compressed_bytes;
    double tick_ms;
} service_tick_stats;

/*
 * One tick. `extra` are colliders the daemon drives itself (demo actors);
 * their ids must not collide with client colliders (use ids >= 0x80000000).
 * Returns 0, or -1 with err set when the backend failed.
 */
int service_tick(service *s, const sim_collider *extra, int extra_count, service_tick_stats *stats,
                 error_text *err);

/*
 * Who says a tick happened (the host: its status block and metrics, which
 * /v1/stats, ?tick=, /healthz and the scrapes read). Called once per tick on
 * the sim thread (service_current_tick is the tick) with the tick's stats
 * (tick_ms: the tick up to here), after
 * the tick is computed and logged and before anything names the tick outside
 * the sim thread: its frames are handed to the network and the height reads
 * it answers are served after fn returns. So no client can learn of tick T
 * from a frame or an X-Terrad-Tick before every reader of the status takes T
 * as the world's tick (docs/design.md "One tick", row 9). NULL: none.
 */
typedef void (*service_publish_fn)(void *arg, const service_tick_stats *stats);
void service_set_publisher(service *s, service_publish_fn fn, void *arg);

/*
 * Make every tick durable in st before it is published (store.h): a tick's
 * changes are appended after the deformation and its frames held until the
 * store says they are as durable as its policy promises; while the store
 * cannot write, no deformation runs and clients' pose batches are refused.
 * The tick counter continues from recovered_tick and Σh is recomputed from
 * the recovered world. st stays the caller's.
 */
void service_attach_store(service *s, store *st, uint64_t recovered_tick);

/* The tick's cost budget (limits.max_tick_cells): while the posed client
 * colliders' footprint cells pass it, the most expensive client's colliders
 * wait a tick (service_shed.c). 0: none (the default). max_sweep_cells
 * (limits.max_sweep_cells): one client's cost this tick; the new poses that
 * would take it past are refused (the colliders stay where they were, the
 * client gets limit_colliders naming the pose). 0: none (the default). */
void service_set_tick_budget(service *s, int64_t max_tick_cells, int64_t max_sweep_cells);

/* Desync detection (PROTOCOL.md "CHECKSUM"): every `ticks` ticks (tick % ticks
 * == 0), each subscription's tile hashes go to its client behind the tick's
 * other frames (service_checksums.c). 0: none. */
void service_set_checksum_interval(service *s, int ticks);

/* A client-clocked world (scene "clock": "client"; PROTOCOL.md "STEP"): each
 * tick takes its poses from its driver's STEP (hub_push_step) and the step's
 * last tick sends STEPPED. Before the first tick. */
void service_set_client_clock(service *s, int on);
/* Ticks of the step under way not run yet (0: none under way). */
int service_step_remaining(const service *s);
/* Frames held back for durability (a group commit) published once the store
 * says they are durable: 1 when nothing is held any more. A client-clocked
 * world that stops between steps calls it until it says 1, since no later
 * tick would publish them. */
int service_settle(service *s);
uint64_t service_current_tick(const service *s);
int64_t service_volume(const service *s); /* Σh, kept exactly, tick by tick */
uint32_t service_tile_version(const service *s, int tile_x, int tile_y);

#endif
