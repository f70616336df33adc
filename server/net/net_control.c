/*
 * net_control.c: the JSON control-message parser (see net_control_internal.h), a pure
 * function of the text and the server's configuration. Every refusal names
 * the field and says what it must be (PROTOCOL.md "Control messages"); the
 * first problem found is the one reported, in the order the protocol lists
 * the fields, so a client always hears the same error for the same message.
 *
 * Frames: the protocol's capsule and cylinder stand along the collider's z
 * axis, the collider module's along its y axis (a wheel's axle). Such
 * colliders carry a fixed quarter turn about x, applied to every pose here
 * and in net_requests.c, so the sim sees collider-module poses only.
 *
 * The field readers here are not base.h's json_get_*: their messages
 * ("x: missing, an integer in [...]") are the protocol's, which clients and
 * tests read, and name fields without a JSON path.
 */
#include "net/net_control_internal.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "terrad_proto.h"

typedef struct parser {
    const cJSON *msg;
    const net_control_context *ctx;
    net_control_error *err;
} parser;

static int fail(parser *r, int code, const char *fmt, ...) __attribute__((format(printf, 3, 4)));

static int fail(parser *r, int code, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(r->err->message, sizeof r->err->message, fmt, ap);
    va_end(ap);
    r->err->code = code;
    return -1;
}

static int is_integer(const cJSON *v)
{
    return cJSON_IsNumber(v) && isfinite(v->valuedouble) &&
           floor(v->valuedouble) == v->valuedouble && fabs(v->valuedouble) <= 9007199254740992.0;
}

/* 1 found, 0 absent (optional), -1 refused. */
static int get_int(parser *r, const char *name, int required, int64_t lo, int64_t hi, int64_t *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, name);
    if (!v && !required)
        return 0;
    if (!v || !is_integer(v) || v->valuedouble < (double)lo || v->valuedouble > (double)hi)
        return fail(r, TERRAD_E_BAD_VALUE, "%s: %s an integer in [%lld, %lld]", name,
                    v ? "must be" : "missing,", (long long)lo, (long long)hi);
    *out = (int64_t)v->valuedouble;
    return 1;
}

static int get_length(parser *r, const char *name, double *out)
{
    double max = r->ctx->limits->max_collider_extent_m;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, name);
    if (!v || !cJSON_IsNumber(v) || !isfinite(v->valuedouble) || !(v->valuedouble > 0) ||
        v->valuedouble > max)
        return fail(r, TERRAD_E_BAD_VALUE,
                    "%s: %s a number of metres > 0 and <= %g (max_collider_extent_m)", name,
                    v ? "must be" : "missing,", max);
    *out = v->valuedouble;
    return 0;
}

/* An array of exactly n finite numbers. */
static int get_numbers(parser *r, const cJSON *a, const char *name, int n, double *out)
{
    int ok = cJSON_IsArray(a) && cJSON_GetArraySize(a) == n;
    int i = 0;
    const cJSON *it;
    if (ok)
        cJSON_ArrayForEach(it, a)
        {
            if (!cJSON_IsNumber(it) || !isfinite(it->valuedouble)) {
                ok = 0;
                break;
            }
            out[i++] = it->valuedouble;
        }
    if (!ok)
        return fail(r, TERRAD_E_BAD_VALUE, "%s: must be an array of %d numbers", name, n);
    return 0;
}

/* An optional boolean: 0 when absent. */
static int get_bool(parser *r, const char *name, int absent, int *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, name);
    if (v && !cJSON_IsBool(v))
        return fail(r, TERRAD_E_BAD_VALUE, "%s: must be true or false", name);
    *out = v ? cJSON_IsTrue(v) : absent;
    return 0;
}

int net_control_quat_norm_ok(double w, double x, double y, double z)
{
    double n2 = w * w + x * x + y * y + z * z;
    return n2 >= 0.81 && n2 <= 1.21;
}

/* ---- hello ---- */

static int parse_hello(parser *r, net_control *out)
{
    if (get_int(r, "protocol", 1, INT32_MIN, INT32_MAX, &out->protocol) < 0)
        return -1;
    if (out->protocol != TERRAD_PROTO_VERSION) {
        r->err->fatal = 1;
        return fail(r, TERRAD_E_BAD_VERSION,
                    "protocol: this server speaks version %d only (got %lld)", TERRAD_PROTO_VERSION,
                    (long long)out->protocol);
    }
    const cJSON *token = cJSON_GetObjectItemCaseSensitive(r->msg, "token");
    if (token && (!cJSON_IsString(token) || strlen(token->valuestring) > NET_TOKEN_MAX_BYTES))
        return fail(r, TERRAD_E_BAD_VALUE, "token: must be a string of at most %d bytes",
                    NET_TOKEN_MAX_BYTES);
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(r->msg, "client");
    if (name && (!cJSON_IsString(name) || strlen(name->valuestring) > NET_CLIENT_NAME_MAX_BYTES))
        return fail(r, TERRAD_E_BAD_VALUE, "client: must be a string of at most %d bytes",
                    NET_CLIENT_NAME_MAX_BYTES);
    const cJSON *world = cJSON_GetObjectItemCaseSensitive(r->msg, "world");
    if (world && (!cJSON_IsString(world) || strlen(world->valuestring) > NET_CLIENT_NAME_MAX_BYTES))
        return fail(r, TERRAD_E_BAD_VALUE, "world: must be a string of at most %d bytes",
                    NET_CLIENT_NAME_MAX_BYTES);
    if (get_bool(r, "snapshot_base", 0, &out->snapshot_base) < 0)
        return -1;
    if (get_bool(r, "snapshot_slope", 0, &out->snapshot_slope) < 0)
        return -1;
    /* budget: bytes/s, 0 for none; the daemon's max_budget_bytes_per_s bounds it */
    double max = r->ctx->limits->max_budget_bytes_per_s;
    out->budget = -1;
    if (get_int(r, "budget", 0, 0, INT64_C(1000000000000), &out->budget) < 0)
        return -1;
    if (out->budget >= 0 && out->budget < NET_BUDGET_MIN && out->budget != 0)
        return fail(r, TERRAD_E_BAD_VALUE,
                    "budget: %lld bytes/s is under the smallest budget, %d (0: none)",
                    (long long)out->budget, NET_BUDGET_MIN);
    if (max > 0 && (out->budget == 0 || out->budget > max))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "budget: %lld bytes/s is over this server's max_budget_bytes_per_s (%.0f)%s",
                    (long long)out->budget, max, out->budget == 0 ? " (0 asks for none)" : "");
    out->has_token = token != NULL;
    snprintf(out->token, sizeof out->token, "%s", token ? token->valuestring : "");
    snprintf(out->client, sizeof out->client, "%s", name ? name->valuestring : "");
    snprintf(out->world, sizeof out->world, "%s", world ? world->valuestring : "");
    return 0;
}

/* ---- collider_create ---- */

static int material_known(const cJSON *materials, const char *name)
{
    const cJSON *it;
    cJSON_ArrayForEach(it, materials) if (strcmp(it->valuestring, name) == 0) return 1;
    return 0;
}

static void mesh_free(collider_mesh *m)
{
    if (m) {
        collider_mesh_free(m);
        free(m);
    }
}

/* vertices and indices of a mesh shape; NULL after an error. */
static collider_mesh *parse_mesh(parser *r)
{
    const net_limits *l = r->ctx->limits;
    const cJSON *va = cJSON_GetObjectItemCaseSensitive(r->msg, "vertices");
    const cJSON *ia = cJSON_GetObjectItemCaseSensitive(r->msg, "indices");
    if (!cJSON_IsArray(va) || cJSON_GetArraySize(va) % 3 != 0) {
        fail(r, TERRAD_E_BAD_VALUE,
             "vertices: must be an array of 3·n numbers [x0, y0, z0, x1, ...]");
        return NULL;
    }
    if (!cJSON_IsArray(ia) || cJSON_GetArraySize(ia) % 3 != 0) {
        fail(r, TERRAD_E_BAD_VALUE, "indices: must be an array of 3·m integers [a, b, c, ...]");
        return NULL;
    }
    int n = cJSON_GetArraySize(va) / 3, m = cJSON_GetArraySize(ia) / 3;
    if (n > l->max_mesh_vertices) {
        fail(r, TERRAD_E_TOO_LARGE, "vertices: %d vertices, over max_mesh_vertices (%d)", n,
             l->max_mesh_vertices);
        return NULL;
    }
    if (m > l->max_mesh_triangles) {
        fail(r, TERRAD_E_TOO_LARGE, "indices: %d triangles, over max_mesh_triangles (%d)", m,
             l->max_mesh_triangles);
        return NULL;
    }
    if (n < 3 || m < 1) {
        fail(r, TERRAD_E_BAD_VALUE,
             "mesh: needs at least 3 vertices and 1 triangle (got %d and %d)", n, m);
        return NULL;
    }
    collider_mesh *mesh = calloc(1, sizeof *mesh);
    if (mesh) {
        mesh->vertices = malloc((size_t)n * 3 * sizeof *mesh->vertices);
        mesh->indices = malloc((size_t)m * 3 * sizeof *mesh->indices);
    }
    if (!mesh || !mesh->vertices || !mesh->indices) {
        mesh_free(mesh);
        fail(r, TERRAD_E_INTERNAL, "out of memory for the mesh");
        return NULL;
    }
    mesh->vertex_count = n;
    mesh->triangle_count = m;
    double radius2 = 0;
    int i = 0;
    const cJSON *it;
    cJSON_ArrayForEach(it, va)
    {
        if (!cJSON_IsNumber(it) || !isfinite(it->valuedouble) ||
            fabs(it->valuedouble) > l->max_collider_extent_m) {
            fail(r, TERRAD_E_BAD_VALUE,
                 "vertices[%d]: must be a number with |v| <= %g m (max_collider_extent_m)", i,
                 l->max_collider_extent_m);
            mesh_free(mesh);
            return NULL;
        }
        mesh->vertices[i++] = (float)it->valuedouble;
    }
    for (int v = 0; v < n; v++) {
        const float *p = &mesh->vertices[3 * v];
        double d2 = (double)p[0] * p[0] + (double)p[1] * p[1] + (double)p[2] * p[2];
        if (d2 > radius2)
            radius2 = d2;
    }
    mesh->bounding_radius = sqrt(radius2);
    i = 0;
    cJSON_ArrayForEach(it, ia)
    {
        if (!is_integer(it) || it->valuedouble < 0 || it->valuedouble >= n) {
            fail(r, TERRAD_E_BAD_VALUE,
                 "indices[%d]: must be an integer in [0, %d) (the vertex count)", i, n);
            mesh_free(mesh);
            return NULL;
        }
        mesh->indices[i++] = (uint32_t)it->valuedouble;
    }
    if (!(mesh->bounding_radius > 0) || mesh->bounding_radius > l->max_collider_extent_m) {
        fail(r, TERRAD_E_BAD_VALUE,
             "vertices: must reach a distance > 0 and <= %g m from the origin (got %g)",
             l->max_collider_extent_m, mesh->bounding_radius);
        mesh_free(mesh);
        return NULL;
    }
    return mesh;
}

/* Optional "pose": 1 given, 0 absent, -1 refused. */
static int parse_pose(parser *r, int axis_z, collider_pose *out)
{
    const cJSON *pose = cJSON_GetObjectItemCaseSensitive(r->msg, "pose");
    if (!pose)
        return 0;
    if (!cJSON_IsObject(pose))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "pose: must be an object {\"p\": [x, y, z], \"q\": [qw, qx, qy, qz]}");
    double p[3], q[4];
    if (get_numbers(r, cJSON_GetObjectItemCaseSensitive(pose, "p"), "pose.p", 3, p) ||
        get_numbers(r, cJSON_GetObjectItemCaseSensitive(pose, "q"), "pose.q", 4, q))
        return -1;
    if (!net_control_quat_norm_ok(q[0], q[1], q[2], q[3]))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "pose.q: must be a unit quaternion (|q| within 0.9..1.1)");
    collider_pose cp = {{p[0], p[1], p[2]}, {q[0], q[1], q[2], q[3]}};
    error_text err;
    if (collider_pose_validate(&cp, &err))
        return fail(r, TERRAD_E_BAD_VALUE, "pose: %s", err.message);
    cp.orientation = collider_wire_orientation(cp.orientation, axis_z);
    *out = cp;
    return 1;
}

/* The shape and its dimensions into out->geometry (and out->mesh). */
static int parse_shape(parser *r, const char *sh, net_control *out)
{
    collider_geometry *g = &out->geometry;
    double max = r->ctx->limits->max_collider_extent_m;
    if (strcmp(sh, "sphere") == 0) {
        g->shape = COLLIDER_SPHERE;
        return get_length(r, "radius", &g->radius);
    }
    if (strcmp(sh, "box") == 0) {
        g->shape = COLLIDER_BOX;
        double e[3];
        const cJSON *a = cJSON_GetObjectItemCaseSensitive(r->msg, "half_extents");
        if (get_numbers(r, a, "half_extents", 3, e))
            return -1;
        for (int i = 0; i < 3; i++)
            if (!(e[i] > 0) || e[i] > max)
                return fail(r, TERRAD_E_BAD_VALUE,
                            "half_extents[%d]: must be > 0 and <= %g m (max_collider_extent_m)", i,
                            max);
        g->half_extents = (vec3d){e[0], e[1], e[2]};
        return 0;
    }
    if (strcmp(sh, "capsule") == 0 || strcmp(sh, "cylinder") == 0) {
        g->shape = sh[1] == 'a' ? COLLIDER_CAPSULE : COLLIDER_CYLINDER;
        out->axis_z = 1;
        if (get_length(r, "radius", &g->radius) || get_length(r, "half_length", &g->half_length))
            return -1;
        return 0;
    }
    if (strcmp(sh, "wheel") == 0) {
        g->shape = COLLIDER_CYLINDER; /* the module's cylinder axis is y: the axle */
        double width = 0.0;
        if (get_length(r, "radius", &g->radius) || get_length(r, "width", &width))
            return -1;
        g->half_length = width / 2;
        /* optional lugs (collider_grousers_from_json; their sizes against the rim are
         * collider_geometry_validate's, after this) */
        error_text err;
        if (collider_grousers_from_json(r->msg, "", &g->grousers, &err) < 0)
            return fail(r, TERRAD_E_BAD_VALUE, "%s", err.message);
        return 0;
    }
    if (strcmp(sh, "mesh") == 0) {
        g->shape = COLLIDER_MESH;
        out->mesh = parse_mesh(r);
        g->mesh = out->mesh;
        return out->mesh ? 0 : -1;
    }
    return fail(r, TERRAD_E_UNSUPPORTED_COLLIDER,
                "shape: \"%.64s\" is not one of sphere, box, capsule, cylinder, wheel, mesh", sh);
}

/* An optional "load_n": a load-driven collider (PROTOCOL.md "Load-driven
 * colliders"), only where the world's model computes soil forces. */
static int parse_load(parser *r, double *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, "load_n");
    *out = 0.0;
    if (!v)
        return 0;
    if (!r->ctx->loads)
        return fail(r, TERRAD_E_UNSUPPORTED_COLLIDER,
                    "load_n: this world's model computes no soil forces (load-driven colliders "
                    "need the bekker model)");
    if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble) || !(v->valuedouble > 0) ||
        v->valuedouble > NET_LOAD_MAX_N)
        return fail(r, TERRAD_E_BAD_VALUE, "load_n: must be a number of newtons > 0 and <= %g",
                    NET_LOAD_MAX_N);
    *out = v->valuedouble;
    return 0;
}

static int parse_collider_create(parser *r, net_control *out)
{
    const cJSON *shape = cJSON_GetObjectItemCaseSensitive(r->msg, "shape");
    if (!cJSON_IsString(shape))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "shape: %s a string (sphere, box, capsule, cylinder, wheel or mesh)",
                    shape ? "must be" : "missing,");
    const cJSON *material = cJSON_GetObjectItemCaseSensitive(r->msg, "material");
    if (material && !cJSON_IsString(material))
        return fail(r, TERRAD_E_BAD_VALUE, "material: must be a string");
    const char *mat = material ? material->valuestring : "default";
    if (strlen(mat) >= sizeof out->material || !material_known(r->ctx->materials, mat))
        return fail(r, TERRAD_E_UNSUPPORTED_COLLIDER,
                    "material: \"%.64s\" is not one of world.materials", mat);
    snprintf(out->material, sizeof out->material, "%s", mat);
    if (get_bool(r, "feedback", 1, &out->feedback) || parse_load(r, &out->load_n) ||
        get_bool(r, "forces_height", 0, &out->forces_height) ||
        parse_shape(r, shape->valuestring, out))
        return -1;
    if (cJSON_GetObjectItemCaseSensitive(r->msg, "grousers") && out->geometry.grousers.count == 0)
        return fail(r, TERRAD_E_BAD_VALUE,
                    "grousers: only a wheel carries grousers (shape \"wheel\", its axle the "
                    "collider's y axis)");
    error_text err;
    if (collider_geometry_validate(&out->geometry, &err))
        return fail(r, TERRAD_E_BAD_VALUE, "%s", err.message);
    memset(&out->pose, 0, sizeof out->pose); /* all-zero orientation: no pose yet */
    return parse_pose(r, out->axis_z, &out->pose) < 0 ? -1 : 0;
}

/* ---- subscriptions ---- */

static int parse_subscribe(parser *r, net_control *out)
{
    int64_t x, y, w, h;
    if (get_int(r, "x", 1, INT32_MIN, INT32_MAX, &x) < 0 ||
        get_int(r, "y", 1, INT32_MIN, INT32_MAX, &y) < 0 ||
        get_int(r, "w", 1, 1, INT32_MAX, &w) < 0 || get_int(r, "h", 1, 1, INT32_MAX, &h) < 0 ||
        get_bool(r, "colliders", 0, &out->colliders) ||
        get_bool(r, "grousers", 0, &out->grousers) ||
        get_bool(r, "footprints", 0, &out->footprints))
        return -1;
    if (out->grousers && !out->colliders)
        return fail(r, TERRAD_E_BAD_VALUE,
                    "grousers: asks for the wheels' grousers in COLLIDERS frames, so it needs "
                    "\"colliders\": true");
    int ww = r->ctx->world_width, wh = r->ctx->world_height;
    if (x < 0 || y < 0 || x + w > ww || y + h > wh)
        return fail(r, TERRAD_E_OUTSIDE_WORLD,
                    "rectangle x=%lld y=%lld w=%lld h=%lld is not inside the world (%d x %d cells)",
                    (long long)x, (long long)y, (long long)w, (long long)h, ww, wh);
    out->rect = (world_rect){(int)x, (int)y, (int)w, (int)h};
    return 0;
}

/* "id" of a collider_delete, unsubscribe or (optional) resync. */
static int parse_id(parser *r, int required, net_control *out)
{
    int64_t id = 0;
    int got = get_int(r, "id", required, 0, UINT32_MAX, &id);
    if (got < 0)
        return -1;
    out->id = (uint32_t)id;
    out->has_id = got;
    return 0;
}

/* resync: "id" (required with "tiles"), and "tiles", an array of 1 to
 * max_resync_tiles [tile x, tile y] pairs of integers >= 0 inside the world
 * (PROTOCOL.md "resync"). Bounding them here keeps tile x * tile_size an int
 * for net_desync.c; whether each tile meets the subscription is the client's
 * state (net_requests.c). */
static int parse_resync(parser *r, net_control *out)
{
    const cJSON *tiles = cJSON_GetObjectItemCaseSensitive(r->msg, "tiles");
    if (parse_id(r, tiles != NULL, out) != 0)
        return -1;
    if (!tiles)
        return 0;
    int max = r->ctx->limits->max_resync_tiles, n = cJSON_GetArraySize(tiles);
    if (!cJSON_IsArray(tiles) || n == 0)
        return fail(r, TERRAD_E_BAD_VALUE, "tiles: must be a non-empty array of [x, y] tiles");
    if (n > max)
        return fail(r, TERRAD_E_TOO_LARGE, "tiles: %d tiles, more than max_resync_tiles (%d)", n,
                    max);
    out->tiles = malloc((size_t)n * 2 * sizeof *out->tiles);
    if (!out->tiles)
        return fail(r, TERRAD_E_INTERNAL, "out of memory");
    int ts = r->ctx->tile_size > 0 ? r->ctx->tile_size : 1;
    int64_t tiles_x = ((int64_t)r->ctx->world_width + ts - 1) / ts,
            tiles_y = ((int64_t)r->ctx->world_height + ts - 1) / ts;
    int i = 0;
    for (const cJSON *t = tiles->child; t; t = t->next, i++) {
        const cJSON *x = cJSON_GetArrayItem(t, 0), *y = cJSON_GetArrayItem(t, 1);
        if (!cJSON_IsArray(t) || cJSON_GetArraySize(t) != 2 || !is_integer(x) || !is_integer(y) ||
            x->valuedouble < 0 || y->valuedouble < 0)
            return fail(r, TERRAD_E_BAD_VALUE,
                        "tiles[%d]: must be [x, y], two integers >= 0 (tile coordinates)", i);
        if (x->valuedouble >= tiles_x || y->valuedouble >= tiles_y)
            return fail(r, TERRAD_E_OUTSIDE_WORLD,
                        "tiles[%d]: tile (%.0f, %.0f) is outside the world (%lld x %lld tiles of "
                        "%d cells)",
                        i, x->valuedouble, y->valuedouble, (long long)tiles_x, (long long)tiles_y,
                        ts);
        out->tiles[2 * i] = (int32_t)x->valuedouble;
        out->tiles[2 * i + 1] = (int32_t)y->valuedouble;
    }
    out->tile_count = n;
    return 0;
}

/* collider_delete's optional "any_owner": an admin deleting another client's collider. */
static int parse_any_owner(parser *r, net_control *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, "any_owner");
    if (v && !cJSON_IsBool(v))
        return fail(r, TERRAD_E_BAD_VALUE, "any_owner: must be true or false");
    out->any_owner = cJSON_IsTrue(v);
    return 0;
}

/* ---- the message ---- */

static const struct {
    const char *name;
    net_control_kind kind;
} control_types[] = {
    {"hello", NET_CONTROL_HELLO},
    {"collider_create", NET_CONTROL_COLLIDER_CREATE},
    {"collider_delete", NET_CONTROL_COLLIDER_DELETE},
    {"subscribe", NET_CONTROL_SUBSCRIBE},
    {"unsubscribe", NET_CONTROL_UNSUBSCRIBE},
    {"resync", NET_CONTROL_RESYNC},
    {"edit", NET_CONTROL_EDIT},
    {"subscribe_events", NET_CONTROL_SUBSCRIBE_EVENTS},
    {"seen", NET_CONTROL_SEEN},
    {"focus", NET_CONTROL_FOCUS},
    {"spectate", NET_CONTROL_SPECTATE},
    {"spectate_step", NET_CONTROL_SPECTATE_STEP},
    {"spectate_stop", NET_CONTROL_SPECTATE_STOP},
};

/* spectate: a window (as subscribe's), "from_tick", and "speed" (1..8,
 * default 1) or "step": true (PROTOCOL.md "Spectate"). */
static int parse_spectate(parser *r, net_control *out)
{
    int64_t from = 0, speed = 1;
    if (parse_subscribe(r, out) < 0 ||
        get_int(r, "from_tick", 1, 0, INT64_C(9007199254740992), &from) < 0 ||
        get_int(r, "speed", 0, 1, 8, &speed) < 0 || get_bool(r, "step", 0, &out->stepping))
        return -1;
    out->from_tick = (uint64_t)from;
    out->speed = (int)speed;
    return 0;
}

/* focus: "x" and "y", cells inside the world, both or neither (neither: cleared). */
static int parse_focus(parser *r, net_control *out)
{
    const cJSON *x = cJSON_GetObjectItemCaseSensitive(r->msg, "x");
    const cJSON *y = cJSON_GetObjectItemCaseSensitive(r->msg, "y");
    if (!x && !y)
        return 0;
    const char *bad = !cJSON_IsNumber(x) || !isfinite(x->valuedouble) || x->valuedouble < 0 ||
                              x->valuedouble > r->ctx->world_width
                          ? "x"
                      : !cJSON_IsNumber(y) || !isfinite(y->valuedouble) || y->valuedouble < 0 ||
                              y->valuedouble > r->ctx->world_height
                          ? "y"
                          : NULL;
    if (bad)
        return fail(r, TERRAD_E_BAD_VALUE,
                    "%s: must be a number of cells in [0, %d] (x and y both, or neither to "
                    "clear the focus)",
                    bad, bad[0] == 'x' ? r->ctx->world_width : r->ctx->world_height);
    out->has_focus = 1;
    out->focus_x = x->valuedouble;
    out->focus_y = y->valuedouble;
    return 0;
}

/* subscribe_events: "events", an array of known event names (empty: none). */
static int parse_events(parser *r, net_control *out)
{
    static const char *const names[] = {NET_EVENT_NAMES};
    const cJSON *events = cJSON_GetObjectItemCaseSensitive(r->msg, "events");
    if (!cJSON_IsArray(events))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "events: required, an array of event names (world_created, world_deleted, "
                    "world_state)");
    int i = 0;
    for (const cJSON *e = events->child; e; e = e->next, i++) {
        int known = -1;
        for (int k = 0; k < NET_EVENT_COUNT && cJSON_IsString(e); k++)
            if (strcmp(e->valuestring, names[k]) == 0)
                known = k;
        if (known < 0)
            return fail(r, TERRAD_E_BAD_VALUE,
                        "events[%d]: not an event name (world_created, world_deleted, world_state)",
                        i);
        out->events |= 1u << known;
    }
    return 0;
}

/* An edit's fields (hub_edit_parse, shared with POST /v1/worlds/{name}/edits). */
static int parse_edit(parser *r, net_control *out)
{
    hub_edit_error werr;
    world_edit e;
    if (hub_edit_parse(r->msg, r->ctx->world_width, r->ctx->world_height,
                       r->ctx->limits->max_edit_cells, &e, &werr) != 0)
        return fail(r, werr.code, "%s", werr.message);
    out->edit = malloc(sizeof *out->edit);
    if (!out->edit) {
        world_edit_free(&e);
        return fail(r, TERRAD_E_INTERNAL, "out of memory");
    }
    *out->edit = e;
    return 0;
}

/* The message's "type" and "ref" (0), or -1 with the message refused. */
static int parse_envelope(parser *r, const cJSON *msg, net_control *out, const char **type_name)
{
    const cJSON *type = cJSON_IsObject(msg) ? cJSON_GetObjectItemCaseSensitive(msg, "type") : NULL;
    if (!cJSON_IsString(type))
        return fail(r, TERRAD_E_BAD_JSON,
                    msg ? "not a JSON object with a string \"type\"" : "malformed JSON");
    *type_name = type->valuestring;
    for (size_t i = 0; i < sizeof control_types / sizeof control_types[0]; i++)
        if (strcmp(type->valuestring, control_types[i].name) == 0)
            out->kind = control_types[i].kind;
    const cJSON *ref = cJSON_GetObjectItemCaseSensitive(msg, "ref");
    if (ref && !((cJSON_IsString(ref) && strlen(ref->valuestring) <= NET_REF_MAX_BYTES) ||
                 is_integer(ref)))
        return fail(r, TERRAD_E_BAD_VALUE,
                    "ref: must be a string of at most %d bytes or an integer", NET_REF_MAX_BYTES);
    if (ref && !(out->ref = cJSON_Duplicate(ref, 1)))
        return fail(r, TERRAD_E_INTERNAL, "out of memory");
    return 0;
}

int net_control_parse(const char *text, size_t len, const net_control_context *ctx,
                      net_control *out, net_control_error *err)
{
    memset(out, 0, sizeof *out);
    memset(err, 0, sizeof *err);
    cJSON *msg = cJSON_ParseWithLengthOpts(text, len, NULL, 0);
    parser r = {.msg = msg, .ctx = ctx, .err = err};
    const char *type = NULL;
    int rc = parse_envelope(&r, msg, out, &type);
    if (rc == 0) {
        err->field = 1;
        switch (out->kind) {
        case NET_CONTROL_NONE:
            err->field = 0;
            rc = fail(&r, TERRAD_E_UNKNOWN_TYPE, "type: \"%.64s\" is not a request", type);
            break;
        case NET_CONTROL_HELLO:
            rc = parse_hello(&r, out);
            break;
        case NET_CONTROL_COLLIDER_CREATE:
            rc = parse_collider_create(&r, out);
            break;
        case NET_CONTROL_COLLIDER_DELETE:
            rc = parse_id(&r, 1, out);
            if (rc == 0)
                rc = parse_any_owner(&r, out);
            break;
        case NET_CONTROL_UNSUBSCRIBE:
            rc = parse_id(&r, 1, out);
            break;
        case NET_CONTROL_SUBSCRIBE:
            rc = parse_subscribe(&r, out);
            break;
        case NET_CONTROL_RESYNC:
            rc = parse_resync(&r, out);
            break;
        case NET_CONTROL_EDIT:
            rc = parse_edit(&r, out);
            break;
        case NET_CONTROL_SUBSCRIBE_EVENTS:
            rc = parse_events(&r, out);
            break;
        case NET_CONTROL_FOCUS:
            rc = parse_focus(&r, out);
            break;
        case NET_CONTROL_SPECTATE:
            rc = parse_spectate(&r, out);
            break;
        case NET_CONTROL_SPECTATE_STEP:
            rc = get_int(&r, "ticks", 1, 1, r.ctx->limits->max_step_ticks, &out->step_ticks) < 0
                     ? -1
                     : 0;
            break;
        case NET_CONTROL_SPECTATE_STOP:
            break;
        case NET_CONTROL_SEEN: { /* "tick": an integer a double holds exactly */
            int64_t tick = 0;
            rc = get_int(&r, "tick", 1, 0, INT64_C(9007199254740992), &tick) < 0 ? -1 : 0;
            out->seen_tick = (uint64_t)tick;
            break;
        }
        }
    }
    cJSON_Delete(msg);
    if (rc == 0)
        err->field = 0;
    return rc;
}

void net_control_free(net_control *r)
{
    cJSON_Delete(r->ref);
    r->ref = NULL;
    mesh_free(r->mesh);
    r->mesh = NULL;
    free(r->tiles);
    r->tiles = NULL;
    r->tile_count = 0;
    r->geometry.mesh = NULL;
    if (r->edit) {
        world_edit_free(r->edit);
        free(r->edit);
        r->edit = NULL;
    }
}
