/*
 * soil_rig.c: a window of bekker soil with one collider for the tests
 * (soil_rig.h). Linked into every unit and validation test by CMake.
 */
#include "soil_rig.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define RIG_UNITS_PER_M 10000

void soil_rig_init(soil_rig *r, const sim_soil *soil, double compression, double cell_m, int w,
                   int h, double height_m)
{
    memset(r, 0, sizeof *r);
    sim_material m = sim_material_default();
    m.model = SIM_MODEL_BEKKER;
    m.soil = *soil;
    m.compression = compression;
    m.slope_iterations = 0;
    error_text err;
    if (sim_params_from_material(&m, cell_m, RIG_UNITS_PER_M, 0, &r->p, &err) != 0) {
        printf("soil rig: %s\n", err.message);
        abort();
    }
    r->cells = (int64_t)w * h;
    r->heights = malloc(sizeof(int32_t) * (size_t)r->cells);
    r->heights_copy = malloc(sizeof(int32_t) * (size_t)r->cells);
    r->state = calloc((size_t)r->cells * SIM_SOIL_STATE_FIELDS, sizeof(int32_t));
    r->state_copy = malloc(sizeof(int32_t) * (size_t)r->cells * SIM_SOIL_STATE_FIELDS);
    r->scratch = malloc(sizeof(int32_t) * (size_t)sim_bekker_scratch_cells(w, h));
    if (!r->heights || !r->heights_copy || !r->state || !r->state_copy || !r->scratch) {
        printf("soil rig: out of memory\n");
        abort();
    }
    for (int64_t i = 0; i < r->cells; i++)
        r->heights[i] = (int32_t)(height_m * RIG_UNITS_PER_M);
    r->job.rect = (world_rect){0, 0, w, h};
    r->job.cell_size_m = cell_m;
    r->job.units_per_m = RIG_UNITS_PER_M;
    r->job.heights = r->heights;
    r->job.soil_state = r->state;
    r->job.contacts = &r->contact;
    r->job.colliders = &r->collider;
    r->job.collider_count = 1;
    r->collider.id = 1;
    r->collider.geometry = &r->geometry;
    r->collider.pose.orientation = (quatd){1, 0, 0, 0};
}

void soil_rig_free(soil_rig *r)
{
    free(r->heights);
    free(r->heights_copy);
    free(r->state);
    free(r->state_copy);
    free(r->scratch);
}

void soil_rig_place(soil_rig *r, double x, double y, double z, quatd q, int has_previous)
{
    r->collider.previous_pose = r->collider.pose;
    r->collider.pose.position = (vec3d){x, y, z};
    r->collider.pose.orientation = q;
    r->collider.has_previous = has_previous;
    if (!has_previous)
        r->collider.previous_pose = r->collider.pose;
}

void soil_rig_plate(soil_rig *r, double hx, double hy, double hz, double x, double y, double z)
{
    r->geometry.shape = COLLIDER_BOX;
    r->geometry.half_extents = (vec3d){hx, hy, hz};
    soil_rig_place(r, x, y, z, (quatd){1, 0, 0, 0}, 0);
}

int32_t soil_rig_carry(soil_rig *r, double load_n)
{
    int32_t top = r->heights[0];
    for (int64_t i = 0; i < r->cells; i++)
        if (r->heights[i] > top)
            top = r->heights[i];
    int32_t reach = (int32_t)(collider_reach(&r->geometry) * RIG_UNITS_PER_M) + 2;
    return sim_bekker_carry(&r->p, &r->job, &r->collider, load_n, r->p.floor + reach, top + reach,
                            r->scratch, r->heights_copy, r->state_copy);
}

void soil_rig_step(soil_rig *r)
{
    if (sim_bekker_window(&r->p, &r->job, r->scratch) != SIM_WINDOW_OK) {
        printf("soil rig: window refused\n");
        abort();
    }
}

int64_t soil_rig_mass(const soil_rig *r)
{
    int64_t s = 0;
    for (int64_t i = 0; i < r->cells; i++)
        s += (int64_t)r->heights[i] + r->state[i * SIM_SOIL_STATE_FIELDS + SIM_SOIL_COMPACTED];
    return s;
}
