/*
 * host_world.c: one world's life, the same for every world a daemon ticks
 * (host.h): open (the registry backend's open: its scene, world and store) →
 * its hub and simulation started → on the ports (one entry of the table of
 * worlds both read, hub_worlds_add) and in the metrics (a labelled slot) → ready → on
 * the ticker, which runs its ticks as its clock says → asked to end, or a
 * tick failed, or the registry's check said stop → its end on a worker: off
 * the ports (reads fail fast, requests in flight end, its clients are told
 * and closed), freed (its GL context is current on that worker), and the
 * registry told last (ops->ended). Before issue 29 a created world
 * (app/serve_worlds.c) and a cluster world (app/serve_node.c) each had their
 * own copy of this, and the default world (app/serve.c) was made with the
 * ports; what still differs between them is in their ops.
 */
#include <stdio.h>
#include <string.h>

#include "host/host.h"
#include "metrics/metrics.h"

/* Its name on the ports: a named world's, or the default world's scene's. */
static const char *port_name(const host_world *hw)
{
    return hw->m.name[0] ? hw->m.name : hw->m.sc.name;
}

/* The world joins the ports, then the registry hears it serves. */
static int world_register(host_world *hw, error_text *err)
{
    host_sim *m = &hw->m;
    hw->info = host_sim_world_info(m); /* read by the net thread when it adopts it */
    hub_world e = {.h = m->h,
                   .base = &m->w,
                   .history = store_history_kept(&m->status.history) ? &m->status.history : NULL,
                   .status = &m->status,
                   .info = &hw->info};
    snprintf(e.name, sizeof e.name, "%.64s", port_name(hw)); /* as http_status.scene_name */
    if (!(hw->entry = hub_worlds_add(hw->worlds, &e, err)))
        return -1;
    if (m->name[0]) /* the default world's series are the unlabelled ones */
        m->metrics_slot = metrics_world_slot(m->name);
    host_sim_ready(m);
    atomic_store(&hw->registered, 1);
    return hw->ops->registered ? hw->ops->registered(hw, err) : 0;
}

/* The world leaves the ports: reads fail fast, requests in flight end, its
 * clients are told (deleted, or stopped) and closed. */
static void world_unregister(host_world *hw)
{
    host_sim *m = &hw->m;
    if (m->h) {
        char why[160];
        snprintf(why, sizeof why, "world %s %s", port_name(hw),
                 hw->deleted ? hw->ops->deleted_why : hw->ops->stopped_why);
        hub_close_reads(m->h);
        hub_close_edits(m->h, why);
    }
    if (!atomic_load(&hw->registered))
        return;
    atomic_store(&hw->registered, 0);
    if (hw->ops->unregistering)
        hw->ops->unregistering(hw);
    /* m is freed after this; should the net thread keep m->h (a failed
     * removal below), a STEP or height read must no longer wake m's clock */
    if (m->h)
        hub_set_step_notify(m->h, NULL, NULL);
    /* out of the one table: the HTTP requests using it end, the net thread
     * tells its clients (deleted, or stopped) and closes them */
    if (hub_worlds_remove(hw->worlds, hw->entry, hw->deleted) != 0)
        m->h = NULL; /* the net thread may still hold it: left to the exit */
    hw->entry = NULL;
    metrics_world_drop(m->metrics_slot);
}

static int world_check(void *ctx, host_sim *m, long tick, char *why, size_t cap)
{
    (void)m;
    host_world *hw = ctx;
    return hw->ops->check(hw, tick, why, cap);
}

/* The job's end, on a worker: off the ports, freed, the registry told. */
static void world_end(host_job *j, int rc)
{
    host_world *hw = j->ctx;
    host_sim *m = &hw->m;
    if (rc != 0)
        snprintf(hw->why, sizeof hw->why, "%s", j->why);
    world_unregister(hw);
    hw->last_tick = (unsigned long long)service_current_tick(m->svc);
    hw->overruns = (unsigned long long)m->overruns;
    host_sim_free(m); /* off the ports: nobody reads it any more */
    if (hw->ops->ended)
        hw->ops->ended(hw, rc);
}

void host_world_place(host_world *hw, const host_world_ops *ops, void *owner, hub_worlds *worlds,
                      net_server *net, host_ticker *ticker)
{
    hw->ops = ops;
    hw->owner = owner;
    hw->worlds = worlds;
    hw->net = net;
    hw->ticker = ticker;
}

int host_world_open(host_world *hw, char *why, size_t cap)
{
    host_sim *m = &hw->m;
    m->metrics_slot = -1;
    error_text err = {{0}};
    if (hw->ops->open(hw, &err) == 0) {
        host_sim_status_init(m);
        if ((m->h = hub_create()))
            return 0;
        error_set(&err, "out of memory");
    }
    snprintf(why, cap, "%s", err.message);
    host_sim_free(m);
    return -1;
}

int host_world_run(host_world *hw, char *why, size_t cap)
{
    host_sim *m = &hw->m;
    error_text err = {{0}};
    /* a client-clocked world hears its steps from the moment it joins the ports */
    if (host_sim_start(m, &hw->config, &err) == 0 &&
        host_clock_client_attach(m, hw->ticker, &hw->job) == 0 && world_register(hw, &err) == 0) {
        hw->job = (host_job){.m = m,
                             .net = hw->net,
                             .max_ticks = hw->max_ticks,
                             .clock = m->sc.client_clock ? host_clock_client(m) : hw->clock,
                             .check = hw->ops->check ? world_check : NULL,
                             .end = world_end,
                             .ctx = hw};
        if (host_ticker_add(hw->ticker, &hw->job, &err) == 0)
            return 0;
    }
    snprintf(why, cap, "%s", err.message);
    world_unregister(hw);
    host_sim_free(m);
    return -1;
}

int host_world_start(host_world *hw, char *why, size_t cap)
{
    return host_world_open(hw, why, cap) == 0 ? host_world_run(hw, why, cap) : -1;
}

void host_world_end(host_world *hw)
{
    host_ticker_end(hw->ticker, &hw->job);
}

void host_world_free(host_world *hw)
{
    host_sim_free(&hw->m);
}
