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

#endif /* TWIN_INTERNAL_H */
