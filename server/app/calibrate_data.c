/*
 * calibrate_data.c: the measured data `terrad calibrate` fits — plate
 * sinkage and single-wheel CSV files read and checked, every refusal naming
 * the file, the line and the field — and the plate fit, Bekker's equation by
 * linear least squares (calibrate_internal.h). Offline; no tick.
 */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/calibrate_internal.h"

#define CSV_LINE_MAX 4096
#define CSV_FIELDS_MAX 64
#define CSV_ROWS_MAX 100000

/* One CSV file read line by line: the header's names, then each row's fields. */
typedef struct csv_reader {
    FILE *f;
    const char *path;
    int line;
    char buf[CSV_LINE_MAX];
    char *fields[CSV_FIELDS_MAX];
    int count;
    char header[CSV_LINE_MAX];
    char *names[CSV_FIELDS_MAX];
    int name_count;
} csv_reader;

static char *trim(char *s)
{
    while (isspace((unsigned char)*s))
        s++;
    size_t n = strlen(s);
    while (n > 0 && isspace((unsigned char)s[n - 1]))
        s[--n] = '\0';
    return s;
}

/* Split buf at commas into out (trimmed); returns the count or -1 if too many. */
static int split(char *buf, char **out)
{
    int n = 0;
    for (char *p = buf;;) {
        char *comma = strchr(p, ',');
        if (comma)
            *comma = '\0';
        if (n == CSV_FIELDS_MAX)
            return -1;
        out[n++] = trim(p);
        if (!comma)
            return n;
        p = comma + 1;
    }
}

/* The next data line (comments and blank lines skipped): 1, 0 at the end, -1 on error. */
static int csv_next(csv_reader *r, error_text *err)
{
    while (fgets(r->buf, sizeof r->buf, r->f)) {
        r->line++;
        size_t n = strlen(r->buf);
        if (n == sizeof r->buf - 1 && r->buf[n - 1] != '\n') {
            error_set(err, "%s:%d: line longer than %d bytes", r->path, r->line, CSV_LINE_MAX - 2);
            return -1;
        }
        char *s = trim(r->buf);
        if (*s == '\0' || *s == '#')
            continue;
        memmove(r->buf, s, strlen(s) + 1);
        r->count = split(r->buf, r->fields);
        if (r->count < 0) {
            error_set(err, "%s:%d: more than %d fields", r->path, r->line, CSV_FIELDS_MAX);
            return -1;
        }
        return 1;
    }
    if (ferror(r->f)) {
        error_set(err, "%s: read failed: %s", r->path, strerror(errno));
        return -1;
    }
    return 0;
}

static int csv_open(csv_reader *r, const char *path, error_text *err)
{
    memset(r, 0, sizeof *r);
    r->path = path;
    r->f = fopen(path, "r");
    if (!r->f) {
        error_set(err, "%s: cannot open: %s", path, strerror(errno));
        return -1;
    }
    int got = csv_next(r, err);
    if (got <= 0) {
        if (got == 0)
            error_set(err, "%s: no header line (a CSV with named columns is expected)", path);
        fclose(r->f);
        return -1;
    }
    /* the header's fields, kept while the rows reuse buf */
    memcpy(r->header, r->buf, sizeof r->header);
    r->name_count = r->count;
    for (int i = 0; i < r->count; i++)
        r->names[i] = r->header + (r->fields[i] - r->buf);
    return 0;
}

/* The column's index, -1 if absent (required: an error naming it). */
static int csv_column(const csv_reader *r, const char *name, int required, error_text *err)
{
    for (int i = 0; i < r->name_count; i++)
        if (strcmp(r->names[i], name) == 0)
            return i;
    if (required)
        error_set(err, "%s: missing column \"%s\" (the header has %d columns)", r->path, name,
                  r->name_count);
    return -1;
}

/* A finite number from field `col` of the current row; empty gives *has 0
 * when allow_empty. Errors name file:line and the column. */
static int csv_number(const csv_reader *r, int col, int allow_empty, double *out, int *has,
                      error_text *err)
{
    const char *name = r->names[col];
    if (col >= r->count) {
        error_set(err, "%s:%d: %s: missing (the row has %d fields, the header %d)", r->path,
                  r->line, name, r->count, r->name_count);
        return -1;
    }
    const char *s = r->fields[col];
    if (*s == '\0' && allow_empty) {
        *has = 0;
        return 0;
    }
    char *end = NULL;
    errno = 0;
    double v = strtod(s, &end);
    if (*s == '\0' || *end != '\0' || errno == ERANGE || !isfinite(v)) {
        error_set(err, "%s:%d: %s: not a finite number (got \"%s\")", r->path, r->line, name, s);
        return -1;
    }
    *out = v;
    if (has)
        *has = 1;
    return 0;
}

/* lo < v (strict) or lo <= v, and v <= hi; the message names the field. */
static int in_range(const csv_reader *r, const char *field, double v, double lo, int lo_open,
                    double hi, error_text *err)
{
    if ((lo_open ? v > lo : v >= lo) && v <= hi)
        return 0;
    error_set(err, "%s:%d: %s: must be in %s%g, %g] (got %g)", r->path, r->line, field,
              lo_open ? "(" : "[", lo, hi, v);
    return -1;
}

static int grow(void **rows, int count, int *cap, size_t size, error_text *err)
{
    if (count < *cap)
        return 0;
    int next = *cap ? 2 * *cap : 32;
    void *p = realloc(*rows, (size_t)next * size);
    if (!p) {
        error_set(err, "out of memory");
        return -1;
    }
    *rows = p;
    *cap = next;
    return 0;
}

int cal_read_plates(const char *path, cal_plate_row **rows, error_text *err)
{
    *rows = NULL;
    csv_reader r;
    if (csv_open(&r, path, err) != 0)
        return -1;
    int cb = csv_column(&r, "width_m", 1, err),
        cp = cb < 0 ? -1 : csv_column(&r, "pressure_pa", 1, err);
    int cz = cp < 0 ? -1 : csv_column(&r, "sinkage_m", 1, err);
    int count = 0, cap = 0, got = 0;
    cal_plate_row *out = NULL;
    while (cz >= 0 && (got = csv_next(&r, err)) == 1) {
        if (count == CSV_ROWS_MAX) {
            error_set(err, "%s:%d: more than %d rows", path, r.line, CSV_ROWS_MAX);
            got = -1;
            break;
        }
        if (grow((void **)&out, count, &cap, sizeof *out, err) != 0) {
            got = -1;
            break;
        }
        cal_plate_row *row = &out[count];
        row->line = r.line;
        if (csv_number(&r, cb, 0, &row->width_m, NULL, err) ||
            in_range(&r, "width_m", row->width_m, 0, 1, 100, err) ||
            csv_number(&r, cp, 0, &row->pressure_pa, NULL, err) ||
            in_range(&r, "pressure_pa", row->pressure_pa, 0, 1, 1e10, err) ||
            csv_number(&r, cz, 0, &row->sinkage_m, NULL, err) ||
            in_range(&r, "sinkage_m", row->sinkage_m, 0, 1, 10, err)) {
            got = -1;
            break;
        }
        count++;
    }
    fclose(r.f);
    if (cz < 0 || got < 0) {
        free(out);
        return -1;
    }
    *rows = out;
    return count;
}

/* A row's lugs: grouser_count, grouser_height_m and grouser_thickness_m where the file
 * has them (col[0..2]), else --grousers's; a count of 0 is a smooth rim whatever the
 * rest says. The sizes against the rim are the testbed's (collider_geometry_validate). */
static int wheel_grousers(const csv_reader *r, const int *col, const cal_wheel_defaults *d,
                          cal_wheel_row *row, error_text *err)
{
    double v[3] = {d->grousers.count, d->grousers.height, d->grousers.thickness};
    const char *names[3] = {"grouser_count", "grouser_height_m", "grouser_thickness_m"};
    const double hi[3] = {COLLIDER_GROUSERS_MAX, 1, 1};
    for (int k = 0; k < 3; k++)
        if (col[k] >= 0 && (csv_number(r, col[k], 0, &v[k], NULL, err) ||
                            in_range(r, names[k], v[k], 0, 0, hi[k], err)))
            return -1;
    if (v[0] != floor(v[0])) {
        error_set(err, "%s:%d: grouser_count: must be a whole number (got %g)", r->path, r->line,
                  v[0]);
        return -1;
    }
    row->grousers = (collider_grousers){(int)v[0], v[1], v[2]};
    if (row->grousers.count == 0) {
        row->grousers = (collider_grousers){0};
        return 0;
    }
    for (int k = 1; k < 3; k++)
        if (!(v[k] > 0)) {
            error_set(err,
                      "%s:%d: %s: a lugged row (grouser_count %d) needs it > 0 (a column, or "
                      "--grousers)",
                      r->path, r->line, names[k], row->grousers.count);
            return -1;
        }
    return 0;
}

/* Rows must be numbered; the where filter compares text. */
static int wheel_row(const csv_reader *r, const int *col, const cal_wheel_defaults *d,
                     cal_wheel_row *row, error_text *err)
{
    const char *names[3] = {"radius_m", "width_m", "load_n"};
    double fallback[3] = {d->radius_m, d->width_m, d->load_n},
           *dest[3] = {&row->radius_m, &row->width_m, &row->load_n};
    const double hi[3] = {10, 10, 1e7};
    for (int k = 0; k < 3; k++) {
        if (col[k] >= 0) {
            if (csv_number(r, col[k], 0, dest[k], NULL, err))
                return -1;
        } else
            *dest[k] = fallback[k];
        if (in_range(r, names[k], *dest[k], 0, 1, hi[k], err))
            return -1;
    }
    if (csv_number(r, col[3], 0, &row->slip, NULL, err) ||
        in_range(r, "slip", row->slip, 0, 0, 0.95, err))
        return -1;
    cal_measure *m[3] = {&row->pull_n, &row->sinkage_m, &row->torque_nm};
    for (int k = 0; k < 3; k++)
        if (col[4 + k] >= 0 && csv_number(r, col[4 + k], 1, &m[k]->value, &m[k]->has, err) != 0)
            return -1;
    if (row->sinkage_m.has && in_range(r, "sinkage_m", row->sinkage_m.value, 0, 1, 10, err))
        return -1;
    if (wheel_grousers(r, col + 8, d, row, err) != 0)
        return -1;
    if (!row->pull_n.has && !row->sinkage_m.has && !row->torque_nm.has) {
        error_set(err, "%s:%d: drawbar_pull_n, sinkage_m, torque_nm: all empty (nothing to fit)",
                  r->path, r->line);
        return -1;
    }
    return 0;
}

/* The wheel columns, in wheel_row's order; a missing radius/width/load needs its option. */
static int wheel_columns(const csv_reader *r, const cal_wheel_defaults *d, int *col,
                         error_text *err)
{
    const char *names[7] = {"radius_m",       "width_m",   "load_n",   "slip",
                            "drawbar_pull_n", "sinkage_m", "torque_nm"};
    const char *options[3] = {"--radius", "--width", "--load"};
    double given[3] = {d->radius_m, d->width_m, d->load_n};
    for (int k = 0; k < 7; k++)
        col[k] = csv_column(r, names[k], 0, err);
    for (int k = 0; k < 3; k++)
        if (col[k] < 0 && !(given[k] > 0)) {
            error_set(err, "%s: missing column \"%s\" (or give %s)", r->path, names[k], options[k]);
            return -1;
        }
    if (col[3] < 0) {
        error_set(err, "%s: missing column \"slip\"", r->path);
        return -1;
    }
    if (col[4] < 0 && col[5] < 0 && col[6] < 0) {
        error_set(err,
                  "%s: missing column \"drawbar_pull_n\", \"sinkage_m\" or \"torque_nm\" "
                  "(at least one is measured)",
                  r->path);
        return -1;
    }
    const char *lugs[3] = {"grouser_count", "grouser_height_m", "grouser_thickness_m"};
    for (int k = 0; k < 3; k++)
        col[8 + k] = csv_column(r, lugs[k], 0, err);
    col[7] = -1;
    if (d->where_column) {
        col[7] = csv_column(r, d->where_column, 0, err);
        if (col[7] < 0) {
            error_set(err, "%s: --where: no column \"%s\"", r->path, d->where_column);
            return -1;
        }
    }
    return 0;
}

int cal_read_wheel(const char *path, const cal_wheel_defaults *d, cal_wheel_row **rows,
                   error_text *err)
{
    *rows = NULL;
    csv_reader r;
    if (csv_open(&r, path, err) != 0)
        return -1;
    int col[11];
    int ok = wheel_columns(&r, d, col, err) == 0;
    int count = 0, cap = 0, got = 0;
    cal_wheel_row *out = NULL;
    while (ok && (got = csv_next(&r, err)) == 1) {
        if (col[7] >= 0 && (col[7] >= r.count || strcmp(r.fields[col[7]], d->where_value) != 0))
            continue;
        if (count == CSV_ROWS_MAX || grow((void **)&out, count, &cap, sizeof *out, err) != 0) {
            if (count == CSV_ROWS_MAX)
                error_set(err, "%s:%d: more than %d rows", path, r.line, CSV_ROWS_MAX);
            got = -1;
            break;
        }
        memset(&out[count], 0, sizeof out[count]);
        out[count].line = r.line;
        if (wheel_row(&r, col, d, &out[count], err) != 0) {
            got = -1;
            break;
        }
        count++;
    }
    fclose(r.f);
    if (ok && got == 0 && count < 2) {
        error_set(err, "%s: %d wheel row%s%s (at least 2 are needed to fit)", path, count,
                  count == 1 ? "" : "s", d->where_column ? " after --where" : "");
        got = -1;
    }
    if (!ok || got < 0) {
        free(out);
        return -1;
    }
    *rows = out;
    return count;
}

/* ---- The plate fit ---- */

#define WIDTHS_MAX 64

void cal_plate_fit_free(cal_plate_fit *fit)
{
    free(fit->pressure_rel);
    free(fit->sinkage_rel);
    fit->pressure_rel = fit->sinkage_rel = NULL;
}

/* Distinct widths in first-seen order; rows per width; -1 if too many. */
static int plate_widths(const cal_plate_row *rows, int count, double *widths, int *per, int *group)
{
    int g = 0;
    for (int i = 0; i < count; i++) {
        int k = 0;
        while (k < g && widths[k] != rows[i].width_m)
            k++;
        if (k == g) {
            if (g == WIDTHS_MAX)
                return -1;
            widths[g] = rows[i].width_m;
            per[g++] = 0;
        }
        per[k]++;
        group[i] = k;
    }
    return g;
}

int cal_fit_plates(const cal_plate_row *rows, int count, const char *path, cal_plate_fit *fit,
                   error_text *err)
{
    memset(fit, 0, sizeof *fit);
    double widths[WIDTHS_MAX], mx[WIDTHS_MAX] = {0}, my[WIDTHS_MAX] = {0}, k[WIDTHS_MAX];
    int per[WIDTHS_MAX], *group = malloc(sizeof(int) * (size_t)(count > 0 ? count : 1));
    if (!group) {
        error_set(err, "out of memory");
        return -1;
    }
    int g = plate_widths(rows, count, widths, per, group);
    int enough = g >= 2;
    for (int j = 0; j < g && enough; j++)
        enough = per[j] >= 2;
    if (!enough) {
        error_set(err,
                  "%s: width_m: %d width%s with %s (at least 2 widths of at least 2 rows "
                  "each give n, kc and kphi; at most %d widths)",
                  path, g < 0 ? WIDTHS_MAX + 1 : g, g == 1 ? "" : "s",
                  g >= 2 ? "a width of one row" : "the rows", WIDTHS_MAX);
        free(group);
        return -1;
    }
    /* 1. ln p = ln k_b + n ln z: one slope, an intercept per width */
    for (int i = 0; i < count; i++) {
        mx[group[i]] += log(rows[i].sinkage_m) / per[group[i]];
        my[group[i]] += log(rows[i].pressure_pa) / per[group[i]];
    }
    double sxy = 0, sxx = 0;
    for (int i = 0; i < count; i++) {
        double dx = log(rows[i].sinkage_m) - mx[group[i]];
        sxy += dx * (log(rows[i].pressure_pa) - my[group[i]]);
        sxx += dx * dx;
    }
    if (!(sxx > 0)) {
        error_set(err, "%s: sinkage_m: every width's rows have one sinkage (n cannot be fitted)",
                  path);
        free(group);
        return -1;
    }
    fit->n = sxy / sxx;
    fit->widths = g;
    /* 2. k_b = kc u + kphi, u = 1/b, over the widths */
    double mu = 0, mk = 0, suu = 0, suk = 0;
    for (int j = 0; j < g; j++) {
        k[j] = exp(my[j] - fit->n * mx[j]);
        mu += 1.0 / widths[j] / g;
        mk += k[j] / g;
    }
    for (int j = 0; j < g; j++) {
        suu += (1.0 / widths[j] - mu) * (1.0 / widths[j] - mu);
        suk += (1.0 / widths[j] - mu) * (k[j] - mk);
    }
    fit->kc = suk / suu;
    fit->kphi = mk - fit->kc * mu;
    if (fit->kc < 0) { /* k falls with narrower plates: no cohesive share */
        fit->kc = 0;
        fit->kphi = mk;
        fit->clamped = 1;
    } else if (fit->kphi < 0) { /* through the origin */
        double su2 = 0, sk = 0;
        for (int j = 0; j < g; j++) {
            su2 += 1.0 / (widths[j] * widths[j]);
            sk += k[j] / widths[j];
        }
        fit->kc = sk / su2;
        fit->kphi = 0;
        fit->clamped = 1;
    }
    free(group);
    if (!(fit->n > 0 && fit->n <= 3)) {
        error_set(err,
                  "%s: the fit gives n = %g, outside (0, 3]: pressure must grow with "
                  "sinkage as a power of it",
                  path, fit->n);
        return -1;
    }
    fit->pressure_rel = malloc(sizeof(double) * (size_t)count);
    fit->sinkage_rel = malloc(sizeof(double) * (size_t)count);
    if (!fit->pressure_rel || !fit->sinkage_rel) {
        cal_plate_fit_free(fit);
        error_set(err, "out of memory");
        return -1;
    }
    for (int i = 0; i < count; i++) {
        double kb = fit->kc / rows[i].width_m + fit->kphi;
        double p = kb * pow(rows[i].sinkage_m, fit->n);
        double z = pow(rows[i].pressure_pa / kb, 1.0 / fit->n);
        fit->pressure_rel[i] = (p - rows[i].pressure_pa) / rows[i].pressure_pa;
        fit->sinkage_rel[i] = (z - rows[i].sinkage_m) / rows[i].sinkage_m;
    }
    return 0;
}
