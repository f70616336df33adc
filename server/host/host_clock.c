/*
 * host_clock.c: the wall clock, the one backend of host/'s clock seam today
 * (host.h, host_clock): a world's ticks are due at its scene's tick_hz on
 * time_now_ms's clock, the first at once. A world that fell behind (a tick
 * longer than its period, or a worker that came late) is due now: the
 * backlog is dropped and the rate kept, as the daemon's loop always did, so
 * a slow tick never turns into a burst of ticks back to back. The ticker
 * (host_ticker.c) asks the clock after every tick. The client clock (below)
 * is the other backend: a client-clocked world ticks when its driver steps it.
 */
#include <pthread.h>

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

/* ---- the client clock (a client-clocked world, PROTOCOL.md "STEP") ----
 * Its ticks are due only while its driver's steps owe some: the net thread
 * adds each accepted step's ticks to m->clock_owed (client_step, hub's step
 * notify) and wakes the job; the ticker asks due_ms after each tick with the
 * ticks run so far, so the world runs exactly the ticks asked for, back to
 * back, then waits (HOST_CLOCK_NEVER) for the next step however long it takes.
 * No wall-clock time decides anything of a tick's content; only when. */

static double client_due_ms(void *ctx, long tick, double period_ms, double last_due_ms,
                            double now_ms)
{
    (void)period_ms;
    (void)last_due_ms;
    (void)tick; /* the job's count includes the passes that only served reads */
    host_sim *m = ctx;
    return host_sim_tick_owed(m) || hub_reads_pending(m->h) ? now_ms : HOST_CLOCK_NEVER;
}

host_clock host_clock_client(host_sim *m)
{
    return (host_clock){.name = "client", .due_ms = client_due_ms, .ctx = m};
}

/* A step reached the hub (net thread): its ticks are owed, the world is no
 * longer waiting (the watchdog's clock runs from now), its job is woken. */
static void client_step(void *arg, uint32_t ticks)
{
    host_sim *m = arg;
    if (ticks > 0) {
        atomic_fetch_add(&m->clock_owed, (long long)ticks);
        http_status *s = &m->status;
        pthread_mutex_lock(&s->lock);
        s->waiting = 0;
        s->published_ms = time_now_ms();
        pthread_mutex_unlock(&s->lock);
    }
    if (m->clock_ticker) /* a step, or a height read (ticks 0) */
        host_ticker_wake(m->clock_ticker, m->clock_job);
}

int host_clock_client_attach(host_sim *m, host_ticker *t, host_job *j)
{
    if (!m->sc.client_clock)
        return 0;
    m->clock_ticker = t;
    m->clock_job = j;
    hub_set_step_notify(m->h, client_step, m);
    return 0;
}

int host_sim_tick_owed(host_sim *m)
{
    return atomic_load(&m->clock_owed) > atomic_load(&m->clock_ran);
}
