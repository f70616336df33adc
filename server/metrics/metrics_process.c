/*
 * metrics_process.c: the standard process_* metrics every Prometheus
 * exporter has (CPU time, start time, memory, file descriptors) and
 * terrad_build_info, read from /proc/self when /metrics is scraped — never
 * on the tick. metrics.c appends this text to its exposition.
 */
#include <dirent.h>
#include <stdio.h>
#include <string.h>
#include <sys/resource.h>
#include <unistd.h>

#include "metrics/metrics.h"
#include "terrad_version.h"

/* The process's start in seconds since the epoch: /proc/stat's btime plus
 * field 22 of /proc/self/stat (clock ticks after boot). -1 if unreadable. */
static double start_time_s(void)
{
    char buf[1024];
    double btime = -1, start_ticks = -1;
    FILE *f = fopen("/proc/stat", "r");
    if (f) {
        while (fgets(buf, sizeof buf, f))
            if (sscanf(buf, "btime %lf", &btime) == 1)
                break;
        fclose(f);
    }
    f = fopen("/proc/self/stat", "r");
    if (f) {
        size_t n = fread(buf, 1, sizeof buf - 1, f);
        buf[n] = 0;
        fclose(f);
        char *p = strrchr(buf, ')'); /* the command name may hold spaces and ')' */
        unsigned long long st = 0;
        /* after ") ": state (field 3) ... starttime (field 22) */
        if (p && sscanf(p + 2,
                        "%*c %*d %*d %*d %*d %*d %*u %*u %*u %*u %*u %*u %*u %*d %*d %*d "
                        "%*d %*d %*d %llu",
                        &st) == 1)
            start_ticks = (double)st;
    }
    long hz = sysconf(_SC_CLK_TCK);
    return btime < 0 || start_ticks < 0 || hz <= 0 ? -1 : btime + start_ticks / (double)hz;
}

static long open_fds(void)
{
    DIR *d = opendir("/proc/self/fd");
    if (!d)
        return -1;
    long n = 0;
    struct dirent *e;
    while ((e = readdir(d)))
        if (e->d_name[0] != '.')
            n++;
    closedir(d);
    return n - 1; /* not the one opendir holds */
}

int metrics_process_text(char *out, size_t cap)
{
    struct rusage ru;
    double cpu = 0;
    if (getrusage(RUSAGE_SELF, &ru) == 0)
        cpu = (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 + (double)ru.ru_stime.tv_sec +
              ru.ru_stime.tv_usec * 1e-6;
    unsigned long long pages_virt = 0, pages_res = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (f) {
        if (fscanf(f, "%llu %llu", &pages_virt, &pages_res) != 2)
            pages_virt = pages_res = 0;
        fclose(f);
    }
    unsigned long long page = (unsigned long long)sysconf(_SC_PAGESIZE);
    struct rlimit rl = {0, 0};
    getrlimit(RLIMIT_NOFILE, &rl);
    int n = snprintf(
        out, cap,
        "# HELP terrad_build_info The daemon's version (CMakeLists.txt's project VERSION).\n"
        "# TYPE terrad_build_info gauge\n"
        "terrad_build_info{version=\"%s\"} 1\n"
        "# HELP process_cpu_seconds_total Total user and system CPU time spent in seconds.\n"
        "# TYPE process_cpu_seconds_total counter\n"
        "process_cpu_seconds_total %.6f\n"
        "# HELP process_start_time_seconds Start time of the process since unix epoch in "
        "seconds.\n"
        "# TYPE process_start_time_seconds gauge\n"
        "process_start_time_seconds %.2f\n"
        "# HELP process_resident_memory_bytes Resident memory size in bytes.\n"
        "# TYPE process_resident_memory_bytes gauge\n"
        "process_resident_memory_bytes %llu\n"
        "# HELP process_virtual_memory_bytes Virtual memory size in bytes.\n"
        "# TYPE process_virtual_memory_bytes gauge\n"
        "process_virtual_memory_bytes %llu\n"
        "# HELP process_open_fds Number of open file descriptors.\n"
        "# TYPE process_open_fds gauge\n"
        "process_open_fds %ld\n"
        "# HELP process_max_fds Maximum number of open file descriptors.\n"
        "# TYPE process_max_fds gauge\n"
        "process_max_fds %lld\n",
        TERRAD_VERSION, cpu, start_time_s(), pages_res * page, pages_virt * page, open_fds(),
        rl.rlim_cur == RLIM_INFINITY ? -1LL : (long long)rl.rlim_cur);
    return n < 0 || (size_t)n >= cap ? -1 : n;
}
