// ctest-timeout: 900
/*
 * test_single_wheel_ding2011.c: the bekker model's single-wheel testbed run
 * against Ding et al. 2011 (J. Terramechanics 48(1):27-45, HIT testbed; the
 * smooth wheel of their Fig. 9, values read off the plots, about +-0.5 mm and
 * +-1 N; tests/validation/single-wheel-ding2011.csv). Wheel R 0.15735 m, width
 * 0.165 m, 80 N, on their soil (Table 2: n 1.10, kc 15.6 kN/m^(n+1), kphi
 * 2407.4 kN/m^(n+2), c 0.25 kPa, phi 31.9 deg, K 11 mm: preset "ding2011").
 *
 * The wheel is load-driven (sim_bekker_carry each tick), moves at 0.05 m/s
 * and turns at v / (R (1 - s)); means over the second half of 0.5 m
 * (sim_wheel_testbed, the run `terrad calibrate` and the trade also use). Printed
 * per slip: drawbar pull (Fx), sinkage, driving torque (minus the soil's
 * torque about the axle), each beside the measurement, and the median
 * relative errors (docs/validation.md). Chrono SCM on the same wheel
 * (the note, measured here): median error 125 % on pull, 24 % on sinkage.
 *
 * Asserted, so a regression fails: the median errors on drawbar pull, on
 * sinkage and on torque stay within DP_BOUND, SINKAGE_BOUND and
 * TORQUE_BOUND — today's 25 %, 20 % and 35 % (deterministic: the same on
 * every run and machine) plus five points, room for a deliberate change of
 * the model that does not make it worse; Bekker-Wong's own model-form error
 * is quoted at 15-30 % (before the load search met the load within 0.1 % or 1/1024 of
 * a height unit, sim_bekker_carry, the wheel carried 4-14 % more than its
 * load and the medians were 30 / 21 / 34 %) — and
 * the physics that must hold whatever the calibration: a resisted wheel at
 * slip 0; pull and torque rising with slip up to 0.3 and then levelling off
 * as the real wheel's do (measured: 15 N from slip 0.3 to 0.6; the rise past
 * 0.3 stays under an eighth (pull) and a fifth (torque) of the rise up to
 * it: the model before Wong-Reece's rear region, bekker_shear_share, rose
 * by 22 % and 25 %, Wong-Reece's closed form by 36 % of its pull); sinkage
 * growing with slip (slip-sinkage: the ding2011 soil's slip_n 0.4, fitted on
 * these data; 41 % median sinkage error without it). The goal
 * (median <= 20 % on both) is met for sinkage, NOT for pull: the model's
 * pull now levels off, but too low (about 11 N against 15) and its torque
 * at slip 0.1-0.2 is half the measured. docs/validation.md has the table.
 *
 * second_pass: the same wheel twice over one rut (issue 31 item 4), printed
 * per pass; asserted, the directions docs/validation.md states.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "check.h"
#include "soil_rig.h"

/* Ding et al. 2011, smooth wheel, 80 N (sim.h's sim_wheel_ding2011): slip,
 * DP (N), sinkage (m), torque (N m). */
#define RADIUS SIM_WHEEL_DING2011_RADIUS_M
#define WIDTH SIM_WHEEL_DING2011_WIDTH_M
#define LOAD SIM_WHEEL_DING2011_LOAD_N
/* today's medians plus a margin (see the top comment) */
#define DP_BOUND 0.30
#define SINKAGE_BOUND 0.25
#define TORQUE_BOUND 0.40
/* the lugged wheel's (lugged_wheel): today's medians plus about five points */
#define LUG_DP_BOUND 0.50
#define LUG_SINKAGE_BOUND 0.43
#define LUG_TORQUE_BOUND 0.40

/* The testbed run (sim_wheel_testbed: 5 mm cells, 0.05 m/s, 2.5 mm a tick). */
static void run_lugs(double slip, const collider_grousers *lugs, double *dp, double *sinkage,
                     double *torque);

static void run(double slip, double *dp, double *sinkage, double *torque)
{
    run_lugs(slip, NULL, dp, sinkage, torque);
}

/* The testbed run, with lugs (NULL: smooth). */
static void run_lugs(double slip, const collider_grousers *lugs, double *dp, double *sinkage,
                     double *torque)
{
    sim_soil s;
    sim_soil_preset("ding2011", &s);
    sim_wheel_run r;
    sim_wheel_run_defaults(&r);
    r.radius_m = RADIUS;
    r.width_m = WIDTH;
    r.load_n = LOAD;
    r.slip = slip;
    if (lugs)
        r.grousers = *lugs;
    sim_wheel_result out;
    error_text err;
    if (sim_wheel_testbed(&s, &r, &out, &err) != 0) {
        printf("testbed: %s\n", err.message);
        abort();
    }
    *dp = out.drawbar_pull_n;
    *sinkage = out.sinkage_m;
    *torque = out.torque_nm;
}

/*
 * Wong-Reece's driven rigid wheel (the note's "Closed forms"): normal stress
 * (kc/b + kphi) R^n (cos θ - cos θ1)^n ahead of θm = (0.43 + 0.32 s) θ1,
 * mirrored behind it; shear from j(θ) = R[(θ1 - θ) - (1 - s)(sin θ1 - sin θ)].
 * The entry angle θ1 is found by bisection so that the vertical load is W;
 * then DP = R b ∫(τ cos θ - σ sin θ) dθ, T = R² b ∫ τ dθ (midpoint rule,
 * 2,000 steps). The prediction the measured data are usually set against.
 */
static void wong_reece_at(const sim_soil *s, double slip, double t1, double *w, double *dp,
                          double *torque)
{
    const int steps = 2000;
    double k = s->kc / WIDTH + s->kphi, tm = (0.43 + 0.32 * slip) * t1;
    double tf = tan(s->friction_deg * M_PI / 180), sw = 0, sdp = 0, st = 0, d = t1 / steps;
    for (int i = 0; i < steps; i++) {
        double t = (i + 0.5) * d;
        double arg = t >= tm ? cos(t) - cos(t1) : cos(t1 - t / tm * t1) - cos(t1);
        double sigma = arg > 0 ? k * pow(RADIUS, s->n) * pow(arg, s->n) : 0.0;
        double j = RADIUS * ((t1 - t) - (1 - slip) * (sin(t1) - sin(t)));
        double tau = (s->cohesion_pa + sigma * tf) * (1 - exp(-fabs(j) / s->shear_k_m));
        tau = j < 0 ? -tau : tau;
        sw += (sigma * cos(t) + tau * sin(t)) * d;
        sdp += (tau * cos(t) - sigma * sin(t)) * d;
        st += tau * d;
    }
    *w = RADIUS * WIDTH * sw;
    *dp = RADIUS * WIDTH * sdp;
    *torque = RADIUS * RADIUS * WIDTH * st;
}

static void wong_reece(double slip, double *dp, double *sinkage, double *torque)
{
    sim_soil s;
    sim_soil_preset("ding2011", &s);
    double lo = 1e-4, hi = 1.2, w;
    for (int i = 0; i < 60; i++) {
        double mid = 0.5 * (lo + hi);
        wong_reece_at(&s, slip, mid, &w, dp, torque);
        if (w < LOAD)
            lo = mid;
        else
            hi = mid;
    }
    wong_reece_at(&s, slip, hi, &w, dp, torque);
    *sinkage = RADIUS * (1 - cos(hi));
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

static double median(double *v, int n)
{
    qsort(v, (size_t)n, sizeof *v, by_value);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/*
 * Ding 2011's lugged wheel (issue 31 item 1; sim_wheel_ding2011_lugged, the
 * CSV's wheel=lugged rows): the same rim, soil (preset ding2011) and load
 * with 30 lugs 10 mm tall; sinkage at the lug tips (the wheel's lowest
 * point, where Ding's wheel first touches the soil). Printed as the smooth
 * table, with the smooth run (sdp, sz, st: main's) beside it; asserted: the
 * medians within their bounds, and the lugs' effect the measurements show —
 * at every slip from 0.1 the lugged wheel pulls more and needs more torque
 * than the smooth one (measured: +3 to +9.5 N, +0.5 to +1.9 N m).
 */
static void lugged_wheel(const double *sdp, const double *st)
{
    const collider_grousers lugs = {SIM_WHEEL_DING2011_LUG_COUNT, SIM_WHEEL_DING2011_LUG_HEIGHT_M,
                                    SIM_WHEEL_DING2011_LUG_THICKNESS_M};
    const sim_wheel_measured *m = sim_wheel_ding2011_lugged;
    double dp[6], z[6], tq[6], e_dp[6], e_z[6], e_t[6];
    int nt = 0;
    printf("\nlugged wheel (30 lugs, 10 mm):\n"
           "| slip | DP terrad (N) | DP Ding | sinkage terrad (mm) | Ding | torque terrad (N m) "
           "| Ding |\n|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < 6; i++) {
        run_lugs(m[i].slip, &lugs, &dp[i], &z[i], &tq[i]);
        printf("| %.1f | %.2f | %.1f | %.2f | %.1f | %.2f | %.1f |\n", m[i].slip, dp[i],
               m[i].drawbar_pull_n, z[i] * 1e3, m[i].sinkage_m * 1e3, tq[i], m[i].torque_nm);
        e_dp[i] = fabs(dp[i] - m[i].drawbar_pull_n) / fabs(m[i].drawbar_pull_n);
        e_z[i] = fabs(z[i] - m[i].sinkage_m) / m[i].sinkage_m;
        if (m[i].torque_nm > 0.0)
            e_t[nt++] = fabs(tq[i] - m[i].torque_nm) / m[i].torque_nm;
    }
    double m_dp = median(e_dp, 6), m_z = median(e_z, 6), m_t = median(e_t, nt);
    printf("lugged median relative error: drawbar pull %.0f %%, sinkage %.0f %%, torque %.0f %%\n",
           100 * m_dp, 100 * m_z, 100 * m_t);
    for (int i = 1; i < 6; i++)
        CHECK(dp[i] > sdp[i] && tq[i] > st[i],
              "slip %.1f: the lugged wheel pulls more (%.2f N, smooth %.2f) and needs more "
              "torque (%.2f N m, smooth %.2f)",
              m[i].slip, dp[i], sdp[i], tq[i], st[i]);
    CHECK(m_dp <= LUG_DP_BOUND, "lugged: median drawbar pull error %.0f %% within %.0f %%",
          100 * m_dp, 100 * LUG_DP_BOUND);
    CHECK(m_z <= LUG_SINKAGE_BOUND, "lugged: median sinkage error %.0f %% within %.0f %%",
          100 * m_z, 100 * LUG_SINKAGE_BOUND);
    CHECK(m_t <= LUG_TORQUE_BOUND, "lugged: median torque error %.0f %% within %.0f %%", 100 * m_t,
          100 * LUG_TORQUE_BOUND);
}

/*
 * A second pass in the rut (issue 31 item 4): Ding's wheel at 80 N rolls the
 * testbed's 0.5 m (5 mm cells, 0.05 m/s, 0.05 s ticks) twice over the same
 * soil, the second time from the same start in the first one's rut; means
 * over the second half of each. The rut's depth after the first pass is the
 * mean of the ground less the heights on the wheel's centre line there.
 */
static void rut_pass(soil_rig *r, double slip, double out[4])
{
    double R = RADIUS, v = 0.05, x = 1.5 * R, angle = 0.0, y = r->job.rect.h * 0.005 / 2;
    double omega = v / (R * (1.0 - slip));
    soil_rig_place(r, x, y, 0.5 + R, (quatd){1, 0, 0, 0}, 0);
    int ticks = (int)(0.5 / (v * r->p.tick_s)), n = 0;
    out[0] = out[1] = out[2] = out[3] = 0.0;
    for (int k = 0; k < ticks; k++) {
        x += v * r->p.tick_s;
        angle += omega * r->p.tick_s;
        soil_rig_place(r, x, y, r->collider.pose.position.z,
                       quat_from_axis_angle((vec3d){0, 1, 0}, angle), k > 0);
        soil_rig_carry(r, LOAD);
        soil_rig_step(r);
        if (k >= ticks / 2) {
            out[0] += r->contact.force_n[0];
            out[1] += 0.5 - (r->collider.pose.position.z - R);
            out[2] += -r->contact.torque_nm[1];
            n++;
        }
    }
    for (int i = 0; i < 3; i++)
        out[i] /= n;
    int w = r->job.rect.w, row = r->job.rect.h / 2, from = (int)((1.5 * R + 0.25) / 0.005);
    int to = (int)((1.5 * R + 0.45) / 0.005);
    for (int cx = from; cx < to; cx++)
        out[3] += 0.5 - r->heights[row * w + cx] / 1e4;
    out[3] /= to - from;
}

static void second_pass(void)
{
    sim_soil soil;
    sim_soil_preset("ding2011", &soil);
    printf("\nsecond pass in the rut (means over each pass's second half)\n"
           "| slip | pass | DP (N) | sinkage (mm) | torque (N m) | rut after (mm) |\n"
           "|---|---|---|---|---|---|\n");
    for (int i = 0; i < 3; i++) {
        double slip = 0.2 * i, a[4], b[4];
        soil_rig r;
        soil_rig_init(&r, &soil, 0.5, 0.005, (int)((0.5 + 4 * RADIUS) / 0.005),
                      (int)(WIDTH / 0.005) + 20, 0.5);
        r.p.tick_s = 0.05;
        r.geometry.shape = COLLIDER_CYLINDER;
        r.geometry.radius = RADIUS;
        r.geometry.half_length = WIDTH / 2;
        rut_pass(&r, slip, a);
        rut_pass(&r, slip, b);
        printf(
            "| %.1f | 1 | %.2f | %.2f | %.2f | %.2f |\n| %.1f | 2 | %.2f | %.2f | %.2f | %.2f |\n",
            slip, a[0], a[1] * 1e3, a[2], a[3] * 1e3, slip, b[0], b[1] * 1e3, b[2], b[3] * 1e3);
        /* the behaviour docs/validation.md states: the rut deepens on the second
         * pass but by less than the first pass sank, and the following wheel
         * needs less torque (it meets soil already pressed to its depth) */
        CHECK(b[1] > a[1] && b[1] - a[3] < a[1],
              "slip %.1f: the second pass sinks deeper in total (%.2f mm against %.2f) but by "
              "less than the first below the rut (%.2f mm)",
              slip, b[1] * 1e3, a[1] * 1e3, (b[1] - a[3]) * 1e3);
        CHECK(b[2] < a[2] + 0.05, "slip %.1f: the second pass needs no more torque (%.2f, %.2f)",
              slip, b[2], a[2]);
        soil_rig_free(&r);
    }
}

int main(void)
{
    double e_dp[6], e_z[6], e_t[5], dp[6], z[6], tq[6], w_dp[6], w_z[6], w_t[6];
    int nt = 0;
    printf("| slip | DP terrad (N) | DP Ding | DP Wong-Reece | sinkage terrad (mm) | Ding | "
           "Wong-Reece | torque terrad (N m) | Ding | Wong-Reece |\n"
           "|---|---|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < 6; i++) {
        run(sim_wheel_ding2011[i].slip, &dp[i], &z[i], &tq[i]);
        wong_reece(sim_wheel_ding2011[i].slip, &w_dp[i], &w_z[i], &w_t[i]);
        printf("| %.1f | %.2f | %.1f | %.2f | %.2f | %.1f | %.2f | %.2f | %.1f | %.2f |\n",
               sim_wheel_ding2011[i].slip, dp[i], sim_wheel_ding2011[i].drawbar_pull_n, w_dp[i],
               z[i] * 1e3, sim_wheel_ding2011[i].sinkage_m * 1e3, w_z[i] * 1e3, tq[i],
               sim_wheel_ding2011[i].torque_nm, w_t[i]);
        e_dp[i] = fabs(dp[i] - sim_wheel_ding2011[i].drawbar_pull_n) /
                  fabs(sim_wheel_ding2011[i].drawbar_pull_n);
        e_z[i] = fabs(z[i] - sim_wheel_ding2011[i].sinkage_m) / sim_wheel_ding2011[i].sinkage_m;
        if (sim_wheel_ding2011[i].torque_nm > 0.0)
            e_t[nt++] =
                fabs(tq[i] - sim_wheel_ding2011[i].torque_nm) / sim_wheel_ding2011[i].torque_nm;
    }
    double m_dp = median(e_dp, 6), m_z = median(e_z, 6), m_t = median(e_t, nt);
    printf("median relative error: drawbar pull %.0f %%, sinkage %.0f %%, torque %.0f %%\n",
           100 * m_dp, 100 * m_z, 100 * m_t);
    CHECK(dp[0] < 0.0, "slip 0: the wheel is resisted (DP %.2f N)", dp[0]);
    for (int i = 1; i <= 3; i++)
        CHECK(dp[i] > dp[i - 1] && tq[i] > tq[i - 1],
              "pull and torque grow with slip up to 0.3 (slip %.1f: DP %.2f, torque %.2f)",
              sim_wheel_ding2011[i].slip, dp[i], tq[i]);
    for (int i = 4; i < 6; i++)
        CHECK(fabs(dp[i] - dp[3]) < (dp[3] - dp[0]) / 8 &&
                  fabs(tq[i] - tq[3]) < (tq[3] - tq[0]) / 5,
              "pull and torque level off past slip 0.3 (slip %.1f: DP %.2f against %.2f, torque "
              "%.2f against %.2f)",
              sim_wheel_ding2011[i].slip, dp[i], dp[3], tq[i], tq[3]);
    CHECK(z[5] > z[0] + 0.004,
          "slip-sinkage: the wheel sinks deeper at slip 0.6 (%.2f mm) than "
          "at 0 (%.2f mm)",
          z[5] * 1e3, z[0] * 1e3);
    CHECK(m_dp <= DP_BOUND, "median drawbar pull error %.0f %% within %.0f %%", 100 * m_dp,
          100 * DP_BOUND);
    CHECK(m_z <= SINKAGE_BOUND, "median sinkage error %.0f %% within %.0f %%", 100 * m_z,
          100 * SINKAGE_BOUND);
    CHECK(m_t <= TORQUE_BOUND, "median torque error %.0f %% within %.0f %%", 100 * m_t,
          100 * TORQUE_BOUND);
    lugged_wheel(dp, tq);
    second_pass();
    return check_report();
}
