/*
 * terrad_twin.h: the twin as a client library (libterrad-twin, docs/engines.md)
 * — the deformation core of the daemon's CPU twin (server/sim, collider,
 * ground, world), compiled from the same source, behind a small C API that a
 * client runs on its own window: describe the world, create a window from the
 * server's heights, give colliders their poses, tick, read heights. The
 * heights are the daemon's bit for bit (tests/integration/test_twin.py runs
 * this library natively and as WebAssembly against `terrad simulate`).
 *
 * A window is a rectangle of the world's cells; the twin knows nothing outside
 * it but the world's base terrain, so its edge cells are exact only while the
 * model's reach stays inside (docs/engines.md, "Halo"). One twin is one
 * thread's: calls on one twin must not overlap; separate twins are
 * independent. Errors: every function that can fail returns -1 (or NULL) and
 * writes a sentence naming the field into `err` (TERRAD_TWIN_ERROR_MAX bytes;
 * err may be NULL).
 *
 * This is the subsystem's one public header, installed as
 * <terrad/terrad_twin.h>; it depends on nothing but <stdint.h>.
 */
#ifndef TERRAD_TWIN_H
#define TERRAD_TWIN_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TERRAD_TWIN_ERROR_MAX 256

/* The shared library exports these and nothing else (CMakeLists.txt). */
#ifndef TERRAD_TWIN_API
#define TERRAD_TWIN_API
#endif

/* The world's parameters and material, set key by key (the scene's names). */
typedef struct terrad_twin_config terrad_twin_config;
typedef struct terrad_twin terrad_twin;

/* Defaults: a 1024 x 1024 world of 5 cm cells, 10,000 units per metre, flat
 * base at 0, the default material (persson-ssbo, Table 5.3), 60 ticks per
 * second, margin 4. NULL when out of memory. */
TERRAD_TWIN_API terrad_twin_config *terrad_twin_config_new(void);
TERRAD_TWIN_API void terrad_twin_config_free(terrad_twin_config *c);
/*
 * Numeric keys: width, height (cells), cell_size_m, units_per_m, floor_units,
 * margin_cells (the scene's active_margin_cells), tick_hz; the base terrain's
 * terrain.height_m (flat), terrain.min_height_m, terrain.max_height_m,
 * terrain.wavelength_m, terrain.octaves, terrain.seed (dunes); the material's
 * compression, roughness, repose_deg, obstacle_gap_m, multi_target_m,
 * multi_target_max, displace_iterations, slope_iterations, refill_m_per_s,
 * trail_scale_per_m, trail_range_m, edge_height, edge_width, diffusion_d,
 * diffusion_zeta_inv, diffusion_force_scale, diffusion_dt, diffusion_substeps,
 * diffusion_conservative, decal_min_strength_m; the bekker model's soil.n,
 * soil.kc, soil.kphi, soil.cohesion_pa, soil.friction_deg, soil.shear_k_m,
 * soil.elastic_pa_m, soil.damping_pa_s_m, soil.slip_n. An unknown key or a
 * non-finite value is refused; ranges are checked at terrad_twin_create.
 */
TERRAD_TWIN_API int terrad_twin_config_set(terrad_twin_config *c, const char *key, double value,
                                           char *err);
/* Name keys: model (persson-iterative | persson-ssbo | persson-multi |
 * subtract | deferred | diffusion | sumner | decals | bekker), metric (euclidean |
 * manhattan | chebyshev), terrain.kind (flat | dunes). */
TERRAD_TWIN_API int terrad_twin_config_set_name(terrad_twin_config *c, const char *key,
                                                const char *value, char *err);

/* A window [x, x + w) x [y, y + h) of the configured world, heights w * h
 * row-major in height units (the server's), or NULL: the window is the
 * world's untouched base terrain. The config is not kept. */
TERRAD_TWIN_API terrad_twin *terrad_twin_create(const terrad_twin_config *c, int x, int y, int w,
                                                int h, const int32_t *heights, char *err);
TERRAD_TWIN_API void terrad_twin_destroy(terrad_twin *t);

/* Colliders, identified by the caller's id (any int, unique per twin). shape:
 * "sphere" (radius), "box" (hx, hy, hz half extents), "capsule" and
 * "cylinder" (radius, half_length; axis = local Y). Sizes in metres. */
TERRAD_TWIN_API int terrad_twin_add_collider(terrad_twin *t, int id, const char *shape,
                                             double radius, double half_length, double hx,
                                             double hy, double hz, char *err);
/* A triangle mesh: vertices xyz (local frame, metres), 3 indices per
 * triangle. The arrays are copied. */
TERRAD_TWIN_API int terrad_twin_add_mesh(terrad_twin *t, int id, const float *vertices,
                                         int vertex_count, const uint32_t *indices,
                                         int triangle_count, char *err);
TERRAD_TWIN_API int terrad_twin_remove_collider(terrad_twin *t, int id, char *err);
/* The collider's pose from the next tick on (position in metres, world frame;
 * unit quaternion w, x, y, z). Like the daemon: a collider presses every tick
 * once it has a pose, swept from the previous tick's pose; its first pose is
 * not swept. */
TERRAD_TWIN_API int terrad_twin_set_pose(terrad_twin *t, int id, double x, double y, double z,
                                         double qw, double qx, double qy, double qz, char *err);
/* The collider stood at this pose in the last tick: its pose from now on, and
 * the pose the next tick sweeps from. How a predicting client puts its
 * collider back where the server's acknowledged tick left it (docs/engines.md,
 * "Prediction") after writing that tick's heights into the window. */
TERRAD_TWIN_API int terrad_twin_place(terrad_twin *t, int id, double x, double y, double z,
                                      double qw, double qx, double qy, double qz, char *err);
/* One tick: the daemon's sim_engine_tick over the window with every posed
 * collider, in the order they were added. */
TERRAD_TWIN_API int terrad_twin_tick(terrad_twin *t, char *err);
/* Copy a rectangle inside the window out of (read) or into (write) the twin:
 * write is how a client resets its window to the server's state. */
TERRAD_TWIN_API int terrad_twin_read(const terrad_twin *t, int x, int y, int w, int h, int32_t *out,
                                     char *err);
TERRAD_TWIN_API int terrad_twin_write(terrad_twin *t, int x, int y, int w, int h,
                                      const int32_t *heights, char *err);

#ifdef __cplusplus
}
#endif
#endif
