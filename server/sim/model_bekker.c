/*
 * model_bekker.c: soil that pushes back (issue 21). A CPU window function
 * the engine calls per window (row 4d of the tick) when a scene picks the
 * bekker model; the GL backend runs it on the CPU too, as every non-persson
 * model. Per window:
 *
 *   1. depth at the collider's pose, one collider at a time, so every cell
 *      knows which collider touches it (the lowest; ties to the first). A
 *      collider whose pose travels more than 1.5 cells in a tick is pressed
 *      in one-cell slices (sim_slices.c; bekker_sliced), each a slow tick;
 *   2. contact patches: 4-connected cells of one collider below the surface;
 *      each patch's Bekker width b = 2 A / L (Chrono SCM's rule: a long strip
 *      of width w gives w, a disc of radius r gives r);
 *   3. per contact cell, Chrono SCM's node rule (docs/notes/
 *      terramechanics.md) in height units: the total sinkage s is the cell's
 *      plastic sinkage plus how far the collider is below its surface; the
 *      elastic trial K_e (s - s_plastic) is the pressure unless it passes
 *      Bekker's (kc/b + kphi) s^n, in which case the cell yields: its
 *      plastic sinkage grows so that only the elastic share sigma/K_e stays
 *      between the surface and the collider. Slip-sinkage: n grows by the
 *      soil's slip_n times the cell's slip ratio (bekker_slip_ratio), so a
 *      slipping wheel digs in as real ones do. A cell pressed before (a second
 *      pass) reloads elastically up to where it yielded, so it sinks less.
 *      Damping adds R times the sinking speed. Janosi-Hanamoto shear:
 *      tau = (c + f sigma tan phi)(1 - e^(-j/K)), f the share Wong-Reece's
 *      rear region leaves a cell behind the peak angle (bekker_shear_share,
 *      1 ahead of it and for a plate), j the shear displacement
 *      accumulated along the collider's slip while the cell stays in contact
 *      (reset when it leaves contact: j is per pass, as in Wong-Reece; SCM
 *      never resets it), against the slip. The cell's force is
 *      A (sigma N + tau T), N the collider's surface normal there;
 *   4. the plastic lowering splits into compaction (the material's
 *      `compression` share, kept per cell as an integer) and displacement,
 *      which goes through Sumner's first-ring spread and the slope evening
 *      (sim_sumner_settle), so Σh + Σcompacted is exact.
 *
 * With a scene's `materials` table, steps 3 and 4 read each cell's own row:
 * its material's soil (ground_material_table.soils: the scene's unless the
 * entry has "soil") and compression; the patch width b stays the patch's.
 *
 * Forces are summed over cells in row-major order into one contact per
 * collider of the window; the engine adds windows in plan order. Every
 * per-cell quantity is computed from that cell's inputs alone, so the sums
 * and the integer state are identical for any thread count and tiling.
 * sim_bekker_carry finds, by bisection on whole height units, the height at
 * which the soil carries a given load (load-driven colliders).
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdint.h>
#include <string.h>

/* One slice's press and settle: bottom, owner, tmp, cls, patch, queue (6n),
 * settle (12n + 2), per-patch edges (n), then doubles aligned (+2): the
 * patches' widths, entry and exit angles (n each). */
static int64_t press_scratch_cells(int w, int h)
{
    int64_t n = (int64_t)w * h;
    return 6 * n + sim_settle_scratch_cells(w, h) + 2 + 2 * n + n + 4 * n;
}

/* A slice's press over its part, then the part packed: heights (n), soil
 * state (SIM_SOIL_STATE_FIELDS n) and material ids (n bytes). */
int64_t sim_bekker_scratch_cells(int w, int h)
{
    int64_t n = (int64_t)w * h;
    return press_scratch_cells(w, h) + n + SIM_SOIL_STATE_FIELDS * n + (n + 3) / 4;
}

static vec3d v3(double x, double y, double z)
{
    return (vec3d){x, y, z};
}

static vec3d v3_cross(vec3d a, vec3d b)
{
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

static double v3_dot(vec3d a, vec3d b)
{
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

/* Linear and angular velocity of a collider from its two poses this tick. */
static void collider_velocity(const sim_collider *c, double tick_s, vec3d *v, vec3d *w)
{
    *v = *w = v3(0, 0, 0);
    if (!c->has_previous || !(tick_s > 0.0))
        return;
    vec3d a = c->previous_pose.position, b = c->pose.position;
    *v = v3((b.x - a.x) / tick_s, (b.y - a.y) / tick_s, (b.z - a.z) / tick_s);
    quatd p = c->previous_pose.orientation;
    quatd d = quat_multiply(c->pose.orientation, (quatd){p.w, -p.x, -p.y, -p.z});
    if (d.w < 0.0)
        d = (quatd){-d.w, -d.x, -d.y, -d.z};
    double s = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    if (!(s > 0.0) || !isfinite(s))
        return;
    double angle = 2.0 * atan2(s, d.w) / tick_s;
    *w = v3(d.x / s * angle, d.y / s * angle, d.z / s * angle);
}

/* 1: depth at each collider's pose (where it stands at the end of slice j
 * of `slices`) and the collider that owns each cell. */
static void bekker_depth(const sim_window_job *job, int j, int slices, int32_t *bottom,
                         int32_t *owner, int32_t *tmp)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    if (job->bottom_override) {
        for (int64_t i = 0; i < n; i++) {
            bottom[i] = job->bottom_override[i];
            owner[i] = bottom[i] != COLLIDER_BOTTOM_NONE && job->collider_count > 0 ? 0 : -1;
        }
    } else {
        for (int64_t i = 0; i < n; i++) {
            bottom[i] = COLLIDER_BOTTOM_NONE;
            owner[i] = -1;
        }
        for (int k = 0; k < job->collider_count; k++) {
            for (int64_t i = 0; i < n; i++)
                tmp[i] = COLLIDER_BOTTOM_NONE;
            const sim_collider *c = &job->colliders[k];
            collider_pose at = sim_slice_pose(c, job->cell_size_m, j, slices);
            at.position.z -= c->lift_units / job->units_per_m; /* at its whole unit */
            /* a lugged wheel presses with its lugs' envelope (model_lugs.c) */
            collider_geometry g = sim_lug_envelope(c->geometry);
            collider_depth_cpu(&g, at, job->rect, job->cell_size_m, job->units_per_m, tmp);
            for (int64_t i = 0; i < n; i++)
                if (tmp[i] < bottom[i]) {
                    bottom[i] = tmp[i];
                    owner[i] = k;
                }
        }
    }
    if (job->bottom_out)
        memcpy(job->bottom_out, bottom, (size_t)n * sizeof *bottom);
}

/*
 * 2: contact patches (4-connected, one owner) labelled in row-major order of
 * their first cell; width[l] = 2 A / L in metres, L counting every cell edge
 * not shared with the same patch (the window's border included). Returns the
 * count. edges is scratch (one per patch).
 */
static int32_t bekker_patches(int w, int h, double cell_m, const int32_t *cls, const int32_t *owner,
                              int32_t *label, int32_t *queue, int32_t *cells, int32_t *edges,
                              double *width)
{
    static const int dx[4] = {1, -1, 0, 0}, dy[4] = {0, 0, 1, -1};
    int n = w * h;
    for (int i = 0; i < n; i++)
        label[i] = -1;
    int32_t count = 0;
    for (int start = 0; start < n; start++) {
        if (cls[start] != SIM_CELL_PENETRATING || label[start] >= 0)
            continue;
        int head = 0, tail = 0;
        queue[tail++] = start;
        label[start] = count;
        cells[count] = edges[count] = 0;
        while (head < tail) {
            int i = queue[head++], x = i % w, y = i / w;
            cells[count]++;
            for (int j = 0; j < 4; j++) {
                int qx = x + dx[j], qy = y + dy[j], q = qy * w + qx;
                if (qx < 0 || qy < 0 || qx >= w || qy >= h || cls[q] != SIM_CELL_PENETRATING ||
                    owner[q] != owner[i]) {
                    edges[count]++;
                    continue;
                }
                if (label[q] < 0) {
                    label[q] = count;
                    queue[tail++] = q;
                }
            }
        }
        width[count] = 2.0 * cells[count] * cell_m / edges[count];
        count++;
    }
    return count;
}

/* The collider's surface normal at cell (x, y) from its depth (central
 * differences over the same collider's cells, one-sided at its edge). */
static vec3d bekker_normal(const sim_window_job *job, const int32_t *bottom, const int32_t *owner,
                           int x, int y)
{
    int w = job->rect.w, h = job->rect.h, i = y * w + x;
    double scale = 1.0 / ((double)job->units_per_m * job->cell_size_m);
    double g[2] = {0.0, 0.0};
    for (int axis = 0; axis < 2; axis++) {
        int ax = axis == 0, ay = axis == 1;
        int pi = -1, ni = -1;
        if (x + ax < w && y + ay < h && owner[i + ax + ay * w] == owner[i])
            pi = i + ax + ay * w;
        if (x - ax >= 0 && y - ay >= 0 && owner[i - ax - ay * w] == owner[i])
            ni = i - ax - ay * w;
        if (pi >= 0 && ni >= 0)
            g[axis] = ((double)bottom[pi] - bottom[ni]) * scale / 2.0;
        else if (pi >= 0)
            g[axis] = ((double)bottom[pi] - bottom[i]) * scale;
        else if (ni >= 0)
            g[axis] = ((double)bottom[i] - bottom[ni]) * scale;
    }
    double len = sqrt(g[0] * g[0] + g[1] * g[1] + 1.0);
    return v3(-g[0] / len, -g[1] / len, 1.0 / len);
}

/* What one contact cell does: its pressure, plastic lowering and shear. */
typedef struct bekker_cell {
    double sigma, tau;
    int32_t raw;
    double sinkage_m;
} bekker_cell;

/* 3: SCM's node rule for one cell (state updated in place). lift: the
 * collider's height above the whole unit its depth was cast at (the
 * sub-unit elastic state: the cell's penetration is e - lift, 0 <= lift < 1,
 * so the pressure is continuous in the collider's height). */
static bekker_cell bekker_cell_step(const sim_params *p, const sim_soil *s, int32_t height,
                                    int32_t bottom, double lift, double width_m, double sink_speed,
                                    double slip_step_m, double slip_ratio, double shear_share,
                                    int32_t *state)
{
    sim_soil slipping = *s;
    slipping.n += s->slip_n * slip_ratio;
    double upm = (double)p->units_per_m;
    int64_t e = (int64_t)height - bottom; /* >= 1: in contact */
    double pen = (double)e - lift;        /* > 0 */
    double total = (double)state[SIM_SOIL_SINK] + pen;
    bekker_cell out = {0.0, 0.0, 0, total / upm};
    double bekker = sim_soil_bekker_pa(&slipping, width_m, total / upm);
    double trial = s->elastic_pa_m * (pen / upm);
    if (trial > bekker) {
        /* yield: only the elastic share sigma / K_e stays above the collider;
         * the plastic lowering is whole units, so the share kept is rounded
         * up to the next unit boundary: reloaded at the same height the cell
         * then yields again at the same sigma and stays. Rounded down (as
         * before), a share under one unit left nothing to carry a load at the
         * same height next tick, so a static load crept one unit per tick. */
        double el = bekker / s->elastic_pa_m * upm;
        int64_t raw = pen > el ? (int64_t)floor(pen - el) : 0;
        if (raw > (int64_t)height - p->floor)
            raw = (int64_t)height - p->floor > 0 ? (int64_t)height - p->floor : 0;
        out.raw = (int32_t)raw;
        out.sigma = bekker;
    } else {
        out.sigma = trial; /* reloading below where the cell last yielded */
    }
    out.sigma += s->damping_pa_s_m * sink_speed;
    if (out.sigma < 0.0)
        out.sigma = 0.0;
    int64_t sink = (int64_t)state[SIM_SOIL_SINK] + out.raw;
    state[SIM_SOIL_SINK] = sink > INT32_MAX ? INT32_MAX : (int32_t)sink;
    double j = (double)state[SIM_SOIL_SHEAR_UM] + floor(slip_step_m * 1e6);
    state[SIM_SOIL_SHEAR_UM] = j > (double)INT32_MAX ? INT32_MAX : (int32_t)j;
    double strength =
        s->cohesion_pa + shear_share * out.sigma * tan(s->friction_deg * M_PI / 180.0);
    out.tau = strength * (1.0 - exp(-(double)state[SIM_SOIL_SHEAR_UM] * 1e-6 / s->shear_k_m));
    return out;
}

/* The window's per-collider kinematics into its contacts. */
static void bekker_contacts_begin(const sim_params *p, sim_window_job *job)
{
    for (int k = 0; k < job->collider_count; k++) {
        sim_contact *c = &job->contacts[k];
        memset(c, 0, sizeof *c);
        c->collider_id = job->colliders[k].id;
        vec3d v, w;
        collider_velocity(&job->colliders[k], p->tick_s, &v, &w);
        c->velocity[0] = v.x, c->velocity[1] = v.y, c->velocity[2] = v.z;
        c->angular[0] = w.x, c->angular[1] = w.y, c->angular[2] = w.z;
    }
}

/* A contact cell's force and torque into its collider's contact. */
static void bekker_contact_add(sim_contact *c, vec3d at, vec3d centre, vec3d normal, vec3d slip,
                               const bekker_cell *cell, double area)
{
    double sl = sqrt(v3_dot(slip, slip));
    vec3d f = v3(area * cell->sigma * normal.x, area * cell->sigma * normal.y,
                 area * cell->sigma * normal.z);
    if (sl > 0.0) {
        double t = area * cell->tau / sl; /* against the slip */
        f = v3(f.x - t * slip.x, f.y - t * slip.y, f.z - t * slip.z);
    }
    vec3d tq = v3_cross(v3(at.x - centre.x, at.y - centre.y, at.z - centre.z), f);
    c->force_n[0] += f.x, c->force_n[1] += f.y, c->force_n[2] += f.z;
    c->torque_nm[0] += tq.x, c->torque_nm[1] += tq.y, c->torque_nm[2] += tq.z;
    c->area_m2 += area;
    c->cells++;
}

/* CONTACT's measures of one contact cell (PROTOCOL.md) into its collider's
 * contact, and the sinkage at the collider's lowest point. Cells come in
 * row-major order: the deepest point's ties keep the first. */
static void bekker_contact_measure(const sim_window_job *job, sim_contact *c, int owner_k, int x,
                                   int y, int32_t bottom, double sinkage_m)
{
    int w = job->rect.w, h = job->rect.h, i = y * w + x;
    const int32_t *hs = job->heights;
    int64_t pen = (int64_t)hs[i] - bottom;
    double cell = job->cell_size_m, upm = (double)job->units_per_m;
    c->volume += pen;
    if (pen > c->deepest_units) {
        c->deepest_units = pen;
        c->deepest[0] = (job->rect.x + x + 0.5) * cell;
        c->deepest[1] = (job->rect.y + y + 0.5) * cell;
        c->deepest[2] = (bottom + job->colliders[owner_k].lift_units) / upm;
    }
    /* among the cells where the bottom is lowest (a cylinder's whole line),
     * the least: a cell at the rut's side edge was also pressed under soil
     * the spread had put on it, which was never the undisturbed surface */
    if (c->cells == 1 || bottom < c->lowest_bottom ||
        (bottom == c->lowest_bottom && sinkage_m < c->sinkage_m)) {
        c->lowest_bottom = bottom;
        c->sinkage_m = sinkage_m;
    }
    int xp = x + 1 < w ? x + 1 : x, xm = x > 0 ? x - 1 : x;
    int yp = y + 1 < h ? y + 1 : y, ym = y > 0 ? y - 1 : y;
    double gx = ((double)hs[y * w + xp] - hs[y * w + xm]) / upm / ((xp - xm) * cell);
    double gy = ((double)hs[yp * w + x] - hs[ym * w + x]) / upm / ((yp - ym) * cell);
    double len = sqrt(gx * gx + gy * gy + 1.0);
    c->normal_sum[0] += -gx / len;
    c->normal_sum[1] += -gy / len;
    c->normal_sum[2] += 1.0 / len;
}

/* The surface point's velocity of collider k at `at`: its sinking speed
 * (along -normal), and its tangential slip from the collider's horizontal
 * travel and turning — sinking is not slip (Wong-Reece's shear displacement
 * is the rim's against the ground's travel). With the vertical speed in it, a
 * sinking wheel's sloped cells slipped: a standing wheel's soil then sheared
 * (against the search's trial motion) at every height but exactly its last
 * one and was softer there (slip ratio 0.5), so the load search met a jump of
 * up to 115 N at the height it had stood at. */
static void bekker_point_motion(const sim_contact *c, vec3d centre, vec3d at, vec3d normal,
                                double *sink_speed, vec3d *slip)
{
    vec3d r = v3(at.x - centre.x, at.y - centre.y, at.z - centre.z);
    vec3d wr = v3_cross(v3(c->angular[0], c->angular[1], c->angular[2]), r);
    vec3d v = v3(c->velocity[0] + wr.x, c->velocity[1] + wr.y, c->velocity[2] + wr.z);
    *sink_speed = -v3_dot(v, normal);
    v.z -= c->velocity[2];
    double vn = v3_dot(v, normal);
    *slip = v3(v.x - vn * normal.x, v.y - vn * normal.y, v.z - vn * normal.z);
}

/* The cell's slip ratio: its tangential slip speed u (bekker_point_motion)
 * against u plus the collider's own tangential travel speed. At a wheel's
 * lowest point this is the wheel's slip 1 - v/(wR); a plate pressed
 * straight down, or a wheel at rest, has 0; a block sliding without turning
 * 0.5. */
static double bekker_slip_ratio(const sim_contact *c, vec3d normal, double u)
{
    vec3d v = v3(c->velocity[0], c->velocity[1], 0.0);
    double vn = v3_dot(v, normal);
    vec3d vt = v3(v.x - vn * normal.x, v.y - vn * normal.y, v.z - vn * normal.z);
    double sum = u + sqrt(v3_dot(vt, vt));
    return sum > 0.0 ? u / sum : 0.0;
}

/* The angle θ of the collider's surface at a cell from straight down, in
 * the vertical plane of its travel, positive ahead (a wheel's front arc);
 * 0 when the collider does not travel. */
static double bekker_angle(const sim_contact *c, vec3d normal)
{
    double vx = c->velocity[0], vy = c->velocity[1], v = sqrt(vx * vx + vy * vy);
    if (!(v > 0.0))
        return 0.0;
    return atan2(-(normal.x * vx + normal.y * vy) / v, normal.z);
}

/* Each patch's contact arc: its entry angle θ1 (the largest θ, ahead) and
 * its exit angle θ2 (the smallest, behind; <= 0), per patch label. */
static void bekker_arcs(const sim_window_job *job, const int32_t *bottom, const int32_t *owner,
                        const int32_t *cls, const int32_t *label, double *entry, double *rear)
{
    int w = job->rect.w, h = job->rect.h;
    for (int i = 0; i < w * h; i++)
        entry[i] = rear[i] = 0.0;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            if (cls[i] != SIM_CELL_PENETRATING)
                continue;
            double t = /* the same normal the cell step uses */
                bekker_angle(&job->contacts[owner[i]], bekker_normal(job, bottom, owner, x, y));
            if (t > entry[label[i]])
                entry[label[i]] = t;
            if (t < rear[label[i]])
                rear[label[i]] = t;
        }
}

/*
 * The share of a cell's normal stress that its shear may use: Wong-Reece's
 * rear region (Wong & Reece 1967, docs/notes/terramechanics.md), in
 * the form with an exit angle θ2 used for rover wheels (Ishigami et al.
 * 2007, J. Field Robotics 24(3):233-250). Over a
 * slipping wheel's arc the normal stress peaks at θm = (0.43 + 0.32 s) θ1
 * and falls behind it to nothing at the exit θ2, as the rim carries the
 * soil it shears backwards; the grid's cells behind θm instead keep the
 * full Bekker stress of their own depth, so with c + σ tan φ on every cell
 * a driven wheel mobilised its whole W tan φ and its pull kept rising with
 * slip (Ding 2011 at slip 0.6: 38 N against 15 measured). Behind θm the
 * shear uses σ scaled by the mirrored profile's ratio
 * ((cos θe - cos θ1) / (cos θ - cos θ1))^n, θe = θ1 - (θ - θ2)/(θm - θ2)
 * (θ1 - θm) the point ahead whose stress the mirror takes. 1 for a
 * collider that does not slip (a plate, a towed wheel at its bottom) or
 * does not travel, so the plate checks do not move; the normal force and
 * the plastic state are the cell's own, so only forces change, not heights.
 */
static double bekker_shear_share(const sim_soil *s, const sim_contact *c, vec3d normal, double t1,
                                 double t2, double slip)
{
    if (!(t1 > 0.0) || !(slip > 0.0))
        return 1.0;
    double t = bekker_angle(c, normal), tm = (0.43 + 0.32 * slip) * t1;
    if (t >= tm)
        return 1.0;
    double te = t1 - (t - t2) / (tm - t2) * (t1 - tm);
    double a = cos(te) - cos(t1), b = cos(t) - cos(t1);
    if (!(a > 0.0) || !(b > 0.0))
        return 0.0;
    double f = pow(a / b, s->n);
    return f < 1.0 ? f : 1.0;
}

/* Steps 1-3 and the split of step 4 for slice j of `slices` (1 of 1: the
 * tick): raw (plastic lowering) and moved (displaced part) into the settle
 * scratch, the classes into cls, the state and the contacts updated. Heights
 * are not changed. A slice is 1/slices of the tick: the colliders stand
 * where it ends, their velocities are the tick's, their slip lasts
 * tick_s / slices. */
static void bekker_press(const sim_params *p, sim_window_job *job, int j, int slices,
                         int32_t *scratch, int32_t **cls_out, int32_t **settle_out)
{
    int w = job->rect.w, h = job->rect.h, n = w * h;
    int32_t *bottom = scratch, *owner = bottom + n, *tmp = owner + n, *cls = tmp + n;
    int32_t *label = cls + n, *queue = label + n, *settle = queue + n;
    int32_t *edges = settle + sim_settle_scratch_cells(w, h);
    double *width = (double *)(void *)(((uintptr_t)(edges + n) + 7) & ~(uintptr_t)7);
    double *entry = width + n, *rear = entry + n;
    int32_t *raw = SIM_SETTLE_RAW(settle, n), *moved = SIM_SETTLE_MOVED(settle, n);
    const int32_t *heights = job->heights;
    bekker_depth(job, j, slices, bottom, owner, tmp);
    for (int i = 0; i < n; i++) {
        int32_t gap = bottom[i] == COLLIDER_BOTTOM_NONE ? INT32_MAX : bottom[i] - heights[i];
        cls[i] = owner[i] >= 0 && bottom[i] < heights[i]   ? SIM_CELL_PENETRATING
                 : owner[i] >= 0 && gap <= p->obstacle_gap ? SIM_CELL_OBSTACLE
                                                           : SIM_CELL_SEED;
        raw[i] = moved[i] = 0;
    }
    bekker_patches(w, h, job->cell_size_m, cls, owner, label, queue, tmp, edges, width);
    bekker_contacts_begin(p, job);
    bekker_arcs(job, bottom, owner, cls, label, entry, rear);
    double cell = job->cell_size_m, area = cell * cell, upm = (double)job->units_per_m;
    for (int y = 0; y < h; y++)
        for (int x = 0; x < w; x++) {
            int i = y * w + x;
            int32_t *state = job->soil_state + (int64_t)i * SIM_SOIL_STATE_FIELDS;
            if (cls[i] != SIM_CELL_PENETRATING) {
                state[SIM_SOIL_SHEAR_UM] = 0; /* a pass ends when the cell leaves contact */
                continue;
            }
            sim_contact *c = &job->contacts[owner[i]];
            vec3d centre = sim_slice_pose(&job->colliders[owner[i]], cell, j, slices).position;
            vec3d at =
                v3((job->rect.x + x + 0.5) * cell, (job->rect.y + y + 0.5) * cell, bottom[i] / upm);
            vec3d normal = bekker_normal(job, bottom, owner, x, y), slip;
            double sink_speed;
            bekker_point_motion(c, centre, at, normal, &sink_speed, &slip);
            double u = sqrt(v3_dot(slip, slip)), slip_step = u * p->tick_s / slices;
            double ratio = bekker_slip_ratio(c, normal, u);
            int id = job->material_ids ? job->material_ids[i] : 0;
            const sim_soil *soil = job->materials ? &job->materials->soils[id] : &p->soil;
            int32_t compression_q16 =
                job->materials ? job->materials->rows[id].compression_q16 : p->compression_q16;
            double share =
                bekker_shear_share(soil, c, normal, entry[label[i]], rear[label[i]], ratio);
            bekker_cell r = bekker_cell_step(p, soil, heights[i], bottom[i],
                                             job->colliders[owner[i]].lift_units, width[label[i]],
                                             sink_speed, slip_step, ratio, share, state);
            bekker_contact_add(c, at, centre, normal, slip, &r, area);
            bekker_contact_measure(job, c, owner[i], x, y, bottom[i], r.sinkage_m);
            if (tmp[label[i]] > c->patch_cells) { /* tmp: the patches' cell counts */
                c->patch_cells = tmp[label[i]];
                c->patch_width_m = width[label[i]];
            }
            int64_t compacted = ((int64_t)r.raw * compression_q16) >> 16;
            if ((int64_t)state[SIM_SOIL_COMPACTED] + compacted > INT32_MAX)
                compacted = 0; /* the memory is full: displace it all, Σ stays exact */
            state[SIM_SOIL_COMPACTED] += (int32_t)compacted;
            raw[i] = r.raw;
            moved[i] = r.raw - (int32_t)compacted;
        }
    for (int k = 0; k < job->collider_count; k++) /* a lugged wheel's bulldozing */
        if (sim_lugged(job->colliders[k].geometry))
            sim_lug_thrust(&p->soil, &job->colliders[k],
                           sim_slice_pose(&job->colliders[k], cell, j, slices),
                           job->contacts[k].lowest_bottom / upm, &job->contacts[k]);
    *cls_out = cls;
    *settle_out = settle;
}

/* Slice j's depth (scratch's first array) into the window's bottom_out,
 * the lowest over the slices: the depth the tick pressed with. */
static void slice_bottom_out(const sim_window_job *job, world_rect part, const int32_t *bottom)
{
    for (int y = 0; y < part.h; y++)
        for (int x = 0; x < part.w; x++) {
            int32_t *out = job->bottom_out + (int64_t)(part.y - job->rect.y + y) * job->rect.w +
                           (part.x - job->rect.x + x);
            int32_t b = bottom[(int64_t)y * part.w + x];
            if (b < *out)
                *out = b;
        }
}

/*
 * A tick whose fastest collider's pose travels more than 1.5 cells
 * (sim_travel_slices): one slice per cell, each the press and settle of a slow tick with every
 * collider where its slice ends, over its part of the window. Bekker's depth
 * is at the pose, not swept (forces belong to where the collider is), so a
 * tick of one press at its end left a dotted rut. The contacts are the last
 * slice's: the push where each collider stands now. A refused slice refuses
 * the window whole (the engine keeps the world's heights and state).
 */
static sim_window_status bekker_sliced(const sim_params *p, sim_window_job *job, int slices,
                                       int32_t *scratch)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    int32_t *heights = scratch + press_scratch_cells(job->rect.w, job->rect.h);
    int32_t *state = heights + n;
    uint8_t *ids = (uint8_t *)(void *)(state + SIM_SOIL_STATE_FIELDS * n);
    if (job->bottom_out)
        for (int64_t i = 0; i < n; i++)
            job->bottom_out[i] = COLLIDER_BOTTOM_NONE;
    for (int j = 1; j <= slices; j++) {
        sim_window_job part = *job;
        part.rect = sim_slice_rect(job, j, slices);
        if (part.rect.w <= 0 || part.rect.h <= 0) {
            bekker_contacts_begin(p, job); /* nothing touched where it ends */
            continue;
        }
        part.heights = heights;
        part.soil_state = state;
        part.bottom_out = NULL;
        part.compaction = NULL;
        part.base_heights = NULL;
        sim_slice_copy(job->rect, part.rect, job->heights, heights, sizeof *heights, 1);
        sim_slice_copy(job->rect, part.rect, job->soil_state, state,
                       SIM_SOIL_STATE_FIELDS * sizeof *state, 1);
        if (job->material_ids) {
            sim_slice_copy(job->rect, part.rect, (void *)(uintptr_t)job->material_ids, ids,
                           sizeof *ids, 1);
            part.material_ids = ids;
        }
        int32_t *cls, *settle;
        bekker_press(p, &part, j, slices, scratch, &cls, &settle);
        if (job->bottom_out)
            slice_bottom_out(job, part.rect, scratch);
        sim_window_status st = sim_sumner_settle(p, &part, cls, settle);
        if (st != SIM_WINDOW_OK)
            return st;
        sim_slice_copy(job->rect, part.rect, job->heights, heights, sizeof *heights, 0);
        sim_slice_copy(job->rect, part.rect, job->soil_state, state,
                       SIM_SOIL_STATE_FIELDS * sizeof *state, 0);
    }
    return SIM_WINDOW_OK;
}

sim_window_status sim_bekker_window(const sim_params *p, sim_window_job *job, int32_t *scratch)
{
    /* a given depth is the tick's: one slice */
    int slices = job->bottom_override ? 1 : sim_travel_slices(job);
    if (slices > 1)
        return bekker_sliced(p, job, slices, scratch);
    int32_t *cls, *settle;
    bekker_press(p, job, 1, 1, scratch, &cls, &settle);
    return sim_sumner_settle(p, job, cls, settle);
}

/* The vertical force on job collider c at pose height z + q / 2^CARRY_BITS
 * units, the job's heights and state restored from the copies first. */
#define CARRY_BITS 10
typedef struct carry_search {
    const sim_params *p;
    sim_window_job *job;
    sim_collider *c;
    const int32_t *h0, *s0;
    int32_t *scratch;
} carry_search;

static double carry_force(const carry_search *k, int32_t z, int32_t q)
{
    int64_t n = (int64_t)k->job->rect.w * k->job->rect.h;
    memcpy(k->job->heights, k->h0, (size_t)n * sizeof *k->h0);
    memcpy(k->job->soil_state, k->s0, (size_t)n * SIM_SOIL_STATE_FIELDS * sizeof *k->s0);
    k->c->lift_units = ldexp((double)q, -CARRY_BITS);
    k->c->pose.position.z = ((double)z + k->c->lift_units) / k->p->units_per_m;
    int32_t *cls, *settle;
    bekker_press(k->p, k->job, 1, 1, k->scratch, &cls, &settle);
    return k->job->contacts[k->c - k->job->colliders].force_n[2];
}

/*
 * Whole units: the highest z in [lo, hi) whose force reaches the load (lo
 * when none does), galloping out from the unit the collider stood at (its
 * pose: last tick's height, so a few trials a tick, not a bisection of the
 * whole range), then bisecting. *flo and *fhi: the forces at the z found and
 * one unit above (NAN at lo when lo was never tried; 0 at the range's top,
 * which is above every cell).
 */
static int32_t carry_units(const carry_search *k, double load_n, int32_t lo, int32_t hi,
                           double *flo, double *fhi)
{
    *flo = NAN;
    *fhi = 0.0;
    double zu = floor(k->c->pose.position.z * k->p->units_per_m);
    int32_t g = !(zu < (double)hi - 1) ? hi - 1
                : !(zu > (double)lo)   ? lo
                                       : (int32_t)zu; /* NaN: hi - 1 */
    double f = carry_force(k, g, 0);
    if (f >= load_n) {
        lo = g, *flo = f;
        for (int64_t step = 1; lo + step < hi; step *= 2) {
            f = carry_force(k, (int32_t)(lo + step), 0);
            if (f < load_n) {
                hi = (int32_t)(lo + step), *fhi = f;
                break;
            }
            lo = (int32_t)(lo + step), *flo = f;
        }
    } else {
        hi = g, *fhi = f;
        for (int64_t step = 1; hi - step > lo; step *= 2) {
            f = carry_force(k, (int32_t)(hi - step), 0);
            if (f >= load_n) {
                lo = (int32_t)(hi - step), *flo = f;
                break;
            }
            hi = (int32_t)(hi - step), *fhi = f;
        }
    }
    while (hi - lo > 1) {
        int32_t mid = lo + (hi - lo) / 2;
        f = carry_force(k, mid, 0);
        if (f >= load_n)
            lo = mid, *flo = f;
        else
            hi = mid, *fhi = f;
    }
    return lo;
}

/*
 * Within the unit above z (F(z) = flo >= load > F(z + 1) = fhi): the
 * highest lift q / 2^CARRY_BITS found whose force reaches the load, by
 * regula falsi (the force is continuous in the lift, bekker_cell_step, and
 * nearly straight over one unit; Illinois' halving keeps a stuck end
 * moving), until the force is within CARRY_TOL of the load or the bracket is
 * one step. Returns q.
 */
#define CARRY_TOL 1e-3
static int32_t carry_lift(const carry_search *k, double load_n, int32_t z, double flo, double fhi)
{
    int32_t qlo = 0, qhi = 1 << CARRY_BITS;
    double wlo = flo - load_n, whi = fhi - load_n; /* >= 0, < 0 */
    int side = 0;
    while (qhi - qlo > 1 && !(flo - load_n <= CARRY_TOL * load_n)) {
        double t = wlo / (wlo - whi);
        int32_t q = qlo + (int32_t)nearbyint(t * (qhi - qlo));
        q = q <= qlo ? qlo + 1 : q >= qhi ? qhi - 1 : q;
        double f = carry_force(k, z, q);
        if (f >= load_n) {
            qlo = q, flo = f, wlo = f - load_n;
            if (side == 1)
                whi /= 2;
            side = 1;
        } else {
            qhi = q, whi = f - load_n;
            if (side == -1)
                wlo /= 2;
            side = -1;
        }
    }
    return qlo;
}

/*
 * Whole units, then the unit above the one found, so the force carried at
 * the height found is the load within CARRY_TOL (0.1 %) or within what 1/1024
 * of a unit changes it: under a standing wheel, whose cells all reload
 * elastically (K_e A: 165 N a unit under Ding's wheel), 0.16 N. Whole units
 * alone left it up to one unit's step above the load (4-14 % rolling, 178 N
 * for 80 standing).
 */
int32_t sim_bekker_carry(const sim_params *p, sim_window_job *job, sim_collider *c, double load_n,
                         int32_t lo, int32_t hi, int32_t *scratch, int32_t *heights_copy,
                         int32_t *state_copy)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    memcpy(heights_copy, job->heights, (size_t)n * sizeof *heights_copy);
    memcpy(state_copy, job->soil_state, (size_t)n * SIM_SOIL_STATE_FIELDS * sizeof *state_copy);
    carry_search k = {p, job, c, heights_copy, state_copy, scratch};
    double flo, fhi;
    int32_t z = carry_units(&k, load_n, lo, hi, &flo, &fhi);
    /* even lo does not carry the load: it stays there */
    int32_t q = flo >= load_n ? carry_lift(&k, load_n, z, flo, fhi) : 0;
    memcpy(job->heights, heights_copy, (size_t)n * sizeof *heights_copy);
    memcpy(job->soil_state, state_copy, (size_t)n * SIM_SOIL_STATE_FIELDS * sizeof *state_copy);
    c->lift_units = ldexp((double)q, -CARRY_BITS);
    c->pose.position.z = ((double)z + c->lift_units) / p->units_per_m;
    return z;
}

void sim_bekker_contact_merge(sim_contact *to, const sim_contact *from)
{
    for (int a = 0; a < 3; a++) {
        to->force_n[a] += from->force_n[a];
        to->torque_nm[a] += from->torque_nm[a];
        to->velocity[a] = from->velocity[a];
        to->angular[a] = from->angular[a];
        to->normal_sum[a] += from->normal_sum[a];
    }
    if (from->cells > 0 &&
        (to->cells == 0 || from->lowest_bottom < to->lowest_bottom ||
         (from->lowest_bottom == to->lowest_bottom && from->sinkage_m < to->sinkage_m))) {
        to->lowest_bottom = from->lowest_bottom; /* as in the press: the least at the lowest */
        to->sinkage_m = from->sinkage_m;
    }
    if (from->deepest_units > to->deepest_units) { /* ties: the earlier window's */
        to->deepest_units = from->deepest_units;
        memcpy(to->deepest, from->deepest, sizeof to->deepest);
    }
    to->volume += from->volume;
    to->area_m2 += from->area_m2;
    to->cells += from->cells;
    if (from->patch_cells > to->patch_cells) { /* ties: the earlier window's */
        to->patch_cells = from->patch_cells;
        to->patch_width_m = from->patch_width_m;
    }
}
