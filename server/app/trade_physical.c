/*
 * trade_physical.c: the trade's physical axis (`terrad bench --trade`,
 * docs/trade.md). The geometric sweep measures every model against a
 * converged run of terrad's own; this measures what can be set against
 * the physical world: the bekker model, the one model with forces, on
 * Ding et al. 2011's single-wheel testbed (their smooth wheel and their
 * lugged one, 30 lugs 10 mm tall, 80 N, slips 0-0.6; sim_wheel_testbed, the
 * run the validation test makes), both wheels at the same several
 * cell sizes and travels per tick (a wheel that moves more than 1.5 cells
 * in a tick is pressed in one-cell slices: the model's sub-steps). Each
 * configuration gets its cost (ms per tick), its error against the
 * measurements (median relative error of drawbar pull, sinkage and torque
 * over the slips) and, as the geometric rows, against the model's own
 * finest configuration of the same wheel. The geometric models have no forces: they have no
 * physical row. Offline; no tick of a world runs here.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/trade_internal.h"

static const double full_cells[] = {0.02, 0.01, 0.005};
static const double full_ticks_s[] = {0.2, 0.05, 0.02}; /* 10, 2.5 and 1 mm a tick */
static const double quick_cells[] = {0.02, 0.01};
static const double quick_ticks_s[] = {0.05};

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Median of |model - measured| / |measured| over the rows with measured != 0. */
static double median_error(const sim_wheel_measured *data, const double *model, int k)
{
    double v[SIM_WHEEL_DING2011_ROWS];
    int n = 0;
    for (int i = 0; i < SIM_WHEEL_DING2011_ROWS; i++) {
        const sim_wheel_measured *m = &data[i];
        double measured = k == 0 ? m->drawbar_pull_n : k == 1 ? m->sinkage_m : m->torque_nm;
        if (measured != 0)
            v[n++] = fabs(model[i] - measured) / fabs(measured);
    }
    qsort(v, (size_t)n, sizeof *v, by_value);
    return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

static double rms(const double *a, const double *b, int n)
{
    double s = 0;
    for (int i = 0; i < n; i++)
        s += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(s / n);
}

/* One configuration: every slip of one wheel (lugged: Ding's 30 lugs, the
 * validation test's geometry), timed. */
static int physical_row(int lugged, double cell_m, double tick_s, trade_physical_row *row,
                        error_text *err)
{
    memset(row, 0, sizeof *row);
    const sim_wheel_measured *data = lugged ? sim_wheel_ding2011_lugged : sim_wheel_ding2011;
    sim_soil soil;
    sim_soil_preset("ding2011", &soil);
    double ms = 0;
    for (int i = 0; i < SIM_WHEEL_DING2011_ROWS; i++) {
        sim_wheel_run run;
        sim_wheel_run_defaults(&run);
        run.radius_m = SIM_WHEEL_DING2011_RADIUS_M;
        run.width_m = SIM_WHEEL_DING2011_WIDTH_M;
        run.load_n = SIM_WHEEL_DING2011_LOAD_N;
        run.slip = data[i].slip;
        if (lugged)
            run.grousers =
                (collider_grousers){SIM_WHEEL_DING2011_LUG_COUNT, SIM_WHEEL_DING2011_LUG_HEIGHT_M,
                                    SIM_WHEEL_DING2011_LUG_THICKNESS_M};
        run.cell_m = cell_m;
        run.tick_s = tick_s;
        sim_wheel_result out;
        double t0 = time_now_ms();
        if (sim_wheel_testbed(&soil, &run, &out, err) != 0)
            return -1;
        ms += (time_now_ms() - t0) / (double)out.ticks;
        row->pull_n[i] = out.drawbar_pull_n;
        row->sinkage_m[i] = out.sinkage_m;
        row->torque_nm[i] = out.torque_nm;
        row->ticks = out.ticks;
        row->tick_mm = run.speed_m_s * tick_s * 1e3;
    }
    row->lugged = lugged;
    row->cell_m = cell_m;
    row->tick_ms_mean = ms / SIM_WHEEL_DING2011_ROWS;
    row->pull_error = median_error(data, row->pull_n, 0);
    row->sinkage_error = median_error(data, row->sinkage_m, 1);
    row->torque_error = median_error(data, row->torque_nm, 2);
    return 0;
}

int trade_physical_run(int quick, trade_physical_row *rows, int *count, error_text *err)
{
    const double *cells = quick ? quick_cells : full_cells,
                 *ticks = quick ? quick_ticks_s : full_ticks_s;
    int nc = quick ? 2 : 3, nt = quick ? 1 : 3;
    *count = 0;
    for (int lugged = 0; lugged <= 1; lugged++) {
        int first = *count;
        for (int c = 0; c < nc; c++)
            for (int t = 0; t < nt; t++) {
                if (physical_row(lugged, cells[c], ticks[t], &rows[*count], err) != 0)
                    return -1;
                (*count)++;
            }
        /* against the wheel's own finest (its last): the model's own convergence */
        const trade_physical_row *fine = &rows[*count - 1];
        for (int i = first; i < *count; i++) {
            rows[i].pull_rms_vs_finest_n =
                rms(rows[i].pull_n, fine->pull_n, SIM_WHEEL_DING2011_ROWS);
            rows[i].sinkage_rms_vs_finest_m =
                rms(rows[i].sinkage_m, fine->sinkage_m, SIM_WHEEL_DING2011_ROWS);
        }
    }
    return 0;
}

int trade_physical_write_csv(const char *path, const trade_physical_row *rows, int count)
{
    FILE *f = fopen(path, "w");
    if (!f)
        return -1;
    fprintf(f, "model,case,wheel,cell_m,tick_mm,ticks,tick_ms_mean,pull_median_error,"
               "sinkage_median_error,torque_median_error,pull_rms_vs_finest_n,"
               "sinkage_rms_vs_finest_m\n");
    for (int i = 0; i < count; i++) {
        const trade_physical_row *r = &rows[i];
        fprintf(f, "bekker,ding2011-single-wheel,%s,%g,%g,%ld,%.4f,%.4f,%.4f,%.4f,%.4f,%.6f\n",
                r->lugged ? "lugged" : "smooth", r->cell_m, r->tick_mm, r->ticks, r->tick_ms_mean,
                r->pull_error, r->sinkage_error, r->torque_error, r->pull_rms_vs_finest_n,
                r->sinkage_rms_vs_finest_m);
    }
    return fclose(f);
}

void trade_physical_report(FILE *f, const trade_physical_row *rows, int count)
{
    fprintf(f, "\nagainst measured data: bekker (ding2011 soil) on Ding et al. 2011's smooth "
               "wheel and lugged wheel (30 lugs, 10 mm), 80 N, slips 0-0.6\n"
               "(median relative error over the slips; vs finest: RMS against the same "
               "wheel's finest configuration)\n");
    fprintf(f, "%7s %8s %8s %10s %8s %8s %8s %12s %12s\n", "wheel", "cell_m", "mm/tick", "ms/tick",
            "pull", "sinkage", "torque", "pull vs fine", "sink vs fine");
    for (int i = 0; i < count; i++) {
        const trade_physical_row *r = &rows[i];
        fprintf(f, "%7s %8g %8g %10.3f %7.0f%% %7.0f%% %7.0f%% %10.2f N %9.2f mm\n",
                r->lugged ? "lugged" : "smooth", r->cell_m, r->tick_mm, r->tick_ms_mean,
                100 * r->pull_error, 100 * r->sinkage_error, 100 * r->torque_error,
                r->pull_rms_vs_finest_n, r->sinkage_rms_vs_finest_m * 1e3);
    }
    fprintf(f, "the geometric models (persson-*, subtract, deferred, diffusion, sumner, decals) "
               "compute no forces: no row against measured data\n");
}
