/*
 * sim_params.c: turns a material as a person writes it (angles, ratios,
 * metres) into the integer parameters the stages use, once, on the CPU.
 * This is where the angle of repose becomes height-difference thresholds for
 * axial and diagonal neighbours, so no GPU ever evaluates atan or compares
 * floats (the original's slope test did both).
 */
#include "sim/sim.h"

#include <math.h>
#include <string.h>

sim_material sim_material_default(void)
{
    sim_material m = {
        .compression = 0.0,
        .roughness = 0.3,
        .repose_deg = 35.0,
        .obstacle_gap_m = 0.1,
        .multi_target_m = 0.1,
        .multi_target_max = 16,
        .displace_iterations = 10,
        .slope_iterations = 10,
        .metric = SIM_METRIC_EUCLIDEAN,
        .method = SIM_METHOD_SSBO,
    };
    return m;
}

static const char *const metric_names[] = {"euclidean", "manhattan", "chebyshev"};
static const char *const method_names[] = {"iterative", "ssbo", "multi"};

const char *sim_metric_name(sim_metric m)
{
    return (unsigned)m < 3 ? metric_names[m] : "unknown";
}

const char *sim_method_name(sim_method m)
{
    return (unsigned)m < 3 ? method_names[m] : "unknown";
}

int sim_metric_parse(const char *name, sim_metric *out)
{
    for (int i = 0; i < 3; i++)
        if (name && strcmp(name, metric_names[i]) == 0) {
            *out = (sim_metric)i;
            return 0;
        }
    return -1;
}

int sim_method_parse(const char *name, sim_method *out)
{
    for (int i = 0; i < 3; i++)
        if (name && strcmp(name, method_names[i]) == 0) {
            *out = (sim_method)i;
            return 0;
        }
    return -1;
}

static int in_range(double v, double lo, double hi)
{
    return isfinite(v) && v >= lo && v <= hi;
}

/* A non-negative length in units, saturated at 2^30 (any larger threshold
 * already means "never"). */
static int32_t units_saturated(double units)
{
    if (!(units > 0.0))
        return 0;
    if (units >= (double)(1 << 30))
        return 1 << 30;
    return (int32_t)floor(units);
}

int sim_params_from_material(const sim_material *m, double cell_size_m, int32_t units_per_m,
                             int32_t floor_units, sim_params *p, error_text *err)
{
    if (!in_range(m->compression, 0.0, 1.0)) {
        error_set(err, "material.compression: must be a number in [0, 1] (got %g)", m->compression);
        return -1;
    }
    if (!in_range(m->roughness, 0.0, 1.0)) {
        error_set(err, "material.roughness: must be a number in [0, 1] (got %g)", m->roughness);
        return -1;
    }
    if (!isfinite(m->repose_deg) || m->repose_deg < 0.0 || m->repose_deg >= 90.0) {
        error_set(err, "material.repose_deg: must be a number in [0, 90) (got %g)", m->repose_deg);
        return -1;
    }
    if (!in_range(m->obstacle_gap_m, 0.0, 1000.0)) {
        error_set(err, "material.obstacle_gap_m: must be a number in [0, 1000] (got %g)",
                  m->obstacle_gap_m);
        return -1;
    }
    if (!isfinite(m->multi_target_m) || m->multi_target_m <= 0.0 || m->multi_target_m > 1000.0) {
        error_set(err, "material.multi_target_m: must be a number in (0, 1000] (got %g)",
                  m->multi_target_m);
        return -1;
    }
    if (m->multi_target_max < 1 || m->multi_target_max > 1024) {
        error_set(err, "material.multi_target_max: must be an integer in [1, 1024] (got %d)",
                  m->multi_target_max);
        return -1;
    }
    if (m->displace_iterations < 0 || m->displace_iterations > 1000) {
        error_set(err, "material.displace_iterations: must be an integer in [0, 1000] (got %d)",
                  m->displace_iterations);
        return -1;
    }
    if (m->slope_iterations < 0 || m->slope_iterations > 1000) {
        error_set(err, "material.slope_iterations: must be an integer in [0, 1000] (got %d)",
                  m->slope_iterations);
        return -1;
    }
    if ((unsigned)m->metric > SIM_METRIC_CHEBYSHEV) {
        error_set(err, "material.metric: unknown metric");
        return -1;
    }
    if ((unsigned)m->method > SIM_METHOD_MULTI) {
        error_set(err, "material.method: unknown method");
        return -1;
    }
    if (!isfinite(cell_size_m) || cell_size_m <= 0.0 || units_per_m < 1) {
        error_set(err, "world: cell size and units per metre must be positive");
        return -1;
    }
    memset(p, 0, sizeof *p);
    p->metric = m->metric;
    p->method = m->method;
    p->compression_q16 = (int32_t)lround(m->compression * 65536.0);
    p->roughness_q16 = (int32_t)lround(m->roughness * 65536.0);
    double rise_per_m = tan(m->repose_deg * M_PI / 180.0);
    double axial = rise_per_m * cell_size_m * units_per_m;
    p->slope_threshold_axial = units_saturated(axial);
    p->slope_threshold_diagonal = units_saturated(axial * M_SQRT2);
    p->obstacle_gap = units_saturated(m->obstacle_gap_m * units_per_m);
    int32_t step = (int32_t)lround(m->multi_target_m * units_per_m);
    p->multi_target_step = step < 1 ? 1 : step;
    p->multi_target_max = m->multi_target_max;
    p->displace_iterations = m->displace_iterations;
    p->slope_iterations = m->slope_iterations;
    p->floor = floor_units;
    return 0;
}
