/*
 * main.c: terrad's entry point — dispatches to a command (see app/).
 */
#include <stdio.h>
#include <string.h>

#include "app/app.h"

void app_print_help(void)
{
    printf("terrad: a terrain deformation service (volume-preserving, headless OpenGL)\n"
           "\n"
           "usage:\n"
           "  terrad serve [options]        run the daemon (the default command)\n"
           "  terrad simulate [options]     run a scene offline and print a JSON report\n"
           "  terrad export [options]       write a data directory's world (or a region)\n"
           "  terrad bench --trade [...]    the speed/accuracy sweep (terrad bench --help)\n"
           "  terrad world add NAME --scene FILE | list | remove NAME  [--cluster URLS]\n"
           "                                the cluster's worlds (docs/cluster.md)\n"
           "  terrad --help | --version\n"
           "\n"
           "serve options:\n"
           "  --config FILE       JSON file with any of the options below (keys without the\n"
           "                      dashes, '_' for '-') and \"limits\": {...} with the names of\n"
           "                      proto/PROTOCOL.md's limits; later flags override it\n"
           "  --scene FILE        scene JSON (default: the embedded default scene)\n"
           "  --backend gl|cpu    deformation backend (default gl: EGL, no window)\n"
           "  --http-port N       HTTP port: /healthz /readyz /metrics /v1/world /v1/stats\n"
           "                      /v1/heights and the viewer at / (default 8080; 0: any free)\n"
           "  --ws-port N         websocket port, subprotocol terrad.v1 (default 8081; 0: any)\n"
           "  --bind-any          listen on all interfaces (default: 127.0.0.1 only)\n"
           "  --token T           clients must send this token in hello (default: none)\n"
           "  --tick-hz N         tick rate, 1..1000 (default: the scene's, normally 60)\n"
           "  --demo-actors N     built-in spheres sliding over the terrain (default 6)\n"
           "  --no-demo           no demo actors\n"
           "  --ticks N           stop after N ticks (default: run until SIGINT/SIGTERM)\n"
           "  --data DIR          data directory: tile snapshots + write-ahead log, recovered\n"
           "                      at start (default ./data; docs/storage.md)\n"
           "  --no-data           keep the terrain in memory only\n"
           "  --durability P      every-tick (default: fdatasync before a tick is published),\n"
           "                      group:MS (one fdatasync per MS ms; ticks held until it) or\n"
           "                      none (written before publish, never synced)\n"
           "  --wal-segment-bytes N  compact the log into tile snapshots past N bytes (16 MiB)\n"
           "  --store-fault FILE  test hook: storage writes fail ENOSPC while FILE exists\n"
           "                      (also TERRAD_STORE_FAULT)\n"
           "\n"
           "export options:\n"
           "  --data DIR          data directory (default ./data); read only, never repaired\n"
           "  --scene FILE        the scene the daemon ran (default: the embedded scene)\n"
           "  --out FILE          output file (required)\n"
           "  --format F          raw32 (little-endian int32, row-major; default) or png16\n"
           "                      (height = value * scale + offset, written to FILE.json)\n"
           "  --region x,y,w,h    a region in cells (default: the whole world)\n"
           "  --tick T            the world as of tick T (default: the last logged tick)\n"
           "\n"
           "simulate options:\n"
           "  --scene FILE        scene JSON with scripted colliders (default: embedded scene)\n"
           "  --ticks N           number of ticks to run (required)\n"
           "  --backend gl|cpu    default gl\n"
           "  --method M          iterative | ssbo | multi (overrides the scene's material)\n"
           "  --model M           persson-iterative | persson-ssbo | persson-multi | subtract |\n"
           "                      deferred | diffusion | decals (overrides the scene's model)\n"
           "  --metric K          euclidean | manhattan | chebyshev (overrides the scene's)\n"
           "  --out FILE          write the final heights: little-endian int32, row-major\n"
           "  --depth-from-cpu    feed the CPU twin's analytic depth to the backend, so the\n"
           "                      gl and cpu backends can be compared bit for bit\n"
           "\n"
           "environment:\n"
           "  TERRAD_EGL_PLATFORM=device|surfaceless   force an EGL platform\n");
}

int main(int argc, char **argv)
{
    const char *command = argc > 1 ? argv[1] : "serve";
    if (strcmp(command, "--help") == 0 || strcmp(command, "-h") == 0 ||
        strcmp(command, "help") == 0) {
        app_print_help();
        return 0;
    }
    if (strcmp(command, "--version") == 0) {
        printf("terrad 0.1.0\n");
        return 0;
    }
    if (strcmp(command, "simulate") == 0)
        return app_simulate(argc - 2, argv + 2);
    if (strcmp(command, "bench") == 0)
        return app_bench(argc - 2, argv + 2);
    if (strcmp(command, "serve") == 0)
        return app_serve(argc - 2, argv + 2);
    if (strcmp(command, "export") == 0)
        return app_export(argc - 2, argv + 2);
    if (strcmp(command, "world") == 0)
        return app_world(argc - 2, argv + 2);
    if (command[0] == '-') /* options without a command: serve */
        return app_serve(argc - 1, argv + 1);
    fprintf(stderr, "terrad: unknown command \"%s\" (see terrad --help)\n", command);
    return 2;
}
