/*
 * twin.c: the twin as a client library (terrad_twin.h). A client's window is
 * a sparse world (world/) of the server's extent and base terrain with the
 * window's heights written into it, one CPU backend and one engine
 * (sim/sim_engine.c) — the very code `terrad serve --backend cpu` and
 * `terrad simulate` tick, so heights match bit for bit. Colliders keep their
 * pose between ticks and sweep from the previous tick's pose, as the
 * service's collider table does (service/service.c, gather_colliders).
 * Nothing here runs on the daemon's tick; the daemon links this file only
 * because server/ is one library.
 */
#include "twin/terrad_twin.h"
#include "twin/twin_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ground/ground.h"
#include "sim/sim.h"

struct terrad_twin_config {
    int width, height;
    double cell_size_m;
    double units_per_m, floor_units, margin_cells, tick_hz;
    world_base_spec base;
    sim_material material;
};

typedef struct twin_collider {
    int id;
    collider_geometry geometry;
    collider_mesh mesh; /* owned copy when geometry.shape is COLLIDER_MESH */
    collider_pose pose, previous_pose;
    int has_pose, has_previous;
    double load_n; /* > 0: load-driven (bekker), the height is the engine's to find */
} twin_collider;

struct terrad_twin {
    world_rect window;
    int bekker; /* the model computes soil forces: load-driven colliders may be */
    world w;
    ground g;
    sim_params params;
    sim_backend *backend;
    sim_engine *engine;
    twin_collider *colliders;
    int collider_count;
    int64_t collider_capacity;
    sim_collider *batch;
};

int twin_fail(char *err, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        vsnprintf(err, TERRAD_TWIN_ERROR_MAX, fmt, ap);
        va_end(ap);
    }
    return -1;
}

static void copy_error(char *err, const error_text *e)
{
    if (err)
        snprintf(err, TERRAD_TWIN_ERROR_MAX, "%s", e->message);
}

terrad_twin_config *terrad_twin_config_new(void)
{
    terrad_twin_config *c = calloc(1, sizeof *c);
    if (!c)
        return NULL;
    c->width = c->height = 1024;
    c->cell_size_m = 0.05;
    c->units_per_m = 10000;
    c->margin_cells = 4;
    c->tick_hz = 60;
    c->base.kind = WORLD_BASE_FLAT;
    c->material = sim_material_default();
    return c;
}

void terrad_twin_config_free(terrad_twin_config *c)
{
    free(c);
}

double twin_config_tick_hz(const terrad_twin_config *c)
{
    return c->tick_hz;
}

/* The numeric keys: each a double field, or an int one (is_int). */
typedef struct config_key {
    const char *name;
    size_t offset;
    int is_int;
} config_key;

#define KEY_D(name, field)                                                                         \
    {                                                                                              \
        name, offsetof(terrad_twin_config, field), 0                                               \
    }
#define KEY_I(name, field)                                                                         \
    {                                                                                              \
        name, offsetof(terrad_twin_config, field), 1                                               \
    }
static const config_key config_keys[] = {
    KEY_I("width", width),
    KEY_I("height", height),
    KEY_D("cell_size_m", cell_size_m),
    KEY_D("units_per_m", units_per_m),
    KEY_D("floor_units", floor_units),
    KEY_D("margin_cells", margin_cells),
    KEY_D("tick_hz", tick_hz),
    KEY_D("terrain.height_m", base.height_m),
    KEY_D("terrain.min_height_m", base.min_height_m),
    KEY_D("terrain.max_height_m", base.max_height_m),
    KEY_D("terrain.wavelength_m", base.wavelength_m),
    KEY_I("terrain.octaves", base.octaves),
    KEY_D("compression", material.compression),
    KEY_D("roughness", material.roughness),
    KEY_D("repose_deg", material.repose_deg),
    KEY_D("obstacle_gap_m", material.obstacle_gap_m),
    KEY_D("multi_target_m", material.multi_target_m),
    KEY_I("multi_target_max", material.multi_target_max),
    KEY_I("displace_iterations", material.displace_iterations),
    KEY_I("slope_iterations", material.slope_iterations),
    KEY_D("refill_m_per_s", material.refill_m_per_s),
    KEY_D("trail_scale_per_m", material.trail_scale_per_m),
    KEY_D("trail_range_m", material.trail_range_m),
    KEY_D("edge_height", material.edge_height),
    KEY_D("edge_width", material.edge_width),
    KEY_D("diffusion_d", material.diffusion_d),
    KEY_D("diffusion_zeta_inv", material.diffusion_zeta_inv),
    KEY_D("diffusion_force_scale", material.diffusion_force_scale),
    KEY_D("diffusion_dt", material.diffusion_dt),
    KEY_I("diffusion_substeps", material.diffusion_substeps),
    KEY_I("diffusion_conservative", material.diffusion_conservative),
    KEY_D("decal_min_strength_m", material.decal_min_strength_m),
    KEY_D("soil.n", material.soil.n),
    KEY_D("soil.kc", material.soil.kc),
    KEY_D("soil.kphi", material.soil.kphi),
    KEY_D("soil.cohesion_pa", material.soil.cohesion_pa),
    KEY_D("soil.friction_deg", material.soil.friction_deg),
    KEY_D("soil.shear_k_m", material.soil.shear_k_m),
    KEY_D("soil.elastic_pa_m", material.soil.elastic_pa_m),
    KEY_D("soil.damping_pa_s_m", material.soil.damping_pa_s_m),
    KEY_D("soil.slip_n", material.soil.slip_n),
    KEY_D("soil.density_kg_m3", material.soil.density_kg_m3),
};

int terrad_twin_config_set(terrad_twin_config *c, const char *key, double value, char *err)
{
    if (!c || !key)
        return twin_fail(err, "config: no config or key");
    if (!isfinite(value))
        return twin_fail(err, "%s: must be a finite number (got %g)", key, value);
    if (strcmp(key, "terrain.seed") == 0) {
        if (value < 0 || value > 4294967295.0 || value != floor(value))
            return twin_fail(err, "%s: must be an integer in [0, 2^32) (got %g)", key, value);
        c->base.seed = (uint32_t)value;
        return 0;
    }
    for (size_t i = 0; i < sizeof config_keys / sizeof config_keys[0]; i++) {
        const config_key *k = &config_keys[i];
        if (strcmp(k->name, key) != 0)
            continue;
        char *field = (char *)c + k->offset;
        if (k->is_int) {
            if (value != floor(value) || fabs(value) > 2147483647.0)
                return twin_fail(err, "%s: must be an integer (got %g)", key, value);
            *(int *)field = (int)value;
        } else {
            *(double *)field = value;
        }
        return 0;
    }
    return twin_fail(err, "%s: no such key (terrad_twin.h lists them)", key);
}

int terrad_twin_config_set_name(terrad_twin_config *c, const char *key, const char *value,
                                char *err)
{
    if (!c || !key || !value)
        return twin_fail(err, "config: no config, key or value");
    sim_material *m = &c->material;
    if (strcmp(key, "model") == 0) {
        if (sim_model_parse(value, &m->model) != 0)
            return twin_fail(err, "model: must be one of " SIM_MODEL_LIST " (got \"%s\")", value);
        if (sim_model_is_persson(m->model))
            m->method = m->model == SIM_MODEL_PERSSON_ITERATIVE ? SIM_METHOD_ITERATIVE
                        : m->model == SIM_MODEL_PERSSON_MULTI   ? SIM_METHOD_MULTI
                                                                : SIM_METHOD_SSBO;
        return 0;
    }
    if (strcmp(key, "metric") == 0) {
        if (sim_metric_parse(value, &m->metric) != 0)
            return twin_fail(err, "metric: must be euclidean, manhattan or chebyshev (got \"%s\")",
                             value);
        return 0;
    }
    if (strcmp(key, "terrain.kind") == 0) {
        if (strcmp(value, "flat") == 0)
            c->base.kind = WORLD_BASE_FLAT;
        else if (strcmp(value, "dunes") == 0)
            c->base.kind = WORLD_BASE_DUNES;
        else
            return twin_fail(err, "terrain.kind: must be flat or dunes (got \"%s\")", value);
        return 0;
    }
    return twin_fail(err, "%s: no such name key (model, metric, terrain.kind)", key);
}

void terrad_twin_destroy(terrad_twin *t)
{
    if (!t)
        return;
    if (t->engine)
        sim_engine_destroy(t->engine);
    if (t->backend)
        t->backend->destroy(t->backend);
    ground_free(&t->g);
    world_free(&t->w);
    for (int i = 0; i < t->collider_count; i++)
        collider_mesh_free(&t->colliders[i].mesh);
    free(t->colliders);
    free(t->batch);
    free(t);
}

static int in_window(const terrad_twin *t, int x, int y, int w, int h)
{
    const world_rect *r = &t->window;
    return w > 0 && h > 0 && x >= r->x && y >= r->y && (int64_t)x + w <= (int64_t)r->x + r->w &&
           (int64_t)y + h <= (int64_t)r->y + r->h;
}

/* The world, its ground and the engine, as the daemon makes them from a
 * scene (scene_create_world, scene_create_ground, host_sim_start). */
static int twin_open(terrad_twin *t, const terrad_twin_config *c, error_text *e)
{
    if (c->units_per_m < 1 || c->units_per_m > 1e9 || c->floor_units != floor(c->floor_units) ||
        fabs(c->floor_units) > WORLD_HEIGHT_MAX || c->margin_cells != floor(c->margin_cells) ||
        !(c->tick_hz > 0 && c->tick_hz <= 10000)) {
        error_set(e, "config: units_per_m, floor_units, margin_cells or tick_hz out of range");
        return -1;
    }
    if (world_init(&t->w, c->width, c->height, c->cell_size_m, (int32_t)c->units_per_m,
                   (int32_t)c->floor_units, e) != 0 ||
        world_generate_base(&t->w, &c->base, e) != 0)
        return -1;
    sim_material m = c->material;
    m.tick_s = 1.0 / c->tick_hz;
    ground_material base = sim_material_ground(&m);
    if (sim_params_from_material(&m, t->w.cell_size_m, t->w.units_per_m, t->w.floor, &t->params,
                                 e) != 0 ||
        ground_init_uniform(&t->g, ground_extent_of_world(&t->w), &base, e) != 0)
        return -1;
    if (!(t->backend = sim_backend_cpu_create(e)) ||
        !(t->engine = sim_engine_create(&t->w, &t->params, t->backend, (int)c->margin_cells, e)))
        return -1;
    sim_engine_set_ground(t->engine, &t->g);
    t->bekker = m.model == SIM_MODEL_BEKKER;
    return 0;
}

terrad_twin *terrad_twin_create(const terrad_twin_config *c, int x, int y, int w, int h,
                                const int32_t *heights, char *err)
{
    if (!c) {
        twin_fail(err, "create: no config");
        return NULL;
    }
    terrad_twin *t = calloc(1, sizeof *t);
    if (!t) {
        twin_fail(err, "create: out of memory");
        return NULL;
    }
    error_text e = {{0}};
    if (twin_open(t, c, &e) != 0) {
        copy_error(err, &e);
        terrad_twin_destroy(t);
        return NULL;
    }
    t->window = (world_rect){x, y, w, h};
    if (x < 0 || y < 0 || !in_window(t, x, y, w, h) || (int64_t)x + w > t->w.width ||
        (int64_t)y + h > t->w.height) {
        twin_fail(err, "window: %d,%d %dx%d must be non-empty and inside the %dx%d world", x, y, w,
                  h, t->w.width, t->w.height);
        terrad_twin_destroy(t);
        return NULL;
    }
    if (heights && terrad_twin_write(t, x, y, w, h, heights, err) != 0) {
        terrad_twin_destroy(t);
        return NULL;
    }
    return t;
}

static int find_collider(const terrad_twin *t, int id)
{
    for (int i = 0; i < t->collider_count; i++)
        if (t->colliders[i].id == id)
            return i;
    return -1;
}

/* Append a collider whose geometry is valid; the mesh copy moves in. */
static int add_collider(terrad_twin *t, int id, const collider_geometry *g, collider_mesh *mesh,
                        char *err)
{
    if (find_collider(t, id) >= 0)
        return twin_fail(err, "id: collider %d exists already", id);
    error_text e = {{0}};
    if (collider_geometry_validate(g, &e) != 0) {
        copy_error(err, &e);
        return -1;
    }
    if (array_grow((void **)&t->colliders, &t->collider_capacity, (int64_t)t->collider_count + 1,
                   sizeof *t->colliders) != 0 ||
        !(t->batch = realloc(t->batch, (size_t)t->collider_capacity * sizeof *t->batch)))
        return twin_fail(err, "collider: out of memory");
    twin_collider *c = &t->colliders[t->collider_count++];
    memset(c, 0, sizeof *c);
    c->id = id;
    c->geometry = *g;
    if (mesh) {
        c->mesh = *mesh;
        c->geometry.mesh = &c->mesh;
    }
    return 0;
}

int terrad_twin_add_collider(terrad_twin *t, int id, const char *shape, double radius,
                             double half_length, double hx, double hy, double hz, char *err)
{
    if (!t || !shape)
        return twin_fail(err, "collider: no twin or shape");
    collider_geometry g = {
        .radius = radius, .half_length = half_length, .half_extents = {hx, hy, hz}};
    if (strcmp(shape, "sphere") == 0)
        g.shape = COLLIDER_SPHERE;
    else if (strcmp(shape, "box") == 0)
        g.shape = COLLIDER_BOX;
    else if (strcmp(shape, "capsule") == 0)
        g.shape = COLLIDER_CAPSULE;
    else if (strcmp(shape, "cylinder") == 0)
        g.shape = COLLIDER_CYLINDER;
    else
        return twin_fail(err, "shape: must be sphere, box, capsule or cylinder (got \"%s\")",
                         shape);
    return add_collider(t, id, &g, NULL, err);
}

int terrad_twin_add_wheel(terrad_twin *t, int id, double radius, double half_length,
                          double grouser_count, double grouser_height, double grouser_thickness,
                          char *err)
{
    if (!t)
        return twin_fail(err, "collider: no twin");
    /* the count's own check (the geometry's takes it as an int): a binding's double, whole */
    if (!(grouser_count >= 0 && grouser_count <= COLLIDER_GROUSERS_MAX) ||
        grouser_count != floor(grouser_count))
        return twin_fail(err, "grousers.count: must be an integer 0..%d (got %g)",
                         COLLIDER_GROUSERS_MAX, grouser_count);
    if (grouser_count == 0 && (grouser_height != 0 || grouser_thickness != 0))
        return twin_fail(err,
                         "grousers.count: 0 is a smooth rim, which has no grousers.height or "
                         "grousers.thickness (got %g, %g)",
                         grouser_height, grouser_thickness);
    collider_geometry g = {.shape = COLLIDER_CYLINDER,
                           .radius = radius,
                           .half_length = half_length,
                           .grousers = {(int)grouser_count, grouser_height, grouser_thickness}};
    return add_collider(t, id, &g, NULL, err); /* the sizes: collider_geometry_validate's */
}

int terrad_twin_add_mesh(terrad_twin *t, int id, const float *vertices, int vertex_count,
                         const uint32_t *indices, int triangle_count, char *err)
{
    if (!t || !vertices || !indices || vertex_count < 3 || triangle_count < 1 ||
        vertex_count > (1 << 24) || triangle_count > (1 << 24))
        return twin_fail(err, "mesh: needs 3 to 2^24 vertices and 1 to 2^24 triangles%s", "");
    collider_mesh m = {.vertex_count = vertex_count, .triangle_count = triangle_count};
    m.vertices = malloc((size_t)vertex_count * 3 * sizeof *m.vertices);
    m.indices = malloc((size_t)triangle_count * 3 * sizeof *m.indices);
    if (!m.vertices || !m.indices) {
        collider_mesh_free(&m);
        return twin_fail(err, "mesh: out of memory");
    }
    memcpy(m.vertices, vertices, (size_t)vertex_count * 3 * sizeof *m.vertices);
    memcpy(m.indices, indices, (size_t)triangle_count * 3 * sizeof *m.indices);
    for (int i = 0; i < vertex_count; i++) {
        const float *v = m.vertices + 3 * i;
        double r = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
        if (!isfinite(r)) {
            collider_mesh_free(&m);
            return twin_fail(err, "mesh: vertex %d is not finite", i);
        }
        if (r > m.bounding_radius)
            m.bounding_radius = r;
    }
    for (int i = 0; i < triangle_count * 3; i++)
        if (m.indices[i] >= (uint32_t)vertex_count) {
            collider_mesh_free(&m);
            return twin_fail(err, "mesh: index %d names no vertex", i);
        }
    collider_geometry g = {.shape = COLLIDER_MESH, .mesh = &m};
    if (add_collider(t, id, &g, &m, err) != 0) {
        collider_mesh_free(&m);
        return -1;
    }
    return 0;
}

int terrad_twin_remove_collider(terrad_twin *t, int id, char *err)
{
    int k = t ? find_collider(t, id) : -1;
    if (k < 0)
        return twin_fail(err, "id: no collider %d", id);
    collider_mesh_free(&t->colliders[k].mesh);
    memmove(t->colliders + k, t->colliders + k + 1,
            (size_t)(t->collider_count - k - 1) * sizeof *t->colliders);
    t->collider_count--;
    for (int i = k; i < t->collider_count; i++) /* the mesh moved with its collider */
        if (t->colliders[i].geometry.shape == COLLIDER_MESH)
            t->colliders[i].geometry.mesh = &t->colliders[i].mesh;
    return 0;
}

/* Collider id's pose p once p is valid (else -1, err written). placed: also
 * its previous pose, as if the last tick had pressed there (no sweep to it);
 * otherwise a collider that had no pose has no previous one to sweep from. */
static int pose_collider(terrad_twin *t, int id, collider_pose p, int placed, char *err)
{
    int k = t ? find_collider(t, id) : -1;
    if (k < 0)
        return twin_fail(err, "id: no collider %d", id);
    error_text e = {{0}};
    if (collider_pose_validate(&p, &e) != 0) {
        copy_error(err, &e);
        return -1;
    }
    twin_collider *c = &t->colliders[k];
    if (placed) {
        c->previous_pose = p;
        c->has_previous = 1;
    } else if (!c->has_pose) {
        c->has_previous = 0;
    }
    c->has_pose = 1;
    c->pose = p;
    return 0;
}

int terrad_twin_set_pose(terrad_twin *t, int id, double x, double y, double z, double qw, double qx,
                         double qy, double qz, char *err)
{
    return pose_collider(t, id, (collider_pose){{x, y, z}, {qw, qx, qy, qz}}, 0, err);
}

int terrad_twin_place(terrad_twin *t, int id, double x, double y, double z, double qw, double qx,
                      double qy, double qz, char *err)
{
    return pose_collider(t, id, (collider_pose){{x, y, z}, {qw, qx, qy, qz}}, 1, err);
}

int twin_unpose(terrad_twin *t, int id, char *err)
{
    int k = t ? find_collider(t, id) : -1;
    if (k < 0)
        return twin_fail(err, "id: no collider %d", id);
    t->colliders[k].has_pose = t->colliders[k].has_previous = 0;
    return 0;
}

int terrad_twin_set_load(terrad_twin *t, int id, double load_n, char *err)
{
    int k = t ? find_collider(t, id) : -1;
    if (k < 0)
        return twin_fail(err, "id: no collider %d", id);
    if (!isfinite(load_n) || load_n < 0)
        return twin_fail(err, "load_n: must be a number of newtons >= 0 (got %g)", load_n);
    if (load_n > 0 && !t->bekker)
        return twin_fail(err, "load_n: this world's model computes no soil forces (load-driven "
                              "colliders need the bekker model)");
    t->colliders[k].load_n = load_n;
    return 0;
}

int terrad_twin_tick(terrad_twin *t, char *err)
{
    if (!t)
        return twin_fail(err, "tick: no twin");
    int n = 0;
    for (int i = 0; i < t->collider_count; i++) {
        const twin_collider *c = &t->colliders[i];
        if (!c->has_pose)
            continue;
        /* as the service's gather_colliders: one rule for a load-driven height */
        t->batch[n++] = sim_collider_for_tick(c->id, &c->geometry, c->pose, c->previous_pose,
                                              c->has_previous, c->load_n);
    }
    sim_tick_report report;
    error_text e = {{0}};
    if (sim_engine_tick(t->engine, t->batch, n, &report, &e) != 0) {
        copy_error(err, &e);
        return -1;
    }
    for (int i = 0, k = 0; i < t->collider_count; i++) {
        twin_collider *c = &t->colliders[i];
        if (!c->has_pose)
            continue; /* the contacts are the tick's colliders, in its order */
        if (c->load_n > 0.0 && k < report.contact_count)
            c->pose.position.z = report.contacts[k].pose_z_m; /* where the soil carried it */
        k++;
    }
    for (int i = 0; i < t->collider_count; i++) {
        t->colliders[i].previous_pose = t->colliders[i].pose;
        t->colliders[i].has_previous = t->colliders[i].has_pose;
    }
    return 0;
}

int terrad_twin_read(const terrad_twin *t, int x, int y, int w, int h, int32_t *out, char *err)
{
    if (!t || !out || !in_window(t, x, y, w, h))
        return twin_fail(err, "read: the rectangle must be non-empty and inside the window");
    world_gather_window(&t->w, (world_rect){x, y, w, h}, out);
    return 0;
}

int terrad_twin_write(terrad_twin *t, int x, int y, int w, int h, const int32_t *heights, char *err)
{
    if (!t || !heights || !in_window(t, x, y, w, h))
        return twin_fail(err, "write: the rectangle must be non-empty and inside the window");
    for (int64_t i = 0; i < (int64_t)w * h; i++)
        if (heights[i] < WORLD_HEIGHT_MIN || heights[i] > WORLD_HEIGHT_MAX)
            return twin_fail(err, "heights: cell %lld is outside the height range", (long long)i);
    world_scatter_window(&t->w, (world_rect){x, y, w, h}, heights);
    return 0;
}

/* ---- what the window holds beside its heights (twin_internal.h) ---------- */

int64_t twin_state_values(const terrad_twin *t)
{
    int64_t n = 0;
    for (int l = 0; l < WORLD_LAYERS; l++)
        n += (int64_t)world_layer_fields((world_layer_id)l) * t->window.w * t->window.h;
    return n;
}

void twin_state_read(const terrad_twin *t, int32_t *out)
{
    for (int l = 0; l < WORLD_LAYERS; l++) {
        world_layer_gather(&t->w, (world_layer_id)l, t->window, out);
        out += (int64_t)world_layer_fields((world_layer_id)l) * t->window.w * t->window.h;
    }
}

int twin_state_write(terrad_twin *t, const int32_t *in)
{
    for (int l = 0; l < WORLD_LAYERS; l++) {
        int64_t n = (int64_t)world_layer_fields((world_layer_id)l) * t->window.w * t->window.h;
        int64_t any = 0;
        for (int64_t i = 0; i < n && !any; i++)
            any = in[i];
        /* a layer the world never enabled stays off while its values are all 0 */
        if ((any || world_layer_enabled(&t->w, (world_layer_id)l)) &&
            world_layer_scatter(&t->w, (world_layer_id)l, t->window, in) != 0)
            return -1;
        in += n;
    }
    return 0;
}

int twin_keeps_state(const terrad_twin *t)
{
    for (int l = 0; l < WORLD_LAYERS; l++)
        if (world_layer_enabled(&t->w, (world_layer_id)l))
            return 1;
    return t->bekker; /* its soil layer comes with the first press */
}

int twin_pose_z(const terrad_twin *t, int id, double *z)
{
    int k = t ? find_collider(t, id) : -1;
    if (k < 0 || !t->colliders[k].has_pose)
        return -1;
    *z = t->colliders[k].pose.position.z;
    return 0;
}
