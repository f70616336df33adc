/*
 * scene_material.c: a scene's "material" — the deformation model and its
 * parameters, read strictly (every key known, every number in range, errors
 * naming the field) before the first tick, and checked by the sim's own
 * conversion (sim_params_from_material), which has the last word on what a
 * tick can run. scene_material_load_file reads one on its own (the JSON
 * `terrad calibrate --out` writes, which `terrad wheel --soil FILE` takes)
 * through the same code.
 */
#include <stdlib.h>
#include <string.h>

#include "scene/scene_internal.h"

static const char *const material_keys[] = {"compression",
                                            "roughness",
                                            "repose_deg",
                                            "obstacle_gap_m",
                                            "multi_target_m",
                                            "multi_target_max",
                                            "displace_iterations",
                                            "slope_iterations",
                                            "metric",
                                            "method",
                                            "model",
                                            "refill_m_per_s",
                                            "trail_scale_per_m",
                                            "trail_range_m",
                                            "edge_height",
                                            "edge_width",
                                            "preset",
                                            "D",
                                            "zeta_inv",
                                            "force_scale",
                                            "dt",
                                            "substeps",
                                            "conservative",
                                            "decal_min_strength_m",
                                            "soil",
                                            NULL};

static const char *const soil_keys[] = {
    "preset",        "n",         "kc",           "kphi",           "cohesion_pa",
    "friction_deg",  "shear_k_m", "elastic_pa_m", "damping_pa_s_m", "slip_n",
    "density_kg_m3", NULL};

int scene_parse_soil(const cJSON *s, const char *path, const char *parent, sim_soil *soil,
                     error_text *err)
{
    if (json_expect_object(s, path, parent, err) || json_check_keys(s, path, soil_keys, NULL, err))
        return -1;
    char preset[32];
    int r;
    if ((r = json_get_string(s, path, "preset", preset, sizeof preset, err)) < 0)
        return -1;
    if (r && sim_soil_preset(preset, soil) != 0) {
        error_set(err, "%s.preset: must be one of " SIM_SOIL_PRESET_LIST " (got \"%s\")", path,
                  preset);
        return -1;
    }
    /* any finite number here; the soil's own check states the range */
    if (json_get_number(s, path, "n", -1e308, 1e308, &soil->n, err) < 0 ||
        json_get_number(s, path, "kc", -1e308, 1e308, &soil->kc, err) < 0 ||
        json_get_number(s, path, "kphi", -1e308, 1e308, &soil->kphi, err) < 0 ||
        json_get_number(s, path, "cohesion_pa", -1e308, 1e308, &soil->cohesion_pa, err) < 0 ||
        json_get_number(s, path, "friction_deg", -1e308, 1e308, &soil->friction_deg, err) < 0 ||
        json_get_number(s, path, "shear_k_m", -1e308, 1e308, &soil->shear_k_m, err) < 0 ||
        json_get_number(s, path, "elastic_pa_m", -1e308, 1e308, &soil->elastic_pa_m, err) < 0 ||
        json_get_number(s, path, "damping_pa_s_m", -1e308, 1e308, &soil->damping_pa_s_m, err) < 0 ||
        json_get_number(s, path, "slip_n", -1e308, 1e308, &soil->slip_n, err) < 0 ||
        json_get_number(s, path, "density_kg_m3", -1e308, 1e308, &soil->density_kg_m3, err) < 0)
        return -1;
    return sim_soil_validate(soil, path, err);
}

/* "soil": the bekker model's terramechanics parameters — a preset first (the
 * soils of docs/models.md), then each number overrides it. */
static int material_soil(const cJSON *o, sim_material *m, error_text *err)
{
    const cJSON *s = cJSON_GetObjectItemCaseSensitive(o, "soil");
    return s ? scene_parse_soil(s, "material.soil", "material", &m->soil, err) : 0;
}

/* The numbers every model shares: compression, roughness, repose, the
 * multi-target settings and the iteration counts. */
static int material_numbers(const cJSON *o, sim_material *m, error_text *err)
{
    const char *P = "material";
    double v;
    int r;
    if (json_get_number(o, P, "compression", 0, 1, &m->compression, err) < 0 ||
        json_get_number(o, P, "roughness", 0, 1, &m->roughness, err) < 0 ||
        json_get_number(o, P, "obstacle_gap_m", 0, 1000, &m->obstacle_gap_m, err) < 0 ||
        json_get_positive(o, P, "multi_target_m", 1000, 0, &m->multi_target_m, err) < 0)
        return -1;
    /* [0, 90): read over any finite number so the one message states the
     * range actually enforced (90 itself is refused: tan 90 is infinite) */
    if ((r = json_get_number(o, P, "repose_deg", -1e308, 1e308, &v, err)) < 0)
        return -1;
    if (r) {
        if (v < 0.0 || v >= 90.0) {
            error_set(err, "material.repose_deg: must be in [0, 90) (got %g)", v);
            return -1;
        }
        m->repose_deg = v;
    }
    if ((r = json_get_integer(o, P, "multi_target_max", 1, 1024, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->multi_target_max = (int)v;
    if ((r = json_get_integer(o, P, "displace_iterations", 0, 1000, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->displace_iterations = (int)v;
    if ((r = json_get_integer(o, P, "slope_iterations", 0, 1000, 0, &v, err)) < 0)
        return -1;
    if (r)
        m->slope_iterations = (int)v;
    return 0;
}

/* "metric", "method" and "model": names, the method an alias of the persson-* models. */
static int material_names(const cJSON *o, sim_material *m, error_text *err)
{
    const char *P = "material";
    int r;
    char name[32];
    if ((r = json_get_string(o, P, "metric", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_metric_parse(name, &m->metric) != 0) {
        error_set(err, "material.metric: must be euclidean, manhattan or chebyshev (got \"%s\")",
                  name);
        return -1;
    }
    if ((r = json_get_string(o, P, "method", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_method_parse(name, &m->method) != 0) {
        error_set(err, "material.method: must be iterative, ssbo or multi (got \"%s\")", name);
        return -1;
    }
    int has_method = r;
    m->model = sim_model_from_method(m->method);
    if ((r = json_get_string(o, P, "model", name, sizeof name, err)) < 0)
        return -1;
    if (r && sim_model_parse(name, &m->model) != 0) {
        error_set(err, "material.model: must be one of " SIM_MODEL_LIST " (got \"%s\")", name);
        return -1;
    }
    if (r && sim_model_is_persson(m->model)) {
        sim_method implied = m->model == SIM_MODEL_PERSSON_ITERATIVE ? SIM_METHOD_ITERATIVE
                             : m->model == SIM_MODEL_PERSSON_MULTI   ? SIM_METHOD_MULTI
                                                                     : SIM_METHOD_SSBO;
        if (has_method && implied != m->method) {
            error_set(err, "material.method: \"%s\" contradicts material.model \"%s\"",
                      sim_method_name(m->method), name);
            return -1;
        }
        m->method = implied;
    }
    return 0;
}

/* The other models' parameters: subtract, deferred, diffusion, decals. */
static int material_model_params(const cJSON *o, sim_material *m, error_text *err)
{
    const char *P = "material";
    double v;
    int r;
    /* a preset first, so explicit D / zeta_inv / repose_deg override it */
    char preset[32];
    if ((r = json_get_string(o, P, "preset", preset, sizeof preset, err)) < 0)
        return -1;
    if (r) {
        double repose = m->repose_deg;
        const cJSON *rd = cJSON_GetObjectItemCaseSensitive(o, "repose_deg");
        if (sim_material_diffusion_preset(m, preset) != 0) {
            error_set(err, "material.preset: must be mud, pebbles or sand (got \"%s\")", preset);
            return -1;
        }
        if (rd)
            m->repose_deg = repose;
    }
    if (json_get_number(o, P, "refill_m_per_s", 0, 1000, &m->refill_m_per_s, err) < 0 ||
        json_get_number(o, P, "trail_scale_per_m", 0, 1e6, &m->trail_scale_per_m, err) < 0 ||
        json_get_number(o, P, "trail_range_m", 0, 1000, &m->trail_range_m, err) < 0 ||
        json_get_number(o, P, "edge_height", 0, 100, &m->edge_height, err) < 0 ||
        json_get_positive(o, P, "edge_width", 100, 0, &m->edge_width, err) < 0 ||
        json_get_number(o, P, "D", 0, 1e12, &m->diffusion_d, err) < 0 ||
        json_get_number(o, P, "zeta_inv", 0, 1e12, &m->diffusion_zeta_inv, err) < 0 ||
        json_get_number(o, P, "force_scale", 0, 1e12, &m->diffusion_force_scale, err) < 0 ||
        json_get_number(o, P, "dt", 0, 1e12, &m->diffusion_dt, err) < 0 ||
        json_get_number(o, P, "decal_min_strength_m", 0, 1000, &m->decal_min_strength_m, err) < 0)
        return -1;
    const cJSON *sub = cJSON_GetObjectItemCaseSensitive(o, "substeps");
    if (sub && cJSON_IsString(sub)) {
        if (strcmp(sub->valuestring, "auto") != 0) {
            error_set(err, "material.substeps: must be \"auto\" or an integer in [1, 100000]");
            return -1;
        }
        m->diffusion_substeps = SIM_DIFFUSION_SUBSTEPS_AUTO;
    } else {
        if ((r = json_get_integer(o, P, "substeps", 1, 100000, 0, &v, err)) < 0)
            return -1;
        if (r)
            m->diffusion_substeps = (int)v;
    }
    const cJSON *cons = cJSON_GetObjectItemCaseSensitive(o, "conservative");
    if (cons) {
        if (!cJSON_IsBool(cons)) {
            error_set(err, "material.conservative: must be true or false");
            return -1;
        }
        m->diffusion_conservative = cJSON_IsTrue(cons) ? 1 : 0;
    }
    return 0;
}

int scene_parse_material(const cJSON *root, scene *s, error_text *err)
{
    sim_material *m = &s->material;
    *m = sim_material_default();
    m->tick_s = 1.0 / s->tick_hz;
    const cJSON *o = cJSON_GetObjectItemCaseSensitive(root, "material");
    if (!o)
        return 0;
    if (json_expect_object(o, "material", "scene", err) ||
        json_check_keys(o, "material", material_keys, NULL, err) || material_numbers(o, m, err) ||
        material_names(o, m, err) || material_model_params(o, m, err) || material_soil(o, m, err))
        return -1;
    /* the sim's own conversion has the last word on what it can run */
    sim_params p;
    if (sim_params_from_material(m, s->cell_size_m, s->units_per_m, s->floor_units, &p, err) != 0)
        return -1;
    return 0;
}

int scene_material_load_file(const char *path, double cell_size_m, int32_t units_per_m,
                             sim_material *m, error_text *err)
{
    uint8_t *data = NULL;
    size_t len = 0;
    if (file_read_all(path, SCENE_FILE_BYTES_MAX, &data, &len, err) != 0)
        return -1;
    /* file_read_all ends the text with a NUL; one inside it would end the parse early */
    cJSON *o =
        strlen((const char *)data) == len ? cJSON_ParseWithOpts((const char *)data, NULL, 1) : NULL;
    free(data);
    if (!o) {
        error_set(err, "%s: not a JSON object (a syntax error)", path);
        return -1;
    }
    /* read as a scene of these cells reads its "material": the same checks, the same names */
    cJSON *root = cJSON_CreateObject();
    scene s;
    memset(&s, 0, sizeof s);
    s.tick_hz = 60;
    s.cell_size_m = cell_size_m;
    s.units_per_m = units_per_m;
    int rc = -1;
    if (root && cJSON_AddItemToObject(root, "material", o)) {
        o = NULL;
        rc = scene_parse_material(root, &s, err);
        if (rc != 0)
            error_prefix(err, path, ": ");
    } else
        error_set(err, "%s: out of memory", path);
    cJSON_Delete(o);
    cJSON_Delete(root);
    if (rc == 0)
        *m = s.material;
    return rc;
}
