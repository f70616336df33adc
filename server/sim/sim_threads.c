/*
 * sim_threads.c: how many threads the CPU twin's stages use (--threads on
 * serve and simulate). One process-wide setting, read at the start of each
 * parallel region: the windows of a tick run in parallel (backend_cpu.c), and
 * a window's work lists split into bands across threads (sim_stages.c). Every
 * parallel loop writes only its own cells from values read before the loop
 * (Jacobi), so heights are identical for any thread count. Built without
 * OpenMP, everything runs on the calling thread and the setting is reported
 * as 1.
 */
#include "sim/sim_internal.h"

#include <stdatomic.h>
#ifdef _OPENMP
#include <omp.h>
#endif
#include <unistd.h>

static atomic_int thread_count; /* 0: not set, the machine's cores */

int sim_default_threads(void)
{
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    if (cores < 1)
        cores = 1;
    return cores > SIM_THREADS_MAX ? SIM_THREADS_MAX : (int)cores;
}

void sim_set_threads(int n)
{
    atomic_store(&thread_count, n < 1 ? 0 : n > SIM_THREADS_MAX ? SIM_THREADS_MAX : n);
}

int sim_threads(void)
{
#ifdef _OPENMP
    int n = atomic_load(&thread_count);
    return n > 0 ? n : sim_default_threads();
#else
    return 1;
#endif
}

int sim_thread_index(void)
{
#ifdef _OPENMP
    return omp_get_thread_num();
#else
    return 0;
#endif
}

int sim_band_threads(int64_t items)
{
#ifdef _OPENMP
    /* below this a parallel region costs more than it saves */
    if (items < SIM_BAND_MIN_ITEMS || omp_in_parallel())
        return 1;
    int n = sim_threads();
    int64_t most = items / (SIM_BAND_MIN_ITEMS / 2);
    return most < n ? (int)most : n;
#else
    (void)items;
    return 1;
#endif
}
