/*
 * model_diffusion.c: Gilardi, Watten and Newbury's drift-diffusion terrain
 * (eq. 1-8), in two forms, chosen by material.conservative:
 *
 *   conservative (default): an integer flux form. Every edge between two
 *     neighbouring cells of the window carries one flux per substep,
 *     computed once and applied + to one cell and - to the other, so Σh over
 *     the window is exact whatever happens. Two fluxes share the edge:
 *       diffusion  c_d * (|Δh| - T)+ downhill, T the angle of repose as a
 *                  height threshold (the role of Gilardi's weights w, eq. 4);
 *       drift      c_z * ((p_i - p_j) + (p_i + p_j)/2 * u·e), the collider's
 *                  push (eq. 2's -∇·(F ζ⁻¹) with F = force_scale * p (u + radial)):
 *                  p is the penetration of the column, u the travel direction
 *                  of the nearest collider, e the edge's direction.
 *     A cell never gives more than it has above the floor (its outgoing
 *     fluxes are scaled down together), so no column crosses the floor; the
 *     drift never lifts a column above the top of the collider that pushes
 *     (edge_flux), so no column rises above what touched the scene.
 *
 *   Gilardi's scheme: eq. 6-8 as published, explicit and centred, in double,
 *     heights measured in cells (Δx = 1); the result is rounded back to
 *     integer units each tick. It drifts in volume (they saw it; the rounding
 *     adds to it) and, with a fixed substep count and Δt past its limit, it
 *     oscillates and grows: the window is then refused at the height limit
 *     rather than let a NaN or a wrapped value into the world.
 *
 * Stability, and why any Δt works under automatic sub-stepping: with
 * c_d + c_z <= 1/8 per substep, a cell's new height is a convex combination
 * of its own and its neighbours' (4 edges, each weight <= 1/8, own weight
 * >= 1/2): no new maximum or minimum from diffusion (a maximum principle),
 * and the checkerboard mode's factor 1 - 8c stays >= 0, so nothing
 * oscillates. Auto picks n = ceil(8 (D + ζ⁻¹ force_scale) Δt) substeps of
 * Δt/n; past SIM_DIFFUSION_SUBSTEPS_MAX it runs that many at the bound (the
 * tick is "saturated": the material relaxes as fast as it can be resolved,
 * which for such Δt is to its rest state anyway). Integer fluxes round
 * toward zero, which only lowers the weights.
 *
 * A fast collider, sliced (issue 20, item 4). The model is a rate: a column
 * deforms for as long as a collider presses it. Pressing the whole swept
 * path for one Δt let a collider that crossed 20 cells in a tick touch each
 * column for a tick or two instead of the ten a slow one gives, and the bow
 * wave each tick left at its last pose stood above the snow in the middle of
 * the next tick's path: a row of dents, not a trench. So a tick whose
 * fastest collider crosses L > 1 cells runs L slices, each a full Δt with
 * every collider at the next 1/L of its sweep (the sub-step poses of
 * collider/sweep.c, each cast once; the slicing is sim_slices.c, shared
 * with bekker): a collider crossing L cells in a tick
 * presses each column as long as one crossing a cell per tick for L ticks,
 * so the trail does not depend on how its motion is cut into ticks. Δt is
 * the model's own time per tick (a scene parameter, not the tick's wall
 * time), and here it follows the collider's advance. A collider that moves at most 1.5 cells a
 * tick is one slice: the tick is exactly as before. A slice of the integer
 * form runs over its colliders' part of the window only (sim_slice_rect), so a
 * sliced tick costs what L slow ticks cost, not L times the whole sweep.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <string.h>

#define STABLE_SUM (1.0 / 8.0)

int sim_diffusion_substeps(const sim_params *p, double *c_diffusion, double *c_drift)
{
    double cd = p->diffusion_d * p->diffusion_dt;
    double cz = p->diffusion_zeta_inv * p->diffusion_force_scale * p->diffusion_dt;
    if (!isfinite(cd))
        cd = 1e300;
    if (!isfinite(cz))
        cz = 1e300;
    double total = cd + cz;
    int n;
    if (p->diffusion_substeps != SIM_DIFFUSION_SUBSTEPS_AUTO) {
        n = p->diffusion_substeps;
    } else {
        double need = ceil(total / STABLE_SUM);
        n = need < 1.0                          ? 1
            : need > SIM_DIFFUSION_SUBSTEPS_MAX ? SIM_DIFFUSION_SUBSTEPS_MAX
                                                : (int)need;
    }
    cd /= n;
    cz /= n;
    /* the integer form always keeps the bound; Gilardi's scheme only under auto */
    if ((p->diffusion_conservative || p->diffusion_substeps == SIM_DIFFUSION_SUBSTEPS_AUTO) &&
        cd + cz > STABLE_SUM) {
        double k = STABLE_SUM / (cd + cz);
        cd *= k;
        cz *= k;
    }
    *c_diffusion = cd;
    *c_drift = cz;
    return n;
}

/* Travel direction (unit, or 0) of collider c in the window. */
static void travel(const sim_collider *c, double *ux, double *uy)
{
    *ux = *uy = 0.0;
    if (!c->has_previous)
        return;
    double dx = c->pose.position.x - c->previous_pose.position.x;
    double dy = c->pose.position.y - c->previous_pose.position.y;
    double len = hypot(dx, dy);
    if (!(len > 1e-12) || !isfinite(len))
        return;
    *ux = dx / len;
    *uy = dy / len;
}

/* The depth slice j presses with: the engine's (the whole sweep) when the
 * tick is one slice, else cast into spare. */
static const int32_t *slice_bottom(const sim_window_job *job, int j, int slices, int32_t *spare)
{
    if (slices == 1)
        return job->bottom_override;
    sim_window_depth_slice(job, j, slices, spare);
    return spare;
}

/* The collider nearest (in xy) to each cell where slice j ends: whose travel
 * pushes it (-1 with no collider). best_d: n doubles of scratch. */
static void nearest_collider(const sim_window_job *job, int j, int slices, int32_t *owner,
                             double *best_d)
{
    int w = job->rect.w, h = job->rect.h;
    int64_t n = (int64_t)w * h;
    for (int64_t i = 0; i < n; i++)
        owner[i] = -1;
    /* collider by collider, each one's position once; ties keep the first */
    for (int c = 0; c < job->collider_count; c++) {
        const sim_collider *col = &job->colliders[c];
        vec3d q = sim_slice_pose(col, job->cell_size_m, j, slices).position;
        for (int y = 0; y < h; y++) {
            double cy = (job->rect.y + y + 0.5) * job->cell_size_m;
            for (int x = 0; x < w; x++) {
                double cx = (job->rect.x + x + 0.5) * job->cell_size_m;
                double d = (q.x - cx) * (q.x - cx) + (q.y - cy) * (q.y - cy);
                int64_t i = (int64_t)y * w + x;
                if (owner[i] < 0 || d < best_d[i]) {
                    owner[i] = c;
                    best_d[i] = d;
                }
            }
        }
    }
}

static int32_t penetration(const sim_params *p, int32_t h, int32_t bottom)
{
    int32_t under = bottom > p->floor ? bottom : p->floor;
    return h > under ? h - under : 0;
}

/* floor(c * v) toward zero, c in [0, 1/8] as Q32, |v| < 2^31. */
static int64_t scaled(int64_t c_q32, int64_t v)
{
    int64_t m = v < 0 ? -v : v;
    int64_t r = (int64_t)(((uint64_t)c_q32 * (uint64_t)m) >> 32);
    return v < 0 ? -r : r;
}

/*
 * Flux from a to b (negative: b to a) across one edge; u·e in Q16. top: the
 * highest point of the collider that pushes (units). The drift part never
 * lifts its receiver above that top: at most 1/8 of the room left under it,
 * so with the diffusion part (each edge <= 1/8 of a height difference, four
 * edges) a column ends at most at max(its highest neighbour, top) — the
 * maximum principle of the diffusion extended to the push. Without it the
 * drift fed the column just ahead of a deeply pressed ball faster than the
 * slope could take it away, and a bow wave grew past the ball's own top
 * (2.31 m beside a ball reaching 1.10 m; issue 12, item 1).
 */
static int64_t edge_flux(const sim_params *p, int64_t cd_q32, int64_t cz_q32, int32_t ha,
                         int32_t hb, int32_t pa, int32_t pb, int64_t ue_q16, int32_t top)
{
    int64_t dh = (int64_t)ha - hb, flux = 0;
    int64_t t = p->slope_threshold_axial;
    if (dh > t)
        flux += scaled(cd_q32, dh - t);
    else if (dh < -t)
        flux += scaled(cd_q32, dh + t);
    if (pa || pb) {
        int64_t push = (int64_t)pa - pb + ((((int64_t)pa + pb) * ue_q16) >> 17);
        int64_t drift = scaled(cz_q32, push);
        int64_t room = (int64_t)top - (drift > 0 ? hb : ha); /* under the receiver's top */
        int64_t most = room > 0 ? room / 8 : 0;
        if (drift > most)
            drift = most;
        else if (drift < -most)
            drift = -most;
        flux += drift;
    }
    return flux;
}

/* top[i]: the highest point (units) of the collider that pushes cell i, the
 * swept collider's, so the push of a tick stays under what touched it. */
static void pusher_tops(const sim_window_job *job, const int32_t *owner, int32_t *top)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    for (int64_t i = 0; i < n; i++)
        top[i] = WORLD_HEIGHT_MIN;
    for (int c = 0; c < job->collider_count; c++) {
        vec3d lo, hi;
        sim_collider_sweep_bounds(&job->colliders[c], job->cell_size_m, &lo, &hi);
        int32_t z = sim_units_clamped(hi.z, job->units_per_m);
        z = z > WORLD_HEIGHT_MAX ? WORLD_HEIGHT_MAX : z < WORLD_HEIGHT_MIN ? WORLD_HEIGHT_MIN : z;
        for (int64_t i = 0; i < n; i++)
            if (owner[i] == c)
                top[i] = z;
    }
}

/* The integer flux form's state over one window: scratch arrays and the
 * per-substep coefficients. */
typedef struct flux_state {
    int w, h;
    int64_t cd_q32, cz_q32;
    const int32_t *bottom;
    int32_t *owner, *top, *pen, *fx, *fy;
    int64_t *out;
} flux_state;

/* Each edge's flux, once: fx[i] from i to i+1, fy[i] from i to i+w; out[i]
 * sums what cell i gives. */
static void edge_fluxes(const sim_params *p, const sim_window_job *job, const flux_state *f)
{
    int w = f->w, h = f->h;
    const int32_t *heights = job->heights, *pen = f->pen;
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int64_t i = (int64_t)y * w + x;
            double ux = 0.0, uy = 0.0;
            int o = f->owner[i];
            if (o >= 0 && (pen[i] || (x + 1 < w && pen[i + 1]) || (y + 1 < h && pen[i + w])))
                travel(&job->colliders[o], &ux, &uy);
            f->fx[i] = f->fy[i] = 0;
            if (x + 1 < w) {
                int64_t fl = edge_flux(p, f->cd_q32, f->cz_q32, heights[i], heights[i + 1], pen[i],
                                       pen[i + 1], (int64_t)lround(ux * 65536.0), f->top[i]);
                f->fx[i] = (int32_t)fl;
                f->out[fl > 0 ? i : i + 1] += fl > 0 ? fl : -fl;
            }
            if (y + 1 < h) {
                int64_t fl = edge_flux(p, f->cd_q32, f->cz_q32, heights[i], heights[i + w], pen[i],
                                       pen[i + w], (int64_t)lround(uy * 65536.0), f->top[i]);
                f->fy[i] = (int32_t)fl;
                f->out[fl > 0 ? i : i + w] += fl > 0 ? fl : -fl;
            }
        }
    }
}

/* A cell gives at most what it has above the floor: scale its outflows
 * together (each edge has one giver, so the sum stays exact). */
static void limit_outflows(const sim_params *p, const sim_window_job *job, const flux_state *f)
{
    int w = f->w, h = f->h;
    int64_t n = (int64_t)w * h;
    int64_t *out = f->out;
    int32_t *fx = f->fx, *fy = f->fy;
    for (int64_t i = 0; i < n; i++) {
        int64_t avail = (int64_t)job->heights[i] - p->floor;
        if (avail < 0)
            avail = 0;
        out[i] = out[i] > avail ? (avail << 20) / out[i] : -1; /* Q20 factor, -1 = 1 */
    }
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int64_t i = (int64_t)y * w + x;
            if (x + 1 < w && fx[i]) {
                int64_t giver = fx[i] > 0 ? i : i + 1;
                if (out[giver] >= 0)
                    fx[i] = (int32_t)(fx[i] > 0 ? (fx[i] * out[giver]) >> 20
                                                : -((-(int64_t)fx[i] * out[giver]) >> 20));
            }
            if (y + 1 < h && fy[i]) {
                int64_t giver = fy[i] > 0 ? i : i + w;
                if (out[giver] >= 0)
                    fy[i] = (int32_t)(fy[i] > 0 ? (fy[i] * out[giver]) >> 20
                                                : -((-(int64_t)fy[i] * out[giver]) >> 20));
            }
        }
    }
}

/* One substep of the integer flux form. */
static sim_window_status flux_substep(const sim_params *p, sim_window_job *job, const flux_state *f)
{
    int w = f->w, h = f->h;
    int64_t n = (int64_t)w * h;
    int32_t *heights = job->heights;
    for (int64_t i = 0; i < n; i++) {
        f->pen[i] = penetration(p, heights[i], f->bottom[i]);
        f->out[i] = 0;
    }
    edge_fluxes(p, job, f);
    limit_outflows(p, job, f);
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int64_t i = (int64_t)y * w + x;
            int64_t v = heights[i];
            if (x + 1 < w)
                v -= f->fx[i];
            if (x > 0)
                v += f->fx[i - 1];
            if (y + 1 < h)
                v -= f->fy[i];
            if (y > 0)
                v += f->fy[i - w];
            if (v > WORLD_HEIGHT_MAX || v < WORLD_HEIGHT_MIN)
                return SIM_WINDOW_HEIGHT_LIMIT;
            /* fluxes were read from pen/fx/fy only: in place is safe */
            f->out[i] = v;
        }
    }
    for (int64_t i = 0; i < n; i++)
        heights[i] = (int32_t)f->out[i];
    return SIM_WINDOW_OK;
}

/* Slice j of the integer flux form over job's rect: its depth, who pushes
 * each cell, then the tick's substeps. */
static sim_window_status flux_slice(const sim_params *p, sim_window_job *job, flux_state *f, int j,
                                    int slices, int substeps, int32_t *spare)
{
    f->w = job->rect.w;
    f->h = job->rect.h;
    f->bottom = slice_bottom(job, j, slices, spare);
    nearest_collider(job, j, slices, f->owner, (double *)(void *)f->out); /* out: free here */
    pusher_tops(job, f->owner, f->top);
    for (int s = 0; s < substeps; s++) {
        sim_window_status st = flux_substep(p, job, f);
        if (st != SIM_WINDOW_OK)
            return st;
    }
    return SIM_WINDOW_OK;
}

static sim_window_status conservative_window(const sim_params *p, sim_window_job *job,
                                             int32_t *scratch)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    int32_t *pen = scratch, *fx = pen + n, *fy = fx + n, *owner = fy + n;
    int64_t *out = (int64_t *)(void *)(owner + n); /* 4n int32 in: 8-byte aligned */
    int32_t *top = (int32_t *)(void *)(out + n), *spare = top + n, *packed = spare + n;
    double cd, cz;
    int steps = sim_diffusion_substeps(p, &cd, &cz);
    flux_state f = {.cd_q32 = (int64_t)floor(cd * 4294967296.0),
                    .cz_q32 = (int64_t)floor(cz * 4294967296.0),
                    .owner = owner,
                    .top = top,
                    .pen = pen,
                    .fx = fx,
                    .fy = fy,
                    .out = out};
    if (f.cd_q32 == 0 && f.cz_q32 == 0)
        return SIM_WINDOW_OK; /* D = 0 and no drift: nothing moves */
    int slices = sim_sweep_slices(job);
    if (slices == 1)
        return flux_slice(p, job, &f, 1, 1, steps, spare);
    for (int j = 1; j <= slices; j++) {
        sim_window_job part = *job;
        part.rect = sim_slice_rect(job, j, slices);
        if (part.rect.w <= 0 || part.rect.h <= 0)
            continue;
        part.heights = packed;
        sim_slice_copy(job->rect, part.rect, job->heights, packed, sizeof *packed, 1);
        sim_window_status st = flux_slice(p, &part, &f, j, slices, steps, spare);
        if (st != SIM_WINDOW_OK)
            return st; /* the window is refused whole */
        sim_slice_copy(job->rect, part.rect, job->heights, packed, sizeof *packed, 0);
    }
    return SIM_WINDOW_OK;
}

/* Gilardi eq. 4 / 8: the weight of one direction. */
static double repose_weight(double d, double alpha)
{
    double span = M_PI / 2.0 - alpha;
    if (!(span > 1e-12))
        return 0.0;
    double w = (fabs(d) - alpha) / span;
    return w < 0.0 ? 0.0 : w > 1.0 ? 1.0 : w;
}

/* Gilardi's scheme's state over one window: heights in cells (H, next), the
 * force field, and what the substeps read. */
typedef struct gilardi_state {
    int w, h;
    double dt, cell_units;
    double *H, *next, *Fx, *Fy;
    const int32_t *bottom, *owner;
} gilardi_state;

/* One explicit substep: H advances into next, then the two swap. */
static void gilardi_substep(const sim_params *p, const sim_window_job *job, gilardi_state *g)
{
    int w = g->w, h = g->h;
    double *H = g->H, *next = g->next, *Fx = g->Fx, *Fy = g->Fy;
    /* F = force_scale * (p u - ∇p), p in cells, spread over the contact */
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int64_t i = (int64_t)y * w + x;
            int32_t hi =
                (int32_t)fmax(fmin(H[i] * g->cell_units, WORLD_HEIGHT_MAX), WORLD_HEIGHT_MIN);
            double pc = penetration(p, hi, g->bottom[i]) / g->cell_units;
            double ux = 0.0, uy = 0.0;
            if (g->owner[i] >= 0 && pc > 0.0)
                travel(&job->colliders[g->owner[i]], &ux, &uy);
            Fx[i] = p->diffusion_force_scale * pc * ux;
            Fy[i] = p->diffusion_force_scale * pc * uy;
        }
    }
    for (int y = 0; y < h; y++) {
        for (int x = 0; x < w; x++) {
            int64_t i = (int64_t)y * w + x;
            int64_t l = x > 0 ? i - 1 : i, r = x + 1 < w ? i + 1 : i;
            int64_t d = y > 0 ? i - w : i, u = y + 1 < h ? i + w : i;
            /* eq. 6 and its z twin (Δx = 1) */
            double dx = p->diffusion_d * (H[l] + H[r] - 2.0 * H[i]) -
                        0.5 * p->diffusion_zeta_inv * (Fx[r] - Fx[l]);
            double dy = p->diffusion_d * (H[d] + H[u] - 2.0 * H[i]) -
                        0.5 * p->diffusion_zeta_inv * (Fy[u] - Fy[d]);
            /* eq. 7 with the weights of eq. 4 / 8 */
            next[i] = H[i] + g->dt * (repose_weight(dx, p->repose_rad) * dx +
                                      repose_weight(dy, p->repose_rad) * dy);
        }
    }
    g->H = next;
    g->next = H;
}

static sim_window_status gilardi_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    gilardi_state g = {.w = job->rect.w, .h = job->rect.h};
    int64_t n = (int64_t)g.w * g.h;
    g.H = (double *)(void *)scratch;
    g.next = g.H + n;
    g.Fx = g.next + n;
    g.Fy = g.Fx + n;
    int32_t *owner = (int32_t *)(void *)(g.Fy + n), *spare = owner + n;
    g.owner = owner;
    g.cell_units = (double)p->units_per_m * p->cell_size_m; /* units per cell of height */
    double cd, cz;
    int steps = sim_diffusion_substeps(p, &cd, &cz);
    g.dt = p->diffusion_dt / steps;
    /* under auto the substep keeps (D + ζ⁻¹ force_scale) Δt at the bound too */
    double rate = p->diffusion_d + p->diffusion_zeta_inv * p->diffusion_force_scale;
    if (p->diffusion_substeps == SIM_DIFFUSION_SUBSTEPS_AUTO && rate * g.dt > STABLE_SUM)
        g.dt = STABLE_SUM / rate;
    (void)cd;
    (void)cz;
    for (int64_t i = 0; i < n; i++)
        g.H[i] = job->heights[i] / g.cell_units;
    int slices = sim_sweep_slices(job);
    for (int j = 1; j <= slices; j++) {
        g.bottom = slice_bottom(job, j, slices, spare);
        nearest_collider(job, j, slices, owner, g.Fx); /* Fx: free until the substep */
        for (int s = 0; s < steps; s++)
            gilardi_substep(p, job, &g);
    }
    /* back to integer units; a non-finite or out-of-range column refuses the window */
    int32_t *heights = job->heights;
    for (int64_t i = 0; i < n; i++) {
        double u = g.H[i] * g.cell_units;
        if (!isfinite(u) || u > WORLD_HEIGHT_MAX || u < WORLD_HEIGHT_MIN)
            return SIM_WINDOW_HEIGHT_LIMIT;
    }
    for (int64_t i = 0; i < n; i++) {
        int32_t v = (int32_t)llround(g.H[i] * g.cell_units);
        /* material never goes below the floor; a column already under it stays */
        if (v < p->floor)
            v = heights[i] < p->floor ? heights[i] : p->floor;
        heights[i] = v;
    }
    return SIM_WINDOW_OK;
}

sim_window_status sim_diffusion_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    if (p->diffusion_conservative)
        return conservative_window(p, job, scratch);
    return gilardi_window(p, job, scratch);
}
