/*
 * terrad_client: a small synchronous C client for terrad (proto/PROTOCOL.md)
 * over libwebsockets' client API, for game backends and simulators written
 * in C or C++.
 *
 * Usage (the whole program: clients/c/examples/drive_wheel.c):
 *
 *     char err[256];
 *     terrad_client *c = terrad_client_connect((terrad_client_desc){.port = 8081}, err,
 *                                              sizeof err);
 *     uint32_t wheel, sub, seq;
 *     terrad_client_create_collider(
 *         c, (terrad_collider_desc){.shape = TERRAD_SHAPE_WHEEL, .radius = 0.3, .width = 0.2},
 *         &wheel);
 *     terrad_client_subscribe(c, 0, 0, 128, 128, &sub);
 *     terrad_pose p = {wheel, 1.0f, 1.0f, 0.5f, 1, 0, 0, 0};
 *     terrad_client_send_poses(c, &p, 1, &seq);
 *     while (terrad_client_poll(c, 20) >= 0) {
 *         const terrad_mirror *m = terrad_client_mirror(c, sub);
 *         ... m->heights: row-major int32, exact where the tile's version is not 0 ...
 *     }
 *     terrad_client_close(c);
 *
 * Build against the installed library:
 *
 *     cc app.c $(pkg-config --cflags --libs terrad-client)
 *
 * and include <terrad/terrad_client.h>.
 *
 * One connection, one thread, no callbacks needed: requests (collider
 * create/delete, subscribe, unsubscribe) block until the server's reply or
 * error; terrad_client_poll services the socket for up to a timeout and
 * handles whatever arrived: DELTA frames update a terrad_mirror per
 * subscription (a mirror that falls out of step asks for a resync by
 * itself), CONTACT frames replace the latest contact feedback, ACKs the
 * latest acknowledged tick and sequence, and unsolicited errors are counted
 * and kept as the last error. An optional hook sees every binary frame after
 * it has been handled (for example to copy a mirror at each ACK). The client
 * tells the server the latest tick handled (PROTOCOL.md "seen": after the
 * hook, at most every 0.1 s, and from terrad_client_poll after a pause), so
 * the server bounds its lag end to end: keep polling.
 *
 * Return values: 0 for success; a positive protocol error code
 * (terrad_proto_err) when the server refused a request or a value is not
 * allowed; a negative TERRAD_CLIENT_E_* (or TERRAD_E_NO_MEMORY) for local
 * failures. terrad_client_last_error() has a sentence for people.
 * Not thread-safe: use one client from one thread.
 *
 * Logging: the client writes nothing to stdout or stderr. Its messages (the
 * same sentences terrad_client_last_error returns, and a line on connect and
 * close) go to desc.log when one is given. libwebsockets' own log is
 * process-wide; terrad_client_connect sets it to desc.lws_log_levels (0, the
 * default: silent), or leaves it alone with TERRAD_CLIENT_LWS_LOG_KEEP for a
 * host that uses libwebsockets itself.
 */
#ifndef TERRAD_CLIENT_H
#define TERRAD_CLIENT_H

#include <stddef.h>
#include <stdint.h>

#include "terrad_proto.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Local failures (never travel on the wire). */
#define TERRAD_CLIENT_E_TIMEOUT (-10)  /* no reply within the timeout */
#define TERRAD_CLIENT_E_CLOSED (-11)   /* the connection is closed */
#define TERRAD_CLIENT_E_CONNECT (-12)  /* could not connect or upgrade */
#define TERRAD_CLIENT_E_PROTOCOL (-13) /* the server sent something the protocol does not allow */

typedef struct terrad_client terrad_client;

/* Called after each binary frame has been handled; msg_type is a
 * terrad_msg_type, tick the frame's tick (0 for PING/PONG). */
typedef void (*terrad_client_hook)(void *user, terrad_client *c, int msg_type, uint64_t tick);

/* Levels of the log callback. */
typedef enum terrad_client_log_level {
    TERRAD_LOG_ERROR = 1, /* a request or the connection failed */
    TERRAD_LOG_WARN = 2,  /* something was refused or repaired (a resync) */
    TERRAD_LOG_INFO = 3,  /* connected, closed */
} terrad_client_log_level;

/* One log message (no newline at the end). */
typedef void (*terrad_client_log_fn)(void *user, int level, const char *message);

/* desc.lws_log_levels: leave libwebsockets' log level and emitter as they are. */
#define TERRAD_CLIENT_LWS_LOG_KEEP (-1)

typedef struct terrad_client_desc {
    const char *host;         /* NULL: "127.0.0.1" */
    int port;                 /* 0: 8081 */
    const char *token;        /* NULL: "" */
    const char *name;         /* hello.client; NULL: "terrad-c" */
    int timeout_ms;           /* connect + hello, and each request; 0: 5000 */
    terrad_client_hook hook;  /* optional */
    void *user;               /* passed to hook and log */
    terrad_client_log_fn log; /* optional; NULL: the client logs nothing */
    int log_level;            /* messages up to this level reach log; 0: TERRAD_LOG_INFO */
    int lws_log_levels;       /* libwebsockets' LLL_* bits to stderr; 0: silent; or KEEP */
    /* TLS (a daemon started with --tls-cert): 1 connects with wss://, the
     * server's certificate checked against tls_ca_file (a PEM file, e.g. a
     * self-signed certificate itself) or, when that is NULL, the system's CAs;
     * its name must match host. 0: plain ws:// */
    int tls;
    const char *tls_ca_file;
    /* bytes per second the server may send this client (PROTOCOL.md
     * "Budgets": near tiles every tick, far ones later, exact once the
     * terrain settles; terrad_world_info.budget says the one in force).
     * 0: the server's default; -1: none */
    int64_t budget;
} terrad_client_desc;

/* The world message (PROTOCOL.md "world"); limits not listed keep their defaults. */
typedef struct terrad_world_info {
    int width, height; /* cells */
    int tile_size;
    double cell_size_m;
    double tick_hz;
    int32_t units_per_m;
    int64_t height_min, height_max;
    uint64_t tick; /* at hello */
    int64_t max_message_bytes, max_poses_per_batch, max_colliders, max_subscriptions;
    int64_t budget; /* this connection's budget in bytes/s (0: none) */
} terrad_world_info;

/* Counters and the latest of each kind of frame. */
typedef struct terrad_client_stats {
    uint64_t delta_frames, delta_bytes, delta_tick; /* tick of the last DELTA */
    uint64_t contact_frames, contact_tick;
    uint64_t forces_frames; /* FORCES frames (worlds of the bekker soil model) */
    uint64_t acks, ack_tick;
    uint32_t ack_seq;  /* the last POSE_BATCH the server used */
    uint64_t errors;   /* error messages not answering a request */
    uint64_t resyncs;  /* resyncs this client asked for (mirror out of step) */
    uint64_t messages; /* everything received */
    int last_error_code;
    int close_code; /* the server's close code, once closed (0: none given) */
    /* desync detection (PROTOCOL.md "CHECKSUM"; appended, so the layout of
     * libterrad-client.so.1's fields above is unchanged): CHECKSUM frames
     * compared, tiles found differing from the server's, and tiles asked for
     * again (resync with "tiles"); each differing tile is not held (its deltas
     * skipped) until its snapshot comes, which makes it equal again */
    uint64_t checksum_frames, checksum_tick;
    uint64_t tiles_differing, tiles_resynced;
} terrad_client_stats;

typedef enum terrad_shape {
    TERRAD_SHAPE_SPHERE = 1, /* radius */
    TERRAD_SHAPE_BOX,        /* half_extents */
    TERRAD_SHAPE_CAPSULE,    /* radius, half_length; axis z */
    TERRAD_SHAPE_CYLINDER,   /* radius, half_length; axis z */
    TERRAD_SHAPE_WHEEL,      /* radius, width; axle along y */
} terrad_shape;

typedef struct terrad_collider_desc {
    terrad_shape shape;
    double radius, half_length, width; /* metres, as the shape needs */
    double half_extents[3];
    const char *material; /* NULL: "default" */
    int no_feedback;      /* 1: no CONTACT entries for it (zero: feedback on) */
} terrad_collider_desc;

/* Connects, sends hello and waits for the world message. NULL on failure,
 * with a sentence in err (when err_cap > 0). */
terrad_client *terrad_client_connect(terrad_client_desc d, char *err, size_t err_cap);
/* Closes with code 1000 (waiting briefly for the close handshake) and frees c. */
void terrad_client_close(terrad_client *c);

const terrad_world_info *terrad_client_world(const terrad_client *c);
const terrad_client_stats *terrad_client_get_stats(const terrad_client *c);
const char *terrad_client_last_error(const terrad_client *c);
int terrad_client_is_open(const terrad_client *c);

int terrad_client_create_collider(terrad_client *c, terrad_collider_desc d, uint32_t *id_out);
/* A load-driven collider (bekker worlds, PROTOCOL.md "Load-driven
 * colliders"): load_n is the vertical load in newtons; the server sets the
 * height that carries it every tick and reports it in FORCES (the poses'
 * heights are ignored). A call of its own rather than a field of
 * terrad_collider_desc, which is passed by value and so is part of
 * libterrad-client.so.1's ABI (a program or a C# P/Invoke struct built
 * against the first layout would pass a shorter struct). The server judges
 * load_n and names it when it refuses (NaN, <= 0, a world without soil). */
int terrad_client_create_loaded_collider(terrad_client *c, terrad_collider_desc d, double load_n,
                                         uint32_t *id_out);
/* A wheel with grousers (PROTOCOL.md collider_create "grousers"): `count`
 * lugs across the rim, `height` out from it, `thickness` along it (metres).
 * d.shape must be TERRAD_SHAPE_WHEEL (the server refuses another shape,
 * naming grousers); load_n 0: pose-driven, else load-driven as above. A call
 * of its own for the same ABI reason. Predicted like a smooth wheel
 * (terrad_client_predict): the twin library presses the lugs as the server. */
typedef struct terrad_grousers {
    int count;
    double height, thickness;
} terrad_grousers;
int terrad_client_create_lugged_collider(terrad_client *c, terrad_collider_desc d,
                                         terrad_grousers g, double load_n, uint32_t *id_out);
int terrad_client_delete_collider(terrad_client *c, uint32_t id);
/* Sends one POSE_BATCH (the next sequence number, returned in *seq_out)
 * and pushes it to the socket without waiting for anything. count 0 asks
 * for an ACK. */
int terrad_client_send_poses(terrad_client *c, const terrad_pose *poses, size_t count,
                             uint32_t *seq_out);
/* Subscribes and makes a mirror of the region; the snapshot arrives with
 * later polls (terrad_client_mirror_complete says when). */
int terrad_client_subscribe(terrad_client *c, int32_t x, int32_t y, uint32_t w, uint32_t h,
                            uint32_t *sid_out);
/* The same, with COLLIDERS frames for the region (PROTOCOL.md "COLLIDERS": every collider in
 * view, other clients' and the daemon's too); grousers 1 asks for the wheels' grousers with
 * them (the extension). terrad_client_colliders reads the latest frame. */
int terrad_client_subscribe_colliders(terrad_client *c, int32_t x, int32_t y, uint32_t w,
                                      uint32_t h, int grousers, uint32_t *sid_out);
/* The latest COLLIDERS frame: copies up to cap entries (and, when grousers is not NULL, each
 * one's grousers: all zero for none or from a frame without the extension) and returns how
 * many the frame had (0 before the first). */
size_t terrad_client_colliders(const terrad_client *c, terrad_collider_state *states,
                               terrad_collider_grousers *grousers, size_t cap, uint64_t *tick_out);
int terrad_client_unsubscribe(terrad_client *c, uint32_t sid);
/* A terrain edit (PROTOCOL.md "edit"): edit_json is the message's fields as a
 * JSON object, e.g. {"op":"stamp","x":0,"y":0,"w":2,"h":2,"data":"..."}
 * ("type" and "ref" are set here). Waits for the server's "edited": 0 with
 * the tick it took effect and its exact volume change (height units), or the
 * error code with terrad_client_last_error naming the field. */
int terrad_client_edit(terrad_client *c, const char *edit_json, uint64_t *tick_out,
                       int64_t *volume_out);
/* A crater at cell (x, y) of radius cells and depth units; rim 1 keeps Σh. */
int terrad_client_crater(terrad_client *c, int32_t x, int32_t y, int32_t radius, int32_t depth,
                         int rim, uint64_t *tick_out, int64_t *volume_out);
/* A budgeted client's focus, in cells: its nearest tiles come first
 * (PROTOCOL.md "focus"); set 0 clears it (its colliders again). No reply. */
int terrad_client_focus(terrad_client *c, int set, double x, double y);
/* Asks for fresh snapshots of one subscription (sid 0: all); no reply. */
int terrad_client_resync(terrad_client *c, uint32_t sid);
/* Sends a PING frame with the given nonce (the PONG shows in the hook). */
int terrad_client_ping(terrad_client *c, uint64_t nonce);

/* The mirror of a subscription, or NULL. Its heights are exact for every
 * tile whose version is not 0. */
const terrad_mirror *terrad_client_mirror(const terrad_client *c, uint32_t sid);
/* 1 when every tile of the subscription is held. */
int terrad_client_mirror_complete(const terrad_client *c, uint32_t sid);
/* The latest contact feedback for a collider (1), or 0 when none came yet. */
int terrad_client_contact(const terrad_client *c, uint32_t collider, terrad_contact *out,
                          uint64_t *tick_out);

/* The soil's latest push on a collider (FORCES, worlds of the bekker model):
 * 1, or 0 when none came yet. */
int terrad_client_force(const terrad_client *c, uint32_t collider, terrad_force *out,
                        uint64_t *tick_out);
/* A load-driven collider's height (m) the server found, from the same latest
 * FORCES frame (terrad_client_create_loaded_collider asks for the heights:
 * PROTOCOL.md "FORCES", the height extension): 1, or 0 when that frame had
 * none for it. */
int terrad_client_force_height(const terrad_client *c, uint32_t collider, double *z_m);

/* Services the connection for up to timeout_ms (0: only what is ready),
 * returning as soon as at least one message was handled: the number of
 * messages handled (0 on timeout), or TERRAD_CLIENT_E_CLOSED once the
 * connection is closed. */
int terrad_client_poll(terrad_client *c, int timeout_ms);

/* ---- added in 0.3: new calls only, libterrad-client.so.1's ABI is unchanged ---- */

/* terrad_client_connect, with a hello naming the world to join (PROTOCOL.md
 * "hello"): a world created by POST /v1/worlds, the default world's scene name,
 * or, on a cluster, any registered world; NULL or "" is the default world. A
 * name the server does not serve fails (NULL, err names "world" and the worlds
 * it serves); a name longer than 64 bytes is refused before connecting. */
terrad_client *terrad_client_connect_world(terrad_client_desc d, const char *world, char *err,
                                           size_t err_cap);
/* The world message's `world`: the name of the world joined ("" when it
 * carried none: a single daemon's default world). */
const char *terrad_client_world_name(const terrad_client *c);

/*
 * Prediction (docs/engines.md, "Prediction"): the client runs the daemon's own
 * deformation code (libterrad-twin) on a subscription's window, so this
 * client's own colliders press it in the call that sends their poses, and
 * every ACK reconciles it exactly with the server's heights. The wire is the
 * same with it on or off.
 *
 *   terrad_client_subscribe(c, x, y, w, h, &sid);  ... poll until mirror_complete ...
 *   terrad_prediction *p;
 *   terrad_client_predict(c, sid, "model=persson-ssbo margin_cells=4 terrain.height_m=0.4", &p);
 *   terrad_client_send_poses(c, poses, n, &seq);   // the twin ticks before the bytes leave
 *   terrad_prediction_heights(p);                  // w * h, the own rut already in it
 *
 * config: the world's parameters as "key=value" pairs separated by spaces,
 * tabs, commas or semicolons, under terrad_twin.h's keys (model, metric,
 * margin_cells, terrain.kind, terrain.*, the material's compression, ...);
 * a value that reads whole as a number is numeric, any other is a name.
 * width, height, cell_size_m, units_per_m and tick_hz come from the world
 * message unless given. The subscription's snapshot must be complete.
 * Returns 0, or TERRAD_E_BAD_VALUE / TERRAD_E_NO_MEMORY with
 * terrad_client_last_error naming the field ("sid", "config", or the key).
 *
 * Each terrad_client_send_poses is one tick of the twin with this client's own
 * colliders (created by this client, default material; a load-driven one,
 * terrad_client_create_loaded_collider, at the height the server's search
 * finds in the twin) at their new poses;
 * each ACK of tick t (batch seq) replays the server's ticks since the previous
 * ACK from that ACK's heights with the poses the ACKs say were used, counts
 * the cells differing from the mirror (0 when nothing else touched the
 * window), resets the twin to the mirror, puts each own collider where tick t
 * left it and applies the batches sent after seq again. Delete a predicted
 * collider once its last batch is acknowledged: it leaves the prediction at
 * once, so a replay of a tick that still had it would differ.
 */
typedef struct terrad_prediction terrad_prediction;

typedef struct terrad_prediction_stats {
    uint64_t predicted;  /* pose batches ticked locally */
    uint64_t reconciled; /* ACKs taken */
    uint64_t replayed;   /* ACKs whose replay was compared with the server's heights */
    uint64_t exact;      /* of those, with 0 cells differing */
    uint64_t skipped;    /* ACKs not compared (resyncing, a long gap, batches spread over a gap) */
    uint64_t on_time;    /* ACKs whose batch's prediction already was the server's heights */
    uint64_t last_differing; /* cells of the last comparison */
    uint64_t pending;        /* batches sent and not acknowledged yet */
    /* added in 0.5 (appended: the fields above are where they were): the client's events the
     * twin failed on — an ACK or batch taken but with the soil state not restored (out of
     * memory: inexact until the state is pressed anew), a batch not predicted, an own
     * collider not added or removed; terrad_prediction_last_error says why. The client goes
     * on: every later ACK is taken, compared and reset to the mirror as before. */
    uint64_t errors;
} terrad_prediction_stats;

int terrad_client_predict(terrad_client *c, uint32_t sid, const char *config,
                          terrad_prediction **out);
/* The predicted heights of the subscription's window (w * h, row-major, as
 * the mirror's), valid until the next call on the client. */
const int32_t *terrad_prediction_heights(const terrad_prediction *p);
const terrad_prediction_stats *terrad_prediction_get_stats(const terrad_prediction *p);
/* The twin's sentence for the last of stats.errors ("" while there is none). */
const char *terrad_prediction_last_error(const terrad_prediction *p);
/* Ends a prediction (terrad_client_close ends those left). */
void terrad_prediction_stop(terrad_prediction *p);

/* The connection's socket descriptor (-1 once closed), for a program that
 * drives many clients from one thread: wait with poll() on every client's
 * descriptor, then call terrad_client_poll(c, 0) on those that are ready. */
int terrad_client_fd(const terrad_client *c);

/* ---- added in 0.4: lockstep co-simulation (PROTOCOL.md "STEP"; docs/simulators.md) ----
 *
 * A world made with "clock": "client" ticks only when its driver steps it:
 *
 *     terrad_pose wheels[4] = {...};                       // this tick's poses
 *     terrad_step s = {.ticks = 1, .poses = wheels, .count = 4, .sets = 1};
 *     uint64_t tick;
 *     terrad_client_step(c, &s, &tick);                    // the tick ran and is durable
 *     terrad_client_force(c, wheel_id, &f, NULL);          // its FORCES entry
 *
 * Each of the step's ticks sends what a wall-clock tick sends (DELTA, CONTACT,
 * FORCES, ACK naming the step, ... each through the hook as usual), then one
 * STEPPED after the last. The first accepted step makes this client the
 * world's driver until it disconnects; another client's step is refused with
 * forbidden (22) naming "driver". A step the server refuses returns the
 * error's code, terrad_client_last_error naming the field (ticks, sets,
 * count, poses[i], clock, driver, queue, store). */
typedef struct terrad_step {
    uint32_t ticks;           /* ticks to run, 1..limits.max_step_ticks */
    const terrad_pose *poses; /* sets * count poses, set after set */
    uint16_t count;           /* poses per set (<= limits.max_poses_per_batch) */
    /* 0: every collider holds its pose; 1: the set poses them at the first
     * tick and they hold after; ticks: set i is tick i's (ticks <= 65535) */
    uint16_t sets;
} terrad_step;

/* Sends a STEP (its number in *seq_out) without waiting. Up to 64 may wait
 * on the server (the world's queue); more are refused naming "queue". */
int terrad_client_step_send(terrad_client *c, const terrad_step *s, uint32_t *seq_out);
/* Services the connection until step seq is answered: 0 with the tick its
 * last tick had (*tick_out), or the server's error code for it, or
 * TERRAD_CLIENT_E_TIMEOUT after desc.timeout_ms, or TERRAD_CLIENT_E_CLOSED. */
int terrad_client_step_wait(terrad_client *c, uint32_t seq, uint64_t *tick_out);
/* step_send then step_wait. */
int terrad_client_step(terrad_client *c, const terrad_step *s, uint64_t *tick_out);
/* K worlds stepped as one (vectorised environments): steps[i] goes to
 * clients[i] (each connected to its own client-clocked world), all sent
 * before any is waited for, so the worlds' ticks run at once on the server's
 * shared pool of sim workers; then every client is serviced until each step
 * is answered. ticks_out[i] (may be NULL): the tick each ended at; rcs_out[i]
 * (may be NULL): each one's result as terrad_client_step_wait's. Returns 0
 * when all succeeded, else the first non-zero result. */
int terrad_client_step_many(terrad_client *const *clients, const terrad_step *steps, size_t k,
                            uint64_t *ticks_out, int *rcs_out);
/* 1 when the world joined ticks on its driver's steps (world "clock":
 * "client"), 0 on the server's wall clock. */
int terrad_client_world_client_clock(const terrad_client *c);

/* ---- added in 0.5: base snapshots (PROTOCOL.md "Base snapshots"), new calls only ----
 *
 * terrad_client_connect_world, with a hello asking for base snapshots: a late
 * joiner's snapshots come as its heights less the scene's base terrain, which
 * this library rebuilds over each subscription with the twin library (from
 * the world message's "base"), coded so that a window dug for an hour costs a
 * fraction of its raw heights (docs/performance.md "Late join"). The mirrors
 * hold exactly the same heights either way. A server that cannot make the
 * base (a file base, per-cell materials) or predates them sends absolute
 * snapshots: terrad_client_base_snapshots says 0. */
terrad_client *terrad_client_connect_base(terrad_client_desc d, const char *world, char *err,
                                          size_t err_cap);
/* 1 when the server agreed to base snapshots for this connection. */
int terrad_client_base_snapshots(const terrad_client *c);

/* ---- added in 0.6: slope snapshots (PROTOCOL.md "Slope snapshots"), new calls only ----
 *
 * terrad_client_connect_base, also offering slope snapshots (encoding 3): the
 * server then codes each snapshot piece both ways and sends the shorter; on
 * ground driven over for an hour (a sand pile at its angle of repose) that is
 * about a fifth less than encoding 2. terrad_client_slope_snapshots says 1
 * when the server agreed (an older server ignores the offer: encoding 2). */
terrad_client *terrad_client_connect_slope(terrad_client_desc d, const char *world, char *err,
                                           size_t err_cap);
int terrad_client_slope_snapshots(const terrad_client *c);

#ifdef __cplusplus
}
#endif

#endif /* TERRAD_CLIENT_H */
