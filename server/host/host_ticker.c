/*
 * host_ticker.c: one shared pool of sim workers that ticks every world of
 * the process at its own rate (issue 22) — a single daemon's created worlds
 * and a cluster node's worlds alike — instead of one sim thread per world.
 *
 * Each world is a job with a due time, which its clock gives (host_clock.c:
 * the wall clock, one period after the last due time, or now when the world
 * fell behind). A free worker takes the job whose due time is earliest
 * (earliest deadline first) and runs one tick of it (host_sim_step, then the
 * owner's check), then asks the clock when the next is due. A job whose
 * clock says HOST_CLOCK_NEVER waits, taken by no worker, until
 * host_ticker_wake asks its clock again. So a heavy world delays nobody more than one tick
 * of its own: every world that is due is taken in order of how late it is,
 * and when the cores do not suffice every world slows alike.
 *
 * A world's tick is the same code on whichever worker runs it, and the
 * engine's heights do not depend on the thread that computes them (nor on
 * how many threads sim_parallel_for has), so a world on the pool is
 * bit-identical to the same world alone. Two exceptions to "any worker":
 * a world whose backend holds a GL context is pinned to one worker (the
 * context stays current on one thread, the GL backend's rule), and its end
 * runs there too. The sim thread's ownership (service, hub's sim end,
 * engine, store) moves with the tick: the worker claims it before each tick
 * (service_claim; the ticker's lock orders the hand-over).
 *
 * Why more workers than cores: a tick may wait (an fsync with
 * --durability every-tick, a JetStream commit waiting for the replicas), and
 * a worker waiting must not hold the other worlds back; workers sleep on a
 * condition variable, so the extra ones cost a stack each and no CPU.
 */
#include <errno.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "host/host.h"

#define TICKER_WORKERS_PER_CORE 2
#define TICKER_WORKERS_MIN 4
#define TICKER_WORKERS_MAX 32
#define TICKER_WORKER_STACK (256 * 1024) /* a tick's deepest call chain is far below this */

typedef struct ticker_worker {
    host_ticker *t;
    int index;
    pthread_t thread;
} ticker_worker;

struct host_ticker {
    pthread_mutex_t lock;
    pthread_cond_t wake; /* a job added, ended, or due earlier than a worker's wait */
    host_job **jobs;
    int njobs, cap;
    int stopping;
    int next_pin; /* round-robin worker for pinned (GL) jobs */
    int nworkers;
    int idle;  /* workers waiting with nothing to take */
    int cores; /* a world's tick runs serially once there are as many worlds */
    ticker_worker *workers;
};

int host_ticker_default_workers(void)
{
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    long n = (cores < 1 ? 1 : cores) * TICKER_WORKERS_PER_CORE;
    return n < TICKER_WORKERS_MIN   ? TICKER_WORKERS_MIN
           : n > TICKER_WORKERS_MAX ? TICKER_WORKERS_MAX
                                    : (int)n;
}

/* The next job this worker may run: an ending one first, else the earliest due. */
static host_job *pick(host_ticker *t, int worker)
{
    host_job *best = NULL;
    for (int i = 0; i < t->njobs; i++) {
        host_job *j = t->jobs[i];
        if (j->running || (j->pinned >= 0 && j->pinned != worker))
            continue;
        if (j->ending)
            return j;
        if (j->due_ms >= HOST_CLOCK_NEVER)
            continue; /* its clock waits for host_ticker_wake */
        if (!best || j->due_ms < best->due_ms)
            best = j;
    }
    return best;
}

static void drop(host_ticker *t, host_job *j)
{
    for (int i = 0; i < t->njobs; i++)
        if (t->jobs[i] == j) {
            t->jobs[i] = t->jobs[--t->njobs];
            return;
        }
}

static void wait_until(host_ticker *t, double due_ms)
{
    double ms = due_ms - time_now_ms();
    struct timespec ts = time_after_ms(CLOCK_MONOTONIC, ms > 1000 ? 1000 : ms);
    pthread_cond_timedwait(&t->wake, &t->lock, &ts);
}

/* One tick of j (outside the lock): its rc, why set when it is not 0. */
static int tick_once(host_job *j, int serial)
{
    host_sim *m = j->m;
    sim_thread_serial(serial);
    service_claim(m->svc); /* this worker is the world's sim thread for this tick */
    error_text err = {{0}};
    int clients = j->net ? net_server_client_count(j->net) : 0;
    if (host_sim_step(m, j->tick, clients, &err) != 0) {
        snprintf(j->why, sizeof j->why, "%s", err.message);
        return -1;
    }
    if (j->check && j->check(j->ctx, m, j->tick, j->why, sizeof j->why) != 0)
        return 1;
    return 0;
}

static void *worker_main(void *arg)
{
    ticker_worker *w = arg;
    host_ticker *t = w->t;
    pthread_mutex_lock(&t->lock);
    for (;;) {
        host_job *j = pick(t, w->index);
        if (!j) {
            if (t->stopping && t->njobs == 0)
                break;
            t->idle++;
            pthread_cond_wait(&t->wake, &t->lock);
            t->idle--;
            continue;
        }
        if (!j->ending && j->due_ms > time_now_ms()) {
            wait_until(t, j->due_ms);
            continue;
        }
        if (j->ending) {
            /* its end is the last the ticker does with it: the owner frees it after */
            drop(t, j);
            pthread_cond_broadcast(&t->wake);
            pthread_mutex_unlock(&t->lock);
            service_claim(j->m->svc); /* its end frees what the sim thread owns */
            j->end(j, j->rc);
            pthread_mutex_lock(&t->lock);
            continue;
        }
        j->running = 1;
        /* as many worlds as cores: they are the parallelism (sim_thread_serial
         * says why); a world alone (a daemon's default world, say) keeps
         * --threads' helpers, as it had on its own thread, even on one core */
        int serial = t->njobs > 1 && t->njobs >= t->cores;
        pthread_mutex_unlock(&t->lock);
        int rc = tick_once(j, serial);
        pthread_mutex_lock(&t->lock);
        j->running = 0;
        j->tick++;
        j->due_ms = j->clock.due_ms(j->clock.ctx, j->tick, j->period_ms, j->due_ms, time_now_ms());
        if (rc != 0 || (j->max_ticks >= 0 && j->tick >= j->max_ticks)) {
            j->ending = 1;
            j->rc = rc;
            pthread_cond_broadcast(&t->wake); /* a pinned job's end is its worker's */
        } else if (t->idle > 0) {
            /* a worker that found every job taken: it may take this one, or the
             * next due, while this worker runs another (one wake, not a herd) */
            pthread_cond_signal(&t->wake);
        }
    }
    pthread_mutex_unlock(&t->lock);
    return NULL;
}

host_ticker *host_ticker_start(int workers, error_text *err)
{
    host_ticker *t = calloc(1, sizeof *t);
    if (!t || !(t->workers = calloc((size_t)workers, sizeof *t->workers))) {
        free(t);
        error_set(err, "ticker: out of memory");
        return NULL;
    }
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    t->cores = cores < 1 ? 1 : (int)cores;
    pthread_mutex_init(&t->lock, NULL);
    pthread_condattr_t ca;
    pthread_condattr_init(&ca);
    pthread_condattr_setclock(&ca, CLOCK_MONOTONIC);
    pthread_cond_init(&t->wake, &ca);
    pthread_condattr_destroy(&ca);
    pthread_attr_t attr;
    pthread_attr_init(&attr);
    pthread_attr_setstacksize(&attr, TICKER_WORKER_STACK);
    for (int i = 0; i < workers; i++) {
        t->workers[i] = (ticker_worker){.t = t, .index = i};
        if (pthread_create(&t->workers[i].thread, &attr, worker_main, &t->workers[i]) != 0)
            break;
        t->nworkers++;
    }
    pthread_attr_destroy(&attr);
    if (t->nworkers == 0) {
        error_set(err, "ticker: cannot start a worker thread");
        host_ticker_stop(t);
        return NULL;
    }
    log_info("ticker: %d sim workers tick every world of this process", t->nworkers);
    return t;
}

int host_ticker_add(host_ticker *t, host_job *j, error_text *err)
{
    pthread_mutex_lock(&t->lock);
    if (t->njobs == t->cap) {
        int cap = t->cap ? 2 * t->cap : 16;
        host_job **jobs = realloc(t->jobs, (size_t)cap * sizeof *jobs);
        if (!jobs) {
            pthread_mutex_unlock(&t->lock);
            error_set(err, "ticker: out of memory");
            return -1;
        }
        t->jobs = jobs;
        t->cap = cap;
    }
    if (!j->clock.due_ms)
        j->clock = host_clock_wall;
    j->period_ms = 1000.0 / j->m->sc.tick_hz;
    j->tick = 0;
    double now = time_now_ms();
    j->due_ms = j->clock.due_ms(j->clock.ctx, 0, j->period_ms, now, now);
    j->running = j->rc = 0;
    j->ending = j->max_ticks == 0;
    j->why[0] = 0;
    /* a GL context is current on one thread: its world stays on one worker */
    j->pinned = strcmp(j->m->backend->name, "cpu") != 0 ? t->next_pin++ % t->nworkers : -1;
    t->jobs[t->njobs++] = j;
    pthread_cond_broadcast(&t->wake);
    pthread_mutex_unlock(&t->lock);
    return 0;
}

void host_ticker_wake(host_ticker *t, host_job *j)
{
    pthread_mutex_lock(&t->lock);
    for (int i = 0; i < t->njobs; i++)
        if (t->jobs[i] == j && !j->running && !j->ending && j->due_ms >= HOST_CLOCK_NEVER) {
            double now = time_now_ms();
            j->due_ms = j->clock.due_ms(j->clock.ctx, j->tick, j->period_ms, now, now);
            pthread_cond_broadcast(&t->wake);
        }
    pthread_mutex_unlock(&t->lock);
}

void host_ticker_end(host_ticker *t, host_job *j)
{
    pthread_mutex_lock(&t->lock);
    for (int i = 0; i < t->njobs; i++)
        if (t->jobs[i] == j && !j->ending) {
            j->ending = 1; /* rc stays 0: asked to stop */
            pthread_cond_broadcast(&t->wake);
        }
    pthread_mutex_unlock(&t->lock);
}

void host_ticker_stop(host_ticker *t)
{
    if (!t)
        return;
    pthread_mutex_lock(&t->lock);
    t->stopping = 1;
    for (int i = 0; i < t->njobs; i++)
        t->jobs[i]->ending = 1;
    pthread_cond_broadcast(&t->wake);
    pthread_mutex_unlock(&t->lock);
    for (int i = 0; i < t->nworkers; i++)
        pthread_join(t->workers[i].thread, NULL);
    pthread_cond_destroy(&t->wake);
    pthread_mutex_destroy(&t->lock);
    free(t->jobs);
    free(t->workers);
    free(t);
}
