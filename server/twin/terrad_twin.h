/*
 * terrad_twin.h: the twin as a client library (libterrad-twin, docs/engines.md)
 * — the deformation core of the daemon's CPU twin (server/sim, collider,
 * ground, world), compiled from the same source, behind a small C API that a
 * client runs on its own window: describe the world, create a window from the
 * server's heights, give colliders their poses, tick, read heights. The
 * heights are the daemon's bit for bit (tests/integration/clients/test_twin.py runs
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
 * soil.elastic_pa_m, soil.damping_pa_s_m, soil.slip_n, soil.density_kg_m3
 * (the lugs' bulldozing, terrad_twin_add_wheel). An unknown key or a
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
/* A wheel: a cylinder (radius, half_length; axle = local Y) whose rim may
 * carry grousers (lugs) as the server's does (PROTOCOL.md collider_create
 * "grousers", docs/scene-format.md "Grousers"): `grouser_count` flat plates
 * across the whole width, each `grouser_height` m out of the rim and
 * `grouser_thickness` m thick along it, spaced 360°/count about the axle, lug
 * 0 along local -z; on a bekker world they also add their thrust to the
 * soil's forces, as on the server. Count 0 with height and thickness 0: the
 * smooth "cylinder" of terrad_twin_add_collider. The count is a double so
 * that a binding passes what its caller gave (JavaScript's numbers, Python's
 * floats): one that is not a whole number 0..360 is refused naming
 * grousers.count; a height or thickness that is not > 0 and <= the radius
 * is refused naming grousers.height or grousers.thickness. */
TERRAD_TWIN_API int terrad_twin_add_wheel(terrad_twin *t, int id, double radius, double half_length,
                                          double grouser_count, double grouser_height,
                                          double grouser_thickness, char *err);
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
/* A load-driven collider (PROTOCOL.md "Load-driven colliders", the wire's
 * collider_create "load_n"; bekker worlds only): from the next tick on the
 * engine finds its height, as the server's does, where the soil carries
 * load_n newtons (sim_bekker_carry, the daemon's own search), starting from
 * the height it found last tick (the first tick: from its pose's); its
 * poses give x, y and the orientation only. 0: pose-driven again. A load
 * that is not a finite number >= 0, or > 0 on a world whose model is not
 * bekker, is refused naming load_n. */
TERRAD_TWIN_API int terrad_twin_set_load(terrad_twin *t, int id, double load_n, char *err);
/* One tick: the daemon's sim_engine_tick over the window with every posed
 * collider, in the order they were added. */
TERRAD_TWIN_API int terrad_twin_tick(terrad_twin *t, char *err);
/* Copy a rectangle inside the window out of (read) or into (write) the twin:
 * write is how a client resets its window to the server's state. */
TERRAD_TWIN_API int terrad_twin_read(const terrad_twin *t, int x, int y, int w, int h, int32_t *out,
                                     char *err);
TERRAD_TWIN_API int terrad_twin_write(terrad_twin *t, int x, int y, int w, int h,
                                      const int32_t *heights, char *err);

/*
 * Prediction (docs/engines.md, "Prediction"): a client's twin of one window,
 * kept exact against the server's heights. Every client's prediction is this
 * code: the C client (terrad_client_predict.c), Python (terrad.predict, by
 * ctypes) and JavaScript (web/predict.mjs, this library as WebAssembly).
 *
 * The client tells it three things. sent: each pose batch it sends is one
 * server tick, so it is one tick of the twin at once, with the client's own
 * colliders at their poses (the wire's values: each number through float32,
 * the orientation turned as the server turns it, collider_wire_orientation).
 * acked: when the ACK of tick t (batch seq) arrives, every DELTA of t came
 * before it, so the client's mirror holds the server's heights at t; the
 * prediction replays the server's ticks since the previous ACK from that
 * ACK's heights (tick t took the latest pose of each collider of the batches
 * up to seq; a tick without an ACK kept the poses), counts the cells that
 * differ from the mirror (0 whenever nothing else touched the window), then
 * restarts the twin from the mirror, puts each own collider where tick t left
 * it and applies the batches sent after seq again. Colliders: the client's
 * own, added and removed as it creates and deletes them. State beyond the
 * heights (bekker's soil, the compaction memory) is not on the wire: the
 * restart takes the window's state, and each load-driven collider's height,
 * from the replay of tick t (the server's while the replays are exact; where
 * batches were acknowledged together after a gap, the orders they could have
 * been taken in are replayed until one gives the server's heights).
 */
typedef struct terrad_twin_prediction terrad_twin_prediction;

typedef struct terrad_twin_prediction_stats {
    uint64_t predicted;      /* pose batches ticked locally */
    uint64_t reconciled;     /* ACKs taken (with the mirror's heights) */
    uint64_t replayed;       /* ACKs whose replay was compared with the server's heights */
    uint64_t exact;          /* of those, with 0 cells differing */
    uint64_t skipped;        /* ACKs not compared: resyncing, a gap longer than max_replay_ticks,
                                or batches acknowledged together after a gap (which tick took
                                which is unknown) */
    uint64_t on_time;        /* ACKs whose batch's prediction already was the server's heights */
    uint64_t last_differing; /* cells of the last comparison */
    uint64_t pending;        /* batches sent and not acknowledged yet */
} terrad_twin_prediction_stats;

/* A prediction of the window [x, x + w) x [y, y + h) from the server's heights
 * there (a complete mirror). max_replay_ticks: the longest gap between ACKs
 * that is replayed, or 0 for 4 seconds of the config's ticks. */
TERRAD_TWIN_API terrad_twin_prediction *
terrad_twin_prediction_create(const terrad_twin_config *c, int x, int y, int w, int h,
                              const int32_t *heights, int max_replay_ticks, char *err);
TERRAD_TWIN_API void terrad_twin_prediction_destroy(terrad_twin_prediction *p);
/* An own collider, by its wire id and the wire's shape: "sphere" (radius),
 * "box" (hx, hy, hz), "capsule" and "cylinder" (radius, half_length; the
 * wire's axis z), "wheel" (radius, half_length = half its width; axle y). */
TERRAD_TWIN_API int terrad_twin_prediction_add_collider(terrad_twin_prediction *p, uint32_t id,
                                                        const char *shape, double radius,
                                                        double half_length, double hx, double hy,
                                                        double hz, char *err);
/* An own wheel with grousers (the wire's "wheel" with its "grousers" object:
 * radius, half_length = half its width, count, height, thickness; axle y), as
 * terrad_twin_add_wheel takes and refuses them. */
TERRAD_TWIN_API int terrad_twin_prediction_add_wheel(terrad_twin_prediction *p, uint32_t id,
                                                     double radius, double half_length,
                                                     double grouser_count, double grouser_height,
                                                     double grouser_thickness, char *err);
TERRAD_TWIN_API int terrad_twin_prediction_add_mesh(terrad_twin_prediction *p, uint32_t id,
                                                    const float *vertices, int vertex_count,
                                                    const uint32_t *indices, int triangle_count,
                                                    char *err);
/* An own collider is load-driven (the wire's "load_n", given when it was
 * created), as terrad_twin_set_load takes and refuses it: each tick of the
 * prediction and of its replays finds its height as the server does; the
 * height the replay of an ACK's tick found is where the tick left it. */
TERRAD_TWIN_API int terrad_twin_prediction_set_load(terrad_twin_prediction *p, uint32_t id,
                                                    double load_n, char *err);
/* Deleted: it leaves the prediction at once (0 also when it was not in it). */
TERRAD_TWIN_API int terrad_twin_prediction_remove_collider(terrad_twin_prediction *p, uint32_t id,
                                                           char *err);
/* Batch seq is being sent: poses[7 * i ...] = x, y, z, qw, qx, qy, qz of ids[i]
 * as on the wire; ids that are not own colliders are left out. */
TERRAD_TWIN_API int terrad_twin_prediction_sent(terrad_twin_prediction *p, uint32_t seq,
                                                const uint32_t *ids, const double *poses, int count,
                                                char *err);
/* The ACK of tick (batch seq); server: the mirror's w * h heights at tick, or
 * NULL while the mirror is resyncing (the batches are forgotten, the twin goes
 * on predicting until an ACK with heights). -1 (here and in _resume) also when
 * the soil state could not be restored (out of memory): the ACK is taken all
 * the same, but the prediction is inexact from then on. */
TERRAD_TWIN_API int terrad_twin_prediction_acked(terrad_twin_prediction *p, uint64_t tick,
                                                 uint32_t seq, const int32_t *server, char *err);
/* For own colliders the server had posed before this prediction was made (a
 * window made or moved while driving), right after it was made from the
 * mirror at the ACK of tick: where the latest acknowledged batch left each
 * (poses as in _sent). The batches sent after that ACK then go to _sent. */
TERRAD_TWIN_API int terrad_twin_prediction_resume(terrad_twin_prediction *p, uint64_t tick,
                                                  const uint32_t *ids, const double *poses,
                                                  int count, char *err);
/* The predicted heights (w * h, row-major), valid until the next call. */
TERRAD_TWIN_API const int32_t *terrad_twin_prediction_heights(const terrad_twin_prediction *p);
TERRAD_TWIN_API const terrad_twin_prediction_stats *
terrad_twin_prediction_get_stats(const terrad_twin_prediction *p);
/* The seqs of the batches sent and not acknowledged, oldest first: up to max
 * into seqs; returns how many there are. */
TERRAD_TWIN_API int terrad_twin_prediction_pending(const terrad_twin_prediction *p, uint32_t *seqs,
                                                   int max);
/* The prediction's twin, for reading (terrad_twin_read); it belongs to p. */
TERRAD_TWIN_API terrad_twin *terrad_twin_prediction_twin(terrad_twin_prediction *p);
/* Test hook: the next `count` restores of a prediction's soil state in this
 * process (or WebAssembly instance), of any prediction, fail as they do out of
 * memory (the state is left as it was; _acked and _resume return -1 with
 * their sentence); 0 disarms. Only a stateful window restores (a bekker
 * world, the compaction memory). That failure cannot be provoked otherwise
 * (the restore writes into tiles its twin already holds), so this is how the
 * clients' handling of it is tested (test_twin_predict, test_predict_c /
 * _python / _js); nothing else should call it. */
TERRAD_TWIN_API void terrad_twin_fault_restores(int count);

#ifdef __cplusplus
}
#endif
#endif
