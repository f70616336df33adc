/*
 * net_requests.c: what a client may ask for, checked field by field before
 * anything reaches the sim (PROTOCOL.md "Control messages", "POSE_BATCH").
 *
 * Every request is either refused with one error to its sender (and a
 * metric), or turned into a hub command / hub pose and answered at once.
 * The sim never sees a bad value: shapes, sizes, meshes, poses, ownership,
 * rectangles and limits are all settled here.
 *
 * Frames: the protocol's capsule and cylinder stand along the collider's z
 * axis, the collider module's along its y axis (a wheel's axle). Such
 * colliders carry a fixed quarter turn about x, applied to every pose here,
 * so the sim sees collider-module poses only.
 */
#include "net/net_requests.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"
#include "terrad_proto.h"

#define NET_REF_MAX_BYTES 64
#define NET_TOKEN_MAX_BYTES 256
#define NET_CLIENT_NAME_MAX_BYTES 64

/* ---- replies ---- */

static cJSON *reply(const char *type, const cJSON *ref)
{
    cJSON *r = cJSON_CreateObject();
    cJSON_AddStringToObject(r, "type", type);
    cJSON_AddItemToObject(r, "ref", net_ref_copy(ref));
    return r;
}

/* The ref as JSON text for hub_command.ref ("" if none or too long). */
static void ref_text(const cJSON *ref, char *out, size_t cap)
{
    out[0] = 0;
    if (!ref)
        return;
    char *t = cJSON_PrintUnformatted(ref);
    if (t && strlen(t) < cap)
        memcpy(out, t, strlen(t) + 1);
    free(t);
}

/* ---- field readers: each sends bad_value naming the field and returns -1 ---- */

typedef struct req {
    net_client *c;
    const cJSON *msg, *ref;
} req;

static int is_integer(const cJSON *v)
{
    return cJSON_IsNumber(v) && isfinite(v->valuedouble) &&
           floor(v->valuedouble) == v->valuedouble && fabs(v->valuedouble) <= 9007199254740992.0;
}

/* 1 found, 0 absent (optional), -1 refused. */
static int get_int(const req *r, const char *name, int required, int64_t lo, int64_t hi,
                   int64_t *out)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, name);
    if (!v && !required)
        return 0;
    if (!v || !is_integer(v) || v->valuedouble < (double)lo || v->valuedouble > (double)hi) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "%s: %s an integer in [%lld, %lld]",
                  name, v ? "must be" : "missing,", (long long)lo, (long long)hi);
        return -1;
    }
    *out = (int64_t)v->valuedouble;
    return 1;
}

static int get_length(const req *r, const char *name, double *out)
{
    double max = r->c->srv->cfg.limits.max_collider_extent_m;
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(r->msg, name);
    if (!v || !cJSON_IsNumber(v) || !isfinite(v->valuedouble) || !(v->valuedouble > 0) ||
        v->valuedouble > max) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "%s: %s a number of metres > 0 and <= %g (max_collider_extent_m)", name,
                  v ? "must be" : "missing,", max);
        return -1;
    }
    *out = v->valuedouble;
    return 0;
}

/* An array of exactly n finite numbers. */
static int get_numbers(const req *r, const cJSON *a, const char *name, int n, double *out)
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
    if (!ok) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "%s: must be an array of %d numbers",
                  name, n);
        return -1;
    }
    return 0;
}

/* ---- poses ---- */

/* Orientation as the collider module wants it (see the top of the file). */
static quatd module_orientation(quatd q, int axis_z)
{
    q = quat_normalize(q);
    if (axis_z) {
        const double h = 0.70710678118654752440; /* a quarter turn about x: y -> z */
        q = quat_normalize(quat_multiply(q, (quatd){h, h, 0, 0}));
    }
    return q;
}

static int quat_norm_ok(double w, double x, double y, double z)
{
    double n2 = w * w + x * x + y * y + z * z;
    return n2 >= 0.81 && n2 <= 1.21;
}

/* ---- hello ---- */

static int token_equal(const char *a, const char *b)
{
    size_t na = strlen(a), nb = strlen(b);
    unsigned char diff = (unsigned char)(na != nb);
    for (size_t i = 0; i < na; i++)
        diff |= (unsigned char)(a[i] ^ b[i % (nb ? nb : 1)]);
    return diff == 0;
}

static cJSON *world_message(net_state *s, const net_client *c)
{
    const net_world_info *w = &s->cfg.world;
    const net_limits *l = &s->cfg.limits;
    cJSON *m = cJSON_CreateObject();
    cJSON_AddStringToObject(m, "type", "world");
    cJSON_AddNumberToObject(m, "protocol", TERRAD_PROTO_VERSION);
    cJSON_AddStringToObject(m, "server", s->server_name);
    cJSON_AddNumberToObject(m, "client_id", c->id);
    cJSON_AddNumberToObject(m, "width", w->width);
    cJSON_AddNumberToObject(m, "height", w->height);
    cJSON_AddNumberToObject(m, "cell_size_m", w->cell_size_m);
    cJSON_AddNumberToObject(m, "units_per_m", w->units_per_m);
    cJSON *range = cJSON_AddArrayToObject(m, "height_range");
    cJSON_AddItemToArray(range, cJSON_CreateNumber(w->height_min));
    cJSON_AddItemToArray(range, cJSON_CreateNumber(w->height_max));
    cJSON_AddNumberToObject(m, "tick_hz", w->tick_hz);
    cJSON_AddNumberToObject(m, "tick", (double)s->tick);
    cJSON_AddNumberToObject(m, "tile_size", w->tile_size);
    cJSON_AddItemToObject(m, "models", cJSON_Duplicate(s->models, 1));
    cJSON_AddItemToObject(m, "materials", cJSON_Duplicate(s->materials, 1));
    static const char *const shapes[] = {"sphere", "box", "capsule", "cylinder", "wheel", "mesh"};
    cJSON_AddItemToObject(m, "shapes", cJSON_CreateStringArray(shapes, 6));
    cJSON *lim = cJSON_AddObjectToObject(m, "limits");
    cJSON_AddNumberToObject(lim, "max_message_bytes", (double)l->max_message_bytes);
    cJSON_AddNumberToObject(lim, "max_colliders", l->max_colliders);
    cJSON_AddNumberToObject(lim, "max_poses_per_batch", l->max_poses_per_batch);
    cJSON_AddNumberToObject(lim, "max_subscriptions", l->max_subscriptions);
    cJSON_AddNumberToObject(lim, "max_subscribed_cells", (double)l->max_subscribed_cells);
    cJSON_AddNumberToObject(lim, "max_messages_per_s", l->max_messages_per_s);
    cJSON_AddNumberToObject(lim, "messages_burst", l->messages_burst);
    cJSON_AddNumberToObject(lim, "max_mesh_vertices", l->max_mesh_vertices);
    cJSON_AddNumberToObject(lim, "max_mesh_triangles", l->max_mesh_triangles);
    cJSON_AddNumberToObject(lim, "max_collider_extent_m", l->max_collider_extent_m);
    cJSON_AddNumberToObject(lim, "max_pending_bytes", (double)l->max_pending_bytes);
    cJSON_AddNumberToObject(lim, "hello_timeout_s", l->hello_timeout_s);
    return m;
}

static void handle_hello(const req *r)
{
    net_client *c = r->c;
    net_state *s = c->srv;
    if (c->ready) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "hello: already received");
        return;
    }
    int64_t protocol;
    if (get_int(r, "protocol", 1, INT32_MIN, INT32_MAX, &protocol) < 0)
        return;
    if (protocol != TERRAD_PROTO_VERSION) {
        net_error(c, TERRAD_E_BAD_VERSION, r->ref, -1, 1,
                  "protocol: this server speaks version %d only (got %lld)", TERRAD_PROTO_VERSION,
                  (long long)protocol);
        net_close_after_flush(c, 4000 + TERRAD_E_BAD_VERSION, "bad protocol version");
        return;
    }
    const cJSON *token = cJSON_GetObjectItemCaseSensitive(r->msg, "token");
    if (token && (!cJSON_IsString(token) || strlen(token->valuestring) > NET_TOKEN_MAX_BYTES)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "token: must be a string of at most %d bytes", NET_TOKEN_MAX_BYTES);
        return;
    }
    const cJSON *name = cJSON_GetObjectItemCaseSensitive(r->msg, "client");
    if (name && (!cJSON_IsString(name) || strlen(name->valuestring) > NET_CLIENT_NAME_MAX_BYTES)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "client: must be a string of at most %d bytes", NET_CLIENT_NAME_MAX_BYTES);
        return;
    }
    if (s->token && !token_equal(token ? token->valuestring : "", s->token)) {
        net_error(c, TERRAD_E_UNAUTHORIZED, r->ref, -1, 1, "token: wrong token");
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "unauthorized");
        return;
    }
    c->ready = 1;
    lws_set_timer_usecs(c->wsi, LWS_SET_TIMER_USEC_CANCEL);
    snprintf(c->name, sizeof c->name, "%s", name ? name->valuestring : "");
    for (char *p = c->name; *p; p++) /* for log lines */
        if ((unsigned char)*p < 0x20 || *p == 0x7f)
            *p = '?';
    cJSON *w = world_message(s, c);
    cJSON_AddItemToObject(w, "ref", net_ref_copy(r->ref));
    net_send_json(c, w);
    hub_command cmd = {.kind = HUB_CLIENT_JOINED, .client = c->id};
    ref_text(r->ref, cmd.ref, sizeof cmd.ref);
    net_push_must(s, &cmd);
    log_info("net: client %u (%s) said hello as \"%s\"", c->id, c->peer, c->name);
}

/* ---- collider_create ---- */

static int material_known(net_state *s, const char *name)
{
    const cJSON *it;
    cJSON_ArrayForEach(it, s->materials) if (strcmp(it->valuestring, name) == 0) return 1;
    return 0;
}

static void mesh_free(collider_mesh *m)
{
    if (m) {
        collider_mesh_free(m);
        free(m);
    }
}

/* vertices and indices of a mesh shape; NULL after an error was sent. */
static collider_mesh *parse_mesh(const req *r)
{
    net_client *c = r->c;
    const net_limits *l = &c->srv->cfg.limits;
    const cJSON *va = cJSON_GetObjectItemCaseSensitive(r->msg, "vertices");
    const cJSON *ia = cJSON_GetObjectItemCaseSensitive(r->msg, "indices");
    if (!cJSON_IsArray(va) || cJSON_GetArraySize(va) % 3 != 0) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "vertices: must be an array of 3·n numbers [x0, y0, z0, x1, ...]");
        return NULL;
    }
    if (!cJSON_IsArray(ia) || cJSON_GetArraySize(ia) % 3 != 0) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "indices: must be an array of 3·m integers [a, b, c, ...]");
        return NULL;
    }
    int n = cJSON_GetArraySize(va) / 3, m = cJSON_GetArraySize(ia) / 3;
    if (n > l->max_mesh_vertices) {
        net_error(c, TERRAD_E_TOO_LARGE, r->ref, -1, 0,
                  "vertices: %d vertices, over max_mesh_vertices (%d)", n, l->max_mesh_vertices);
        return NULL;
    }
    if (m > l->max_mesh_triangles) {
        net_error(c, TERRAD_E_TOO_LARGE, r->ref, -1, 0,
                  "indices: %d triangles, over max_mesh_triangles (%d)", m, l->max_mesh_triangles);
        return NULL;
    }
    if (n < 3 || m < 1) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
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
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0, "out of memory for the mesh");
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
            net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
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
            net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                      "indices[%d]: must be an integer in [0, %d) (the vertex count)", i, n);
            mesh_free(mesh);
            return NULL;
        }
        mesh->indices[i++] = (uint32_t)it->valuedouble;
    }
    if (!(mesh->bounding_radius > 0) || mesh->bounding_radius > l->max_collider_extent_m) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "vertices: must reach a distance > 0 and <= %g m from the origin (got %g)",
                  l->max_collider_extent_m, mesh->bounding_radius);
        mesh_free(mesh);
        return NULL;
    }
    return mesh;
}

/* Optional "pose": 1 given, 0 absent, -1 refused. */
static int parse_pose(const req *r, int axis_z, collider_pose *out)
{
    const cJSON *pose = cJSON_GetObjectItemCaseSensitive(r->msg, "pose");
    if (!pose)
        return 0;
    if (!cJSON_IsObject(pose)) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "pose: must be an object {\"p\": [x, y, z], \"q\": [qw, qx, qy, qz]}");
        return -1;
    }
    double p[3], q[4];
    if (get_numbers(r, cJSON_GetObjectItemCaseSensitive(pose, "p"), "pose.p", 3, p) ||
        get_numbers(r, cJSON_GetObjectItemCaseSensitive(pose, "q"), "pose.q", 4, q))
        return -1;
    if (!quat_norm_ok(q[0], q[1], q[2], q[3])) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "pose.q: must be a unit quaternion (|q| within 0.9..1.1)");
        return -1;
    }
    collider_pose cp = {{p[0], p[1], p[2]}, {q[0], q[1], q[2], q[3]}};
    error_text err;
    if (collider_pose_validate(&cp, &err)) {
        net_error(r->c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "pose: %s", err.message);
        return -1;
    }
    cp.orientation = module_orientation(cp.orientation, axis_z);
    *out = cp;
    return 1;
}

static void handle_collider_create(const req *r)
{
    net_client *c = r->c;
    net_state *s = c->srv;
    if (c->collider_count >= s->cfg.limits.max_colliders) {
        net_error(c, TERRAD_E_LIMIT_COLLIDERS, r->ref, -1, 0,
                  "this client already has max_colliders (%d) colliders",
                  s->cfg.limits.max_colliders);
        return;
    }
    const cJSON *shape = cJSON_GetObjectItemCaseSensitive(r->msg, "shape");
    if (!cJSON_IsString(shape)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                  "shape: %s a string (sphere, box, capsule, cylinder, wheel or mesh)",
                  shape ? "must be" : "missing,");
        return;
    }
    const cJSON *material = cJSON_GetObjectItemCaseSensitive(r->msg, "material");
    if (material && !cJSON_IsString(material)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "material: must be a string");
        return;
    }
    const char *mat = material ? material->valuestring : "default";
    if (strlen(mat) >= sizeof(((hub_command *)0)->material) || !material_known(s, mat)) {
        net_error(c, TERRAD_E_UNSUPPORTED_COLLIDER, r->ref, -1, 0,
                  "material: \"%.64s\" is not one of world.materials", mat);
        return;
    }
    const cJSON *feedback = cJSON_GetObjectItemCaseSensitive(r->msg, "feedback");
    if (feedback && !cJSON_IsBool(feedback)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "feedback: must be true or false");
        return;
    }

    collider_geometry g;
    memset(&g, 0, sizeof g);
    collider_mesh *mesh = NULL;
    int axis_z = 0;
    const char *sh = shape->valuestring;
    if (strcmp(sh, "sphere") == 0) {
        g.shape = COLLIDER_SPHERE;
        if (get_length(r, "radius", &g.radius))
            return;
    } else if (strcmp(sh, "box") == 0) {
        g.shape = COLLIDER_BOX;
        double e[3];
        const cJSON *a = cJSON_GetObjectItemCaseSensitive(r->msg, "half_extents");
        if (get_numbers(r, a, "half_extents", 3, e))
            return;
        for (int i = 0; i < 3; i++)
            if (!(e[i] > 0) || e[i] > s->cfg.limits.max_collider_extent_m) {
                net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0,
                          "half_extents[%d]: must be > 0 and <= %g m (max_collider_extent_m)", i,
                          s->cfg.limits.max_collider_extent_m);
                return;
            }
        g.half_extents = (vec3d){e[0], e[1], e[2]};
    } else if (strcmp(sh, "capsule") == 0 || strcmp(sh, "cylinder") == 0) {
        g.shape = sh[1] == 'a' ? COLLIDER_CAPSULE : COLLIDER_CYLINDER;
        axis_z = 1;
        if (get_length(r, "radius", &g.radius) || get_length(r, "half_length", &g.half_length))
            return;
    } else if (strcmp(sh, "wheel") == 0) {
        g.shape = COLLIDER_CYLINDER; /* the module's cylinder axis is y: the axle */
        double width;
        if (get_length(r, "radius", &g.radius) || get_length(r, "width", &width))
            return;
        g.half_length = width / 2;
    } else if (strcmp(sh, "mesh") == 0) {
        g.shape = COLLIDER_MESH;
        mesh = parse_mesh(r);
        if (!mesh)
            return;
        g.mesh = mesh;
    } else {
        net_error(c, TERRAD_E_UNSUPPORTED_COLLIDER, r->ref, -1, 0,
                  "shape: \"%.64s\" is not one of sphere, box, capsule, cylinder, wheel, mesh", sh);
        return;
    }
    error_text err;
    if (collider_geometry_validate(&g, &err)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "%s", err.message);
        mesh_free(mesh);
        return;
    }
    collider_pose pose;
    memset(&pose, 0, sizeof pose); /* all-zero orientation: no pose yet */
    if (parse_pose(r, axis_z, &pose) < 0) {
        mesh_free(mesh);
        return;
    }

    uint32_t id = s->next_collider_id;
    if (id == 0 || net_collider_insert(s, id, c->id, axis_z) != 0) {
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0,
                  id == 0 ? "collider ids exhausted" : "out of memory");
        mesh_free(mesh);
        return;
    }
    hub_command cmd;
    memset(&cmd, 0, sizeof cmd);
    cmd.kind = HUB_COLLIDER_CREATE;
    cmd.client = c->id;
    cmd.collider = id;
    cmd.geometry = g;
    cmd.mesh = mesh;
    cmd.pose = pose;
    snprintf(cmd.material, sizeof cmd.material, "%s", mat);
    cmd.feedback = feedback ? cJSON_IsTrue(feedback) : 1;
    ref_text(r->ref, cmd.ref, sizeof cmd.ref);
    int grown = array_grow((void **)&c->colliders, &c->collider_capacity,
                           (int64_t)c->collider_count + 1, sizeof *c->colliders) == 0;
    if (!grown || net_push_refusable(s, &cmd) != 0) {
        net_collider_remove(s, id);
        mesh_free(mesh);
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0,
                  grown ? "server busy: the simulation's command queue is full, try again"
                        : "out of memory");
        return;
    }
    c->colliders[c->collider_count++] = id;
    s->next_collider_id = id + 1;
    cJSON *rep = reply("collider_created", r->ref);
    cJSON_AddNumberToObject(rep, "id", id);
    net_send_json(c, rep);
}

/* ---- collider_delete ---- */

/* The slot of one of c's colliders, or NULL after an error was sent. */
static net_collider_slot *owned(net_client *c, uint32_t id, const cJSON *ref)
{
    net_collider_slot *slot = net_collider_find(c->srv, id);
    if (!slot) {
        net_error(c, TERRAD_E_UNKNOWN_COLLIDER, ref, id, 0, "collider %u does not exist", id);
        return NULL;
    }
    if (slot->owner != c->id) {
        net_error(c, TERRAD_E_NOT_OWNER, ref, id, 0, "collider %u belongs to another client", id);
        return NULL;
    }
    return slot;
}

static void handle_collider_delete(const req *r)
{
    net_client *c = r->c;
    int64_t id;
    if (get_int(r, "id", 1, 0, UINT32_MAX, &id) < 0 || !owned(c, (uint32_t)id, r->ref))
        return;
    hub_command cmd = {.kind = HUB_COLLIDER_DELETE, .client = c->id, .collider = (uint32_t)id};
    ref_text(r->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(c->srv, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, r->ref, id, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    net_collider_remove(c->srv, (uint32_t)id);
    hub_forget_pose(c->srv->hub, (uint32_t)id);
    for (int i = 0; i < c->collider_count; i++)
        if (c->colliders[i] == (uint32_t)id) {
            c->colliders[i] = c->colliders[--c->collider_count];
            break;
        }
    cJSON *rep = reply("collider_deleted", r->ref);
    cJSON_AddNumberToObject(rep, "id", (double)id);
    net_send_json(c, rep);
}

/* ---- subscriptions ---- */

static int sub_index(const net_client *c, uint32_t id)
{
    for (int i = 0; i < c->sub_count; i++)
        if (c->subs[i].id == id)
            return i;
    return -1;
}

static void handle_subscribe(const req *r)
{
    net_client *c = r->c;
    net_state *s = c->srv;
    const net_limits *l = &s->cfg.limits;
    int64_t x, y, w, h;
    if (get_int(r, "x", 1, INT32_MIN, INT32_MAX, &x) < 0 ||
        get_int(r, "y", 1, INT32_MIN, INT32_MAX, &y) < 0 ||
        get_int(r, "w", 1, 1, INT32_MAX, &w) < 0 || get_int(r, "h", 1, 1, INT32_MAX, &h) < 0)
        return;
    const cJSON *colliders = cJSON_GetObjectItemCaseSensitive(r->msg, "colliders");
    if (colliders && !cJSON_IsBool(colliders)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "colliders: must be true or false");
        return;
    }
    const cJSON *footprints = cJSON_GetObjectItemCaseSensitive(r->msg, "footprints");
    if (footprints && !cJSON_IsBool(footprints)) {
        net_error(c, TERRAD_E_BAD_VALUE, r->ref, -1, 0, "footprints: must be true or false");
        return;
    }
    if (x < 0 || y < 0 || x + w > s->cfg.world.width || y + h > s->cfg.world.height) {
        net_error(c, TERRAD_E_OUTSIDE_WORLD, r->ref, -1, 0,
                  "rectangle x=%lld y=%lld w=%lld h=%lld is not inside the world (%d x %d cells)",
                  (long long)x, (long long)y, (long long)w, (long long)h, s->cfg.world.width,
                  s->cfg.world.height);
        return;
    }
    if (c->sub_count >= l->max_subscriptions) {
        net_error(c, TERRAD_E_LIMIT_SUBSCRIPTIONS, r->ref, -1, 0,
                  "this client already has max_subscriptions (%d) subscriptions",
                  l->max_subscriptions);
        return;
    }
    if (c->sub_cells + w * h > l->max_subscribed_cells) {
        net_error(c, TERRAD_E_LIMIT_SUBSCRIPTIONS, r->ref, -1, 0,
                  "%lld more cells would pass max_subscribed_cells (%lld; %lld subscribed)",
                  (long long)(w * h), (long long)l->max_subscribed_cells, (long long)c->sub_cells);
        return;
    }
    if (array_grow((void **)&c->subs, &c->sub_capacity, (int64_t)c->sub_count + 1,
                   sizeof *c->subs) != 0) {
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0, "out of memory");
        return;
    }
    world_rect rect = {(int)x, (int)y, (int)w, (int)h};
    hub_command cmd = {.kind = HUB_SUBSCRIBE,
                       .client = c->id,
                       .subscription = c->next_sub_id,
                       .rect = rect,
                       .colliders = colliders ? cJSON_IsTrue(colliders) : 0,
                       .footprints = footprints ? cJSON_IsTrue(footprints) : 0};
    ref_text(r->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(s, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    c->subs[c->sub_count++] = (net_sub){c->next_sub_id, rect};
    c->sub_cells += w * h;
    c->snapshots_requested++; /* the sim ends the subscription's snapshot with a marker */
    cJSON *rep = reply("subscribed", r->ref);
    cJSON_AddNumberToObject(rep, "id", c->next_sub_id);
    cJSON_AddNumberToObject(rep, "x", (double)x);
    cJSON_AddNumberToObject(rep, "y", (double)y);
    cJSON_AddNumberToObject(rep, "w", (double)w);
    cJSON_AddNumberToObject(rep, "h", (double)h);
    net_send_json(c, rep);
    c->next_sub_id++;
}

static void handle_unsubscribe(const req *r)
{
    net_client *c = r->c;
    int64_t id;
    if (get_int(r, "id", 1, 0, UINT32_MAX, &id) < 0)
        return;
    int i = sub_index(c, (uint32_t)id);
    if (i < 0) {
        net_error(c, TERRAD_E_UNKNOWN_SUBSCRIPTION, r->ref, -1, 0,
                  "subscription %lld does not exist", (long long)id);
        return;
    }
    hub_command cmd = {.kind = HUB_UNSUBSCRIBE,
                       .client = c->id,
                       .subscription = (uint32_t)id,
                       .rect = c->subs[i].rect};
    ref_text(r->ref, cmd.ref, sizeof cmd.ref);
    if (net_push_refusable(c->srv, &cmd) != 0) {
        net_error(c, TERRAD_E_INTERNAL, r->ref, -1, 0,
                  "server busy: the simulation's command queue is full, try again");
        return;
    }
    c->sub_cells -= (int64_t)c->subs[i].rect.w * c->subs[i].rect.h;
    c->subs[i] = c->subs[--c->sub_count];
    cJSON *rep = reply("unsubscribed", r->ref);
    cJSON_AddNumberToObject(rep, "id", (double)id);
    net_send_json(c, rep);
}

static void handle_resync(const req *r)
{
    int64_t id = 0;
    int got = get_int(r, "id", 0, 0, UINT32_MAX, &id);
    if (got < 0)
        return;
    if (got && sub_index(r->c, (uint32_t)id) < 0) {
        net_error(r->c, TERRAD_E_UNKNOWN_SUBSCRIPTION, r->ref, -1, 0,
                  "subscription %lld does not exist", (long long)id);
        return;
    }
    net_request_resync(r->c, (uint32_t)id);
}

/* ---- text messages ---- */

void net_handle_text(net_client *c, const char *text, size_t len)
{
    THREAD_OWNED(&c->srv->owner);
    cJSON *msg = cJSON_ParseWithLengthOpts(text, len, NULL, 0);
    const cJSON *type = cJSON_IsObject(msg) ? cJSON_GetObjectItemCaseSensitive(msg, "type") : NULL;
    if (!c->ready && !(cJSON_IsString(type) && strcmp(type->valuestring, "hello") == 0)) {
        net_error(c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1, "the first message must be hello");
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "no hello");
        cJSON_Delete(msg);
        return;
    }
    if (!cJSON_IsString(type)) {
        net_error(c, TERRAD_E_BAD_JSON, NULL, -1, 0,
                  msg ? "not a JSON object with a string \"type\"" : "malformed JSON");
        cJSON_Delete(msg);
        return;
    }
    req r = {.c = c, .msg = msg, .ref = cJSON_GetObjectItemCaseSensitive(msg, "ref")};
    if (r.ref && !((cJSON_IsString(r.ref) && strlen(r.ref->valuestring) <= NET_REF_MAX_BYTES) ||
                   is_integer(r.ref))) {
        r.ref = NULL;
        net_error(c, TERRAD_E_BAD_VALUE, NULL, -1, 0,
                  "ref: must be a string of at most %d bytes or an integer", NET_REF_MAX_BYTES);
        cJSON_Delete(msg);
        return;
    }
    const char *t = type->valuestring;
    if (strcmp(t, "hello") == 0)
        handle_hello(&r);
    else if (strcmp(t, "collider_create") == 0)
        handle_collider_create(&r);
    else if (strcmp(t, "collider_delete") == 0)
        handle_collider_delete(&r);
    else if (strcmp(t, "subscribe") == 0)
        handle_subscribe(&r);
    else if (strcmp(t, "unsubscribe") == 0)
        handle_unsubscribe(&r);
    else if (strcmp(t, "resync") == 0)
        handle_resync(&r);
    else
        net_error(c, TERRAD_E_UNKNOWN_TYPE, r.ref, -1, 0, "type: \"%.64s\" is not a request", t);
    cJSON_Delete(msg);
}

/* ---- binary messages ---- */

static uint32_t rd_u32le(const unsigned char *p)
{
    return (uint32_t)p[0] | (uint32_t)p[1] << 8 | (uint32_t)p[2] << 16 | (uint32_t)p[3] << 24;
}

/* The id of the first pose the decoder would refuse as bad_value, -1 if none found. */
static int64_t first_bad_pose(const unsigned char *data, size_t len)
{
    size_t count = (size_t)data[8] | (size_t)data[9] << 8;
    for (size_t i = 0; i < count && TERRAD_POSE_BATCH_FIXED + (i + 1) * TERRAD_POSE_SIZE <= len;
         i++) {
        const unsigned char *p = data + TERRAD_POSE_BATCH_FIXED + i * TERRAD_POSE_SIZE;
        float v[7];
        for (int k = 0; k < 7; k++) {
            uint32_t u = rd_u32le(p + 4 + 4 * k);
            memcpy(&v[k], &u, sizeof u);
        }
        int ok = 1;
        for (int k = 0; k < 7; k++)
            ok &= isfinite(v[k]) != 0;
        if (!ok || !quat_norm_ok(v[3], v[4], v[5], v[6]))
            return rd_u32le(p);
    }
    return -1;
}

static void handle_pose_batch(net_client *c, const unsigned char *data, size_t len)
{
    net_state *s = c->srv;
    uint32_t seq = 0;
    size_t count = 0;
    char store_reason[256];
    cJSON *ref = len >= 8 ? cJSON_CreateNumber(rd_u32le(data + 4)) : NULL;
    int rc = terrad_pose_batch_decode(data, len, &seq, s->poses,
                                      (size_t)s->cfg.limits.max_poses_per_batch, &count);
    if (rc == TERRAD_E_TOO_LARGE) {
        net_error(c, rc, ref, -1, 0, "POSE_BATCH of %u poses is over max_poses_per_batch (%d)",
                  (unsigned)(data[8] | data[9] << 8), s->cfg.limits.max_poses_per_batch);
    } else if (rc == TERRAD_E_BAD_VALUE) {
        net_error(c, rc, ref, first_bad_pose(data, len), 0,
                  "POSE_BATCH: a pose is not finite or its quaternion is not unit length "
                  "(|q| within 0.9..1.1): batch dropped");
    } else if (rc) {
        net_error(c, rc, ref, -1, 0, "POSE_BATCH: %s (%zu bytes)", terrad_err_name(rc), len);
    } else if (hub_store_unavailable(s->hub, store_reason, sizeof store_reason)) {
        net_error(c, TERRAD_E_STORE_UNAVAILABLE, ref, -1, 0,
                  "POSE_BATCH refused: storage cannot make ticks durable (%s); retry later",
                  store_reason);
    } else {
        for (size_t i = 0; i < count; i++) {
            const terrad_pose *p = &s->poses[i];
            if (!owned(c, p->id, ref))
                goto done;
            collider_pose cp = {{p->x, p->y, p->z}, {p->qw, p->qx, p->qy, p->qz}};
            error_text err;
            if (collider_pose_validate(&cp, &err)) {
                net_error(c, TERRAD_E_BAD_VALUE, ref, p->id, 0, "collider %u: %s", p->id,
                          err.message);
                goto done;
            }
        }
        for (size_t i = 0; i < count; i++) {
            const terrad_pose *p = &s->poses[i];
            net_collider_slot *slot = net_collider_find(s, p->id);
            hub_pose hp = {
                .collider = p->id,
                .client = c->id,
                .sequence = seq,
                .pose = {{p->x, p->y, p->z},
                         module_orientation((quatd){p->qw, p->qx, p->qy, p->qz}, slot->axis_z)},
            };
            if (hub_set_pose(s->hub, &hp) != 0) {
                net_error(c, TERRAD_E_INTERNAL, ref, p->id, 0,
                          "the pose table is full: pose of collider %u dropped", p->id);
                break;
            }
        }
        /* every accepted batch, empty ones too, is acknowledged by the next tick */
        hub_note_batch(s->hub, c->id, seq);
    }
done:
    cJSON_Delete(ref);
}

void net_handle_binary(net_client *c, const unsigned char *data, size_t len)
{
    THREAD_OWNED(&c->srv->owner);
    if (!c->ready) {
        net_error(c, TERRAD_E_UNAUTHORIZED, NULL, -1, 1, "the first message must be hello");
        net_close_after_flush(c, 4000 + TERRAD_E_UNAUTHORIZED, "no hello");
        return;
    }
    terrad_header h;
    int rc = terrad_header_decode(data, len, &h);
    if (rc) {
        net_error(c, rc, NULL, -1, 0, "binary frame refused: %s", terrad_err_name(rc));
        return;
    }
    switch (h.type) {
    case TERRAD_MSG_POSE_BATCH:
        handle_pose_batch(c, data, len);
        return;
    case TERRAD_MSG_PING:
    case TERRAD_MSG_PONG: {
        uint8_t type;
        uint64_t nonce;
        rc = terrad_ping_decode(data, len, &type, &nonce);
        if (rc) {
            net_error(c, rc, NULL, -1, 0, "%s: %s", terrad_msg_type_name(h.type),
                      terrad_err_name(rc));
            return;
        }
        if (type == TERRAD_MSG_PONG)
            return;
        hub_frame *f = hub_frame_new(1, TERRAD_PING_SIZE);
        size_t n;
        if (!f || terrad_ping_encode(f->data, f->len, &n, TERRAD_MSG_PONG, nonce) != 0) {
            hub_frame_unref(f);
            return;
        }
        net_enqueue(c, f, NET_ITEM_REPLY);
        return;
    }
    default:
        net_error(c, TERRAD_E_UNKNOWN_TYPE, NULL, -1, 0, "a %s frame is not accepted by the server",
                  terrad_msg_type_name(h.type));
        return;
    }
}
