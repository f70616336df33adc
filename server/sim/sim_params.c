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
        .model = SIM_MODEL_PERSSON_SSBO,
        .tick_s = 1.0 / 60.0,
        .refill_m_per_s = 0.0,
        .trail_scale_per_m = 4.0,
        .trail_range_m = 1.0,
        .edge_height = 0.25,
        .edge_width = 0.5,
        .diffusion_d = 0.25, /* Gilardi's mud */
        .diffusion_zeta_inv = 6e-4,
        .diffusion_force_scale = 10000.0,
        .diffusion_dt = 0.2,
        .diffusion_substeps = SIM_DIFFUSION_SUBSTEPS_AUTO,
        .diffusion_conservative = 1,
        .decal_min_strength_m = 0.0,
    };
    sim_soil_preset("ding2011", &m.soil); /* the soil the validation measures */
    return m;
}

int sim_material_diffusion_preset(sim_material *m, const char *name)
{
    /* Gilardi, Watten, Newbury, Fig. 4 */
    if (strcmp(name, "mud") == 0) {
        m->diffusion_zeta_inv = 6e-4;
        m->repose_deg = 72.0; /* 2π/5 */
        m->diffusion_d = 0.25;
    } else if (strcmp(name, "pebbles") == 0) {
        m->diffusion_zeta_inv = 3e-4;
        m->repose_deg = 60.0; /* π/3 */
        m->diffusion_d = 0.9;
    } else if (strcmp(name, "sand") == 0) {
        m->diffusion_zeta_inv = 4e-4;
        m->repose_deg = 45.0; /* π/4 */
        m->diffusion_d = 1.0;
    } else {
        return -1;
    }
    return 0;
}

static const char *const model_names[SIM_MODEL_COUNT] = {
    "persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
    "diffusion",         "sumner",       "decals",        "bekker"};

const char *sim_model_name(sim_model m)
{
    return (unsigned)m < SIM_MODEL_COUNT ? model_names[m] : "unknown";
}

int sim_model_parse(const char *name, sim_model *out)
{
    for (int i = 0; i < SIM_MODEL_COUNT; i++) {
        if (name && strcmp(name, model_names[i]) == 0) {
            *out = (sim_model)i;
            return 0;
        }
    }
    return -1;
}

int sim_model_is_persson(sim_model m)
{
    return m == SIM_MODEL_PERSSON_ITERATIVE || m == SIM_MODEL_PERSSON_SSBO ||
           m == SIM_MODEL_PERSSON_MULTI;
}

sim_model sim_model_from_method(sim_method m)
{
    return m == SIM_METHOD_ITERATIVE ? SIM_MODEL_PERSSON_ITERATIVE
           : m == SIM_METHOD_MULTI   ? SIM_MODEL_PERSSON_MULTI
                                     : SIM_MODEL_PERSSON_SSBO;
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

ground_material sim_material_ground(const sim_material *m)
{
    ground_material g = {"default", m->compression, m->roughness, m->repose_deg, 0.0, 0.0, m->soil};
    return g;
}

/* The persson stages' fields, in the order their errors are reported. */
static int validate_persson(const sim_material *m, error_text *err)
{
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
    if ((unsigned)m->model >= SIM_MODEL_COUNT) {
        error_set(err, "material.model: unknown model");
        return -1;
    }
    return 0;
}

/* The tick and the other models' fields. */
static int validate_models(const sim_material *m, error_text *err)
{
    if (!isfinite(m->tick_s) || m->tick_s <= 0.0 || m->tick_s > 3600.0) {
        error_set(err, "tick_hz: the tick must last (0, 3600] s (got %g s)", m->tick_s);
        return -1;
    }
    if (!in_range(m->refill_m_per_s, 0.0, 1000.0)) {
        error_set(err, "material.refill_m_per_s: must be a number in [0, 1000] (got %g)",
                  m->refill_m_per_s);
        return -1;
    }
    if (!in_range(m->trail_scale_per_m, 0.0, 1e6)) {
        error_set(err, "material.trail_scale_per_m: must be a number in [0, 1e6] (got %g)",
                  m->trail_scale_per_m);
        return -1;
    }
    if (!in_range(m->trail_range_m, 0.0, 1000.0)) {
        error_set(err, "material.trail_range_m: must be a number in [0, 1000] (got %g)",
                  m->trail_range_m);
        return -1;
    }
    if (!in_range(m->edge_height, 0.0, 100.0)) {
        error_set(err, "material.edge_height: must be a number in [0, 100] (got %g)",
                  m->edge_height);
        return -1;
    }
    if (!isfinite(m->edge_width) || m->edge_width <= 0.0 || m->edge_width > 100.0) {
        error_set(err, "material.edge_width: must be a number in (0, 100] (got %g)", m->edge_width);
        return -1;
    }
    if (!in_range(m->diffusion_d, 0.0, 1e12)) {
        error_set(err, "material.D: must be a number in [0, 1e12] (got %g)", m->diffusion_d);
        return -1;
    }
    if (!in_range(m->diffusion_zeta_inv, 0.0, 1e12)) {
        error_set(err, "material.zeta_inv: must be a number in [0, 1e12] (got %g)",
                  m->diffusion_zeta_inv);
        return -1;
    }
    if (!in_range(m->diffusion_force_scale, 0.0, 1e12)) {
        error_set(err, "material.force_scale: must be a number in [0, 1e12] (got %g)",
                  m->diffusion_force_scale);
        return -1;
    }
    if (!in_range(m->diffusion_dt, 0.0, 1e12)) {
        error_set(err, "material.dt: must be a number in [0, 1e12] (got %g)", m->diffusion_dt);
        return -1;
    }
    if (m->diffusion_substeps < 0 || m->diffusion_substeps > 100000) {
        error_set(err, "material.substeps: must be \"auto\" or an integer in [1, 100000] (got %d)",
                  m->diffusion_substeps);
        return -1;
    }
    if (!in_range(m->decal_min_strength_m, 0.0, 1000.0)) {
        error_set(err, "material.decal_min_strength_m: must be a number in [0, 1000] (got %g)",
                  m->decal_min_strength_m);
        return -1;
    }
    return 0;
}

int sim_params_from_material(const sim_material *m, double cell_size_m, int32_t units_per_m,
                             int32_t floor_units, sim_params *p, error_text *err)
{
    /* the per-cell part (compression, roughness, repose) is the ground's row */
    ground_material_row row;
    ground_material per_cell = sim_material_ground(m);
    if (ground_material_row_from(&per_cell, cell_size_m, units_per_m, "material", &row, err) != 0)
        return -1;
    if (validate_persson(m, err) != 0 || validate_models(m, err) != 0)
        return -1;
    if (m->model == SIM_MODEL_BEKKER && sim_soil_validate(&m->soil, "material.soil", err) != 0)
        return -1;
    if (!isfinite(cell_size_m) || cell_size_m <= 0.0 || units_per_m < 1) {
        error_set(err, "world: cell size and units per metre must be positive");
        return -1;
    }
    memset(p, 0, sizeof *p);
    p->metric = m->metric;
    p->method = m->method;
    p->compression_q16 = row.compression_q16;
    p->roughness_q16 = row.roughness_q16;
    p->slope_threshold_axial = row.slope_threshold_axial;
    p->slope_threshold_diagonal = row.slope_threshold_diagonal;
    p->obstacle_gap = ground_units_saturated(m->obstacle_gap_m * units_per_m);
    int32_t step = (int32_t)lround(m->multi_target_m * units_per_m);
    p->multi_target_step = step < 1 ? 1 : step;
    p->multi_target_max = m->multi_target_max;
    p->displace_iterations = m->displace_iterations;
    p->slope_iterations = m->slope_iterations;
    p->floor = floor_units;
    /* for Persson the method says which variant (code that sets only the
     * method, as before models existed, keeps working) */
    p->model = sim_model_is_persson(m->model) ? sim_model_from_method(m->method) : m->model;
    p->refill_q16_per_tick =
        (int64_t)llround(m->refill_m_per_s * units_per_m * m->tick_s * 65536.0);
    /* d is measured in cells: scale per m -> units per cell^2 */
    double scale_units = m->trail_scale_per_m * cell_size_m * cell_size_m * units_per_m;
    double scale_q16 = scale_units * 65536.0;
    p->trail_scale_q16 = scale_q16 >= 2147483647.0 ? 2147483647 : (int32_t)llround(scale_q16);
    double range = floor(m->trail_range_m / cell_size_m);
    p->trail_range_cells = range > 1024.0 ? 1024 : (int32_t)range;
    p->edge_height_q16 = (int32_t)lround(m->edge_height * 65536.0);
    p->edge_width_q16 = (int32_t)lround(m->edge_width * 65536.0);
    p->diffusion_d = m->diffusion_d;
    p->diffusion_zeta_inv = m->diffusion_zeta_inv;
    p->diffusion_force_scale = m->diffusion_force_scale;
    p->diffusion_dt = m->diffusion_dt;
    p->diffusion_substeps = m->diffusion_substeps;
    p->diffusion_conservative = m->diffusion_conservative ? 1 : 0;
    p->repose_rad = m->repose_deg * M_PI / 180.0;
    p->cell_size_m = cell_size_m;
    p->units_per_m = units_per_m;
    p->decal_min_strength = ground_units_saturated(m->decal_min_strength_m * units_per_m);
    p->soil = m->soil;
    p->tick_s = m->tick_s;
    return 0;
}
