/*
 * test_params.c: the unit tests' shared set-up of simulation parameters
 * (test_params.h). Linked into every unit test by CMake.
 */
#include "test_params.h"

#include <stdio.h>
#include <stdlib.h>

sim_params test_params_from_material(const sim_material *m, int32_t floor_units)
{
    sim_params p;
    error_text err;
    if (sim_params_from_material(m, TEST_CELL_M, TEST_UNITS_PER_M, floor_units, &p, &err) != 0) {
        printf("params: %s\n", err.message);
        abort();
    }
    return p;
}

int64_t test_sum(const int32_t *heights, int64_t n)
{
    int64_t s = 0;
    for (int64_t i = 0; i < n; i++)
        s += heights[i];
    return s;
}

void test_dunes_world(world *w, int width, int height, uint32_t seed)
{
    error_text err;
    world_base_spec b = {.kind = WORLD_BASE_DUNES,
                         .min_height_m = -0.1,
                         .max_height_m = 0.4,
                         .wavelength_m = 3.0,
                         .octaves = 3,
                         .seed = seed};
    if (world_init(w, width, height, 0.1, 10000, WORLD_HEIGHT_MIN, &err) != 0 ||
        world_generate_base(w, &b, &err) != 0) {
        fprintf(stderr, "test_dunes_world: %s\n", err.message);
        exit(2);
    }
}

uint32_t test_next_random(uint32_t *state)
{
    *state = *state * 1664525u + 1013904223u;
    return *state >> 8;
}
