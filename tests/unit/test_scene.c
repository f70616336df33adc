/*
 * test_scene.c: every scene under tests/scenes loads and builds its world;
 * the thesis car is where the thesis puts it; and every way a scene can be
 * wrong — bad JSON, unknown keys, wrong types, Inf, zero and negative sizes,
 * keyframes out of order, too many colliders — is refused with a message that
 * names the JSON path of the culprit. Files are found under
 * $TERRAD_SOURCE_DIR (default ".").
 */
#include <dirent.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "scene/scene.h"
#include "check.h"

static const char *source_dir(void)
{
    const char *d = getenv("TERRAD_SOURCE_DIR");
    return d && d[0] ? d : ".";
}

static int has(const error_text *e, const char *needle)
{
    return strstr(e->message, needle) != NULL;
}

static void test_all_scenes(void)
{
    char dir[1024];
    snprintf(dir, sizeof dir, "%s/tests/scenes", source_dir());
    DIR *d = opendir(dir);
    CHECK(d != NULL, "open %s", dir);
    if (!d)
        return;
    int count = 0;
    struct dirent *ent;
    while ((ent = readdir(d))) {
        size_t n = strlen(ent->d_name);
        if (n < 6 || strcmp(ent->d_name + n - 5, ".json") != 0)
            continue;
        char path[2048];
        snprintf(path, sizeof path, "%s/%s", dir, ent->d_name);
        scene s;
        error_text e = {{0}};
        int ok = scene_load_file(path, &s, &e) == 0;
        CHECK(ok, "%s loads%s%s", ent->d_name, ok ? "" : ": ", ok ? "" : e.message);
        if (!ok)
            continue;
        count++;
        world w;
        ok = scene_create_world(&s, &w, &e) == 0;
        CHECK(ok && w.width == s.width && w.height == s.height, "%s builds its %d x %d world%s%s",
              ent->d_name, s.width, s.height, ok ? "" : ": ", ok ? "" : e.message);
        if (ok) {
            /* every collider's start pose is valid and its shape checks out */
            int valid = 1;
            for (int i = 0; i < s.collider_count; i++) {
                collider_pose p = collider_motion_pose(&s.colliders[i].motion, 1.0);
                valid &= collider_geometry_validate(&s.colliders[i].geometry, &e) == 0 &&
                         collider_pose_validate(&p, &e) == 0;
            }
            CHECK(valid, "%s: %d colliders valid", ent->d_name, s.collider_count);
            world_free(&w);
        }
        scene_free(&s);
    }
    closedir(d);
    CHECK(count >= 6, "%d scenes found", count);
}

static void test_thesis_car(void)
{
    char path[1024];
    snprintf(path, sizeof path, "%s/tests/scenes/thesis-car.json", source_dir());
    scene s;
    error_text e = {{0}};
    if (scene_load_file(path, &s, &e) != 0) {
        CHECK(0, "thesis-car loads: %s", e.message);
        return;
    }
    double size = s.width * s.cell_size_m;
    CHECK(s.width == 1024 && s.height == 1024 && s.cell_size_m == 200.0 / 4096 &&
              s.units_per_m == 10000 && s.floor_units == 0,
          "1024^2 cells of 200 m / 4096");
    CHECK(s.base.kind == WORLD_BASE_FLAT && s.base.height_m == 0.4, "flat snow 0.4 m");
    CHECK(s.material.compression == 0 && s.material.roughness == 0.3 &&
              s.material.repose_deg == 35 && s.material.displace_iterations == 10 &&
              s.material.slope_iterations == 10 && s.material.method == SIM_METHOD_SSBO &&
              s.material.metric == SIM_METRIC_EUCLIDEAN,
          "the thesis's material");
    CHECK(s.collider_count == 4, "four wheels");
    double xs[4], ys[4];
    int wheels_ok = 1;
    for (int i = 0; i < 4 && i < s.collider_count; i++) {
        const scene_collider *c = &s.colliders[i];
        const collider_motion *m = &c->motion;
        wheels_ok &= c->geometry.shape == COLLIDER_CYLINDER && c->geometry.radius == 0.33 &&
                     c->geometry.half_length == 0.1 && m->kind == COLLIDER_MOTION_VELOCITY &&
                     m->velocity.x == 0.55 && m->velocity.y == 0 &&
                     fabs(m->start.position.z - 0.33 - (0.4 - 0.08)) < 1e-9 &&
                     fabs(m->spin_rad_per_s - 0.55 / 0.33) < 1e-6 && m->spin_axis.y > 0 &&
                     m->start.orientation.w == 1;
        xs[i] = m->start.position.x;
        ys[i] = m->start.position.y;
    }
    CHECK(wheels_ok, "wheels: r 0.33, 8 cm into the snow, 0.55 m/s east, rolling at v/r about +y");
    double xmin = fmin(fmin(xs[0], xs[1]), fmin(xs[2], xs[3]));
    double xmax = fmax(fmax(xs[0], xs[1]), fmax(xs[2], xs[3]));
    double ymin = fmin(fmin(ys[0], ys[1]), fmin(ys[2], ys[3]));
    double ymax = fmax(fmax(ys[0], ys[1]), fmax(ys[2], ys[3]));
    CHECK(fabs(xmax - xmin - 2.6) < 1e-9 && fabs(ymax - ymin - 1.5) < 1e-9,
          "wheelbase 2.6 m, track 1.5 m");
    double t_end = 5000.0 / s.tick_hz;
    double rear_end = xmin + 0.55 * t_end, front_end = xmax + 0.55 * t_end;
    CHECK(rear_end + 0.33 < size, "after 5000 ticks the rear wheels are still inside (x = %.2f m)",
          rear_end);
    CHECK(front_end + 0.33 > size && front_end - 0.33 < size,
          "after 5000 ticks the front wheels straddle the east edge (x = %.2f m of %.0f)",
          front_end, size);
    CHECK(rear_end - xmin > 0.8 * size, "the car crosses most of the world (%.1f m)",
          rear_end - xmin);
    /* the motion really puts it there */
    collider_pose p = collider_motion_pose(&s.colliders[0].motion, t_end);
    CHECK(fabs(p.position.x - (xs[0] + 0.55 * t_end)) < 1e-9, "motion at tick 5000");
    scene_free(&s);
}

static void test_default_scene(void)
{
    scene s;
    error_text e = {{0}};
    int ok = scene_load_default(&s, &e) == 0;
    CHECK(ok, "embedded default scene loads%s%s", ok ? "" : ": ", ok ? "" : e.message);
    if (!ok)
        return;
    CHECK(s.width == 512 && s.height == 512 && s.cell_size_m == 0.05 &&
              s.base.kind == WORLD_BASE_DUNES && s.base.min_height_m == 0.3 &&
              s.base.max_height_m == 0.7 && s.collider_count == 0,
          "default: 512^2 dunes 0.3-0.7 m, no colliders");
    CHECK(s.material.method == SIM_METHOD_SSBO && s.material.roughness == 0.5 &&
              s.material.repose_deg == 35,
          "default material");
    world w;
    CHECK(scene_create_world(&s, &w, &e) == 0 && world_height_at(&w, 0, 0) >= 3000 &&
              world_height_at(&w, 0, 0) <= 7000,
          "default world builds");
    world_free(&w);
    scene_free(&s);
}

#define WORLD "\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 0.05}"

/* Load text that must be refused with `needle` in the message. */
static void refused(const char *text, const char *needle)
{
    scene s;
    error_text e = {{0}};
    int rc = scene_load_json(text, "/tmp", &s, &e);
    CHECK(rc != 0 && has(&e, needle) && s.colliders == NULL, "refused [%s]: %s", needle, e.message);
    if (rc == 0)
        scene_free(&s);
}

static void test_errors(void)
{
    refused("{ \"world\": { \"width\": 16,, } }",
            "scene: JSON syntax error near byte 2"); /* 24-26 */
    refused("", "scene: JSON syntax error near byte 0");
    refused("{" WORLD "} trailing", "scene: JSON syntax error");
    refused("[1, 2]", "scene: must be an object");
    refused("{\"name\": \"x\"}", "world: missing");
    refused("{" WORLD ", \"colour\": 1}", "colour: unknown key");
    refused("{" WORLD ", \"material\": {\"rougness\": 0.3}}", "material.rougness: unknown key");
    refused("{" WORLD ", \"material\": {\"roughness\": 0.3, \"roughness\": 0.4}}",
            "material.roughness: duplicate key");
    refused("{" WORLD ", \"material\": {\"roughness\": 1.5}}",
            "material.roughness: must be in [0, 1]");
    refused("{" WORLD ", \"material\": {\"repose_deg\": 90}}", "material.repose_deg");
    /* issue 12: refusals that name the field and state what is enforced */
    refused("{" WORLD ", \"material\": {\"repose_deg\": 95}}",
            "material.repose_deg: must be in [0, 90) (got 95)");
    refused("{" WORLD ", \"material\": {\"repose_deg\": 90}}",
            "material.repose_deg: must be in [0, 90) (got 90)");
    refused("{" WORLD ", \"material\": {\"roughness\": NaN}}",
            "scene: NaN at byte 86 (after key \"roughness\") is not JSON");
    refused("{" WORLD ", \"material\": {\"compression\": -Infinity}}",
            "scene: -Infinity at byte 88 (after key \"compression\") is not JSON");
    refused("{\"name\": \"Infinity: NaN\", " WORLD ", \"tick_hz\": Infinity}",
            "scene: Infinity at byte 96 (after key \"tick_hz\") is not JSON");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1e-300}}",
            "world.cell_size_m: must be in [0.0001, 1000] m (got 1e-300)");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 0.001, \"units_per_m\": "
            "100}}",
            "world.cell_size_m: 0.001 m at units_per_m 100 is 0.1 height units per cell");
    refused("{" WORLD ", \"colliders\": [{\"name\": \"m\", \"shape\": \"mesh\", \"obj\": \".\", "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].obj: /tmp/.: not a regular file");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1, \"units_per_m\": 1}, "
            "\"material\": {\"repose_deg\": 30}}",
            "material.repose_deg: 30 deg rises 0.577 units per cell at cell_size_m 1 and "
            "units_per_m 1");
    refused("{" WORLD ", \"material\": {\"metric\": \"euclidian\"}}", "material.metric");
    refused("{" WORLD ", \"material\": {\"method\": 3}}", "material.method: must be a string");
    refused("{" WORLD ", \"material\": {\"slope_iterations\": 2.5}}",
            "material.slope_iterations: must be an integer");
    refused("{" WORLD ", \"material\": []}", "material: must be an object");
    refused("{\"world\": {\"width\": \"16\", \"height\": 16, \"cell_size_m\": 0.05}}",
            "world.width: must be an integer");
    refused("{\"world\": {\"width\": 0, \"height\": 16, \"cell_size_m\": 0.05}}", "world.width");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1e999}}",
            "world.cell_size_m: must be a finite number > 0");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": -0.05}}",
            "world.cell_size_m");
    refused("{\"world\": {\"width\": 16, \"height\": 16}}", "world.cell_size_m: missing");
    refused("{\"world\": {\"width\": 64, \"height\": 64, \"cell_size_m\": 1, \"tile_cells\": 100}}",
            "world.tile_cells");
    refused("{\"world\": {\"width\": 64, \"height\": 64, \"cell_size_m\": 1, \"tile_cells\": 8}}",
            "world.tile_cells");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1, \"units_per_m\": 0}}",
            "world.units_per_m");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1, \"floor_m\": 1e6}}",
            "world.floor_m");
    refused("{\"world\": {\"width\": 16, \"height\": 16, \"cell_size_m\": 1, \"depth\": 1}}",
            "world.depth: unknown key");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"flat\", \"height_m\": 1e6}}",
            "terrain.height_m");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"flat\", \"height_m\": -1}}", "terrain.height_m");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"flat\"}}", "terrain.height_m: missing");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"flat\", \"height_m\": 1, \"seed\": 3}}",
            "terrain.seed: unknown key");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"hills\"}}", "terrain.kind");
    refused("{" WORLD ", \"terrain\": {\"height_m\": 1}}", "terrain.kind: missing");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"dunes\", \"min_height_m\": 0.5, "
            "\"max_height_m\": 0.4}}",
            "terrain.max_height_m");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"dunes\", \"min_height_m\": 0.3, "
            "\"max_height_m\": 0.4, \"octaves\": 9}}",
            "terrain.octaves");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"dunes\", \"min_height_m\": 0.3, "
            "\"max_height_m\": 0.4, \"seed\": -1}}",
            "terrain.seed");
    refused("{" WORLD ", \"terrain\": {\"kind\": \"png16\"}}", "terrain.path: missing");
    refused("{" WORLD ", \"tick_hz\": 0}", "tick_hz");
    refused("{" WORLD ", \"active_margin_cells\": -1}", "active_margin_cells");
    refused("{" WORLD ", \"colliders\": {}}", "colliders: must be an array");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": -0.2, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].radius: must be a finite number > 0");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].radius");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 1e999, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].radius");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": \"big\", "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].radius");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.2, "
            "\"position\": [0, 0, 0]}, {\"shape\": \"box\", \"radius\": 0.2, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[1].radius: unknown key for a box");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"box\", \"half_extents\": [1, -1, 1], "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].half_extents[1]");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"box\", \"half_extents\": [1, 1], "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].half_extents: must be an array of 3 numbers");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"wheel\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].half_length: missing");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"wheel\", \"radius\": 0.3, "
            "\"half_length\": 0.1, \"grousers\": {\"count\": 12, \"height\": 0.02}, "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].grousers.thickness: missing");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"wheel\", \"radius\": 0.3, "
            "\"half_length\": 0.1, \"grousers\": {\"count\": 12, \"height\": 0.5, "
            "\"thickness\": 0.01}, \"position\": [0, 0, 0]}]}",
            "colliders[0].grousers.height: must be a finite number > 0 and <= the radius");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"capsule\", \"radius\": 0.3, "
            "\"half_length\": 0.1, \"grousers\": {\"count\": 12, \"height\": 0.02, "
            "\"thickness\": 0.01}, \"position\": [0, 0, 0]}]}",
            "colliders[0].grousers: unknown key for a capsule");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"blob\", \"position\": [0, 0, 0]}]}",
            "colliders[0].shape");
    refused("{" WORLD ", \"colliders\": [{\"radius\": 0.3, \"position\": [0, 0, 0]}]}",
            "colliders[0].shape: missing");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3}]}",
            "colliders[0].position: missing");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [1e7, 0, 0]}]}",
            "colliders[0].position[0]");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, null, 0]}]}",
            "colliders[0].position[1]: must be a finite number");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], \"orientation\": [0, 0, 0, 0]}]}",
            "colliders[0].orientation");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], \"motion\": {\"velocity\": [1e999, 0, 0]}}]}",
            "colliders[0].motion.velocity[0]: must be a finite number");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], \"motion\": {\"velocity\": [1, 0, 0], \"speed\": 1}}]}",
            "colliders[0].motion.speed: unknown key");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], \"motion\": {\"spin_axis\": [0, 0, 0], "
            "\"spin_deg_per_s\": 10}}]}",
            "colliders[0].motion.spin_axis");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"motion\": {\"keyframes\": [{\"time_s\": 1, \"position\": [0, 0, 0]}, "
            "{\"time_s\": 1, \"position\": [1, 0, 0]}]}}]}",
            "colliders[0].motion.keyframes[1].time_s: must be greater");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"motion\": {\"keyframes\": []}}]}",
            "colliders[0].motion.keyframes: must be an array of 1 to 100000");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"motion\": {\"keyframes\": [{\"time_s\": 0}]}}]}",
            "colliders[0].motion.keyframes[0].position: missing");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], "
            "\"motion\": {\"keyframes\": [{\"time_s\": 0, \"position\": [0, 0, 0]}]}}]}",
            "colliders[0].position: not allowed with motion.keyframes");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"motion\": {\"velocity\": [1, 0, 0], "
            "\"keyframes\": [{\"time_s\": 0, \"position\": [0, 0, 0]}]}}]}",
            "colliders[0].motion.velocity: unknown key");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"mesh\", \"obj\": \"no-such.obj\", "
            "\"position\": [0, 0, 0]}]}",
            "colliders[0].obj: /tmp/no-such.obj: cannot open");
    refused("{" WORLD ", \"colliders\": [{\"shape\": \"sphere\", \"radius\": 0.3, "
            "\"position\": [0, 0, 0], \"name\": 5}]}",
            "colliders[0].name: must be a string");

    /* more colliders than allowed */
    size_t cap = 4200 * 80 + 256;
    char *big = malloc(cap);
    size_t n = (size_t)snprintf(big, cap, "{" WORLD ", \"colliders\": [");
    for (int i = 0; i < 4097; i++)
        n += (size_t)snprintf(big + n, cap - n,
                              "%s{\"shape\": \"sphere\", \"radius\": 0.1, "
                              "\"position\": [0, 0, 0]}",
                              i ? "," : "");
    snprintf(big + n, cap - n, "]}");
    refused(big, "colliders: at most 4096");
    free(big);
}

static void test_details(void)
{
    scene s;
    error_text e = {{0}};
    int ok =
        scene_load_json("{" WORLD ", \"material\": {\"roughness\": 0.7}, \"colliders\": ["
                        "{\"name\": \"w\", \"shape\": \"wheel\", \"radius\": 0.3, "
                        "\"half_length\": 0.1, \"position\": [1, 2, 3], "
                        "\"grousers\": {\"count\": 12, \"height\": 0.02, \"thickness\": 0.01}, "
                        "\"orientation\": [2, 0, 0, 0], \"motion\": {\"velocity\": [1, 0, 0], "
                        "\"spin_axis\": [0, 1, 0], \"spin_deg_per_s\": 90}},"
                        "{\"shape\": \"capsule\", \"radius\": 0.1, \"half_length\": 0, "
                        "\"motion\": {\"keyframes\": [{\"time_s\": 0, \"position\": [0, 0, 1]},"
                        "{\"time_s\": 2, \"position\": [2, 0, 1], "
                        "\"orientation\": [0, 0, 0, 1]}]}}]}",
                        "/tmp", &s, &e) == 0;
    CHECK(ok, "a scene with every collider feature loads%s%s", ok ? "" : ": ", ok ? "" : e.message);
    if (!ok)
        return;
    sim_material def = sim_material_default();
    CHECK(s.material.roughness == 0.7 && s.material.repose_deg == def.repose_deg &&
              s.material.method == def.method,
          "missing material keys come from sim_material_default()");
    CHECK(s.tick_hz == 60 && s.active_margin_cells == 4 && s.units_per_m == 10000 &&
              s.base.kind == WORLD_BASE_FLAT && s.base.height_m == 0 &&
              strcmp(s.name, "unnamed") == 0,
          "top-level defaults");
    CHECK(strcmp(s.colliders[0].name, "w") == 0 && strcmp(s.colliders[1].name, "collider-1") == 0,
          "collider names, given and defaulted");
    CHECK(s.colliders[0].geometry.shape == COLLIDER_CYLINDER &&
              s.colliders[0].motion.start.orientation.w == 1 &&
              fabs(s.colliders[0].motion.spin_rad_per_s - M_PI / 2) < 1e-12 &&
              s.colliders[0].geometry.grousers.count == 12 &&
              s.colliders[0].geometry.grousers.height == 0.02 &&
              s.colliders[0].geometry.grousers.thickness == 0.01 &&
              s.colliders[1].geometry.grousers.count == 0,
          "wheel is a cylinder with its grousers; orientation normalised; spin in rad/s");
    collider_pose p = collider_motion_pose(&s.colliders[1].motion, 1.0);
    CHECK(s.colliders[1].motion.kind == COLLIDER_MOTION_KEYFRAMES &&
              s.colliders[1].motion.keyframe_count == 2 && fabs(p.position.x - 1) < 1e-12,
          "keyframes parsed and interpolated");
    scene_free(&s);
    CHECK(s.colliders == NULL && s.collider_count == 0, "scene_free clears");

    /* relative heightmap and mesh paths resolve against the scene's directory */
    char dir[] = "/tmp/terrad_test_scene_XXXXXX";
    if (!mkdtemp(dir)) {
        CHECK(0, "mkdtemp");
        return;
    }
    char path[512];
    snprintf(path, sizeof path, "%s/h.raw", dir);
    FILE *f = fopen(path, "wb");
    for (int i = 0; i < 6; i++) {
        fputc(i * 10, f);
        fputc(0, f);
    }
    fclose(f);
    snprintf(path, sizeof path, "%s/tri.obj", dir);
    f = fopen(path, "wb");
    fputs("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n", f);
    fclose(f);
    snprintf(path, sizeof path, "%s/s.json", dir);
    f = fopen(path, "wb");
    fputs("{\"world\": {\"width\": 3, \"height\": 2, \"cell_size_m\": 0.5},\n"
          " \"terrain\": {\"kind\": \"raw_int16\", \"path\": \"h.raw\", \"scale_units\": 2, "
          "\"offset_units\": 5},\n"
          " \"colliders\": [{\"shape\": \"mesh\", \"obj\": \"tri.obj\", \"scale\": 0.5, "
          "\"position\": [0, 0, 0]}]}\n",
          f);
    fclose(f);
    ok = scene_load_file(path, &s, &e) == 0;
    CHECK(ok, "scene with relative paths loads%s%s", ok ? "" : ": ", ok ? "" : e.message);
    if (ok) {
        world w;
        CHECK(scene_create_world(&s, &w, &e) == 0 && world_height_at(&w, 0, 0) == 5 &&
                  world_height_at(&w, 5 % w.width, 5 / w.width) == 105,
              "raw heightmap found beside the scene, scaled and offset");
        world_free(&w);
        const collider_mesh *m = s.colliders[0].geometry.mesh;
        CHECK(s.mesh_count == 1 && m == &s.meshes[0] && m->triangle_count == 4 &&
                  m->vertices[3] == 0.5f && fabs(m->bounding_radius - 0.5) < 1e-9,
              "mesh found beside the scene and scaled");
        scene_free(&s);
    }
    /* a heightmap of the wrong size is refused when the world is built */
    f = fopen(path, "wb");
    fputs("{\"world\": {\"width\": 4, \"height\": 2, \"cell_size_m\": 0.5},\n"
          " \"terrain\": {\"kind\": \"raw_int16\", \"path\": \"h.raw\"}}\n",
          f);
    fclose(f);
    if (scene_load_file(path, &s, &e) == 0) {
        world w;
        CHECK(scene_create_world(&s, &w, &e) != 0 && has(&e, "h.raw") && has(&e, "bytes"),
              "wrong-size heightmap refused naming the file: %s", e.message);
        scene_free(&s);
    } else {
        CHECK(0, "wrong-size scene loads before its world is built: %s", e.message);
    }
    f = fopen(path, "wb");
    fputs("{\"world\": {\"width\": 4, \"height\": 2, \"cell_size_m\": 0.5}, \"oops\": 1}", f);
    fclose(f);
    CHECK(scene_load_file(path, &s, &e) != 0 && has(&e, path) && has(&e, "oops: unknown key"),
          "file errors name the file and the key: %s", e.message);
    char rm[600];
    snprintf(rm, sizeof rm, "rm -rf '%s'", dir);
    if (system(rm) != 0)
        printf("     (could not remove %s)\n", dir);
    CHECK(scene_load_file("/nonexistent/scene.json", &s, &e) != 0 &&
              has(&e, "/nonexistent/scene.json"),
          "missing scene file named: %s", e.message);
}

int main(void)
{
    test_all_scenes();
    test_thesis_car();
    test_default_scene();
    test_errors();
    test_details();
    printf("%d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
