/*
 * store_remove.c: `terrad serve --fresh` — start a data directory over. Runs
 * before store_open, outside any tick. It deletes only the files a data
 * directory holds (store_internal.h's layout: MANIFEST, CONTROL, LOCK,
 * wal-*.log and the wal-*.log.lost segments --recover-truncate set aside,
 * tiles/t-X-Y.snap, and their *.tmp leftovers of an interrupted write), and
 * refuses a directory holding anything else, so a mistyped --data (a home
 * directory, a project) loses nothing. It takes the directory's lock first:
 * a daemon running on it keeps it.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/file.h>
#include <unistd.h>

#include "store/store_internal.h"

/* 1 when the whole of `name` matches `fmt` (its numbers, then %n). */
static int name_is(const char *name, const char *fmt, int fields)
{
    unsigned long long a, b;
    int end = -1;
    int got = fields == 1 ? sscanf(name, fmt, &a, &end) : sscanf(name, fmt, &a, &b, &end);
    return got == fields && end > 0 && name[end] == 0;
}

static int strip_tmp(const char *name, char *out, size_t cap)
{
    size_t n = strlen(name);
    if (n >= cap)
        return -1;
    memcpy(out, name, n + 1);
    if (n > 4 && strcmp(out + n - 4, ".tmp") == 0)
        out[n - 4] = 0;
    return 0;
}

static int top_level_known(const char *name)
{
    char base[256];
    if (strip_tmp(name, base, sizeof base) != 0)
        return 0;
    return strcmp(base, "MANIFEST") == 0 || strcmp(base, "CONTROL") == 0 ||
           strcmp(name, "LOCK") == 0 ||
           (strncmp(base, "wal-", 4) == 0 &&
            (name_is(base, "wal-%16llu.log%n", 1) || name_is(base, "wal-%16llu.log.lost%n", 1)));
}

static int tile_known(const char *name)
{
    char base[256];
    uint64_t tick;
    int tx, ty, done;
    if (strip_tmp(name, base, sizeof base) != 0)
        return 0;
    return (strncmp(base, "t-", 2) == 0 && name_is(base, "t-%5llu-%5llu.snap%n", 2)) ||
           store_keyframe_name(base, &tick, &tx, &ty, &done); /* replay's (store_replay.c) */
}

/* Checks (remove = 0) or deletes (remove = 1) every entry of dir/sub; an
 * unknown one is an error naming it. Counts what it deletes in *count. */
static int walk(const char *dir, const char *sub, int remove, int *count, error_text *err)
{
    char path[1200];
    snprintf(path, sizeof path, sub ? "%s/%s" : "%s", dir, sub);
    DIR *d = opendir(path);
    if (!d) {
        if (sub && errno == ENOENT)
            return 0;
        error_set(err, "store: cannot read %s: %s", path, strerror(errno));
        return -1;
    }
    int rc = 0;
    struct dirent *e;
    while (rc == 0 && (e = readdir(d))) {
        const char *n = e->d_name;
        if (strcmp(n, ".") == 0 || strcmp(n, "..") == 0)
            continue;
        char p[1500];
        snprintf(p, sizeof p, "%s/%s", path, n);
        /* a single daemon's created worlds (app/serve_worlds.c: one data
         * directory each under worlds/, kept ones under worlds-kept/): the
         * daemon's to remove, never a reason to refuse */
        if (!sub && (strcmp(n, "worlds") == 0 || strcmp(n, "worlds-kept") == 0))
            continue;
        if (!sub && strcmp(n, "tiles") == 0) {
            rc = walk(dir, "tiles", remove, count, err);
            if (rc == 0 && remove && rmdir(p) != 0) {
                error_set(err, "store: cannot remove %s: %s", p, strerror(errno));
                rc = -1;
            }
            continue;
        }
        if (!(sub ? tile_known(n) : top_level_known(n))) {
            error_set(err,
                      "store: %s is not a file of a terrad data directory: nothing removed "
                      "(start over by hand, or choose another --data)",
                      p);
            rc = -1;
        } else if (remove && strcmp(n, "LOCK") != 0) {
            if (unlink(p) != 0) {
                error_set(err, "store: cannot remove %s: %s", p, strerror(errno));
                rc = -1;
            } else {
                (*count)++;
            }
        }
    }
    closedir(d);
    return rc;
}

int store_remove(const char *dir, int *removed, error_text *err)
{
    *removed = 0;
    DIR *d = opendir(dir);
    if (!d) {
        if (errno == ENOENT)
            return 0; /* nothing to start over */
        error_set(err, "store: cannot read %s: %s", dir, strerror(errno));
        return -1;
    }
    closedir(d);
    if (walk(dir, NULL, 0, removed, err) != 0)
        return -1;
    char lock[1200];
    snprintf(lock, sizeof lock, "%s/LOCK", dir);
    int fd = open(lock, O_RDWR | O_CLOEXEC);
    if (fd >= 0 && flock(fd, LOCK_EX | LOCK_NB) != 0) {
        error_set(err, "store: %s is in use by another terrad: nothing removed", dir);
        close(fd);
        return -1;
    }
    int rc = walk(dir, NULL, 1, removed, err);
    if (rc == 0 && fd >= 0) {
        if (unlink(lock) != 0) {
            error_set(err, "store: cannot remove %s: %s", lock, strerror(errno));
            rc = -1;
        } else {
            (*removed)++;
        }
    }
    if (fd >= 0)
        close(fd);
    return rc;
}
