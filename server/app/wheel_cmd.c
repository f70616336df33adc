/*
 * wheel_cmd.c: `terrad wheel` — the single-wheel testbed from the command
 * line (docs/calibrate.md, "Running the testbed"). A soil (a preset, or a
 * material JSON file as `terrad calibrate --out` writes it), a rigid wheel
 * (radius, width, vertical load) and a list of slips go through
 * sim_wheel_testbed (sim/sim_testbed.c), the very run `terrad calibrate` makes
 * for every measured row and the Ding 2011 validation test makes for its
 * table; out come the drawbar pull, sinkage and driving torque per slip, as
 * CSV (the columns `terrad calibrate --wheel` reads, so a run can be fed back
 * to it) or JSON. Offline: no daemon, no world, no tick. Every number is
 * printed so that it reads back to the same double: the figures are the
 * testbed's exactly, the same on every run.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"

#define WHEEL_SLIPS_MAX 100
/* the slips a testbed run takes, as `terrad calibrate --wheel`'s rows */
#define WHEEL_SLIP_MAX 0.95

typedef struct wheel_options {
    const char *soil_arg;
    sim_soil soil;
    double compression; /* NAN: not given (then the file's, or 0.5) */
    int json;
    sim_wheel_run run; /* radius, width, load (NAN: not given; required) and the testbed's cell,
                          distance, speed, tick */
    double slips[WHEEL_SLIPS_MAX];
    int slip_count;
} wheel_options;

static int parse_slips(void *ctx, const char *list, error_text *err)
{
    wheel_options *o = ctx;
    o->slip_count = 0;
    const char *p = list;
    for (;;) {
        char *end;
        double s = strtod(p, &end);
        if (end == p || (*end && *end != ',') || !isfinite(s) || s < 0 || s > WHEEL_SLIP_MAX) {
            error_set(err, "\"%.*s\": each slip must be a number in [0, %g]", (int)strcspn(p, ","),
                      p, WHEEL_SLIP_MAX);
            return -1;
        }
        if (o->slip_count == WHEEL_SLIPS_MAX) {
            error_set(err, "at most %d slips", WHEEL_SLIPS_MAX);
            return -1;
        }
        o->slips[o->slip_count++] = s;
        if (!*end)
            return 0;
        p = end + 1;
    }
}

int app_parse_grousers(const char *v, collider_grousers *g, error_text *err)
{
    double f[3];
    const char *p = v;
    for (int k = 0; k < 3; k++) {
        char *end;
        f[k] = strtod(p, &end);
        if (end == p || !isfinite(f[k]) || (k < 2 ? *end != ',' : *end != '\0')) {
            error_set(err, "\"%s\": must be COUNT,HEIGHT,THICKNESS (e.g. 30,0.01,0.004)", v);
            return -1;
        }
        p = end + 1;
    }
    if (!(f[0] >= 1 && f[0] <= COLLIDER_GROUSERS_MAX && f[0] == floor(f[0])) || !(f[1] > 0) ||
        !(f[2] > 0)) {
        error_set(err,
                  "\"%s\": the count must be a whole number 1..%d, the height and the thickness "
                  "> 0 m",
                  v, COLLIDER_GROUSERS_MAX);
        return -1;
    }
    *g = (collider_grousers){(int)f[0], f[1], f[2]};
    return 0;
}

static int format_option(void *ctx, const char *v, error_text *err)
{
    if (strcmp(v, "csv") != 0 && strcmp(v, "json") != 0) {
        error_set(err, "must be csv or json (got \"%s\")", v);
        return -1;
    }
    ((wheel_options *)ctx)->json = strcmp(v, "json") == 0;
    return 0;
}

static int grousers_option(void *ctx, const char *v, error_text *err)
{
    return app_parse_grousers(v, &((wheel_options *)ctx)->run.grousers, err);
}

static const cli_option wheel_table[] = {
    {"soil", "PRESET|FILE",
     "the soil: a preset of docs/models.md (an unknown name lists them)\n"
     "or a material JSON file (a scene's \"material\" of the bekker model,\n"
     "as terrad calibrate --out writes it)",
     CLI_AT_STRING(wheel_options, soil_arg)},
    APP_OPTIONS_WHEEL(wheel_options, run, grousers_option),
    {"slips", "LIST",
     "the slips to run, comma-separated, each in [0, 0.95]\n"
     "(s = 1 - v / (omega R); at most 100)",
     CLI_CALLS(parse_slips)},
    {"format", "csv|json",
     "csv (default: slip,drawbar_pull_n,sinkage_m,torque_nm,radius_m,\n"
     "width_m,load_n - what terrad calibrate --wheel reads) or json",
     CLI_CALLS(format_option)},
    APP_OPTIONS_TESTBED(wheel_options, run, "--soil"),
    {"speed", "M/S", "the wheel's forward speed (default 0.05)",
     CLI_AT_DOUBLE(wheel_options, run.speed_m_s, 1e-3, 10)},
    {"tick", "S", "the testbed's time step (default 0.05)",
     CLI_AT_DOUBLE(wheel_options, run.tick_s, 1e-4, 1)},
    {0},
};

static const char wheel_usage[] =
    "--soil PRESET|FILE --radius M --width M --load N --slips LIST [options]";

void app_wheel_usage(FILE *f)
{
    cli_print_help(f, "wheel", wheel_usage, wheel_table);
}

int app_soil_load(const char *arg, const char *option, double cell_m, sim_soil *soil,
                  double *compression, error_text *err)
{
    *compression = 0.5;
    if (sim_soil_preset(arg, soil) == 0)
        return 0;
    sim_material m;
    /* read for the bin's cells and height quantum (sim_testbed.c's 0.1 mm) */
    if (scene_material_load_file(arg, cell_m, 10000, &m, err) != 0) {
        char prefix[256];
        snprintf(prefix, sizeof prefix,
                 "%s: not a preset (" SIM_SOIL_PRESET_LIST ") nor a material file", option);
        error_prefix(err, prefix, ": ");
        return -1;
    }
    if (m.model != SIM_MODEL_BEKKER) {
        error_set(err,
                  "%s: %s: material.model must be \"bekker\" (got \"%s\"): only the "
                  "bekker model has a soil to run a wheel on",
                  option, arg, sim_model_name(m.model));
        return -1;
    }
    *soil = m.soil;
    *compression = m.compression;
    return 0;
}

/* --soil: a preset name, else a material file of the bekker model. */
static int wheel_soil(wheel_options *o, error_text *err)
{
    double compression;
    if (app_soil_load(o->soil_arg, "--soil", o->run.cell_m, &o->soil, &compression, err) != 0)
        return -1;
    if (isnan(o->compression))
        o->compression = compression;
    o->run.compression = o->compression;
    return 0;
}

/* The shortest decimal that reads back to the same double (cJSON's rule). */
static void exact(FILE *f, double v)
{
    char buf[32];
    snprintf(buf, sizeof buf, "%.15g", v);
    if (strtod(buf, NULL) != v)
        snprintf(buf, sizeof buf, "%.17g", v);
    fputs(buf, f);
}

static void print_csv(const wheel_options *o, const sim_wheel_result *r)
{
    /* a lugged wheel's three columns, as terrad calibrate --wheel reads them */
    const collider_grousers *g = &o->run.grousers;
    int cols = g->count > 0 ? 10 : 7;
    printf("slip,drawbar_pull_n,sinkage_m,torque_nm,radius_m,width_m,load_n%s\n",
           cols > 7 ? ",grouser_count,grouser_height_m,grouser_thickness_m" : "");
    for (int i = 0; i < o->slip_count; i++) {
        double row[10] = {o->slips[i],     r[i].drawbar_pull_n, r[i].sinkage_m, r[i].torque_nm,
                          o->run.radius_m, o->run.width_m,      o->run.load_n,  g->count,
                          g->height,       g->thickness};
        for (int k = 0; k < cols; k++) {
            if (k)
                putchar(',');
            exact(stdout, row[k]);
        }
        putchar('\n');
    }
}

/* text, then v exactly */
static void put(const char *text, double v)
{
    fputs(text, stdout);
    exact(stdout, v);
}

/* JSON by hand: cJSON prints 15 digits whenever they come within an epsilon
 * of the value, and these figures are promised exactly. */
static void print_json(const wheel_options *o, const sim_wheel_result *r)
{
    const sim_soil *s = &o->soil;
    const char *names[10] = {
        "n",         "kc",           "kphi",           "cohesion_pa", "friction_deg",
        "shear_k_m", "elastic_pa_m", "damping_pa_s_m", "slip_n",      "density_kg_m3"};
    double values[10] = {
        s->n,         s->kc,           s->kphi,           s->cohesion_pa, s->friction_deg,
        s->shear_k_m, s->elastic_pa_m, s->damping_pa_s_m, s->slip_n,      s->density_kg_m3};
    /* the one string: escaped by cJSON */
    char *quoted = json_print_delete(cJSON_CreateString(o->soil_arg));
    printf("{\"soil_source\": %s, \"soil\": {", quoted ? quoted : "null");
    free(quoted);
    for (int k = 0; k < 10; k++) {
        printf("%s\"%s\": ", k ? ", " : "", names[k]);
        exact(stdout, values[k]);
    }
    put("},\n \"compression\": ", o->compression);
    put(",\n \"wheel\": {\"radius_m\": ", o->run.radius_m);
    put(", \"width_m\": ", o->run.width_m);
    put(", \"load_n\": ", o->run.load_n);
    if (o->run.grousers.count > 0) {
        printf(", \"grousers\": {\"count\": %d", o->run.grousers.count);
        put(", \"height\": ", o->run.grousers.height);
        put(", \"thickness\": ", o->run.grousers.thickness);
        printf("}");
    }
    put("},\n \"testbed\": {\"cell_m\": ", o->run.cell_m);
    put(", \"distance_m\": ", o->run.distance_m);
    put(", \"speed_m_s\": ", o->run.speed_m_s);
    put(", \"tick_s\": ", o->run.tick_s);
    printf(", \"ticks\": %ld},\n \"runs\": [", o->slip_count ? r[0].ticks : 0L);
    for (int i = 0; i < o->slip_count; i++) {
        put(i ? ",\n  {\"slip\": " : "\n  {\"slip\": ", o->slips[i]);
        put(", \"drawbar_pull_n\": ", r[i].drawbar_pull_n);
        put(", \"sinkage_m\": ", r[i].sinkage_m);
        put(", \"torque_nm\": ", r[i].torque_nm);
        printf("}");
    }
    printf("]}\n");
}

int app_wheel(int argc, char **argv)
{
    wheel_options o;
    memset(&o, 0, sizeof o);
    sim_wheel_run_defaults(&o.run);
    o.run.radius_m = o.run.width_m = o.run.load_n = o.compression = NAN;
    cli_result r = cli_parse("wheel", wheel_usage, wheel_table, argc, argv, &o, NULL);
    if (r != CLI_OK)
        return r == CLI_HELP ? 0 : 2;
    const char *missing = !o.soil_arg             ? "--soil"
                          : isnan(o.run.radius_m) ? "--radius"
                          : isnan(o.run.width_m)  ? "--width"
                          : isnan(o.run.load_n)   ? "--load"
                          : !o.slip_count         ? "--slips"
                                                  : NULL;
    error_text err;
    if (missing) {
        fprintf(stderr, "terrad wheel: %s is required (see terrad wheel --help)\n", missing);
        return 2;
    }
    if (wheel_soil(&o, &err) != 0) {
        fprintf(stderr, "terrad wheel: %s\n", err.message);
        return 2;
    }
    sim_wheel_result *out = calloc((size_t)o.slip_count, sizeof *out);
    if (!out) {
        fprintf(stderr, "terrad wheel: out of memory\n");
        return 1;
    }
    for (int i = 0; i < o.slip_count; i++) {
        sim_wheel_run run = o.run;
        run.slip = o.slips[i];
        if (sim_wheel_testbed(&o.soil, &run, &out[i], &err) != 0) {
            fprintf(stderr, "terrad wheel: slip %g: %s\n", o.slips[i], err.message);
            free(out);
            return 1;
        }
    }
    if (o.json)
        print_json(&o, out);
    else
        print_csv(&o, out);
    free(out);
    if (fflush(stdout) != 0 || ferror(stdout)) {
        fprintf(stderr, "terrad wheel: cannot write the results\n");
        return 1;
    }
    return 0;
}
