/*
 * scene_twin.c: a scene's parameters as the twin library's config keys
 * (server/twin/terrad_twin.h): what a predicting client gives its twin so that
 * its window deforms as the daemon's does (docs/engines.md, "Prediction").
 * The daemon serves them at GET /v1/twin (the viewer's prediction reads them);
 * tests/support/twin_trace.c prints them for the twin's replay tests. One list,
 * so a new material parameter reaches both or neither.
 */
#include <cjson/cJSON.h>
#include <stdlib.h>

#include "scene/scene.h"

int scene_twin_config(const scene *sc, scene_twin_key_fn fn, void *ctx, error_text *err)
{
    if (sc->ground_json ||
        (sc->base.kind != WORLD_BASE_FLAT && sc->base.kind != WORLD_BASE_DUNES)) {
        error_set(err, "per-cell materials and file bases are not part of the twin library");
        return -1;
    }
    const sim_material *m = &sc->material;
    const struct {
        const char *key;
        double v;
    } numbers[] = {
        {"width", sc->width},
        {"height", sc->height},
        {"cell_size_m", sc->cell_size_m},
        {"units_per_m", sc->units_per_m},
        {"floor_units", sc->floor_units},
        {"margin_cells", sc->active_margin_cells},
        {"tick_hz", sc->tick_hz},
        {"terrain.height_m", sc->base.height_m},
        {"terrain.min_height_m", sc->base.min_height_m},
        {"terrain.max_height_m", sc->base.max_height_m},
        {"terrain.wavelength_m", sc->base.wavelength_m},
        {"terrain.octaves", sc->base.octaves},
        {"terrain.seed", sc->base.seed},
        {"compression", m->compression},
        {"roughness", m->roughness},
        {"repose_deg", m->repose_deg},
        {"obstacle_gap_m", m->obstacle_gap_m},
        {"multi_target_m", m->multi_target_m},
        {"multi_target_max", m->multi_target_max},
        {"displace_iterations", m->displace_iterations},
        {"slope_iterations", m->slope_iterations},
        {"refill_m_per_s", m->refill_m_per_s},
        {"trail_scale_per_m", m->trail_scale_per_m},
        {"trail_range_m", m->trail_range_m},
        {"edge_height", m->edge_height},
        {"edge_width", m->edge_width},
        {"diffusion_d", m->diffusion_d},
        {"diffusion_zeta_inv", m->diffusion_zeta_inv},
        {"diffusion_force_scale", m->diffusion_force_scale},
        {"diffusion_dt", m->diffusion_dt},
        {"diffusion_substeps", m->diffusion_substeps},
        {"diffusion_conservative", m->diffusion_conservative},
        {"decal_min_strength_m", m->decal_min_strength_m},
        {"soil.n", m->soil.n},
        {"soil.kc", m->soil.kc},
        {"soil.kphi", m->soil.kphi},
        {"soil.cohesion_pa", m->soil.cohesion_pa},
        {"soil.friction_deg", m->soil.friction_deg},
        {"soil.shear_k_m", m->soil.shear_k_m},
        {"soil.elastic_pa_m", m->soil.elastic_pa_m},
        {"soil.damping_pa_s_m", m->soil.damping_pa_s_m},
        {"soil.slip_n", m->soil.slip_n},
        {"soil.density_kg_m3", m->soil.density_kg_m3},
    };
    fn(ctx, "terrain.kind", 0, sc->base.kind == WORLD_BASE_FLAT ? "flat" : "dunes");
    fn(ctx, "model", 0, sim_model_name(m->model));
    fn(ctx, "metric", 0, sim_metric_name(m->metric));
    for (size_t i = 0; i < sizeof numbers / sizeof numbers[0]; i++)
        fn(ctx, numbers[i].key, numbers[i].v, NULL);
    return 0;
}

static void add_key(void *ctx, const char *key, double number, const char *name)
{
    cJSON *o = ctx;
    if (name)
        cJSON_AddStringToObject(o, key, name);
    else
        cJSON_AddNumberToObject(o, key, number);
}

char *scene_twin_config_json(const scene *sc, error_text *err)
{
    cJSON *o = cJSON_CreateObject();
    if (o && scene_twin_config(sc, add_key, o, err) != 0) {
        cJSON_Delete(o);
        return NULL;
    }
    char *text = json_print_delete(o);
    if (!text)
        error_set(err, "scene: out of memory");
    return text;
}
