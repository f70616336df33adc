/*
 * bench_stream.c: this machine's memory bandwidth, STREAM-style (McCalpin's
 * "copy": b[i] = a[i] over arrays far larger than the caches), so that
 * bench_core.py can print the sim's nanoseconds per active cell beside what
 * the memory could move in that time. One thread; best of several runs.
 * Prints one JSON line: {"bench":"stream_copy","bytes":...,"gb_per_s":...,
 * "ns_per_int32_read_write":...}.
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static double now_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec * 1e-9;
}

int main(void)
{
    const size_t n = (size_t)32 << 20; /* 32 Mi int32 = 128 MiB per array */
    int32_t *a = malloc(n * sizeof *a), *b = malloc(n * sizeof *b);
    if (!a || !b) {
        fprintf(stderr, "bench_stream: out of memory\n");
        return 1;
    }
    for (size_t i = 0; i < n; i++) {
        a[i] = (int32_t)i;
        b[i] = 0;
    }
    double best = 1e30;
    for (int rep = 0; rep < 6; rep++) {
        double t0 = now_s();
        memcpy(b, a, n * sizeof *a);
        double t = now_s() - t0;
        best = t < best ? t : best;
        a[rep] = b[n - 1 - (size_t)rep]; /* keep the copies observable */
    }
    /* STREAM counts the bytes read plus the bytes written */
    double bytes = 2.0 * (double)n * sizeof *a;
    double gbs = bytes / best / 1e9;
    printf("{\"bench\":\"stream_copy\",\"bytes\":%.0f,\"gb_per_s\":%.2f,"
           "\"ns_per_int32_read_write\":%.3f,\"check\":%d}\n",
           bytes, gbs, best * 1e9 / (double)n, (int)(a[0] + b[1]));
    free(a);
    free(b);
    return 0;
}
