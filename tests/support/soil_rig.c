/*
 * soil_rig.c: the tests' soil bin (soil_rig.h) over the model's own
 * (sim_soil_bin). Linked into every unit and validation test by CMake.
 */
#include "soil_rig.h"

#include <stdio.h>
#include <stdlib.h>

void soil_rig_init(soil_rig *r, const sim_soil *soil, double compression, double cell_m, int w,
                   int h, double height_m)
{
    error_text err;
    if (sim_soil_bin_init(r, soil, compression, cell_m, w, h, height_m, &err) != 0) {
        printf("soil rig: %s\n", err.message);
        abort();
    }
}

void soil_rig_free(soil_rig *r)
{
    sim_soil_bin_free(r);
}

void soil_rig_place(soil_rig *r, double x, double y, double z, quatd q, int has_previous)
{
    sim_soil_bin_place(r, x, y, z, q, has_previous);
}

void soil_rig_plate(soil_rig *r, double hx, double hy, double hz, double x, double y, double z)
{
    r->geometry.shape = COLLIDER_BOX;
    r->geometry.half_extents = (vec3d){hx, hy, hz};
    soil_rig_place(r, x, y, z, (quatd){1, 0, 0, 0}, 0);
}

int32_t soil_rig_carry(soil_rig *r, double load_n)
{
    return sim_soil_bin_carry(r, load_n);
}

void soil_rig_step(soil_rig *r)
{
    if (sim_soil_bin_step(r) != SIM_WINDOW_OK) {
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
