/*
 * store_control.c: the data directory's CONTROL file, after PostgreSQL's
 * pg_control — the one place that says what the directory must hold, so that
 * recovery can tell a torn tail (cut) from damage (refused): the log segments
 * that must be present (first..last, no gap), the tile snapshots that exist
 * (and the tick of each) and the last tick known durable when it was written.
 *
 * It is written atomically (tmp, fsync, rename, fsync of the directory) when
 * a directory is opened, when a segment is started, when a compaction has
 * written its snapshots (before the older segments are deleted) and at close;
 * never in an ordinary tick. Text, one fact a line, with a CRC32C line:
 *
 *   terrad-control 1
 *   tick 1234
 *   segments 7 9
 *   tile 0 1 1200
 *   crc32c 89abcdef
 */
#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "store/store_internal.h"

int store_control_init(store_control *c, int tiles_x, int tiles_y)
{
    memset(c, 0, sizeof *c);
    c->tiles_x = tiles_x;
    c->tiles_y = tiles_y;
    c->tile_tick = calloc((size_t)tiles_x * tiles_y + 1, sizeof *c->tile_tick);
    return c->tile_tick ? 0 : -1;
}

void store_control_free(store_control *c)
{
    free(c->tile_tick);
    c->tile_tick = NULL;
}

int store_control_read(const char *dir, store_control *c, error_text *err)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/CONTROL", dir);
    if (access(path, F_OK) != 0)
        return 1;
    uint8_t *data;
    size_t len;
    if (store_file_read(path, "", &data, &len, err) != 0)
        return -1;
    char *text = (char *)data;
    const char *crc_end = store_text_crc_end(text, "\n");
    int ok = crc_end != NULL;
    unsigned long long tick = 0, first = 0, last = 0;
    int n = 0;
    ok = ok &&
         sscanf(text, "terrad-control 1\ntick %llu\nsegments %llu %llu\n%n", &tick, &first, &last,
                &n) == 3 &&
         n > 0;
    char *line = ok ? text + n : NULL;
    while (ok && line < crc_end) {
        int tx, ty, used = 0;
        unsigned long long tt;
        ok = sscanf(line, "tile %d %d %llu\n%n", &tx, &ty, &tt, &used) == 3 && used > 0 &&
             tx >= 0 && ty >= 0 && tx < c->tiles_x && ty < c->tiles_y;
        if (ok)
            c->tile_tick[ty * c->tiles_x + tx] = tt;
        line += used;
    }
    free(data);
    if (!ok) {
        error_set(err, "store: %s is corrupt (checksum mismatch, truncated or malformed)", path);
        return -1;
    }
    c->tick = tick;
    c->first_seq = first;
    c->last_seq = last;
    return 0;
}

int store_control_write(const store_dir *st, const char *dir, const store_control *c,
                        error_text *err)
{
    size_t cap = 128, len = 0;
    for (int i = 0; i < c->tiles_x * c->tiles_y; i++)
        cap += c->tile_tick[i] ? 48 : 0;
    char *text = malloc(cap + 32);
    if (!text) {
        error_set(err, "store: out of memory writing CONTROL");
        return -1;
    }
    len += (size_t)snprintf(text, cap, "terrad-control 1\ntick %llu\nsegments %llu %llu\n",
                            (unsigned long long)c->tick, (unsigned long long)c->first_seq,
                            (unsigned long long)c->last_seq);
    for (int i = 0; i < c->tiles_x * c->tiles_y; i++)
        if (c->tile_tick[i])
            len += (size_t)snprintf(text + len, cap - len, "tile %d %d %llu\n", i % c->tiles_x,
                                    i / c->tiles_x, (unsigned long long)c->tile_tick[i]);
    len +=
        (size_t)snprintf(text + len, cap + 32 - len, "crc32c %08x\n", store_crc32c(0, text, len));
    int rc = store_dir_write_atomic(st, dir, "CONTROL", text, len, NULL, 0, err);
    free(text);
    return rc;
}

/* Under st->ctl_lock: both the sim and the compaction thread update it. */
int store_control_save(store_dir *st, error_text *err)
{
    pthread_mutex_lock(&st->ctl_lock);
    int rc = store_control_write(st, st->dir, &st->ctl, err);
    pthread_mutex_unlock(&st->ctl_lock);
    return rc;
}
