/*
 * service_contacts.c: contact feedback (PROTOCOL.md "CONTACT") and the
 * tick's ACKs. Each collider with feedback is measured against the terrain
 * before the deformation (how deep it sinks, where, the surface normal);
 * after the deformation the support height under it is filled in, and each
 * client gets one CONTACT frame with its colliders, in a world of the
 * bekker model one FORCES frame (the soil's push the engine summed), and one
 * ACK of the latest pose batch the tick used. A load-driven collider's
 * CONTACT is the engine's, measured where the engine put it (its height is
 * the server's, not the pose's). Sim thread only.
 */
#include "service/service_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static double height_m(const world *w, int x, int y)
{
    x = x < 0 ? 0 : x >= w->width ? w->width - 1 : x;
    y = y < 0 ? 0 : y >= w->height ? w->height - 1 : y;
    return (double)world_height_at(w, x, y) / w->units_per_m;
}

/* -1 when there was no memory to measure (the contact then says nothing). */
static int contact_measure(service *s, const svc_collider *c, terrad_contact *out)
{
    const world *w = s->world;
    memset(out, 0, sizeof *out);
    out->id = c->id;
    vec3d lo, hi;
    collider_bounds(c->geometry, c->pose, &lo, &hi);
    double cs = w->cell_size_m;
    world_rect r = {(int)floor(fmax(fmin(lo.x / cs, 1e9), -1e9)),
                    (int)floor(fmax(fmin(lo.y / cs, 1e9), -1e9)), 0, 0};
    r.w = (int)floor(fmax(fmin(hi.x / cs, 1e9), -1e9)) - r.x + 1;
    r.h = (int)floor(fmax(fmin(hi.y / cs, 1e9), -1e9)) - r.y + 1;
    int cx = (int)floor(c->pose.position.x / cs), cy = (int)floor(c->pose.position.y / cs);
    double nx = 0, ny = 0, nz = 0;
    int64_t deepest = -1;
    if (world_clip_rect(w, &r)) {
        int64_t n = (int64_t)r.w * r.h;
        if (array_grow((void **)&s->bottom, &s->bottom_cap, n, sizeof *s->bottom) != 0)
            return -1;
        sim_collider one = {.geometry = c->geometry, .pose = c->pose};
        sim_window_job job = {.rect = r,
                              .cell_size_m = cs,
                              .units_per_m = w->units_per_m,
                              .colliders = &one,
                              .collider_count = 1};
        sim_window_depth(&job, s->bottom);
        for (int y = 0; y < r.h; y++) {
            for (int x = 0; x < r.w; x++) {
                int32_t b = s->bottom[(int64_t)y * r.w + x];
                if (b == COLLIDER_BOTTOM_NONE)
                    continue;
                int wx = r.x + x, wy = r.y + y;
                int32_t h = world_height_at(w, wx, wy);
                if (b >= h)
                    continue;
                int64_t pen = (int64_t)h - b;
                out->volume += pen;
                out->cells++;
                if (pen > deepest) { /* row-major scan: ties keep the lowest row, column */
                    deepest = pen;
                    out->deepest[0] = (float)((wx + 0.5) * cs);
                    out->deepest[1] = (float)((wy + 0.5) * cs);
                    out->deepest[2] = (float)((double)b / w->units_per_m);
                }
                double gx = (height_m(w, wx + 1, wy) - height_m(w, wx - 1, wy)) / (2 * cs);
                double gy = (height_m(w, wx, wy + 1) - height_m(w, wx, wy - 1)) / (2 * cs);
                double len = sqrt(gx * gx + gy * gy + 1.0);
                nx += -gx / len;
                ny += -gy / len;
                nz += 1.0 / len;
            }
        }
    }
    if (out->cells == 0) {
        double gx = (height_m(w, cx + 1, cy) - height_m(w, cx - 1, cy)) / (2 * cs);
        double gy = (height_m(w, cx, cy + 1) - height_m(w, cx, cy - 1)) / (2 * cs);
        nx = -gx;
        ny = -gy;
        nz = 1.0;
        out->deepest[0] = (float)c->pose.position.x;
        out->deepest[1] = (float)c->pose.position.y;
        out->deepest[2] = NAN; /* filled with the support height after the tick */
    }
    double len = sqrt(nx * nx + ny * ny + nz * nz);
    out->normal[0] = (float)(nx / len);
    out->normal[1] = (float)(ny / len);
    out->normal[2] = (float)(nz / len);
    out->area_m2 = (float)(out->cells * cs * cs);
    return 0;
}

void service_contacts_before_tick(service *s)
{
    THREAD_OWNED(&s->owner);
    service_batch *b = &s->batch;
    b->contact_count = 0;
    for (int i = 0; i < s->collider_count; i++) {
        svc_collider *c = &s->colliders[i];
        if (!c->feedback || !c->has_pose)
            continue;
        if (array_grow((void **)&b->contacts, &b->contact_capacity, (int64_t)b->contact_count + 1,
                       sizeof *b->contacts) != 0) {
            service_note_drop(s, "contact", "no memory for the contacts of %d colliders",
                              s->collider_count - i);
            return;
        }
        if (contact_measure(s, c, &b->contacts[b->contact_count].contact) != 0)
            service_note_drop(s, "contact", "no memory to measure collider %u", c->id);
        b->contacts[b->contact_count++].client = c->client;
    }
}

/* A load-driven collider's contact is the engine's, measured in the model's
 * press at the height the engine found for it against the heights before the
 * deformation (sim_contact's CONTACT fields): the client's pose height,
 * which contact_measure saw, is not where the collider stood. */
static void contact_from_engine(const world *w, const sim_tick_report *report, terrad_contact *ct)
{
    for (int i = 0; i < report->contact_count; i++) {
        const sim_contact *e = &report->contacts[i];
        if ((uint32_t)e->collider_id != ct->id)
            continue;
        ct->volume = e->volume;
        ct->cells = e->cells > UINT32_MAX ? UINT32_MAX : (uint32_t)e->cells;
        ct->area_m2 = (float)(e->cells * w->cell_size_m * w->cell_size_m);
        if (e->cells == 0)
            return; /* no contact: contact_measure's normal and centre stand */
        double len =
            sqrt(e->normal_sum[0] * e->normal_sum[0] + e->normal_sum[1] * e->normal_sum[1] +
                 e->normal_sum[2] * e->normal_sum[2]);
        for (int a = 0; a < 3; a++) {
            ct->deepest[a] = (float)e->deepest[a];
            ct->normal[a] = (float)(e->normal_sum[a] / len);
        }
        return;
    }
}

void service_contacts_after_tick(service *s, const sim_tick_report *report)
{
    const world *w = s->world;
    for (int i = 0; i < s->batch.contact_count; i++) {
        terrad_contact *ct = &s->batch.contacts[i].contact;
        int k = service_find_collider(s, ct->id);
        if (k < 0)
            continue;
        if (s->colliders[k].load_n > 0.0 && !s->colliders[k].held) {
            ct->volume = 0, ct->cells = 0, ct->area_m2 = 0.0f;
            ct->deepest[0] = (float)s->colliders[k].pose.position.x;
            ct->deepest[1] = (float)s->colliders[k].pose.position.y;
            ct->deepest[2] = NAN; /* the support height below, unless in contact */
            contact_from_engine(w, report, ct);
        }
        const collider_pose *p = &s->colliders[k].pose;
        int cx = (int)floor(p->position.x / w->cell_size_m);
        int cy = (int)floor(p->position.y / w->cell_size_m);
        ct->support_height_m = (float)height_m(w, cx, cy);
        if (isnan(ct->deepest[2]))
            ct->deepest[2] = ct->support_height_m;
    }
}

/* One client's CONTACT frame: its share of the tick's contacts. */
static void send_contacts(service *s, const svc_client *cl)
{
    const service_batch *b = &s->batch;
    int n = 0;
    for (int i = 0; i < b->contact_count; i++)
        n += b->contacts[i].client == cl->id;
    if (n == 0)
        return;
    terrad_contact *mine = malloc((size_t)n * sizeof *mine);
    if (!mine) {
        service_note_drop(s, "frame", "no memory for the CONTACT frame of client %u", cl->id);
        return;
    }
    int k = 0;
    for (int i = 0; i < b->contact_count; i++)
        if (b->contacts[i].client == cl->id)
            mine[k++] = b->contacts[i].contact;
    size_t size = terrad_contact_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (f && terrad_contact_encode(f->data, size, &f->len, s->tick, mine, (size_t)n) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    service_queue_client(s, cl->id, f, TERRAD_MSG_CONTACT, 0);
    free(mine);
}

/* One client's FORCES frame (bekker worlds): the soil's push on each of its
 * colliders with feedback, in the tick's collider order. When one of them was
 * created with "forces_height", every entry carries its pose height the tick
 * deformed at (a load-driven one's: found by the server), an extension
 * flagged in the header (PROTOCOL.md "FORCES"), so a client that never asks
 * gets the frames it always did. */
static void send_forces(service *s, const svc_client *cl, const sim_tick_report *report)
{
    int n = 0, heights = 0;
    for (int i = 0; i < report->contact_count; i++) {
        int k = service_find_collider(s, (uint32_t)report->contacts[i].collider_id);
        int mine = k >= 0 && s->colliders[k].client == cl->id && s->colliders[k].feedback;
        n += mine;
        heights |= mine && s->colliders[k].forces_height;
    }
    if (n == 0)
        return;
    terrad_force *mine = malloc((size_t)n * (sizeof *mine + sizeof(double)));
    if (!mine) {
        service_note_drop(s, "frame", "no memory for the FORCES frame of client %u", cl->id);
        return;
    }
    double *height = (double *)(void *)(mine + n); /* 48-byte entries: aligned */
    int m = 0;
    for (int i = 0; i < report->contact_count; i++) {
        const sim_contact *c = &report->contacts[i];
        int k = service_find_collider(s, (uint32_t)c->collider_id);
        if (k < 0 || s->colliders[k].client != cl->id || !s->colliders[k].feedback)
            continue;
        terrad_force *f = &mine[m++];
        f->id = (uint32_t)c->collider_id;
        for (int a = 0; a < 3; a++) {
            f->force[a] = (float)c->force_n[a];
            f->torque[a] = (float)c->torque_nm[a];
        }
        f->sinkage_m = (float)c->sinkage_m;
        f->area_m2 = (float)c->area_m2;
        f->patch_width_m = (float)c->patch_width_m;
        f->slip = (float)c->slip;
        f->cells = c->cells > UINT32_MAX ? UINT32_MAX : (uint32_t)c->cells;
        height[m - 1] = c->pose_z_m;
    }
    size_t size = heights ? terrad_forces_heights_size((size_t)n) : terrad_forces_size((size_t)n);
    hub_frame *f = hub_frame_new(1, size);
    if (f &&
        (heights ? terrad_forces_encode_heights(f->data, size, &f->len, s->tick, mine, height,
                                                (size_t)n)
                 : terrad_forces_encode(f->data, size, &f->len, s->tick, mine, (size_t)n)) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    service_queue_client(s, cl->id, f, TERRAD_MSG_FORCES, 0);
    free(mine);
}

void service_publish_feedback(service *s, const sim_tick_report *report)
{
    THREAD_OWNED(&s->owner);
    for (int c = 0; c < s->client_count; c++) {
        svc_client *cl = &s->clients[c];
        send_contacts(s, cl);
        send_forces(s, cl, report);
        /* a held client's poses were not used; a tick the store did not log
         * (refused or not writable) is not acknowledged at all: its number
         * is not in the log, so a new owner or a restart would reuse it for
         * other heights. The batch stays pending and the next logged tick,
         * which deforms with its poses, ACKs it. */
        if (cl->sequence_pending && !cl->held && s->tick_logged) {
            hub_frame *f = hub_frame_new(1, TERRAD_ACK_SIZE);
            if (f && terrad_ack_encode(f->data, TERRAD_ACK_SIZE, &f->len, s->tick,
                                       cl->last_sequence) != 0) {
                hub_frame_unref(f);
                f = NULL;
            }
            service_queue_client(s, cl->id, f, TERRAD_MSG_ACK, 0);
            cl->sequence_pending = 0;
        }
    }
}
