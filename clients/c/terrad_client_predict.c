/*
 * terrad_client_predict.c: client-side prediction in the C client
 * (terrad_client.h "Prediction", docs/engines.md): the steps of the Python
 * client's terrad/predict.py over libterrad-twin, the daemon's own
 * deformation code.
 *
 * How it fits the server's tick: each pose batch the client sends is one
 * server tick, so it is one tick of the twin at once (predict_sent, before the
 * bytes leave). When the ACK of tick t arrives, every DELTA of t came before it,
 * so the mirror holds the server's heights at t: predict_acked replays the
 * server's ticks since the previous ACK (which batches each used, the ACKs say)
 * from that ACK's heights and counts the cells that differ, then restarts the
 * twin from the mirror and applies the batches sent after t's again.
 */
#ifndef _POSIX_C_SOURCE
#define _POSIX_C_SOURCE 200809L
#endif

#include "terrad_client_internal.h"
#include "terrad_twin.h"

#include <ctype.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A pose as the server uses it (through float32, the quaternion normalised). */
typedef struct server_pose {
    uint32_t id;
    double p[3], q[4];
} server_pose;

/* A batch sent and not acknowledged yet: its own poses and a digest of the
 * heights its prediction left (for on_time). */
typedef struct pending_batch {
    uint32_t seq;
    size_t n;
    server_pose *poses;
    uint64_t digest;
} pending_batch;

/* An own collider in the twin and the pose the acknowledged tick left it at. */
typedef struct own_state {
    client_own o;
    int axis_z; /* capsule and cylinder: the wire's z axis is the engine's y */
    int has_acked;
    server_pose acked;
} own_state;

struct terrad_prediction {
    terrad_prediction *next;
    terrad_client *client;
    uint32_t sid;
    terrad_twin *twin;
    int32_t x, y;
    uint32_t w, h;
    int32_t *heights; /* the twin's window after the last change */
    int32_t *base;    /* the server's heights at the last ACK */
    int has_base_tick;
    uint64_t base_tick;
    uint64_t max_replay_ticks;
    own_state *own;
    size_t nown, own_cap;
    pending_batch *pending;
    size_t npending, pending_cap;
    terrad_prediction_stats stats;
};

/* ---- the server's pose arithmetic --------------------------------------- */

/* collider.c's quat_normalize, operation for operation. */
static void quat_normalize(double q[4])
{
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(n > 1e-300) || !isfinite(n)) {
        q[0] = 1;
        q[1] = q[2] = q[3] = 0;
        return;
    }
    for (int i = 0; i < 4; i++)
        q[i] /= n;
}

/* net_control_orientation: normalised, and for a capsule or cylinder (axis z
 * on the wire, y in the engine) turned a quarter about x. */
static void server_orientation(double q[4], int axis_z)
{
    quat_normalize(q);
    if (!axis_z)
        return;
    const double h = 0.70710678118654752440;
    const double a[4] = {q[0], q[1], q[2], q[3]}, b[4] = {h, h, 0, 0};
    q[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3];
    q[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2];
    q[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1];
    q[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0];
    quat_normalize(q);
}

static own_state *find_own(terrad_prediction *p, uint32_t id)
{
    for (size_t i = 0; i < p->nown; i++)
        if (p->own[i].o.id == id)
            return &p->own[i];
    return NULL;
}

static int grow(void **ptr, size_t *cap, size_t need, size_t elem)
{
    if (need <= *cap)
        return 0;
    size_t n = *cap ? *cap * 2 : 8;
    while (n < need)
        n *= 2;
    void *q = realloc(*ptr, n * elem);
    if (!q)
        return -1;
    *ptr = q;
    *cap = n;
    return 0;
}

/* ---- the twin ------------------------------------------------------------ */

static int twin_add(terrad_prediction *p, const client_own *o, char *err)
{
    const int id = (int)o->id;
    switch (o->shape) {
    case TERRAD_SHAPE_SPHERE:
        return terrad_twin_add_collider(p->twin, id, "sphere", o->radius, 0, 0, 0, 0, err);
    case TERRAD_SHAPE_BOX:
        return terrad_twin_add_collider(p->twin, id, "box", 0, 0, o->half_extents[0],
                                        o->half_extents[1], o->half_extents[2], err);
    case TERRAD_SHAPE_CAPSULE:
        return terrad_twin_add_collider(p->twin, id, "capsule", o->radius, o->half_length, 0, 0, 0,
                                        err);
    case TERRAD_SHAPE_CYLINDER:
        return terrad_twin_add_collider(p->twin, id, "cylinder", o->radius, o->half_length, 0, 0, 0,
                                        err);
    case TERRAD_SHAPE_WHEEL: /* the server's wheel: a cylinder with its axle along y */
        return terrad_twin_add_collider(p->twin, id, "cylinder", o->radius, o->width / 2, 0, 0, 0,
                                        err);
    }
    snprintf(err, TERRAD_TWIN_ERROR_MAX, "shape: %d cannot be predicted", (int)o->shape);
    return -1;
}

/* The twin's copy of an own collider (only default-material ones: the twin
 * presses with the world's material). */
static int add_own(terrad_prediction *p, const client_own *o, char *err)
{
    if (!o->default_material || find_own(p, o->id))
        return 0;
    if (grow((void **)&p->own, &p->own_cap, p->nown + 1, sizeof *p->own)) {
        snprintf(err, TERRAD_TWIN_ERROR_MAX, "out of memory");
        return -1;
    }
    if (twin_add(p, o, err))
        return -1;
    own_state *s = &p->own[p->nown++];
    memset(s, 0, sizeof *s);
    s->o = *o;
    s->axis_z = o->shape == TERRAD_SHAPE_CAPSULE || o->shape == TERRAD_SHAPE_CYLINDER;
    return 0;
}

static uint64_t digest(const int32_t *h, size_t n)
{
    uint64_t d = 1469598103934665603ull; /* FNV-1a over the values */
    for (size_t i = 0; i < n; i++) {
        d ^= (uint32_t)h[i];
        d *= 1099511628211ull;
    }
    return d;
}

static size_t cells(const terrad_prediction *p)
{
    return (size_t)p->w * p->h;
}

/* One tick of the twin with these poses; the digest of the heights it left. */
static uint64_t apply(terrad_prediction *p, const server_pose *poses, size_t n)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    for (size_t i = 0; i < n; i++)
        if (find_own(p, poses[i].id))
            terrad_twin_set_pose(p->twin, (int)poses[i].id, poses[i].p[0], poses[i].p[1],
                                 poses[i].p[2], poses[i].q[0], poses[i].q[1], poses[i].q[2],
                                 poses[i].q[3], err);
    terrad_twin_tick(p->twin, err);
    terrad_twin_read(p->twin, p->x, p->y, (int)p->w, (int)p->h, p->heights, err);
    return digest(p->heights, cells(p));
}

/* The twin at these heights, each own collider where the acknowledged tick
 * left it (one without an acknowledged pose has none: removed and added). */
static void restart(terrad_prediction *p, const int32_t *heights)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    terrad_twin_write(p->twin, p->x, p->y, (int)p->w, (int)p->h, heights, err);
    for (size_t i = 0; i < p->nown; i++) {
        own_state *s = &p->own[i];
        if (s->has_acked) {
            terrad_twin_place(p->twin, (int)s->o.id, s->acked.p[0], s->acked.p[1], s->acked.p[2],
                              s->acked.q[0], s->acked.q[1], s->acked.q[2], s->acked.q[3], err);
        } else {
            terrad_twin_remove_collider(p->twin, (int)s->o.id, err);
            twin_add(p, &s->o, err);
        }
    }
}

/* ---- making one ---------------------------------------------------------- */

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
    for (size_t i = 0; i < p->npending; i++)
        free(p->pending[i].poses);
    free(p->pending);
    free(p->own);
    free(p->heights);
    free(p->base);
    terrad_twin_destroy(p->twin);
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
    size_t n = (size_t)m->w * m->h;
    if (p) {
        p->heights = malloc(n * sizeof *p->heights);
        p->base = malloc(n * sizeof *p->base);
    }
    if (!p || !p->heights || !p->base) {
        terrad_twin_config_free(cfg);
        return refuse(c, p, TERRAD_E_NO_MEMORY, "out of memory");
    }
    p->client = c;
    p->sid = sid;
    p->x = m->x, p->y = m->y, p->w = m->w, p->h = m->h;
    memcpy(p->base, m->heights, n * sizeof *p->base);
    memcpy(p->heights, m->heights, n * sizeof *p->heights);
    double hz = terrad_client_world(c)->tick_hz;
    p->max_replay_ticks = (uint64_t)(4 * (hz > 0 ? hz : 60)); /* 4 s, as the Python client */
    p->twin = terrad_twin_create(cfg, p->x, p->y, (int)p->w, (int)p->h, m->heights, err);
    terrad_twin_config_free(cfg);
    if (!p->twin)
        return refuse(c, p, TERRAD_E_BAD_VALUE, err);
    size_t nown = 0;
    const client_own *own = client_own_colliders(c, &nown);
    for (size_t i = 0; i < nown; i++)
        if (add_own(p, &own[i], err))
            return refuse(c, p, TERRAD_E_BAD_VALUE, err);
    terrad_prediction **head = client_predictions(c);
    p->next = *head;
    *head = p;
    *out = p;
    return 0;
}

const int32_t *terrad_prediction_heights(const terrad_prediction *p)
{
    return p ? p->heights : NULL;
}

const terrad_prediction_stats *terrad_prediction_get_stats(const terrad_prediction *p)
{
    return p ? &p->stats : NULL;
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

static void sent_one(terrad_prediction *p, uint32_t seq, const terrad_pose *poses, size_t count)
{
    if (grow((void **)&p->pending, &p->pending_cap, p->npending + 1, sizeof *p->pending))
        return; /* out of memory: this batch is not predicted; the next ACK resets */
    pending_batch *b = &p->pending[p->npending];
    b->seq = seq;
    b->n = 0;
    b->poses = malloc((count ? count : 1) * sizeof *b->poses);
    if (!b->poses)
        return;
    for (size_t i = 0; i < count; i++) {
        own_state *s = find_own(p, poses[i].id);
        if (!s)
            continue;
        server_pose *sp = &b->poses[b->n++];
        sp->id = poses[i].id;
        sp->p[0] = poses[i].x, sp->p[1] = poses[i].y, sp->p[2] = poses[i].z;
        sp->q[0] = poses[i].qw, sp->q[1] = poses[i].qx, sp->q[2] = poses[i].qy;
        sp->q[3] = poses[i].qz;
        server_orientation(sp->q, s->axis_z);
    }
    b->digest = apply(p, b->poses, b->n);
    p->npending++;
    p->stats.predicted++;
    p->stats.pending = p->npending;
}

void predict_sent(terrad_client *c, uint32_t seq, const terrad_pose *poses, size_t count)
{
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next)
        sent_one(p, seq, poses, count);
}

/* Batches up to seq (wrapping) are acknowledged. */
static int acknowledged(uint32_t batch, uint32_t seq)
{
    return (uint32_t)(seq - batch) < 0x80000000u;
}

/* The poses each acknowledged batch used become where tick t left the colliders. */
static void remember(terrad_prediction *p, size_t ndone)
{
    for (size_t i = 0; i < ndone; i++)
        for (size_t j = 0; j < p->pending[i].n; j++) {
            own_state *s = find_own(p, p->pending[i].poses[j].id);
            if (s) {
                s->acked = p->pending[i].poses[j];
                s->has_acked = 1;
            }
        }
}

/* The server's ticks since the previous ACK, replayed from its heights: the
 * idle ticks keep the poses, tick t takes the latest pose of each collider
 * of the acknowledged batches. Cells differing from the mirror are counted. */
static void replay(terrad_prediction *p, size_t ndone, uint64_t gap, const int32_t *server)
{
    restart(p, p->base);
    char err[TERRAD_TWIN_ERROR_MAX];
    for (uint64_t i = 1; i < gap; i++)
        terrad_twin_tick(p->twin, err);
    size_t total = 0;
    for (size_t i = 0; i < ndone; i++)
        total += p->pending[i].n;
    server_pose *merged = malloc((total ? total : 1) * sizeof *merged);
    size_t nm = 0;
    for (size_t i = 0; merged && i < ndone; i++)
        for (size_t j = 0; j < p->pending[i].n; j++) {
            const server_pose *sp = &p->pending[i].poses[j];
            size_t k = 0;
            while (k < nm && merged[k].id != sp->id)
                k++;
            merged[k] = *sp;
            nm += k == nm;
        }
    apply(p, merged, nm);
    free(merged);
    uint64_t differ = 0;
    for (size_t i = 0; i < cells(p); i++)
        differ += p->heights[i] != server[i];
    p->stats.last_differing = differ;
    p->stats.replayed++;
    p->stats.exact += differ == 0;
}

static void acked_one(terrad_prediction *p, uint64_t tick, uint32_t seq)
{
    size_t ndone = 0;
    while (ndone < p->npending && acknowledged(p->pending[ndone].seq, seq))
        ndone++;
    const terrad_mirror *m = terrad_client_mirror(p->client, p->sid);
    if (m && terrad_client_mirror_complete(p->client, p->sid)) {
        const int32_t *server = m->heights;
        if (ndone && p->pending[ndone - 1].seq == seq) /* was batch seq's prediction tick t? */
            p->stats.on_time += p->pending[ndone - 1].digest == digest(server, cells(p));
        int any_acked = 0;
        for (size_t i = 0; i < p->nown; i++)
            any_acked |= p->own[i].has_acked;
        /* nothing of ours pressed before t: the idle ticks changed nothing */
        uint64_t gap = !any_acked ? 1 : p->has_base_tick ? tick - p->base_tick : 0;
        /* batches acknowledged together after a gap may have been taken at different
         * ticks of it (a slow client's ACKs are coalesced): not compared */
        int spread = gap > 1 && ndone > 1;
        if (gap >= 1 && gap <= p->max_replay_ticks && !spread)
            replay(p, ndone, gap, server);
        else
            p->stats.skipped++;
        remember(p, ndone);
        memcpy(p->base, server, cells(p) * sizeof *p->base);
        p->base_tick = tick;
        p->has_base_tick = 1;
    } else {
        p->stats.skipped++; /* resyncing: reconcile at the next ACK that has the heights */
        remember(p, ndone);
    }
    for (size_t i = 0; i < ndone; i++)
        free(p->pending[i].poses);
    memmove(p->pending, p->pending + ndone, (p->npending - ndone) * sizeof *p->pending);
    p->npending -= ndone;
    p->stats.pending = p->npending;
    if (!m || !terrad_client_mirror_complete(p->client, p->sid))
        return; /* the twin goes on predicting until heights come */
    restart(p, p->base);
    char err[TERRAD_TWIN_ERROR_MAX];
    terrad_twin_read(p->twin, p->x, p->y, (int)p->w, (int)p->h, p->heights, err);
    for (size_t i = 0; i < p->npending; i++)
        p->pending[i].digest = apply(p, p->pending[i].poses, p->pending[i].n);
    p->stats.reconciled++;
    p->stats.pending = p->npending;
}

void predict_acked(terrad_client *c, uint64_t tick, uint32_t seq)
{
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next)
        acked_one(p, tick, seq);
}

void predict_collider(terrad_client *c, const client_own *o, int added)
{
    char err[TERRAD_TWIN_ERROR_MAX];
    for (terrad_prediction *p = *client_predictions(c); p; p = p->next) {
        if (added) {
            if (add_own(p, o, err))
                client_set_error(c, "predict: collider %u: %s", (unsigned)o->id, err);
            continue;
        }
        own_state *s = find_own(p, o->id);
        if (!s)
            continue;
        terrad_twin_remove_collider(p->twin, (int)o->id, err);
        size_t i = (size_t)(s - p->own); /* keep the order: restart walks it */
        memmove(s, s + 1, (p->nown - i - 1) * sizeof *s);
        p->nown--;
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
