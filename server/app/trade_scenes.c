/*
 * trade_scenes.c: the standard scenes of `terrad bench --trade`, built in
 * code so one physical scene can be made at any cell size and turned to any
 * heading on the grid, the models (what a model name means for a material),
 * and the trail cross-section sampler the errors are measured with.
 *
 * Each scene is written in its own frame (x along the trail, y across it,
 * z up) and placed so its bounding box's centre is the world's centre: a
 * heading only rotates the colliders' motion about that point, so the same
 * trail lands on the grid at 0°, 30° or 45°. The material is the thesis's
 * snow (tests/scenes/thesis-car.json): 0.4 m flat, roughness 0.3, repose
 * 35°, obstacle gap 0.1 m, no compression.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "app/trade_internal.h"

/* ---- Models ---- */

const char *const trade_model_names[] = {
    "persson-iterative", "persson-ssbo", "persson-multi", "subtract", "deferred",
    "diffusion",         "sumner",       "decals",        "bekker"};
const int trade_model_count = (int)(sizeof trade_model_names / sizeof trade_model_names[0]);

int trade_model_index(const char *name)
{
    for (int i = 0; i < trade_model_count; i++)
        if (strcmp(trade_model_names[i], name) == 0)
            return i;
    return -1;
}

int trade_model_configure(const char *name, sim_material *m, error_text *err)
{
    /* Persson's three displacement/slope combinations (thesis Table 5.1). */
    if (strcmp(name, "persson-iterative") == 0) {
        m->method = SIM_METHOD_ITERATIVE;
        m->model = sim_model_from_method(m->method);
        return 0;
    }
    if (strcmp(name, "persson-ssbo") == 0) {
        m->method = SIM_METHOD_SSBO;
        m->model = sim_model_from_method(m->method);
        return 0;
    }
    if (strcmp(name, "persson-multi") == 0) {
        m->method = SIM_METHOD_MULTI;
        m->model = sim_model_from_method(m->method);
        return 0;
    }
    /* The other models with their documented defaults (docs/models.md); the
     * sweep's iteration count still sets the slope iterations sumner uses. */
    sim_model model;
    if (trade_model_index(name) >= 0 && sim_model_parse(name, &model) == 0) {
        m->model = model;
        return 0;
    }
    error_set(err, "unknown model \"%s\"", name);
    return -1;
}

/* ---- Scenes ---- */

const char *const trade_scene_names[] = {"car", "spheres", "footsteps"};
const int trade_scene_count = (int)(sizeof trade_scene_names / sizeof trade_scene_names[0]);

static const char *const scene_about[] = {
    "the thesis's car on snow: four wheels r 0.33 m, 8 cm deep, 0.55 m/s, 3 s (165 cm of trail)",
    "16 spheres r 0.12 m, 5 cm deep, rolling at 1 m/s in lanes 0.3 m apart for 1.5 s (Wasmut)",
    "a box foot 0.28 x 0.12 m stamping 5 cm deep four times, 0.6 m apart, lifting between steps",
};

int trade_scene_index(const char *name)
{
    for (int i = 0; i < trade_scene_count; i++)
        if (strcmp(trade_scene_names[i], name) == 0)
            return i;
    return -1;
}

const char *trade_scene_about(int index)
{
    return index >= 0 && index < trade_scene_count ? scene_about[index] : "";
}

#define SNOW_DEPTH_M 0.4
#define TICK_HZ 60.0

/* A scene in its own frame before it is placed in a world. */
typedef struct local_scene {
    scene_collider *colliders;
    int count;
    double lo_x, lo_y, hi_x, hi_y; /* bounding box of everything the colliders touch */
    double duration_s;
} local_scene;

static scene_collider *add_collider(local_scene *ls, const char *name)
{
    scene_collider *c = &ls->colliders[ls->count++];
    memset(c, 0, sizeof *c);
    snprintf(c->name, sizeof c->name, "%s", name);
    c->motion.start.orientation = (quatd){1, 0, 0, 0};
    c->motion.spin_axis = (vec3d){0, 0, 1};
    return c;
}

static void rolling(scene_collider *c, vec3d position, double speed, double radius)
{
    c->motion.kind = COLLIDER_MOTION_VELOCITY;
    c->motion.start.position = position;
    c->motion.velocity = (vec3d){speed, 0, 0};
    c->motion.spin_axis = (vec3d){0, 1, 0};
    c->motion.spin_rad_per_s = speed / radius; /* rolling without slip */
}

/* Persson's car (wheelbase 2.6 m, track 1.5 m) from its rear axle at x = 0. */
static int build_car(local_scene *ls, trade_profile_spec *p)
{
    const double r = 0.33, depth = 0.08, speed = 0.55;
    const double xs[2] = {0.0, 2.6}, ys[2] = {-0.75, 0.75};
    const char *names[4] = {"rear-right", "rear-left", "front-right", "front-left"};
    for (int i = 0; i < 4; i++) {
        scene_collider *c = add_collider(ls, names[i]);
        c->geometry.shape = COLLIDER_CYLINDER;
        c->geometry.radius = r;
        c->geometry.half_length = 0.1;
        rolling(c, (vec3d){xs[i / 2], ys[i % 2], SNOW_DEPTH_M - depth + r}, speed, r);
    }
    ls->duration_s = 3.0;
    ls->lo_x = -0.6;
    ls->hi_x = 2.6 + speed * ls->duration_s + 0.6;
    ls->lo_y = -1.2;
    ls->hi_y = 1.2;
    /* The rear wheels' finished trail, away from where they started and stopped. */
    p->station_count = 3;
    p->stations[0] = 0.5;
    p->stations[1] = 0.9;
    p->stations[2] = 1.3;
    p->across_lo_m = -1.1;
    p->across_hi_m = 1.1;
    return 0;
}

/* Wasmut's spheres: 16 lanes, one sphere each, rolling side by side. */
static int build_spheres(local_scene *ls, trade_profile_spec *p)
{
    const double r = 0.12, depth = 0.05, speed = 1.0, lane = 0.3;
    const int lanes = 16;
    for (int i = 0; i < lanes; i++) {
        char name[32];
        snprintf(name, sizeof name, "sphere-%d", i);
        scene_collider *c = add_collider(ls, name);
        c->geometry.shape = COLLIDER_SPHERE;
        c->geometry.radius = r;
        double y = (i - (lanes - 1) * 0.5) * lane;
        rolling(c, (vec3d){0, y, SNOW_DEPTH_M - depth + r}, speed, r);
    }
    ls->duration_s = 1.5;
    ls->lo_x = -0.4;
    ls->hi_x = speed * ls->duration_s + 0.4;
    ls->lo_y = -(lanes * 0.5) * lane - 0.2;
    ls->hi_y = (lanes * 0.5) * lane + 0.2;
    p->station_count = 3;
    p->stations[0] = 0.4;
    p->stations[1] = 0.75;
    p->stations[2] = 1.1;
    p->across_lo_m = ls->lo_y + 0.1;
    p->across_hi_m = ls->hi_y - 0.1;
    return 0;
}

/* A foot: down 5 cm, held, lifted 10 cm clear, carried to the next step. */
static int build_footsteps(local_scene *ls, trade_profile_spec *p)
{
    const double half_z = 0.05, depth = 0.05, lift = 0.10, pitch = 0.6, period = 0.5;
    const int steps = 4;
    scene_collider *c = add_collider(ls, "foot");
    c->geometry.shape = COLLIDER_BOX;
    c->geometry.half_extents = (vec3d){0.14, 0.06, half_z};
    c->motion.kind = COLLIDER_MOTION_KEYFRAMES;
    c->motion.keyframe_count = steps * 4;
    c->motion.keyframes = calloc((size_t)c->motion.keyframe_count, sizeof *c->motion.keyframes);
    if (!c->motion.keyframes)
        return -1;
    const double z_down = SNOW_DEPTH_M - depth + half_z, z_up = SNOW_DEPTH_M + lift + half_z;
    /* per step: above, down, still down, above again (then carried to the next) */
    const double at[4] = {0.0, 0.15, 0.3, 0.45};
    const double z[4] = {z_up, z_down, z_down, z_up};
    for (int s = 0; s < steps; s++)
        for (int k = 0; k < 4; k++) {
            collider_keyframe *f = &c->motion.keyframes[s * 4 + k];
            f->time_s = s * period + at[k];
            f->pose.position = (vec3d){s * pitch, 0, z[k]};
            f->pose.orientation = (quatd){1, 0, 0, 0};
        }
    ls->duration_s = steps * period;
    ls->lo_x = -0.4;
    ls->hi_x = (steps - 1) * pitch + 0.4;
    ls->lo_y = -0.4;
    ls->hi_y = 0.4;
    p->station_count = steps;
    for (int s = 0; s < steps; s++)
        p->stations[s] = s * pitch;
    p->across_lo_m = -0.3;
    p->across_hi_m = 0.3;
    return 0;
}

/* Rotate about z by the heading and move the scene frame's origin to (ox, oy). */
static vec3d place_point(vec3d v, double c, double s, double ox, double oy)
{
    return (vec3d){ox + c * v.x - s * v.y, oy + s * v.x + c * v.y, v.z};
}

static vec3d turn_vector(vec3d v, double c, double s)
{
    return (vec3d){c * v.x - s * v.y, s * v.x + c * v.y, v.z};
}

static void place_motion(collider_motion *m, double heading_rad, double ox, double oy)
{
    double c = cos(heading_rad), s = sin(heading_rad);
    quatd turn = quat_from_axis_angle((vec3d){0, 0, 1}, heading_rad);
    /* rot(R a, w t) · (turn · q0) = turn · rot(a, w t) · q0: spin axes and
     * velocities turn with the scene, start orientations are pre-multiplied. */
    m->start.position = place_point(m->start.position, c, s, ox, oy);
    m->start.orientation = quat_normalize(quat_multiply(turn, m->start.orientation));
    m->velocity = turn_vector(m->velocity, c, s);
    m->spin_axis = turn_vector(m->spin_axis, c, s);
    for (int k = 0; k < m->keyframe_count; k++) {
        collider_pose *pose = &m->keyframes[k].pose;
        pose->position = place_point(pose->position, c, s, ox, oy);
        pose->orientation = quat_normalize(quat_multiply(turn, pose->orientation));
    }
}

int trade_scene_build(int index, double cell_m, double heading_deg, const sim_material *material,
                      scene *out, long *ticks, trade_profile_spec *profile, error_text *err)
{
    memset(out, 0, sizeof *out);
    memset(profile, 0, sizeof *profile);
    if (index < 0 || index >= trade_scene_count) {
        error_set(err, "unknown scene %d", index);
        return -1;
    }
    if (!(cell_m > 0) || !isfinite(cell_m) || !isfinite(heading_deg)) {
        error_set(err, "%s: cell size %g m / heading %g deg not usable", trade_scene_names[index],
                  cell_m, heading_deg);
        return -1;
    }
    local_scene ls = {0};
    ls.colliders = calloc(32, sizeof *ls.colliders);
    if (!ls.colliders) {
        error_set(err, "out of memory");
        return -1;
    }
    int built = index == 0   ? build_car(&ls, profile)
                : index == 1 ? build_spheres(&ls, profile)
                             : build_footsteps(&ls, profile);
    out->colliders = ls.colliders;
    out->collider_count = ls.count;
    if (built != 0) {
        scene_free(out);
        error_set(err, "out of memory");
        return -1;
    }
    /* A square world that holds the scene's bounding box at any heading, a
     * whole number of 0.4 m tiles so every cell size of the sweep divides it. */
    double diagonal = hypot(ls.hi_x - ls.lo_x, ls.hi_y - ls.lo_y);
    double side_m = ceil((diagonal + 0.4) / 0.4) * 0.4;
    long cells = lround(side_m / cell_m);
    if (cells < 8 || cells > 8192) {
        scene_free(out);
        error_set(err, "%s: cell size %g m gives %ld cells a side (8..8192)",
                  trade_scene_names[index], cell_m, cells);
        return -1;
    }
    double heading = heading_deg * M_PI / 180.0;
    double c = cos(heading), s = sin(heading);
    double mid_x = 0.5 * (ls.lo_x + ls.hi_x), mid_y = 0.5 * (ls.lo_y + ls.hi_y);
    /* origin + R·mid = world centre */
    double ox = 0.5 * side_m - (c * mid_x - s * mid_y);
    double oy = 0.5 * side_m - (s * mid_x + c * mid_y);
    for (int i = 0; i < ls.count; i++)
        place_motion(&out->colliders[i].motion, heading, ox, oy);

    snprintf(out->name, sizeof out->name, "trade-%s", trade_scene_names[index]);
    out->width = out->height = (int)cells;
    out->cell_size_m = side_m / (double)cells;
    out->units_per_m = 10000;
    out->floor_units = 0;
    out->base.kind = WORLD_BASE_FLAT;
    out->base.height_m = SNOW_DEPTH_M;
    out->material = *material;
    out->tick_hz = TICK_HZ;
    out->active_margin_cells = 4;
    *ticks = lround(ls.duration_s * TICK_HZ);

    profile->step_m = 0.01;
    profile->origin_x = ox;
    profile->origin_y = oy;
    profile->cos_heading = c;
    profile->sin_heading = s;
    profile->base_m = SNOW_DEPTH_M;
    return 0;
}

/* ---- Cross-sections ---- */

static int samples_across(const trade_profile_spec *p)
{
    return (int)floor((p->across_hi_m - p->across_lo_m) / p->step_m + 1e-9) + 1;
}

int trade_profile_length(const trade_profile_spec *p)
{
    return p->station_count * samples_across(p);
}

/* Heights live at cell centres ((i + 0.5) * cell); outside them, the edge. */
static double bilinear_m(const world *w, double x_m, double y_m)
{
    double fx = x_m / w->cell_size_m - 0.5, fy = y_m / w->cell_size_m - 0.5;
    fx = fmin(fmax(fx, 0.0), (double)(w->width - 1));
    fy = fmin(fmax(fy, 0.0), (double)(w->height - 1));
    int x0 = (int)floor(fx), y0 = (int)floor(fy);
    int x1 = x0 + 1 < w->width ? x0 + 1 : x0, y1 = y0 + 1 < w->height ? y0 + 1 : y0;
    double tx = fx - x0, ty = fy - y0;
    double a = world_height_at(w, x0, y0), b = world_height_at(w, x1, y0);
    double cc = world_height_at(w, x0, y1), d = world_height_at(w, x1, y1);
    double v = (a * (1 - tx) + b * tx) * (1 - ty) + (cc * (1 - tx) + d * tx) * ty;
    return v / (double)w->units_per_m;
}

void trade_profile_sample(const trade_profile_spec *p, const world *w, double *out)
{
    int n = samples_across(p), k = 0;
    for (int st = 0; st < p->station_count; st++)
        for (int i = 0; i < n; i++) {
            double along = p->stations[st], across = p->across_lo_m + i * p->step_m;
            double x = p->origin_x + p->cos_heading * along - p->sin_heading * across;
            double y = p->origin_y + p->sin_heading * along + p->cos_heading * across;
            out[k++] = bilinear_m(w, x, y) - p->base_m;
        }
}

double trade_rms_difference(const double *a, const double *b, int n)
{
    if (n <= 0)
        return 0.0;
    double sum = 0.0;
    for (int i = 0; i < n; i++)
        sum += (a[i] - b[i]) * (a[i] - b[i]);
    return sqrt(sum / n);
}

world_rect trade_profile_rect(const trade_profile_spec *p, const world *w)
{
    double lo_x = INFINITY, lo_y = INFINITY, hi_x = -INFINITY, hi_y = -INFINITY;
    double across[2] = {p->across_lo_m, p->across_hi_m};
    for (int st = 0; st < p->station_count; st++)
        for (int k = 0; k < 2; k++) {
            double x = p->origin_x + p->cos_heading * p->stations[st] - p->sin_heading * across[k];
            double y = p->origin_y + p->sin_heading * p->stations[st] + p->cos_heading * across[k];
            lo_x = fmin(lo_x, x);
            hi_x = fmax(hi_x, x);
            lo_y = fmin(lo_y, y);
            hi_y = fmax(hi_y, y);
        }
    /* whole cells, one more on each side so bilinear neighbours are in */
    int x0 = (int)floor(lo_x / w->cell_size_m) - 1, y0 = (int)floor(lo_y / w->cell_size_m) - 1;
    int x1 = (int)ceil(hi_x / w->cell_size_m) + 1, y1 = (int)ceil(hi_y / w->cell_size_m) + 1;
    world_rect r = {x0, y0, x1 - x0, y1 - y0};
    if (!world_clip_rect(w, &r))
        r = (world_rect){0, 0, 0, 0};
    return r;
}
