/*
 * store_recover.c: recovery of a data directory before the first tick — the
 * tile snapshots over the base terrain, then every log segment in order —
 * and the checks that tell a torn tail from damage.
 *
 * Only one thing a crash can leave is cut silently: a torn tail of the newest
 * segment (the record being written; no client saw its tick). Anything else
 * is damage and refuses the start with an error naming the file: a record
 * that fails its checksum with good records after it, a damaged segment that
 * is not the newest, a segment missing from the range CONTROL records, a tile
 * snapshot CONTROL records that is missing or corrupt, a log that ends before
 * the tick CONTROL records as durable. With --recover-truncate the damage is
 * cut instead (the log is cut at the damage, the segments after it renamed
 * *.lost) and the log says exactly which ticks are lost. terrad fsck runs the
 * same checks without changing anything.
 */
#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "store/store_internal.h"

typedef struct recover_state {
    const recover_args *a;
    store_recovery *rec;
    error_text *err;
    uint64_t snapshot_tick;
} recover_state;

/* One damage found. Returns 1 when recovery must stop now (a refused start). */
static int damage(recover_state *s, const char *fmt, ...)
{
    char msg[900];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, sizeof msg, fmt, ap);
    va_end(ap);
    s->rec->damage++;
    if (s->a->flags & STORE_RECOVER_TRUNCATE) {
        log_error("store: damage: %s; --recover-truncate: starting anyway", msg);
        return 0;
    }
    /* the refusal names the damage first: error_text is short, and the
     * operator's way out (fsck, --recover-truncate) is logged beside it */
    if (s->rec->damage == 1)
        error_set(s->err, "store: refusing to start: %s", msg);
    if (s->rec->damage == 1 && !(s->a->flags & STORE_RECOVER_ALL))
        log_error("store: %s is damaged: `terrad fsck --data %s` lists the damage; "
                  "--recover-truncate starts anyway, cutting it and logging what is lost",
                  s->a->dir, s->a->dir);
    if (s->a->flags & STORE_RECOVER_ALL) {
        log_error("store: damage: %s", msg);
        return 0;
    }
    return 1;
}

/* Segment seq, which CONTROL records, is not in the directory: one damage,
 * "SEGMENT is missing (CONTROL records segments F..L): " and what is lost.
 * damage()'s result. */
static int segment_missing(recover_state *s, uint64_t seq, const char *lost)
{
    const store_control *ctl = s->a->ctl;
    char path[1100];
    store_segment_path(s->a->dir, seq, path, sizeof path);
    return damage(s, "%s is missing (CONTROL records segments %llu..%llu): %s", path,
                  (unsigned long long)ctl->first_seq, (unsigned long long)ctl->last_seq, lost);
}

/* Keep a damaged file for the operator instead of replaying or deleting it. */
static void set_aside(const recover_state *s, const char *path)
{
    if (!(s->a->flags & STORE_RECOVER_REPAIR))
        return;
    char lost[1200];
    if (snprintf(lost, sizeof lost, "%.1190s.lost", path) >= (int)sizeof lost)
        return; /* cannot happen: paths here are under 1,100 bytes */
    if (rename(path, lost) == 0)
        log_error("store: %s renamed %s", path, lost);
}

/* Every tile snapshot over the base; then those CONTROL records must all be there. */
static int load_tiles(recover_state *s)
{
    const recover_args *a = s->a;
    char tiles_dir[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", a->dir);
    int tiles_x = (a->w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    DIR *d = opendir(tiles_dir);
    struct dirent *e;
    while (d && (e = readdir(d))) {
        int tx, ty;
        char tail[8];
        if (sscanf(e->d_name, "t-%d-%d.%7s", &tx, &ty, tail) != 3 || strcmp(tail, "snap") != 0)
            continue;
        if (store_cancel_now(a->cancel)) {
            error_set(s->err, "store: cancelled");
            closedir(d);
            return -1;
        }
        char path[1400];
        snprintf(path, sizeof path, "%s/%s", tiles_dir, e->d_name);
        uint64_t tile_tick = 0;
        error_text terr = {{0}};
        if (store_tile_load(path, a->w, a->upto_tick, a->clip, &tile_tick, &terr) != 0) {
            if (!(a->flags & STORE_RECOVER_CHECK)) {
                *s->err = terr;
                closedir(d);
                return -1;
            }
            if (damage(s, "%s; the cells of its tile as of that snapshot are lost",
                       terr.message + 7 /* "store: " */)) {
                closedir(d);
                return -1;
            }
            set_aside(s, path);
            continue;
        }
        if (tile_tick > s->snapshot_tick)
            s->snapshot_tick = tile_tick;
        if (a->found && tx >= 0 && ty >= 0 && tx < a->found->tiles_x && ty < a->found->tiles_y)
            a->found->tile_tick[ty * tiles_x + tx] = tile_tick;
        s->rec->tiles_loaded++;
    }
    if (d)
        closedir(d);
    if (!(a->flags & STORE_RECOVER_CHECK) || !a->ctl || !a->found)
        return 0;
    for (int i = 0; i < a->ctl->tiles_x * a->ctl->tiles_y; i++)
        if (a->ctl->tile_tick[i] && !a->found->tile_tick[i] &&
            damage(s,
                   "%s/tiles/t-%05d-%05d.snap is missing (CONTROL records a snapshot of tick "
                   "%llu): its cells lose the changes up to tick %llu the log no longer holds",
                   a->dir, i % a->ctl->tiles_x, i / a->ctl->tiles_x,
                   (unsigned long long)a->ctl->tile_tick[i],
                   (unsigned long long)a->ctl->tile_tick[i]))
            return -1;
    return 0;
}

/* "ticks A..B are lost", or "ticks from A on are lost" when nothing says how far. */
static void lost_ticks(char *buf, size_t cap, uint64_t from, uint64_t to)
{
    if (to >= from)
        snprintf(buf, cap, "ticks %llu..%llu are lost", (unsigned long long)from,
                 (unsigned long long)to);
    else
        snprintf(buf, cap, "ticks from %llu on are lost", (unsigned long long)from);
}

/* The last tick held by segments seqs[from..count-1] (counted, not applied). */
static uint64_t max_tick_after(const recover_state *s, const uint64_t *seqs, int from, int count)
{
    uint64_t max = 0;
    for (int i = from; i < count; i++) {
        char path[1100];
        store_segment_path(s->a->dir, seqs[i], path, sizeof path);
        replay_result r;
        error_text e = {{0}};
        if (store_segment_replay(path, NULL, NULL, NULL, 0, 0, NULL, &r, &e) != 0)
            continue;
        if (r.last_tick > max)
            max = r.last_tick;
        if (r.later_max_tick > max)
            max = r.later_max_tick;
    }
    return max;
}

/* Returns 1 when the whole segment was removed (its header was torn). */
static int cut_tail(recover_state *s, const char *path, const replay_result *res)
{
    int64_t cut = res->file_len - (res->header_ok ? res->good_len : 0);
    s->rec->bytes_cut += cut;
    int repair = s->a->flags & STORE_RECOVER_REPAIR;
    log_error("store: %s: %s; %s %lld bytes after offset %lld (last good tick %llu)", path,
              res->problem, repair ? "cutting" : "skipping", (long long)cut,
              (long long)(res->header_ok ? res->good_len : 0), (unsigned long long)res->last_tick);
    if (!repair)
        return 0;
    int rc = res->header_ok ? truncate(path, res->good_len) : unlink(path);
    if (rc != 0 || store_dir_fsync(s->a->dir) != 0)
        log_error("store: cannot cut the tail of %s: %s", path, strerror(errno));
    int fd = res->header_ok ? open(path, O_WRONLY | O_CLOEXEC) : -1;
    if (fd >= 0) {
        fsync(fd);
        close(fd);
    }
    return !res->header_ok;
}

/* Replay segments in order; returns the index of the first segment not
 * replayed (count when all were), or -1 on a refused start. */
static int replay_segments(recover_state *s, const uint64_t *seqs, int count, uint64_t *tick)
{
    const recover_args *a = s->a;
    int check = a->flags & STORE_RECOVER_CHECK;
    for (int i = 0; i < count; i++) {
        char path[1100];
        store_segment_path(a->dir, seqs[i], path, sizeof path);
        /* a gap in the sequence CONTROL records: the missing segment's ticks are gone */
        if (check && i > 0 && seqs[i] != seqs[i - 1] + 1 && a->ctl && seqs[i] <= a->ctl->last_seq) {
            char missing[1100];
            store_segment_path(a->dir, seqs[i - 1] + 1, missing, sizeof missing);
            uint64_t to = max_tick_after(s, seqs, i, count);
            if (a->ctl->tick > to)
                to = a->ctl->tick;
            if (damage(s,
                       "%s is missing (CONTROL records segments %llu..%llu): ticks %llu..%llu "
                       "are lost",
                       missing, (unsigned long long)a->ctl->first_seq,
                       (unsigned long long)a->ctl->last_seq, (unsigned long long)*tick + 1,
                       (unsigned long long)to))
                return -1;
            return i;
        }
        replay_result res;
        if (store_segment_replay(path, a->w, a->clip, a->changed, *tick, a->upto_tick, a->cancel,
                                 &res, s->err) != 0)
            return -1;
        s->rec->records_replayed += res.records;
        *tick = res.last_tick;
        if (!res.problem[0])
            continue;
        if (!check && i != count - 1) {
            error_set(s->err,
                      "store: log segment %s is corrupt (%s) and is not the last segment: "
                      "refusing to start rather than skip committed ticks",
                      path, res.problem);
            return -1;
        }
        if (check && (res.later_records > 0 || i != count - 1)) {
            uint64_t to = res.later_max_tick;
            uint64_t after = max_tick_after(s, seqs, i + 1, count);
            to = after > to ? after : to;
            to = a->ctl && a->ctl->tick > to ? a->ctl->tick : to;
            char follow[64] = "", lost[96];
            if (res.later_records > 0)
                snprintf(follow, sizeof follow, ", but %lld good records follow it",
                         (long long)res.later_records);
            lost_ticks(lost, sizeof lost, res.last_tick + 1, to);
            if (damage(s, "%s: %s%s%s: this is damage, not a torn tail; %s", path, res.problem,
                       follow, i != count - 1 ? " in a segment that is not the newest" : "", lost))
                return -1;
            return i + 1 - cut_tail(s, path, &res);
        }
        if (cut_tail(s, path, &res))
            return i; /* a segment with a torn header is gone */
    }
    return count;
}

int store_recover(const recover_args *a, uint64_t *last_seq, store_recovery *rec, error_text *err)
{
    double t0 = time_now_ms();
    memset(rec, 0, sizeof *rec);
    recover_state s = {.a = a, .rec = rec, .err = err};
    /* A compaction may have folded every record into the snapshots and left an
     * empty log: the world is then as of the newest snapshot, and the tick
     * counter must go on from there, never back to 0. */
    if (!(a->flags & STORE_RECOVER_NO_TILES) && load_tiles(&s) != 0)
        return -1;
    uint64_t *seqs;
    int count;
    if (store_list_segments(a->dir, &seqs, &count) != 0) {
        error_set(err, "store: cannot list %s: %s", a->dir, strerror(errno));
        return -1;
    }
    if ((a->flags & STORE_RECOVER_NO_TILES) && (count == 0 || seqs[0] != 1)) {
        /* a replay from the base needs every record: a compaction took the first */
        error_set(err, "store: the first log segment of %s went during the rebuild", a->dir);
        free(seqs);
        return -1;
    }
    int check = a->flags & STORE_RECOVER_CHECK;
    const store_control *ctl = a->ctl;
    uint64_t tick = 0;
    int replayed = count;
    /* the segments CONTROL records must start at its first one */
    if (check && ctl && ctl->last_seq >= ctl->first_seq && ctl->first_seq > 0 &&
        (count == 0 || seqs[count - 1] < ctl->first_seq || seqs[0] > ctl->first_seq)) {
        char lost[100];
        snprintf(lost, sizeof lost, "ticks after %llu up to %llu are lost",
                 (unsigned long long)s.snapshot_tick, (unsigned long long)ctl->tick);
        if (segment_missing(&s, ctl->first_seq, lost))
            goto fail;
        replayed = 0;
    } else if ((replayed = replay_segments(&s, seqs, count, &tick)) < 0) {
        goto fail;
    } else if (check && ctl && count > 0 && seqs[count - 1] < ctl->last_seq && !rec->damage) {
        char lost[120];
        snprintf(lost, sizeof lost,
                 "the ticks it held are lost, every tick after %llu (CONTROL last recorded "
                 "tick %llu)",
                 (unsigned long long)tick, (unsigned long long)ctl->tick);
        if (segment_missing(&s, ctl->last_seq, lost))
            goto fail;
    }
    if (replayed < count && (a->flags & STORE_RECOVER_TRUNCATE))
        for (int i = replayed; i < count; i++) {
            char path[1100];
            store_segment_path(a->dir, seqs[i], path, sizeof path);
            set_aside(&s, path);
        }
    rec->tick = tick > s.snapshot_tick ? tick : s.snapshot_tick;
    /* the newest segments are gone (or cut): the log ends before a durable tick */
    if (check && ctl && rec->tick < ctl->tick && !rec->damage) {
        char newest[1100];
        store_segment_path(a->dir, ctl->last_seq, newest, sizeof newest);
        if (damage(&s,
                   "the log ends at tick %llu but %s/CONTROL records tick %llu as durable (is %s "
                   "missing or cut?): ticks %llu..%llu are lost",
                   (unsigned long long)rec->tick, a->dir, (unsigned long long)ctl->tick, newest,
                   (unsigned long long)rec->tick + 1, (unsigned long long)ctl->tick))
            goto fail;
    }
    if (a->found) {
        a->found->first_seq = replayed > 0 ? seqs[0] : 0;
        a->found->last_seq = replayed > 0 ? seqs[replayed - 1] : 0;
    }
    /* the next segment follows the last one kept, so CONTROL's range has no gap */
    *last_seq = replayed > 0 ? seqs[replayed - 1] : count ? seqs[0] - 1 : 0;
    if (!(a->flags & STORE_RECOVER_REPAIR))
        *last_seq = count ? seqs[count - 1] : 0;
    free(seqs);
    /* ticks that changed nothing are logged only every STORE_TICK_LOG_EVERY
     * ticks: a client may have seen up to that many more */
    rec->tick_floor = rec->tick + STORE_TICK_LOG_EVERY;
    /* a directory that never held a tick: no client can have seen one */
    if (!ctl && rec->records_replayed == 0 && rec->tiles_loaded == 0)
        rec->tick_floor = rec->tick;
    if (ctl && ctl->tick > rec->tick_floor)
        rec->tick_floor = ctl->tick;
    rec->ms = time_now_ms() - t0;
    return (a->flags & STORE_RECOVER_ALL) && rec->damage ? -1 : 0;
fail:
    free(seqs);
    return -1;
}

int store_dir_has_data(const char *dir)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/CONTROL", dir);
    if (access(path, F_OK) == 0)
        return 1;
    uint64_t *seqs;
    int count;
    if (store_list_segments(dir, &seqs, &count) == 0) {
        for (int i = 0; i < count; i++) {
            store_segment_path(dir, seqs[i], path, sizeof path);
            FILE *f = fopen(path, "rb");
            long size = -1;
            if (f && fseek(f, 0, SEEK_END) == 0)
                size = ftell(f);
            if (f)
                fclose(f);
            if (size > WAL_HEADER) {
                free(seqs);
                return 1;
            }
        }
        free(seqs);
    }
    snprintf(path, sizeof path, "%s/tiles", dir);
    DIR *d = opendir(path);
    struct dirent *e;
    int found = 0;
    while (d && !found && (e = readdir(d)))
        found = strstr(e->d_name, ".snap") != NULL;
    if (d)
        closedir(d);
    return found;
}
