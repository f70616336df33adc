/*
 * service_shed.c: the tick's cost budget (issue 15, item 3: one client within
 * its own limits took the tick from 60 to 1.5 ticks/s and stalled everyone).
 * At the start of each tick, before the colliders are gathered, the footprint
 * cells of every posed client collider are summed (each charged
 * collider_cost_cells, as the per-client budget max_active_cells charges it,
 * net_requests.c: the square around its bounding sphere, and a mesh's
 * triangles too) once per sweep sub-step this tick (issue 20: a fast
 * collider does its depth work once per sub-step, collider_sweep_steps, and
 * a collider held last tick sweeps the two ticks' travel) and once more with
 * contact feedback (service_contacts.c measures its depth again against the
 * terrain before the tick). While the sum is over max_tick_cells, the most
 * expensive client's colliders wait a tick ("held"): they do not deform, keep
 * their previous pose (so the next tick sweeps the whole way and the trail
 * has no gap) and the client's ACK waits with them.
 *
 * Fair and never a stall: only a client over its fair share (max_tick_cells
 * divided by the clients with posed colliders) is ever held, so a light client
 * keeps moving every tick; a client held in one tick is not held in the next;
 * the last client with colliders is never held; a tick that cannot get under
 * the budget that way runs over it. Deterministic: by cells, ties by lower
 * client id; no clock. Counted in terrad_tick_shed_total and logged at most
 * once a second.
 *
 * Holding only defers a sweep, and the last client is never held, so a lone
 * client moving a large collider hundreds of cells a tick was charged but not
 * bounded (a 2 m sphere at the sub-step cap costs ~264 k cells). So one
 * client's cost this tick is bounded too (max_sweep_cells): when the poses it
 * sent since the last tick would take it past, those poses are refused, the
 * most expensive first, until it is within: each refused collider stays where
 * it stood (a later pose sweeps from there) and its sender gets
 * limit_colliders naming the collider, the pose's position and the budget
 * (counted in terrad_refused_messages_total{reason="limit_colliders"}). A
 * collider at rest never passes it: collider_create charged it against the
 * smaller max_active_cells. Sim thread only.
 */
#include "service/service_internal.h"

#include <cjson/cJSON.h>
#include <stdio.h>

#include "metrics/metrics.h"

void service_set_tick_budget(service *s, int64_t max_tick_cells, int64_t max_sweep_cells)
{
    s->max_tick_cells = max_tick_cells > 0 ? max_tick_cells : 0;
    s->max_sweep_cells = max_sweep_cells > 0 ? max_sweep_cells : 0;
}

/* What a posed collider costs this tick, in cells: collider_cost_cells of its
 * sweep sub-steps this tick (the rule the backends sweep by,
 * sim_collider_sweep_steps) and its contact feedback. */
static int64_t tick_cost(const service *s, const svc_collider *c)
{
    sim_collider one = {.geometry = c->geometry,
                        .pose = c->pose,
                        .previous_pose = c->previous_pose,
                        .has_previous = c->has_previous};
    return collider_cost_cells(&c->cost, sim_collider_sweep_steps(&one, s->world->cell_size_m),
                               c->feedback);
}

/* Its pose refused: the collider stays where it stood; its sender hears why
 * (ref: the POSE_BATCH's seq) and the refusal is counted. */
static void refuse_pose(service *s, svc_collider *c, int64_t cost, int64_t client_cells)
{
    const vec3d *p = &c->pose.position, *b = &c->pose_before.position;
    char message[400], ref[16];
    snprintf(message, sizeof message,
             "POSE_BATCH %u: the pose of collider %u at (%.3f, %.3f, %.3f) would sweep %lld "
             "cells this tick (its client's colliders %lld), over max_sweep_cells (%lld): "
             "pose refused, the collider stays where it was",
             c->pose_sequence, c->id, p->x, p->y, p->z, (long long)cost, (long long)client_cells,
             (long long)s->max_sweep_cells);
    cJSON *obj = cJSON_CreateObject();
    cJSON_AddStringToObject(obj, "type", "error");
    cJSON_AddNumberToObject(obj, "code", TERRAD_E_LIMIT_COLLIDERS);
    cJSON_AddStringToObject(obj, "name", terrad_err_name(TERRAD_E_LIMIT_COLLIDERS));
    cJSON_AddStringToObject(obj, "message", message);
    cJSON_AddNumberToObject(obj, "collider", c->id);
    snprintf(ref, sizeof ref, "%u", c->pose_sequence);
    service_reply_json(s, c->client, ref, obj);
    metrics_count_refused(TERRAD_E_LIMIT_COLLIDERS);
    double now = time_now_ms();
    if (s->last_sweep_log_ms <= 0 || now - s->last_sweep_log_ms >= 1000.0) {
        log_info("service: tick %llu: client %u: %s (from (%.3f, %.3f, %.3f); at most one "
                 "such line a second)",
                 (unsigned long long)s->tick, c->client, message, b->x, b->y, b->z);
        s->last_sweep_log_ms = now;
    }
    c->pose = c->pose_before;
    c->has_pose = c->had_pose;
}

/* The new pose of client cl's that costs most this tick (ties: lower id). */
static svc_collider *costliest_new_pose(service *s, uint32_t client, int64_t *cost)
{
    svc_collider *pick = NULL;
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (c->client != client || !c->pose_new || !c->has_pose)
            continue;
        int64_t cells = tick_cost(s, c);
        if (!pick || cells > *cost || (cells == *cost && c->id < pick->id)) {
            pick = c;
            *cost = cells;
        }
    }
    return pick;
}

void service_bound_sweeps(service *s)
{
    THREAD_OWNED(&s->owner);
    for (int i = 0; s->max_sweep_cells && i < s->client_count; i++)
        s->clients[i].tick_cells = 0;
    for (int i = 0; s->max_sweep_cells && i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        svc_client *cl = c->has_pose ? service_find_client(s, c->client) : NULL;
        if (cl)
            cl->tick_cells += tick_cost(s, c);
    }
    for (int i = 0; s->max_sweep_cells && i < s->client_count; i++) {
        svc_client *cl = &s->clients[i];
        int64_t cost = 0;
        svc_collider *c;
        while (cl->tick_cells > s->max_sweep_cells &&
               (c = costliest_new_pose(s, cl->id, &cost)) != NULL) {
            refuse_pose(s, c, cost, cl->tick_cells);
            c->pose_new = 0;
            cl->tick_cells -= cost - (c->has_pose ? tick_cost(s, c) : 0);
        }
    }
    for (int i = 0; i < s->collider_count; i++)
        s->colliders[i].pose_new = 0;
}

/* The client to hold next: the most cells among those over the fair share and
 * neither held now nor held last tick; -1 when there is none. */
static int most_expensive(const service *s, int64_t fair)
{
    int pick = -1;
    for (int i = 0; i < s->client_count; i++) {
        const svc_client *cl = &s->clients[i];
        if (cl->tick_cells <= fair || cl->held || cl->held_last)
            continue;
        if (pick < 0 || cl->tick_cells > s->clients[pick].tick_cells ||
            (cl->tick_cells == s->clients[pick].tick_cells && cl->id < s->clients[pick].id))
            pick = i;
    }
    return pick;
}

static void log_shed(service *s, uint64_t colliders, int64_t total)
{
    double now = time_now_ms();
    s->shed_unlogged += colliders;
    if (s->last_shed_log_ms > 0 && now - s->last_shed_log_ms < 1000.0)
        return;
    log_info("service: tick %llu: %llu collider(s) wait a tick (%lld cells asked for, "
             "max_tick_cells %lld; counted since the last such line)",
             (unsigned long long)s->tick, (unsigned long long)s->shed_unlogged, (long long)total,
             (long long)s->max_tick_cells);
    s->shed_unlogged = 0;
    s->last_shed_log_ms = now;
}

void service_shed(service *s)
{
    THREAD_OWNED(&s->owner);
    if (!s->max_tick_cells)
        return; /* no budget: nothing is ever held, the flags stay 0 */
    int64_t total = 0;
    for (int i = 0; i < s->client_count; i++) {
        svc_client *cl = &s->clients[i];
        cl->held_last = cl->held;
        cl->held = 0;
        cl->tick_cells = 0;
    }
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        c->held = 0;
        svc_client *cl = c->has_pose ? service_find_client(s, c->client) : NULL;
        if (!cl)
            continue;
        int64_t cells = tick_cost(s, c);
        cl->tick_cells += cells;
        total += cells;
    }
    if (total <= s->max_tick_cells)
        return;
    int active = 0;
    for (int i = 0; i < s->client_count; i++)
        active += s->clients[i].tick_cells > 0;
    int64_t left = total, fair = s->max_tick_cells / (active > 0 ? active : 1);
    while (left > s->max_tick_cells && active > 1) {
        int k = most_expensive(s, fair);
        if (k < 0)
            break; /* everyone left went last tick's wait: over budget this tick */
        s->clients[k].held = 1;
        left -= s->clients[k].tick_cells;
        active--;
    }
    uint64_t held = 0;
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        svc_client *cl = c->has_pose ? service_find_client(s, c->client) : NULL;
        if (cl && cl->held) {
            c->held = 1;
            held++;
        }
    }
    if (held) {
        metrics_count_tick_shed(held);
        log_shed(s, held, total);
    }
}
