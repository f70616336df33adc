/*
 * main.c: terrad's entry point — dispatches to a command (see app/). Each
 * command parses its own options from its table (base.h's cli_parse), so
 * "terrad CMD --help" prints exactly the options CMD takes; "terrad --help"
 * prints the commands and every command's table.
 */
#include <stdio.h>
#include <string.h>

#include "app/app.h"
#include "terrad_version.h"

static void print_help(void)
{
    printf("terrad: a terrain deformation service (volume-preserving, headless OpenGL)\n"
           "\n"
           "usage:\n"
           "  terrad serve [options]        run the daemon (the default command)\n"
           "  terrad simulate [options]     run a scene offline and print a JSON report\n"
           "  terrad export [options]       write a data directory's world (or a region)\n"
           "  terrad fsck [options]         check a data directory without starting\n"
           "  terrad bench --trade [...]    the speed/accuracy sweep\n"
           "  terrad calibrate [options]    fit a soil's parameters to measured data\n"
           "  terrad wheel [options]        the single-wheel testbed at chosen slips\n"
           "  terrad loadgen [options]      drive clients against a running daemon, measure it\n"
           "  terrad world add|list|remove  the cluster's worlds (docs/cluster.md)\n"
           "  terrad token add|hash         tokens of an --auth-file (docs/security.md)\n"
           "  terrad --help | --version\n"
           "\n"
           "Options take \"--opt value\" or \"--opt=value\"; \"terrad CMD --help\" prints one\n"
           "command's options. Every command's:\n\n");
    void (*usages[])(FILE *) = {app_serve_usage, app_simulate_usage, app_export_usage,
                                app_fsck_usage,  app_bench_usage,    app_loadgen_usage,
                                app_world_usage, app_token_usage,    app_calibrate_usage,
                                app_wheel_usage};
    for (size_t i = 0; i < sizeof usages / sizeof usages[0]; i++) {
        usages[i](stdout);
        printf("\n");
    }
    printf(
        "environment:\n"
        "  TERRAD_EGL_PLATFORM=device|surfaceless   force an EGL platform\n"
        "  TERRAD_GL_TILE_CACHE=LAYERS,BUDGET_BYTES  the GL backend's tile cache (default\n"
        "                   64,4194304; 0 layers: off; docs/tiles.md)\n"
        "  TERRAD_NO_AVX2=1   the CPU stages' SSE2 baseline instead of their AVX2 forms\n"
        "                   (the same heights; for comparing them, docs/performance.md)\n"
        "  TERRAD_CLUSTER=URLS   world add|list|remove: the NATS URLs when --cluster is not\n"
        "                   given (comma-separated; default nats://127.0.0.1:4222)\n"
        "  TERRAD_TOKEN=T   loadgen's token for a daemon with --auth-file (a driver's)\n"
        "  TERRAD_STORE_FAULT=FILE   test hook, as serve --store-fault: storage writes fail\n"
        "                   with ENOSPC while FILE exists (docs/storage.md)\n"
        "  TERRAD_FAULT_STALL=FILE   test hook: while FILE exists and names \"tick\" or\n"
        "                   \"net\", that thread stalls (the watchdog's test; docs/service.md)\n");
}

int main(int argc, char **argv)
{
    const char *command = argc > 1 ? argv[1] : "serve";
    if (strcmp(command, "--help") == 0 || strcmp(command, "-h") == 0 ||
        strcmp(command, "help") == 0) {
        print_help();
        return 0;
    }
    if (strcmp(command, "--version") == 0) {
        printf("terrad %s\n", TERRAD_VERSION);
        return 0;
    }
    /* a command gets its own argv: argv[0] is its name */
    if (strcmp(command, "simulate") == 0)
        return app_simulate(argc - 1, argv + 1);
    if (strcmp(command, "bench") == 0)
        return app_bench(argc - 1, argv + 1);
    if (strcmp(command, "serve") == 0 && argc > 1)
        return app_serve(argc - 1, argv + 1);
    if (strcmp(command, "export") == 0)
        return app_export(argc - 1, argv + 1);
    if (strcmp(command, "loadgen") == 0)
        return app_loadgen(argc - 1, argv + 1);
    if (strcmp(command, "fsck") == 0)
        return app_fsck(argc - 1, argv + 1);
    if (strcmp(command, "world") == 0)
        return app_world(argc - 1, argv + 1);
    if (strcmp(command, "token") == 0)
        return app_token(argc - 1, argv + 1);
    if (strcmp(command, "calibrate") == 0)
        return app_calibrate(argc - 1, argv + 1);
    if (strcmp(command, "wheel") == 0)
        return app_wheel(argc - 1, argv + 1);
    if (argc == 1 || command[0] == '-') /* no command, or options without one: serve */
        return app_serve(argc, argv);
    fprintf(stderr, "terrad: unknown command \"%s\" (see terrad --help)\n", command);
    return 2;
}
