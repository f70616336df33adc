/*
 * twin_predict.c: client-side prediction over the twin (terrad_twin.h,
 * "Prediction"; docs/engines.md) — the one copy every client runs: the C
 * client links it, Python calls it by ctypes, JavaScript as WebAssembly.
 *
 * How it fits the server's tick: each pose batch a client sends is one server
 * tick, so it is one tick of the twin at once (terrad_twin_prediction_sent,
 * before the bytes leave). When the ACK of tick t arrives, every DELTA of t
 * came before it, so the client's mirror holds the server's heights at t:
 * _acked replays the server's ticks since the previous ACK (which batches each
 * used, the ACKs say) from that ACK's heights and counts the cells that
 * differ, then restarts the twin from the mirror and applies the batches sent
 * after t's again. The poses go through the server's own arithmetic (float32
 * on the wire, collider_wire_orientation), so the twin presses with its bits.
 */
#include "twin/terrad_twin.h"
#include "twin/twin_internal.h"

#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/sim.h"

/* A pose as the server uses it. */
typedef struct predict_pose {
    uint32_t id;
    collider_pose pose;
} predict_pose;

/* A batch sent and not acknowledged yet: its own colliders' poses and a
 * digest of the heights its prediction left (for on_time). */
typedef struct predict_batch {
    uint32_t seq;
    int64_t n;
    predict_pose *poses;
    uint64_t digest;
} predict_batch;

/* An own collider in the twin and the pose the acknowledged tick left it at. */
typedef struct predict_own {
    uint32_t id;
    int axis_z; /* capsule and cylinder: the wire's z axis is the engine's y */
    int loaded; /* load-driven: acked's height is the one the replay found */
    int has_acked;
    collider_pose acked;
} predict_own;

struct terrad_twin_prediction {
    terrad_twin *twin;
    int x, y, w, h;
    int32_t *heights;    /* the twin's window after the last change */
    int32_t *base;       /* the server's heights at the last ACK */
    int32_t *base_state; /* the window's soil state there, as the replay reached it */
    int stateful;        /* twin_keeps_state: base_state is kept and restored */
    int has_base_tick;
    uint64_t base_tick;
    uint64_t max_replay_ticks;
    predict_own *own;
    int64_t nown, own_cap;
    predict_batch *pending;
    int64_t npending, pending_cap;
    terrad_twin_prediction_stats stats;
};

static predict_own *find_own(terrad_twin_prediction *p, uint32_t id)
{
    for (int64_t i = 0; i < p->nown; i++)
        if (p->own[i].id == id)
            return &p->own[i];
    return NULL;
}

static size_t cells(const terrad_twin_prediction *p)
{
    return (size_t)p->w * (size_t)p->h;
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

/* ---- the twin ------------------------------------------------------------ */

/* One tick of the twin with these poses; the digest of the heights it left. */
static uint64_t apply(terrad_twin_prediction *p, const predict_pose *poses, int64_t n)
{
    for (int64_t i = 0; i < n; i++) {
        const collider_pose *c = &poses[i].pose;
        terrad_twin_set_pose(p->twin, (int)poses[i].id, c->position.x, c->position.y, c->position.z,
                             c->orientation.w, c->orientation.x, c->orientation.y, c->orientation.z,
                             NULL);
    }
    terrad_twin_tick(p->twin, NULL);
    terrad_twin_read(p->twin, p->x, p->y, p->w, p->h, p->heights, NULL);
    return digest(p->heights, cells(p));
}

/* The restores left to fail (terrad_twin_fault_restores, a test hook). */
static atomic_int fault_restores;

void terrad_twin_fault_restores(int count)
{
    atomic_store(&fault_restores, count > 0 ? count : 0);
}

/* 1 when the hook takes this restore (one of those left), else 0. */
static int restore_faulted(void)
{
    int n = atomic_load(&fault_restores);
    while (n > 0 && !atomic_compare_exchange_weak(&fault_restores, &n, n - 1))
        ;
    return n > 0;
}

/* The twin at these heights and the base's soil state, each own collider
 * where the acknowledged tick left it (one without an acknowledged pose has
 * none). -1 when the state could not be restored (out of memory for its
 * layer): the twin then presses on the wrong soil, so the caller says so
 * (restored); the colliders are placed all the same. */
static int restart(terrad_twin_prediction *p, const int32_t *heights)
{
    terrad_twin_write(p->twin, p->x, p->y, p->w, p->h, heights, NULL);
    int rc = !p->stateful        ? 0
             : restore_faulted() ? -1 /* as out of memory: the state left as it was */
                                 : twin_state_write(p->twin, p->base_state);
    for (int64_t i = 0; i < p->nown; i++) {
        const predict_own *s = &p->own[i];
        const collider_pose *a = &s->acked;
        if (s->has_acked)
            terrad_twin_place(p->twin, (int)s->id, a->position.x, a->position.y, a->position.z,
                              a->orientation.w, a->orientation.x, a->orientation.y,
                              a->orientation.z, NULL);
        else
            twin_unpose(p->twin, (int)s->id, NULL);
    }
    return rc;
}

/* The caller's error when a restart's state could not be restored (lost: -1). */
static int restored(int lost, const char *call, char *err)
{
    if (lost)
        return twin_fail(err,
                         "%s: out of memory restoring the soil state; the prediction is inexact "
                         "until the window is predicted anew",
                         call);
    return 0;
}

/* The wire's poses of own colliders as the server uses them: each number
 * through float32, the orientation normalised and turned
 * (collider_wire_orientation). out holds count; returns how many were own. */
static int64_t server_poses(terrad_twin_prediction *p, const uint32_t *ids, const double *poses,
                            int count, predict_pose *out)
{
    int64_t n = 0;
    for (int i = 0; i < count; i++) {
        const predict_own *s = find_own(p, ids[i]);
        if (!s)
            continue;
        double v[7];
        for (int k = 0; k < 7; k++)
            v[k] = (double)(float)poses[7 * i + k];
        quatd q = collider_wire_orientation((quatd){v[3], v[4], v[5], v[6]}, s->axis_z);
        out[n++] = (predict_pose){ids[i], {{v[0], v[1], v[2]}, q}};
    }
    return n;
}

/* ---- making one ---------------------------------------------------------- */

terrad_twin_prediction *terrad_twin_prediction_create(const terrad_twin_config *c, int x, int y,
                                                      int w, int h, const int32_t *heights,
                                                      int max_replay_ticks, char *err)
{
    if (!c || !heights || w <= 0 || h <= 0) {
        twin_fail(err, "prediction: needs a config and the window's heights");
        return NULL;
    }
    terrad_twin_prediction *p = calloc(1, sizeof *p);
    size_t n = (size_t)w * (size_t)h;
    if (p) {
        p->heights = malloc(n * sizeof *p->heights);
        p->base = malloc(n * sizeof *p->base);
    }
    if (!p || !p->heights || !p->base) {
        twin_fail(err, "prediction: out of memory");
        terrad_twin_prediction_destroy(p);
        return NULL;
    }
    p->x = x, p->y = y, p->w = w, p->h = h;
    p->twin = terrad_twin_create(c, x, y, w, h, heights, err);
    if (!p->twin) {
        terrad_twin_prediction_destroy(p);
        return NULL;
    }
    /* the soil's state is not on the wire: it starts untouched, as the twin's */
    if (!(p->base_state = malloc((size_t)twin_state_values(p->twin) * sizeof *p->base_state))) {
        twin_fail(err, "prediction: out of memory");
        terrad_twin_prediction_destroy(p);
        return NULL;
    }
    twin_state_read(p->twin, p->base_state);
    p->stateful = twin_keeps_state(p->twin);
    memcpy(p->base, heights, n * sizeof *p->base);
    memcpy(p->heights, heights, n * sizeof *p->heights);
    double hz = twin_config_tick_hz(c);
    p->max_replay_ticks = max_replay_ticks > 0 ? (uint64_t)max_replay_ticks
                                               : (uint64_t)(4 * (hz > 0 ? hz : 60)); /* 4 s */
    return p;
}

void terrad_twin_prediction_destroy(terrad_twin_prediction *p)
{
    if (!p)
        return;
    for (int64_t i = 0; i < p->npending; i++)
        free(p->pending[i].poses);
    free(p->pending);
    free(p->own);
    free(p->heights);
    free(p->base);
    free(p->base_state);
    terrad_twin_destroy(p->twin);
    free(p);
}

/* id may become an own collider: a twin's id, not one already. */
static int own_id_free(terrad_twin_prediction *p, uint32_t id, char *err)
{
    if (id > INT32_MAX)
        return twin_fail(err, "id: %u is not a collider id", (unsigned)id);
    if (find_own(p, id))
        return twin_fail(err, "id: collider %u is predicted already", (unsigned)id);
    return 0;
}

/* The own collider's entry, once the twin holds its copy (added is the twin's
 * call's result). */
static int own_added(terrad_twin_prediction *p, uint32_t id, int axis_z, int added, char *err)
{
    if (added != 0)
        return -1;
    if (array_grow((void **)&p->own, &p->own_cap, p->nown + 1, sizeof *p->own) != 0) {
        terrad_twin_remove_collider(p->twin, (int)id, NULL);
        return twin_fail(err, "collider: out of memory");
    }
    p->own[p->nown++] = (predict_own){.id = id, .axis_z = axis_z};
    return 0;
}

int terrad_twin_prediction_add_collider(terrad_twin_prediction *p, uint32_t id, const char *shape,
                                        double radius, double half_length, double hx, double hy,
                                        double hz, char *err)
{
    if (!p || !shape)
        return twin_fail(err, "collider: no prediction or shape");
    if (own_id_free(p, id, err) != 0)
        return -1;
    int axis_z = strcmp(shape, "capsule") == 0 || strcmp(shape, "cylinder") == 0;
    const char *twin_shape = strcmp(shape, "wheel") == 0 ? "cylinder" : shape; /* axle along y */
    if (!axis_z && strcmp(shape, "sphere") != 0 && strcmp(shape, "box") != 0 &&
        strcmp(shape, "wheel") != 0)
        return twin_fail(err,
                         "shape: \"%s\" cannot be predicted (sphere, box, capsule, cylinder, "
                         "wheel, mesh)",
                         shape);
    return own_added(p, id, axis_z,
                     terrad_twin_add_collider(p->twin, (int)id, twin_shape, radius, half_length, hx,
                                              hy, hz, err),
                     err);
}

int terrad_twin_prediction_add_wheel(terrad_twin_prediction *p, uint32_t id, double radius,
                                     double half_length, double grouser_count,
                                     double grouser_height, double grouser_thickness, char *err)
{
    if (!p)
        return twin_fail(err, "collider: no prediction");
    if (own_id_free(p, id, err) != 0)
        return -1;
    return own_added(p, id, 0, /* a wheel's axle is y on the wire as in the engine */
                     terrad_twin_add_wheel(p->twin, (int)id, radius, half_length, grouser_count,
                                           grouser_height, grouser_thickness, err),
                     err);
}

int terrad_twin_prediction_add_mesh(terrad_twin_prediction *p, uint32_t id, const float *vertices,
                                    int vertex_count, const uint32_t *indices, int triangle_count,
                                    char *err)
{
    if (!p)
        return twin_fail(err, "collider: no prediction");
    if (own_id_free(p, id, err) != 0)
        return -1;
    return own_added(p, id, 0,
                     terrad_twin_add_mesh(p->twin, (int)id, vertices, vertex_count, indices,
                                          triangle_count, err),
                     err);
}

int terrad_twin_prediction_set_load(terrad_twin_prediction *p, uint32_t id, double load_n,
                                    char *err)
{
    if (!p)
        return twin_fail(err, "collider: no prediction");
    predict_own *s = find_own(p, id);
    if (!s)
        return twin_fail(err, "id: collider %u is not predicted", (unsigned)id);
    if (terrad_twin_set_load(p->twin, (int)id, load_n, err) != 0)
        return -1;
    s->loaded = load_n > 0;
    return 0;
}

int terrad_twin_prediction_remove_collider(terrad_twin_prediction *p, uint32_t id, char *err)
{
    if (!p)
        return twin_fail(err, "collider: no prediction");
    predict_own *s = find_own(p, id);
    if (!s)
        return 0;
    terrad_twin_remove_collider(p->twin, (int)id, NULL);
    int64_t i = s - p->own; /* keep the order: restart walks it */
    memmove(s, s + 1, (size_t)(p->nown - i - 1) * sizeof *s);
    p->nown--;
    return 0;
}

/* ---- the client's events ------------------------------------------------- */

static int check_poses(const uint32_t *ids, const double *poses, int count, char *err)
{
    if (count < 0 || (count > 0 && (!ids || !poses)))
        return twin_fail(err, "poses: %d poses without their ids or numbers", count);
    return 0;
}

int terrad_twin_prediction_sent(terrad_twin_prediction *p, uint32_t seq, const uint32_t *ids,
                                const double *poses, int count, char *err)
{
    if (!p)
        return twin_fail(err, "sent: no prediction");
    if (check_poses(ids, poses, count, err))
        return -1;
    if (array_grow((void **)&p->pending, &p->pending_cap, p->npending + 1, sizeof *p->pending))
        return twin_fail(err, "sent: out of memory");
    predict_batch *b = &p->pending[p->npending];
    b->seq = seq;
    b->poses = malloc((size_t)(count ? count : 1) * sizeof *b->poses);
    if (!b->poses)
        return twin_fail(err, "sent: out of memory");
    b->n = server_poses(p, ids, poses, count, b->poses);
    b->digest = apply(p, b->poses, b->n);
    p->npending++;
    p->stats.predicted++;
    p->stats.pending = (uint64_t)p->npending;
    return 0;
}

/* Batches up to seq (wrapping) are acknowledged. */
static int acknowledged(uint32_t batch, uint32_t seq)
{
    return (uint32_t)(seq - batch) < 0x80000000u;
}

/* The poses each acknowledged batch used become where tick t left the
 * colliders (a load-driven one keeps the height found last: found sets it). */
static void remember(terrad_twin_prediction *p, int64_t ndone)
{
    for (int64_t i = 0; i < ndone; i++)
        for (int64_t j = 0; j < p->pending[i].n; j++) {
            predict_own *s = find_own(p, p->pending[i].poses[j].id);
            if (!s)
                continue;
            double z = s->acked.position.z;
            s->acked = p->pending[i].poses[j].pose;
            if (s->loaded && s->has_acked)
                s->acked.position.z = z;
            s->has_acked = 1;
        }
}

/* After the replay of tick t: the soil state it reached is the base's, and
 * each load-driven collider stands at the height it found (the server's,
 * when the replay is exact: the same search on the same heights and state). */
static void found(terrad_twin_prediction *p)
{
    if (p->stateful)
        twin_state_read(p->twin, p->base_state);
    for (int64_t i = 0; i < p->nown; i++) {
        predict_own *s = &p->own[i];
        double z;
        if (s->loaded && s->has_acked && twin_pose_z(p->twin, (int)s->id, &z) == 0)
            s->acked.position.z = z;
    }
}

/* The poses of the acknowledged batches tick j of a replay took (at[i]: batch
 * i's tick, 1..gap; NULL: all at the last), the latest of each collider. */
static int64_t merge(const terrad_twin_prediction *p, int64_t ndone, const uint64_t *at, uint64_t j,
                     uint64_t gap, predict_pose *merged)
{
    int64_t nm = 0;
    for (int64_t i = 0; i < ndone; i++) {
        if ((at ? at[i] : gap) != j)
            continue;
        for (int64_t k = 0; k < p->pending[i].n; k++) {
            const predict_pose *sp = &p->pending[i].poses[k];
            int64_t m = 0;
            while (m < nm && merged[m].id != sp->id)
                m++;
            merged[m] = *sp;
            nm += m == nm;
        }
    }
    return nm;
}

/* The server's ticks since the previous ACK, replayed from its heights and
 * soil state: the idle ticks keep the poses, tick j takes the latest pose of
 * each collider of the batches it took (at, as in merge). Returns the cells
 * differing from the server's (server NULL: 0, not compared); *lost is set
 * when the soil state could not be restored (restart). */
static uint64_t replay(terrad_twin_prediction *p, int64_t ndone, uint64_t gap, const uint64_t *at,
                       const int32_t *server, int *lost)
{
    *lost |= restart(p, p->base) != 0;
    int64_t total = 0;
    for (int64_t i = 0; i < ndone; i++)
        total += p->pending[i].n;
    predict_pose *merged = malloc((size_t)(total ? total : 1) * sizeof *merged);
    for (uint64_t j = 1; j <= gap; j++) {
        int64_t nm = merged ? merge(p, ndone, at, j, gap, merged) : 0;
        if (nm == 0 && j < gap)
            terrad_twin_tick(p->twin, NULL);
        else
            apply(p, merged, nm); /* the last tick reads the heights */
    }
    free(merged);
    uint64_t differ = 0;
    for (size_t i = 0; server && i < cells(p); i++)
        differ += p->heights[i] != server[i];
    return differ;
}

enum { SPREAD_TRIES = 64, SPREAD_TICKS = 512 }; /* the most assignments tried, ticks replayed */

/* Batches acknowledged together after a gap may have been taken at different
 * ticks of it (a slow client's older ACK is replaced by the newer one,
 * PROTOCOL.md "Slow clients"): which tick took which is not known, so the ACK
 * is not compared; but the soil state and the heights load-driven colliders
 * found must be the server's, so the orders the server could have taken them
 * in (each batch at or after the one before, the last at tick t) are
 * replayed until one gives the server's heights (SPREAD_TRIES orders, at
 * most SPREAD_TICKS ticks in all). None: the last batch's tick alone, the
 * best guess. */
static void replay_spread(terrad_twin_prediction *p, int64_t ndone, uint64_t gap,
                          const int32_t *server, int *lost)
{
    uint64_t *at = malloc((size_t)ndone * sizeof *at);
    for (int64_t i = 0; at && i < ndone; i++)
        at[i] = i == ndone - 1 ? gap : 1;
    for (int tries = 0; at && tries < SPREAD_TRIES && (uint64_t)(tries + 1) * gap <= SPREAD_TICKS;
         tries++) {
        if (replay(p, ndone, gap, at, server, lost) == 0) {
            free(at);
            return;
        }
        int64_t i = ndone - 2; /* the next nondecreasing assignment */
        while (i >= 0 && at[i] == gap)
            i--;
        if (i < 0)
            break;
        at[i]++;
        for (int64_t k = i + 1; k < ndone - 1; k++)
            at[k] = at[i];
    }
    free(at);
    replay(p, ndone, gap, NULL, NULL, lost);
}

/* Compare (when the ACKs say which ticks used which batches) and take the
 * server's heights at tick as the new base, with the soil state and found
 * heights the replay reached. */
static void reconcile(terrad_twin_prediction *p, uint64_t tick, uint32_t seq, int64_t ndone,
                      const int32_t *server, int *lost)
{
    if (ndone && p->pending[ndone - 1].seq == seq) /* was batch seq's prediction tick t? */
        p->stats.on_time += p->pending[ndone - 1].digest == digest(server, cells(p));
    int any_acked = 0;
    for (int64_t i = 0; i < p->nown; i++)
        any_acked |= p->own[i].has_acked;
    /* nothing of ours pressed before t: the idle ticks changed nothing. Gap 0:
     * ours pressed, but no ACK with heights came since the prediction was made
     * (the mirror resynced at the ACKs before this one), so how many ticks the
     * server ran since the base, and the batches those ACKs acknowledged
     * (forgotten there), are unknown. No replay can then be exact: the soil
     * state those ticks left is not on the wire. The one tick below is the
     * same best guess as after a gap too long to replay (it may save a state
     * of a tick the server never ran, as that one may); not replaying would
     * be no better: it keeps the state from before those presses and leaves a
     * load-driven collider at its posed height rather than on the soil. The
     * next compared ACKs count what the guess got wrong (exact < replayed). */
    uint64_t gap = !any_acked ? 1 : p->has_base_tick ? tick - p->base_tick : 0;
    int spread = gap > 1 && ndone > 1;
    if (gap >= 1 && gap <= p->max_replay_ticks && !spread) {
        uint64_t differ = replay(p, ndone, gap, NULL, server, lost);
        p->stats.last_differing = differ;
        p->stats.replayed++;
        p->stats.exact += differ == 0;
    } else {
        p->stats.skipped++;
        int loaded = 0;
        for (int64_t i = 0; i < p->nown; i++)
            loaded |= p->own[i].loaded;
        /* without state or loads the mirror's heights are all the restart needs */
        if ((p->stateful || loaded) && spread && gap <= p->max_replay_ticks)
            replay_spread(p, ndone, gap, server, lost);
        else if (p->stateful || loaded) /* one tick with the batches' poses: the best guess */
            replay(p, ndone, 1, NULL, NULL, lost);
    }
    remember(p, ndone);
    found(p);
    memcpy(p->base, server, cells(p) * sizeof *p->base);
    p->base_tick = tick;
    p->has_base_tick = 1;
}

int terrad_twin_prediction_acked(terrad_twin_prediction *p, uint64_t tick, uint32_t seq,
                                 const int32_t *server, char *err)
{
    if (!p)
        return twin_fail(err, "acked: no prediction");
    int64_t ndone = 0;
    while (ndone < p->npending && acknowledged(p->pending[ndone].seq, seq))
        ndone++;
    int lost = 0; /* the bookkeeping goes on: the next ACK finds it consistent */
    if (server) {
        reconcile(p, tick, seq, ndone, server, &lost);
    } else {
        p->stats.skipped++; /* resyncing: reconcile at the next ACK that has the heights */
        remember(p, ndone);
    }
    for (int64_t i = 0; i < ndone; i++)
        free(p->pending[i].poses);
    memmove(p->pending, p->pending + ndone, (size_t)(p->npending - ndone) * sizeof *p->pending);
    p->npending -= ndone;
    p->stats.pending = (uint64_t)p->npending;
    if (!server)
        return 0; /* the twin goes on predicting until heights come */
    lost |= restart(p, p->base) != 0;
    terrad_twin_read(p->twin, p->x, p->y, p->w, p->h, p->heights, NULL);
    for (int64_t i = 0; i < p->npending; i++)
        p->pending[i].digest = apply(p, p->pending[i].poses, p->pending[i].n);
    p->stats.reconciled++;
    return restored(lost, "acked", err);
}

int terrad_twin_prediction_resume(terrad_twin_prediction *p, uint64_t tick, const uint32_t *ids,
                                  const double *poses, int count, char *err)
{
    if (!p)
        return twin_fail(err, "resume: no prediction");
    if (check_poses(ids, poses, count, err))
        return -1;
    predict_pose *sp = malloc((size_t)(count ? count : 1) * sizeof *sp);
    if (!sp)
        return twin_fail(err, "resume: out of memory");
    int64_t n = server_poses(p, ids, poses, count, sp);
    for (int64_t i = 0; i < n; i++) {
        predict_own *s = find_own(p, sp[i].id);
        s->acked = sp[i].pose;
        s->has_acked = 1;
    }
    free(sp);
    p->base_tick = tick;
    p->has_base_tick = 1;
    int lost = restart(p, p->base) != 0;
    terrad_twin_read(p->twin, p->x, p->y, p->w, p->h, p->heights, NULL);
    return restored(lost, "resume", err);
}

const int32_t *terrad_twin_prediction_heights(const terrad_twin_prediction *p)
{
    return p ? p->heights : NULL;
}

const terrad_twin_prediction_stats *
terrad_twin_prediction_get_stats(const terrad_twin_prediction *p)
{
    return p ? &p->stats : NULL;
}

int terrad_twin_prediction_pending(const terrad_twin_prediction *p, uint32_t *seqs, int max)
{
    if (!p)
        return 0;
    for (int64_t i = 0; seqs && i < p->npending && i < max; i++)
        seqs[i] = p->pending[i].seq;
    return (int)p->npending;
}

terrad_twin *terrad_twin_prediction_twin(terrad_twin_prediction *p)
{
    return p ? p->twin : NULL;
}
