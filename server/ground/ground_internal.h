/*
 * ground_internal.h: what ground.c shares with ground_json.c — setting a
 * ground's extent, one checked material row and the finishing step. Only
 * server/ground/ includes it.
 */
#ifndef TERRAD_GROUND_INTERNAL_H
#define TERRAD_GROUND_INTERNAL_H

#include "ground/ground.h"

/* The integer row of one material with its compaction memory; `path` names
 * it in errors. */
int ground_row_checked(const ground *g, const ground_material *m, const char *path,
                       ground_material_row *row, error_text *err);
/* Zero g and set its extent and tile counts. */
void ground_base(ground *g, ground_extent w);
/* Finish: uniform flag, compaction flag and its tile directory. */
int ground_finish(ground *g, error_text *err);

#endif
