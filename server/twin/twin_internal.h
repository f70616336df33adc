/*
 * twin_internal.h: what twin.c (the twin) lends twin_predict.c (prediction
 * over it) inside the twin library; not installed, not exported.
 */
#ifndef TWIN_INTERNAL_H
#define TWIN_INTERNAL_H

#include "twin/terrad_twin.h"

/* -1, with the sentence in err (TERRAD_TWIN_ERROR_MAX bytes; err may be NULL). */
int twin_fail(char *err, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
/* The config's ticks per second (tick_hz). */
double twin_config_tick_hz(const terrad_twin_config *c);
/* The collider keeps its place in the tick's order but has no pose any more:
 * it presses again once it gets one (unswept), as a new collider would. */
int twin_unpose(terrad_twin *t, int id, char *err);

/* The window's per-cell state beside its heights (world/ layers: bekker's
 * soil, the compaction memory), every layer's fields in world_layer_id
 * order: how many int32 values, and a copy out of or into the twin. A
 * prediction restarts from the server's heights with the state its replay
 * reached, as it does the heights. write: 0, or -1 out of memory. */
int64_t twin_state_values(const terrad_twin *t);
void twin_state_read(const terrad_twin *t, int32_t *out);
int twin_state_write(terrad_twin *t, const int32_t *in);
/* The window may hold such state: a bekker world, or a layer enabled (the
 * compaction memory, at creation). 0: heights are all there is to restart. */
int twin_keeps_state(const terrad_twin *t);
/* The collider's pose height (m): a load-driven one's is where the last tick
 * found the soil carries it. -1 when it has no pose. */
int twin_pose_z(const terrad_twin *t, int id, double *z);

#endif /* TWIN_INTERNAL_H */
