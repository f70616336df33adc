/*
 * net_steps.c: a client-clocked world's STEP (PROTOCOL.md "STEP"), the part of
 * the middle layer of the net thread (net_requests_internal.h) that turns a
 * driver's STEP into a hub_step for the world's ticks. Everything the tick
 * cannot judge is judged here, before anything is queued, so a refused step
 * costs nothing but its error: the world's clock (a wall-clocked world takes
 * no step), its driver (one at a time; the first accepted step makes one,
 * leaving ends it), the counts, every pose's values and owner, the storage
 * and the queue's room. Each refusal names its field and is counted in
 * terrad_steps_refused_total{field}. Net thread only.
 */
#include "net/net_requests_internal.h"

#include <stdio.h>
#include <stdlib.h>

#include "metrics/metrics.h"
#include "net/net_control_internal.h"
#include "terrad_proto.h"

static uint32_t rd_u32le(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The step's error: code, the field, the metric. */
#define REFUSE(field, code, collider, ...)                                                         \
    do {                                                                                           \
        metrics_count_step_refused(field);                                                         \
        net_error(c, code, ref, collider, 0, __VA_ARGS__);                                         \
        goto done;                                                                                 \
    } while (0)

/* The poses, checked and made the sim's (orientation into the collider
 * module's axes, as POSE_BATCH's): NULL after an error naming the pose. */
static hub_pose *step_poses(net_client *c, const terrad_pose *in, size_t n, uint32_t seq,
                            const cJSON *ref)
{
    hub_pose *hp = malloc((n ? n : 1) * sizeof *hp);
    if (!hp) {
        net_error(c, TERRAD_E_INTERNAL, ref, -1, 0, "STEP: out of memory");
        return NULL;
    }
    for (size_t i = 0; i < n; i++) {
        const terrad_pose *p = &in[i];
        net_collider_slot *slot = net_collider_find(c->srv, p->id);
        collider_pose cp = {{p->x, p->y, p->z}, {p->qw, p->qx, p->qy, p->qz}};
        error_text err;
        int code = !slot                               ? TERRAD_E_UNKNOWN_COLLIDER
                   : slot->owner != c->id              ? TERRAD_E_NOT_OWNER
                   : collider_pose_validate(&cp, &err) ? TERRAD_E_BAD_VALUE
                                                       : 0;
        if (code) {
            net_error(c, code, ref, p->id, 0, "poses[%zu]: collider %u %s", i, p->id,
                      code == TERRAD_E_UNKNOWN_COLLIDER ? "does not exist"
                      : code == TERRAD_E_NOT_OWNER      ? "belongs to another client"
                                                        : err.message);
            metrics_count_step_refused("poses");
            free(hp);
            return NULL;
        }
        hp[i] = (hub_pose){
            .collider = p->id,
            .client = c->id,
            .sequence = seq,
            .pose = {{p->x, p->y, p->z},
                     collider_wire_orientation((quatd){p->qw, p->qx, p->qy, p->qz}, slot->axis_z)},
        };
    }
    return hp;
}

void net_handle_step(net_client *c, const unsigned char *data, size_t len)
{
    net_state *s = c->srv;
    const net_limits *l = &s->cfg.limits;
    char ref_text[24]; /* "step:SEQ": no POSE_BATCH's ref (a number) looks like it */
    snprintf(ref_text, sizeof ref_text, "step:%u", len >= 8 ? rd_u32le(data + 4) : 0u);
    cJSON *ref = cJSON_CreateString(ref_text);
    terrad_pose *poses = NULL;
    hub_pose *hp = NULL;
    char store_reason[256];
    /* The role is checked here, not where the frame is routed, so that a refusal carries the
     * STEP's ref and the client's wait for that step ends with the error, not a timeout. */
    if (!net_auth_allows(c, AUTH_DRIVER, "STEP", ref)) {
        metrics_count_step_refused("driver");
        goto done;
    }
    if (!s->cfg.world.client_clock)
        REFUSE("clock", TERRAD_E_BAD_VALUE, -1,
               "clock: this world ticks on the server's wall clock (\"clock\": \"wall\"); STEP "
               "needs a world made with \"clock\": \"client\"");
    if (s->driver && s->driver != c->id)
        REFUSE("driver", TERRAD_E_FORBIDDEN, -1,
               "driver: client %u drives this world (one driver at a time; the others may "
               "watch, and the next STEP after it leaves makes a new driver)",
               s->driver);
    size_t cap = len > TERRAD_STEP_FIXED ? (len - TERRAD_STEP_FIXED) / TERRAD_POSE_SIZE : 0;
    poses = malloc((cap ? cap : 1) * sizeof *poses);
    terrad_step_head h = {0};
    long bad = -1;
    int rc = poses ? terrad_step_decode(data, len, &h, poses, cap, &bad) : TERRAD_E_INTERNAL;
    if (rc == TERRAD_E_BAD_FRAME || rc == TERRAD_E_INTERNAL)
        REFUSE("frame", rc, -1, "frame: %s: %zu bytes, not 16 + 32 x count x sets",
               terrad_err_name(rc), len);
    if (h.ticks == 0)
        REFUSE("ticks", TERRAD_E_BAD_VALUE, -1, "ticks: must be at least 1 (got 0)");
    if (h.ticks > (uint32_t)l->max_step_ticks)
        REFUSE("ticks", TERRAD_E_TOO_LARGE, -1, "ticks: %u is over max_step_ticks (%d)", h.ticks,
               l->max_step_ticks);
    if (h.sets > 1 && h.sets != h.ticks)
        REFUSE("sets", TERRAD_E_BAD_VALUE, -1,
               "sets: must be 0 (hold), 1 (the first tick's) or ticks (%u), got %u", h.ticks,
               (unsigned)h.sets);
    if (h.count > l->max_poses_per_batch)
        REFUSE("count", TERRAD_E_TOO_LARGE, -1,
               "count: %u poses per tick is over "
               "max_poses_per_batch (%d)",
               (unsigned)h.count, l->max_poses_per_batch);
    int64_t bad_id =
        bad >= 0 ? (int64_t)rd_u32le(data + TERRAD_STEP_FIXED + (size_t)bad * TERRAD_POSE_SIZE)
                 : -1; /* the decoder checked the length: it is there */
    if (rc == TERRAD_E_BAD_VALUE)
        REFUSE("poses", rc, bad_id,
               "poses[%ld]: not finite, or its quaternion is not unit length (|q| within "
               "0.9..1.1): step dropped",
               bad);
    if (rc)
        REFUSE("frame", rc, -1, "frame: %s", terrad_err_name(rc));
    if (hub_store_unavailable(s->hub, store_reason, sizeof store_reason))
        REFUSE("store", TERRAD_E_STORE_UNAVAILABLE, -1,
               "STEP refused: storage cannot make ticks durable (%s); retry later", store_reason);
    size_t n = (size_t)h.count * h.sets;
    if (!(hp = step_poses(c, poses, n, h.seq, ref)))
        goto done;
    hub_step st = {.client = c->id,
                   .seq = h.seq,
                   .ticks = h.ticks,
                   .count = h.count,
                   .sets = h.sets,
                   .poses = hp};
    if (hub_push_step(s->hub, &st) != 0)
        REFUSE("queue", TERRAD_E_RATE_LIMITED, -1,
               "queue: %d steps already wait for this world's ticks; wait for STEPPED",
               HUB_STEP_CAPACITY);
    hp = NULL; /* the hub's now */
    s->driver = c->id;
done:
    free(hp);
    free(poses);
    cJSON_Delete(ref);
}
