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

int test_deform_random(world *w, uint32_t *rng, world_rect *rects)
{
    int n = 1 + (int)(test_next_random(rng) % 3);
    for (int i = 0; i < n; i++) {
        world_rect r;
        r.x = (int)(test_next_random(rng) % (uint32_t)(w->width - 40));
        r.y = (int)(test_next_random(rng) % (uint32_t)(w->height - 40));
        r.w = 1 + (int)(test_next_random(rng) % 40);
        r.h = 1 + (int)(test_next_random(rng) % 40);
        int32_t *v = malloc(4 * (size_t)r.w * r.h);
        if (!v)
            exit(2);
        world_gather_window(w, r, v);
        for (int k = 0; k < r.w * r.h; k++)
            v[k] -= 1 + (int32_t)(test_next_random(rng) % 50);
        world_scatter_window(w, r, v);
        free(v);
        rects[i] = r;
    }
    return n;
}
