/*
 * soil_rig.h: one window of bekker soil and one collider for the tests that
 * press plates and roll wheels without a world — test_bekker (unit) and the
 * validation tests (tests/validation/). The rig is the model's own soil bin
 * (sim_soil_bin, server/sim/sim_testbed.c, which the single-wheel testbed
 * runs on); these wrappers abort on what would be a broken test, and add the
 * plate and the mass sum only tests need. The window is flat at height_m;
 * the collider is the job's only one.
 */
#ifndef TERRAD_SOIL_RIG_H
#define TERRAD_SOIL_RIG_H

#include "sim/sim_internal.h"

typedef sim_soil_bin soil_rig;

/* A w x h window of cell_m cells (10,000 units per metre) at height_m, the
 * soil and compression given, slope evening off. Aborts (printing why) when
 * the soil is refused: a broken test. */
void soil_rig_init(soil_rig *r, const sim_soil *soil, double compression, double cell_m, int w,
                   int h, double height_m);
void soil_rig_free(soil_rig *r);
/* The collider at (x, y) with orientation q, its previous pose the current
 * one (has_previous 1), or none (0). */
void soil_rig_place(soil_rig *r, double x, double y, double z, quatd q, int has_previous);
/* A box plate of half extents (hx, hy, hz), upright at (x, y, z), no
 * previous pose: the collider of the plate-sinkage tests. */
void soil_rig_plate(soil_rig *r, double hx, double hy, double hz, double x, double y, double z);
/* Load-driven: the highest pose height (units) at which the soil carries
 * load_n; the collider is left there (sim_bekker_carry). */
int32_t soil_rig_carry(soil_rig *r, double load_n);
/* One tick of the model at the collider's pose; aborts on a refused window. */
void soil_rig_step(soil_rig *r);
/* Σh + Σcompacted over the window: constant under the model. */
int64_t soil_rig_mass(const soil_rig *r);

#endif
