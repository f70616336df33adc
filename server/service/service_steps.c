/*
 * service_steps.c: the ticks of a client-clocked world (PROTOCOL.md "STEP";
 * docs/design.md "Client-clocked worlds"). Such a world ticks only when its
 * driver's STEP says so; each of the step's ticks is an ordinary tick whose
 * input is taken from the step (its pose set for that tick, or none: the
 * colliders hold) on top of what the hub holds, and whose ACK names the step.
 * After the step's last tick its driver gets STEPPED, queued behind that
 * tick's frames, so it goes out when they do: once the tick is durable. A
 * step tick the store could not log ends the step with an error instead.
 *
 * Nothing here reads a clock: which tick takes which poses is the step's
 * order alone, so the same steps give the same heights, soil state and FORCES
 * whatever the thread count, the load or the wall-clock time between steps.
 */
#include "service/service_internal.h"

#include <cjson/cJSON.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"

void service_set_client_clock(service *s, int on)
{
    s->client_clock = on;
}

void service_step_input(service *s)
{
    if (!s->client_clock)
        return;
    service_step_state *st = &s->step;
    if (st->step.ticks == 0) {
        if (!hub_take_step(s->hub, &st->step))
            return; /* a tick with no step: nothing to pose (the clock owed none) */
        st->done = 0;
    }
    hub_step *p = &st->step;
    const hub_pose *set = NULL;
    if (p->sets == 1 && st->done == 0)
        set = p->poses;
    else if (p->sets > 1)
        set = p->poses + (size_t)st->done * (size_t)p->count;
    if (set)
        service_apply_poses(s, set, p->count);
    svc_client *cl = service_find_client(s, p->client);
    if (cl) { /* every stepped tick is acknowledged, naming the step */
        cl->last_sequence = p->seq;
        cl->sequence_pending = 1;
    }
}

/* The step's tick could not be logged (the store cannot write, or its
 * commit failed: deform_and_commit undid it). STEPPED promises durable ticks,
 * so the driver gets an error naming the store instead, the step's remaining
 * ticks and pose sets are dropped, and its ACK is not sent: the world stays at
 * the last logged tick and the driver may send the step again. */
static void step_refuse_store(service *s)
{
    service_step_state *st = &s->step;
    svc_client *cl = service_find_client(s, st->step.client);
    if (cl) {
        if (cl->sequence_pending && cl->last_sequence == st->step.seq)
            cl->sequence_pending = 0;
        char message[300], ref[32];
        snprintf(message, sizeof message,
                 "store: STEP %u: tick %llu (tick %u of %u) could not be made durable (storage "
                 "unavailable or its log failed): the step is dropped, the world stays at the "
                 "last logged tick; retry later",
                 st->step.seq, (unsigned long long)s->tick, st->done + 1, st->step.ticks);
        cJSON *obj = cJSON_CreateObject();
        cJSON_AddStringToObject(obj, "type", "error");
        cJSON_AddNumberToObject(obj, "code", TERRAD_E_STORE_UNAVAILABLE);
        cJSON_AddStringToObject(obj, "name", terrad_err_name(TERRAD_E_STORE_UNAVAILABLE));
        cJSON_AddStringToObject(obj, "message", message);
        snprintf(ref, sizeof ref, "\"step:%u\"", st->step.seq); /* as net_handle_step's refusals */
        service_reply_json(s, cl->id, ref, obj);
    }
    metrics_count_step_refused("store");
    hub_step_free(&st->step);
    memset(&st->step, 0, sizeof st->step);
    st->done = 0;
}

void service_step_finish(service *s)
{
    service_step_state *st = &s->step;
    if (!s->client_clock || st->step.ticks == 0)
        return;
    if (!s->tick_logged) {
        step_refuse_store(s);
        return;
    }
    metrics_count_stepped_ticks(1);
    if (++st->done < st->step.ticks)
        return;
    hub_frame *f = hub_frame_new(1, TERRAD_STEPPED_SIZE);
    if (f &&
        terrad_stepped_encode(f->data, f->len, NULL, s->tick, st->step.seq, st->step.ticks) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    if (service_find_client(s, st->step.client))
        service_queue_client(s, st->step.client, f, TERRAD_MSG_STEPPED, 0);
    else if (f)
        hub_frame_unref(f); /* the driver left meanwhile: its ticks ran, nobody to tell */
    metrics_count_steps(1);
    hub_step_free(&st->step);
    memset(&st->step, 0, sizeof st->step);
    st->done = 0;
}

int service_step_remaining(const service *s)
{
    return s->step.step.ticks ? (int)(s->step.step.ticks - s->step.done) : 0;
}
