/*
 * sim_testbed.c: the single-wheel testbed run entirely in the bekker model,
 * with no world, engine or service — what a terramechanics lab does with a
 * rigid wheel on a soil bin, and what the physical side of the trade
 * (`terrad bench --trade`), `terrad calibrate` and the Ding 2011 validation
 * test (tests/validation/) all measure. Not part of a tick: it drives the
 * model's window function (sim_bekker_window, row 4d) on one flat window
 * with one collider, the way the engine would, load-driven each tick
 * (sim_bekker_carry), so the figures are the model's own.
 *
 * The wheel starts 1.5 radii into the bin, moves at speed_m_s and turns at
 * v / (R (1 - s)) about its axle (y); its pull, sinkage and driving torque
 * are averaged over the second half of the distance (the steady state, as
 * the testbeds report it). Everything is computed from the inputs alone, in
 * one order: the same run gives the same bits on every machine.
 */
#include "sim/sim_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* the bin's height quantum: 0.1 mm, as the scenes' default */
#define TESTBED_UNITS_PER_M 10000
#define TESTBED_GROUND_M 0.5

/* Ding et al. 2011, smooth wheel, 80 N (sim.h): slip, DP (N), sinkage (m), torque (N m). */
const sim_wheel_measured sim_wheel_ding2011[SIM_WHEEL_DING2011_ROWS] = {
    {0.0, -6.5, 0.005, 0.0}, {0.1, 11.0, 0.0055, 3.0}, {0.2, 14.5, 0.0075, 4.2},
    {0.3, 15.0, 0.010, 4.8}, {0.4, 15.0, 0.0125, 5.0}, {0.6, 15.0, 0.0175, 5.3},
};

/* Ding et al. 2011, lugged wheel (30 lugs, 10 mm), 80 N: the same columns. */
const sim_wheel_measured sim_wheel_ding2011_lugged[SIM_WHEEL_DING2011_ROWS] = {
    {0.0, -6.5, 0.0045, 0.0}, {0.1, 14.0, 0.005, 3.5}, {0.2, 20.0, 0.0075, 5.0},
    {0.3, 22.0, 0.0105, 5.8}, {0.4, 23.0, 0.014, 6.3}, {0.6, 24.5, 0.027, 7.2},
};

void sim_wheel_run_defaults(sim_wheel_run *r)
{
    memset(r, 0, sizeof *r);
    r->cell_m = 0.005;
    r->distance_m = 0.5;
    r->speed_m_s = 0.05;
    r->tick_s = 0.05;
    r->compression = 0.5;
}

void sim_soil_bin_free(sim_soil_bin *t)
{
    free(t->heights);
    free(t->heights_copy);
    free(t->state);
    free(t->state_copy);
    free(t->scratch);
    memset(t, 0, sizeof *t);
}

int sim_soil_bin_init(sim_soil_bin *t, const sim_soil *soil, double compression, double cell_m,
                      int w, int h, double height_m, error_text *err)
{
    memset(t, 0, sizeof *t);
    sim_material m = sim_material_default();
    m.model = SIM_MODEL_BEKKER;
    m.soil = *soil;
    m.compression = compression;
    m.slope_iterations = 0;
    if (sim_params_from_material(&m, cell_m, TESTBED_UNITS_PER_M, 0, &t->p, err) != 0)
        return -1;
    t->cells = (int64_t)w * h;
    t->heights = malloc(sizeof(int32_t) * (size_t)t->cells);
    t->heights_copy = malloc(sizeof(int32_t) * (size_t)t->cells);
    t->state = calloc((size_t)t->cells * SIM_SOIL_STATE_FIELDS, sizeof(int32_t));
    t->state_copy = malloc(sizeof(int32_t) * (size_t)t->cells * SIM_SOIL_STATE_FIELDS);
    t->scratch = malloc(sizeof(int32_t) * (size_t)sim_bekker_scratch_cells(w, h));
    if (!t->heights || !t->heights_copy || !t->state || !t->state_copy || !t->scratch) {
        sim_soil_bin_free(t);
        error_set(err, "soil bin: out of memory (%dx%d cells)", w, h);
        return -1;
    }
    for (int64_t i = 0; i < t->cells; i++)
        t->heights[i] = (int32_t)(height_m * TESTBED_UNITS_PER_M);
    t->job.rect = (world_rect){0, 0, w, h};
    t->job.cell_size_m = cell_m;
    t->job.units_per_m = TESTBED_UNITS_PER_M;
    t->job.heights = t->heights;
    t->job.soil_state = t->state;
    t->job.contacts = &t->contact;
    t->job.colliders = &t->collider;
    t->job.collider_count = 1;
    t->collider.id = 1;
    t->collider.geometry = &t->geometry;
    t->collider.pose.orientation = (quatd){1, 0, 0, 0};
    return 0;
}

void sim_soil_bin_place(sim_soil_bin *t, double x, double y, double z, quatd q, int has_previous)
{
    t->collider.previous_pose = t->collider.pose;
    t->collider.pose.position = (vec3d){x, y, z};
    t->collider.pose.orientation = q;
    t->collider.has_previous = has_previous;
    if (!has_previous)
        t->collider.previous_pose = t->collider.pose;
}

/* Bisection between the floor and just above the highest cell. */
int32_t sim_soil_bin_carry(sim_soil_bin *t, double load_n)
{
    int32_t top = t->heights[0];
    for (int64_t i = 0; i < t->cells; i++)
        if (t->heights[i] > top)
            top = t->heights[i];
    int32_t reach = (int32_t)(collider_reach(&t->geometry) * TESTBED_UNITS_PER_M) + 2;
    return sim_bekker_carry(&t->p, &t->job, &t->collider, load_n, t->p.floor + reach, top + reach,
                            t->scratch, t->heights_copy, t->state_copy);
}

sim_window_status sim_soil_bin_step(sim_soil_bin *t)
{
    return sim_bekker_window(&t->p, &t->job, t->scratch);
}

static int run_checked(const sim_wheel_run *r, error_text *err)
{
    if (!(r->radius_m > 0 && r->radius_m <= 10) || !(r->width_m > 0 && r->width_m <= 10) ||
        !(r->load_n > 0 && r->load_n <= 1e7) || !(r->slip >= 0 && r->slip < 1) ||
        !(r->cell_m >= 1e-4 && r->cell_m <= 1) || !(r->distance_m > 0 && r->distance_m <= 100) ||
        !(r->speed_m_s > 0 && r->speed_m_s <= 100) || !(r->tick_s > 0 && r->tick_s <= 10) ||
        !(r->compression >= 0 && r->compression <= 1)) {
        error_set(err,
                  "wheel testbed: radius %g m, width %g m, load %g N, slip %g, cell %g m, "
                  "distance %g m, speed %g m/s, tick %g s or compression %g out of range",
                  r->radius_m, r->width_m, r->load_n, r->slip, r->cell_m, r->distance_m,
                  r->speed_m_s, r->tick_s, r->compression);
        return -1;
    }
    double w = (r->distance_m + 4 * r->radius_m) / r->cell_m, h = r->width_m / r->cell_m + 20;
    long ticks = (long)(r->distance_m / (r->speed_m_s * r->tick_s));
    if (w * h > 4e7 || ticks < 2 || ticks > 10000000) {
        error_set(err,
                  "wheel testbed: %.0f x %.0f cells and %ld ticks (at most 4e7 cells, 2 to "
                  "1e7 ticks): choose another cell size, speed or tick",
                  w, h, ticks);
        return -1;
    }
    return 0;
}

int sim_wheel_testbed(const sim_soil *soil, const sim_wheel_run *run, sim_wheel_result *out,
                      error_text *err)
{
    memset(out, 0, sizeof *out);
    if (run_checked(run, err) != 0 || sim_soil_validate(soil, "soil", err) != 0)
        return -1;
    collider_geometry rim = {.shape = COLLIDER_CYLINDER,
                             .radius = run->radius_m,
                             .half_length = run->width_m / 2,
                             .grousers = run->grousers};
    if (collider_geometry_validate(&rim, err) != 0) {
        error_prefix(err, "wheel testbed", ": ");
        return -1;
    }
    /* the wheel's lowest point: the lugs' tips (Ding 2011 measures the sinkage from the
     * wheel's first touch of the surface, the tips of a lugged wheel) */
    const double tip = run->grousers.count > 0 ? run->grousers.height : 0.0;
    const double R = run->radius_m, cell = run->cell_m, v = run->speed_m_s, dt = run->tick_s;
    const double ground = TESTBED_GROUND_M;
    int w = (int)((run->distance_m + 4 * R) / cell), h = (int)(run->width_m / cell) + 20;
    sim_soil_bin t;
    if (sim_soil_bin_init(&t, soil, run->compression, cell, w, h, ground, err) != 0)
        return -1;
    t.p.tick_s = dt;
    t.geometry = rim;
    double x = 1.5 * R, angle = 0.0, y = h * cell / 2;
    double omega = v / (R * (1.0 - run->slip));
    sim_soil_bin_place(&t, x, y, ground + R, (quatd){1, 0, 0, 0}, 0);
    long ticks = (long)(run->distance_m / (v * dt));
    double sum_dp = 0, sum_z = 0, sum_t = 0;
    long n = 0;
    for (long k = 0; k < ticks; k++) {
        x += v * dt;
        angle += omega * dt;
        sim_soil_bin_place(&t, x, y, t.collider.pose.position.z,
                           quat_from_axis_angle((vec3d){0, 1, 0}, angle), k > 0);
        sim_soil_bin_carry(&t, run->load_n);
        if (sim_soil_bin_step(&t) != SIM_WINDOW_OK) {
            error_set(err,
                      "wheel testbed: the soil window was refused at tick %ld (the wheel "
                      "reached the height limit)",
                      k);
            sim_soil_bin_free(&t);
            return -1;
        }
        if (k >= ticks / 2) {
            sum_dp += t.contact.force_n[0];
            sum_z += ground - (t.collider.pose.position.z - R - tip);
            sum_t += -t.contact.torque_nm[1];
            n++;
        }
    }
    out->drawbar_pull_n = sum_dp / n;
    out->sinkage_m = sum_z / n;
    out->torque_nm = sum_t / n;
    out->ticks = ticks;
    sim_soil_bin_free(&t);
    return 0;
}
