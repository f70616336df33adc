/*
 * calibrate.c: `terrad calibrate` — a soil's parameters fitted to measured
 * data (docs/calibrate.md). Offline, no tick: plate-sinkage curves give
 * Bekker's n, kc and kphi by linear least squares (calibrate_data.c);
 * single-wheel runs give the shear and slip parameters (c, phi, K, slip_n
 * or the ones --fit names, n, kc and kphi among them) by running the bekker
 * model's own testbed (sim_wheel_testbed) for every row: a 3 x 3 grid over
 * the first two parameters, then rounds of coordinate descent with halving
 * steps and a pattern move; what the rows cannot separate is reported. No
 * randomness and one order of evaluation, so the same input gives the same
 * bytes out. Out: a report with the residual of every row (stdout), the
 * scene-ready material JSON (--out) and the residuals as CSV (--residuals).
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "app/calibrate_internal.h"

/* ---- The wheel's parameters: name, search range, first step ---- */

enum { FIT_C, FIT_PHI, FIT_K, FIT_SLIP_N, FIT_N, FIT_KC, FIT_KPHI, FIT_COUNT };

/* --fit's default: the shear and slip parameters; n, kc and kphi on request */
#define FIT_DEFAULT_COUNT FIT_N

typedef struct fit_param {
    const char *name;
    double lo, hi, step; /* step: added, or for K a factor (log steps) */
    int log_step;
} fit_param;

/* Ranges inside sim_soil_validate's, and where real soils lie (Wong's and
 * Ding's tables: c 0-70 kPa, phi 13-35 deg, K 1-25 mm, slip_n 0-2, n
 * 0.2-1.6; kc and kphi span decades, so they move in log steps). */
static const fit_param fit_params[FIT_COUNT] = {
    {"cohesion_pa", 0.0, 1e5, 500.0, 0},
    {"friction_deg", 0.0, 50.0, 4.0, 0},
    {"shear_k_m", 0.001, 0.1, 1.6, 1},
    {"slip_n", 0.0, 2.0, 0.2, 0},
    {"n", 0.2, 2.5, 0.1, 0},
    {"kc", 1.0, 1e8, 1.6, 1},
    {"kphi", 1.0, 1e10, 1.6, 1},
};

static double *param_field(sim_soil *s, int p)
{
    double *f[FIT_COUNT] = {&s->cohesion_pa, &s->friction_deg, &s->shear_k_m, &s->slip_n,
                            &s->n,           &s->kc,           &s->kphi};
    return f[p];
}

typedef struct cal_options {
    const char *plates, *wheel, *predict, *out, *residuals, *base;
    cal_wheel_defaults wheel_defaults;
    int fit[FIT_COUNT], fit_count;
    long rounds;
    double compression;    /* NAN: not given (then the --base file's, or 0.5) */
    sim_wheel_run testbed; /* cell, distance, speed and tick of every run */
} cal_options;

static int parse_fit(void *ctx, const char *list, error_text *err)
{
    cal_options *o = ctx;
    char buf[256];
    o->fit_count = 0;
    if (strlen(list) >= sizeof buf || !*list) {
        error_set(err, "--fit: expected a comma-separated list");
        return -1;
    }
    strcpy(buf, list);
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok;
         tok = strtok_r(NULL, ",", &save)) {
        int p = 0;
        while (p < FIT_COUNT && strcmp(fit_params[p].name, tok) != 0)
            p++;
        int seen = 0;
        for (int i = 0; i < o->fit_count && p < FIT_COUNT; i++)
            seen |= o->fit[i] == p;
        if (p == FIT_COUNT || seen) {
            error_set(err,
                      "--fit: \"%s\" is %s (cohesion_pa, friction_deg, shear_k_m, slip_n, n, "
                      "kc, kphi)",
                      tok, seen ? "named twice" : "not a fitted parameter");
            return -1;
        }
        o->fit[o->fit_count++] = p;
    }
    return 0;
}

/* --where COL=VALUE: the column's name copied out, the value left in argv */
static int where_option(void *ctx, const char *v, error_text *err)
{
    cal_wheel_defaults *d = &((cal_options *)ctx)->wheel_defaults;
    const char *eq = strchr(v, '=');
    static char column[128];
    if (!eq || eq == v || (size_t)(eq - v) >= sizeof column) {
        error_set(err, "--where: expected COL=VALUE (got \"%s\")", v);
        return -1;
    }
    memcpy(column, v, (size_t)(eq - v));
    column[eq - v] = '\0';
    d->where_column = column;
    d->where_value = eq + 1;
    return 0;
}

static int grousers_option(void *ctx, const char *v, error_text *err)
{
    return app_parse_grousers(v, &((cal_options *)ctx)->wheel_defaults.grousers, err);
}

static const cli_option cal_table[] = {
    {"plates", "FILE",
     "plate-sinkage CSV: width_m, pressure_pa, sinkage_m (>= 2 widths of\n"
     ">= 2 rows): n, kc and kphi by least squares",
     CLI_AT_STRING(cal_options, plates)},
    {"wheel", "FILE",
     "single-wheel CSV: slip and drawbar_pull_n, sinkage_m and/or torque_nm\n"
     "(an empty cell is not measured); radius_m, width_m, load_n and\n"
     "grouser_count, grouser_height_m, grouser_thickness_m as columns,\n"
     "or for rows whose file lacks one, the options below",
     CLI_AT_STRING(cal_options, wheel)},
    {"predict", "FILE",
     "wheel rows held out of the fit (the --wheel format, the same\n"
     "defaults and --where): the base and fitted soils' errors on them",
     CLI_AT_STRING(cal_options, predict)},
    {"where", "COL=VALUE", "use only the wheel rows whose COL is VALUE", CLI_CALLS(where_option)},
    APP_OPTIONS_WHEEL(cal_options, wheel_defaults, grousers_option),
    {"base", "PRESET|FILE",
     "the soil the fit starts from and keeps what it does not fit:\n"
     "a preset of docs/models.md (default ding2011) or a material\n"
     "JSON file of the bekker model (as --out writes it)",
     CLI_AT_STRING(cal_options, base)},
    {"fit", "LIST",
     "the wheel parameters fitted, in order (default\n"
     "cohesion_pa,friction_deg,shear_k_m,slip_n; n, kc and kphi may join\n"
     "them); the grid is over the first two",
     CLI_CALLS(parse_fit)},
    {"rounds", "N", "rounds of coordinate descent after the grid (default 3)",
     CLI_AT_LONG(cal_options, rounds, 0, 50)},
    APP_OPTIONS_TESTBED(cal_options, testbed, "--base"),
    {"out", "FILE", "write the material JSON here (it is also printed)",
     CLI_AT_STRING(cal_options, out)},
    {"residuals", "FILE", "write every row's residuals here as CSV",
     CLI_AT_STRING(cal_options, residuals)},
    {0},
};

static const char cal_usage[] = "--plates FILE | --wheel FILE [options]";

void app_calibrate_usage(FILE *f)
{
    cli_print_help(f, "calibrate", cal_usage, cal_table);
}

/* ---- The wheel fit ---- */

/* The model's three measures for every row, and the objective. */
typedef struct wheel_eval {
    double *pull, *sinkage, *torque;
    double objective;
} wheel_eval;

typedef struct wheel_fit {
    const cal_wheel_row *rows;
    int count;
    const cal_options *o;
    double scale[3]; /* RMS of each measured column: residuals are in these units */
    double z_ref;    /* > 0: n moves with kc, kphi so that the pressure at z_ref stays */
    long evaluations;
} wheel_fit;

static int eval_alloc(wheel_eval *e, int n)
{
    e->pull = calloc((size_t)n, sizeof(double));
    e->sinkage = calloc((size_t)n, sizeof(double));
    e->torque = calloc((size_t)n, sizeof(double));
    return e->pull && e->sinkage && e->torque ? 0 : -1;
}

static void eval_free(wheel_eval *e)
{
    free(e->pull);
    free(e->sinkage);
    free(e->torque);
}

static void eval_copy(wheel_eval *dst, const wheel_eval *src, int n)
{
    memcpy(dst->pull, src->pull, sizeof(double) * (size_t)n);
    memcpy(dst->sinkage, src->sinkage, sizeof(double) * (size_t)n);
    memcpy(dst->torque, src->torque, sizeof(double) * (size_t)n);
    dst->objective = src->objective;
}

/* Every row through the testbed; the objective is Σ ((model - measured) /
 * scale)² over the measured cells, each measure in its column's RMS. */
static int evaluate(wheel_fit *f, const sim_soil *soil, wheel_eval *e, error_text *err)
{
    e->objective = 0;
    f->evaluations++;
    for (int i = 0; i < f->count; i++) {
        const cal_wheel_row *r = &f->rows[i];
        sim_wheel_run run = f->o->testbed;
        run.radius_m = r->radius_m;
        run.grousers = r->grousers;
        run.width_m = r->width_m;
        run.load_n = r->load_n;
        run.slip = r->slip;
        run.compression = f->o->compression;
        sim_wheel_result out;
        if (sim_wheel_testbed(soil, &run, &out, err) != 0)
            return -1;
        e->pull[i] = out.drawbar_pull_n;
        e->sinkage[i] = out.sinkage_m;
        e->torque[i] = out.torque_nm;
        const cal_measure *m[3] = {&r->pull_n, &r->sinkage_m, &r->torque_nm};
        double got[3] = {out.drawbar_pull_n, out.sinkage_m, out.torque_nm};
        for (int k = 0; k < 3; k++)
            if (m[k]->has && f->scale[k] > 0) {
                double d = (got[k] - m[k]->value) / f->scale[k];
                e->objective += d * d;
            }
    }
    return 0;
}

/* x moved by one step in direction dir (-1, +1), within the range. */
static double stepped(int p, double x, double step, int dir)
{
    const fit_param *fp = &fit_params[p];
    double y = fp->log_step ? (dir > 0 ? x * step : x / step) : x + dir * step;
    return fmin(fmax(y, fp->lo), fp->hi);
}

static int fitting(const cal_options *o, int p)
{
    for (int i = 0; i < o->fit_count; i++)
        if (o->fit[i] == p)
            return 1;
    return 0;
}

/* Parameter p of s set to x. With n fitted beside kc or kphi, a step of n
 * alone would cross the valley where n and the modulus trade (the rows feel
 * (kc/b + kphi) z^n over a narrow range of z): n then moves along it, kc and
 * kphi (those fitted) scaled so that the pressure at the rows' typical
 * sinkage z_ref stays, and the modulus' own steps move across it. */
static void set_param(const wheel_fit *f, sim_soil *s, int p, double x)
{
    if (p == FIT_N && f->z_ref > 0) {
        double scale = pow(f->z_ref, s->n - x);
        for (int q = FIT_KC; q <= FIT_KPHI; q++)
            if (fitting(f->o, q)) /* one left out keeps its value: it is not fitted */
                *param_field(s, q) =
                    fmin(fmax(*param_field(s, q) * scale, fit_params[q].lo), fit_params[q].hi);
    }
    *param_field(s, p) = x;
}

/* Try soil with parameter p at x; keep it in best when strictly better. */
static int try_value(wheel_fit *f, sim_soil *best, wheel_eval *be, wheel_eval *trial, int p,
                     double x, error_text *err)
{
    sim_soil s = *best;
    if (*param_field(&s, p) == x)
        return 0;
    set_param(f, &s, p, x);
    if (evaluate(f, &s, trial, err) != 0)
        return -1;
    if (trial->objective < be->objective) {
        *best = s;
        eval_copy(be, trial, f->count);
        return 1;
    }
    return 0;
}

/* The grid, then the rounds; best starts as the base soil, evaluated. */
static int search(wheel_fit *f, sim_soil *best, wheel_eval *be, FILE *report, error_text *err)
{
    const cal_options *o = f->o;
    wheel_eval trial;
    if (eval_alloc(&trial, f->count) != 0) {
        error_set(err, "out of memory");
        return -1;
    }
    double step[FIT_COUNT];
    for (int p = 0; p < FIT_COUNT; p++)
        step[p] = fit_params[p].step;
    int rc = 0;
    if (o->fit_count >= 2) { /* 3 x 3 around the base, in one fixed order */
        int a = o->fit[0], b = o->fit[1];
        sim_soil centre = *best;
        for (int i = -1; i <= 1 && rc == 0; i++)
            for (int j = -1; j <= 1 && rc == 0; j++) {
                sim_soil s = centre;
                set_param(f, &s, a, stepped(a, *param_field(&centre, a), step[a], i));
                set_param(f, &s, b, stepped(b, *param_field(&centre, b), step[b], j));
                if ((i == 0 && j == 0) || evaluate(f, &s, &trial, err) != 0) {
                    rc = (i == 0 && j == 0) ? 0 : -1;
                    continue;
                }
                if (trial.objective < be->objective) {
                    *best = s;
                    eval_copy(be, &trial, f->count);
                }
            }
        fprintf(report, "grid 3 x 3 over %s, %s: objective %.6g\n", fit_params[a].name,
                fit_params[b].name, be->objective);
    }
    for (long round = 0; round < o->rounds && rc == 0; round++) {
        sim_soil before = *best;
        for (int i = 0; i < o->fit_count && rc == 0; i++) {
            int p = o->fit[i], moved = 0;
            for (int dir = -1; dir <= 1 && rc == 0; dir += 2) {
                int got = try_value(f, best, be, &trial, p,
                                    stepped(p, *param_field(best, p), step[p], dir), err);
                rc = got < 0 ? -1 : 0;
                moved |= got > 0;
            }
            if (!moved)
                step[p] = fit_params[p].log_step ? sqrt(step[p]) : step[p] / 2;
        }
        /* Hooke-Jeeves' pattern move: the round's move once more, all
         * parameters at once, follows a valley across the axes (n against
         * kphi) that one-at-a-time steps only zigzag along */
        sim_soil pattern = *best;
        int moved = 0;
        for (int i = 0; i < o->fit_count; i++) {
            int p = o->fit[i];
            double x = *param_field(best, p), x0 = *param_field(&before, p);
            double y = fit_params[p].log_step && x0 > 0 ? x * (x / x0) : 2 * x - x0;
            *param_field(&pattern, p) = fmin(fmax(y, fit_params[p].lo), fit_params[p].hi);
            moved |= y != x;
        }
        if (moved && rc == 0) {
            rc = evaluate(f, &pattern, &trial, err);
            if (rc == 0 && trial.objective < be->objective) {
                *best = pattern;
                eval_copy(be, &trial, f->count);
            }
        }
        fprintf(report, "round %ld: objective %.6g\n", round + 1, be->objective);
    }
    eval_free(&trial);
    return rc;
}

/* Values as the JSON writes them (%.6g), so the residuals are those of the
 * material printed, not of bits the JSON cannot carry. */
static double printed(double v)
{
    char buf[64];
    snprintf(buf, sizeof buf, "%.6g", v);
    return strtod(buf, NULL);
}

static void round_soil(sim_soil *s)
{
    double *f[10] = {
        &s->n,         &s->kc,           &s->kphi,           &s->cohesion_pa, &s->friction_deg,
        &s->shear_k_m, &s->elastic_pa_m, &s->damping_pa_s_m, &s->slip_n,      &s->density_kg_m3};
    for (int i = 0; i < 10; i++)
        *f[i] = printed(*f[i]);
}

/* ---- Output ---- */

static void write_material(FILE *out, const sim_soil *s, double compression)
{
    fprintf(out,
            "{\"model\": \"bekker\", \"compression\": %.6g, \"soil\": {\"n\": %.6g, \"kc\": %.6g, "
            "\"kphi\": %.6g, \"cohesion_pa\": %.6g, \"friction_deg\": %.6g, \"shear_k_m\": %.6g, "
            "\"elastic_pa_m\": %.6g, \"damping_pa_s_m\": %.6g, \"slip_n\": %.6g, "
            "\"density_kg_m3\": %.6g}}\n",
            compression, s->n, s->kc, s->kphi, s->cohesion_pa, s->friction_deg, s->shear_k_m,
            s->elastic_pa_m, s->damping_pa_s_m, s->slip_n, s->density_kg_m3);
}

static double relative(double model, double measured)
{
    return measured != 0 ? (model - measured) / fabs(measured) : NAN;
}

static int by_value(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return x < y ? -1 : x > y;
}

/* Median of |relative error| over the rows that measured k (nonzero), or NaN. */
static double median_error(const cal_wheel_row *rows, int n, const wheel_eval *e, int k)
{
    double *v = malloc(sizeof(double) * (size_t)n);
    int m = 0;
    for (int i = 0; v && i < n; i++) {
        const cal_measure *c[3] = {&rows[i].pull_n, &rows[i].sinkage_m, &rows[i].torque_nm};
        double got[3] = {e->pull[i], e->sinkage[i], e->torque[i]};
        if (c[k]->has && c[k]->value != 0)
            v[m++] = fabs(relative(got[k], c[k]->value));
    }
    double r = NAN;
    if (m > 0) {
        qsort(v, (size_t)m, sizeof *v, by_value);
        r = m % 2 ? v[m / 2] : 0.5 * (v[m / 2 - 1] + v[m / 2]);
    }
    free(v);
    return r;
}

static const char *const measure_names[3] = {"drawbar_pull_n", "sinkage_m", "torque_nm"};

static void report_wheel(FILE *out, FILE *csv, const char *kind, const wheel_fit *f,
                         const wheel_eval *base, const wheel_eval *fitted, const char *base_name)
{
    fprintf(out, "\n| line | slip | pull measured | base | fitted | sinkage mm measured | base | "
                 "fitted | torque measured | base | fitted |\n"
                 "|---|---|---|---|---|---|---|---|---|---|---|\n");
    for (int i = 0; i < f->count; i++) {
        const cal_wheel_row *r = &f->rows[i];
        const cal_measure *m[3] = {&r->pull_n, &r->sinkage_m, &r->torque_nm};
        double b[3] = {base->pull[i], base->sinkage[i], base->torque[i]};
        double g[3] = {fitted->pull[i], fitted->sinkage[i], fitted->torque[i]};
        double unit[3] = {1, 1e3, 1};
        fprintf(out, "| %d | %.3g", r->line, r->slip);
        for (int k = 0; k < 3; k++) {
            if (m[k]->has)
                fprintf(out, " | %.2f", m[k]->value * unit[k]);
            else
                fprintf(out, " | -");
            fprintf(out, " | %.2f | %.2f", b[k] * unit[k], g[k] * unit[k]);
            if (csv && m[k]->has)
                fprintf(csv, "%s,%d,%.6g,%s,%.6g,%.6g,%.6g\n", kind, r->line, r->slip,
                        measure_names[k], m[k]->value, g[k], relative(g[k], m[k]->value));
        }
        fprintf(out, " |\n");
    }
    fprintf(out, "\nmedian relative error, base %s -> fitted:", base_name);
    const char *label[3] = {"drawbar pull", "sinkage", "torque"};
    for (int k = 0; k < 3; k++) {
        double a = median_error(f->rows, f->count, base, k);
        double c = median_error(f->rows, f->count, fitted, k);
        if (!isnan(a))
            fprintf(out, "%s %s %.0f %% -> %.0f %%", k ? "," : "", label[k], 100 * a, 100 * c);
    }
    fprintf(out, "\nobjective (sum of squared residuals in each column's RMS): %.6g -> %.6g\n",
            base->objective, fitted->objective);
}

/* ---- What the wheel rows cannot separate ---- */

/*
 * Bekker's pressure (kc/b + kphi) z^n seen through wheel rows: kc and kphi
 * act only through kc/b + kphi, b the contact patch's width (near the
 * wheel's), so wheels of one width cannot tell them apart; and one wheel
 * under one load sinks over a narrow range of z (only slip-sinkage moves
 * it), so n largely trades against the modulus. The search still stops
 * at some pair; the report says which pair is not (or poorly) determined
 * rather than present it as measured. Returns the count of such warnings.
 */
static int report_separable(const cal_options *o, const cal_wheel_row *rows, int count, FILE *out)
{
    int widths = 1, wheels = 1;
    for (int i = 1; i < count; i++) {
        int new_width = 1, new_wheel = 1;
        for (int j = 0; j < i; j++) {
            new_width &= rows[j].width_m != rows[i].width_m;
            new_wheel &= rows[j].width_m != rows[i].width_m ||
                         rows[j].radius_m != rows[i].radius_m || rows[j].load_n != rows[i].load_n ||
                         rows[j].grousers.count != rows[i].grousers.count ||
                         rows[j].grousers.height != rows[i].grousers.height;
        }
        widths += new_width;
        wheels += new_wheel;
    }
    int warned = 0;
    if (fitting(o, FIT_KC) && fitting(o, FIT_KPHI) && widths < 2) {
        fprintf(out,
                "\nnot separable: kc and kphi from wheels of one width (%g m): only "
                "kc/b + kphi is determined; the pair printed is one point of that line "
                "(fit kc or kphi alone, add rows of another width, or give --plates)\n",
                rows[0].width_m);
        warned++;
    }
    if (fitting(o, FIT_N) && (fitting(o, FIT_KC) || fitting(o, FIT_KPHI)) && wheels < 2) {
        fprintf(out, "\npoorly separable: n with kc/kphi from one wheel under one load: its "
                     "sinkage spans little of the pressure-sinkage curve (only slip-sinkage "
                     "moves it), so n and the modulus largely trade against each other; the "
                     "pair is uncertain (add rows of another load or wheel, or give --plates)\n");
        warned++;
    }
    return warned;
}

/* The rows and each measured column's RMS (the objective's units). */
static void fit_init(wheel_fit *f, const cal_options *o, const cal_wheel_row *rows, int count)
{
    *f = (wheel_fit){rows, count, o, {0, 0, 0}, 0, 0};
    /* z_ref: the geometric mean of the measured sinkages */
    double lz = 0;
    int nz = 0;
    for (int i = 0; i < count; i++)
        if (rows[i].sinkage_m.has) {
            lz += log(rows[i].sinkage_m.value);
            nz++;
        }
    if (nz && fitting(o, FIT_N) && (fitting(o, FIT_KC) || fitting(o, FIT_KPHI)))
        f->z_ref = exp(lz / nz);
    for (int k = 0; k < 3; k++) {
        double s2 = 0;
        int m = 0;
        for (int i = 0; i < count; i++) {
            const cal_measure *c[3] = {&rows[i].pull_n, &rows[i].sinkage_m, &rows[i].torque_nm};
            if (c[k]->has) {
                s2 += c[k]->value * c[k]->value;
                m++;
            }
        }
        f->scale[k] = m ? sqrt(s2 / m) : 0;
    }
}

/* --predict: rows the fit never saw, run on the base soil and the fitted
 * one; their errors beside the fit's own say whether the soil carries over
 * to another wheel, or only to the wheel it was fitted on. */
static int predict_wheel(const cal_options *o, const sim_soil *base_soil, const sim_soil *soil,
                         FILE *report, FILE *csv, error_text *err)
{
    cal_wheel_row *rows;
    int count = cal_read_wheel(o->predict, &o->wheel_defaults, &rows, err);
    if (count < 0)
        return 2;
    wheel_fit f;
    fit_init(&f, o, rows, count);
    wheel_eval base, fitted;
    int rc = 1;
    if (eval_alloc(&base, count) != 0 || eval_alloc(&fitted, count) != 0)
        error_set(err, "out of memory");
    else if (evaluate(&f, base_soil, &base, err) == 0 && evaluate(&f, soil, &fitted, err) == 0) {
        fprintf(report, "\nheld out (not fitted): %d rows of %s\n", count, o->predict);
        report_wheel(report, csv, "predict", &f, &base, &fitted, o->base);
        rc = 0;
    }
    eval_free(&base);
    eval_free(&fitted);
    free(rows);
    return rc;
}

/* The wheel rows: the base soil evaluated, searched, the result rounded and re-run. */
static int fit_wheel(const cal_options *o, const cal_wheel_row *rows, int count, sim_soil *soil,
                     FILE *report, FILE *csv, error_text *err)
{
    wheel_fit f;
    fit_init(&f, o, rows, count);
    wheel_eval base, best;
    int rc = -1;
    if (eval_alloc(&base, count) != 0 || eval_alloc(&best, count) != 0)
        error_set(err, "out of memory");
    else if (evaluate(&f, soil, &base, err) == 0) {
        fprintf(report, "base soil: objective %.6g\n", base.objective);
        eval_copy(&best, &base, count);
        if (search(&f, soil, &best, report, err) == 0) {
            sim_soil exact = *soil;
            round_soil(soil);
            rc = memcmp(&exact, soil, sizeof exact) != 0 ? evaluate(&f, soil, &best, err) : 0;
        }
    }
    if (rc == 0) {
        fprintf(report, "%ld testbed evaluations of %d rows (cell %g m, %g m at %g m/s)\n",
                f.evaluations, count, o->testbed.cell_m, o->testbed.distance_m,
                o->testbed.speed_m_s);
        report_wheel(report, csv, "wheel", &f, &base, &best, o->base);
        report_separable(o, rows, count, report);
    }
    eval_free(&base);
    eval_free(&best);
    return rc;
}

static void report_plates(FILE *out, FILE *csv, const cal_plate_row *rows, int count,
                          const cal_plate_fit *fit)
{
    fprintf(out, "plates: %d rows, %d widths -> n %.6g, kc %.6g N/m^(n+1), kphi %.6g N/m^(n+2)%s\n",
            count, fit->widths, fit->n, fit->kc, fit->kphi,
            fit->clamped ? " (a modulus came out negative and is held at 0)" : "");
    fprintf(out,
            "\n| line | width_m | pressure_pa | sinkage_mm | pressure error | sinkage error |\n"
            "|---|---|---|---|---|---|\n");
    double worst = 0;
    for (int i = 0; i < count; i++) {
        fprintf(out, "| %d | %.6g | %.6g | %.4g | %+.2f %% | %+.2f %% |\n", rows[i].line,
                rows[i].width_m, rows[i].pressure_pa, rows[i].sinkage_m * 1e3,
                100 * fit->pressure_rel[i], 100 * fit->sinkage_rel[i]);
        worst = fmax(worst, fabs(fit->pressure_rel[i]));
        if (csv) {
            double kb = fit->kc / rows[i].width_m + fit->kphi;
            fprintf(csv, "plate,%d,%.6g,pressure_pa,%.6g,%.6g,%.6g\n", rows[i].line,
                    rows[i].width_m, rows[i].pressure_pa, kb * pow(rows[i].sinkage_m, fit->n),
                    fit->pressure_rel[i]);
        }
    }
    fprintf(out, "largest pressure error %.2f %%\n\n", 100 * worst);
}

/* ---- The command ---- */

static int write_file(const char *path, const char *what, const sim_soil *s, double compression,
                      error_text *err)
{
    FILE *f = fopen(path, "w");
    if (f) {
        write_material(f, s, compression);
        if (fclose(f) == 0)
            return 0;
    }
    error_set(err, "%s: cannot write the %s", path, what);
    return -1;
}

/* The plates (if any) then the wheel (if any); 0, 1 (a failure) or 2 (bad input). */
static int calibrate(cal_options *o, sim_soil *soil, FILE *csv, error_text *err)
{
    if (o->plates) {
        cal_plate_row *rows;
        int n = cal_read_plates(o->plates, &rows, err);
        if (n < 0)
            return 2;
        cal_plate_fit fit;
        int rc = cal_fit_plates(rows, n, o->plates, &fit, err);
        if (rc == 0) {
            soil->n = fit.n;
            soil->kc = fit.kc;
            soil->kphi = fit.kphi;
            report_plates(stdout, csv, rows, n, &fit);
            cal_plate_fit_free(&fit);
        }
        free(rows);
        if (rc != 0)
            return 2;
    }
    if (sim_soil_validate(soil, "soil", err) != 0)
        return 2;
    if (o->wheel) {
        cal_wheel_row *rows;
        int n = cal_read_wheel(o->wheel, &o->wheel_defaults, &rows, err);
        if (n < 0)
            return 2;
        printf("wheel: %d rows of %s; fitting", n, o->wheel);
        for (int i = 0; i < o->fit_count; i++)
            printf("%s %s", i ? "," : "", fit_params[o->fit[i]].name);
        printf("\n");
        sim_soil base_soil = *soil;
        int rc = fit_wheel(o, rows, n, soil, stdout, csv, err);
        free(rows);
        if (rc != 0)
            return 1;
        if (o->predict && (rc = predict_wheel(o, &base_soil, soil, stdout, csv, err)) != 0)
            return rc;
    } else
        round_soil(soil);
    return 0;
}

int app_calibrate(int argc, char **argv)
{
    cal_options o = {.base = "ding2011", .rounds = 3, .compression = NAN};
    sim_wheel_run_defaults(&o.testbed);
    for (int p = 0; p < FIT_DEFAULT_COUNT; p++)
        o.fit[o.fit_count++] = p;
    error_text err;
    int first = 0;
    cli_result r = cli_parse("calibrate", cal_usage, cal_table, argc, argv, &o, &first);
    if (r != CLI_OK)
        return r == CLI_HELP ? 0 : 2;
    if (first < argc || (!o.plates && !o.wheel) || (o.predict && !o.wheel)) {
        fprintf(stderr, "terrad calibrate: %s\n",
                first < argc            ? "unexpected operand (see --help)"
                : !o.plates && !o.wheel ? "give --plates FILE and/or --wheel FILE"
                                        : "--predict: needs --wheel (the rows fitted)");
        return 2;
    }
    sim_soil soil;
    double compression;
    if (app_soil_load(o.base, "--base", o.testbed.cell_m, &soil, &compression, &err) != 0) {
        fprintf(stderr, "terrad calibrate: %s\n", err.message);
        return 2;
    }
    if (isnan(o.compression))
        o.compression = compression;
    FILE *csv = NULL;
    if (o.residuals) {
        csv = fopen(o.residuals, "w");
        if (!csv) {
            fprintf(stderr, "terrad calibrate: %s: cannot write the residuals\n", o.residuals);
            return 1;
        }
        fprintf(csv, "kind,line,x,measure,measured,model,relative_error\n");
    }
    printf("terrad calibrate: base soil %s\n", o.base);
    int rc = calibrate(&o, &soil, csv, &err);
    if (csv && fclose(csv) != 0 && rc == 0) {
        error_set(&err, "%s: cannot write the residuals", o.residuals);
        rc = 1;
    }
    if (rc == 0 && o.out)
        rc = write_file(o.out, "material", &soil, o.compression, &err) == 0 ? 0 : 1;
    if (rc != 0) {
        fprintf(stderr, "terrad calibrate: %s\n", err.message);
        return rc;
    }
    printf("\nmaterial (a scene's \"material\", or an entry of its \"materials\"):\n");
    write_material(stdout, &soil, o.compression);
    return 0;
}
