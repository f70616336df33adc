/*
 * app: terrad's commands — `simulate` (an offline run of a scene that prints
 * one JSON report) and `serve` (the daemon: tick loop, demo actors, HTTP).
 * main.c only dispatches to these.
 */
#ifndef TERRAD_APP_H
#define TERRAD_APP_H

#include "base/base.h"
#include "ground/ground.h"
#include "scene/scene.h"
#include "sim/sim.h"

int app_simulate(int argc, char **argv);
int app_serve(int argc, char **argv);
int app_export(int argc, char **argv); /* a data directory's world to raw32 / png16 */
void app_print_help(void);

/* "gl" or "cpu". */
sim_backend *app_backend_create(const char *name, error_text *err);

/* The scene's ground into the engine. On failure nothing is held. */
int app_ground_attach(const scene *sc, const world *w, sim_engine *engine, ground *g,
                      error_text *err);

#endif
