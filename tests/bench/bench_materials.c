/*
 * bench_materials.c: cost of the Sumner model and of the per-cell material
 * stages against the uniform Persson CPU twin, on one square window with a
 * sphere pressed into it (the shape of the thesis's active areas). Prints one
 * JSON line per window size; timings are wall clock, mean over the runs.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "sim/sim_internal.h"

static void fill(int32_t *h, int n, int side)
{
    for (int i = 0; i < n; i++)
        h[i] = 20000 + (int32_t)(300.0 * sin((i % side) * 0.2) * cos((i / side) * 0.15));
}

int main(void)
{
    sim_material m = sim_material_default();
    sim_params p;
    error_text err;
    if (sim_params_from_material(&m, 0.05, 10000, 0, &p, &err) != 0)
        return 1;
    ground_material_table t = {.count = 2};
    t.rows[0] = sim_material_row_from_params(&p, 0);
    t.rows[1] = t.rows[0];
    t.rows[1].slope_threshold_axial /= 2;
    t.rows[1].slope_threshold_diagonal /= 2;
    t.rows[1].compression_q16 = 32768;
    t.rows[1].max_compaction = 3000;
    static const int sides[] = {64, 128, 256};
    for (int s = 0; s < 3; s++) {
        int side = sides[s], n = side * side, runs = 40;
        int32_t *h = malloc((size_t)n * 4), *bottom = malloc((size_t)n * 4);
        int32_t *scratch = malloc((size_t)sim_sumner_scratch_cells(side, side) * 4);
        int32_t *raw = malloc((size_t)n * 4), *moved = malloc((size_t)n * 4);
        int32_t *cls = malloc((size_t)n * 4), *seed = malloc((size_t)n * 4);
        uint8_t *ids = malloc((size_t)n);
        uint16_t *mem = calloc((size_t)n, 2);
        for (int i = 0; i < n; i++) {
            int dx = i % side - side / 2, dy = i / side - side / 2;
            double r2 = (dx * dx + dy * dy) / (double)(side * side / 16);
            bottom[i] = r2 < 1.0 ? 19700 + (int32_t)(600.0 * r2) : COLLIDER_BOTTOM_NONE;
            ids[i] = (uint8_t)((i % side) * 2 / side);
        }
        sim_window_job job;
        memset(&job, 0, sizeof job);
        job.rect = (world_rect){0, 0, side, side};
        job.bottom_override = bottom;
        double sumner = 0, uniform = 0, mixed = 0;
        for (int r = 0; r < runs; r++) {
            fill(h, n, side);
            job.heights = h;
            double t0 = time_now_ms();
            sim_sumner_window(&p, &job, scratch);
            double t1 = time_now_ms();
            fill(h, n, side);
            sim_classify(&p, n, h, bottom, raw, moved, cls);
            sim_jump_flood(&p, side, side, 0, 0, cls, seed, scratch);
            sim_displace(&p, side, side, cls, seed, raw, moved, h, scratch);
            sim_even_slopes(&p, side, side, cls, h, scratch);
            double t2 = time_now_ms();
            fill(h, n, side);
            sim_classify_materials(&p, &t, ids, mem, n, h, bottom, raw, moved, cls);
            sim_jump_flood(&p, side, side, 0, 0, cls, seed, scratch);
            sim_displace(&p, side, side, cls, seed, raw, moved, h, scratch);
            sim_even_slopes_materials(&p, &t, ids, side, side, cls, h, scratch);
            sim_compaction_commit(&t, ids, n, raw, moved, mem);
            double t3 = time_now_ms();
            sumner += t1 - t0;
            uniform += t2 - t1;
            mixed += t3 - t2;
        }
        printf("{\"window\": %d, \"sumner_ms\": %.3f, \"persson_uniform_ms\": %.3f, "
               "\"persson_two_materials_compaction_ms\": %.3f}\n",
               side, sumner / runs, uniform / runs, mixed / runs);
        free(h);
        free(bottom);
        free(scratch);
        free(raw);
        free(moved);
        free(cls);
        free(seed);
        free(ids);
        free(mem);
    }
    return 0;
}
