/*
 * service_commands.c: the first step of a tick (docs/design.md) — take what
 * the net thread queued in the hub and apply it to the sim's view of the
 * clients: commands (join/leave, collider create/delete, subscribe,
 * unsubscribe, resync), the latest pose of each collider, and the batch
 * sequences the tick will ACK. Sim thread only.
 */
#include "service/service_internal.h"

#include "metrics/metrics.h"

#include <stdlib.h>
#include <string.h>

void service_release_collider(service *s, svc_collider *c)
{
    sim_backend *backend = sim_engine_backend(s->engine);
    backend->forget_geometry(backend, c->geometry);
    free(c->geometry);
    c->geometry = NULL;
    if (c->mesh) {
        collider_mesh_free(c->mesh);
        free(c->mesh);
        c->mesh = NULL;
    }
}

static void remove_collider(service *s, int index)
{
    service_release_collider(s, &s->colliders[index]);
    memmove(&s->colliders[index], &s->colliders[index + 1],
            (size_t)(s->collider_count - index - 1) * sizeof *s->colliders);
    s->collider_count--;
}

/* 1 when the pending request ending at job `end` is the same client's same
 * list of rectangles as subs (deduplicated like queue_snapshots does). */
static void queue_snapshot_jobs(service *s, uint32_t client, const svc_subscription *subs, int n)
{
    service_batch *b = &s->batch;
    for (int i = 0; i < n; i++) {
        if (array_grow((void **)&b->snapshots, &b->snapshot_capacity,
                       (int64_t)b->snapshot_count + 1, sizeof *b->snapshots) != 0) {
            service_note_drop(s, "snapshot", "no memory for %d snapshot requests of client %u",
                              n - i, client);
            return;
        }
        b->snapshots[b->snapshot_count++] =
            (snapshot_job){.client = client, .rect = subs[i].rect, .last = i == n - 1};
    }
}

static int same_request(const service_batch *b, int end, uint32_t client, const world_rect *rects,
                        int n)
{
    int start = end;
    while (start > 0 && !b->snapshots[start - 1].last)
        start--;
    if (end - start + 1 != n)
        return 0;
    for (int i = 0; i < n; i++) {
        const snapshot_job *j = &b->snapshots[start + i];
        if (j->client != client || memcmp(&j->rect, &rects[i], sizeof rects[i]) != 0)
            return 0;
    }
    return 1;
}

/* A subscribe's or resync's snapshot request joins the pending queue
 * (answered by service_publish_snapshots within the per-tick budget). The
 * same rectangle twice in one request is built once (the client's frames
 * serve all its subscriptions); a request identical to one of the same
 * client still pending is coalesced into it: one more snapshot_done mark,
 * no second build (a resync flood costs one build per tick at most). */
static void queue_snapshots(service *s, uint32_t client, const svc_subscription *subs, int n)
{
    service_batch *b = &s->batch;
    world_rect *rects = malloc(((size_t)n + 1) * sizeof *rects);
    int k = 0;
    for (int i = 0; rects && i < n; i++) {
        int dup = 0;
        for (int j = 0; j < k && !dup; j++)
            dup = memcmp(&rects[j], &subs[i].rect, sizeof rects[j]) == 0;
        if (!dup)
            rects[k++] = subs[i].rect;
    }
    for (int e = 0; rects && k > 0 && e < b->snapshot_count; e++) {
        if (b->snapshots[e].last && b->snapshots[e].client == client &&
            same_request(b, e, client, rects, k)) {
            b->snapshots[e].marks++;
            metrics_count_snapshots_coalesced(1);
            free(rects);
            return;
        }
    }
    if (rects) {
        svc_subscription *packed = calloc((size_t)k + 1, sizeof *packed);
        for (int i = 0; packed && i < k; i++)
            packed[i].rect = rects[i];
        if (packed && k != n) {
            free(rects);
            queue_snapshot_jobs(s, client, packed, k);
            free(packed);
            return;
        }
        free(packed);
        free(rects);
    }
    queue_snapshot_jobs(s, client, subs, n);
}

static void client_join(service *s, svc_client *cl, uint32_t id, int snapshot_base)
{
    if (cl)
        return;
    if (array_grow((void **)&s->clients, &s->client_capacity, (int64_t)s->client_count + 1,
                   sizeof *s->clients) != 0) {
        service_note_drop(s, "command", "no memory for client %u", id);
        return;
    }
    s->clients[s->client_count++] = (svc_client){.id = id, .snapshot_base = snapshot_base};
}

static void client_leave(service *s, svc_client *cl, uint32_t id)
{
    for (int i = s->collider_count - 1; i >= 0; i--)
        if (s->colliders[i].client == id)
            remove_collider(s, i);
    if (cl) {
        free(cl->subs);
        *cl = s->clients[--s->client_count];
    }
}

static void collider_create(service *s, hub_command *c)
{
    collider_geometry *g = malloc(sizeof *g);
    int known = service_find_collider(s, c->collider) >= 0 ||
                (s->collider_count && s->colliders[s->collider_count - 1].id > c->collider);
    if (!g || known ||
        array_grow((void **)&s->colliders, &s->collider_capacity, (int64_t)s->collider_count + 1,
                   sizeof *s->colliders) != 0) {
        if (!known) /* the net thread gives out each id once, in order */
            service_note_drop(s, "command", "no memory for collider %u of client %u", c->collider,
                              c->client);
        free(g);
        if (c->mesh) {
            collider_mesh_free(c->mesh);
            free(c->mesh);
        }
        return;
    }
    *g = c->geometry;
    g->mesh = c->mesh;
    /* the net thread sends an all-zero orientation for "no pose yet" */
    const quatd *q = &c->pose.orientation;
    int has_pose = q->w != 0 || q->x != 0 || q->y != 0 || q->z != 0;
    s->colliders[s->collider_count++] =
        (svc_collider){.id = c->collider,
                       .client = c->client,
                       .geometry = g,
                       .mesh = c->mesh,
                       .pose = c->pose,
                       .previous_pose = c->pose,
                       .has_pose = has_pose,
                       .feedback = c->feedback,
                       .load_n = c->load_n,
                       .forces_height = c->forces_height,
                       .cost = collider_cost_of(g, s->world->cell_size_m)};
    c->mesh = NULL;
}

static void subscribe(service *s, svc_client *cl, const hub_command *c)
{
    /* the net thread pauses nothing for a subscribe, but it counts one
     * snapshot mark per request: send it even when there is nothing */
    svc_subscription sub = {.id = c->subscription,
                            .rect = c->rect,
                            .colliders = c->colliders,
                            .grousers = c->grousers,
                            .footprints = c->footprints};
    if (cl && c->colliders)
        cl->colliders_hash = 0; /* a new region: send the list at the next chance */
    if (cl && array_grow((void **)&cl->subs, &cl->sub_capacity, (int64_t)cl->sub_count + 1,
                         sizeof *cl->subs) == 0) {
        cl->subs[cl->sub_count++] = sub;
    } else {
        if (cl)
            service_note_drop(s, "command", "no memory for a subscription of client %u", cl->id);
        sub.rect = (world_rect){0, 0, 0, 0};
    }
    queue_snapshots(s, c->client, &sub, 1);
}

static void resync(service *s, svc_client *cl, const hub_command *c)
{
    if (!cl)
        return;
    if (c->subscription == 0) {
        queue_snapshots(s, cl->id, cl->subs, cl->sub_count);
        if (cl->sub_count == 0) /* nothing to send, but the client waits for the mark */
            queue_snapshots(s, cl->id, &(svc_subscription){.id = 0}, 1);
    } else {
        svc_subscription sub = {.id = c->subscription};
        for (int i = 0; i < cl->sub_count; i++)
            if (cl->subs[i].id == c->subscription)
                sub = cl->subs[i];
        queue_snapshots(s, cl->id, &sub, 1); /* one mark, even for a gone subscription */
    }
}

static void apply_command(service *s, hub_command *c)
{
    svc_client *cl = service_find_client(s, c->client);
    switch (c->kind) {
    case HUB_CLIENT_JOINED:
        client_join(s, cl, c->client, c->snapshot_base);
        break;
    case HUB_CLIENT_LEFT:
        service_drop_snapshots(s, c->client); /* never built for a client that is gone */
        client_leave(s, cl, c->client);
        break;
    case HUB_COLLIDER_CREATE:
        collider_create(s, c);
        break;
    case HUB_COLLIDER_DELETE: {
        int i = service_find_collider(s, c->collider);
        if (i >= 0 && s->colliders[i].client == c->client)
            remove_collider(s, i);
        break;
    }
    case HUB_SUBSCRIBE:
        subscribe(s, cl, c);
        break;
    case HUB_UNSUBSCRIBE:
        for (int i = 0; cl && i < cl->sub_count; i++)
            if (cl->subs[i].id == c->subscription) {
                cl->subs[i] = cl->subs[--cl->sub_count];
                break;
            }
        break;
    case HUB_RESYNC:
        resync(s, cl, c);
        break;
    case HUB_EDIT:
        service_edit_command(s, c);
        break;
    case HUB_RESYNC_TILE:
        if (cl)
            service_resync_tile(s, c);
        break;
    }
}

void service_apply_poses(service *s, const hub_pose *poses, int n)
{
    service_batch *b = &s->batch;
    for (int i = 0; i < n; i++) {
        const hub_pose *p = &poses[i];
        int k = service_find_collider(s, p->collider);
        if (k < 0 || s->colliders[k].client != p->client)
            continue; /* deleted meanwhile */
        svc_collider *c = &s->colliders[k];
        if (!c->pose_new) { /* where it stood: a refused pose leaves it there */
            c->pose_new = 1;
            c->had_pose = c->has_pose;
            c->pose_before = c->pose;
        }
        c->pose_sequence = p->sequence;
        if (!c->has_pose) {
            c->has_pose = 1;
            c->has_previous = 0; /* no sweep from a pose it never had */
        }
        c->pose = p->pose;
        if (b->oldest_pose_ms == 0 || p->received_ms < b->oldest_pose_ms)
            b->oldest_pose_ms = p->received_ms;
    }
}

/* The batches (empty ones too) this tick answers with an ACK: taken with
 * their poses (hub_take_input), so the ACK names the batch the tick used. */
static void apply_batches(service *s, int n)
{
    for (int i = 0; i < n; i++) {
        svc_client *cl = service_find_client(s, s->batch.batches[i].client);
        if (cl) {
            cl->last_sequence = s->batch.batches[i].sequence;
            cl->sequence_pending = 1;
        }
    }
}

void service_take_input(service *s)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    int n = hub_take_commands(s->hub, b->commands, SERVICE_COMMANDS_PER_TICK);
    for (int i = 0; i < n; i++)
        apply_command(s, &b->commands[i]);
    b->oldest_pose_ms = 0;
    int batches = 0;
    if (array_grow((void **)&b->poses, &b->pose_capacity, (int64_t)s->collider_count + 64,
                   sizeof *b->poses) == 0) {
        int poses;
        batches = hub_take_input(s->hub, b->poses, (int)b->pose_capacity, &poses, b->batches);
        service_apply_poses(s, b->poses, poses);
    } else { /* poses and batches stay in the hub (latest wins) for the next tick */
        service_note_drop(s, "poses", "no memory to take the poses of %d colliders this tick",
                          s->collider_count);
    }
    apply_batches(s, batches);
    service_step_input(s);   /* a client-clocked world: the step's poses win */
    service_bound_sweeps(s); /* before anything measures the poses */
}
