/*
 * backend_cpu.c: the CPU twin as a backend. It runs a tick's windows one
 * after another through the same stages as the GL backend — depth (fixed
 * point, collider/depth_cpu.c), classify, jump flooding, displacement, slope
 * evening — and is both the test oracle and the backend for machines without
 * OpenGL 4.3. Scratch memory grows to the largest window seen, never to the
 * world. Its depth stage, sim_window_depth, is the one CPU depth routine of
 * the tick (the engine, Sumner and decals cast theirs with it too). The
 * backend interface's optional entries are reached through the calls at the
 * end, which answer for a backend that lacks them.
 */
#include "sim/sim_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Per-cell int32 arrays: bottom, raw, moved, cls, seed, and 5 of stage scratch. */
#define CPU_ARRAYS_PER_CELL 10

typedef struct cpu_backend {
    sim_backend base;
    /* one arena per thread: the windows of a tick run in parallel */
    int32_t *arena[SIM_THREADS_MAX];
    int64_t capacity_cells[SIM_THREADS_MAX];
} cpu_backend;

static int ensure_capacity(cpu_backend *b, int thread, int64_t cells, error_text *err)
{
    /* at least 1024 cells, so small windows do not regrow the arena */
    if (array_grow((void **)&b->arena[thread], &b->capacity_cells[thread],
                   cells < 1024 ? 1024 : cells, CPU_ARRAYS_PER_CELL * sizeof(int32_t)) != 0) {
        error_set(err, "cpu backend: out of memory for %lld window cells", (long long)cells);
        return -1;
    }
    return 0;
}

void sim_window_cast(const sim_window_job *job, int j, int slices, int32_t *target)
{
    for (int c = 0; c < job->collider_count; c++) {
        const sim_collider *col = &job->colliders[c];
        int steps = sim_collider_sweep_steps(col, job->cell_size_m);
        int k0 = sim_slice_end(j - 1, slices, steps), k1 = sim_slice_end(j, slices, steps);
        /* the swept collider: min over its sub-step poses of the slice (the
         * pose it stands at when it does not move within the slice) */
        for (int k = k1 > k0 ? k0 + 1 : k1; k <= k1; k++)
            collider_depth_cpu(col->geometry, sim_collider_sweep_pose(col, k, steps), job->rect,
                               job->cell_size_m, job->units_per_m, target);
    }
}

void sim_window_depth_slice(const sim_window_job *job, int j, int slices, int32_t *bottom)
{
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    for (int64_t i = 0; i < n; i++)
        bottom[i] = COLLIDER_BOTTOM_NONE;
    sim_window_cast(job, j, slices, bottom);
}

void sim_window_depth(const sim_window_job *job, int32_t *bottom)
{
    sim_window_depth_slice(job, 1, 1, bottom); /* one slice: every sub-step, 1..steps */
}

/* One window through the stages, in the arena of the thread that runs it. */
static void cpu_run_window(const sim_params *p, sim_window_job *job, int32_t *arena, int *status,
                           sim_stage_times *times)
{
    int w = job->rect.w, h = job->rect.h;
    int64_t n = (int64_t)w * h;
    int32_t *bottom = arena, *raw = bottom + n, *moved = raw + n, *cls = moved + n;
    int32_t *seed = cls + n, *scratch = seed + n;

    double t0 = time_now_ms();
    if (job->bottom_override)
        memcpy(bottom, job->bottom_override, (size_t)n * sizeof *bottom);
    else
        sim_window_depth(job, bottom);
    if (job->bottom_out)
        memcpy(job->bottom_out, bottom, (size_t)n * sizeof *bottom);
    double t1 = time_now_ms();
    if (job->materials)
        sim_classify_materials(p, job->materials, job->material_ids, job->compaction, (int)n,
                               job->heights, bottom, raw, moved, cls);
    else
        sim_classify(p, (int)n, job->heights, bottom, raw, moved, cls);
    double t2 = time_now_ms();
    /* A window no collider penetrates has raw = moved = 0 everywhere:
     * displacement (and the seeds it reads) would change nothing. */
    int penetrated = 0;
    for (int64_t i = 0; i < n && !penetrated; i++)
        penetrated = cls[i] == SIM_CELL_PENETRATING;
    if (penetrated)
        sim_jump_flood(p, w, h, job->rect.x, job->rect.y, cls, seed, scratch);
    double t3 = time_now_ms();
    *status = penetrated ? sim_displace(p, w, h, cls, seed, raw, moved, job->heights, scratch)
                         : SIM_WINDOW_OK;
    double t4 = time_now_ms();
    if (*status == SIM_WINDOW_OK && job->materials) {
        sim_even_slopes_materials(p, job->materials, job->material_ids, w, h, cls, job->heights,
                                  scratch);
        if (job->compaction)
            sim_compaction_commit(job->materials, job->material_ids, (int)n, raw, moved,
                                  job->compaction);
    } else if (*status == SIM_WINDOW_OK) {
        sim_even_slopes(p, w, h, cls, job->heights, scratch);
    }
    double t5 = time_now_ms();
    times->depth += t1 - t0;
    times->classify += t2 - t1;
    times->jump_flood += t3 - t2;
    times->displace += t4 - t3;
    times->even_slopes += t5 - t4;
}

/* The windows loop's shared state: each thread sums its stage times apart. */
typedef struct windows_loop {
    cpu_backend *b;
    const sim_params *p;
    sim_window_job *jobs;
    int *status;
    sim_stage_times per_thread[SIM_THREADS_MAX];
} windows_loop;

static void run_windows_range(void *ctx, int64_t begin, int64_t end, int thread)
{
    windows_loop *l = ctx;
    for (int64_t j = begin; j < end; j++)
        cpu_run_window(l->p, &l->jobs[j], l->b->arena[thread], &l->status[j],
                       &l->per_thread[thread]);
}

/*
 * The windows of a tick are disjoint and independent: with several, they
 * run in parallel (each thread in its own arena, one window at a time
 * claimed from the pool's counter) when they hold at least
 * 2 * SIM_BAND_MIN_ITEMS cells; a window alone or holding more than half of
 * the tick's cells runs with the others one after another
 * and spreads its work lists over the threads inside the stages instead
 * (sim_band_threads; a loop nested in the windows' runs on one thread).
 * Stage times are summed over windows, so with threads they are CPU time.
 */
static int cpu_run_windows(sim_backend *base, const sim_params *p, sim_window_job *jobs,
                           int job_count, int *status, sim_stage_times *times, error_text *err)
{
    cpu_backend *b = (cpu_backend *)base;
    int threads = sim_threads();
    if (threads > job_count)
        threads = job_count;
    int64_t largest = 0, total = 0;
    for (int j = 0; j < job_count; j++) {
        int64_t n = (int64_t)jobs[j].rect.w * jobs[j].rect.h;
        largest = n > largest ? n : largest;
        total += n;
    }
    /* a tick too small to pay for waking threads runs on this one */
    if (largest * 2 > total || total < 2 * SIM_BAND_MIN_ITEMS)
        threads = 1;
    for (int t = 0; t < (threads > 1 ? threads : 1); t++)
        if (ensure_capacity(b, t, largest, err) != 0)
            return -1;
    if (threads <= 1) {
        for (int j = 0; j < job_count; j++)
            cpu_run_window(p, &jobs[j], b->arena[0], &status[j], times);
        return 0;
    }
    windows_loop loop, *l = &loop;
    memset(l, 0, sizeof *l);
    l->b = b;
    l->p = p;
    l->jobs = jobs;
    l->status = status;
    sim_parallel_for(job_count, 1, threads, run_windows_range, l);
    for (int t = 0; t < threads; t++) {
        times->depth += l->per_thread[t].depth;
        times->classify += l->per_thread[t].classify;
        times->jump_flood += l->per_thread[t].jump_flood;
        times->displace += l->per_thread[t].displace;
        times->even_slopes += l->per_thread[t].even_slopes;
    }
    return 0;
}

static void cpu_forget_geometry(sim_backend *b, const collider_geometry *g)
{
    (void)b; /* the CPU twin caches nothing per geometry */
    (void)g;
}

static uint64_t cpu_scratch_bytes(const sim_backend *base)
{
    const cpu_backend *b = (const cpu_backend *)base;
    uint64_t cells = 0;
    for (int t = 0; t < SIM_THREADS_MAX; t++)
        cells += (uint64_t)b->capacity_cells[t];
    return cells * CPU_ARRAYS_PER_CELL * sizeof(int32_t);
}

/* bottom → depth; raw, moved, cls → classify; seed → jump_flood; the five
 * arrays of stage scratch are displacement's (jump flooding and slope
 * evening borrow fewer of them). */
static void cpu_stage_bytes(const sim_backend *base, sim_stage_memory *out)
{
    const cpu_backend *b = (const cpu_backend *)base;
    uint64_t cells = 0;
    for (int t = 0; t < SIM_THREADS_MAX; t++)
        cells += (uint64_t)b->capacity_cells[t];
    uint64_t array = cells * sizeof(int32_t);
    out->depth += array;
    out->classify += 3 * array;
    out->jump_flood += array;
    out->displace += 5 * array;
}

static void cpu_destroy(sim_backend *base)
{
    cpu_backend *b = (cpu_backend *)base;
    for (int t = 0; t < SIM_THREADS_MAX; t++)
        free(b->arena[t]);
    free(b);
}

static void cpu_describe(char *out, size_t size)
{
    snprintf(out, size, "CPU twin");
    FILE *f = fopen("/proc/cpuinfo", "r");
    if (!f)
        return;
    char line[512];
    while (fgets(line, sizeof line, f)) {
        if (strncmp(line, "model name", 10) == 0) {
            char *colon = strchr(line, ':');
            if (colon) {
                colon++;
                while (*colon == ' ')
                    colon++;
                colon[strcspn(colon, "\n")] = 0;
                snprintf(out, size, "CPU twin on %s", colon);
            }
            break;
        }
    }
    fclose(f);
}

sim_backend *sim_backend_cpu_create(error_text *err)
{
    cpu_backend *b = calloc(1, sizeof *b);
    if (!b) {
        error_set(err, "cpu backend: out of memory");
        return NULL;
    }
    b->base.name = "cpu";
    cpu_describe(b->base.renderer, sizeof b->base.renderer);
    snprintf(b->base.version, sizeof b->base.version, "C11 integer twin");
    b->base.run_windows = cpu_run_windows;
    b->base.forget_geometry = cpu_forget_geometry;
    b->base.scratch_bytes = cpu_scratch_bytes;
    b->base.stage_bytes = cpu_stage_bytes;
    b->base.destroy = cpu_destroy;
    return &b->base;
}

/* ---- the backend interface's optional entries, for any backend ---- */

void sim_backend_tile_cache_stats(const sim_backend *b, sim_tile_cache_stats *out)
{
    memset(out, 0, sizeof *out);
    if (b && b->tile_cache_stats)
        b->tile_cache_stats(b, out);
}

void sim_backend_gpu_sync_stats(const sim_backend *b, sim_gpu_sync_stats *out)
{
    memset(out, 0, sizeof *out);
    if (b && b->gpu_sync_stats)
        b->gpu_sync_stats(b, out);
}

void sim_backend_set_stage_timing(sim_backend *b, int on)
{
    if (b && b->set_stage_timing)
        b->set_stage_timing(b, on);
}
