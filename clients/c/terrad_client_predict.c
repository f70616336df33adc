/*
 * terrad_client_predict.c: client-side prediction in the C client
 * (terrad_client.h "Prediction", docs/engines.md): the client's side of the
 * twin library's prediction (terrad_twin.h, terrad_twin_prediction_*), the
 * one copy every client runs. This file makes a prediction from a complete
 * mirror and the world, and hands it the client's events: each pose batch
 * sent (one tick of the twin at once, before the bytes leave), each ACK (the
 * mirror then holds the server's heights at its tick: reconcile), each own
 * collider created or deleted. An event the twin fails on (a soil state it
 * could not restore at an ACK, out of memory) is counted in the prediction's
 * stats with its sentence, and the client goes on: the frame is processed and
 * the next ACK reconciles again.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L
#endif

#include "terrad_client_internal.h"
#include "terrad_twin.h"

#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct terrad_prediction {
    terrad_prediction *next;
    terrad_client *client;
    uint32_t sid;
    terrad_twin_prediction *twin;
    terrad_prediction_stats stats; /* the twin's, as of the last event, and errors */
    char last_error[TERRAD_TWIN_ERROR_MAX];
};

static void sync_stats(terrad_prediction *p)
{
    const terrad_twin_prediction_stats *t = terrad_twin_prediction_get_stats(p->twin);
    p->stats = (terrad_prediction_stats){t->predicted,      t->reconciled, t->replayed,
                                         t->exact,          t->skipped,    t->on_time,
                                         t->last_differing, t->pending,    p->stats.errors};
}

/* The twin's call for one of the client's events returned rc: a failure is
 * counted with its sentence (err), and the client goes on. */
static void took(terrad_prediction *p, int rc, const char *err)
{
    if (rc == 0)
        return;
    p->stats.errors++;
    snprintf(p->last_error, sizeof p->last_error, "%s", err);
}

/* The twin's copy of an own collider (only default-material ones: the twin
 * presses with the world's material); a wheel with its grousers, if any. */
static int add_shape(terrad_prediction *p, const client_own *o, char *err)
{
    static const char *const shapes[] = {[TERRAD_SHAPE_SPHERE] = "sphere",
                                         [TERRAD_SHAPE_BOX] = "box",
                                         [TERRAD_SHAPE_CAPSULE] = "capsule",
                                         [TERRAD_SHAPE_CYLINDER] = "cylinder",
                                         [TERRAD_SHAPE_WHEEL] = "wheel"};
    if (!o->default_material)
        return 0;
    if ((unsigned)o->shape >= sizeof shapes / sizeof shapes[0] || !shapes[o->shape]) {
        snprintf(err, TERRAD_TWIN_ERROR_MAX, "shape: %d cannot be predicted", (int)o->shape);
        return -1;
    }
    if (o->shape == TERRAD_SHAPE_WHEEL)
        return terrad_twin_prediction_add_wheel(p->twin, o->id, o->radius, o->width / 2,
                                                o->lugs.count, o->lugs.height, o->lugs.thickness,
                                                err);
    return terrad_twin_prediction_add_collider(p->twin, o->id, shapes[o->shape], o->radius,
                                               o->half_length, o->half_extents[0],
                                               o->half_extents[1], o->half_extents[2], err);
}

/* ... and a load-driven one's load: the twin finds its height as the server does. */
static int add_own(terrad_prediction *p, const client_own *o, char *err)
{
    if (add_shape(p, o, err) != 0)
        return -1;
    if (o->default_material && o->load_n > 0.0)
        return terrad_twin_prediction_set_load(p->twin, o->id, o->load_n, err);
    return 0;
}

/* "key=value" pairs into the twin's config; -1 with err naming the key. */
static int parse_config(terrad_twin_config *cfg, const char *text, char *err)
{
    const char *s = text;
    while (*s) {
        while (*s && (isspace((unsigned char)*s) || *s == ',' || *s == ';'))
            s++;
        size_t len = 0;
        while (s[len] && !isspace((unsigned char)s[len]) && s[len] != ',' && s[len] != ';')
            len++;
        if (!len)
            break;
        char pair[160];
        if (len >= sizeof pair) {
            snprintf(err, TERRAD_TWIN_ERROR_MAX, "config: a pair longer than %zu bytes",
                     sizeof pair - 1);
            return -1;
        }
        memcpy(pair, s, len);
        pair[len] = 0;
        s += len;
        char *eq = strchr(pair, '=');
        if (!eq || eq == pair || !eq[1]) {
            snprintf(err, TERRAD_TWIN_ERROR_MAX, "config: '%s' is not key=value", pair);
            return -1;
        }
        *eq = 0;
        char *end;
        double v = strtod(eq + 1, &end);
        int rc = *end == 0 ? terrad_twin_config_set(cfg, pair, v, err)
                           : terrad_twin_config_set_name(cfg, pair, eq + 1, err);
        if (rc)
            return -1;
    }
    return 0;
}

static terrad_twin_config *make_config(const terrad_world_info *w, const char *text, char *err)
{
    terrad_twin_config *cfg = terrad_twin_config_new();
    if (!cfg) {
        snprintf(err, TERRAD_TWIN_ERROR_MAX, "out of memory");
        return NULL;
    }
    const struct {
        const char *key;
        double v;
    } world[] = {{"width", w->width},
                 {"height", w->height},
                 {"cell_size_m", w->cell_size_m},
                 {"units_per_m", w->units_per_m},
                 {"tick_hz", w->tick_hz}};
    for (size_t i = 0; i < sizeof world / sizeof world[0]; i++)
        if (terrad_twin_config_set(cfg, world[i].key, world[i].v, err))
            goto fail;
    if (parse_config(cfg, text, err))
        goto fail;
    return cfg;
fail:
    terrad_twin_config_free(cfg);
    return NULL;
}

static void prediction_free(terrad_prediction *p)
{
    terrad_twin_prediction_destroy(p->twin);
    free(p);
}

static int refuse(terrad_client *c, terrad_prediction *p, int code, const char *what)
{
    client_set_error(c, "predict: %s", what);
    if (p)
        prediction_free(p);
    return code;
}

int terrad_client_predict(terrad_client *c, uint32_t sid, const char *config,
                          terrad_prediction **out)
{
    char err[TERRAD_TWIN_ERROR_MAX] = "";
    if (!c)
        return TERRAD_E_BAD_VALUE;
    if (!out)
        return refuse(c, NULL, TERRAD_E_BAD_VALUE, "out: NULL");
    *out = NULL;
    const terrad_mirror *m = terrad_client_mirror(c, sid);
    if (!m) {
        snprintf(err, sizeof err, "sid: no subscription %u", (unsigned)sid);
        return refuse(c, NULL, TERRAD_E_BAD_VALUE, err);
    }
    if (!terrad_client_mirror_complete(c, sid)) {
        snprintf(err, sizeof err, "sid: subscription %u has no snapshot yet", (unsigned)sid);
        return refuse(c, NULL, TERRAD_E_BAD_VALUE, err);
    }
    for (terrad_prediction *q = *client_predictions(c); q; q = q->next)
        if (q->sid == sid)
            return refuse(c, NULL, TERRAD_E_BAD_VALUE, "sid: this subscription is predicted");
    terrad_twin_config *cfg = make_config(terrad_client_world(c), config ? config : "", err);
    if (!cfg)
        return refuse(c, NULL, TERRAD_E_BAD_VALUE, err);
    terrad_prediction *p = calloc(1, sizeof *p);
    if (!p) {
        terrad_twin_config_free(cfg);
        return refuse(c, NULL, TERRAD_E_NO_MEMORY, "out of memory");
    }
    p->client = c;
    p->sid = sid;
    p->twin =
        terrad_twin_prediction_create(cfg, m->x, m->y, (int)m->w, (int)m->h, m->heights, 0, err);
    terrad_twin_config_free(cfg);
    if (!p->twin)
        return refuse(c, p, TERRAD_E_BAD_VALUE, err);
    size_t nown = 0;
    const client_own *own = client_own_colliders(c, &nown);
    for (size_t i = 0; i < nown; i++)
        if (add_own(p, &own[i], err))
            return refuse(c, p, TERRAD_E_BAD_VALUE, err);
    sync_stats(p);
    terrad_prediction **head = client_predictions(c);
    p->next = *head;
    *head = p;
    *out = p;
    return 0;
}

const int32_t *terrad_prediction_heights(const terrad_prediction *p)
{
    return p ? terrad_twin_prediction_heights(p->twin) : NULL;
}

const terrad_prediction_stats *terrad_prediction_get_stats(const terrad_prediction *p)
{
    return p ? &p->stats : NULL;
}

const char *terrad_prediction_last_error(const terrad_prediction *p)
{
    return p ? p->last_error : "";
}

void terrad_prediction_stop(terrad_prediction *p)
{
    if (!p)
        return;
    for (terrad_prediction **q = client_predictions(p->client); *q; q = &(*q)->next)
        if (*q == p) {
            *q = p->next;
            break;
        }
    prediction_free(p);
}

/* ---- the client's events ------------------------------------------------- */

void predict_sent(terrad_client *c, uint32_t seq, const terrad_pose *poses, size_t count)
{
    if (!*client_predictions(c))
        return;
    uint32_t *ids = malloc((count ? count : 1) * sizeof *ids);
    double *v = malloc((count ? count : 1) * 7 * sizeof *v);
    for (size_t i = 0; ids && v && i < count; i++) {
        const terrad_pose *q = &poses[i];
        ids[i] = q->id;
        const double pose[7] = {q->x, q->y, q->z, q->qw, q->qx, q->qy, q->qz};
        memcpy(v + 7 * i, pose, sizeof pose);
    }
    char err[TERRAD_TWIN_ERROR_MAX] = "sent: out of memory";
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next) {
        /* out of memory: this batch is not predicted; the next ACK resets */
        took(p, ids && v ? terrad_twin_prediction_sent(p->twin, seq, ids, v, (int)count, err) : -1,
             err);
        sync_stats(p);
    }
    free(ids);
    free(v);
}

void predict_acked(terrad_client *c, uint64_t tick, uint32_t seq)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next) {
        const terrad_mirror *m = terrad_client_mirror(c, p->sid);
        const int32_t *server = m && terrad_client_mirror_complete(c, p->sid) ? m->heights : NULL;
        /* -1 also when the ACK was taken but the soil state not restored: counted */
        took(p, terrad_twin_prediction_acked(p->twin, tick, seq, server, err), err);
        sync_stats(p);
    }
}

void predict_collider(terrad_client *c, const client_own *o, int added)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next) {
        int rc = added ? add_own(p, o, err)
                       : terrad_twin_prediction_remove_collider(p->twin, o->id, err);
        took(p, rc, err);
        if (rc && added)
            client_set_error(c, "predict: collider %u: %s", (unsigned)o->id, err);
    }
}

void predict_free_all(terrad_client *c)
{
    terrad_prediction **head = client_predictions(c);
    while (*head) {
        terrad_prediction *p = *head;
        *head = p->next;
        prediction_free(p);
    }
}
