/*
 * test_bekker_closed_forms.c: the bekker model against Bekker's closed forms
 * (docs/validation.md; docs/notes/terramechanics.md, "Closed forms").
 *
 * 1. Plate sinkage, every soil of the note's table (the presets of
 *    sim_soil_preset), three pressures each: a rigid plate 10 x 50 cells of
 *    5 mm is given a load W (load-driven: sim_bekker_carry finds the highest
 *    height, the load met within 0.1 %, at which the soil carries it) and its sinkage must
 *    meet z = (p / (kc/b + kphi))^(1/n), p = W / A, within 1 % or one height
 *    unit (0.1 mm), b the patch width the model uses, 2 A / L (Chrono SCM's
 *    rule), computed here from the plate's size. The pressures are chosen
 *    as those of sinkages 10, 25 and 50 mm, above where the elastic trial
 *    K_e z passes Bekker's pressure for every soil (heavy clay's crossover,
 *    the highest, is 4 mm), so the plate yields as the formula assumes.
 *
 * 2. Rigid wheel, towed at zero slip under a vertical load (load-driven each
 *    tick): its steady sinkage and rolling resistance against Bekker's
 *    z0 = [3W / ((3 - n)(kc + b kphi) sqrt(D))]^(2/(2n+1)) and
 *    Rc = (kc + b kphi) z0^(n+1) / (n+1), the note's two worked cases (Ding's
 *    wheel on Ding's soil, z0/R 0.058; a small wheel on lunar soil, z0/R
 *    0.22). Rc is the normal stress's share of the resistance, so it is
 *    measured with c = phi = 0 (at zero slip the rolling wheel's shear
 *    thrust, Wong-Reece's j(θ) > 0, otherwise cancels most of it on the
 *    deeper lunar case: 1.4 N net against 12.5). Tolerance 30 % on sinkage
 *    and 35 % on resistance, because the
 *    closed form and the model differ in ways the formula itself ignores:
 *    it puts the wheel's width in kc/b where the model uses its contact
 *    patch's 2A/L (the patch is shorter than it is wide: kc/b up to 3x
 *    larger, +6 % stiffness on Ding's soil, so ~5 % less sinkage); it is
 *    derived for small sinkage (cos θ ~ 1 - θ²/2, good to ~2 % at z0/R 0.06
 *    but ~11 % at 0.22); it has no shear, where the model's rolling wheel
 *    shears the soil a little (Janosi j > 0 off the bottom point even at
 *    zero slip, Wong-Reece's j(θ)), which adds resistance; and it knows no
 *    elastic rebound behind the wheel, nor the displaced half of the plastic
 *    sinkage (compression 0.5) heaped beside and ahead of the wheel, which
 *    carries part of the load (not measured apart). Until 2026-11-27 a
 *    yielded cell's elastic share was rounded down, which let every loaded
 *    cell creep one unit per tick while the slow wheel stood over it: Ding's
 *    wheel sank 8.00 mm (-12 %); rounded up (a static load now holds, see
 *    test_load_driven) it sinks 6.95 mm (-24 %), hence 25 % on sinkage
 *    (was 20 %); with Wong-Reece's rear region in the shear (model_bekker.c,
 *    bekker_shear_share) 7.04 mm (-23 %); with the load met within 0.1 %,
 *    not at the highest whole unit carrying it (which carried 4-14 %
 *    more than the load) 6.66 mm (-27 %), hence 30 %. Grid and height quanta (5 mm cells,
 *    0.1 mm units) are ~1 % of z0. A model change that breaks pressure,
 *    patch width, yielding or the normal's direction moves these figures by
 *    far more than the margins.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "soil_rig.h"

#define UPM 10000.0

static const char *const soils[] = {"dry-sand",    "sandy-loam", "clayey-soil",
                                    "heavy-clay",  "lete-sand",  "snow-us",
                                    "snow-sweden", "lunar",      "ding2011"};

static void test_plates(void)
{
    const int pw = 10, pl = 50; /* plate in cells */
    const double cell = 0.005;
    double area = pw * pl * cell * cell;
    double b = 2.0 * area / (2.0 * (pw + pl) * cell);
    const double depths[] = {0.010, 0.025, 0.050};
    printf("plate %.3f x %.3f m, b = 2A/L = %.5f m\n", pw * cell, pl * cell, b);
    printf("%-12s %10s %10s %10s %8s\n", "soil", "p (kPa)", "z Bekker", "z terrad", "error");
    for (size_t i = 0; i < sizeof soils / sizeof soils[0]; i++) {
        sim_soil s;
        sim_soil_preset(soils[i], &s);
        for (int d = 0; d < 3; d++) {
            soil_rig r;
            soil_rig_init(&r, &s, 0.5, cell, pw + 20, pl + 20, 0.5);
            soil_rig_plate(&r, pw * cell / 2, pl * cell / 2, 0.05, (pw + 20) * cell / 2,
                           (pl + 20) * cell / 2, 0.6);
            double p = (s.kc / b + s.kphi) * pow(depths[d], s.n);
            double z = pow(p / (s.kc / b + s.kphi), 1.0 / s.n); /* the closed form */
            soil_rig_carry(&r, p * area);
            soil_rig_step(&r);
            double got = r.contact.sinkage_m;
            double err = fabs(got - z);
            printf("%-12s %10.3f %10.5f %10.5f %7.2f%%\n", soils[i], p / 1e3, z, got,
                   100.0 * err / z);
            CHECK(err <= 0.01 * z || err <= 1.0 / UPM + 1e-12,
                  "%s, p %.1f Pa: sinkage %.5f m against Bekker's %.5f m", soils[i], p, got, z);
            CHECK(r.contact.force_n[2] >= p * area && fabs(r.contact.patch_width_m - b) < 1e-12,
                  "%s: the load is carried on the plate's b", soils[i]);
            soil_rig_free(&r);
        }
    }
}

/* A wheel towed at zero slip under `load` over `metres`: mean sinkage and
 * resistance (-Fx) over the second half. */
static void tow(const sim_soil *s, double radius, double width, double load, double *sinkage,
                double *resistance)
{
    const double cell = 0.005, v = 0.05, dt = 0.05, metres = 0.5;
    int w = (int)((metres + 4 * radius) / cell), h = (int)(width / cell) + 20;
    soil_rig r;
    soil_rig_init(&r, s, 0.5, cell, w, h, 0.5);
    r.p.tick_s = dt;
    r.geometry.shape = COLLIDER_CYLINDER;
    r.geometry.radius = radius;
    r.geometry.half_length = width / 2;
    double x = 1.5 * radius, angle = 0.0, y = h * cell / 2;
    soil_rig_place(&r, x, y, 0.5 + radius, (quatd){1, 0, 0, 0}, 0);
    int ticks = (int)(metres / (v * dt));
    double zs = 0.0, fx = 0.0;
    int n = 0;
    for (int t = 0; t < ticks; t++) {
        x += v * dt;
        angle += v / radius * dt;
        soil_rig_place(&r, x, y, r.collider.pose.position.z,
                       quat_from_axis_angle((vec3d){0, 1, 0}, angle), t > 0);
        soil_rig_carry(&r, load);
        soil_rig_step(&r);
        if (t >= ticks / 2) {
            zs += 0.5 - (r.collider.pose.position.z - radius);
            fx += r.contact.force_n[0];
            n++;
        }
    }
    *sinkage = zs / n;
    *resistance = -fx / n;
    soil_rig_free(&r);
}

static void test_wheels(void)
{
    struct {
        const char *soil;
        double radius, width, load;
    } cases[] = {{"ding2011", 0.15735, 0.165, 80.0}, {"lunar", 0.10, 0.06, 50.0}};
    for (int i = 0; i < 2; i++) {
        sim_soil s;
        sim_soil_preset(cases[i].soil, &s);
        double k = s.kc + cases[i].width * s.kphi, d = 2.0 * cases[i].radius;
        double z0 = pow(3.0 * cases[i].load / ((3.0 - s.n) * k * sqrt(d)), 2.0 / (2.0 * s.n + 1.0));
        double rc = k * pow(z0, s.n + 1.0) / (s.n + 1.0);
        double z, res, z_slick;
        tow(&s, cases[i].radius, cases[i].width, cases[i].load, &z, &res);
        /* Rc is the normal stress's resistance alone: measured with shear off */
        sim_soil slick = s;
        slick.cohesion_pa = slick.friction_deg = 0.0;
        tow(&slick, cases[i].radius, cases[i].width, cases[i].load, &z_slick, &res);
        printf("wheel R %.5f b %.3f W %.0f N on %s: sinkage %.2f mm (Bekker %.2f, %+.1f%%), "
               "resistance %.2f N (Bekker %.2f, %+.1f%%)\n",
               cases[i].radius, cases[i].width, cases[i].load, cases[i].soil, z * 1e3, z0 * 1e3,
               100.0 * (z - z0) / z0, res, rc, 100.0 * (res - rc) / rc);
        CHECK(fabs(z - z0) <= 0.30 * z0, "%s wheel: sinkage %.2f mm within 30 %% of %.2f mm",
              cases[i].soil, z * 1e3, z0 * 1e3);
        CHECK(fabs(res - rc) <= 0.35 * rc, "%s wheel: resistance %.2f N within 35 %% of %.2f N",
              cases[i].soil, res, rc);
    }
}

int main(void)
{
    test_plates();
    test_wheels();
    return check_report();
}
