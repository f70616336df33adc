/*
 * model_lugs.c: a lugged wheel in the bekker model (issue 31, item 1), part
 * of row 4d (sim_bekker_window's press, model_bekker.c). Two published
 * pieces:
 *
 * 1. The soil between the lugs turns with the wheel: the shearing surface of
 *    a grousered running gear is the envelope of the grouser tips (Wong,
 *    Theory of Ground Vehicles, the thrust of a track with grousers; Wong &
 *    Reece's and Ding et al. 2011's lugged-wheel analyses take the lug tips'
 *    radius R + h as the wheel's). So the press sees the rim's envelope,
 *    a smooth cylinder of radius R + h (sim_lug_envelope): normal stress,
 *    Janosi shear and the plastic sinkage on it, the cell rule unchanged. The
 *    depth stage of the other models keeps the exact lugged profile
 *    (collider/lugs.c); in a bekker world the rut is the envelope's, and its
 *    sinkage is the lug tips' (the wheel's lowest point).
 *
 * 2. Bulldozing at the lugs (sim_lug_thrust): each lug entering the soil in
 *    the front arc (0 <= θ <= θ1, θ from straight down, positive ahead)
 *    pushes a wedge of soil as a vertical blade does: Rankine's passive earth
 *    pressure (Terzaghi), the form Irani, Bauer & Warkentin 2011 (J.
 *    Terramechanics 48(4):307-318) give a grouser, integrated over the lug's
 *    face below the undisturbed surface, from its root depth z_r to its tip
 *    depth z_t:
 *        F = b [ ½ γ N_φ (z_t² - z_r²) + 2 c √N_φ (z_t - z_r) ],
 *        N_φ = tan²(45° + φ/2),
 *    mobilised like the shear, by Janosi's 1 - exp(-j/K) with the lug tip's
 *    slip displacement since entry, Wong-Reece's
 *        j = R' [ (θ1 - θ) - (1 - s')(sin θ1 - sin θ) ],
 *    R' = R + h, s' = 1 - v / (ω R') (docs/notes: Wong-Reece). The force
 *    acts on the wheel along the lug's direction of rotation, against the
 *    lug's motion through the soil (forward for a driven wheel), at the
 *    middle of the face below the surface: it adds to the pull, to the
 *    driving torque and (ahead, upward) to the carried load. γ is the soil's
 *    unit weight ρ g, ρ its density_kg_m3 (every preset's 1600 kg/m³, dry
 *    sand's; Ding 2011's bin: 1605; sim_soil.c).
 *
 * Everything is a function of the tick's poses, the contact the press
 * measured and the soil: deterministic, no heights changed (only forces).
 */
#include "sim/sim_internal.h"

#include <math.h>

#define SIM_LUG_G 9.81

static const double lug_pi = 3.14159265358979323846;

int sim_lugged(const collider_geometry *g)
{
    return g->shape == COLLIDER_CYLINDER && g->grousers.count > 0;
}

collider_geometry sim_lug_envelope(const collider_geometry *g)
{
    collider_geometry e = *g;
    if (sim_lugged(g)) {
        e.radius = g->radius + g->grousers.height;
        e.grousers = (collider_grousers){0};
    }
    return e;
}

/* Passive earth pressure on a blade of width b between depths zr < zt (N). */
static double lug_passive(const sim_soil *s, double b, double zr, double zt)
{
    double kp = tan(lug_pi / 4 + s->friction_deg * lug_pi / 360.0);
    double nphi = kp * kp, gamma = s->density_kg_m3 * SIM_LUG_G;
    return b * (0.5 * gamma * nphi * (zt * zt - zr * zr) + 2.0 * s->cohesion_pa * kp * (zt - zr));
}

void sim_lug_thrust(const sim_soil *s, const sim_collider *col, collider_pose pose, double lowest_m,
                    sim_contact *c)
{
    const collider_geometry *g = col->geometry;
    if (!sim_lugged(g) || c->cells <= 0)
        return;
    double R = g->radius, h = g->grousers.height, Rt = R + h, b = 2.0 * g->half_length;
    /* the undisturbed surface: the contact's sinkage above its lowest point */
    double surface = lowest_m + c->sinkage_m;
    vec3d o = pose.position;
    double ztip = surface - (o.z - Rt); /* the tip circle's depth at the bottom */
    double vx = c->velocity[0], vy = c->velocity[1], v = sqrt(vx * vx + vy * vy);
    if (!(ztip > 0.0) || !(v > 0.0) || !(s->shear_k_m > 0.0))
        return;
    double t1 = acos(fmax(-1.0, 1.0 - ztip / Rt));
    vec3d w = {c->angular[0], c->angular[1], c->angular[2]};
    double wn = sqrt(w.x * w.x + w.y * w.y + w.z * w.z);
    double st = wn > 0.0 ? 1.0 - v / (wn * Rt) : 1.0;
    quatd q = quat_normalize(pose.orientation);
    for (int k = 0; k < g->grousers.count; k++) {
        quatd turn = quat_from_axis_angle((vec3d){0, 1, 0},
                                          2.0 * lug_pi * (double)k / (double)g->grousers.count);
        vec3d d = quat_rotate(quat_normalize(quat_multiply(q, turn)), (vec3d){0, 0, -1});
        double ahead = (d.x * vx + d.y * vy) / v;
        double theta = atan2(ahead, -d.z);
        if (theta < 0.0 || theta > t1)
            continue;
        double zt = surface - (o.z + Rt * d.z), zr = fmax(0.0, surface - (o.z + R * d.z));
        if (!(zt > zr))
            continue;
        double j = Rt * ((t1 - theta) - (1.0 - st) * (sin(t1) - sin(theta)));
        if (!(j > 0.0))
            continue;
        double f = lug_passive(s, b, zr, zt) * (1.0 - exp(-j / s->shear_k_m));
        /* the lug's face normal: its direction of rotation, ω × d; the force opposes the
         * tip's motion along it */
        vec3d t = {w.y * d.z - w.z * d.y, w.z * d.x - w.x * d.z, w.x * d.y - w.y * d.x};
        double tn = sqrt(t.x * t.x + t.y * t.y + t.z * t.z);
        if (!(tn > 0.0))
            continue;
        t = (vec3d){t.x / tn, t.y / tn, t.z / tn};
        double ut = c->velocity[0] * t.x + c->velocity[1] * t.y + c->velocity[2] * t.z + wn * Rt;
        double sign = ut > 0.0 ? -1.0 : 1.0;
        vec3d fv = {sign * f * t.x, sign * f * t.y, sign * f * t.z};
        double ra = Rt - 0.5 * (zt - zr); /* the middle of the face below the surface */
        vec3d r = {d.x * ra, d.y * ra, d.z * ra};
        c->force_n[0] += fv.x, c->force_n[1] += fv.y, c->force_n[2] += fv.z;
        c->torque_nm[0] += r.y * fv.z - r.z * fv.y;
        c->torque_nm[1] += r.z * fv.x - r.x * fv.z;
        c->torque_nm[2] += r.x * fv.y - r.y * fv.x;
    }
}
