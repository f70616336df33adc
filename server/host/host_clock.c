/*
 * host_clock.c: the wall clock, the one backend of host/'s clock seam today
 * (host.h, host_clock): a world's ticks are due at its scene's tick_hz on
 * time_now_ms's clock, the first at once. A world that fell behind (a tick
 * longer than its period, or a worker that came late) is due now: the
 * backlog is dropped and the rate kept, as the daemon's loop always did, so
 * a slow tick never turns into a burst of ticks back to back. The ticker
 * (host_ticker.c) asks the clock after every tick; a client-driven clock
 * (the co-simulation issue) is another backend of the same struct.
 */
#include "host/host.h"

static double wall_due_ms(void *ctx, long tick, double period_ms, double last_due_ms, double now_ms)
{
    (void)ctx;
    if (tick == 0)
        return now_ms;
    double due = last_due_ms + period_ms;
    return due < now_ms ? now_ms : due; /* behind: drop the backlog, keep the rate */
}

const host_clock host_clock_wall = {.name = "wall", .due_ms = wall_due_ms, .ctx = NULL};
