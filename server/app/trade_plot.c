/*
 * trade_plot.c: the SVG scatter plot of `terrad bench --trade` — cost
 * against error, written by hand (no plotting dependency). Two panels share
 * the error axis: mean ms per tick, and bytes per world cell (world heights
 * plus peak scratch). Both axes are logarithmic; an error of exactly 0 (the
 * reference against itself) is drawn on the bottom edge. Each model has its
 * own colour and marker shape; CPU-twin runs are filled, GL runs hollow.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/trade_internal.h"

#define PANEL_W 460.0
#define PANEL_H 360.0
#define MARGIN_L 70.0
#define MARGIN_T 70.0
#define GAP 90.0
/* The legend wraps at this many models a row: eight models in one row would
 * run past the right edge of the two panels. */
#define LEGEND_PER_ROW 4
#define LEGEND_COLUMN_W 250.0
#define LEGEND_ROW_H 22.0

static const char *const colours[] = {"#1f77b4", "#d62728", "#2ca02c", "#ff7f0e",
                                      "#9467bd", "#8c564b", "#e377c2", "#17becf"};
#define COLOUR_COUNT ((int)(sizeof colours / sizeof colours[0]))
#define SHAPE_COUNT 5

static void xml_text(FILE *f, const char *s)
{
    for (; *s; s++) {
        if (*s == '<')
            fputs("&lt;", f);
        else if (*s == '>')
            fputs("&gt;", f);
        else if (*s == '&')
            fputs("&amp;", f);
        else if (*s == '"')
            fputs("&quot;", f);
        else
            fputc(*s, f);
    }
}

/* A decade range [lo, hi] (powers of ten) covering every positive value. */
typedef struct log_axis {
    int lo, hi;
} log_axis;

static log_axis axis_for(const double *v, int n)
{
    double mn = INFINITY, mx = 0;
    for (int i = 0; i < n; i++)
        if (v[i] > 0 && isfinite(v[i])) {
            mn = fmin(mn, v[i]);
            mx = fmax(mx, v[i]);
        }
    if (!(mx > 0))
        return (log_axis){-1, 1};
    log_axis a = {(int)floor(log10(mn)), (int)ceil(log10(mx))};
    if (a.hi <= a.lo)
        a.hi = a.lo + 1;
    return a;
}

/* Position in [0, 1] along the axis; zero and below sit on the low edge. */
static double axis_frac(log_axis a, double v)
{
    if (!(v > 0))
        return 0.0;
    double t = (log10(v) - a.lo) / (double)(a.hi - a.lo);
    return fmin(fmax(t, 0.0), 1.0);
}

static void decade_label(char *buf, size_t size, int k)
{
    if (k >= -3 && k <= 5)
        snprintf(buf, size, "%g", pow(10, k));
    else
        snprintf(buf, size, "1e%d", k);
}

static void marker(FILE *f, int model, int hollow, double x, double y, const char *cls)
{
    const char *c = colours[model % COLOUR_COUNT];
    fprintf(f, "<g class=\"%s\" fill=\"%s\" stroke=\"%s\" stroke-width=\"1.5\">", cls,
            hollow ? "none" : c, c);
    const double r = 4.5;
    switch (model % SHAPE_COUNT) {
    case 0:
        fprintf(f, "<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%.1f\"/>", x, y, r);
        break;
    case 1:
        fprintf(f, "<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\"/>", x - r, y - r,
                2 * r, 2 * r);
        break;
    case 2:
        fprintf(f, "<path d=\"M%.1f %.1fL%.1f %.1fL%.1f %.1fZ\"/>", x, y - r * 1.2, x + r * 1.1,
                y + r * 0.8, x - r * 1.1, y + r * 0.8);
        break;
    case 3:
        fprintf(f, "<path d=\"M%.1f %.1fL%.1f %.1fL%.1f %.1fL%.1f %.1fZ\"/>", x, y - r * 1.3,
                x + r * 1.3, y, x, y + r * 1.3, x - r * 1.3, y);
        break;
    default:
        fprintf(f, "<path d=\"M%.1f %.1fL%.1f %.1fM%.1f %.1fL%.1f %.1f\" stroke-width=\"2.5\"/>",
                x - r, y - r, x + r, y + r, x - r, y + r, x + r, y - r);
        break;
    }
}

static void panel(FILE *f, const char *id, double x0, const char *x_label, const double *xs,
                  const double *errors_mm, const trade_row *rows, int n, log_axis ax, log_axis ay)
{
    double y0 = MARGIN_T;
    fprintf(f, "<g id=\"%s\">\n", id);
    fprintf(f,
            "<rect x=\"%.1f\" y=\"%.1f\" width=\"%.1f\" height=\"%.1f\" fill=\"none\" "
            "stroke=\"#444\"/>\n",
            x0, y0, PANEL_W, PANEL_H);
    char label[32];
    for (int k = ax.lo; k <= ax.hi; k++) {
        double x = x0 + PANEL_W * (k - ax.lo) / (double)(ax.hi - ax.lo);
        decade_label(label, sizeof label, k);
        fprintf(f,
                "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>"
                "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">%s</text>\n",
                x, y0, x, y0 + PANEL_H, x, y0 + PANEL_H + 16, label);
    }
    for (int k = ay.lo; k <= ay.hi; k++) {
        double y = y0 + PANEL_H * (1.0 - (k - ay.lo) / (double)(ay.hi - ay.lo));
        decade_label(label, sizeof label, k);
        fprintf(f,
                "<line x1=\"%.1f\" y1=\"%.1f\" x2=\"%.1f\" y2=\"%.1f\" stroke=\"#ddd\"/>"
                "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"end\">%s</text>\n",
                x0, y, x0 + PANEL_W, y, x0 - 6, y + 4, label);
    }
    fprintf(f, "<text x=\"%.1f\" y=\"%.1f\" text-anchor=\"middle\">", x0 + PANEL_W / 2,
            y0 + PANEL_H + 36);
    xml_text(f, x_label);
    fprintf(f, "</text>\n");
    fprintf(f,
            "<text transform=\"translate(%.1f %.1f) rotate(-90)\" text-anchor=\"middle\">trail "
            "cross-section RMS error vs reference (mm, log)</text>\n",
            x0 - 48, y0 + PANEL_H / 2);
    for (int i = 0; i < n; i++) {
        const trade_row *r = &rows[i];
        int model = trade_model_index(r->model);
        double x = x0 + PANEL_W * axis_frac(ax, xs[i]);
        double y = y0 + PANEL_H * (1.0 - axis_frac(ay, errors_mm[i]));
        marker(f, model < 0 ? 0 : model, strcmp(r->backend, "gl") == 0, x, y, "marker");
        fprintf(f, "<title>");
        char text[400];
        snprintf(text, sizeof text,
                 "%s %s %s %s: cell %g m, %d iterations, %.3f ms/tick, %.1f B/cell, "
                 "cross-section %.3f mm, slope excess %.2f mm, anisotropy %.3f mm",
                 r->scene, r->model, r->backend, r->role, r->cell_m, r->iterations, r->tick_ms_mean,
                 r->bytes_per_world_cell, r->cross_section_rms_m * 1e3, r->max_slope_excess_m * 1e3,
                 r->anisotropy_rms_m * 1e3);
        xml_text(f, text);
        fprintf(f, "</title></g>\n");
    }
    fprintf(f, "</g>\n");
}

int trade_plot_write(const char *path, const trade_row *rows, int row_count, const char *subtitle,
                     error_text *err)
{
    double *ms = calloc((size_t)row_count + 1, sizeof *ms);
    double *bytes = calloc((size_t)row_count + 1, sizeof *bytes);
    double *errors = calloc((size_t)row_count + 1, sizeof *errors);
    FILE *f = NULL;
    int rc = -1;
    if (!ms || !bytes || !errors) {
        error_set(err, "out of memory");
        goto out;
    }
    for (int i = 0; i < row_count; i++) {
        ms[i] = rows[i].tick_ms_mean;
        bytes[i] = rows[i].bytes_per_world_cell;
        errors[i] = rows[i].cross_section_rms_m * 1e3;
    }
    f = fopen(path, "w");
    if (!f) {
        error_set(err, "cannot write %s", path);
        goto out;
    }
    int models_present = 0;
    for (int m = 0; m < trade_model_count; m++)
        for (int i = 0; i < row_count; i++)
            if (trade_model_index(rows[i].model) == m) {
                models_present++;
                break;
            }
    int legend_rows =
        models_present > 0 ? (models_present + LEGEND_PER_ROW - 1) / LEGEND_PER_ROW : 1;
    double width = MARGIN_L + 2 * PANEL_W + GAP + 40,
           height = MARGIN_T + PANEL_H + 110 + (legend_rows - 1) * LEGEND_ROW_H;
    fprintf(f,
            "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
            "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%.0f\" height=\"%.0f\" "
            "viewBox=\"0 0 %.0f %.0f\" font-family=\"sans-serif\" font-size=\"12\">\n"
            "<rect width=\"100%%\" height=\"100%%\" fill=\"white\"/>\n",
            width, height, width, height);
    fprintf(f,
            "<text x=\"%.1f\" y=\"24\" font-size=\"16\" font-weight=\"bold\">terrad bench "
            "--trade: cost against accuracy (log axes)</text>\n",
            MARGIN_L);
    fprintf(f, "<text x=\"%.1f\" y=\"44\">", MARGIN_L);
    xml_text(f, subtitle);
    fprintf(f, "</text>\n");
    log_axis ay = axis_for(errors, row_count);
    panel(f, "panel-ms", MARGIN_L, "mean ms per tick (log)", ms, errors, rows, row_count,
          axis_for(ms, row_count), ay);
    panel(f, "panel-memory", MARGIN_L + PANEL_W + GAP,
          "bytes per world cell: heights + peak scratch (log)", bytes, errors, rows, row_count,
          axis_for(bytes, row_count), ay);
    /* legend: one entry per model that appears, then the fill convention */
    double ly = MARGIN_T + PANEL_H + 62;
    int entry = 0;
    fprintf(f, "<g id=\"legend\">\n");
    for (int m = 0; m < trade_model_count; m++) {
        int present = 0;
        for (int i = 0; i < row_count; i++)
            present |= trade_model_index(rows[i].model) == m;
        if (!present)
            continue;
        double lx = MARGIN_L + LEGEND_COLUMN_W * (entry % LEGEND_PER_ROW),
               ey = ly + LEGEND_ROW_H * (entry / LEGEND_PER_ROW);
        entry++;
        marker(f, m, 0, lx + 6, ey - 4, "legend");
        fprintf(f, "</g><text x=\"%.1f\" y=\"%.1f\">", lx + 16, ey);
        xml_text(f, trade_model_names[m]);
        fprintf(f, "</text>\n");
    }
    fprintf(f,
            "<text x=\"%.1f\" y=\"%.1f\">filled: CPU twin; hollow: GL. Error 0 (the reference "
            "itself) sits on the bottom edge. Hover a marker for its row.</text>\n",
            MARGIN_L, ly + LEGEND_ROW_H * (legend_rows - 1) + 24);
    fprintf(f, "</g>\n</svg>\n");
    if (fclose(f) != 0) {
        f = NULL;
        error_set(err, "cannot write %s", path);
        goto out;
    }
    f = NULL;
    rc = 0;
out:
    if (f)
        fclose(f);
    free(ms);
    free(bytes);
    free(errors);
    return rc;
}
