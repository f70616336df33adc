/*
 * nats_test.h: real nats-server processes for the cluster unit tests and
 * bench_cluster (test_cluster*.c, bench_cluster.c): each on free loopback ports with
 * JetStream and its own store directory under one temporary root; n > 1
 * servers form the cluster "terrad" with routes to each other; nats_pause
 * stops one (SIGSTOP) and returns once every thread of it has. The command
 * line itself is tests/support/nats-start, which cluster_harness.py (the
 * Python tests, scripts/cluster) runs too.
 */
#ifndef TERRAD_TEST_NATS_H
#define TERRAD_TEST_NATS_H

#include <arpa/inet.h>
#include <dirent.h>
#include <netinet/in.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include "cluster/cluster.h"

static inline int nats_installed(void)
{
    return system("command -v nats-server >/dev/null 2>&1") == 0;
}

static char tmp_root[96];

static inline void nats_tmp_root(const char *test)
{
    snprintf(tmp_root, sizeof tmp_root, "/tmp/%s-%d", test, (int)getpid());
}

static inline void nats_tmp_remove(void)
{
    char cmd[160];
    snprintf(cmd, sizeof cmd, "rm -rf %s", tmp_root);
    if (system(cmd) != 0)
        printf("could not remove %s\n", tmp_root);
}

typedef struct nats_proc {
    pid_t pid;
    int port, cluster_port;
    char dir[192];
} nats_proc;

static inline int free_port(void)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET, .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    socklen_t len = sizeof a;
    if (fd < 0 || bind(fd, (struct sockaddr *)&a, sizeof a) != 0 ||
        getsockname(fd, (struct sockaddr *)&a, &len) != 0)
        exit(2);
    close(fd);
    return ntohs(a.sin_port);
}

static inline int port_open(int port)
{
    int fd = socket(AF_INET, SOCK_STREAM, 0);
    struct sockaddr_in a = {.sin_family = AF_INET,
                            .sin_port = htons((uint16_t)port),
                            .sin_addr.s_addr = htonl(INADDR_LOOPBACK)};
    int ok = fd >= 0 && connect(fd, (struct sockaddr *)&a, sizeof a) == 0;
    if (fd >= 0)
        close(fd);
    return ok;
}

/* Starts server i of n (n > 1: clustered with routes to the others). */
static inline void nats_start(nats_proc *all, int i, int n)
{
    nats_proc *p = &all[i];
    char port[16], name[16], cluster_port[16], routes[256] = "", log[256];
    snprintf(port, sizeof port, "%d", p->port);
    snprintf(name, sizeof name, "n%d", i);
    snprintf(cluster_port, sizeof cluster_port, "%d", p->cluster_port);
    snprintf(log, sizeof log, "%s/log", p->dir);
    for (int j = 0; j < n; j++) {
        if (j == i)
            continue;
        size_t at = strlen(routes);
        snprintf(routes + at, sizeof routes - at, "%snats://127.0.0.1:%d", at ? "," : "",
                 all[j].cluster_port);
    }
    char mkdir[256];
    snprintf(mkdir, sizeof mkdir, "mkdir -p %s", p->dir);
    if (system(mkdir) != 0)
        exit(2);
    p->pid = fork();
    if (p->pid == 0) {
        const char *start = TERRAD_TEST_SUPPORT_DIR "/nats-start";
        if (n > 1)
            execl(start, start, name, port, p->dir, log, cluster_port, routes, (char *)NULL);
        else
            execl(start, start, name, port, p->dir, log, (char *)NULL);
        _exit(127);
    }
    for (int k = 0; k < 200 && !port_open(p->port); k++)
        usleep(25000);
}

static inline void nats_stop(nats_proc *p, int sig)
{
    if (p->pid <= 0)
        return;
    kill(p->pid, sig);
    waitpid(p->pid, NULL, 0);
    p->pid = 0;
}

/* 1 when every thread of process pid is stopped: state T (or Z, X: one that
 * has exited meanwhile counts) in each /proc/PID/task/TID/stat; 0 otherwise. */
static inline int process_stopped(pid_t pid)
{
    char path[64];
    snprintf(path, sizeof path, "/proc/%d/task", (int)pid);
    DIR *d = opendir(path);
    if (!d)
        return 0;
    int threads = 0, stopped = 0;
    for (struct dirent *e; (e = readdir(d));) {
        if (e->d_name[0] == '.')
            continue;
        char stat_path[96], stat[512]; /* a thread's id: at most 10 digits */
        snprintf(stat_path, sizeof stat_path, "/proc/%d/task/%.16s/stat", (int)pid, e->d_name);
        FILE *f = fopen(stat_path, "r");
        if (!f)
            continue; /* gone since the listing */
        size_t n = fread(stat, 1, sizeof stat - 1, f);
        fclose(f);
        stat[n] = '\0';
        const char *end = strrchr(stat, ')'); /* the name may hold spaces and parentheses */
        threads++;
        stopped += end && end[1] == ' ' && end[2] && strchr("TZX", end[2]);
    }
    closedir(d);
    return threads > 0 && stopped == threads;
}

/* SIGSTOP server p, then 1 once every thread of it has stopped, 0 when
 * timeout_ms passed first. kill() returns once the signal is queued: the
 * kernel wakes one thread to take it, and only when that thread runs does it
 * stop the others, so on a busy machine the server goes on meanwhile (it
 * answers, routes and commits). Measured with terrad beside stress-ng --cpu 2
 * (Intel Xeon, 2 cores, load 7.7-11): its threads took up to 2.5 s to stop
 * (tests/support/cluster_harness.py, Node.pause, waits the same way). */
static inline int nats_pause(const nats_proc *p, int timeout_ms)
{
    kill(p->pid, SIGSTOP);
    for (int waited = 0; !process_stopped(p->pid) && waited < timeout_ms; waited += 5)
        usleep(5000);
    return process_stopped(p->pid);
}

static inline void nats_resume(const nats_proc *p)
{
    kill(p->pid, SIGCONT);
}

static inline void nats_init(nats_proc *all, int n)
{
    for (int i = 0; i < n; i++) {
        all[i].port = free_port();
        all[i].cluster_port = free_port();
        snprintf(all[i].dir, sizeof all[i].dir, "%s/n%d-%d", tmp_root, n, i);
    }
}

/* Starts all n servers. A port free_port() found may be taken by another
 * test before nats-server binds it (it exits: "address already in use"):
 * then all start again on new ports, up to 5 times. */
static inline void nats_start_all(nats_proc *all, int n)
{
    for (int attempt = 0; attempt < 5; attempt++) {
        for (int i = 0; i < n; i++)
            nats_start(all, i, n);
        usleep(300000); /* the route port is bound just after the client port */
        int dead = 0;
        for (int i = 0; i < n; i++) {
            int status;
            if (waitpid(all[i].pid, &status, WNOHANG) == all[i].pid) {
                all[i].pid = 0;
                dead = 1;
            }
        }
        if (!dead)
            return;
        printf("# a nats-server could not bind its ports: starting the servers again\n");
        for (int i = 0; i < n; i++)
            nats_stop(&all[i], SIGKILL);
        char cmd[160];
        snprintf(cmd, sizeof cmd, "rm -rf %s/n%d-*", tmp_root, n);
        if (system(cmd) != 0)
            printf("# could not clear %s\n", tmp_root);
        nats_init(all, n);
    }
}

static inline void urls_of(const nats_proc *all, int n, char *out, size_t cap)
{
    out[0] = '\0';
    for (int i = 0; i < n; i++) {
        size_t at = strlen(out);
        snprintf(out + at, cap - at, "%snats://127.0.0.1:%d", i ? "," : "", all[i].port);
    }
}

/* One nats-server under the test's temporary root and two nodes, "a" and "b",
 * connected to it (the single-server cluster tests' start); 0 when both are
 * (else err says why, and whichever did connect is closed). */
static inline int nats_one_two_nodes(const char *test, nats_proc *one, cluster **a, cluster **b,
                                     error_text *err)
{
    nats_tmp_root(test);
    nats_init(one, 1);
    nats_start_all(one, 1);
    char urls[64];
    urls_of(one, 1, urls, sizeof urls);
    cluster_config ca = {.urls = urls, .node = "a"}, cb = {.urls = urls, .node = "b"};
    *a = cluster_connect(&ca, err);
    *b = *a ? cluster_connect(&cb, err) : NULL;
    if (*a && *b)
        return 0;
    cluster_close(*a);
    *a = NULL;
    return -1;
}

#endif
