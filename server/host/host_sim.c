/*
 * host_sim.c: one world's simulation inside `terrad serve` — the scene and
 * its world, the engine on its backend, the ground, the service over the hub,
 * the demo actors and the status block HTTP reads — and one step of the
 * fixed-rate tick loop on it (demo poses → service_tick → status and
 * metrics, published inside the tick before anything else names it:
 * publish_tick). Every world of the process has one — a single daemon's default
 * world (app/serve.c), its created worlds (app/serve_worlds.c) and a cluster
 * node's worlds (app/serve_node.c) — ticked by the shared pool of sim workers
 * (host_ticker.c). Everything here runs on whichever thread is the world's
 * sim thread at the time: the one that made it, then the worker running its
 * tick (the backend keeps a GL context on one worker; the hub's sim end moves
 * with the tick).
 */
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "host/host.h"
#include "metrics/metrics.h"
#include "service/service.h"

/* The tick's status and metrics, published inside the tick (below). */
static void publish_tick(void *arg, const service_tick_stats *stats);

int host_sim_start(host_sim *m, const host_sim_config *c, error_text *err)
{
    world *w = &m->w;
    if (sim_params_from_material(&m->sc.material, w->cell_size_m, w->units_per_m, w->floor,
                                 &m->params, err) != 0 ||
        !(m->backend =
              host_backend_create(c->backend, m->backend_reason, sizeof m->backend_reason, err)) ||
        !(m->engine =
              sim_engine_create(w, &m->params, m->backend, m->sc.active_margin_cells, err)) ||
        host_ground_attach(&m->sc, w, m->engine, &m->grd, err) != 0 ||
        !(m->svc = service_create(m->engine, m->h, err)))
        return -1;
    service_set_publisher(m->svc, publish_tick, m);
    service_set_tick_budget(m->svc, c->max_tick_cells, c->max_sweep_cells);
    service_set_checksum_interval(m->svc, c->checksum_interval_ticks);
    service_set_client_clock(m->svc, m->sc.client_clock);
    if (m->st)
        /* go on from the recovered tick, or past it where the store says a
         * client may have seen later (unlogged idle) ticks */
        service_attach_store(m->svc, m->st,
                             m->recovery.tick_floor > m->recovery.tick ? m->recovery.tick_floor
                                                                       : m->recovery.tick);
    m->actors = calloc((size_t)c->demo_actors + 1, sizeof *m->actors);
    m->extra = calloc((size_t)c->demo_actors + 1, sizeof *m->extra);
    if (!m->actors || !m->extra) {
        error_set(err, "serve: out of memory");
        return -1;
    }
    m->demo_actors = c->demo_actors;
    demo_actors_init(m->actors, m->demo_actors, w);
    snprintf(m->models, sizeof m->models, "[\"%s\"]", sim_model_name(m->params.model));
    error_text no_twin = {{0}}; /* a file base or per-cell materials: absolute snapshots only */
    free(m->twin_json);
    m->twin_json = scene_twin_config_json(&m->sc, &no_twin);

    http_status *s = &m->status;
    pthread_mutex_lock(&s->lock);
    s->volume = service_volume(m->svc);
    s->soil_compacted =
        world_layer_sum(&m->w, WORLD_LAYER_SOIL, SIM_SOIL_COMPACTED); /* recovered, before a tick */
    s->compacted = sim_world_compacted(&m->w);
    s->tick = service_current_tick(m->svc);
    pthread_mutex_unlock(&s->lock);
    return 0;
}

void host_sim_ready(host_sim *m)
{
    http_status *s = &m->status;
    pthread_mutex_lock(&s->lock);
    s->ready = 1;
    /* the watchdog's clock starts here: a tick loop stuck before its first
     * tick is as stuck as one stuck after it */
    s->published_ms = time_now_ms();
    /* a client-clocked world with no step yet waits for its driver: not
     * stalled (publish_status keeps this true after each tick) */
    s->waiting = m->sc.client_clock && !host_sim_tick_owed(m);
    snprintf(s->renderer, sizeof s->renderer, "%s", m->backend->renderer);
    snprintf(s->backend, sizeof s->backend, "%s", m->backend->name);
    snprintf(s->backend_reason, sizeof s->backend_reason, "%s", m->backend_reason);
    snprintf(s->method, sizeof s->method, "%s", sim_model_name(m->params.model));
    snprintf(s->metric, sizeof s->metric, "%s", sim_metric_name(m->params.metric));
    pthread_mutex_unlock(&s->lock);
}

void host_sim_status_init(host_sim *m)
{
    http_status *s = &m->status;
    s->world_width = m->w.width;
    s->world_height = m->w.height;
    s->cell_size_m = m->w.cell_size_m;
    s->units_per_m = m->w.units_per_m;
    s->tile_size = SERVICE_TILE_SIZE;
    s->tick_hz = m->sc.tick_hz;
    s->client_clock = m->sc.client_clock;
    snprintf(s->world_name, sizeof s->world_name, "%s", m->name);
    snprintf(s->scene_name, sizeof s->scene_name, "%.64s", m->sc.name);
    s->volume = world_volume(&m->w);
    s->soil_compacted = world_layer_sum(&m->w, WORLD_LAYER_SOIL, SIM_SOIL_COMPACTED);
    s->compacted = sim_world_compacted(&m->w);
}

net_world_info host_sim_world_info(const host_sim *m)
{
    const world *w = &m->w;
    return (net_world_info){.width = w->width,
                            .height = w->height,
                            .cell_size_m = w->cell_size_m,
                            .units_per_m = w->units_per_m,
                            .tick_hz = m->sc.tick_hz,
                            .tile_size = SERVICE_TILE_SIZE,
                            .height_min = WORLD_HEIGHT_MIN,
                            .height_max = WORLD_HEIGHT_MAX,
                            .models_json = m->models,
                            .base_json = m->twin_json,
                            .loads = m->params.model == SIM_MODEL_BEKKER,
                            .client_clock = m->sc.client_clock,
                            .name = m->name[0] ? m->name : NULL,
                            .materials_json = "[\"default\"]"};
}

static void publish_status(host_sim *m, double tick_ms, int clients, int colliders)
{
    http_status *status = &m->status;
    pthread_mutex_lock(&status->lock);
    if (m->st) { /* not ready while deformation is refused; reads go on */
        const char *why = store_failure(m->st);
        status->ready = why[0] == 0;
        snprintf(status->not_ready, sizeof status->not_ready, "%s%s",
                 why[0] ? "storage unavailable, deformation refused: " : "", why);
    }
    status->tick = service_current_tick(m->svc);
    status->volume = service_volume(m->svc);
    status->soil_compacted = world_layer_sum(&m->w, WORLD_LAYER_SOIL, SIM_SOIL_COMPACTED);
    status->compacted = sim_world_compacted(&m->w);
    status->last_tick_ms = tick_ms;
    status->overruns = m->overruns;
    status->clients = clients;
    status->colliders = colliders;
    status->published_ms = time_now_ms();
    /* a client-clocked world whose steps are all run waits for its driver */
    status->waiting = m->sc.client_clock && !host_sim_tick_owed(m);
    pthread_mutex_unlock(&status->lock);
}

/* The process-wide series. A cluster node's worlds share them (the stages'
 * histograms add up); the per-world gauges are the labelled ones instead. */
static void publish_metrics(const host_sim *m, const service_tick_stats *st)
{
    const sim_stage_times *t = &st->report.times;
    metrics_observe_tick_ms(st->tick_ms);
#define OBSERVE_STAGE(name) metrics_observe_stage_ms(#name, t->name);
    SIM_STAGE_LIST(OBSERVE_STAGE)
#undef OBSERVE_STAGE
    metrics_observe_stage_ms("gather_scatter", st->report.gather_scatter_ms);
    metrics_observe_stage_ms("model", st->report.model_ms);
    metrics_set_sim_threads(sim_threads());
    if (st->report.refused_windows)
        metrics_count_refused_windows((uint64_t)st->report.refused_windows);
    if (m->name[0]) {
        metrics_world_figures f = {.tick = service_current_tick(m->svc),
                                   .volume = service_volume(m->svc),
                                   .colliders = st->colliders,
                                   .clients = st->clients,
                                   .store_available = !m->st || !store_failure(m->st)[0],
                                   .tick_ms = st->tick_ms};
        if (m->cs)
            cluster_store_commit_ms(m->cs, &f.commit_p50_ms, &f.commit_p99_ms);
        metrics_world_tick(m->metrics_slot, &f);
        return;
    }
    metrics_set_tick(service_current_tick(m->svc));
    metrics_set_volume(service_volume(m->svc));
    metrics_set_active_cells(st->report.active_cells);
    metrics_set_colliders(st->colliders);
    sim_engine_stats es;
    sim_engine_get_stats(m->engine, &es);
    metrics_set_memory_bytes("world_heights", world_resident_bytes(&m->w));
    metrics_set_memory_bytes("sim_scratch", es.peak_scratch_bytes);
    /* what the scene's models hold, by stage (docs/models.md) */
#define SET_STAGE_MEMORY(name) metrics_set_stage_memory_bytes(#name, es.memory.name);
    SIM_MEMORY_STAGE_LIST(SET_STAGE_MEMORY)
#undef SET_STAGE_MEMORY
    sim_tile_cache_stats cache;
    sim_backend_tile_cache_stats(sim_engine_backend(m->engine), &cache);
    metrics_set_memory_bytes("gpu_tile_cache", cache.texture_bytes);
    metrics_set_gpu_tile_cache(cache.uploads, cache.upload_bytes, cache.evictions,
                               cache.resident_tiles);
}

/* The service's publisher (service_set_publisher): inside service_tick, once
 * the tick is computed and logged and before its frames go to the network and
 * the height reads it answers are served, the tick's status and metrics. So
 * the status names a tick before any client can learn of it otherwise: a
 * GET /v1/heights answered as of tick T (X-Terrad-Tick), an ACK or a
 * STEPPED of T, is never followed by a /v1/stats of an earlier tick or a
 * ?tick=T refused as in the future (http_views.c past_tick reads the status). */
static void publish_tick(void *arg, const service_tick_stats *stats)
{
    host_sim *m = arg;
    if (m->sc.client_clock) {
        atomic_fetch_add(&m->clock_ran, 1); /* before the status says whether it waits */
    } else if (stats->tick_ms > 1000.0 / m->sc.tick_hz) {
        m->overruns++; /* a client-clocked tick has no period to overrun */
        metrics_count_tick_overrun();
    }
    publish_status(m, stats->tick_ms, m->clients, stats->colliders);
    publish_metrics(m, stats);
}

/* The demo actors' poses for this tick, as colliders beside the clients'. */
static void step_demo(host_sim *m, long tick)
{
    double t = (double)tick / m->sc.tick_hz;
    for (int a = 0; a < m->demo_actors; a++) {
        sim_collider *c = &m->extra[a];
        c->id = (int)(0x80000000u + (unsigned)a);
        c->geometry = &m->actors[a].geometry;
        c->previous_pose = c->pose;
        c->pose = demo_actor_step(&m->actors[a], &m->w, t);
        c->has_previous = tick > 0;
    }
}

int host_sim_step(host_sim *m, long tick, int clients, error_text *err)
{
    if (m->sc.client_clock && !host_sim_tick_owed(m)) {
        /* woken by a height read while it waits for its driver: no tick */
        hub_serve_reads(m->h, &m->w, service_current_tick(m->svc));
        return 0;
    }
    fault_stall("tick"); /* test hook (base/fault.c): a sim thread that stops */
    /* a client-clocked world: the ticker's count also counts height reads
     * (the return above), so the demo actors go by the service's tick, which
     * only steps move: the same steps give the same heights */
    step_demo(m, m->sc.client_clock ? (long)service_current_tick(m->svc) + 1 : tick);
    service_tick_stats stats;
    error_text tick_err = {{0}};
    m->clients = clients; /* for the tick's status (publish_tick) */
    if (service_tick(m->svc, m->extra, m->demo_actors, &stats, &tick_err) != 0) {
        error_set(err, "tick %ld: %s", tick, tick_err.message);
        return -1;
    }
    if (m->sc.client_clock) {
        /* the step's last tick: its frames (STEPPED last) go out once durable,
         * and no later tick may come to publish them (a group commit's wait) */
        for (int i = 0; i < 30000 && service_step_remaining(m->svc) == 0 && !service_settle(m->svc);
             i++)
            host_sleep_ms(1);
    }
    return 0;
}

void host_sleep_ms(double ms)
{
    if (ms <= 0)
        return;
    struct timespec ts = {(time_t)(ms / 1000), (long)((ms - 1000 * (time_t)(ms / 1000)) * 1e6)};
    nanosleep(&ts, NULL);
}

void host_sim_stop(host_sim *m)
{
    service_destroy(m->svc);
    m->svc = NULL;
    store_close(m->st); /* a cluster world's closes its JetStream store */
    m->st = NULL;
    m->cs = NULL;
    free(m->extra);
    free(m->actors);
    sim_engine_destroy(m->engine);
    ground_free(&m->grd);
    if (m->backend)
        m->backend->destroy(m->backend);
    m->extra = NULL;
    m->actors = NULL;
    m->engine = NULL;
    m->backend = NULL;
}

void host_sim_free(host_sim *m)
{
    host_sim_stop(m);
    hub_destroy(m->h);
    world_free(&m->w);
    store_history_release(&m->status.history); /* no replay reads it now: the world left */
    scene_free(&m->sc);
    free(m->twin_json);
    m->twin_json = NULL;
    m->h = NULL;
}
