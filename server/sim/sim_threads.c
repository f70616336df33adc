/*
 * sim_threads.c: the CPU twin's threads (--threads on serve and simulate).
 * One process-wide setting and one small pool of worker threads: the windows
 * of a tick run in parallel (backend_cpu.c), and a window's work lists split
 * into chunks across threads (sim_stages.c). Every parallel loop writes only
 * its own cells from values read before the loop (Jacobi), so heights are
 * identical for any thread count and any split.
 *
 * Why a pool of our own and not OpenMP: on a machine whose cores are shared
 * (the daemon beside its clients, other jobs), libgomp's default wait spins
 * for ~300,000 iterations after every parallel region and at every barrier.
 * Measured under the service bench at 64 wheels (docs/performance.md) that
 * spinning was 61 % of the daemon's CPU, taken from the net thread and the
 * clients. Here a worker sleeps on a condition variable between loops, and
 * the caller never waits for a worker that has not started: the items are
 * claimed from an atomic counter, so a caller whose workers are not
 * scheduled runs the whole loop itself and waits only for chunks a worker
 * has already claimed.
 *
 * TERRAD_TWIN_LIB (the twin library's WebAssembly build, docs/engines.md,
 * where there are no threads) compiles the same file without the pool: every
 * loop runs on the caller, which is what a pool of one thread does anyway, so
 * heights are the same.
 */
#include "sim/sim_internal.h"

#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#ifndef TERRAD_TWIN_LIB
#include <pthread.h>
#include <unistd.h>
#endif

static atomic_int thread_count; /* 0: not set, the machine's cores */

/* -1: not read yet; else whether the AVX2 forms run (sim_internal.h) */
static atomic_int avx2_state = -1;
static atomic_int avx2_allowed = 1;

int sim_cpu_avx2(void)
{
    int s = atomic_load_explicit(&avx2_state, memory_order_relaxed);
    if (s < 0) {
#if SIM_AVX2_CLONE
        const char *off = getenv("TERRAD_NO_AVX2");
        s = __builtin_cpu_supports("avx2") && !(off && off[0] && strcmp(off, "0") != 0);
#else
        s = 0;
#endif
        atomic_store_explicit(&avx2_state, s, memory_order_relaxed);
    }
    return s && atomic_load_explicit(&avx2_allowed, memory_order_relaxed);
}

void sim_cpu_avx2_allow(int allow)
{
    atomic_store_explicit(&avx2_allowed, allow != 0, memory_order_relaxed);
}

/* The machine's cores, read once: sysconf(_SC_NPROCESSORS_ONLN) opens and
 * reads /sys/devices/system/cpu/online each time, and sim_threads() is asked
 * in every stage of every window of every tick — 6 % of a daemon's CPU with
 * 16 driven worlds (docs/performance.md, issue 32). */
int sim_default_threads(void)
{
#ifdef TERRAD_TWIN_LIB
    return 1;
#else
    static atomic_int default_threads;
    int n = atomic_load_explicit(&default_threads, memory_order_relaxed);
    if (n > 0)
        return n;
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    if (cores < 1)
        cores = 1;
    n = cores > SIM_THREADS_MAX ? SIM_THREADS_MAX : (int)cores;
    atomic_store_explicit(&default_threads, n, memory_order_relaxed);
    return n;
#endif
}

void sim_set_threads(int n)
{
    atomic_store(&thread_count, n < 1 ? 0 : n > SIM_THREADS_MAX ? SIM_THREADS_MAX : n);
}

int sim_threads(void)
{
    int n = atomic_load(&thread_count);
    return n > 0 ? n : sim_default_threads();
}

#ifdef TERRAD_TWIN_LIB
static const int in_parallel = 0;
static const int serial_thread = 0;

void sim_thread_serial(int on)
{
    (void)on; /* one thread anyway */
}

void sim_parallel_for(int64_t items, int64_t chunk, int threads, sim_range_fn fn, void *ctx)
{
    (void)chunk;
    (void)threads;
    if (items > 0)
        fn(ctx, 0, items, 0);
}
#else
/* One parallel loop: chunks of `chunk` items claimed from `next`. */
typedef struct pool_job {
    sim_range_fn fn;
    void *ctx;
    int64_t items, chunk;
    int threads;       /* slots 0 (the caller) .. threads - 1 */
    atomic_llong next; /* first unclaimed item */
    int joined;        /* workers inside the loop (under pool.lock) */
    int closed;        /* the caller has finished: no worker may join */
} pool_job;

static struct {
    pthread_mutex_t lock;
    pthread_cond_t wake;   /* a new job */
    pthread_cond_t done;   /* the last joined worker left */
    pthread_mutex_t owner; /* one parallel loop at a time; others run serially */
    pool_job *job;
    uint64_t generation;
    int workers; /* started; worker k has slot k (1-based) */
} pool = {PTHREAD_MUTEX_INITIALIZER,
          PTHREAD_COND_INITIALIZER,
          PTHREAD_COND_INITIALIZER,
          PTHREAD_MUTEX_INITIALIZER,
          NULL,
          0,
          0};

/* Non-zero on a pool worker and on a caller inside its loop: a loop nested in
 * a parallel loop runs serially on the thread that meets it. */
static _Thread_local int in_parallel;
static _Thread_local int slot_of_thread;
static _Thread_local int serial_thread; /* sim_thread_serial */

void sim_thread_serial(int on)
{
    serial_thread = on != 0;
}

static void run_chunks(pool_job *j, int slot)
{
    for (;;) {
        int64_t begin = atomic_fetch_add(&j->next, j->chunk);
        if (begin >= j->items)
            return;
        int64_t end = begin + j->chunk < j->items ? begin + j->chunk : j->items;
        j->fn(j->ctx, begin, end, slot);
    }
}

static void *worker_main(void *arg)
{
    int slot = (int)(intptr_t)arg;
    in_parallel = 1;
    slot_of_thread = slot;
    pthread_mutex_lock(&pool.lock);
    uint64_t seen = pool.generation;
    for (;;) {
        while (pool.generation == seen)
            pthread_cond_wait(&pool.wake, &pool.lock);
        seen = pool.generation;
        pool_job *j = pool.job;
        if (!j || j->closed || slot >= j->threads)
            continue;
        j->joined++;
        pthread_mutex_unlock(&pool.lock);
        run_chunks(j, slot);
        pthread_mutex_lock(&pool.lock);
        if (--j->joined == 0 && j->closed)
            pthread_cond_signal(&pool.done);
    }
    return NULL;
}

/* Start workers up to slot threads - 1; fewer if the system refuses. */
static int ensure_workers(int threads)
{
    pthread_mutex_lock(&pool.lock);
    while (pool.workers < threads - 1) {
        pthread_t t;
        pthread_attr_t attr;
        pthread_attr_init(&attr);
        pthread_attr_setdetachstate(&attr, PTHREAD_CREATE_DETACHED);
        int rc = pthread_create(&t, &attr, worker_main, (void *)(intptr_t)(pool.workers + 1));
        pthread_attr_destroy(&attr);
        if (rc != 0)
            break;
        pool.workers++;
    }
    int have = pool.workers + 1;
    pthread_mutex_unlock(&pool.lock);
    return have < threads ? have : threads;
}

void sim_parallel_for(int64_t items, int64_t chunk, int threads, sim_range_fn fn, void *ctx)
{
    if (items <= 0)
        return;
    if (chunk < 1)
        chunk = 1;
    if (threads > SIM_THREADS_MAX)
        threads = SIM_THREADS_MAX;
    if (threads <= 1 || items <= chunk || in_parallel || serial_thread ||
        pthread_mutex_trylock(&pool.owner) != 0) {
        fn(ctx, 0, items, in_parallel ? slot_of_thread : 0);
        return;
    }
    threads = ensure_workers(threads);
    pool_job j = {.fn = fn, .ctx = ctx, .items = items, .chunk = chunk, .threads = threads};
    atomic_init(&j.next, 0);
    pthread_mutex_lock(&pool.lock);
    pool.job = &j;
    pool.generation++;
    pthread_cond_broadcast(&pool.wake);
    pthread_mutex_unlock(&pool.lock);

    in_parallel = 1;
    slot_of_thread = 0;
    run_chunks(&j, 0);
    in_parallel = 0;

    /* every item is claimed; wait only for the workers that claimed some */
    pthread_mutex_lock(&pool.lock);
    j.closed = 1;
    while (j.joined > 0)
        pthread_cond_wait(&pool.done, &pool.lock);
    pool.job = NULL;
    pthread_mutex_unlock(&pool.lock);
    pthread_mutex_unlock(&pool.owner);
}

#endif

int64_t sim_band_chunk(int64_t items, int bands)
{
    int64_t chunk = items / ((int64_t)(bands > 0 ? bands : 1) * 4);
    return chunk < SIM_BAND_MIN_ITEMS / 4 ? SIM_BAND_MIN_ITEMS / 4 : chunk;
}

int sim_band_threads(int64_t items)
{
    /* below this a parallel loop costs more than it saves */
    if (items < SIM_BAND_MIN_ITEMS || in_parallel || serial_thread)
        return 1;
    int n = sim_threads();
    int64_t most = items / (SIM_BAND_MIN_ITEMS / 2);
    return most < n ? (int)most : n;
}
