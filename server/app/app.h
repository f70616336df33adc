/*
 * app: terrad's commands — `simulate` (an offline run of a scene that prints
 * one JSON report), `serve` (the daemon: tick loop, demo actors, HTTP),
 * `export` (a data directory's world to a file), `bench --trade` (the
 * speed/accuracy sweep over models), `calibrate` (a soil fitted to
 * measurements) and `wheel` (the single-wheel testbed at chosen slips). main.c only dispatches to
 * these.
 */
#ifndef TERRAD_APP_H
#define TERRAD_APP_H

#include <stdio.h>

#include "base/base.h"
#include "ground/ground.h"
#include "scene/scene.h"
#include "sim/sim.h"

/* Each command takes its own argv: argv[0] is the command's name, the
 * options follow (base.h's cli_parse). Returns the exit status: 0, 1 (a
 * failure) or 2 (a usage error); "CMD --help" prints the command's options. */
int app_simulate(int argc, char **argv);
int app_serve(int argc, char **argv);
int app_export(int argc, char **argv);    /* a data directory's world to int32 / png16 */
int app_bench(int argc, char **argv);     /* `terrad bench --trade` (bench_trade.c) */
int app_loadgen(int argc, char **argv);   /* load generator for a running daemon (loadgen.c) */
int app_fsck(int argc, char **argv);      /* check a data directory without starting (fsck.c) */
int app_world(int argc, char **argv);     /* `terrad world add|list|remove` (world_cmd.c) */
int app_token(int argc, char **argv);     /* `terrad token add|hash`: the auth file (token_cmd.c) */
int app_calibrate(int argc, char **argv); /* soil parameters fitted to measurements (calibrate.c) */
int app_wheel(int argc, char **argv);     /* the single-wheel testbed run at slips (wheel_cmd.c) */

/* Each command's --help: its usage and its options table (the one place the
 * option texts live). `terrad --help` prints them all. */
void app_serve_usage(FILE *out);
void app_simulate_usage(FILE *out);
void app_export_usage(FILE *out);
void app_bench_usage(FILE *out);
void app_loadgen_usage(FILE *out);
void app_fsck_usage(FILE *out);
void app_world_usage(FILE *out);
void app_token_usage(FILE *out);
void app_calibrate_usage(FILE *out);
void app_wheel_usage(FILE *out);

/* The scene at scene_path (NULL: the embedded default) and its world. On
 * failure nothing is held. */
int app_open_scene_world(const char *scene_path, scene *sc, world *w, error_text *err);

/* The frame of the commands that read a data directory offline (export,
 * fsck): the scene at scene_path and its world (app_open_scene_world), run
 * on that world, then both freed. Returns run's exit status, or 1 when the
 * scene or its world cannot be made (logged). */
typedef int (*app_world_run)(void *ctx, world *w);
int app_offline_world(const char *scene_path, app_world_run run, void *ctx);

/* The --scene row of every command that reads a data directory offline
 * (export, fsck): a directory holds the world as changes over its scene's
 * base terrain, so it must be opened with the scene the daemon ran (the
 * path goes to app_open_scene_world). One row, so the commands say it alike. */
#define APP_OPTION_SCENE_RAN(type, field)                                                          \
    {                                                                                              \
        "scene", "FILE", "the scene the daemon ran (default: the embedded scene)",                 \
            CLI_AT_STRING(type, field)                                                             \
    }

/* The wheel and testbed rows of `terrad wheel` and `terrad calibrate`: the
 * same options, ranges and defaults (both start from sim_wheel_run_defaults
 * and run sim_wheel_testbed), so one copy; calibrate's apply to the rows
 * whose file lacks the column (its --wheel says so). type is the command's
 * options; wheel the path of its radius_m, width_m, load_n (and grousers,
 * which the call grousers parses); bed the path of its cell_m and
 * distance_m; soil the option naming the soil whose file's compression is
 * the default (--soil, --base). */
/* clang-format off */
#define APP_OPTIONS_WHEEL(type, wheel, grousers)                                                   \
    {"radius", "M", "the wheel's radius", CLI_AT_DOUBLE(type, wheel.radius_m, 1e-3, 10)},          \
    {"width", "M", "the wheel's width", CLI_AT_DOUBLE(type, wheel.width_m, 1e-3, 10)},             \
    {"load", "N", "the vertical load on the wheel", CLI_AT_DOUBLE(type, wheel.load_n, 1e-3, 1e7)}, \
    {"grousers", "N,H,T",                                                                          \
     "lugs on the rim: count in [1, 360], height and thickness (m,\n"                              \
     "each <= the radius); default none. The sinkage is then the tips'",                           \
     CLI_CALLS(grousers)}
#define APP_OPTIONS_TESTBED(type, bed, soil)                                                       \
    {"compression", "X",                                                                           \
     "the material's compression (default: the " soil " file's,\n"                                 \
     "or 0.5 for a preset)",                                                                       \
     CLI_AT_DOUBLE(type, compression, 0, 1)},                                                      \
    {"cell", "M", "the testbed's cell size (default 0.005; coarser is faster)",                    \
     CLI_AT_DOUBLE(type, bed.cell_m, 1e-3, 0.1)},                                                  \
    {"distance", "M", "each testbed run's travel (default 0.5; means over its second half)",       \
     CLI_AT_DOUBLE(type, bed.distance_m, 0.05, 10)}
/* clang-format on */

/* A soil given on the command line (option names it in messages): a preset
 * of docs/models.md (compression 0.5), else a material JSON file of the
 * bekker model, as `terrad calibrate --out` writes it (its soil and its
 * compression), read as a scene of cell_m cells reads its "material": the
 * same checks, errors naming the file and the field. wheel_cmd.c. */
/* "COUNT,HEIGHT,THICKNESS" (terrad wheel and calibrate --grousers) into g; the sizes
 * against the rim are collider_geometry_validate's (the testbed's). */
int app_parse_grousers(const char *v, collider_grousers *g, error_text *err);
int app_soil_load(const char *arg, const char *option, double cell_m, sim_soil *soil,
                  double *compression, error_text *err);

/* Called after each tick of app_run_scene_ticks with that tick's report and wall time. */
typedef void (*app_tick_observer)(void *ctx, long tick, const sim_tick_report *report,
                                  double tick_ms);

/*
 * The offline tick loop shared by `simulate` and `bench --trade`: ticks
 * 0..ticks-1 of the scene's scripted colliders (poses at t / tick_hz, swept
 * from the previous tick's pose) through the engine. Returns 0, or -1 with
 * err naming the tick on a backend failure.
 */
int app_run_scene_ticks(const scene *sc, sim_engine *engine, long ticks, app_tick_observer observe,
                        void *ctx, error_text *err);

#endif
