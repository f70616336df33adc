/*
 * service_edits.c: terrain edits from game logic (issue 22; PROTOCOL.md
 * "edit"), applied at the start of a tick. The edits a tick takes from the
 * hub (websocket `edit` messages and POST /v1/worlds/{name}/edits, in the
 * order they arrived) change the world in that order, each whole or not at
 * all, before the colliders deform it, so the tick's result depends only on
 * its inputs. Their rectangles are logged with the deformation's in the
 * tick's one WAL record and their differences join the tick's tile deltas
 * (service_deltas.c), so subscribers see an edit as an ordinary delta and Σh
 * follows it exactly. Each sender hears, once the tick is committed, the
 * tick the edit took effect and its exact volume change — an HTTP sender
 * only once the tick is published (service_edits_answer), since its thread
 * answers at once and nothing may name a tick before the status does, and
 * durable (under a group commit its answer waits with the tick's frames); a
 * tick the store cannot log takes its edits back and tells their senders so.
 * Sim thread only.
 */
#include "service/service_internal.h"

#include <cjson/cJSON.h>
#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"

/* The outcome to whoever sent the edit: its websocket client or HTTP waiter. */
static void tell(service *s, const svc_edit *e, const hub_edit_result *res)
{
    metrics_count_edit(world_edit_op_name(e->op), res->code == 0, res->volume);
    if (e->waiter) {
        hub_edit_finish(e->waiter, res);
        return;
    }
    cJSON *obj = cJSON_CreateObject();
    if (res->code == 0) {
        cJSON_AddStringToObject(obj, "type", "edited");
        cJSON_AddStringToObject(obj, "op", world_edit_op_name(e->op));
        cJSON_AddNumberToObject(obj, "tick", (double)res->tick);
        cJSON_AddNumberToObject(obj, "volume_change", (double)res->volume);
        cJSON_AddNumberToObject(obj, "x", res->rect.x);
        cJSON_AddNumberToObject(obj, "y", res->rect.y);
        cJSON_AddNumberToObject(obj, "w", res->rect.w);
        cJSON_AddNumberToObject(obj, "h", res->rect.h);
    } else {
        cJSON_AddStringToObject(obj, "type", "error");
        cJSON_AddNumberToObject(obj, "code", res->code);
        cJSON_AddStringToObject(obj, "name", terrad_err_name(res->code));
        cJSON_AddStringToObject(obj, "message", res->message);
    }
    service_reply_json(s, e->client, e->ref, obj);
}

void service_edit_command(service *s, hub_command *c)
{
    svc_edit e = {.op = c->edit->op, .client = c->client, .waiter = c->waiter};
    snprintf(e.ref, sizeof e.ref, "%s", c->ref);
    hub_edit_result res = {.tick = s->tick};
    error_text err = {{0}};
    if (s->store && !store_writable(s->store)) {
        res.code = TERRAD_E_STORE_UNAVAILABLE;
        snprintf(res.message, sizeof res.message, "edit: storage unavailable (%s); nothing changed",
                 store_failure(s->store));
    } else if (array_grow((void **)&s->edits, &s->edit_capacity, (int64_t)s->edit_count + 1,
                          sizeof *s->edits) != 0) {
        res.code = TERRAD_E_INTERNAL;
        snprintf(res.message, sizeof res.message, "edit: out of memory; nothing changed");
    } else if (world_edit_apply(s->world, c->edit, &e.rect, &e.diff, &e.volume, &err) != 0) {
        res.code = TERRAD_E_REFUSED_HEIGHT_LIMIT;
        snprintf(res.message, sizeof res.message, "%s", err.message);
    }
    world_edit_free(c->edit);
    free(c->edit);
    c->edit = NULL;
    if (res.code != 0) {
        tell(s, &e, &res);
        return;
    }
    s->edits[s->edit_count++] = e;
}

int service_edits_commit_rects(service *s, const sim_tick_report *report, const world_rect **rects,
                               int *n)
{
    if (s->edit_count == 0 && report->state_dirty_count == 0) {
        *rects = report->dirty;
        *n = report->dirty_count;
        return 0;
    }
    /* the edits', the deformation's, then where only the per-cell state changed */
    int total = s->edit_count + report->dirty_count + report->state_dirty_count;
    if (array_grow((void **)&s->commit_rects, &s->commit_capacity, total,
                   sizeof *s->commit_rects) != 0)
        return -1;
    for (int i = 0; i < s->edit_count; i++)
        s->commit_rects[i] = s->edits[i].rect;
    if (report->dirty_count)
        memcpy(s->commit_rects + s->edit_count, report->dirty,
               (size_t)report->dirty_count * sizeof *report->dirty);
    if (report->state_dirty_count)
        memcpy(s->commit_rects + s->edit_count + report->dirty_count, report->state_dirty,
               (size_t)report->state_dirty_count * sizeof *report->state_dirty);
    *rects = s->commit_rects;
    *n = total;
    return 0;
}

void service_edits_undo(service *s, int code, const char *why)
{
    for (int i = s->edit_count - 1; i >= 0; i--)
        world_edit_undo(s->world, s->edits[i].rect, s->edits[i].diff);
    for (int i = 0; i < s->edit_count; i++) {
        hub_edit_result res = {.code = code, .tick = s->tick};
        snprintf(res.message, sizeof res.message, "edit: %s; nothing changed", why);
        tell(s, &s->edits[i], &res);
        free(s->edits[i].diff);
    }
    s->edit_count = 0;
}

/* What an applied edit did, for its sender. */
static hub_edit_result applied(const service *s, const svc_edit *e)
{
    return (hub_edit_result){.tick = s->tick, .volume = e->volume, .rect = e->rect};
}

void service_edits_finish(service *s)
{
    int kept = 0;
    for (int i = 0; i < s->edit_count; i++) {
        svc_edit *e = &s->edits[i];
        free(e->diff);
        e->diff = NULL;
        if (e->waiter) { /* its HTTP thread answers at once: not before the tick is published */
            s->edits[kept++] = *e;
            continue;
        }
        hub_edit_result res = applied(s, e); /* a frame: out with the tick's, after the status */
        tell(s, e, &res);
    }
    s->edit_count = kept;
}

/* The HTTP sender's answer (its op counted with it, as tell does). */
static void answer(const svc_edit_answer *a)
{
    metrics_count_edit(world_edit_op_name(a->op), a->res.code == 0, a->res.volume);
    hub_edit_finish(a->waiter, &a->res);
}

void service_edits_answer(service *s)
{
    /* The batch still holds frames once publish() has run only while the
     * store has not made the tick durable (a group commit): an HTTP edit's
     * answer is an acknowledgement, so it waits with them — a crash before the
     * sync would otherwise lose an edit its sender was told took effect. */
    int held = s->batch.out_count > 0 || s->held_answer_count > 0;
    for (int i = 0; i < s->edit_count; i++) {
        svc_edit_answer a = {s->edits[i].waiter, s->edits[i].op, applied(s, &s->edits[i])};
        if (held && array_grow((void **)&s->held_answers, &s->held_answer_capacity,
                               (int64_t)s->held_answer_count + 1, sizeof *s->held_answers) == 0) {
            s->held_answers[s->held_answer_count++] = a;
            continue;
        }
        if (held) { /* no memory to hold it: refuse rather than acknowledge early */
            a.res = (hub_edit_result){.code = TERRAD_E_INTERNAL, .tick = a.res.tick};
            snprintf(a.res.message, sizeof a.res.message,
                     "edit: applied at tick %" PRIu64
                     ", but no memory to hold this answer until that tick is durable "
                     "(watch /v1/stats)",
                     a.res.tick);
        }
        answer(&a);
    }
    s->edit_count = 0;
}

void service_edits_answer_held(service *s)
{
    for (int i = 0; i < s->held_answer_count; i++)
        answer(&s->held_answers[i]);
    s->held_answer_count = 0;
}

void service_edits_free(service *s)
{
    for (int i = 0; i < s->edit_count; i++) {
        hub_edit_finish(s->edits[i].waiter, &(hub_edit_result){.code = TERRAD_E_SHUTTING_DOWN});
        free(s->edits[i].diff);
    }
    for (int i = 0; i < s->held_answer_count; i++) /* their ticks never made durable */
        hub_edit_finish(s->held_answers[i].waiter,
                        &(hub_edit_result){.code = TERRAD_E_SHUTTING_DOWN});
    free(s->held_answers);
    free(s->edits);
    free(s->commit_rects);
}
