/*
 * scene_colliders.c: a scene's "colliders" — shapes (analytic or an OBJ
 * mesh) and scripted motion (velocity and spin, or keyframes). Read once;
 * each tick of an offline run or the demo asks every scene collider for its
 * pose with collider_motion_pose.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "scene/scene_internal.h"

static int parse_quat(const cJSON *obj, const char *path, quatd *q, error_text *err)
{
    double v[4];
    int r = json_get_vector(obj, path, "orientation", 4, 1e6, v, err);
    if (r <= 0) {
        *q = (quatd){1, 0, 0, 0};
        return r;
    }
    double n2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3];
    if (!(n2 > 1e-12)) {
        char p[256];
        json_path_join(p, sizeof p, path, "orientation");
        error_set(err, "%s: must be a non-zero quaternion [w, x, y, z]", p);
        return -1;
    }
    *q = quat_normalize((quatd){v[0], v[1], v[2], v[3]});
    return 1;
}

static int parse_position(const cJSON *obj, const char *path, vec3d *p, error_text *err)
{
    double v[3];
    int r = json_get_vector(obj, path, "position", 3, 1e6, v, err);
    if (r > 0)
        *p = (vec3d){v[0], v[1], v[2]};
    return r;
}

static int parse_keyframes(const cJSON *arr, const char *path, collider_motion *m, error_text *err)
{
    int n = cJSON_IsArray(arr) ? cJSON_GetArraySize(arr) : 0;
    if (n < 1 || n > SCENE_KEYFRAMES_MAX) {
        error_set(err, "%s: must be an array of 1 to %d keyframes", path, SCENE_KEYFRAMES_MAX);
        return -1;
    }
    m->keyframes = calloc((size_t)n, sizeof *m->keyframes);
    if (!m->keyframes) {
        error_set(err, "%s: out of memory", path);
        return -1;
    }
    m->keyframe_count = n;
    static const char *const keys[] = {"time_s", "position", "orientation", NULL};
    int i = 0;
    for (const cJSON *k = arr->child; k; k = k->next, i++) {
        char p[256];
        json_path_index(p, sizeof p, path, i);
        collider_keyframe *f = &m->keyframes[i];
        if (json_expect_object(k, p, "scene", err) || json_check_keys(k, p, keys, NULL, err) ||
            json_require_number(k, p, "time_s", -SCENE_TIME_MAX_S, SCENE_TIME_MAX_S, &f->time_s,
                                err))
            return -1;
        if (i > 0 && !(f->time_s > m->keyframes[i - 1].time_s)) {
            error_set(err, "%s.time_s: must be greater than the previous keyframe's (%g <= %g)", p,
                      f->time_s, m->keyframes[i - 1].time_s);
            return -1;
        }
        int r = parse_position(k, p, &f->pose.position, err);
        if (r < 0)
            return -1;
        if (r == 0) {
            error_set(err, "%s.position: missing ([x, y, z] in metres)", p);
            return -1;
        }
        if (parse_quat(k, p, &f->pose.orientation, err) < 0)
            return -1;
    }
    return 0;
}

static int parse_motion(const cJSON *c, const char *path, collider_motion *m, int has_position,
                        error_text *err)
{
    const cJSON *o = cJSON_GetObjectItemCaseSensitive(c, "motion");
    char p[256];
    json_path_join(p, sizeof p, path, "motion");
    m->kind = COLLIDER_MOTION_STATIC;
    if (!o) {
        if (!has_position) {
            error_set(err, "%s.position: missing ([x, y, z] in metres)", path);
            return -1;
        }
        return 0;
    }
    if (json_expect_object(o, p, "scene", err))
        return -1;
    const cJSON *kf = cJSON_GetObjectItemCaseSensitive(o, "keyframes");
    if (kf) {
        static const char *const keys[] = {"keyframes", NULL};
        if (json_check_keys(o, p, keys, "keyframe motion (velocity and keyframes do not mix)", err))
            return -1;
        if (has_position) {
            error_set(err,
                      "%s.position: not allowed with motion.keyframes (the keyframes give "
                      "the pose)",
                      path);
            return -1;
        }
        char q[280];
        json_path_join(q, sizeof q, p, "keyframes");
        if (parse_keyframes(kf, q, m, err) != 0)
            return -1;
        m->kind = COLLIDER_MOTION_KEYFRAMES;
        m->start = m->keyframes[0].pose;
        return 0;
    }
    static const char *const keys[] = {"velocity", "spin_axis", "spin_deg_per_s", NULL};
    if (json_check_keys(o, p, keys, NULL, err))
        return -1;
    if (!has_position) {
        error_set(err, "%s.position: missing ([x, y, z] in metres)", path);
        return -1;
    }
    double v[3] = {0, 0, 0}, axis[3] = {0, 0, 1}, spin = 0;
    if (json_get_vector(o, p, "velocity", 3, SCENE_SPEED_MAX, v, err) < 0 ||
        json_get_vector(o, p, "spin_axis", 3, 1e6, axis, err) < 0 ||
        json_get_number(o, p, "spin_deg_per_s", -SCENE_SPIN_MAX_DEG, SCENE_SPIN_MAX_DEG, &spin,
                        err) < 0)
        return -1;
    if (spin != 0.0 && !(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2] > 1e-12)) {
        error_set(err, "%s.spin_axis: must be a non-zero vector when spin_deg_per_s is not 0", p);
        return -1;
    }
    m->kind = COLLIDER_MOTION_VELOCITY;
    m->velocity = (vec3d){v[0], v[1], v[2]};
    m->spin_axis = (vec3d){axis[0], axis[1], axis[2]};
    m->spin_rad_per_s = spin * (M_PI / 180.0);
    return 0;
}

static int load_mesh(const scene_parser *ps, const cJSON *c, const char *path, scene *s,
                     collider_geometry *g, error_text *err)
{
    char rel[1024], full[1024];
    int r = json_get_string(c, path, "obj", rel, sizeof rel, err);
    if (r < 0)
        return -1;
    if (r == 0 || !rel[0]) {
        error_set(err, "%s.obj: missing (the OBJ file of a mesh collider)", path);
        return -1;
    }
    double scale = 1.0;
    if (json_get_positive(c, path, "scale", 1e6, 0, &scale, err) < 0)
        return -1;
    char field[280];
    json_path_join(field, sizeof field, path, "obj");
    if (scene_resolve_path(ps->base_dir, rel, full, sizeof full, field, err))
        return -1;
    collider_mesh *m = &s->meshes[s->mesh_count];
    if (collider_mesh_load_obj(full, m, err) != 0) {
        error_prefix(err, field, ": ");
        return -1;
    }
    s->mesh_count++;
    if (scale != 1.0) {
        for (int i = 0; i < 3 * m->vertex_count; i++)
            m->vertices[i] = (float)(m->vertices[i] * scale);
        m->bounding_radius *= scale;
    }
    g->mesh = m;
    return 0;
}

/* a cylinder's keys: the axial shape's and its optional lugs (collider/lugs_json.c) */
static const char *const wheel_keys[] = {"name",        "shape",    "position",
                                         "orientation", "motion",   "radius",
                                         "half_length", "grousers", NULL};

static int parse_collider(const scene_parser *ps, const cJSON *c, const char *path, int index,
                          scene *s, scene_collider *sc, error_text *err)
{
    if (json_expect_object(c, path, "scene", err))
        return -1;
    char shape[32];
    int r = json_get_string(c, path, "shape", shape, sizeof shape, err);
    if (r < 0)
        return -1;
    if (r == 0) {
        error_set(err, "%s.shape: missing (sphere, box, capsule, cylinder, wheel or mesh)", path);
        return -1;
    }
    collider_geometry *g = &sc->geometry;
    const char *context;
    static const char *const sphere_keys[] = {"name",   "shape",  "position", "orientation",
                                              "motion", "radius", NULL};
    static const char *const axial_keys[] = {"name",   "shape",  "position",    "orientation",
                                             "motion", "radius", "half_length", NULL};
    static const char *const box_keys[] = {"name",   "shape",        "position", "orientation",
                                           "motion", "half_extents", NULL};
    static const char *const mesh_keys[] = {"name",   "shape", "position", "orientation",
                                            "motion", "obj",   "scale",    NULL};
    const char *const *keys;
    if (strcmp(shape, "sphere") == 0) {
        g->shape = COLLIDER_SPHERE;
        keys = sphere_keys;
        context = "a sphere";
    } else if (strcmp(shape, "box") == 0) {
        g->shape = COLLIDER_BOX;
        keys = box_keys;
        context = "a box";
    } else if (strcmp(shape, "capsule") == 0) {
        g->shape = COLLIDER_CAPSULE;
        keys = axial_keys;
        context = "a capsule";
    } else if (strcmp(shape, "cylinder") == 0 || strcmp(shape, "wheel") == 0) {
        g->shape = COLLIDER_CYLINDER;
        keys = wheel_keys;
        context = "a cylinder";
    } else if (strcmp(shape, "mesh") == 0) {
        g->shape = COLLIDER_MESH;
        keys = mesh_keys;
        context = "a mesh";
    } else {
        error_set(err,
                  "%s.shape: must be sphere, box, capsule, cylinder, wheel or mesh (got \"%s\")",
                  path, shape);
        return -1;
    }
    if (json_check_keys(c, path, keys, context, err))
        return -1;
    r = json_get_string(c, path, "name", sc->name, sizeof sc->name, err);
    if (r < 0)
        return -1;
    if (r == 0)
        snprintf(sc->name, sizeof sc->name, "collider-%d", index);

    switch (g->shape) {
    case COLLIDER_SPHERE:
        if (json_get_positive(c, path, "radius", 1000, 1, &g->radius, err) < 0)
            return -1;
        break;
    case COLLIDER_CAPSULE:
    case COLLIDER_CYLINDER:
        if (json_get_positive(c, path, "radius", 1000, 1, &g->radius, err) < 0)
            return -1;
        if (g->shape == COLLIDER_CAPSULE) {
            if (json_require_number(c, path, "half_length", 0, 1000, &g->half_length, err))
                return -1;
        } else if (json_get_positive(c, path, "half_length", 1000, 1, &g->half_length, err) < 0 ||
                   collider_grousers_from_json(c, path, &g->grousers, err) < 0) {
            return -1;
        }
        break;
    case COLLIDER_BOX: {
        double e[3];
        r = json_get_vector(c, path, "half_extents", 3, 1000, e, err);
        if (r < 0)
            return -1;
        if (r == 0) {
            error_set(err, "%s.half_extents: missing ([x, y, z] half sizes in metres)", path);
            return -1;
        }
        g->half_extents = (vec3d){e[0], e[1], e[2]};
        break;
    }
    case COLLIDER_MESH:
        if (load_mesh(ps, c, path, s, g, err) != 0)
            return -1;
        break;
    }
    /* the collider module's own checks (sizes > 0, mesh extent) have the last word */
    if (collider_geometry_validate(g, err) != 0) {
        error_prefix(err, path, ".");
        return -1;
    }

    collider_motion *m = &sc->motion;
    int has_position = parse_position(c, path, &m->start.position, err);
    if (has_position < 0 || parse_quat(c, path, &m->start.orientation, err) < 0)
        return -1;
    if (parse_motion(c, path, m, has_position, err) != 0)
        return -1;
    if (cJSON_GetObjectItemCaseSensitive(c, "orientation") &&
        m->kind == COLLIDER_MOTION_KEYFRAMES) {
        error_set(err,
                  "%s.orientation: not allowed with motion.keyframes (the keyframes give "
                  "the pose)",
                  path);
        return -1;
    }
    if (collider_pose_validate(&m->start, err) != 0) {
        error_prefix(err, path, ".");
        return -1;
    }
    return 0;
}

int scene_parse_colliders(const cJSON *root, const scene_parser *ps, scene *s, error_text *err)
{
    const cJSON *arr = cJSON_GetObjectItemCaseSensitive(root, "colliders");
    if (!arr)
        return 0;
    if (!cJSON_IsArray(arr)) {
        error_set(err, "colliders: must be an array (got %s)", json_type_name(arr));
        return -1;
    }
    int n = cJSON_GetArraySize(arr);
    if (n > SCENE_COLLIDERS_MAX) {
        error_set(err, "colliders: at most %d colliders (got %d)", SCENE_COLLIDERS_MAX, n);
        return -1;
    }
    if (n == 0)
        return 0;
    int meshes = 0;
    for (const cJSON *c = arr->child; c; c = c->next) {
        const cJSON *sh = cJSON_GetObjectItemCaseSensitive(c, "shape");
        if (cJSON_IsString(sh) && sh->valuestring && strcmp(sh->valuestring, "mesh") == 0)
            meshes++;
    }
    s->colliders = calloc((size_t)n, sizeof *s->colliders);
    /* sized up front: geometry.mesh points into this array, so it never moves */
    s->meshes = meshes ? calloc((size_t)meshes, sizeof *s->meshes) : NULL;
    if (!s->colliders || (meshes && !s->meshes)) {
        error_set(err, "colliders: out of memory");
        return -1;
    }
    int i = 0;
    for (const cJSON *c = arr->child; c; c = c->next, i++) {
        char p[64];
        json_path_index(p, sizeof p, "colliders", i);
        s->collider_count = i + 1; /* so scene_free releases a half-parsed one */
        if (parse_collider(ps, c, p, i, s, &s->colliders[i], err) != 0)
            return -1;
    }
    return 0;
}
