/*
 * collider: the shapes that press into the terrain — sphere, box, capsule,
 * cylinder (a wheel) and triangle meshes from OBJ files — with their poses,
 * bounds, scripted motion and the CPU twin's depth stage.
 *
 * Depth "from below" (thesis Fig. 4.1) is, for every cell of a window, the
 * lowest point of any collider on the vertical line through the cell centre,
 * in height units. Both backends compute it by one fixed-point specification
 * (depth_fixed.c, GLSL twin shaders/depth_exact.comp) on integers prepared
 * once on the CPU, so their int32 "bottom" arrays are identical; a test can
 * still feed one backend's depth to the other.
 *
 * Local frames: a cylinder's and a capsule's axis is the local Y axis (so a
 * wheel with the identity orientation rolls along X); a box is centred on its
 * position. Orientation is a unit quaternion (w, x, y, z).
 */
#ifndef TERRAD_COLLIDER_H
#define TERRAD_COLLIDER_H

#include <stdint.h>

#include "base/base.h"
#include "world/world.h"

/* "No collider above this cell" in a bottom array. */
#define COLLIDER_BOTTOM_NONE INT32_MAX

typedef struct vec3d {
    double x, y, z;
} vec3d;

typedef struct quatd {
    double w, x, y, z;
} quatd;

typedef struct collider_pose {
    vec3d position; /* metres, world frame: x east, y north, z up */
    quatd orientation;
} collider_pose;

typedef enum collider_shape {
    COLLIDER_SPHERE,
    COLLIDER_BOX,
    COLLIDER_CAPSULE,
    COLLIDER_CYLINDER,
    COLLIDER_MESH,
} collider_shape;

typedef struct collider_mesh {
    int vertex_count;
    int triangle_count;
    float *vertices;        /* xyz, local frame, metres */
    uint32_t *indices;      /* 3 per triangle */
    double bounding_radius; /* max |v| over vertices */
} collider_mesh;

/*
 * A wheel's grousers (lugs, issue 31 item 1; lugs.c): `count` flat plates
 * across the whole width of a cylinder's rim, `height` radially out from the
 * rim, `thickness` along it, spaced 360°/count about the axle (local y), lug
 * 0 pointing along local -z. count 0: a smooth rim. The depth stage presses
 * each lug as a box instance of the one fixed-point rule, so the lugged rim
 * is exact and identical on both backends like every shape.
 */
#define COLLIDER_GROUSERS_MAX 360
typedef struct collider_grousers {
    int count;
    double height;    /* m */
    double thickness; /* m */
} collider_grousers;

typedef struct collider_geometry {
    collider_shape shape;
    double radius;              /* sphere, capsule, cylinder */
    double half_length;         /* capsule, cylinder: half the length of the axis segment */
    vec3d half_extents;         /* box */
    const collider_mesh *mesh;  /* mesh: not owned */
    collider_grousers grousers; /* cylinder only; zero: smooth */
} collider_geometry;

/* Refuse NaN, Inf, non-positive or absurd sizes; the message names the field. */
int collider_geometry_validate(const collider_geometry *g, error_text *err);
int collider_pose_validate(const collider_pose *p, error_text *err);

quatd quat_normalize(quatd q);
quatd quat_multiply(quatd a, quatd b);
quatd quat_from_axis_angle(vec3d axis, double radians);
quatd quat_slerp(quatd a, quatd b, double t);
vec3d quat_rotate(quatd q, vec3d v);
/* A pose's orientation as it comes on the wire, as the engine uses it: normalised, and for a
 * shape whose axis is z on the wire and y in the engine (capsule, cylinder: axis_z) turned a
 * quarter about x. The one copy of the rule: the websocket server (net_control, net_requests)
 * and the twin library's prediction (twin_predict.c) both call it, so a client predicts with
 * the server's bits. */
quatd collider_wire_orientation(quatd q, int axis_z);

/* World-space axis-aligned bounds of the collider at a pose. */
void collider_bounds(const collider_geometry *g, collider_pose pose, vec3d *lo, vec3d *hi);
/* A cylinder's radius, its lugs' corners included (lugs.c); other shapes: radius. */
double collider_rim_reach(const collider_geometry *g);
/* Largest distance of any point of the collider from its position (metres). */
double collider_reach(const collider_geometry *g);
/* What the collider costs a tick, in cells of window work (collider.c has
 * the calibration; the per-client max_active_cells and the per-tick
 * max_tick_cells charge it), whatever its orientation: its window (the
 * square around its bounding sphere and the active margin), the depth work of
 * one pose (a mesh's: per triangle), and the lane of window each cell of
 * travel adds. collider_cost_of is O(triangles) for a mesh (g->mesh must be
 * set); collider_cost_cells charges a tick of `steps` sweep sub-steps (each
 * does the depth work again; the travel is about steps / 2 cells) and one
 * more depth pass for contact feedback. */
typedef struct collider_cost {
    int64_t window, step, lane;
} collider_cost;
collider_cost collider_cost_of(const collider_geometry *g, double cell_size_m);
int64_t collider_cost_cells(const collider_cost *c, int steps, int feedback);

/*
 * CPU twin depth stage: for each cell of `window` (world cell coordinates),
 * bottom[i] = min(bottom[i], floor(z * units_per_m)) where z is the lowest
 * point of the collider on the vertical line through the cell centre
 * ((x + 0.5) * cell_size, (y + 0.5) * cell_size). The value is clamped to
 * [WORLD_HEIGHT_MIN - 1, WORLD_HEIGHT_MAX + 1]. Cells the collider does not
 * cover are left alone. The caller fills bottom with COLLIDER_BOTTOM_NONE first.
 * z is the fixed-point rule's (depth_fixed.c's fixed_cell), the same as the GL
 * backend's.
 */
void collider_depth_cpu(const collider_geometry *g, collider_pose pose, world_rect window,
                        double cell_size_m, int32_t units_per_m, int32_t *bottom);

/*
 * The swept collider of a tick (sweep.c): the depth a tick sees is the
 * minimum over the sub-step poses k = 1..steps of collider_sweep_pose(from,
 * to, k, steps) — position lerped, orientation slerped, the last one `to`
 * exactly. steps = ceil(travel / (cell / 2)), where travel = |Δposition| +
 * reach × rotation angle bounds how far any point of the collider moves, so
 * no point moves more than half a cell between sub-steps and no cell is
 * skipped; at least 1 (a collider at rest or moving at most half a cell costs
 * one pose), at most COLLIDER_SWEEP_STEPS_MAX: beyond that (512 cells per
 * tick) the sub-steps are spaced travel / COLLIDER_SWEEP_STEPS_MAX apart and
 * a small collider may leave gaps. Both backends use these poses.
 */
#define COLLIDER_SWEEP_STEPS_MAX 1024
int collider_sweep_steps(const collider_geometry *g, collider_pose from, collider_pose to,
                         double cell_size_m);
collider_pose collider_sweep_pose(collider_pose from, collider_pose to, int k, int steps);
/* World bounds of every pose k = 0..steps (the previous pose included). */
void collider_sweep_bounds(const collider_geometry *g, collider_pose from, collider_pose to,
                           int steps, vec3d *lo, vec3d *hi);

/*
 * The depth stage's fixed-point specification (depth_fixed.c, GLSL twin
 * shaders/depth_exact.comp): a shape at one pose over one window becomes an
 * instance of int64 words, prepared once on the CPU; both backends evaluate
 * the same integer rule on it, so their bottoms are identical. Shapes for
 * which collider_fixed_supported is 0 (a mesh without triangles) are not
 * prepared (return 0). collider_depth_cpu is this rule on the CPU.
 */
#define COLLIDER_FIXED_WORDS 28 /* CF_END + 3, rounded up */
enum {
    CF_SHAPE,  /* collider_shape */
    CF_WINDOW, /* the GL batch's window index (set by the GL backend) */
    CF_X0,     /* first cell, window-local */
    CF_Y0,
    CF_W, /* cells */
    CF_H,
    CF_SHIFT, /* S: fixed unit = 1/2^S height unit */
    CF_CX0,   /* centre of cell (x0, y0) minus the shape's position, fixed units */
    CF_CY0,
    CF_STEP, /* cell pitch, fixed units */
    CF_CZ,   /* the shape's position z, fixed units */
    CF_R,    /* radius, fixed units */
    CF_H0,   /* box half extents; CF_H1: a cylinder's or capsule's half length */
    CF_H1,
    CF_H2,
    CF_ROT,              /* 9 words: local axis j in world coordinates, Q30, at CF_ROT + 3j */
    CF_END = CF_ROT + 9, /* 3 words: a capsule's end centre offset (+ half_length along y) */
};
typedef struct collider_fixed {
    int64_t v[COLLIDER_FIXED_WORDS];
} collider_fixed;
int collider_fixed_supported(const collider_geometry *g);
/* 1: out holds the instance; 0: the shape misses the window or is not supported */
int collider_fixed_prepare(const collider_geometry *g, collider_pose pose, world_rect window,
                           double cell_size_m, int32_t units_per_m, collider_fixed *out);
/* A mesh at a pose: one instance per triangle that meets the window,
 * appended to *out (grown with array_grow). Returns how many, or -1. The
 * triangle's vertices sit at CF_ROT (x, y relative to the first cell
 * centre, z absolute). */
int collider_fixed_mesh_prepare(const collider_geometry *g, collider_pose pose, world_rect window,
                                double cell_size_m, int32_t units_per_m, collider_fixed **out,
                                int64_t *count, int64_t *capacity);
/* A wheel's optional "grousers" object of obj (lugs_json.c; path names obj
 * in messages): 1 read into out, 0 absent (out zeroed), -1 refused. */
int collider_grousers_from_json(const cJSON *obj, const char *path, collider_grousers *out,
                                error_text *err);
/* Every instance of a shape at a pose, appended to *out (grown with
 * array_grow): a mesh's triangles, a primitive's one instance, and a lugged
 * cylinder's rim plus one box per lug that meets the window (lugs.c). The
 * one list both backends lower the bottoms with. Returns how many, or -1. */
int collider_fixed_instances(const collider_geometry *g, collider_pose pose, world_rect window,
                             double cell_size_m, int32_t units_per_m, collider_fixed **out,
                             int64_t *count, int64_t *capacity);
/* Lug k (0 <= k < count) of a lugged cylinder at a pose: the box it is, and
 * its pose (lugs.c). */
collider_geometry collider_lug_box(const collider_geometry *g, collider_pose pose, int k,
                                   collider_pose *lug_pose);
/* bottom (window_w wide) lowered to the rule over the instance's cells. */
void collider_fixed_apply(const collider_fixed *f, int32_t *bottom, int window_w);
uint64_t collider_isqrt64(uint64_t v);

/* OBJ loading: v and f lines (polygons fanned into triangles, negative and
 * v/vt/vn indices accepted); everything else ignored. */
int collider_mesh_load_obj(const char *path, collider_mesh *mesh, error_text *err);
void collider_mesh_free(collider_mesh *mesh);

/* Scripted motion for offline runs and the demo actors. */
typedef struct collider_keyframe {
    double time_s;
    collider_pose pose;
} collider_keyframe;

typedef enum collider_motion_kind {
    COLLIDER_MOTION_STATIC,
    COLLIDER_MOTION_VELOCITY,  /* constant linear velocity and spin */
    COLLIDER_MOTION_KEYFRAMES, /* linear position, slerp orientation, held at the ends */
} collider_motion_kind;

typedef struct collider_motion {
    collider_motion_kind kind;
    collider_pose start;
    vec3d velocity;  /* m/s */
    vec3d spin_axis; /* world frame */
    double spin_rad_per_s;
    collider_keyframe *keyframes; /* owned */
    int keyframe_count;
} collider_motion;

collider_pose collider_motion_pose(const collider_motion *m, double time_s);
void collider_motion_free(collider_motion *m);

#endif
