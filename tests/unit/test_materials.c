/*
 * test_materials.c: per-cell materials and compaction memory (server/ground/,
 * server/sim/sim_stages.c): presets, the scene's material table and
 * map with their errors, the uniform path equal to the plain stages bit for
 * bit, no compaction layer where no material compacts, repeated passes over
 * one track sinking less each time with exact volume accounting, and a
 * mixed-material window where every cell settles at its own material's
 * angle of repose.
 */
#include <cjson/cJSON.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ground/ground.h"
#include "sim/sim_internal.h"
#include "check.h"
#include "test_params.h"

static sim_params base_params(sim_material *m)
{
    *m = sim_material_default();
    return test_params_from_material(m, WORLD_HEIGHT_MIN);
}

static void make_world(world *w, int width, int height, int32_t level)
{
    error_text err;
    if (world_init(w, width, height, 0.05, 10000, WORLD_HEIGHT_MIN, &err) != 0) {
        printf("world_init: %s\n", err.message);
        abort();
    }
    int32_t *row = malloc((size_t)width * sizeof *row);
    for (int x = 0; x < width; x++)
        row[x] = level;
    for (int y = 0; y < height; y++)
        world_scatter_window(w, (world_rect){0, y, width, 1}, row);
    free(row);
}

static int32_t height_at(const world *w, int x, int y)
{
    int32_t h;
    world_gather_window(w, (world_rect){x, y, 1, 1}, &h);
    return h;
}

/* Parse a scene fragment {"materials": ..., "material_map": ...}. */
static int ground_from_text(ground *g, const world *w, const char *text, error_text *err)
{
    cJSON *root = cJSON_Parse(text);
    if (!root)
        abort();
    sim_material base;
    base_params(&base);
    ground_material per_cell = sim_material_ground(&base);
    int r = ground_init_json(g, ground_extent_of_world(w), &per_cell,
                             cJSON_GetObjectItemCaseSensitive(root, "materials"),
                             cJSON_GetObjectItemCaseSensitive(root, "material_map"), err);
    cJSON_Delete(root);
    return r;
}

static void test_presets(void)
{
    ground_material m;
    static const char *const names[] = {"snow", "sand", "mud", "pebbles"};
    for (int i = 0; i < 4; i++) {
        CHECK(ground_material_preset(names[i], &m) == 0, "preset %s exists", names[i]);
        CHECK(strcmp(m.name, names[i]) == 0, "preset name %s", m.name);
        CHECK(m.repose_deg > 0 && m.repose_deg < 90, "%s repose %g", names[i], m.repose_deg);
    }
    ground_material_preset("sand", &m);
    CHECK(fabs(m.repose_deg - 45.0) < 1e-9 && m.roughness == 1.0, "sand: Gilardi pi/4, D = 1");
    ground_material_preset("mud", &m);
    CHECK(fabs(m.repose_deg - 72.0) < 1e-9 && m.roughness == 0.25, "mud: Gilardi 2pi/5, D = 0.25");
    ground_material_preset("pebbles", &m);
    CHECK(fabs(m.repose_deg - 60.0) < 1e-9 && m.roughness == 0.9, "pebbles: pi/3, D = 0.9");
    CHECK(ground_material_preset("gravel", &m) == -1, "unknown preset refused");
}

static void test_table_and_map(void)
{
    world w;
    make_world(&w, 100, 60, 1000);
    ground g;
    error_text err;
    int r = ground_from_text(&g, &w,
                             "{\"materials\": {\"sand\": {\"preset\": \"sand\"},"
                             " \"snow\": {\"preset\": \"snow\", \"roughness\": 0.4},"
                             " \"rock\": {\"repose_deg\": 80, \"roughness\": 0.2}},"
                             " \"material_map\": {\"default\": \"snow\", \"paint\": ["
                             "  {\"material\": \"sand\", \"rect\": [1.0, 0.0, 2.0, 3.0]},"
                             "  {\"material\": \"rock\", \"circle\": [1.5, 1.5, 0.25]}]}}",
                             &err);
    CHECK(r == 0, "table parses (%s)", r ? err.message : "");
    if (r == 0) {
        CHECK(g.material_count == 3 && !g.uniform, "three materials, not uniform");
        CHECK(g.materials[1].roughness == 0.4, "override wins over the preset");
        CHECK(g.uses_compaction, "snow compacts: the layer exists");
        CHECK(world_layer_bytes(&w, WORLD_LAYER_COMPACTION) == 0,
              "no compaction memory before anything is compacted");
        uint8_t ids[100 * 60];
        ground_gather_ids(&g, (world_rect){0, 0, 100, 60}, ids);
        CHECK(ids[0] == 1, "default snow at (0,0) (%d)", ids[0]);
        CHECK(ids[10 * 100 + 25] == 0, "sand in the rectangle (%d)", ids[10 * 100 + 25]);
        CHECK(ids[30 * 100 + 30] == 2, "rock in the circle painted last (%d)", ids[30 * 100 + 30]);
        CHECK(ids[30 * 100 + 39] == 0, "sand beside the circle (%d)", ids[30 * 100 + 39]);
        CHECK(ids[10 * 100 + 40] == 1, "snow right of the rectangle (%d)", ids[10 * 100 + 40]);
        uint8_t sub[4];
        ground_gather_ids(&g, (world_rect){29, 30, 2, 2}, sub);
        CHECK(sub[0] == ids[30 * 100 + 29] && sub[3] == ids[31 * 100 + 30], "sub-rect gather");
        ground_free(&g);
    }
    struct {
        const char *text, *expect;
    } bad[] = {
        {"{\"materials\": {\"a\": {\"roughness\": 2}}}", "materials.a.roughness"},
        {"{\"materials\": {\"a\": {\"preset\": \"lava\"}}}", "materials.a.preset"},
        {"{\"materials\": {\"a\": {\"colour\": 1}}}", "materials.a.colour"},
        {"{\"materials\": {\"a\": {\"repose_deg\": 90}}}", "materials.a.repose_deg"},
        {"{\"materials\": {\"a\": {\"max_compaction_m\": 7}}}", "materials.a.max_compaction_m"},
        {"{\"materials\": {\"a\": {}, \"b\": {}}}", "material_map"},
        {"{\"material_map\": {\"default\": \"a\"}}", "material_map"},
        {"{\"materials\": {\"a\": {}}, \"material_map\": {\"default\": \"b\"}}",
         "material_map.default"},
        {"{\"materials\": {\"a\": {}}, \"material_map\": {\"paint\": [{\"material\": \"a\"}]}}",
         "material_map.paint[0]"},
        {"{\"materials\": {\"a\": {}}, \"material_map\": {\"paint\": [{\"material\": \"a\", "
         "\"rect\": [1, 1, 0, 2]}]}}",
         "material_map.paint[0].rect"},
        {"{\"materials\": {\"a\": {}}, \"material_map\": {\"paint\": [{\"material\": \"z\", "
         "\"circle\": [1, 1, 1]}]}}",
         "material_map.paint[0].material"},
        {"{\"materials\": {}}", "materials"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        err.message[0] = 0;
        int rc = ground_from_text(&g, &w, bad[i].text, &err);
        CHECK(rc == -1 && strncmp(err.message, bad[i].expect, strlen(bad[i].expect)) == 0,
              "bad table %zu refused naming %s (got rc %d, \"%s\")", i, bad[i].expect, rc,
              err.message);
    }
    world_free(&w);
}

static void test_no_layer_without_compaction(void)
{
    world w;
    make_world(&w, 64, 64, 0);
    ground g;
    error_text err;
    int r =
        ground_from_text(&g, &w,
                         "{\"materials\": {\"sand\": {\"preset\": \"sand\"}, \"pebbles\": "
                         "{\"preset\": \"pebbles\"}, \"wet\": {\"compression\": 0, "
                         "\"max_compaction_m\": 1}}, \"material_map\": {\"default\": \"sand\"}}",
                         &err);
    CHECK(r == 0, "parses (%s)", r ? err.message : "");
    CHECK(!g.uses_compaction && !world_layer_enabled(&w, WORLD_LAYER_COMPACTION) &&
              world_layer_bytes(&w, WORLD_LAYER_COMPACTION) == 0,
          "compression 0 everywhere: no compaction layer");
    int32_t mem[4] = {1, 2, 3, 4};
    world_layer_gather(&w, WORLD_LAYER_COMPACTION, (world_rect){0, 0, 2, 2}, mem);
    CHECK(mem[0] == 0 && mem[3] == 0, "no layer reads as zero");
    ground_free(&g);
    sim_material base;
    base_params(&base);
    ground_material per_cell = sim_material_ground(&base);
    CHECK(ground_init_uniform(&g, ground_extent_of_world(&w), &per_cell, &err) == 0 && g.uniform &&
              !g.uses_compaction,
          "the old single material: uniform, no layer");
    ground_free(&g);
    world_free(&w);
}

/* One material equal to the params, no memory: identical to the plain stages. */
static void test_uniform_equals_plain(void)
{
    enum { W = 24, H = 20, N = W * H };
    static int32_t heights[N], bottom[N], raw1[N], moved1[N], cls1[N], raw2[N], moved2[N], cls2[N],
        h1[N], h2[N], scratch[4 * N];
    sim_material m;
    sim_params p = base_params(&m);
    m.compression = 0.37;
    sim_params_from_material(&m, 0.05, 10000, WORLD_HEIGHT_MIN, &p, NULL);
    ground_material_table t = {.count = 1};
    t.rows[0] = sim_material_row_from_params(&p, 0);
    for (int i = 0; i < N; i++) {
        heights[i] = (int32_t)((i * 7919) % 3001) - 1500;
        bottom[i] = (i % 5 == 0) ? heights[i] - (i % 400) : COLLIDER_BOTTOM_NONE;
        if (i % 7 == 0)
            bottom[i] = heights[i] + 10;
    }
    sim_classify(&p, N, heights, bottom, raw1, moved1, cls1);
    sim_classify_materials(&p, &t, NULL, NULL, N, heights, bottom, raw2, moved2, cls2);
    CHECK(memcmp(raw1, raw2, sizeof raw1) == 0 && memcmp(moved1, moved2, sizeof moved1) == 0 &&
              memcmp(cls1, cls2, sizeof cls1) == 0,
          "uniform classify equals sim_classify");
    memcpy(h1, heights, sizeof h1);
    memcpy(h2, heights, sizeof h2);
    sim_even_slopes(&p, W, H, cls1, h1, scratch);
    sim_even_slopes_materials(&p, &t, NULL, W, H, cls1, h2, scratch);
    CHECK(memcmp(h1, h2, sizeof h1) == 0, "uniform even_slopes equals sim_even_slopes");
    CHECK(sim_max_slope_excess(&p, W, H, h1) == sim_max_slope_excess_materials(&t, NULL, W, H, h1),
          "slope excess agrees");
}

/* A Persson tick on one window with the per-cell stages (CPU twin). */
static void run_window(const sim_params *p, ground *g, world *w, world_rect r,
                       const int32_t *bottom, int32_t *raw_out)
{
    int n = r.w * r.h;
    int32_t *heights = malloc((size_t)n * 4), *raw = malloc((size_t)n * 4);
    int32_t *moved = malloc((size_t)n * 4), *cls = malloc((size_t)n * 4);
    int32_t *seed = malloc((size_t)n * 4), *scratch = malloc((size_t)(5 * n + 2) * 4);
    uint8_t *ids = malloc((size_t)n);
    uint16_t *memory = malloc((size_t)n * 2);
    world_gather_window(w, r, heights);
    ground_gather_ids(g, r, ids);
    world_layer_gather(w, WORLD_LAYER_COMPACTION, r,
                       seed); /* the world's int32 memory, as the engine reads it */
    for (int i = 0; i < n; i++)
        memory[i] = (uint16_t)seed[i];
    sim_classify_materials(p, &g->table, g->uniform ? NULL : ids, memory, n, heights, bottom, raw,
                           moved, cls);
    sim_jump_flood(p, r.w, r.h, r.x, r.y, cls, seed, scratch);
    if (sim_displace(p, r.w, r.h, cls, seed, raw, moved, heights, scratch) == SIM_WINDOW_OK) {
        sim_even_slopes_materials(p, &g->table, g->uniform ? NULL : ids, r.w, r.h, cls, heights,
                                  scratch);
        sim_compaction_commit(&g->table, g->uniform ? NULL : ids, n, raw, moved, memory);
        world_scatter_window(w, r, heights);
        for (int i = 0; i < n; i++)
            seed[i] = memory[i];
        if (world_layer_scatter(w, WORLD_LAYER_COMPACTION, r, seed) != 0)
            abort();
    }
    if (raw_out)
        memcpy(raw_out, raw, (size_t)n * 4);
    free(heights);
    free(raw);
    free(moved);
    free(cls);
    free(seed);
    free(scratch);
    free(ids);
    free(memory);
}

static int64_t compaction_sum_of(const int32_t *m, int n)
{
    int64_t s = 0;
    for (int i = 0; i < n; i++)
        s += m[i];
    return s;
}

static int64_t compaction_sum(const world *w, world_rect r)
{
    int32_t *m = malloc((size_t)r.w * r.h * 4);
    world_layer_gather(w, WORLD_LAYER_COMPACTION, r, m);
    int64_t s = compaction_sum_of(m, r.w * r.h);
    free(m);
    return s;
}

/* A 128² world's compaction memory with one 64² tile allocated: the tile
 * (int32 per cell) and the 2x2 tile directory. */
#define ONE_MEMORY_TILE_128 ((uint64_t)64 * 64 * 4 + 4 * sizeof(int32_t *))

/* The same footprint pressed 500 units below the current surface, pass after
 * pass: snow sinks less each time, and Σh + Σmemory is exact. */
static void test_repeated_passes_sink_less(void)
{
    world w;
    make_world(&w, 128, 128, 20000);
    ground g;
    error_text err;
    int r =
        ground_from_text(&g, &w,
                         "{\"materials\": {\"snow\": {\"preset\": \"snow\"}, \"sand\": "
                         "{\"preset\": \"sand\"}}, \"material_map\": {\"default\": \"sand\", "
                         "\"paint\": [{\"material\": \"snow\", \"rect\": [0.5, 0.5, 3.0, 3.0]}]}}",
                         &err);
    CHECK(r == 0, "parses (%s)", r ? err.message : "");
    sim_material m;
    sim_params p = base_params(&m);
    world_rect win = {20, 20, 24, 24};
    int n = win.w * win.h;
    int32_t *bottom = malloc((size_t)n * 4), *raw = malloc((size_t)n * 4);
    int64_t volume = world_rect_volume(&w, (world_rect){0, 0, 128, 128});
    int32_t last_sink = INT32_MAX;
    int monotone = 1, accounted = 1, strictly_less_at_start = 1;
    int centre = 12 * win.w + 12;
    for (int pass = 0; pass < 12; pass++) {
        int32_t here = height_at(&w, win.x + 12, win.y + 12);
        for (int i = 0; i < n; i++) {
            int x = i % win.w, y = i / win.w;
            bottom[i] =
                (x >= 10 && x < 14 && y >= 10 && y < 14) ? here - 500 : COLLIDER_BOTTOM_NONE;
        }
        int64_t mem_before = compaction_sum(&w, win);
        run_window(&p, &g, &w, win, bottom, raw);
        int64_t mem_after = compaction_sum(&w, win);
        int64_t now = world_rect_volume(&w, (world_rect){0, 0, 128, 128});
        if (now + (mem_after - mem_before) != volume)
            accounted = 0;
        volume = now;
        int32_t sink = raw[centre];
        if (sink > last_sink)
            monotone = 0;
        if (pass < 4 && !(sink < last_sink))
            strictly_less_at_start = 0;
        last_sink = sink;
    }
    CHECK(monotone, "sinkage never grows over repeated passes");
    CHECK(strictly_less_at_start, "the first passes sink strictly less each time");
    CHECK(last_sink < 250, "after 12 passes the snow carries the collider (sinks %d of 500)",
          last_sink);
    CHECK(accounted, "Σh falls by exactly the compacted units");
    CHECK(world_layer_bytes(&w, WORLD_LAYER_COMPACTION) == ONE_MEMORY_TILE_128,
          "one compaction tile allocated (%llu bytes)",
          (unsigned long long)world_layer_bytes(&w, WORLD_LAYER_COMPACTION));
    CHECK(world_layer_sum(&w, WORLD_LAYER_COMPACTION, 0) ==
              compaction_sum(&w, (world_rect){0, 0, 128, 128}),
          "the world's Σ memory is kept exactly as cells are written");
    /* the same passes on sand (compression 0): the volume is exact, no memory */
    int64_t before = world_rect_volume(&w, (world_rect){0, 0, 128, 128});
    world_rect sand = {80, 80, 24, 24};
    int32_t sand_sink[3];
    for (int pass = 0; pass < 3; pass++) {
        int32_t here = height_at(&w, sand.x + 12, sand.y + 12);
        for (int i = 0; i < n; i++) {
            int x = i % sand.w, y = i / sand.w;
            bottom[i] =
                (x >= 10 && x < 14 && y >= 10 && y < 14) ? here - 500 : COLLIDER_BOTTOM_NONE;
        }
        run_window(&p, &g, &w, sand, bottom, raw);
        sand_sink[pass] = raw[centre];
    }
    CHECK(world_rect_volume(&w, (world_rect){0, 0, 128, 128}) == before, "sand keeps Σh exactly");
    CHECK(sand_sink[0] == 500 && sand_sink[2] == 500, "sand does not harden (%d, %d)", sand_sink[0],
          sand_sink[2]);
    CHECK(compaction_sum(&w, sand) == 0 &&
              world_layer_bytes(&w, WORLD_LAYER_COMPACTION) == ONE_MEMORY_TILE_128,
          "no memory written for sand");
    free(bottom);
    free(raw);
    ground_free(&g);
    world_free(&w);
}

/* Left sand (45°, roughness 1), right mud (72°, 0.25), a ridge along the
 * middle: every cell ends within the rounding bound of its own material's
 * repose, the two sides at visibly different slopes, Σh exact. */
static void test_mixed_window_repose(void)
{
    enum { W = 40, H = 12, N = W * H };
    world w;
    make_world(&w, W, H, 0);
    ground g;
    error_text err;
    int r = ground_from_text(&g, &w,
                             "{\"materials\": {\"sand\": {\"preset\": \"sand\"}, \"mud\": "
                             "{\"preset\": \"mud\", \"compression\": 0}}, \"material_map\": "
                             "{\"default\": \"sand\", \"paint\": [{\"material\": \"mud\", "
                             "\"rect\": [1.0, 0, 2.0, 0.6]}]}}",
                             &err);
    CHECK(r == 0, "parses (%s)", r ? err.message : "");
    sim_material m;
    sim_params p = base_params(&m);
    p.slope_iterations = 200;
    static int32_t heights[N], cls[N], scratch[4 * N];
    static uint8_t ids[N];
    ground_gather_ids(&g, (world_rect){0, 0, W, H}, ids);
    for (int i = 0; i < N; i++) {
        heights[i] = (i % W == 20) ? 30000 : 0;
        cls[i] = SIM_CELL_SEED;
    }
    int64_t before = 0, after = 0;
    for (int i = 0; i < N; i++)
        before += heights[i];
    for (int round = 0; round < 50; round++)
        sim_even_slopes_materials(&p, &g.table, ids, W, H, cls, heights, scratch);
    for (int i = 0; i < N; i++)
        after += heights[i];
    CHECK(after == before, "Σh exact in the mixed window");
    for (int k = 0; k < 2; k++) {
        /* excess measured per material: the higher column's own threshold */
        static uint8_t only[N];
        ground_material_table t = g.table;
        int64_t worst = 0;
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++)
                for (int j = 0; j < 4; j++) {
                    static const int dx[4] = {1, -1, 0, 0}, dy[4] = {0, 0, 1, -1};
                    int qx = x + dx[j], qy = y + dy[j];
                    if (qx < 0 || qy < 0 || qx >= W || qy >= H || ids[y * W + x] != k)
                        continue;
                    int64_t e = (int64_t)heights[y * W + x] - heights[qy * W + qx] -
                                t.rows[k].slope_threshold_axial;
                    worst = e > worst ? e : worst;
                }
        (void)only;
        int64_t bound = (int64_t)ceil(8.0 * 65536.0 / t.rows[k].roughness_q16);
        CHECK(worst <= bound, "material %d: slope excess %lld within the rounding bound %lld", k,
              (long long)worst, (long long)bound);
    }
    /* mud (72°) stands steeper than sand (45°): the ridge's mud flank is higher */
    CHECK(heights[6 * W + 22] > heights[6 * W + 18],
          "the mud flank holds more height than the sand flank (%d vs %d)", heights[6 * W + 22],
          heights[6 * W + 18]);
    CHECK(sim_max_slope_excess_materials(&g.table, ids, W, H, heights) <=
              (int64_t)ceil(8.0 * 65536.0 / g.table.rows[1].roughness_q16),
          "overall excess within the largest bound");
    ground_free(&g);
    world_free(&w);
}

/* Through the engine and the CPU backend: a sphere pressed 5 cm deeper each
 * tick into snow lowers the ground less each time, the contact (collider
 * inside the ground after the tick, as contact_measure sees it) grows, and
 * Σh + Σmemory stays exactly what it was. */
static void test_engine_compaction(void)
{
    world w;
    make_world(&w, 64, 64, 20000);
    ground g;
    error_text err;
    int r = ground_from_text(&g, &w,
                             "{\"materials\": {\"snow\": {\"preset\": \"snow\", "
                             "\"max_compaction_m\": 0.2}}}",
                             &err);
    CHECK(r == 0 && g.uniform && g.uses_compaction, "snow only: uniform ids, compaction layer");
    sim_material m;
    sim_params p = base_params(&m);
    sim_backend *cpu = sim_backend_cpu_create(&err);
    sim_engine *e = sim_engine_create(&w, &p, cpu, 4, &err);
    CHECK(e != NULL, "engine");
    sim_engine_set_ground(e, &g);
    collider_geometry sphere = {.shape = COLLIDER_SPHERE, .radius = 0.3};
    sim_collider col = {.id = 1, .geometry = &sphere};
    col.pose.orientation = (quatd){1, 0, 0, 0};
    world_rect all = {0, 0, 64, 64};
    int64_t invariant = world_volume(&w) + compaction_sum(&w, all);
    int32_t last_drop = INT32_MAX, last_contact = -1;
    int drops_monotone = 1, contact_monotone = 1, exact = 1;
    int32_t first_drop = 0, drop = 0, contact = 0;
    for (int pass = 1; pass <= 8; pass++) {
        double z = 2.0 + 0.3 - 0.05 * pass;
        col.pose.position = (vec3d){32.5 * 0.05, 32.5 * 0.05, z};
        col.previous_pose = col.pose;
        col.has_previous = pass > 1;
        int32_t before = height_at(&w, 32, 32);
        static int32_t mem_before[64 * 64], mem_after[64 * 64];
        world_layer_gather(&w, WORLD_LAYER_COMPACTION, all, mem_before);
        sim_tick_report rep;
        CHECK(sim_engine_tick(e, &col, 1, &rep, &err) == 0, "tick %d", pass);
        /* every cell whose memory changed is in a rectangle the store logs */
        world_layer_gather(&w, WORLD_LAYER_COMPACTION, all, mem_after);
        int logged = 1, changed = 0;
        for (int c = 0; c < 64 * 64; c++) {
            if (mem_before[c] == mem_after[c])
                continue;
            changed++;
            int in = 0;
            for (int k = 0; k < rep.dirty_count + rep.state_dirty_count; k++) {
                world_rect d =
                    k < rep.dirty_count ? rep.dirty[k] : rep.state_dirty[k - rep.dirty_count];
                in |= c % 64 >= d.x && c % 64 < d.x + d.w && c / 64 >= d.y && c / 64 < d.y + d.h;
            }
            logged &= in;
        }
        CHECK(logged && (changed > 0 || pass > 1),
              "tick %d: the %d cells whose memory changed are in the logged rectangles", pass,
              changed);
        drop = before - height_at(&w, 32, 32);
        int32_t bottom = (int32_t)floor((z - 0.3) * 10000);
        contact = height_at(&w, 32, 32) - bottom;
        if (pass == 1)
            first_drop = drop;
        drops_monotone &= drop <= last_drop;
        contact_monotone &= contact >= last_contact;
        exact &= world_volume(&w) + compaction_sum(&w, all) == invariant;
        last_drop = drop;
        last_contact = contact;
    }
    CHECK(first_drop >= 490, "first pass: fresh snow yields the full 5 cm (%d)", first_drop);
    CHECK(drops_monotone && drop < first_drop / 2, "later passes sink less (last %d)", drop);
    CHECK(contact_monotone && contact > 0,
          "the compacted snow carries the collider: contact depth grows (last %d)", contact);
    CHECK(exact, "Σh + Σmemory exact through the engine");
    CHECK(sim_world_compacted(&w) == compaction_sum(&w, all) && sim_world_compacted(&w) > 0,
          "the world's compacted total is Σ memory (%lld)", (long long)sim_world_compacted(&w));
    /* a tick the store refuses is undone: memory back as it was gathered */
    static int32_t kept[64 * 64], undone[64 * 64];
    world_layer_gather(&w, WORLD_LAYER_COMPACTION, all, kept);
    col.pose.position.z -= 0.05;
    sim_tick_report rep;
    CHECK(sim_engine_tick(e, &col, 1, &rep, &err) == 0, "one more tick");
    CHECK(compaction_sum(&w, all) != compaction_sum_of(kept, 64 * 64), "it compacted more");
    sim_engine_undo_state(e);
    world_layer_gather(&w, WORLD_LAYER_COMPACTION, all, undone);
    CHECK(memcmp(kept, undone, sizeof kept) == 0, "sim_engine_undo_state puts the memory back");
    sim_engine_destroy(e);
    cpu->destroy(cpu);
    ground_free(&g);
    world_free(&w);
}

/* Heights at ±2^29, penetration of 2^30, memory at and past the maximum,
 * compression 0 and 1: every quantity stays in range (UBSan runs this too). */
static void test_classify_extremes(void)
{
    enum { N = 8 };
    sim_material m;
    sim_params p = base_params(&m);
    ground_material_table t = {.count = 2};
    t.rows[0] = sim_material_row_from_params(&p, 65535);
    t.rows[0].compression_q16 = 65536;
    t.rows[1] = sim_material_row_from_params(&p, 1);
    t.rows[1].compression_q16 = 1;
    int32_t heights[N], bottom[N], raw[N], moved[N], cls[N];
    uint8_t ids[N];
    uint16_t memory[N] = {0, 65535, 40000, 1, 0, 1, 65535, 7};
    for (int i = 0; i < N; i++) {
        heights[i] = i % 2 ? WORLD_HEIGHT_MAX : WORLD_HEIGHT_MIN + 1;
        bottom[i] = WORLD_HEIGHT_MIN - 1;
        ids[i] = (uint8_t)(i >= 4);
    }
    sim_classify_materials(&p, &t, ids, memory, N, heights, bottom, raw, moved, cls);
    int ok = 1;
    for (int i = 0; i < N; i++) {
        int64_t pen = (int64_t)heights[i] - WORLD_HEIGHT_MIN;
        ok &= raw[i] >= 0 && raw[i] <= pen && moved[i] >= 0 && moved[i] <= raw[i];
    }
    CHECK(ok, "yield and displaced part within [0, penetration]");
    CHECK(raw[1] == 0, "full memory: the column does not yield (%d)", raw[1]);
    CHECK(raw[3] == (1 << 30) - 16384, "memory 1 of 65535: hardness 1/65536 resists 2^14 (%d)",
          raw[3]);
    sim_compaction_commit(&t, ids, N, raw, moved, memory);
    CHECK(memory[0] == 1 && memory[1] == 65535,
          "compression 1 compacts a 1-unit press whole; full memory stays full (%u, %u)", memory[0],
          memory[1]);
    CHECK(memory[4] == 0 && memory[5] == 1 && memory[6] == 1,
          "compression 1/65536 rounds a 1-unit press to 0; memory clamped to max 1 (%u, %u, %u)",
          memory[4], memory[5], memory[6]);
}

/* One material from a table (a preset) is not the scene's base material: the
 * engine must use it; a ground equal to the params leaves the uniform path. */
static void test_engine_single_material(void)
{
    world w;
    make_world(&w, 32, 32, 0);
    sim_material m;
    sim_params p = base_params(&m);
    error_text err;
    sim_backend *cpu = sim_backend_cpu_create(&err);
    sim_engine *e = sim_engine_create(&w, &p, cpu, 4, &err);
    sim_engine_stats es;
    ground g;
    CHECK(ground_from_text(&g, &w, "{\"materials\": {\"sand\": {\"preset\": \"sand\"}}}", &err) ==
              0,
          "sand only parses");
    sim_engine_set_ground(e, &g);
    sim_engine_get_stats(e, &es);
    CHECK(es.per_cell_materials, "a single sand preset runs on its own row (45 deg, roughness 1)");
    ground_free(&g);
    ground_material per_cell = sim_material_ground(&m);
    CHECK(ground_init_uniform(&g, ground_extent_of_world(&w), &per_cell, &err) == 0,
          "uniform ground");
    sim_engine_set_ground(e, &g);
    sim_engine_get_stats(e, &es);
    CHECK(!es.per_cell_materials, "a ground equal to the params: the uniform path");
    ground_free(&g);
    sim_engine_destroy(e);
    cpu->destroy(cpu);
    world_free(&w);
}

int main(void)
{
    test_presets();
    test_table_and_map();
    test_no_layer_without_compaction();
    test_uniform_equals_plain();
    test_classify_extremes();
    test_repeated_passes_sink_less();
    test_mixed_window_repose();
    test_engine_compaction();
    test_engine_single_material();
    return check_report();
}
