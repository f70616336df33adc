/*
 * host.h: server/host/, the public face of hosting a world — one life for
 * every world a daemon ticks, the default world, a world created by API and
 * a cluster node's world alike (issue 29, docs/design.md "Hosting a world").
 *
 * A world's life is host_world_start → ticks on the shared pool of sim
 * workers (host_ticker.c) → host_world_end → its end on a worker. The parts
 * that differ between worlds are seams with backends, as store/'s backend is:
 *   - the registry (host_world_ops): where the world's scene and store come
 *     from (a local data directory, or the cluster's registry and JetStream
 *     under a lease), what is checked after each tick (a cluster world: is
 *     the lease still ours?), whom to tell when it serves and when it ends;
 *   - the clock (host_clock): when the world's next tick is due — the wall
 *     clock at the scene's tick_hz today; a client-driven clock (the
 *     co-simulation issue: a tick only when the driver sends a step) plugs in
 *     as another backend, woken by host_ticker_wake.
 * Everything else (open the store, register with http/net/metrics, tick,
 * unregister, free) is the same code for every world (host_world.c).
 */
#ifndef TERRAD_HOST_H
#define TERRAD_HOST_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "base/base.h"
#include "cluster/cluster.h"
#include "collider/collider.h"
#include "ground/ground.h"
#include "http/http.h"
#include "hub/hub.h"
#include "net/net.h"
#include "scene/scene.h"
#include "service/service.h"
#include "sim/sim.h"
#include "store/store.h"
#include "world/world.h"

/* ---- the deformation backend and the ground (host_backend.c) ---- */

/* Room for host_backend_create's reason. */
#define HOST_BACKEND_REASON_MAX 320
/* name "auto", "gl" or "cpu"; the choice is logged, and why it was made goes
 * to why (may be NULL) for /v1/world and reports. */
sim_backend *host_backend_create(const char *name, char *why, size_t why_cap, error_text *err);
/* The scene's ground into the engine. On failure nothing is held. */
int host_ground_attach(const scene *sc, const world *w, sim_engine *engine, ground *g,
                       error_text *err);

/* ---- demo actors (host_demo.c) ---- */

/* A sphere that runs laps of an ellipse (centre cx, cy; half-axes ax, ay;
 * omega rad/s from angle0) in its own cell of the world and bobs up and
 * down, dipping below the base terrain at the bottom. */
typedef struct demo_actor {
    collider_geometry geometry;
    double cx, cy, ax, ay, omega, angle0, phase;
} demo_actor;

void demo_actors_init(demo_actor *a, int count, const world *w);
collider_pose demo_actor_step(const demo_actor *a, const world *w, double time_s);

/* ---- one world's simulation (host_sim.c) ---- */

/* The shared pool of sim workers and a world on it (below). */
typedef struct host_ticker host_ticker;
typedef struct host_job host_job;

/* What host_sim_start takes from the daemon's options. */
typedef struct host_sim_config {
    const char *backend; /* "auto", "gl" or "cpu" */
    int64_t max_tick_cells, max_sweep_cells;
    int checksum_interval_ticks; /* limits.checksum_interval_ticks (PROTOCOL.md "CHECKSUM") */
    int demo_actors;
} host_sim_config;

/* Everything one world's sim thread holds; zero means "not made yet", so
 * host_sim_free releases whatever was made. */
typedef struct host_sim {
    char name[CLUSTER_WORLD_NAME_MAX + 1]; /* the world's name; "" for the default world */
    scene sc;
    world w;
    store *st;         /* NULL: memory only */
    cluster_store *cs; /* cluster mode: st's JetStream store (closed by store_close) */
    store_recovery recovery;
    http_status status; /* its lock is the caller's to init and destroy */
    sim_params params;
    sim_backend *backend;
    sim_engine *engine;
    ground grd;
    demo_actor *actors;
    sim_collider *extra;
    int demo_actors;
    service *svc;
    hub *h; /* made by the caller (the HTTP server may need it first) */
    char models[64];
    /* the scene's twin config (JSON), the world message's "base" for clients
     * that ask for base snapshots; NULL where the twin cannot make this base */
    char *twin_json;
    char backend_reason[HOST_BACKEND_REASON_MAX]; /* why this backend (host_backend_create) */
    uint64_t overruns;
    int clients;      /* the net's count for this tick's status (host_sim_step) */
    int metrics_slot; /* a named world's labelled series */
    /* a client-clocked world (scene "clock": "client", host_clock_client):
     * the ticks its driver's steps asked for (added by the net thread) and
     * the ticks run (its sim thread), and whom a step wakes */
    atomic_llong clock_owed;
    atomic_llong clock_ran;
    host_ticker *clock_ticker;
    host_job *clock_job;
} host_sim;

/* The world's status fields, from m->w and m->sc (before HTTP reads it). */
void host_sim_status_init(host_sim *m);
/* On the world's sim thread, with m->w made, m->st recovered and m->h made:
 * the backend, engine, ground, service (attached to the store) and demo actors. */
int host_sim_start(host_sim *m, const host_sim_config *c, error_text *err);
/* The world's info for the net server (pointing into m). */
net_world_info host_sim_world_info(const host_sim *m);
/* Ready for clients: the status block says so, with the backend's names. */
void host_sim_ready(host_sim *m);
/* One tick: demo poses, service_tick, the status block and the metrics. */
int host_sim_step(host_sim *m, long tick, int clients, error_text *err);
/* What the sim thread owns released (service, store, engine, ground,
 * backend, demo actors); what the ports may still read stays (hub, world,
 * scene, status). On the world's sim thread. */
void host_sim_stop(host_sim *m);
/* host_sim_stop, then the hub, world and scene too (the status lock stays
 * the caller's). */
void host_sim_free(host_sim *m);
/* Sleeps ms milliseconds (nothing when ms <= 0). */
void host_sleep_ms(double ms);

/* ---- the clock seam (host_clock.c) ---- */

/* A due time that never comes: the world waits for host_ticker_wake. */
#define HOST_CLOCK_NEVER 1e300
/*
 * When a world's ticks are due. The ticker asks due_ms once when the world
 * joins (tick 0, last_due_ms = now_ms) and again after each tick ran (tick:
 * the next one's number, last_due_ms: when the one that ran was due), and
 * again on host_ticker_wake while the world waits; the answer is a time on
 * time_now_ms's clock (now_ms or earlier: due at once), or HOST_CLOCK_NEVER.
 * Called under the ticker's lock on any worker: quick, never blocking. The
 * wall backend (host_clock_wall) is the daemon's fixed rate: one period
 * after the last due time, or now when the world fell behind (the backlog is
 * dropped, the rate kept). A client-driven backend answers now while its
 * driver has asked for a step it has not had, HOST_CLOCK_NEVER otherwise,
 * and calls host_ticker_wake when a step arrives.
 */
typedef struct host_clock {
    const char *name;
    double (*due_ms)(void *ctx, long tick, double period_ms, double last_due_ms, double now_ms);
    void *ctx; /* due_ms's (the backend's state for this world) */
} host_clock;
/* The wall clock at the scene's tick_hz (ctx NULL). */
extern const host_clock host_clock_wall;
/* A client-clocked world's clock (PROTOCOL.md "STEP"): due now while m's
 * driver's steps owe ticks (m->clock_owed > m->clock_ran) or an HTTP height
 * read waits (host_sim_step then only serves it), else HOST_CLOCK_NEVER: the
 * world waits, however long, for its driver. */
host_clock host_clock_client(host_sim *m);
/* After host_sim_start, before the world joins the net server: nothing for a
 * wall-clocked world; for a client-clocked one (whose job's clock must be
 * host_clock_client(m)) each step reaching m's hub adds its ticks to
 * m->clock_owed and wakes j on t. A wake before j is on the ticker is
 * harmless: the ticker asks the clock when j joins. Returns 0. */
int host_clock_client_attach(host_sim *m, host_ticker *t, host_job *j);
/* 1 while m's driver's steps owe ticks not run yet. Any thread. */
int host_sim_tick_owed(host_sim *m);

/* ---- the shared pool of sim workers (host_ticker.c) ---- */

/* After each of a world's ticks: non-zero (with why) ends it. */
typedef int (*host_check_fn)(void *ctx, host_sim *m, long tick, char *why, size_t cap);
/* On a worker once the job ended: rc 0 asked to (host_ticker_end, max_ticks,
 * the ticker stopping), -1 a tick failed, 1 check said stop (j->why says
 * why). The world leaves its ports and is freed here (its GL context is
 * current on this thread); the ticker does nothing with j after it. */
typedef void (*host_end_fn)(host_job *j, int rc);
/* One world on the pool: the owner fills the first fields (in its own
 * struct, alive until end ran); the rest is the ticker's, under its lock. */
struct host_job {
    host_sim *m;         /* started (host_sim_start) and registered */
    net_server *net;     /* its clients counted in its status (NULL: none) */
    long max_ticks;      /* < 0: none */
    host_clock clock;    /* when its ticks are due (due_ms NULL: host_clock_wall) */
    host_check_fn check; /* NULL: none */
    host_end_fn end;
    void *ctx; /* check's and end's */
    char why[256];
    long tick;
    double due_ms, period_ms;
    int pinned; /* -1: any worker; else the one its GL context is current on */
    int running, ending, rc;
};
/* Worker threads for a process: twice the cores, 4..32 (host_ticker.c says why). */
int host_ticker_default_workers(void);
/* NULL with err when no worker thread starts. */
host_ticker *host_ticker_start(int workers, error_text *err);
/* j ticks from now on as its clock says, its ticks counted from 0. */
int host_ticker_add(host_ticker *t, host_job *j, error_text *err);
/* Asks j's clock again now (a client clock's step arrived). Any thread. */
void host_ticker_wake(host_ticker *t, host_job *j);
/* Asks j to end (end runs soon on a worker); nothing if it is ending already. */
void host_ticker_end(host_ticker *t, host_job *j);
/* Every job ended (each end run), the workers joined. NULL is fine. */
void host_ticker_stop(host_ticker *t);

/* ---- one world's life (host_world.c) ---- */

typedef struct host_world host_world;
/*
 * The registry backend of a world: where it comes from and whom it tells.
 * open is required; the others may be NULL. Each is called with the world;
 * hw->owner is the owner's.
 */
typedef struct host_world_ops {
    /* Its scene, world and store into hw->m (m->name set by the owner), on
     * the thread that calls host_world_start. */
    int (*open)(host_world *hw, error_text *err);
    /* It joined the ports and metrics and is ready, before its first tick:
     * 0, or -1 with err (it leaves them again and does not start). */
    int (*registered)(host_world *hw, error_text *err);
    /* It is about to leave the ports (its clients are told next). */
    void (*unregistering)(host_world *hw);
    /* After each tick: non-zero (with why) ends it. */
    int (*check)(host_world *hw, long tick, char *why, size_t cap);
    /* Its end ran on a worker: it left the ports and was freed (hw->why
     * says why when rc is not 0; hw->last_tick, hw->overruns kept). */
    void (*ended)(host_world *hw, int rc);
    /* Why its clients are closed: deleted (hw->deleted) or stopped. */
    const char *deleted_why, *stopped_why;
} host_world_ops;

struct host_world {
    host_sim m; /* m.name ("": the default world, on the ports by its scene's name) and
                 * m.status.lock: the owner's */
    const host_world_ops *ops;
    void *owner;         /* the ops' */
    hub_worlds *worlds;  /* the table of worlds both ports read, which it joins */
    hub_world *entry;    /* its entry there while it is on the ports */
    net_world_info info; /* what the net thread reads of it (host_sim_world_info) */
    net_server *net;     /* its clients counted in its status */
    host_ticker *ticker; /* the pool it ticks on */
    host_sim_config config;
    long max_ticks;        /* < 0: none */
    host_clock clock;      /* due_ms NULL: the wall clock */
    int deleted;           /* its clients are told it was deleted (set before its end) */
    atomic_int registered; /* on the ports */
    host_job job;
    char why[256];
    unsigned long long last_tick; /* at its end */
    unsigned long long overruns;
};
/* Where hw comes from and where it goes: its registry backend (ops, owner),
 * the table of worlds it joins (the ports read it), the websocket server that
 * counts its clients and the pool it ticks on (the rest of hw as it is). */
void host_world_place(host_world *hw, const host_world_ops *ops, void *owner, hub_worlds *worlds,
                      net_server *net, host_ticker *ticker);
/* host_world_open, then host_world_run. */
int host_world_start(host_world *hw, char *why, size_t cap);
/* Opens hw (ops->open: scene, world, store), its status filled, its hub
 * made: 0, or -1 with why and everything made undone. */
int host_world_open(host_world *hw, char *why, size_t cap);
/* Starts its simulation, joins the ports (hub_worlds_add: the table both
 * read; a labelled metrics slot for a named world), then
 * ops->registered, and hands it to the ticker: 0, or -1 with why and
 * everything made undone (ops->ended is not called). */
int host_world_run(host_world *hw, char *why, size_t cap);
/* Asks hw to end: its end runs soon on a worker (ops->ended last). */
void host_world_end(host_world *hw);
/* What an opened world that never ran still holds, freed (nothing once it ran). */
void host_world_free(host_world *hw);

#endif
