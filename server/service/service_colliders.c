/*
 * service_colliders.c: COLLIDERS frames (PROTOCOL.md "COLLIDERS") — where
 * every collider is, for viewers that subscribed with "colliders": true.
 * Built after the tick's deltas, per client, only when the list changed (at
 * most every COLLIDERS_EVERY_TICKS ticks) or has not been sent for
 * COLLIDERS_REFRESH_TICKS. A client whose subscription asked for "grousers"
 * gets the grousers extension (each entry's lugs after it, the header flag)
 * whenever an entry of its list has lugs; otherwise the frame is the plain
 * one, byte for byte what a client that predates the extension decodes.
 * Sim thread only.
 */
#include "service/service_internal.h"

#include <math.h>

/* COLLIDERS frames: at most one every this many ticks (20 Hz at 60 Hz), and
 * an unchanged list again after COLLIDERS_REFRESH_TICKS, which heals a frame
 * the network dropped for a slow client. */
#define COLLIDERS_EVERY_TICKS 3
#define COLLIDERS_REFRESH_TICKS 60

/* The drawable description of a collider, in the sim's frame (capsule and
 * cylinder axes along y, as PROTOCOL.md's COLLIDERS says). */
static terrad_collider_state collider_state(const collider_geometry *g, collider_pose pose,
                                            uint32_t id, uint8_t owner)
{
    terrad_collider_state st = {.id = id, .owner = owner};
    switch (g->shape) {
    case COLLIDER_SPHERE:
        st.kind = TERRAD_KIND_SPHERE;
        st.dims[0] = (float)g->radius;
        break;
    case COLLIDER_BOX:
        st.kind = TERRAD_KIND_BOX;
        st.dims[0] = (float)g->half_extents.x;
        st.dims[1] = (float)g->half_extents.y;
        st.dims[2] = (float)g->half_extents.z;
        break;
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER:
        st.kind = g->shape == COLLIDER_CAPSULE ? TERRAD_KIND_CAPSULE : TERRAD_KIND_CYLINDER;
        st.dims[0] = (float)g->radius;
        st.dims[1] = (float)g->half_length;
        break;
    case COLLIDER_MESH:
        st.kind = TERRAD_KIND_MESH;
        for (int v = 0; g->mesh && v < g->mesh->vertex_count; v++)
            for (int k = 0; k < 3; k++) {
                float a = fabsf(g->mesh->vertices[3 * v + k]);
                if (a > st.dims[k])
                    st.dims[k] = a;
            }
        break;
    }
    st.p[0] = (float)pose.position.x;
    st.p[1] = (float)pose.position.y;
    st.p[2] = (float)pose.position.z;
    quatd q = quat_normalize(pose.orientation);
    st.q[0] = (float)q.w;
    st.q[1] = (float)q.x;
    st.q[2] = (float)q.y;
    st.q[3] = (float)q.z;
    return st;
}

/* The wire's grousers of a collider: none but on a lugged cylinder (wheel). */
static terrad_collider_grousers collider_lugs(const collider_geometry *g)
{
    terrad_collider_grousers l = {0};
    if (g->shape == COLLIDER_CYLINDER && g->grousers.count > 0) {
        l.count = (uint16_t)g->grousers.count;
        l.height_m = (float)g->grousers.height;
        l.thickness_m = (float)g->grousers.thickness;
    }
    return l;
}

/* Does the collider's footprint meet one of the client's collider-subscriptions? */
static int collider_in_view(const service *s, const svc_client *cl, const collider_geometry *g,
                            collider_pose pose)
{
    vec3d lo, hi;
    collider_bounds(g, pose, &lo, &hi);
    double cs = s->world->cell_size_m;
    double x0 = floor(lo.x / cs), y0 = floor(lo.y / cs), x1 = floor(hi.x / cs),
           y1 = floor(hi.y / cs);
    for (int i = 0; i < cl->sub_count; i++) {
        const world_rect r = cl->subs[i].rect;
        if (cl->subs[i].colliders && x1 >= r.x && x0 < (double)r.x + r.w && y1 >= r.y &&
            y0 < (double)r.y + r.h)
            return 1;
    }
    return 0;
}

/* A frame holds at most TERRAD_MAX_COUNT colliders (the protocol's bound):
 * the rest of a crowded view is left out. */
static int push_state(service *s, int *n, const collider_geometry *g, terrad_collider_state st)
{
    if (*n >= TERRAD_MAX_COUNT)
        return -1;
    if (array_grow((void **)&s->states, &s->state_capacity, (int64_t)*n + 1, sizeof *s->states) !=
            0 ||
        array_grow((void **)&s->lugs, &s->lug_capacity, (int64_t)*n + 1, sizeof *s->lugs) != 0) {
        service_note_drop(s, "frame", "no memory for a COLLIDERS entry: the list is cut short");
        return -1;
    }
    s->lugs[*n] = collider_lugs(g);
    s->states[(*n)++] = st;
    return 0;
}

/* The client's frame of n entries: with the grousers extension when it asked
 * and an entry has lugs. NULL: no memory or an entry the codec refuses. */
static hub_frame *colliders_frame(service *s, int n, int lugged)
{
    size_t size =
        lugged ? terrad_colliders_grousers_size((size_t)n) : terrad_colliders_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (!f)
        return NULL;
    int rc = lugged
                 ? terrad_colliders_encode_grousers(f->data, size, &f->len, s->tick, s->states,
                                                    s->lugs, (size_t)n)
                 : terrad_colliders_encode(f->data, size, &f->len, s->tick, s->states, (size_t)n);
    if (rc != 0) {
        hub_frame_unref(f);
        return NULL;
    }
    return f;
}

/* FNV-1a over the encoded entries: "did anything change since the last frame". */
static uint64_t states_hash(const uint8_t *p, size_t len)
{
    uint64_t h = 1469598103934665603ull;
    for (size_t i = 0; i < len; i++)
        h = (h ^ p[i]) * 1099511628211ull;
    return h | 1; /* never 0: 0 means "nothing sent yet" */
}

/* Per client that asked for it: the colliders meeting its regions, when the
 * list changed (at most every COLLIDERS_EVERY_TICKS ticks) or has not been
 * sent for COLLIDERS_REFRESH_TICKS. */
void service_publish_colliders(service *s, const sim_collider *extra, int extra_count)
{
    THREAD_OWNED(&s->owner);
    for (int c = 0; c < s->client_count; c++) {
        svc_client *cl = &s->clients[c];
        int wants = 0, wants_lugs = 0;
        for (int i = 0; i < cl->sub_count; i++) {
            wants |= cl->subs[i].colliders;
            wants_lugs |= cl->subs[i].colliders && cl->subs[i].grousers;
        }
        if (!wants)
            continue;
        uint64_t since = s->tick - cl->colliders_sent_tick;
        if (cl->colliders_hash != 0 && since < COLLIDERS_EVERY_TICKS)
            continue;
        int n = 0;
        for (int i = 0; i < s->collider_count; i++) {
            const svc_collider *k = &s->colliders[i];
            if (k->has_pose && collider_in_view(s, cl, k->geometry, k->pose))
                push_state(
                    s, &n, k->geometry,
                    collider_state(k->geometry, k->pose, k->id,
                                   k->client == cl->id ? TERRAD_OWNER_OWN : TERRAD_OWNER_OTHER));
        }
        for (int i = 0; i < extra_count; i++)
            if (collider_in_view(s, cl, extra[i].geometry, extra[i].pose))
                push_state(s, &n, extra[i].geometry,
                           collider_state(extra[i].geometry, extra[i].pose, (uint32_t)extra[i].id,
                                          TERRAD_OWNER_DEMO));
        int lugged = 0;
        for (int i = 0; wants_lugs && i < n; i++)
            lugged |= s->lugs[i].count > 0;
        hub_frame *f = colliders_frame(s, n, lugged);
        if (!f) {
            service_queue_client(s, cl->id, NULL, TERRAD_MSG_COLLIDERS, 0); /* counted as dropped */
            continue;
        }
        uint64_t h = states_hash(f->data + TERRAD_COLLIDERS_FIXED, f->len - TERRAD_COLLIDERS_FIXED);
        if (h == cl->colliders_hash && since < COLLIDERS_REFRESH_TICKS) {
            hub_frame_unref(f);
            continue;
        }
        cl->colliders_hash = h;
        cl->colliders_sent_tick = s->tick;
        service_queue_client(s, cl->id, f, TERRAD_MSG_COLLIDERS, 0);
    }
}
