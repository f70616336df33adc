/*
 * store.c: the data directory (see store.h and docs/storage.md).
 *
 *   DIR/MANIFEST            JSON naming the world (dims, scale, CRC32C of the
 *                           base terrain) + a line "crc32c XXXXXXXX"
 *   DIR/LOCK                flock'ed while a daemon owns the directory
 *   DIR/wal-<seq>.log       log segments: a 24-byte header, then records
 *   DIR/tiles/t-X-Y.snap    one per 256² tile ever changed
 *
 * Records hold absolute values, not differences, so replaying a record twice,
 * or a record older than a tile snapshot followed by the newer ones, gives the
 * same heights: recovery simply replays every segment still present, in
 * order, over the snapshots. Compaction (its own thread) writes the changed
 * tiles as of a tick boundary and only then deletes the segments before that
 * boundary; a crash anywhere in between leaves either the old segments or the
 * new snapshots, both enough.
 */
#include "store/store.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cjson/cJSON.h>
#include <zstd.h>

#include "metrics/metrics.h"

#define WAL_MAGIC "TRDWAL01"
#define WAL_HEADER 24
#define REC_MAGIC 0x52445254u /* "TRDR" */
#define REC_HEADER 24
#define REC_MAX_PAYLOAD (1u << 30)
#define TILE_MAGIC "TRDTILE1"
#define TILE_HEADER 56
#define RETRY_MS 500.0

/* ---- CRC32C (Castagnoli, reflected 0x82F63B78), table driven ---- */

static uint32_t crc_table[256];
static pthread_once_t crc_once = PTHREAD_ONCE_INIT;

static void crc_init(void)
{
    for (uint32_t i = 0; i < 256; i++) {
        uint32_t c = i;
        for (int k = 0; k < 8; k++)
            c = c & 1 ? (c >> 1) ^ 0x82F63B78u : c >> 1;
        crc_table[i] = c;
    }
}

uint32_t store_crc32c(uint32_t crc, const void *data, size_t len)
{
    pthread_once(&crc_once, crc_init);
    const uint8_t *p = data;
    crc = ~crc;
    while (len--)
        crc = crc_table[(crc ^ *p++) & 0xff] ^ (crc >> 8);
    return ~crc;
}

/* ---- little-endian fields ---- */

static void put32(uint8_t *p, uint32_t v)
{
    for (int i = 0; i < 4; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static void put64(uint8_t *p, uint64_t v)
{
    for (int i = 0; i < 8; i++)
        p[i] = (uint8_t)(v >> (8 * i));
}
static uint32_t get32(const uint8_t *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}
static uint64_t get64(const uint8_t *p)
{
    return (uint64_t)get32(p) | (uint64_t)get32(p + 4) << 32;
}

/* ---- the store ---- */

typedef struct tile_copy {
    int tx, ty;
    world_rect rect;
    int32_t *values;
} tile_copy;

struct store {
    store_config cfg;
    char dir[1024];
    char fault[1024];
    int lock_fd;
    int width, height, tiles_x, tiles_y;

    int wal_fd;
    uint64_t wal_seq;
    int64_t wal_len; /* bytes known good in the current segment */
    uint64_t appended_tick, durable_tick;
    int unsynced; /* records appended since the last fdatasync */
    double last_sync_ms;

    int failed;
    double failed_at_ms;
    char failure[256];

    uint8_t *changed; /* per tile: changed since the last compaction boundary */
    uint8_t *buf;     /* record scratch */
    size_t buf_cap;
    int32_t *values;
    size_t values_cap;
    ZSTD_CCtx *cctx;

    /* compaction: one job at a time, handed over under the mutex */
    pthread_t thread;
    int thread_started;
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int job_ready, job_running, quit;
    tile_copy *job_tiles;
    int job_count;
    uint64_t job_tick, job_first_live_seq;
};

static int fault_active(const store *st)
{
    return st->fault[0] && access(st->fault, F_OK) == 0;
}

/* write() all of it, or fail with errno (ENOSPC from the fault hook too). */
static int write_all(const store *st, int fd, const void *data, size_t len)
{
    if (st && fault_active(st)) {
        errno = ENOSPC;
        return -1;
    }
    const uint8_t *p = data;
    while (len > 0) {
        ssize_t n = write(fd, p, len);
        if (n < 0) {
            if (errno == EINTR)
                continue;
            return -1;
        }
        p += n;
        len -= (size_t)n;
    }
    return 0;
}

static int fsync_dir(const char *dir)
{
    int fd = open(dir, O_RDONLY | O_DIRECTORY);
    if (fd < 0)
        return -1;
    int rc = fsync(fd);
    close(fd);
    return rc;
}

/* Atomic replacement: DIR/name.tmp, fsync, rename, fsync of DIR. */
static int write_atomic(const store *st, const char *dir, const char *name, const void *a,
                        size_t alen, const void *b, size_t blen, error_text *err)
{
    char path[1200], tmp[1210];
    snprintf(path, sizeof path, "%s/%s", dir, name);
    snprintf(tmp, sizeof tmp, "%s.tmp", path);
    int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        error_set(err, "store: cannot create %s: %s", tmp, strerror(errno));
        return -1;
    }
    if (write_all(st, fd, a, alen) != 0 || (blen && write_all(st, fd, b, blen) != 0) ||
        fsync(fd) != 0) {
        error_set(err, "store: writing %s: %s", tmp, strerror(errno));
        close(fd);
        unlink(tmp);
        return -1;
    }
    close(fd);
    if (rename(tmp, path) != 0 || fsync_dir(dir) != 0) {
        error_set(err, "store: renaming %s to %s: %s", tmp, path, strerror(errno));
        unlink(tmp);
        return -1;
    }
    return 0;
}

static int read_file(const char *path, uint8_t **data, size_t *len)
{
    FILE *f = fopen(path, "rb");
    if (!f)
        return -1;
    struct stat sb;
    if (fstat(fileno(f), &sb) != 0 || sb.st_size > (off_t)REC_MAX_PAYLOAD * 2) {
        fclose(f);
        return -1;
    }
    *data = malloc((size_t)sb.st_size + 1);
    if (!*data) {
        fclose(f);
        return -1;
    }
    *len = fread(*data, 1, (size_t)sb.st_size, f);
    fclose(f);
    return 0;
}

static int grow(void **p, size_t *cap, size_t need)
{
    if (need <= *cap)
        return 0;
    size_t c = *cap ? *cap : 4096;
    while (c < need)
        c *= 2;
    void *q = realloc(*p, c);
    if (!q)
        return -1;
    *p = q;
    *cap = c;
    return 0;
}

/* ---- configuration ---- */

int store_parse_durability(const char *text, store_config *c, error_text *err)
{
    if (strcmp(text, "every-tick") == 0) {
        c->durability = STORE_EVERY_TICK;
        return 0;
    }
    if (strcmp(text, "none") == 0) {
        c->durability = STORE_NONE;
        return 0;
    }
    if (strncmp(text, "group:", 6) == 0) {
        char *end;
        long ms = strtol(text + 6, &end, 10);
        if (text[6] && !*end && ms >= 1 && ms <= 10000) {
            c->durability = STORE_GROUP;
            c->group_ms = (int)ms;
            return 0;
        }
    }
    error_set(err, "durability: \"%s\" is not every-tick, none or group:MS (MS in 1..10000)", text);
    return -1;
}

const char *store_durability_name(const store_config *c, char *buf, size_t cap)
{
    if (c->durability == STORE_GROUP)
        snprintf(buf, cap, "group:%d", c->group_ms);
    else
        snprintf(buf, cap, "%s", c->durability == STORE_NONE ? "none" : "every-tick");
    return buf;
}

/* ---- manifest ---- */

/*
 * The manifest names the world by its base terrain. The world is sparse and may
 * be 65,536² cells, so the base is not summed whole: a lattice of up to 257²
 * cells spread evenly over it, corners included, is read from the base
 * (world_base_fill_rect, never the live heights) and checksummed. Another scene's
 * dunes seed, height or heightmap changes these samples.
 */
static uint32_t base_identity(const world *w)
{
    enum { SAMPLES = 257 };
    uint32_t crc = 0;
    int nx = w->width < SAMPLES ? w->width : SAMPLES;
    int ny = w->height < SAMPLES ? w->height : SAMPLES;
    for (int j = 0; j < ny; j++) {
        int y = ny > 1 ? (int)((int64_t)j * (w->height - 1) / (ny - 1)) : 0;
        for (int i = 0; i < nx; i++) {
            int x = nx > 1 ? (int)((int64_t)i * (w->width - 1) / (nx - 1)) : 0;
            int32_t h;
            world_base_fill_rect(w, (world_rect){x, y, 1, 1}, &h);
            uint8_t le[4] = {(uint8_t)h, (uint8_t)(h >> 8), (uint8_t)(h >> 16),
                             (uint8_t)((uint32_t)h >> 24)};
            crc = store_crc32c(crc, le, sizeof le);
        }
    }
    return crc;
}

static char *manifest_text(const world *w, uint32_t base_crc)
{
    char body[512];
    snprintf(body, sizeof body,
             "{\"format\":1,\"width\":%d,\"height\":%d,\"cell_size_m\":%.17g,"
             "\"units_per_m\":%d,\"base_crc32c\":\"%08x\",\"tile_size\":%d}\n",
             w->width, w->height, w->cell_size_m, (int)w->units_per_m, base_crc, STORE_TILE_SIZE);
    size_t n = strlen(body);
    char *out = malloc(n + 32);
    if (out)
        snprintf(out, n + 32, "%scrc32c %08x\n", body, store_crc32c(0, body, n));
    return out;
}

/* Compare the manifest with the world; errors name the file and the field. */
static int manifest_check(const char *path, const world *w, uint32_t base_crc, error_text *err)
{
    uint8_t *data = NULL;
    size_t len = 0;
    if (read_file(path, &data, &len) != 0) {
        error_set(err, "store: cannot read %s: %s", path, strerror(errno));
        return -1;
    }
    data[len] = 0;
    char *text = (char *)data;
    char *crc_line = strstr(text, "}\ncrc32c ");
    unsigned stored = 0;
    if (!crc_line || sscanf(crc_line + 2, "crc32c %8x", &stored) != 1 ||
        store_crc32c(0, text, (size_t)(crc_line + 2 - text)) != stored) {
        error_set(err, "store: %s is corrupt (checksum mismatch or truncated)", path);
        free(data);
        return -1;
    }
    char *expect = manifest_text(w, base_crc);
    int same = expect && strcmp(expect, text) == 0;
    if (!same) {
        cJSON *doc = cJSON_Parse(text);
        const char *fields[] = {"format",      "width",       "height",
                                "cell_size_m", "units_per_m", "base_crc32c"};
        cJSON *want = expect ? cJSON_Parse(expect) : NULL;
        const char *bad = "contents";
        for (size_t i = 0; doc && want && i < sizeof fields / sizeof *fields; i++) {
            cJSON *a = cJSON_GetObjectItemCaseSensitive(doc, fields[i]);
            cJSON *b = cJSON_GetObjectItemCaseSensitive(want, fields[i]);
            if (!cJSON_Compare(a, b, 1)) {
                bad = fields[i];
                break;
            }
        }
        error_set(err,
                  "store: %s belongs to another world or scene (%s differs: the data directory "
                  "was made for a different scene; use another --data directory)",
                  path, bad);
        cJSON_Delete(doc);
        cJSON_Delete(want);
    }
    free(expect);
    free(data);
    return same ? 0 : -1;
}

/* ---- tile snapshots ---- */

static world_rect tile_rect(int width, int height, int tx, int ty)
{
    world_rect r = {tx * STORE_TILE_SIZE, ty * STORE_TILE_SIZE, STORE_TILE_SIZE, STORE_TILE_SIZE};
    if (r.x + r.w > width)
        r.w = width - r.x;
    if (r.y + r.h > height)
        r.h = height - r.y;
    return r;
}

/* Read one tile snapshot into w; errors name the file. */
static int tile_load(const char *path, world *w, uint64_t upto_tick, uint64_t *tick_out,
                     error_text *err)
{
    uint8_t *data = NULL;
    size_t len = 0;
    if (read_file(path, &data, &len) != 0) {
        error_set(err, "store: cannot read tile snapshot %s: %s", path, strerror(errno));
        return -1;
    }
    int rc = -1;
    int32_t *values = NULL;
    if (len < TILE_HEADER || memcmp(data, TILE_MAGIC, 8) != 0 ||
        get32(data + 52) != store_crc32c(0, data, 52)) {
        error_set(err, "store: tile snapshot %s is corrupt (bad header or header checksum)", path);
        goto out;
    }
    uint32_t ww = get32(data + 12), wh = get32(data + 16), tx = get32(data + 20),
             ty = get32(data + 24), comp = get32(data + 44), crc = get32(data + 48);
    if (ww != (uint32_t)w->width || wh != (uint32_t)w->height) {
        error_set(err, "store: tile snapshot %s is for a %ux%u world, this one is %dx%d", path, ww,
                  wh, w->width, w->height);
        goto out;
    }
    if ((size_t)TILE_HEADER + comp != len || store_crc32c(0, data + TILE_HEADER, comp) != crc) {
        error_set(err, "store: tile snapshot %s is corrupt (truncated or payload checksum)", path);
        goto out;
    }
    if (tx >= (uint32_t)((w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE) ||
        ty >= (uint32_t)((w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE)) {
        error_set(err, "store: tile snapshot %s names tile (%u, %u) outside the world", path, tx,
                  ty);
        goto out;
    }
    if (upto_tick && get64(data + 36) > upto_tick) {
        error_set(err,
                  "store: tile snapshot %s is of tick %llu, after tick %llu: the log before it "
                  "was compacted away",
                  path, (unsigned long long)get64(data + 36), (unsigned long long)upto_tick);
        goto out;
    }
    *tick_out = get64(data + 36);
    world_rect r = tile_rect(w->width, w->height, (int)tx, (int)ty);
    size_t raw = (size_t)r.w * r.h * 4;
    values = malloc(raw);
    if (!values || ZSTD_decompress(values, raw, data + TILE_HEADER, comp) != raw) {
        error_set(err, "store: tile snapshot %s does not decompress to %dx%d cells", path, r.w,
                  r.h);
        goto out;
    }
    for (size_t i = 0; i < (size_t)r.w * r.h; i++) {
        int32_t v = (int32_t)get32((uint8_t *)&values[i]);
        if (v < WORLD_HEIGHT_MIN || v > WORLD_HEIGHT_MAX) {
            error_set(err, "store: tile snapshot %s holds a height outside the limits", path);
            goto out;
        }
        values[i] = v;
    }
    world_scatter_window(w, r, values);
    rc = 0;
out:
    free(values);
    free(data);
    return rc;
}

static int tile_write(const store *st, const char *dir, const tile_copy *t, uint64_t tick,
                      ZSTD_CCtx *cctx, int level, error_text *err)
{
    size_t raw = (size_t)t->rect.w * t->rect.h * 4;
    size_t cap = ZSTD_compressBound(raw);
    uint8_t *packed = malloc(cap);
    if (!packed) {
        error_set(err, "store: out of memory compressing a tile");
        return -1;
    }
    size_t n = ZSTD_compressCCtx(cctx, packed, cap, t->values, raw, level);
    if (ZSTD_isError(n)) {
        error_set(err, "store: zstd: %s", ZSTD_getErrorName(n));
        free(packed);
        return -1;
    }
    uint8_t h[TILE_HEADER] = {0};
    memcpy(h, TILE_MAGIC, 8);
    put32(h + 8, 1);
    put32(h + 12, (uint32_t)st->width);
    put32(h + 16, (uint32_t)st->height);
    put32(h + 20, (uint32_t)t->tx);
    put32(h + 24, (uint32_t)t->ty);
    put32(h + 28, (uint32_t)t->rect.w);
    put32(h + 32, (uint32_t)t->rect.h);
    put64(h + 36, tick);
    put32(h + 44, (uint32_t)n);
    put32(h + 48, store_crc32c(0, packed, n));
    put32(h + 52, store_crc32c(0, h, 52));
    char name[64];
    snprintf(name, sizeof name, "t-%05d-%05d.snap", t->tx, t->ty);
    int rc = write_atomic(st, dir, name, h, sizeof h, packed, n, err);
    free(packed);
    return rc;
}

/* ---- log segments ---- */

typedef struct replay_result {
    uint64_t last_tick;
    int64_t records;
    int64_t good_len; /* offset after the last good record */
    int64_t file_len;
    int header_ok;
    char problem[200];
} replay_result;

/* Apply every good record of one segment to w (and mark changed tiles). Stops
 * at the first record that is torn or fails its checksum. */
static int segment_replay(const char *path, world *w, uint8_t *changed, uint64_t after_tick,
                          uint64_t upto_tick, replay_result *res)
{
    memset(res, 0, sizeof *res);
    res->last_tick = after_tick;
    uint8_t *data = NULL;
    size_t len = 0;
    if (read_file(path, &data, &len) != 0)
        return -1;
    res->file_len = (int64_t)len;
    int tiles_x = (w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    if (len < WAL_HEADER || memcmp(data, WAL_MAGIC, 8) != 0 ||
        get32(data + 16) != store_crc32c(0, data, 16)) {
        snprintf(res->problem, sizeof res->problem, "torn or corrupt segment header");
        free(data);
        return 0;
    }
    res->header_ok = 1;
    size_t at = WAL_HEADER;
    res->good_len = WAL_HEADER;
    int32_t *values = NULL;
    size_t values_cap = 0;
    while (at < len) {
        if (len - at < REC_HEADER) {
            snprintf(res->problem, sizeof res->problem, "torn record header at offset %zu", at);
            break;
        }
        const uint8_t *h = data + at;
        uint32_t plen = get32(h + 4);
        uint64_t tick = get64(h + 8);
        if (get32(h) != REC_MAGIC || get32(h + 20) != store_crc32c(0, h, 20) ||
            plen > REC_MAX_PAYLOAD) {
            snprintf(res->problem, sizeof res->problem,
                     "record header at offset %zu fails its checksum", at);
            break;
        }
        if (len - at - REC_HEADER < plen) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu is torn (%u payload bytes, %zu present)",
                     (unsigned long long)tick, at, plen, len - at - REC_HEADER);
            break;
        }
        const uint8_t *p = h + REC_HEADER;
        if (upto_tick && tick > upto_tick)
            break; /* a rebuild as of an earlier tick: the rest is not wanted */
        if (store_crc32c(0, p, plen) != get32(h + 16)) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu fails its payload checksum",
                     (unsigned long long)tick, at);
            break;
        }
        /* checksummed, so a malformed payload is a writer bug: still refuse it */
        uint32_t nrect = plen >= 4 ? get32(p) : 0;
        size_t table = 4 + (size_t)nrect * 16 + 4;
        int ok = plen >= 4 && nrect <= 1u << 20 && table <= plen && tick > res->last_tick;
        uint64_t raw = 0;
        for (uint32_t i = 0; ok && i < nrect; i++) {
            world_rect r = {(int32_t)get32(p + 4 + 16 * i), (int32_t)get32(p + 8 + 16 * i),
                            (int32_t)get32(p + 12 + 16 * i), (int32_t)get32(p + 16 + 16 * i)};
            world_rect c = r;
            ok = r.w > 0 && r.h > 0 && world_clip_rect(w, &c) && c.x == r.x && c.y == r.y &&
                 c.w == r.w && c.h == r.h;
            raw += (uint64_t)r.w * r.h * 4;
        }
        ok = ok && raw == get32(p + table - 4) && raw <= REC_MAX_PAYLOAD &&
             grow((void **)&values, &values_cap, raw + 4) == 0;
        if (ok)
            ok = ZSTD_decompress(values, raw, p + table, plen - table) == raw;
        if (!ok) {
            snprintf(res->problem, sizeof res->problem,
                     "record of tick %llu at offset %zu is malformed", (unsigned long long)tick,
                     at);
            break;
        }
        size_t off = 0;
        for (uint32_t i = 0; i < nrect; i++) {
            world_rect r = {(int32_t)get32(p + 4 + 16 * i), (int32_t)get32(p + 8 + 16 * i),
                            (int32_t)get32(p + 12 + 16 * i), (int32_t)get32(p + 16 + 16 * i)};
            world_scatter_window(w, r, values + off);
            off += (size_t)r.w * r.h;
            if (changed)
                for (int ty = r.y / STORE_TILE_SIZE; ty <= (r.y + r.h - 1) / STORE_TILE_SIZE; ty++)
                    for (int tx = r.x / STORE_TILE_SIZE; tx <= (r.x + r.w - 1) / STORE_TILE_SIZE;
                         tx++)
                        changed[ty * tiles_x + tx] = 1;
        }
        res->records++;
        res->last_tick = tick;
        at += REC_HEADER + plen;
        res->good_len = (int64_t)at;
    }
    free(values);
    free(data);
    return 0;
}

static int compare_u64(const void *a, const void *b)
{
    uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
    return (x > y) - (x < y);
}

/* The log segments' sequence numbers, ascending. */
static int list_segments(const char *dir, uint64_t **seqs, int *count)
{
    *seqs = NULL;
    *count = 0;
    DIR *d = opendir(dir);
    if (!d)
        return -1;
    int cap = 0;
    struct dirent *e;
    while ((e = readdir(d))) {
        unsigned long long seq;
        char tail[8];
        if (sscanf(e->d_name, "wal-%16llu.%7s", &seq, tail) == 2 && strcmp(tail, "log") == 0) {
            if (*count == cap) {
                cap = cap ? cap * 2 : 16;
                uint64_t *n = realloc(*seqs, (size_t)cap * sizeof *n);
                if (!n) {
                    closedir(d);
                    return -1;
                }
                *seqs = n;
            }
            (*seqs)[(*count)++] = seq;
        }
    }
    closedir(d);
    if (*count > 1)
        qsort(*seqs, (size_t)*count, sizeof **seqs, compare_u64);
    return 0;
}

static void segment_path(const char *dir, uint64_t seq, char *out, size_t cap)
{
    snprintf(out, cap, "%s/wal-%016llu.log", dir, (unsigned long long)seq);
}

/* Load tile snapshots, then replay every segment. With `repair`, a torn tail
 * of the last segment is cut off the file; without, it is only skipped. */
static int recover(const char *dir, world *w, uint8_t *changed, int repair, uint64_t upto_tick,
                   uint64_t *last_seq, store_recovery *rec, error_text *err)
{
    double t0 = time_now_ms();
    memset(rec, 0, sizeof *rec);
    char tiles_dir[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", dir);
    /* A compaction may have folded every record into the snapshots and left an
     * empty log: the world is then as of the newest snapshot, and the tick
     * counter must go on from there, never back to 0. */
    uint64_t snapshot_tick = 0;
    DIR *d = opendir(tiles_dir);
    if (d) {
        struct dirent *e;
        while ((e = readdir(d))) {
            size_t n = strlen(e->d_name);
            if (n > 5 && strcmp(e->d_name + n - 5, ".snap") == 0) {
                char path[1400];
                snprintf(path, sizeof path, "%s/%s", tiles_dir, e->d_name);
                uint64_t tile_tick = 0;
                if (tile_load(path, w, upto_tick, &tile_tick, err) != 0) {
                    closedir(d);
                    return -1;
                }
                if (tile_tick > snapshot_tick)
                    snapshot_tick = tile_tick;
                rec->tiles_loaded++;
            }
        }
        closedir(d);
    }
    uint64_t *seqs;
    int count;
    if (list_segments(dir, &seqs, &count) != 0) {
        error_set(err, "store: cannot list %s: %s", dir, strerror(errno));
        return -1;
    }
    uint64_t tick = 0;
    for (int i = 0; i < count; i++) {
        char path[1100];
        segment_path(dir, seqs[i], path, sizeof path);
        replay_result res;
        if (segment_replay(path, w, changed, tick, upto_tick, &res) != 0) {
            error_set(err, "store: cannot read log segment %s: %s", path, strerror(errno));
            free(seqs);
            return -1;
        }
        rec->records_replayed += res.records;
        tick = res.last_tick;
        if (res.problem[0]) {
            if (i != count - 1) {
                /* only the segment being written at a crash can be torn: this is damage */
                error_set(err,
                          "store: log segment %s is corrupt (%s) and is not the last segment: "
                          "refusing to start rather than skip committed ticks",
                          path, res.problem);
                free(seqs);
                return -1;
            }
            int64_t cut = res.file_len - (res.header_ok ? res.good_len : 0);
            rec->bytes_cut = cut;
            log_error("store: %s: %s; %s %lld bytes after offset %lld (last good tick %llu)", path,
                      res.problem, repair ? "cutting" : "skipping", (long long)cut,
                      (long long)(res.header_ok ? res.good_len : 0),
                      (unsigned long long)res.last_tick);
            if (repair) {
                int rc = res.header_ok ? truncate(path, res.good_len) : unlink(path);
                if (rc != 0 || fsync_dir(dir) != 0) {
                    error_set(err, "store: cannot cut the torn tail of %s: %s", path,
                              strerror(errno));
                    free(seqs);
                    return -1;
                }
                if (res.header_ok) {
                    int fd = open(path, O_WRONLY | O_CLOEXEC);
                    if (fd >= 0) {
                        fsync(fd);
                        close(fd);
                    }
                }
            }
        }
    }
    *last_seq = count ? seqs[count - 1] : 0;
    free(seqs);
    rec->tick = tick > snapshot_tick ? tick : snapshot_tick;
    rec->ms = time_now_ms() - t0;
    return 0;
}

/* Start segment seq: header written and synced, directory synced. */
static int segment_start(store *st, uint64_t seq, error_text *err)
{
    char path[1100];
    segment_path(st->dir, seq, path, sizeof path);
    int fd = open(path, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd < 0) {
        error_set(err, "store: cannot create %s: %s", path, strerror(errno));
        return -1;
    }
    uint8_t h[WAL_HEADER] = {0};
    memcpy(h, WAL_MAGIC, 8);
    put64(h + 8, seq);
    put32(h + 16, store_crc32c(0, h, 16));
    if (write_all(st, fd, h, sizeof h) != 0 || fdatasync(fd) != 0 || fsync_dir(st->dir) != 0) {
        error_set(err, "store: cannot start %s: %s", path, strerror(errno));
        close(fd);
        unlink(path);
        return -1;
    }
    if (st->wal_fd >= 0)
        close(st->wal_fd);
    st->wal_fd = fd;
    st->wal_seq = seq;
    st->wal_len = WAL_HEADER;
    return 0;
}

/* ---- compaction thread ---- */

static void *compaction_main(void *arg)
{
    store *st = arg;
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    char tiles_dir[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", st->dir);
    pthread_mutex_lock(&st->lock);
    for (;;) {
        while (!st->job_ready && !st->quit)
            pthread_cond_wait(&st->cond, &st->lock);
        if (!st->job_ready)
            break;
        tile_copy *tiles = st->job_tiles;
        int count = st->job_count;
        uint64_t tick = st->job_tick, live = st->job_first_live_seq;
        st->job_ready = 0;
        st->job_running = 1;
        pthread_mutex_unlock(&st->lock);

        double t0 = time_now_ms();
        error_text err = {{0}};
        int ok = cctx != NULL;
        for (int i = 0; ok && i < count; i++)
            ok = tile_write(st, tiles_dir, &tiles[i], tick, cctx, st->cfg.compression_level,
                            &err) == 0;
        if (ok) {
            /* every changed tile is on disk: the older segments are no longer needed */
            uint64_t *seqs;
            int n;
            if (list_segments(st->dir, &seqs, &n) == 0) {
                for (int i = 0; i < n; i++) {
                    if (seqs[i] >= live)
                        continue;
                    char path[1100];
                    segment_path(st->dir, seqs[i], path, sizeof path);
                    unlink(path);
                }
                free(seqs);
                fsync_dir(st->dir);
            }
            metrics_count_store_compaction(time_now_ms() - t0);
            log_info("store: compacted %d tiles as of tick %llu in %.1f ms", count,
                     (unsigned long long)tick, time_now_ms() - t0);
        } else {
            /* the segments stay, so nothing is lost; the tiles are retried next time */
            metrics_count_store_error("compaction");
            log_error("store: compaction as of tick %llu failed: %s (the log is kept)",
                      (unsigned long long)tick, err.message[0] ? err.message : "out of memory");
        }
        for (int i = 0; i < count; i++)
            free(tiles[i].values);
        free(tiles);

        pthread_mutex_lock(&st->lock);
        st->job_running = 0;
        if (!ok) /* the sim thread re-marks these tiles when it sees the failure */
            st->job_first_live_seq = 0;
        pthread_cond_broadcast(&st->cond);
    }
    pthread_mutex_unlock(&st->lock);
    ZSTD_freeCCtx(cctx);
    return NULL;
}

/* At a tick boundary: start a new segment, copy the changed tiles, hand them
 * to the compaction thread. Skipped while a compaction is still running. */
static void maybe_compact(store *st, const world *w, uint64_t tick)
{
    if (st->wal_len < st->cfg.segment_bytes || !st->thread_started)
        return;
    pthread_mutex_lock(&st->lock);
    int busy = st->job_ready || st->job_running;
    pthread_mutex_unlock(&st->lock);
    if (busy)
        return;
    int n = 0;
    for (int i = 0; i < st->tiles_x * st->tiles_y; i++)
        n += st->changed[i];
    tile_copy *tiles = calloc((size_t)n + 1, sizeof *tiles);
    if (!tiles)
        return;
    int k = 0;
    for (int i = 0; i < st->tiles_x * st->tiles_y; i++) {
        if (!st->changed[i])
            continue;
        tile_copy *t = &tiles[k];
        t->tx = i % st->tiles_x;
        t->ty = i / st->tiles_x;
        t->rect = tile_rect(st->width, st->height, t->tx, t->ty);
        t->values = malloc((size_t)t->rect.w * t->rect.h * 4);
        if (!t->values)
            break;
        world_gather_window(w, t->rect, t->values);
        k++;
    }
    /* every record so far is synced before the old segment is left behind */
    error_text err = {{0}};
    if (k != n || fdatasync(st->wal_fd) != 0 || segment_start(st, st->wal_seq + 1, &err) != 0) {
        for (int i = 0; i < k; i++)
            free(tiles[i].values);
        free(tiles);
        if (err.message[0])
            log_error("%s (compaction postponed)", err.message);
        return;
    }
    st->durable_tick = st->appended_tick;
    st->unsynced = 0;
    memset(st->changed, 0, (size_t)st->tiles_x * st->tiles_y);
    pthread_mutex_lock(&st->lock);
    st->job_tiles = tiles;
    st->job_count = n;
    st->job_tick = tick;
    st->job_first_live_seq = st->wal_seq;
    st->job_ready = 1;
    pthread_cond_broadcast(&st->cond);
    pthread_mutex_unlock(&st->lock);
}

/* ---- open / close ---- */

store *store_open(const store_config *c, world *w, store_recovery *rec, error_text *err)
{
    store *st = calloc(1, sizeof *st);
    if (!st) {
        error_set(err, "store: out of memory");
        return NULL;
    }
    st->cfg = *c;
    if (st->cfg.segment_bytes <= 0)
        st->cfg.segment_bytes = 16 << 20;
    if (st->cfg.compression_level <= 0)
        st->cfg.compression_level = 3;
    st->lock_fd = st->wal_fd = -1;
    pthread_mutex_init(&st->lock, NULL);
    pthread_cond_init(&st->cond, NULL);
    snprintf(st->dir, sizeof st->dir, "%s", c->dir);
    if (c->fault_path)
        snprintf(st->fault, sizeof st->fault, "%s", c->fault_path);
    st->width = w->width;
    st->height = w->height;
    st->tiles_x = (w->width + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    st->tiles_y = (w->height + STORE_TILE_SIZE - 1) / STORE_TILE_SIZE;
    st->changed = calloc((size_t)st->tiles_x * st->tiles_y, 1);
    st->cctx = ZSTD_createCCtx();
    if (!st->changed || !st->cctx) {
        error_set(err, "store: out of memory");
        goto fail;
    }
    char tiles_dir[1100], path[1100];
    snprintf(tiles_dir, sizeof tiles_dir, "%s/tiles", st->dir);
    const char *made = st->dir;
    if ((mkdir(st->dir, 0755) != 0 && errno != EEXIST) ||
        (made = tiles_dir, mkdir(tiles_dir, 0755) != 0 && errno != EEXIST)) {
        error_set(err, "store: --data: cannot create %s: %s", made, strerror(errno));
        goto fail;
    }
    snprintf(path, sizeof path, "%s/LOCK", st->dir);
    st->lock_fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (st->lock_fd < 0 || flock(st->lock_fd, LOCK_EX | LOCK_NB) != 0) {
        error_set(err, "store: %s: %s", path,
                  errno == EWOULDBLOCK ? "the data directory is in use by another terrad"
                                       : strerror(errno));
        goto fail;
    }
    /* the manifest names the world by its base terrain, before anything is applied */
    uint32_t base_crc = base_identity(w);
    snprintf(path, sizeof path, "%s/MANIFEST", st->dir);
    if (access(path, F_OK) == 0) {
        if (manifest_check(path, w, base_crc, err) != 0)
            goto fail;
    } else {
        char *text = manifest_text(w, base_crc);
        int rc =
            text ? write_atomic(NULL, st->dir, "MANIFEST", text, strlen(text), NULL, 0, err) : -1;
        free(text);
        if (rc != 0)
            goto fail;
    }
    uint64_t last_seq = 0;
    if (recover(st->dir, w, st->changed, 1, 0, &last_seq, rec, err) != 0)
        goto fail;
    st->appended_tick = st->durable_tick = rec->tick;
    /* a fresh segment: nothing is ever appended after a possibly cut tail */
    if (segment_start(st, last_seq + 1, err) != 0)
        goto fail;
    st->last_sync_ms = time_now_ms();
    if (pthread_create(&st->thread, NULL, compaction_main, st) == 0)
        st->thread_started = 1;
    metrics_set_store_recovery(rec->ms, rec->records_replayed, rec->bytes_cut);
    metrics_set_store_durable_tick(st->durable_tick);
    metrics_set_store_available(1);
    return st;
fail:
    store_close(st);
    return NULL;
}

void store_close(store *st)
{
    if (!st)
        return;
    if (st->thread_started) {
        pthread_mutex_lock(&st->lock);
        st->quit = 1;
        pthread_cond_broadcast(&st->cond);
        pthread_mutex_unlock(&st->lock);
        pthread_join(st->thread, NULL);
    }
    if (st->job_ready) { /* never picked up */
        for (int i = 0; i < st->job_count; i++)
            free(st->job_tiles[i].values);
        free(st->job_tiles);
    }
    if (st->wal_fd >= 0) {
        fdatasync(st->wal_fd);
        close(st->wal_fd);
    }
    if (st->lock_fd >= 0)
        close(st->lock_fd); /* releases the flock */
    pthread_mutex_destroy(&st->lock);
    pthread_cond_destroy(&st->cond);
    ZSTD_freeCCtx(st->cctx);
    free(st->changed);
    free(st->buf);
    free(st->values);
    free(st);
}

/* ---- the tick ---- */

static void set_failed(store *st, const char *kind, const char *what, int e)
{
    if (!st->failed)
        log_error("store: %s: %s (%s): new deformation is refused until it can be written "
                  "again; reads go on",
                  what, strerror(e), st->dir);
    st->failed = 1;
    st->failed_at_ms = time_now_ms();
    snprintf(st->failure, sizeof st->failure, "%s: %s", what, strerror(e));
    metrics_count_store_error(kind);
    metrics_set_store_available(0);
}

int store_writable(store *st)
{
    if (!st->failed)
        return 1;
    if (time_now_ms() - st->failed_at_ms < RETRY_MS)
        return 0;
    /* retry: cut back anything a failed write left, then see if a write works */
    st->failed_at_ms = time_now_ms();
    if (fault_active(st) || ftruncate(st->wal_fd, st->wal_len) != 0 ||
        lseek(st->wal_fd, st->wal_len, SEEK_SET) < 0 || fdatasync(st->wal_fd) != 0)
        return 0;
    log_info("store: %s is writable again: deformation resumes", st->dir);
    st->durable_tick = st->appended_tick; /* held group-commit ticks are synced now */
    st->unsynced = 0;
    metrics_set_store_durable_tick(st->durable_tick);
    st->failed = 0;
    st->failure[0] = 0;
    metrics_set_store_available(1);
    return 1;
}

const char *store_failure(const store *st)
{
    return st->failure;
}

uint64_t store_durable_tick(const store *st)
{
    return st->durable_tick;
}

static int sync_now(store *st)
{
    double t0 = time_now_ms();
    if (fdatasync(st->wal_fd) != 0) {
        set_failed(st, "fsync", "fdatasync of the log", errno);
        return -1;
    }
    double now = time_now_ms();
    metrics_observe_store_fsync_ms(now - t0);
    st->last_sync_ms = now;
    st->durable_tick = st->appended_tick;
    st->unsynced = 0;
    metrics_set_store_durable_tick(st->durable_tick);
    return 0;
}

int store_commit_tick(store *st, const world *w, uint64_t tick, const world_rect *rects, int n)
{
    if (st->failed)
        return -1;
    if (n <= 0)
        return 0;
    size_t cells = 0;
    for (int i = 0; i < n; i++)
        cells += (size_t)rects[i].w * rects[i].h;
    size_t raw = cells * 4;
    size_t table = 4 + (size_t)n * 16 + 4;
    size_t bound = ZSTD_compressBound(raw);
    if (grow((void **)&st->values, &st->values_cap, raw + 4) != 0 ||
        grow((void **)&st->buf, &st->buf_cap, REC_HEADER + table + bound) != 0) {
        set_failed(st, "memory", "no memory for a log record", ENOMEM);
        return -1;
    }
    uint8_t *p = st->buf + REC_HEADER;
    put32(p, (uint32_t)n);
    size_t off = 0;
    for (int i = 0; i < n; i++) {
        world_rect r = rects[i];
        put32(p + 4 + 16 * i, (uint32_t)r.x);
        put32(p + 8 + 16 * i, (uint32_t)r.y);
        put32(p + 12 + 16 * i, (uint32_t)r.w);
        put32(p + 16 + 16 * i, (uint32_t)r.h);
        world_gather_window(w, r, st->values + off);
        off += (size_t)r.w * r.h;
        for (int ty = r.y / STORE_TILE_SIZE; ty <= (r.y + r.h - 1) / STORE_TILE_SIZE; ty++)
            for (int tx = r.x / STORE_TILE_SIZE; tx <= (r.x + r.w - 1) / STORE_TILE_SIZE; tx++)
                st->changed[ty * st->tiles_x + tx] = 1;
    }
    put32(p + table - 4, (uint32_t)raw);
    size_t packed =
        ZSTD_compressCCtx(st->cctx, p + table, bound, st->values, raw, st->cfg.compression_level);
    if (ZSTD_isError(packed)) {
        set_failed(st, "compress", "zstd compression of a log record", EIO);
        return -1;
    }
    size_t plen = table + packed;
    uint8_t *h = st->buf;
    put32(h, REC_MAGIC);
    put32(h + 4, (uint32_t)plen);
    put64(h + 8, tick);
    put32(h + 16, store_crc32c(0, p, plen));
    put32(h + 20, store_crc32c(0, h, 20));
    if (write_all(st, st->wal_fd, st->buf, REC_HEADER + plen) != 0) {
        int e = errno;
        /* leave the log exactly as it was: a half-written record is cut now (and
         * would be cut as a torn tail by recovery anyway) */
        if (ftruncate(st->wal_fd, st->wal_len) == 0)
            lseek(st->wal_fd, st->wal_len, SEEK_SET);
        set_failed(st, e == ENOSPC ? "enospc" : "write", "appending to the log", e);
        return -1;
    }
    int64_t before = st->wal_len;
    uint64_t before_tick = st->appended_tick;
    st->wal_len += (int64_t)(REC_HEADER + plen);
    st->appended_tick = tick;
    st->unsynced++;
    metrics_count_store_wal_bytes(REC_HEADER + plen);
    if (st->cfg.durability == STORE_EVERY_TICK && sync_now(st) != 0) {
        /* the caller undoes this tick, so its record must not survive to be replayed */
        st->wal_len = before;
        st->appended_tick = before_tick;
        if (ftruncate(st->wal_fd, before) == 0)
            lseek(st->wal_fd, before, SEEK_SET);
        return -1;
    } else if (st->cfg.durability == STORE_NONE) {
        st->durable_tick = tick; /* as durable as promised: in the page cache */
        metrics_set_store_durable_tick(tick);
    }
    maybe_compact(st, w, tick);
    return 0;
}

int store_settle(store *st)
{
    if (st->durable_tick == st->appended_tick)
        return 1;
    if (st->cfg.durability != STORE_GROUP)
        return 0; /* every-tick after a failed sync: held until a retry syncs */
    if (time_now_ms() - st->last_sync_ms < st->cfg.group_ms)
        return 0;
    return sync_now(st) == 0;
}

int store_load_readonly(const char *dir, world *w, uint64_t upto_tick, store_recovery *rec,
                        error_text *err)
{
    char path[1100];
    snprintf(path, sizeof path, "%s/MANIFEST", dir);
    uint32_t base_crc = base_identity(w);
    if (manifest_check(path, w, base_crc, err) != 0)
        return -1;
    uint64_t last_seq;
    return recover(dir, w, NULL, 0, upto_tick, &last_seq, rec, err);
}
