/*
 * test_bekker_materials.c: the bekker model's soil per material (issue 21,
 * docs/materials.md). A scene's "materials" entries may carry their own
 * "soil"; each contact cell reads its material's soil and compression. Here
 * a plate pressed into the soft and firm halves of one window (one window,
 * one contact patch) must leave, cell for cell on each side of the border,
 * the heights and soil state each soil's own single-material scene leaves;
 * its forces lean to the firm side. A one-entry table whose soil differs
 * from the scene's runs that soil (not the scene's). Σh + Σcompacted exact
 * every tick, and 1 and 2 threads identical bit for bit with a wheel rolling
 * across the border too. Bad soils in an entry are refused naming the field.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "scene/scene.h"

#define W 64
#define H 32
#define BORDER 32 /* the firm half's first column (x = 1.6 m) */

/* Scene text: 64 x 32 cells of 5 cm, 0.4 m flat; `material` and `extra`
 * (", \"materials\": ..." or ""). */
static void scene_text(char *out, size_t size, const char *material, const char *extra)
{
    snprintf(out, size,
             "{\"world\":{\"width\":%d,\"height\":%d,\"cell_size_m\":0.05},"
             "\"terrain\":{\"kind\":\"flat\",\"height_m\":0.4},"
             "\"material\":%s%s}",
             W, H, material, extra);
}

static const char *const SOFT = "{\"model\":\"bekker\",\"compression\":0.5,"
                                "\"soil\":{\"preset\":\"snow-us\"}}";
static const char *const FIRM = "{\"model\":\"bekker\",\"compression\":0.2,"
                                "\"soil\":{\"preset\":\"lete-sand\"}}";
/* soft by default (the scene's soil), the east half firm with its own */
static const char *const MIXED =
    ",\"materials\":{\"soft\":{},"
    "\"firm\":{\"compression\":0.2,\"soil\":{\"preset\":\"lete-sand\"}}},"
    "\"material_map\":{\"default\":\"soft\","
    "\"paint\":[{\"material\":\"firm\",\"rect\":[1.6,0,3.2,1.6]}]}";
/* one entry, no map: its soil, not the scene's (snow-us), everywhere */
static const char *const ONLY_FIRM =
    ",\"materials\":{\"firm\":{\"compression\":0.2,\"soil\":{\"preset\":\"lete-sand\"}}}";

typedef struct run_out {
    int32_t heights[W * H];
    int32_t state[W * H * SIM_SOIL_STATE_FIELDS];
    sim_contact plate, wheel; /* the last tick's */
    int mass_ok, ticks_ok;
} run_out;

/*
 * The scene through the daemon's own path (scene, world, ground, engine):
 * a 0.8 x 0.4 m plate centred on the border pressed 3 mm deeper each tick
 * for 8 ticks, and with `wheel` a wheel rolling east across the border.
 */
static void run(const char *material, const char *extra, int threads, int wheel, run_out *o)
{
    char text[2048];
    scene_text(text, sizeof text, material, extra);
    scene s;
    world w;
    ground g;
    sim_params p;
    error_text err = {{0}};
    sim_backend *backend = NULL;
    sim_engine *e = NULL;
    sim_set_threads(threads);
    if (scene_load_json(text, ".", &s, &err) != 0 || scene_create_world(&s, &w, &err) != 0 ||
        sim_params_from_material(&s.material, w.cell_size_m, w.units_per_m, w.floor, &p, &err) !=
            0 ||
        !(backend = sim_backend_cpu_create(&err)) ||
        !(e = sim_engine_create(&w, &p, backend, s.active_margin_cells, &err)) ||
        scene_create_ground(&s, &w, &g, &err) != 0) {
        printf("scene: %s\n", err.message);
        abort();
    }
    sim_engine_set_ground(e, &g);
    collider_geometry plate = {.shape = COLLIDER_BOX, .half_extents = {0.4, 0.2, 0.05}};
    collider_geometry rim = {.shape = COLLIDER_CYLINDER, .radius = 0.15, .half_length = 0.05};
    sim_collider c[2] = {{.id = 1, .geometry = &plate}, {.id = 2, .geometry = &rim}};
    int64_t start = world_volume(&w);
    o->mass_ok = o->ticks_ok = 1;
    for (int t = 0; t < 8; t++) {
        for (int k = 0; k < 2; k++) {
            c[k].previous_pose = c[k].pose;
            c[k].has_previous = t > 0;
        }
        c[0].pose = (collider_pose){{1.6, 0.8, 0.45 - 0.002 - 0.003 * t}, {1, 0, 0, 0}};
        double x = 1.3 + 0.05 * t; /* one cell a tick, rolling */
        c[1].pose.position = (vec3d){x, 0.3, 0.4 + 0.15 - 0.01};
        c[1].pose.orientation = quat_from_axis_angle((vec3d){0, 1, 0}, (x - 1.3) / 0.15);
        sim_tick_report rep;
        if (sim_engine_tick(e, c, wheel ? 2 : 1, &rep, &err) != 0) {
            printf("tick: %s\n", err.message);
            o->ticks_ok = 0;
            break;
        }
        o->mass_ok &= world_volume(&w) + sim_engine_soil_compacted(e) == start;
        for (int i = 0; i < rep.contact_count; i++) {
            if (rep.contacts[i].collider_id == 1)
                o->plate = rep.contacts[i];
            if (rep.contacts[i].collider_id == 2)
                o->wheel = rep.contacts[i];
        }
    }
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            o->heights[y * W + x] = world_height_at(&w, x, y);
            sim_engine_soil_cell(e, x, y, &o->state[(y * W + x) * SIM_SOIL_STATE_FIELDS]);
        }
    sim_engine_destroy(e);
    backend->destroy(backend);
    ground_free(&g);
    world_free(&w);
    scene_free(&s);
    sim_set_threads(0);
}

/* Cells under the plate (centres within 1.2..2.0 x 0.6..1.0 m) in columns
 * [x0, x1): heights and soil state equal between a and b. */
static int plate_cells_equal(const run_out *a, const run_out *b, int x0, int x1, int *cells)
{
    *cells = 0;
    for (int y = 12; y < 20; y++)
        for (int x = x0; x < x1; x++) {
            int i = y * W + x;
            (*cells)++;
            if (a->heights[i] != b->heights[i] ||
                memcmp(&a->state[i * SIM_SOIL_STATE_FIELDS], &b->state[i * SIM_SOIL_STATE_FIELDS],
                       SIM_SOIL_STATE_FIELDS * sizeof(int32_t)) != 0)
                return 0;
        }
    return 1;
}

static void test_halves(void)
{
    static run_out soft, firm, mixed, only;
    run(SOFT, "", 1, 0, &soft);
    run(FIRM, "", 1, 0, &firm);
    run(SOFT, MIXED, 1, 0, &mixed);
    run(SOFT, ONLY_FIRM, 1, 0, &only);
    CHECK(soft.ticks_ok && firm.ticks_ok && mixed.ticks_ok && only.ticks_ok, "every run ticked");
    CHECK(soft.mass_ok && firm.mass_ok && mixed.mass_ok && only.mass_ok,
          "Σh + Σcompacted exact every tick (soft, firm, mixed, one-entry table)");
    int n;
    /* away from the border by one cell on each side */
    CHECK(plate_cells_equal(&mixed, &soft, 24, BORDER - 1, &n) && n == 7 * 8,
          "the soft half under the plate: heights, plastic sinkage and compaction of the "
          "soft scene, cell for cell (%d cells)",
          n);
    CHECK(plate_cells_equal(&mixed, &firm, BORDER + 1, 40, &n) && n == 7 * 8,
          "the firm half under the plate: heights, plastic sinkage and compaction of the "
          "firm scene, cell for cell (%d cells)",
          n);
    int soft_i = 16 * W + 26, firm_i = 16 * W + 37;
    int32_t ss = mixed.state[soft_i * SIM_SOIL_STATE_FIELDS + SIM_SOIL_SINK];
    int32_t fs = mixed.state[firm_i * SIM_SOIL_STATE_FIELDS + SIM_SOIL_SINK];
    CHECK(ss > fs && fs > 0, "the soft half yields further than the firm one (%d vs %d units)", ss,
          fs);
    int32_t sc = mixed.state[soft_i * SIM_SOIL_STATE_FIELDS + SIM_SOIL_COMPACTED];
    int32_t fc = mixed.state[firm_i * SIM_SOIL_STATE_FIELDS + SIM_SOIL_COMPACTED];
    /* 0.5 and 0.2 of each tick's lowering, rounded down per tick */
    CHECK(10 * (int64_t)sc > 4 * (int64_t)ss && 10 * (int64_t)fc < 3 * (int64_t)fs && fc > 0,
          "each half compacts its own material's share (soft %d of %d, firm %d of %d)", sc, ss, fc,
          fs);
    double fz_soft = soft.plate.force_n[2], fz_firm = firm.plate.force_n[2];
    double fz = mixed.plate.force_n[2];
    CHECK(fz_soft < fz && fz < fz_firm && isfinite(fz),
          "the plate's normal force lies between the soft and firm scenes' (%g < %g < %g N)",
          fz_soft, fz, fz_firm);
    /* the firm east half pushes up harder: a torque about y of -x F_z */
    CHECK(mixed.plate.torque_nm[1] < -0.1 * fabs(fz) * 0.2 &&
              fabs(soft.plate.torque_nm[1]) < 1e-6 * fabs(fz_soft) + 1e-9,
          "the firm half tips the plate (torque_y %g N m; soft alone %g)", mixed.plate.torque_nm[1],
          soft.plate.torque_nm[1]);
    CHECK(memcmp(only.heights, firm.heights, sizeof only.heights) == 0 &&
              memcmp(only.state, firm.state, sizeof only.state) == 0,
          "a one-entry table with its own soil runs that soil, not the scene's: the firm "
          "scene's heights and state everywhere");
}

static void test_threads(void)
{
    static run_out one, two;
    run(SOFT, MIXED, 1, 1, &one);
    run(SOFT, MIXED, 2, 1, &two);
    CHECK(one.ticks_ok && two.ticks_ok && one.mass_ok && two.mass_ok,
          "plate and wheel over two soils: Σh + Σcompacted exact every tick");
    CHECK(one.wheel.cells > 0 && one.plate.cells > 0, "both colliders touch the soil");
    CHECK(memcmp(one.heights, two.heights, sizeof one.heights) == 0 &&
              memcmp(one.state, two.state, sizeof one.state) == 0 &&
              memcmp(&one.plate, &two.plate, sizeof one.plate) == 0 &&
              memcmp(&one.wheel, &two.wheel, sizeof one.wheel) == 0,
          "1 and 2 threads: the same heights, soil state and forces, bit for bit");
}

static int scene_refused(const char *extra, const char *field)
{
    char text[2048];
    scene_text(text, sizeof text, SOFT, extra);
    scene s;
    error_text err = {{0}};
    if (scene_load_json(text, ".", &s, &err) == 0) {
        scene_free(&s);
        printf("accepted: %s\n", extra);
        return 0;
    }
    if (!strstr(err.message, field)) {
        printf("refused without %s: %s\n", field, err.message);
        return 0;
    }
    return 1;
}

static void test_refusals(void)
{
    static const char *const bad[][2] = {
        {"{\"n\":0}", "materials.firm.soil.n"},
        {"{\"kphi\":0,\"kc\":0}", "materials.firm.soil.kphi"},
        {"{\"shear_k_m\":-1}", "materials.firm.soil.shear_k_m"},
        {"{\"friction_deg\":80}", "materials.firm.soil.friction_deg"},
        {"{\"preset\":\"mars\"}", "materials.firm.soil.preset"},
        {"{\"kx\":1}", "materials.firm.soil.kx"},
        {"{\"n\":\"one\"}", "materials.firm.soil.n"},
        {"7", "materials.firm.soil"},
    };
    for (size_t i = 0; i < sizeof bad / sizeof bad[0]; i++) {
        char extra[512];
        snprintf(extra, sizeof extra,
                 ",\"materials\":{\"soft\":{},\"firm\":{\"soil\":%s}},"
                 "\"material_map\":{\"default\":\"soft\"}",
                 bad[i][0]);
        CHECK(scene_refused(extra, bad[i][1]), "soil %s in an entry refused naming %s", bad[i][0],
              bad[i][1]);
    }
}

int main(void)
{
    test_refusals();
    test_halves();
    test_threads();
    return check_report();
}
