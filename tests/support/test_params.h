/*
 * test_params.h: the unit tests' shared set-up of simulation parameters. A
 * test that needs params builds a material, changes the fields it is about,
 * and turns it into params on the tests' usual grid (5 cm cells, 10,000
 * height units per metre); a refused material is a broken test, not a result,
 * so the helper prints the reason and aborts. Σh sums of height arrays live
 * here too, because every volume check needs one.
 */
#ifndef TERRAD_TEST_PARAMS_H
#define TERRAD_TEST_PARAMS_H

#include <stdint.h>

#include "sim/sim.h"
#include "world/world.h"

#define TEST_CELL_M 0.05
#define TEST_UNITS_PER_M 10000

/* Params of material m on the tests' grid with floor_units as the floor;
 * aborts (after printing why) when m is refused. */
sim_params test_params_from_material(const sim_material *m, int32_t floor_units);

/* Σh of n heights, exact in int64. */
int64_t test_sum(const int32_t *heights, int64_t n);

/* The tests' dunes world: width x height cells of 10 cm, 10,000 units per
 * metre, dunes from -0.1 to 0.4 m (3 m wavelength, 3 octaves) of this seed;
 * exits 2 when it cannot be made. */
void test_dunes_world(world *w, int width, int height, uint32_t seed);

/* The tests' small deterministic generator (an LCG): the next 24 bits. */
uint32_t test_next_random(uint32_t *state);

/* A tick of the cluster tests: 1..3 rectangles of 1..40 cells a side at
 * random in w (drawn from *rng), each pushed down by 1..50 units a cell;
 * their count, rects filled (3 at most). */
int test_deform_random(world *w, uint32_t *rng, world_rect *rects);

#endif
