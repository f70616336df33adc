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
