/*
 * test_store.c: the data directory (server/store) on real files under /tmp —
 * round trips through the log and through compaction into tile snapshots,
 * a torn tail cut, a bit flip in a log record detected, a corrupt segment
 * that is not the last refused, truncated and bit-flipped tile snapshots
 * refused naming the file, a manifest of another world refused, the
 * directory lock, the ENOSPC fault hook (nothing appended, recovery when it
 * goes), group commit's promise, no temporary files left behind, the
 * bekker model's per-cell soil state and the compaction memory through the
 * log and snapshots (old formats still read), a replay cursor cancelled
 * before and during its rebuild and between its steps.
 */
#include "test_params.h"
#include <dirent.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include <zstd.h>

#include "store/store.h"
#include "world/world.h"
#include "check.h"

#define W 600 /* 3 x 2 tiles, the last column and row partial */
#define H 300

static char dir[256];
static uint32_t rng = 12345u;

static void make_base(world *w)
{
    test_dunes_world(w, W, H, 7);
}

/* The whole world, dense (W * H is small here). */
static int32_t *dense_copy(const world *w)
{
    int32_t *all = malloc((size_t)W * H * sizeof *all);
    if (!all)
        exit(2);
    world_gather_window(w, (world_rect){0, 0, W, H}, all);
    return all;
}

static void fresh_dir(void)
{
    char cmd[300];
    snprintf(cmd, sizeof cmd, "rm -rf %s", dir);
    if (system(cmd) != 0)
        exit(2);
}

static store *open_dir(world *w, store_recovery *rec, int64_t segment_bytes, error_text *err)
{
    store_config c = {.dir = dir, .durability = STORE_EVERY_TICK, .segment_bytes = segment_bytes};
    char fault[300];
    snprintf(fault, sizeof fault, "%s.fault", dir);
    c.fault_path = fault;
    return store_open(&c, w, rec, err);
}

/* Change a random rectangle of w (as a tick would) and log it. */
static int random_tick(store *st, world *w, uint64_t tick)
{
    world_rect r[2];
    for (int k = 0; k < 2; k++) {
        r[k].w = 1 + (int)(test_next_random(&rng) % 80);
        r[k].h = 1 + (int)(test_next_random(&rng) % 80);
        r[k].x = (int)(test_next_random(&rng) % (uint32_t)(W - r[k].w));
        /* one rectangle in the top half, one on the bottom edge (the partial tiles) */
        r[k].y = k == 0 ? (int)(test_next_random(&rng) % (uint32_t)(H / 2 - r[k].h)) : H - r[k].h;
        int32_t *cells = malloc((size_t)r[k].w * r[k].h * sizeof *cells);
        if (!cells)
            exit(2);
        world_gather_window(w, r[k], cells);
        for (int i = 0; i < r[k].w * r[k].h; i++)
            cells[i] += (int32_t)(test_next_random(&rng) % 200) - 100;
        world_scatter_window(w, r[k], cells);
        free(cells);
    }
    return store_commit_tick(st, w, tick, r, 2);
}

static int same_heights(const world *a, const world *b)
{
    int32_t *da = dense_copy(a), *db = dense_copy(b);
    int same = memcmp(da, db, (size_t)W * H * 4) == 0;
    free(da);
    free(db);
    return same;
}

static int count_files(const char *path, const char *suffix)
{
    DIR *d = opendir(path);
    int n = 0;
    struct dirent *e;
    while (d && (e = readdir(d))) {
        size_t l = strlen(e->d_name), s = strlen(suffix);
        n += l >= s && strcmp(e->d_name + l - s, suffix) == 0;
    }
    if (d)
        closedir(d);
    return n;
}

/* The path of the n-th (0-based) log segment in name order. */
static void segment_name(int n, char *out, size_t cap)
{
    struct dirent **list;
    int count = scandir(dir, &list, NULL, alphasort), k = 0;
    out[0] = 0;
    for (int i = 0; i < count; i++) {
        if (strncmp(list[i]->d_name, "wal-", 4) == 0 && k++ == n)
            snprintf(out, cap, "%s/%s", dir, list[i]->d_name);
        free(list[i]);
    }
    free(list);
}

static long file_size(const char *path)
{
    struct stat sb;
    return stat(path, &sb) == 0 ? (long)sb.st_size : -1;
}

static void flip_byte(const char *path, long offset)
{
    FILE *f = fopen(path, "r+b");
    if (!f)
        return;
    fseek(f, offset, SEEK_SET);
    int c = fgetc(f);
    fseek(f, offset, SEEK_SET);
    fputc(c ^ 0x10, f);
    fclose(f);
}

static void test_crc(void)
{
    CHECK(store_crc32c(0, "123456789", 9) == 0xE3069283u, "CRC32C check value: %08x",
          store_crc32c(0, "123456789", 9));
    uint32_t part = store_crc32c(0, "1234", 4);
    CHECK(store_crc32c(part, "56789", 5) == 0xE3069283u, "CRC32C continues across calls");
}

static void test_round_trip(void)
{
    fresh_dir();
    world live, back;
    make_base(&live);
    make_base(&back);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 0, &err);
    CHECK(st && rec.tick == 0 && rec.records_replayed == 0, "new directory: %s", err.message);
    if (!st)
        return;
    for (uint64_t t = 1; t <= 40; t++)
        CHECK(random_tick(st, &live, t * 2) == 0, "tick %llu logged", (unsigned long long)t);
    CHECK(store_settle(st) == 1 && store_durable_tick(st) == 80, "every-tick: durable at once");
    CHECK(store_commit_tick(st, &live, 81, NULL, 0) == 0, "a tick without changes logs nothing");
    store_close(st);
    st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 80 && rec.records_replayed == 40 && rec.bytes_cut == 0,
          "recovered tick %llu, %lld records: %s", (unsigned long long)rec.tick,
          (long long)rec.records_replayed, err.message);
    CHECK(same_heights(&live, &back), "heights after a log replay equal the live world");
    store_close(st);

    /* read-only recovery sees the same and writes nothing */
    world ro;
    make_base(&ro);
    CHECK(store_load_readonly(dir, &ro, 0, &rec, &err) == 0 && same_heights(&live, &ro),
          "read-only load: %s", err.message);
    world_free(&ro);
    world_free(&live);
    world_free(&back);
}

static void test_compaction(void)
{
    fresh_dir();
    world live, back;
    make_base(&live);
    make_base(&back);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 20000, &err); /* a small segment: compact often */
    if (!st) {
        CHECK(0, "open: %s", err.message);
        return;
    }
    for (uint64_t t = 1; t <= 120; t++)
        random_tick(st, &live, t);
    store_close(st); /* waits for the running compaction */
    char tiles[300];
    snprintf(tiles, sizeof tiles, "%s/tiles", dir);
    CHECK(count_files(tiles, ".snap") == 6, "every changed tile has a snapshot (%d)",
          count_files(tiles, ".snap"));
    CHECK(count_files(dir, ".log") < 10, "old log segments were deleted (%d left)",
          count_files(dir, ".log"));
    CHECK(count_files(tiles, ".tmp") == 0 && count_files(dir, ".tmp") == 0,
          "atomic writes leave no temporary files");
    st = open_dir(&back, &rec, 20000, &err);
    CHECK(st && rec.tick == 120 && rec.tiles_loaded == 6, "recovered tick %llu from %d tiles: %s",
          (unsigned long long)rec.tick, rec.tiles_loaded, err.message);
    CHECK(same_heights(&live, &back), "snapshots + log replay equal the live world");
    /* go on after recovery, then recover again */
    for (uint64_t t = 121; t <= 150; t++)
        random_tick(st, &back, t);
    store_close(st);
    world again;
    make_base(&again);
    st = open_dir(&again, &rec, 20000, &err);
    CHECK(st && rec.tick == 150, "second recovery: tick %llu (%s)", (unsigned long long)rec.tick,
          err.message);
    CHECK(st && same_heights(&back, &again), "second recovery: the heights of tick 150");
    store_close(st);

    world ro;
    make_base(&ro);
    CHECK(store_load_readonly(dir, &ro, 2, &rec, &err) != 0 && strstr(err.message, "compacted"),
          "a rebuild as of a compacted tick is refused: %s", err.message);
    world_free(&ro);

    /* a truncated, then a bit-flipped tile snapshot: refused, naming the file */
    char snap[400];
    snprintf(snap, sizeof snap, "%s/t-00001-00000.snap", tiles);
    long size = file_size(snap);
    CHECK(size > 100 && truncate(snap, size - 7) == 0, "truncate %s", snap);
    world bad;
    make_base(&bad);
    st = open_dir(&bad, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "t-00001-00000.snap") && strstr(err.message, "corrupt"),
          "truncated snapshot refused: %s", err.message);
    store_close(st);
    CHECK(truncate(snap, size) == 0, "restore length");
    flip_byte(snap, size - 7); /* the zero bytes truncate put back are wrong anyway */
    world_free(&bad);
    make_base(&bad);
    st = open_dir(&bad, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "t-00001-00000.snap"), "damaged snapshot refused: %s",
          err.message);
    store_close(st);
    /* a flipped header byte */
    fresh_dir();
    world_free(&bad);
    world_free(&live);
    world_free(&back);
    world_free(&again);
}

static void test_flipped_snapshot_header(void)
{
    fresh_dir();
    world live;
    make_base(&live);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 4096, &err);
    for (uint64_t t = 1; t <= 20 && st; t++)
        random_tick(st, &live, t);
    store_close(st);
    char snap[400];
    snprintf(snap, sizeof snap, "%s/tiles/t-00000-00000.snap", dir);
    flip_byte(snap, 21); /* inside the tile coordinates */
    world bad;
    make_base(&bad);
    st = open_dir(&bad, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "t-00000-00000.snap") && strstr(err.message, "checksum"),
          "bit flip in a snapshot header refused: %s", err.message);
    store_close(st);
    world_free(&bad);
    world_free(&live);
}

/* Log 10 ticks, keeping a copy of the world after tick 9. */
static store *ten_ticks(world *live, world *at9, error_text *err)
{
    fresh_dir();
    make_base(live);
    make_base(at9);
    store_recovery rec;
    store *st = open_dir(live, &rec, 0, err);
    for (uint64_t t = 1; t <= 10 && st; t++) {
        random_tick(st, live, t);
        if (t == 9) {
            int32_t *all = dense_copy(live);
            world_scatter_window(at9, (world_rect){0, 0, W, H}, all);
            free(all);
        }
    }
    return st;
}

/* store_close as a crash leaves the directory: CONTROL as it was while the
 * store ran (a clean close records the last tick as durable, after which a
 * cut tail would be damage, not a crash's torn write). */
static void close_as_crash(store *st)
{
    char path[700];
    snprintf(path, sizeof path, "%s/CONTROL", dir);
    uint8_t *data = NULL;
    size_t len = 0;
    error_text err = {{0}};
    int have = file_read_all(path, 1 << 24, &data, &len, &err) == 0;
    store_close(st);
    FILE *f = have ? fopen(path, "wb") : NULL;
    CHECK(f && fwrite(data, 1, len, f) == len && fclose(f) == 0, "CONTROL put back: %s",
          err.message);
    free(data);
}

static void test_torn_tail(void)
{
    world live, at9, back;
    error_text err = {{0}};
    store_recovery rec;
    close_as_crash(ten_ticks(&live, &at9, &err));
    world ro;
    make_base(&ro);
    CHECK(store_load_readonly(dir, &ro, 9, &rec, &err) == 0 && rec.tick == 9 &&
              same_heights(&ro, &at9),
          "rebuilt as of tick 9: %s", err.message);
    world_free(&ro);
    char seg[700];
    segment_name(0, seg, sizeof seg);
    long size = file_size(seg);
    CHECK(size > 100 && truncate(seg, size - 5) == 0, "tear the last record of %s", seg);
    make_base(&back);
    store *st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 9 && rec.bytes_cut > 0, "torn tail cut: tick %llu, %lld bytes: %s",
          (unsigned long long)rec.tick, (long long)rec.bytes_cut, err.message);
    CHECK(same_heights(&back, &at9), "heights are tick 9's: the torn record is never loaded");
    CHECK(file_size(seg) < size - 5, "the torn tail was cut off the file (%ld)", file_size(seg));
    store_close(st);
    world_free(&live);
    world_free(&at9);
    world_free(&back);
}

static void test_flipped_record(void)
{
    world live, at9, back;
    error_text err = {{0}};
    store_recovery rec;
    close_as_crash(ten_ticks(&live, &at9, &err));
    char seg[700];
    segment_name(0, seg, sizeof seg);
    flip_byte(seg, file_size(seg) - 20); /* inside tick 10's compressed values */
    make_base(&back);
    store *st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 9 && rec.bytes_cut > 0 && same_heights(&back, &at9),
          "a bit flip in the last record is detected and cut: tick %llu: %s",
          (unsigned long long)rec.tick, err.message);
    store_close(st);

    /* the same damage in a segment that is not the last: refused, naming it */
    world_free(&live);
    world_free(&at9);
    world_free(&back);
    store_close(ten_ticks(&live, &at9, &err));
    make_base(&back);
    st = open_dir(&back, &rec, 0, &err); /* starts a second segment */
    store_close(st);
    segment_name(0, seg, sizeof seg);
    flip_byte(seg, file_size(seg) - 20);
    world_free(&back);
    make_base(&back);
    st = open_dir(&back, &rec, 0, &err);
    CHECK(!st && strstr(err.message, seg) && strstr(err.message, "not the newest"),
          "corrupt earlier segment refused: %s", err.message);
    store_close(st);
    world_free(&live);
    world_free(&at9);
    world_free(&back);
}

static void test_manifest_and_lock(void)
{
    fresh_dir();
    world a, other;
    make_base(&a);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&a, &rec, 0, &err);
    store *second = open_dir(&a, &rec, 0, &err);
    CHECK(st && !second && strstr(err.message, "in use"), "a second daemon is refused: %s",
          err.message);
    store_close(st);
    test_dunes_world(&other, W, H, 8); /* another scene's base terrain */
    st = open_dir(&other, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "MANIFEST") && strstr(err.message, "base_crc32c"),
          "another scene's directory refused: %s", err.message);
    store_close(st);
    world small;
    world_init(&small, 100, 100, 0.1, 10000, WORLD_HEIGHT_MIN, &err);
    st = open_dir(&small, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "width"), "another world size refused: %s", err.message);
    store_close(st);
    char manifest[300];
    snprintf(manifest, sizeof manifest, "%s/MANIFEST", dir);
    flip_byte(manifest, 12);
    st = open_dir(&a, &rec, 0, &err);
    CHECK(!st && strstr(err.message, "MANIFEST is corrupt"), "damaged manifest refused: %s",
          err.message);
    store_close(st);
    world_free(&a);
    world_free(&other);
    world_free(&small);
}

static void sleep_ms(int ms)
{
    struct timespec ts = {ms / 1000, (ms % 1000) * 1000000L};
    nanosleep(&ts, NULL);
}

static void test_fault_hook(void)
{
    fresh_dir();
    world live, back;
    make_base(&live);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 0, &err);
    if (!st) {
        CHECK(0, "open: %s", err.message);
        return;
    }
    for (uint64_t t = 1; t <= 5; t++)
        random_tick(st, &live, t);
    char seg[700], fault[300];
    segment_name(0, seg, sizeof seg);
    long size = file_size(seg);
    snprintf(fault, sizeof fault, "%s.fault", dir);
    FILE *f = fopen(fault, "w");
    if (f)
        fclose(f);
    int32_t *before = dense_copy(&live);
    CHECK(random_tick(st, &live, 6) == -1, "a write under the fault hook fails");
    CHECK(strstr(store_failure(st), "No space left"), "the reason says ENOSPC: %s",
          store_failure(st));
    CHECK(store_writable(st) == 0 && file_size(seg) == size, "unwritable; the log is unchanged");
    world_scatter_window(&live, (world_rect){0, 0, W, H}, before); /* the service undoes the tick */
    free(before);
    sleep_ms(600);
    CHECK(store_writable(st) == 0, "still unwritable while the fault file exists");
    unlink(fault);
    sleep_ms(600);
    CHECK(store_writable(st) == 1 && store_failure(st)[0] == 0, "writable again once it is gone");
    CHECK(random_tick(st, &live, 7) == 0, "ticks are logged again");
    store_close(st);
    make_base(&back);
    st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 7 && rec.bytes_cut == 0 && same_heights(&live, &back),
          "nothing on disk was damaged: tick %llu: %s", (unsigned long long)rec.tick, err.message);
    store_close(st);
    world_free(&live);
    world_free(&back);
}

static void test_group_commit(void)
{
    fresh_dir();
    world live;
    make_base(&live);
    error_text err = {{0}};
    store_config c = {.dir = dir};
    CHECK(store_parse_durability("group:150", &c, &err) == 0 && c.durability == STORE_GROUP &&
              c.group_ms == 150,
          "group:150 parses");
    CHECK(store_parse_durability("group:0", &c, &err) != 0 && strstr(err.message, "group:MS"),
          "group:0 refused: %s", err.message);
    CHECK(store_parse_durability("sometimes", &c, &err) != 0, "unknown policy refused");
    store_parse_durability("group:150", &c, &err);
    store_recovery rec;
    store *st = store_open(&c, &live, &rec, &err);
    if (!st) {
        CHECK(0, "open: %s", err.message);
        return;
    }
    sleep_ms(200);
    random_tick(st, &live, 1);
    CHECK(store_settle(st) == 1 && store_durable_tick(st) == 1, "first tick after a pause: synced");
    random_tick(st, &live, 2);
    CHECK(store_settle(st) == 0 && store_durable_tick(st) == 1,
          "within the group interval: held, not durable yet");
    sleep_ms(200);
    CHECK(store_settle(st) == 1 && store_durable_tick(st) == 2, "after the interval: synced");
    store_close(st);
    world_free(&live);
}

/* A per-cell layer of the world, as these tests drive it: the soil state or
 * the compaction memory, how far right its ticks reach
 * (so the right-hand tiles never hold any) and how a tick changes a value. */
typedef struct test_layer {
    world_layer_id id;
    int x_max;
    int32_t (*next)(int32_t old, int64_t i, int k);
} test_layer;

/* 1 when a's layer equals b's, cell for cell and in every field's kept sum. */
static int same_layer(const world *a, const world *b, const test_layer *l)
{
    size_t ints = (size_t)W * H * (size_t)world_layer_fields(l->id);
    int32_t *da = malloc(ints * 4), *db = malloc(ints * 4);
    if (!da || !db)
        exit(2);
    world_layer_gather(a, l->id, (world_rect){0, 0, W, H}, da);
    world_layer_gather(b, l->id, (world_rect){0, 0, W, H}, db);
    int same = memcmp(da, db, ints * 4) == 0;
    free(da);
    free(db);
    for (int f = 0; f < world_layer_fields(l->id); f++)
        same &= world_layer_sum(a, l->id, f) == world_layer_sum(b, l->id, f);
    return same;
}

/* A tick of a model with per-cell state: heights fall and the state changes
 * in one rectangle, and the state alone in another (heights untouched: a
 * wheel resting while its shear resets, a column pressed and refilled by its
 * neighbours in the same tick). */
static int layer_tick(store *st, world *w, uint64_t tick, const test_layer *l)
{
    world_rect r[2];
    for (int k = 0; k < 2; k++) {
        r[k].w = 1 + (int)(test_next_random(&rng) % 60);
        r[k].h = 1 + (int)(test_next_random(&rng) % 60);
        r[k].x = (int)(test_next_random(&rng) % (uint32_t)(l->x_max - r[k].w));
        r[k].y = (int)(test_next_random(&rng) % (uint32_t)(H - r[k].h));
        int64_t n = (int64_t)r[k].w * r[k].h;
        int32_t *cells = malloc((size_t)n * (size_t)world_layer_fields(l->id) * sizeof *cells);
        if (!cells)
            exit(2);
        if (k == 0) {
            world_gather_window(w, r[k], cells);
            for (int64_t i = 0; i < n; i++)
                cells[i] -= (int32_t)(test_next_random(&rng) % 50);
            world_scatter_window(w, r[k], cells);
        }
        world_layer_gather(w, l->id, r[k], cells);
        for (int64_t i = 0; i < n * world_layer_fields(l->id); i++)
            cells[i] = l->next(cells[i], i, k);
        if (world_layer_scatter(w, l->id, r[k], cells) != 0)
            exit(2);
        free(cells);
    }
    return store_commit_tick(st, w, tick, r, 2);
}

/* bekker's soil: the shear (field 1) reset where only the state changes */
static int32_t soil_next(int32_t old, int64_t i, int k)
{
    return k == 1 && i % WORLD_SOIL_FIELDS == 1 ? 0
                                                : old + (int32_t)(test_next_random(&rng) % 1000);
}

static const test_layer soil_layer = {WORLD_LAYER_SOIL, 400, soil_next};

/* The per-cell soil state (issue 21) through the log and through snapshots
 * (format 2 where a tile holds soil, format 1 elsewhere), recovered exactly
 * into a world that has none yet (recovery runs before the engine). */
static void test_soil_state(void)
{
    fresh_dir();
    world live, back, again;
    make_base(&live);
    make_base(&back);
    make_base(&again);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 0, &err);
    CHECK(st && world_layer_enable(&live, WORLD_LAYER_SOIL) == 0, "open: %s", err.message);
    if (!st)
        return;
    for (uint64_t t = 1; t <= 30; t++)
        CHECK(layer_tick(st, &live, t, &soil_layer) == 0, "soil tick %llu logged",
              (unsigned long long)t);
    world_rect far = {500, 10, 20, 20}; /* heights only, in a tile without soil */
    int32_t *cells = malloc((size_t)far.w * far.h * sizeof *cells);
    world_gather_window(&live, far, cells);
    cells[0] += 7;
    world_scatter_window(&live, far, cells);
    free(cells);
    CHECK(store_commit_tick(st, &live, 31, &far, 1) == 0, "a tick without soil changes");
    store_close(st);
    st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 31 && rec.records_replayed == 31, "log replay: tick %llu: %s",
          (unsigned long long)rec.tick, err.message);
    CHECK(same_heights(&live, &back) && same_layer(&live, &back, &soil_layer),
          "log replay: heights and every cell's soil state as they were");
    CHECK(world_layer_sum(&back, WORLD_LAYER_SOIL, 2) > 0, "the soil state is not all zeros");
    store_close(st);

    /* compaction into snapshots, then recovery from them */
    st = open_dir(&back, &rec, 20000, &err);
    for (uint64_t t = 32; t <= 140 && st; t++)
        layer_tick(st, &back, t, &soil_layer);
    store_close(st);
    st = open_dir(&again, &rec, 20000, &err);
    CHECK(st && rec.tick == 140 && rec.tiles_loaded > 0, "snapshots: tick %llu, %d tiles: %s",
          (unsigned long long)rec.tick, rec.tiles_loaded, err.message);
    CHECK(same_heights(&back, &again) && same_layer(&back, &again, &soil_layer),
          "snapshots + log: heights and every cell's soil state as they were");
    store_close(st);
    char snap[400];
    snprintf(snap, sizeof snap, "%s/tiles/t-00000-00000.snap", dir);
    FILE *f = fopen(snap, "rb");
    unsigned char head[12] = {0};
    CHECK(f && fread(head, 1, sizeof head, f) == sizeof head && head[8] == 2,
          "a tile with soil is snapshot in format 2 (%u)", head[8]);
    if (f)
        fclose(f);
    world_free(&live);
    world_free(&back);
    world_free(&again);
}

/* the compaction memory: grows, never past its maximum */
static int32_t memory_next(int32_t old, int64_t i, int k)
{
    (void)i, (void)k;
    int32_t m = old + (int32_t)(test_next_random(&rng) % 700);
    return m > WORLD_COMPACTION_MAX ? WORLD_COMPACTION_MAX : m;
}

/* left of x = 256: the right-hand tiles never hold any */
static const test_layer memory_layer = {WORLD_LAYER_COMPACTION, 256, memory_next};

static unsigned snapshot_format(int tx, int ty)
{
    char snap[400];
    snprintf(snap, sizeof snap, "%s/tiles/t-%05d-%05d.snap", dir, tx, ty);
    FILE *f = fopen(snap, "rb");
    unsigned char head[12] = {0};
    int ok = f && fread(head, 1, sizeof head, f) == sizeof head;
    if (f)
        fclose(f);
    return ok ? head[8] : 0;
}

/* The compaction memory (issue 28) through the log and snapshots: a
 * directory the code before it wrote (a world without the layer: records
 * without bit 30, format 1 snapshots) still loads with its heights and zero
 * memory; records with the memory (bit 30) and format 3 snapshots after it
 * recover every cell's memory and Σ memory exactly; a record holding a memory
 * outside [0, 65535] is refused whole. */
static void test_compaction_memory(void)
{
    fresh_dir();
    world old, live, back, again;
    make_base(&old);
    make_base(&live);
    make_base(&back);
    make_base(&again);
    error_text err = {{0}};
    store_recovery rec;
    /* the old format: what a persson world's store held before the memory was kept */
    store *st = open_dir(&old, &rec, 20000, &err);
    for (uint64_t t = 1; t <= 60 && st; t++)
        CHECK(random_tick(st, &old, t) == 0, "old-format tick %llu", (unsigned long long)t);
    store_close(st);
    CHECK(!world_layer_enabled(&old, WORLD_LAYER_COMPACTION) && snapshot_format(0, 0) == 1,
          "the old store: heights-only records and format 1 snapshots (%u)", snapshot_format(0, 0));

    st = open_dir(&live, &rec, 0, &err);
    CHECK(st && rec.tick == 60 && rec.tiles_loaded > 0 && same_heights(&old, &live) &&
              world_layer_sum(&live, WORLD_LAYER_COMPACTION, 0) == 0,
          "the old store loads: tick %llu, %d snapshots, heights as they were, no memory: %s",
          (unsigned long long)rec.tick, rec.tiles_loaded, err.message);
    if (!st)
        return;
    CHECK(world_layer_enable(&live, WORLD_LAYER_COMPACTION) == 0, "the engine enables the layer");
    for (uint64_t t = 61; t <= 90; t++)
        CHECK(layer_tick(st, &live, t, &memory_layer) == 0, "memory tick %llu logged",
              (unsigned long long)t);
    store_close(st);
    st = open_dir(&back, &rec, 0, &err);
    CHECK(st && rec.tick == 90, "log replay: tick %llu: %s", (unsigned long long)rec.tick,
          err.message);
    CHECK(same_heights(&live, &back) && same_layer(&live, &back, &memory_layer) &&
              world_layer_sum(&back, WORLD_LAYER_COMPACTION, 0) > 0,
          "log replay: heights and every cell's memory as they were (Σ memory %lld)",
          (long long)world_layer_sum(&back, WORLD_LAYER_COMPACTION, 0));
    store_close(st);

    /* compaction into snapshots, then recovery from them */
    st = open_dir(&back, &rec, 20000, &err);
    for (uint64_t t = 91; t <= 200 && st; t++) {
        layer_tick(st, &back, t, &memory_layer);
        if (t % 3 == 0)
            random_tick(st, &back, ++t); /* heights only, the right-hand tiles too */
    }
    store_close(st);
    st = open_dir(&again, &rec, 20000, &err);
    CHECK(st && rec.tick >= 200 && rec.tiles_loaded > 0, "snapshots: tick %llu, %d tiles: %s",
          (unsigned long long)rec.tick, rec.tiles_loaded, err.message);
    CHECK(same_heights(&back, &again) && same_layer(&back, &again, &memory_layer),
          "snapshots + log: heights and every cell's memory as they were");
    store_close(st);
    CHECK(snapshot_format(0, 0) == 3 && snapshot_format(2, 0) == 1,
          "a tile with memory is snapshot in format 3 (%u), one without in format 1 (%u)",
          snapshot_format(0, 0), snapshot_format(2, 0));

    /* a memory out of range: the record is malformed, nothing of it applied */
    store_record c = {0};
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    world_rect r = {3, 4, 2, 1};
    int32_t values[4] = {100, 101, 7, WORLD_COMPACTION_MAX + 1};
    size_t len = store_record_encode(&c, cctx, 1, &r, 1, STORE_LAYER_COMPACTION, values, 0, &err);
    int32_t h_before = 0, h_after = 0;
    world_gather_window(&again, (world_rect){3, 4, 1, 1}, &h_before);
    int applied = len ? store_record_apply(&c, &again, c.buf, len, NULL, NULL) : -2;
    world_gather_window(&again, (world_rect){3, 4, 1, 1}, &h_after);
    CHECK(applied == 1 && h_after == h_before && store_record_layers(c.buf, len) == 2,
          "a memory of 65536 is refused whole (apply %d)", applied);
    values[3] = WORLD_COMPACTION_MAX;
    len = store_record_encode(&c, cctx, 1, &r, 1, STORE_LAYER_COMPACTION, values, 0, &err);
    applied = store_record_apply(&c, &again, c.buf, len, NULL, NULL);
    int32_t m44 = -1, m34 = -1;
    world_layer_cell(&again, WORLD_LAYER_COMPACTION, 4, 4, &m44);
    world_layer_cell(&again, WORLD_LAYER_COMPACTION, 3, 4, &m34);
    CHECK(applied == 0 && m44 == WORLD_COMPACTION_MAX && m34 == 7, "65535 is kept");
    ZSTD_freeCCtx(cctx);
    store_record_free(&c);
    world_free(&old);
    world_free(&live);
    world_free(&back);
    world_free(&again);
}

/* The order a record's values lie in, pinned (the data directories and
 * JetStream logs written so far hold it): every rectangle's heights, then
 * with bit 31 their soil state (WORLD_SOIL_FIELDS per cell), then with bit 30
 * their compaction memory, each part rectangle after rectangle. A record
 * applied to a fresh world puts every value back where it was. */
static void test_record_layout(void)
{
    world w, back;
    make_base(&w);
    make_base(&back);
    world_rect r[2] = {{3, 4, 2, 1}, {10, 20, 1, 1}};
    int32_t h[3] = {111, 112, 113};
    int32_t soil[9] = {1, 2, 3, 4, 5, 6, 7, 8, 9};
    int32_t memory[3] = {65535, 0, 42};
    world_scatter_window(&w, r[0], h);
    world_scatter_window(&w, r[1], h + 2);
    world_layer_scatter(&w, WORLD_LAYER_SOIL, r[0], soil);
    world_layer_scatter(&w, WORLD_LAYER_SOIL, r[1], soil + 6);
    world_layer_scatter(&w, WORLD_LAYER_COMPACTION, r[0], memory);
    world_layer_scatter(&w, WORLD_LAYER_COMPACTION, r[1], memory + 2);
    const int32_t expect[15] = {111, 112, 113, 1, 2, 3, 4, 5, 6, 7, 8, 9, 65535, 0, 42};
    CHECK(store_layers_ints(0) == 1 && store_layers_ints(STORE_LAYER_SOIL) == 4 &&
              store_layers_ints(STORE_LAYER_COMPACTION) == 2 &&
              store_layers_ints(STORE_LAYER_SOIL | STORE_LAYER_COMPACTION) == 5,
          "int32 per cell: 1 + 3 with the soil state + 1 with the compaction memory");
    CHECK(store_world_layers(&w) == (STORE_LAYER_SOIL | STORE_LAYER_COMPACTION) &&
              store_world_layers(&back) == 0 &&
              store_rect_layers(&w, (world_rect){300, 200, 10, 10}) == 0,
          "the layers a world keeps, and none in a tile nobody wrote");
    store_record c = {0};
    unsigned both = STORE_LAYER_SOIL | STORE_LAYER_COMPACTION;
    CHECK(store_record_gather(&c, &w, r, 2, both) == 0 &&
              memcmp(c.values, expect, sizeof expect) == 0,
          "heights, then soil state, then compaction memory, rectangle after rectangle");
    int32_t values[15];
    memcpy(values, c.values, sizeof values);
    error_text err = {{0}};
    ZSTD_CCtx *cctx = ZSTD_createCCtx();
    size_t len = store_record_encode(&c, cctx, 1, r, 2, both, values, 0, &err);
    uint32_t word = len > 4 ? (uint32_t)c.buf[0] | (uint32_t)c.buf[1] << 8 |
                                  (uint32_t)c.buf[2] << 16 | (uint32_t)c.buf[3] << 24
                            : 0;
    CHECK(word == (0xC0000000u | 2u) && store_record_layers(c.buf, len) == both,
          "the count word: 2 rectangles with bits 31 (soil) and 30 (compaction): %s", err.message);
    int applied = len ? store_record_apply(&c, &back, c.buf, len, NULL, NULL) : -2;
    int32_t got_h = 0, got_soil[3] = {0}, got_memory = -1;
    world_gather_window(&back, (world_rect){4, 4, 1, 1}, &got_h);
    world_layer_cell(&back, WORLD_LAYER_SOIL, 4, 4, got_soil);
    world_layer_cell(&back, WORLD_LAYER_COMPACTION, 10, 20, &got_memory);
    CHECK(applied == 0 && got_h == 112 && got_soil[0] == 4 && got_soil[2] == 6 && got_memory == 42,
          "applied to a fresh world: height %d, soil %d..%d, memory %d", got_h, got_soil[0],
          got_soil[2], got_memory);
    ZSTD_freeCCtx(cctx);
    store_record_free(&c);
    world_free(&w);
    world_free(&back);
}

/* A cursor's cancel (store_cancel): counts the questions, says yes from
 * question after + 1 on. Asked before each record a rebuild applies, so the
 * questions before the yes are the records applied. */
typedef struct asker {
    int asked, after;
} asker;

static int ask(void *ctx)
{
    asker *a = ctx;
    return ++a->asked > a->after;
}

/* A spectator's cursor is cancellable in its rebuild and its steps
 * (net_spectate.c: a world's removal waits for the spectator's thread):
 * cancelled before the open, the open returns STORE_CANCELLED having
 * applied no record; cancelled after 10 records of the rebuild's 40, after
 * exactly 10 (no retry); a step after a cancel returns it too. Never
 * cancelled, the cursor's heights are store_replay_rect's. So are an HTTP
 * past-tick read's rebuilds (http_views.c: the removal waits for the
 * request too): store_replay_rect and store_replay_world cancelled after 10
 * records stop at the 11th question, not retried. */
static void test_cursor_cancel(void)
{
    fresh_dir();
    world live, base;
    make_base(&live);
    make_base(&base);
    error_text err = {{0}};
    store_recovery rec;
    store *st = open_dir(&live, &rec, 0, &err);
    CHECK(st != NULL, "new directory: %s", err.message);
    if (!st)
        return;
    for (uint64_t t = 1; t <= 60; t++) /* one segment: a rebuild replays it from the base */
        CHECK(random_tick(st, &live, t) == 0, "tick %llu logged", (unsigned long long)t);
    store_close(st);
    world_rect r = {0, 0, W, H};
    store_cursor *cur = NULL;

    asker before = {0, 0};
    store_cancel c = {.cancelled = ask, .ctx = &before};
    int rc = store_cursor_open(dir, &base, 40, r, &c, &cur, &err);
    CHECK(rc == STORE_CANCELLED && !cur && strstr(err.message, "cancelled") && before.asked == 1,
          "cancelled before the open: STORE_CANCELLED (%d, %s) at the first record, none applied "
          "(asked %d)",
          rc, err.message, before.asked);

    asker during = {0, 10};
    c.ctx = &during;
    rc = store_cursor_open(dir, &base, 40, r, &c, &cur, &err);
    CHECK(rc == STORE_CANCELLED && !cur && during.asked == 11,
          "cancelled after 10 of the rebuild's 40 records: STORE_CANCELLED (%d, %s) with 10 "
          "applied, not retried (asked %d)",
          rc, err.message, during.asked);

    asker never = {0, 1 << 30};
    c.ctx = &never;
    rc = store_cursor_open(dir, &base, 40, r, &c, &cur, &err);
    CHECK(rc == 0 && cur && never.asked >= 40,
          "not cancelled: the cursor opens (%d, %s), asked at each of the 40 records (%d)", rc,
          err.message, never.asked);
    if (!cur) {
        world_free(&live);
        world_free(&base);
        return;
    }
    int32_t *want = malloc((size_t)W * H * sizeof *want),
            *got = malloc((size_t)W * H * sizeof *got);
    if (!want || !got)
        exit(2);
    store_cursor_read(cur, r, got);
    asker rect_during = {0, 10}, world_during = {0, 10}, rect_never = {0, 1 << 30};
    c.ctx = &rect_during;
    rc = store_replay_rect(dir, &base, 40, r, want, &c, &err);
    CHECK(rc == STORE_CANCELLED && strstr(err.message, "cancelled") && rect_during.asked == 11,
          "a past-tick rebuild cancelled after 10 of its 40 records: STORE_CANCELLED (%d, %s), "
          "not retried (asked %d)",
          rc, err.message, rect_during.asked);
    world past;
    c.ctx = &world_during;
    rc = store_replay_world(dir, &base, 40, r, &past, &c, &err);
    CHECK(rc == STORE_CANCELLED && world_during.asked == 11,
          "the same kept as a world: STORE_CANCELLED (%d, %s), asked %d", rc, err.message,
          world_during.asked);
    c.ctx = &rect_never;
    CHECK(store_replay_rect(dir, &base, 40, r, want, &c, &err) == 0 && rect_never.asked >= 40 &&
              memcmp(want, got, (size_t)W * H * sizeof *got) == 0,
          "the cursor holds the heights of a replay of tick 40, asked at each record (%d): %s",
          rect_never.asked, err.message);
    uint64_t t = 0;
    const world_rect *rects;
    int n;
    rc = store_cursor_next(cur, 41, &t, &rects, &n, &err);
    CHECK(rc == 1 && t == 41 && store_cursor_apply(cur, &err) == 0, "a step to tick 41: %d, %s", rc,
          err.message);
    never.after = 0;
    rc = store_cursor_next(cur, 42, &t, &rects, &n, &err);
    CHECK(rc == STORE_CANCELLED && strstr(err.message, "cancelled") && store_cursor_tick(cur) == 41,
          "cancelled between steps: the next step returns STORE_CANCELLED (%d, %s), still at 41",
          rc, err.message);
    store_cursor_close(cur);
    free(want);
    free(got);
    world_free(&live);
    world_free(&base);
}

int main(void)
{
    snprintf(dir, sizeof dir, "/tmp/terrad_test_store_%d", (int)getpid());
    test_crc();
    test_round_trip();
    test_compaction();
    test_flipped_snapshot_header();
    test_torn_tail();
    test_flipped_record();
    test_manifest_and_lock();
    test_fault_hook();
    test_group_commit();
    test_soil_state();
    test_compaction_memory();
    test_record_layout();
    test_cursor_cancel();
    fresh_dir();
    return check_report();
}
