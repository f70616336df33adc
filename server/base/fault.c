/*
 * fault.c: a test hook that makes a thread stop making progress, so that the
 * watchdog behind /healthz (http_server_watch) can be tested on a real daemon
 * (tests/integration/hostile/test_hostile_watchdog.py). SIGSTOP would stop the whole
 * process, probes included; this stops one thread and nothing else.
 *
 * TERRAD_FAULT_STALL=FILE: while FILE exists and its first word names the
 * calling thread ("tick" for the sim thread's loop, "net" for the websocket
 * thread's heartbeat), fault_stall sleeps in 50 ms steps instead of
 * returning. Without the variable it costs one getenv, once per process. Like
 * --store-fault it is compiled into every build and documented
 * (docs/service.md, "Watchdog"); it only ever delays, never changes data.
 */
#include "base/base.h"

#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

static const char *stall_path;
static pthread_once_t stall_once = PTHREAD_ONCE_INIT;

static void read_stall_path(void)
{
    const char *p = getenv("TERRAD_FAULT_STALL");
    stall_path = p && p[0] ? p : NULL;
}

/* 1 while the hook's file exists and names this thread. */
static int stalled(const char *thread)
{
    FILE *f = fopen(stall_path, "r");
    if (!f)
        return 0;
    char word[32] = {0};
    int named = fscanf(f, "%31s", word) == 1 && strcmp(word, thread) == 0;
    fclose(f);
    return named;
}

void fault_stall(const char *thread)
{
    pthread_once(&stall_once, read_stall_path);
    if (!stall_path)
        return;
    int logged = 0;
    while (stalled(thread)) {
        if (!logged++)
            log_warn("fault hook: the %s thread stalls while %s names it", thread, stall_path);
        struct timespec ts = {0, 50 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    if (logged)
        log_warn("fault hook: the %s thread goes on", thread);
}
