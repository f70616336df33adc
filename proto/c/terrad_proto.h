/*
 * terrad_proto: the binary half of the terrad wire protocol (proto/PROTOCOL.md)
 * as plain C11 codecs, shared by the server and by C clients.
 *
 * Every frame starts with a 4-byte header (magic 'T', protocol version,
 * message type, flags) followed by little-endian fields. Encoders write into
 * a caller buffer of known capacity and refuse values the protocol forbids
 * (NaN/Inf floats, counts past 65535); decoders read a buffer of known length
 * and never read past it: a truncated frame, trailing bytes, a count larger
 * than the payload or lengths that do not add up are each refused with one of
 * the protocol's error codes (terrad_proto_err), never a crash or a guess.
 *
 * Heights travel as rectangles of int32: a delta rectangle carries new - old
 * (two's complement, wrapping), a snapshot rectangle the absolute heights;
 * either is zigzag-mapped to u32, packed little-endian row-major and
 * zstd-compressed as one frame with its content size in the header.
 * terrad_rect_compress / terrad_rect_decompress do that; terrad_mirror keeps
 * a client-side copy of a region and applies DELTA frames to it with the
 * version checks of the protocol.
 *
 * Depends on libc and libzstd only. Nothing here allocates except a
 * terrad_codec (and the one-off codec a NULL codec argument stands for).
 */
#ifndef TERRAD_PROTO_H
#define TERRAD_PROTO_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TERRAD_PROTO_VERSION 1
#define TERRAD_PROTO_MAGIC 0x54 /* 'T' */
#define TERRAD_PROTO_SUBPROTOCOL "terrad.v1"

/* Fixed sizes in bytes (PROTOCOL.md, "Binary frames"). */
#define TERRAD_HEADER_SIZE 4
#define TERRAD_POSE_BATCH_FIXED 10     /* header, u32 seq, u16 count */
#define TERRAD_POSE_SIZE 32            /* u32 id, 7 x f32 */
#define TERRAD_DELTA_FIXED 14          /* header, u64 tick, u16 count */
#define TERRAD_RECT_FIXED 25           /* i32 x, y, u16 w, h, u32 base, new, u8 enc, u32 len */
#define TERRAD_CONTACT_FIXED 14        /* header, u64 tick, u16 count */
#define TERRAD_CONTACT_SIZE 48         /* u32 id, i64 volume, u32 cells, 8 x f32 */
#define TERRAD_ACK_SIZE 16             /* header, u64 tick, u32 seq */
#define TERRAD_PING_SIZE 12            /* header, u64 nonce */
#define TERRAD_COLLIDERS_FIXED 14      /* header, u64 tick, u16 count */
#define TERRAD_COLLIDER_STATE_SIZE 48  /* u32 id, u8 owner, u8 shape, u16 0, 10 x f32 */
#define TERRAD_FOOTPRINTS_FIXED 14     /* header, u64 tick, u16 count */
#define TERRAD_FOOTPRINT_SIZE 24       /* u32 collider id, 5 x f32 */
#define TERRAD_FORCES_FIXED 14         /* header, u64 tick, u16 count */
#define TERRAD_FORCE_SIZE 48           /* u32 id, 10 x f32, u32 cells */
#define TERRAD_FORCE_HEIGHT_SIZE 8     /* f64 after each entry with TERRAD_FORCES_FLAG_HEIGHT */
#define TERRAD_FORCES_FLAG_HEIGHT 0x01 /* FORCES header flag: entries carry their height */
#define TERRAD_STEP_FIXED 16           /* header, u32 seq, u32 ticks, u16 count, u16 sets */
#define TERRAD_STEPPED_SIZE 20         /* header, u64 tick, u32 seq, u32 ticks */
#define TERRAD_CHECKSUM_FIXED 18       /* header, u64 tick, u32 subscription, u16 count */
#define TERRAD_TILE_SUM_SIZE 20        /* i32 tile x, i32 tile y, u32 version, u64 hash */
#define TERRAD_MAX_COUNT 65535         /* every count on the wire is a u16 */

/* COLLIDERS' grousers extension: the header flag, and its bytes after each entry */
#define TERRAD_COLLIDERS_FLAG_GROUSERS 0x01
#define TERRAD_COLLIDER_GROUSERS_SIZE 12 /* u16 count, u16 0, f32 height, thickness */

typedef enum terrad_msg_type {
    TERRAD_MSG_POSE_BATCH = 0x01, /* client -> server */
    TERRAD_MSG_PING = 0x02,       /* either way */
    TERRAD_MSG_PONG = 0x03,       /* either way */
    TERRAD_MSG_STEP = 0x04,       /* client -> server: a client-clocked world's ticks */
    TERRAD_MSG_DELTA = 0x10,      /* server -> client */
    TERRAD_MSG_CONTACT = 0x11,    /* server -> client */
    TERRAD_MSG_ACK = 0x12,        /* server -> client */
    TERRAD_MSG_COLLIDERS = 0x13,  /* server -> client */
    TERRAD_MSG_FOOTPRINTS = 0x14, /* server -> client */
    TERRAD_MSG_FORCES = 0x15,     /* server -> client */
    TERRAD_MSG_STEPPED = 0x16,    /* server -> client: a STEP's ticks are done and durable */
    TERRAD_MSG_CHECKSUM = 0x17,   /* server -> client: a subscription's tile hashes at a tick */
} terrad_msg_type;

/* Error codes: positive values are the protocol's (PROTOCOL.md, "Errors"),
 * sent in error messages; negative values are local to this library. */
typedef enum terrad_proto_err {
    TERRAD_OK = 0,
    TERRAD_E_BAD_FRAME = 1,
    TERRAD_E_UNKNOWN_TYPE = 2,
    TERRAD_E_BAD_VERSION = 3,
    TERRAD_E_TOO_LARGE = 4,
    TERRAD_E_BAD_VALUE = 5,
    TERRAD_E_UNKNOWN_COLLIDER = 6,
    TERRAD_E_NOT_OWNER = 7,
    TERRAD_E_LIMIT_COLLIDERS = 8,
    TERRAD_E_LIMIT_SUBSCRIPTIONS = 9,
    TERRAD_E_RATE_LIMITED = 10,
    TERRAD_E_OUTSIDE_WORLD = 11,
    TERRAD_E_BAD_JSON = 12,
    TERRAD_E_UNAUTHORIZED = 13,
    TERRAD_E_REFUSED_HEIGHT_LIMIT = 14,
    TERRAD_E_STORE_UNAVAILABLE = 15,
    TERRAD_E_BAD_COMPRESSION = 16,
    TERRAD_E_STALE_BASE = 17,
    TERRAD_E_UNSUPPORTED_COLLIDER = 18,
    TERRAD_E_UNKNOWN_SUBSCRIPTION = 19,
    TERRAD_E_SHUTTING_DOWN = 20,
    TERRAD_E_INTERNAL = 21,
    TERRAD_E_FORBIDDEN = 22, /* the token's role may not do this (a viewer creating a collider) */
    TERRAD_E_BUFFER_TOO_SMALL = -1, /* local: the caller's output buffer is too small */
    TERRAD_E_NO_MEMORY = -2,        /* local: an allocation failed */
} terrad_proto_err;

#define TERRAD_ERR_FIRST 1
#define TERRAD_ERR_LAST 22

/* "bad_frame" etc.; "ok" for 0; NULL for an unknown code. */
const char *terrad_err_name(int code);
/* The code for a name, or 0 when the name is unknown. */
int terrad_err_from_name(const char *name);
/* "POSE_BATCH" etc.; NULL for an unknown type byte. */
const char *terrad_msg_type_name(int type);

/* ---- header -------------------------------------------------------------- */

typedef struct terrad_header {
    uint8_t magic, version, type, flags;
} terrad_header;

/* Checks, in this order: length >= 4 (bad_frame), magic (bad_frame), version
 * (bad_version), type known (unknown_type), flags zero (bad_frame) but for
 * the flags defined: FORCES' TERRAD_FORCES_FLAG_HEIGHT, COLLIDERS'
 * TERRAD_COLLIDERS_FLAG_GROUSERS. */
int terrad_header_decode(const uint8_t *buf, size_t len, terrad_header *out);

/* ---- POSE_BATCH ---------------------------------------------------------- */

typedef struct terrad_pose {
    uint32_t id;
    float x, y, z;        /* metres, world frame */
    float qw, qx, qy, qz; /* orientation, body to world; |q| in [0.9, 1.1] */
} terrad_pose;

/* Size of a batch of count poses. */
size_t terrad_pose_batch_size(size_t count);
int terrad_pose_batch_encode(uint8_t *buf, size_t cap, size_t *len_out, uint32_t seq,
                             const terrad_pose *poses, size_t count);
/* A batch holding more than cap poses is refused with too_large. */
int terrad_pose_batch_decode(const uint8_t *buf, size_t len, uint32_t *seq_out, terrad_pose *poses,
                             size_t cap, size_t *count_out);

/* ---- DELTA --------------------------------------------------------------- */

typedef enum terrad_encoding {
    TERRAD_ENC_DELTA = 0,    /* new - old, zigzag, packed, zstd */
    TERRAD_ENC_SNAPSHOT = 1, /* absolute heights, zigzag, packed, zstd */
    /* heights less the scene's base terrain, predicted, zigzag, range-coded,
     * no zstd (PROTOCOL.md "Base snapshots"): only to a client whose hello asked */
    TERRAD_ENC_BASE = 2,
    /* heights less the base, each cell first placed against the bounds its
     * decoded neighbours and two slope limits set, range-coded (PROTOCOL.md
     * "Slope snapshots"): only to a client whose hello offered it */
    TERRAD_ENC_BASE_SLOPE = 3,
} terrad_encoding;

typedef struct terrad_rect {
    int32_t x, y;          /* first cell, world cell coordinates */
    uint16_t w, h;         /* cells, >= 1 */
    uint32_t base_version; /* delta: the tile version it applies to (>= 1); snapshot: 0 */
    uint32_t new_version;  /* the tile version after it (>= 1) */
    uint8_t encoding;      /* terrad_encoding */
    uint32_t data_len;     /* compressed bytes */
    const uint8_t *data;   /* encode: caller's bytes; decode: points into the frame */
} terrad_rect;

/* Checks one rectangle's fields (sizes, versions, encoding, extent within
 * int32): 0 or bad_value. */
int terrad_rect_check(const terrad_rect *r);
size_t terrad_delta_size(const terrad_rect *rects, size_t count);
int terrad_delta_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                        const terrad_rect *rects, size_t count);
/* Validates the whole frame (every rectangle, lengths adding up to exactly
 * len) before returning; rects[i].data point into buf. */
int terrad_delta_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, terrad_rect *rects,
                        size_t cap, size_t *count_out);

/* ---- CONTACT ------------------------------------------------------------- */

typedef struct terrad_contact {
    uint32_t id;            /* collider id */
    int64_t volume;         /* penetrating volume, height units x cells, >= 0 */
    uint32_t cells;         /* cells in contact */
    float area_m2;          /* contact area, m^2, >= 0 */
    float deepest[3];       /* deepest point, metres, world frame */
    float normal[3];        /* mean contact normal, unit (0,0,1 when no contact) */
    float support_height_m; /* terrain height under the collider's centre, metres */
} terrad_contact;

size_t terrad_contact_size(size_t count);
int terrad_contact_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                          const terrad_contact *contacts, size_t count);
int terrad_contact_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                          terrad_contact *contacts, size_t cap, size_t *count_out);

/* ---- COLLIDERS ----------------------------------------------------------- */

/* Whose collider an entry is, seen from the receiving client. */
typedef enum terrad_collider_owner {
    TERRAD_OWNER_OWN = 0,   /* created by the receiving client */
    TERRAD_OWNER_OTHER = 1, /* another client's */
    TERRAD_OWNER_DEMO = 2,  /* driven by the daemon itself (demo actors) */
} terrad_collider_owner;

/* Shape kinds as drawn; capsule and cylinder axes lie along the entry's y axis. */
typedef enum terrad_collider_kind {
    TERRAD_KIND_SPHERE = 0,   /* dims: radius, 0, 0 */
    TERRAD_KIND_BOX = 1,      /* dims: half extents x, y, z */
    TERRAD_KIND_CAPSULE = 2,  /* dims: radius, half_length, 0 */
    TERRAD_KIND_CYLINDER = 3, /* dims: radius, half_length, 0 (wheels too) */
    TERRAD_KIND_MESH = 4,     /* dims: half extents of the mesh's origin-centred bounding box */
} terrad_collider_kind;
#define TERRAD_KIND_LAST 4

typedef struct terrad_collider_state {
    uint32_t id;
    uint8_t owner; /* terrad_collider_owner */
    uint8_t kind;  /* terrad_collider_kind */
    float dims[3]; /* metres, >= 0, finite; see terrad_collider_kind */
    float p[3];    /* position, metres, world frame */
    float q[4];    /* qw, qx, qy, qz: entry axes to world axes, |q| in [0.9, 1.1] */
} terrad_collider_state;

size_t terrad_colliders_size(size_t count);
int terrad_colliders_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                            const terrad_collider_state *states, size_t count);
int terrad_colliders_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                            terrad_collider_state *states, size_t cap, size_t *count_out);
/*
 * The grousers extension (PROTOCOL.md "COLLIDERS"): a frame with the header
 * flag TERRAD_COLLIDERS_FLAG_GROUSERS carries after each 48-byte entry 12
 * bytes, the entry's grousers: u16 count (0: none), u16 reserved 0, f32
 * height and thickness (m). Lug 0 points along the entry's -z, lug k turned
 * 360 k / count degrees about its y (the axle), so the entry's q is the
 * lugs' phase. Sent only to a client whose subscription asked ("grousers":
 * true) and only when an entry has lugs, so a client that never asks never
 * sees the flag. terrad_colliders_decode reads both forms (the grousers
 * skipped); terrad_colliders_grousers reads the grousers of one (count 0
 * without the flag).
 */
#define TERRAD_GROUSERS_MAX 360
typedef struct terrad_collider_grousers {
    uint16_t count;    /* 0: none (all zero); 1..TERRAD_GROUSERS_MAX, on a cylinder only */
    float height_m;    /* count > 0: > 0 and <= the entry's radius */
    float thickness_m; /* count > 0: > 0 and <= the entry's radius */
} terrad_collider_grousers;

size_t terrad_colliders_grousers_size(size_t count);
int terrad_colliders_encode_grousers(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                                     const terrad_collider_state *states,
                                     const terrad_collider_grousers *grousers, size_t count);
int terrad_colliders_grousers(const uint8_t *buf, size_t len, terrad_collider_grousers *grousers,
                              size_t cap, size_t *count_out);

/* ---- FOOTPRINTS ---------------------------------------------------------- */

/* One footprint event of the decals model: where a collider pressed into the
 * ground this tick (the heights do not change). */
typedef struct terrad_footprint {
    uint32_t collider; /* collider id, as in COLLIDERS (demo actors >= 2^31) */
    float x, y;        /* centre of the pressed cells, metres, world frame */
    float yaw;         /* heading about z, radians, in [-TERRAD_FOOTPRINT_YAW_MAX, +] */
    float size_m;      /* side of a square with the pressed area, metres, > 0 */
    float strength_m;  /* deepest penetration, metres, > 0 */
} terrad_footprint;
/* pi rounded up to f32, so that every atan2 result in double survives the cast */
#define TERRAD_FOOTPRINT_YAW_MAX 3.1416f

size_t terrad_footprints_size(size_t count);
int terrad_footprints_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                             const terrad_footprint *events, size_t count);
int terrad_footprints_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                             terrad_footprint *events, size_t cap, size_t *count_out);

/* ---- FORCES -------------------------------------------------------------- */

/* The soil's push on one collider in one tick (worlds of the bekker model):
 * what a simulator applies to its body. */
typedef struct terrad_force {
    uint32_t id;         /* collider id */
    float force[3];      /* N, on the collider, world frame */
    float torque[3];     /* N m, about the collider's pose position */
    float sinkage_m;     /* below the undisturbed surface at its lowest point, >= 0 */
    float area_m2;       /* contact area, >= 0 */
    float patch_width_m; /* Bekker's b of its largest contact patch, >= 0 */
    float slip;          /* wheels (cylinders): 1 - v/(wR) driving, wR/v - 1 skidding; else 0 */
    uint32_t cells;      /* cells in contact */
} terrad_force;

size_t terrad_forces_size(size_t count);
int terrad_forces_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                         const terrad_force *forces, size_t count);
int terrad_forces_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, terrad_force *forces,
                         size_t cap, size_t *count_out);
/*
 * The height extension (PROTOCOL.md "FORCES"): a frame with the header flag
 * TERRAD_FORCES_FLAG_HEIGHT carries after each 48-byte entry an f64, the
 * collider's pose height (m) the tick deformed at — a load-driven collider's
 * height found by the server. Sent only for colliders created with
 * "forces_height": true, so a client that never asks never sees the flag.
 * terrad_forces_decode reads both forms (the heights skipped);
 * terrad_forces_heights reads the heights of one (count 0 without the flag).
 */
size_t terrad_forces_heights_size(size_t count);
int terrad_forces_encode_heights(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                                 const terrad_force *forces, const double *heights_m, size_t count);
int terrad_forces_heights(const uint8_t *buf, size_t len, double *heights_m, size_t cap,
                          size_t *count_out);

/* ---- STEP and STEPPED (client-clocked worlds) ------------------------------ */

/* A STEP's fixed fields (PROTOCOL.md "STEP"): the world ticks `ticks` times;
 * `sets` pose sets of `count` poses follow, tick-major: 0 sets holds every
 * collider where it is, 1 set poses them at the first tick and holds them
 * after, `ticks` sets pose them at every tick (set i at the step's tick i). */
typedef struct terrad_step_head {
    uint32_t seq;   /* the client's step number, echoed in ACK and STEPPED */
    uint32_t ticks; /* >= 1 */
    uint16_t count; /* poses per set */
    uint16_t sets;  /* 0, 1 or ticks */
} terrad_step_head;

size_t terrad_step_size(size_t count, size_t sets);
/* poses: sets * count of them. */
int terrad_step_encode(uint8_t *buf, size_t cap, size_t *len_out, const terrad_step_head *h,
                       const terrad_pose *poses);
/* Lengths first (bad_frame); *head_out is then filled whatever follows, so a
 * receiver can name the field: ticks 0 or sets not 0, 1 or ticks (bad_value),
 * more than cap poses (too_large), a pose not finite or far from unit length
 * (bad_value, *bad_pose_out its index; -1 otherwise). */
int terrad_step_decode(const uint8_t *buf, size_t len, terrad_step_head *head_out,
                       terrad_pose *poses, size_t cap, long *bad_pose_out);
/* STEPPED: the step `seq` of `ticks` ticks ended at tick `tick` (ticks >= 1). */
int terrad_stepped_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick, uint32_t seq,
                          uint32_t ticks);
int terrad_stepped_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, uint32_t *seq_out,
                          uint32_t *ticks_out);

/* ---- CHECKSUM (desync detection, PROTOCOL.md "CHECKSUM") ------------------ */

/* The hash of a rectangle of heights (PROTOCOL.md "Tile hash"): FNV-1a 64 over
 * the heights as u32 words, row-major: h = 0xcbf29ce484222325, then for each
 * height h = (h ^ (uint32_t)height) * 0x100000001b3 (mod 2^64). Each step is a
 * bijection of h, so a change of any one height always changes the hash. */
#define TERRAD_HASH_SEED 0xcbf29ce484222325ull
#define TERRAD_HASH_PRIME 0x100000001b3ull
/* w x h heights whose rows are stride heights apart. */
uint64_t terrad_heights_hash(const int32_t *heights, size_t stride, uint32_t w, uint32_t h);

/* One tile of a subscription: its version and the hash of its part of the
 * subscription (tile ∩ subscription) at the frame's tick. */
typedef struct terrad_tile_sum {
    int32_t tile_x, tile_y; /* tile coordinates (cells / tile_size), >= 0 */
    uint32_t version;       /* >= 1 */
    uint64_t hash;          /* terrad_heights_hash of the tile's part */
} terrad_tile_sum;

size_t terrad_checksum_size(size_t count);
int terrad_checksum_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick,
                           uint32_t subscription, const terrad_tile_sum *sums, size_t count);
/* subscription 0, a negative tile coordinate or version 0: bad_value. */
int terrad_checksum_decode(const uint8_t *buf, size_t len, uint64_t *tick_out,
                           uint32_t *subscription_out, terrad_tile_sum *sums, size_t cap,
                           size_t *count_out);

/* ---- ACK, PING, PONG ----------------------------------------------------- */

int terrad_ack_encode(uint8_t *buf, size_t cap, size_t *len_out, uint64_t tick, uint32_t seq);
int terrad_ack_decode(const uint8_t *buf, size_t len, uint64_t *tick_out, uint32_t *seq_out);
/* type is TERRAD_MSG_PING or TERRAD_MSG_PONG. */
int terrad_ping_encode(uint8_t *buf, size_t cap, size_t *len_out, uint8_t type, uint64_t nonce);
/* Accepts either PING or PONG; *type_out says which. */
int terrad_ping_decode(const uint8_t *buf, size_t len, uint8_t *type_out, uint64_t *nonce_out);

/* ---- rectangle payloads -------------------------------------------------- */

uint32_t terrad_zigzag32(int32_t v);
int32_t terrad_unzigzag32(uint32_t u);
/* out[i] = new[i] - old[i], wrapping modulo 2^32 (exact for any int32 pair). */
void terrad_rect_diff(const int32_t *old_h, const int32_t *new_h, size_t cells, int32_t *out);
/* Zigzag and pack as little-endian u32: out holds 4 * cells bytes. */
void terrad_rect_pack(const int32_t *values, size_t cells, uint8_t *out);
void terrad_rect_unpack(const uint8_t *in, size_t cells, int32_t *out);

/* Reusable zstd contexts and packing scratch; every function taking one
 * accepts NULL and then makes a one-off context. Not thread-safe: one per
 * thread. */
typedef struct terrad_codec terrad_codec;
terrad_codec *terrad_codec_new(int level); /* level <= 0: 3 */
void terrad_codec_free(terrad_codec *c);

/* Largest compressed size of a rectangle of cells. */
size_t terrad_rect_compress_bound(size_t cells);
/* Pack and compress cells values (zstd level of the codec, 3 for NULL) as
 * one zstd frame with its content size. */
int terrad_rect_compress(terrad_codec *c, const int32_t *values, size_t cells, uint8_t *out,
                         size_t cap, size_t *len_out);
/* Decompress a rectangle of cells values into out (out_cap values). Refuses
 * cells > out_cap (too_large) and, with bad_compression, anything but exactly
 * one zstd frame whose declared and actual content size are 4 * cells. */
int terrad_rect_decompress(terrad_codec *c, const uint8_t *data, size_t len, size_t cells,
                           int32_t *out, size_t out_cap);

/* ---- base snapshots (terrad_proto_base.c; PROTOCOL.md "Base snapshots") ----
 * A rectangle's heights less the scene's base terrain, d = h - base (wrapping),
 * each cell predicted from its decoded neighbours (left + up - up-left; the
 * first row from the left, the first column from above, the first cell 0),
 * and the residual d - p (wrapping, zigzagged) coded with an adaptive binary
 * range coder whose context is the size of the neighbours' residuals. Exact
 * for any int32 heights; no zstd. */
size_t terrad_rect_compress_base_bound(size_t cells);
/* diff: w * h values h - base; too_large for an empty or huge rectangle,
 * buffer_too_small when cap is less than the bound. */
int terrad_rect_compress_base(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out, size_t cap,
                              size_t *len_out);
/* Back to w * h values h - base in out (out_cap values: too_large past it);
 * bad_compression for a payload that ends before the last cell or a value
 * past 2^32. */
int terrad_rect_decompress_base(const uint8_t *data, size_t len, uint32_t w, uint32_t h,
                                int32_t *out, size_t out_cap);
/* Slope snapshots (encoding 3, PROTOCOL.md "Slope snapshots"): the same
 * differences h - base, each cell coded as at its upper or lower bound (the
 * decoded left, upper, upper-left and upper-right neighbours plus the axial
 * limit a or the diagonal limit b), or else as encoding 2's residual against
 * its prediction clamped into the bounds. Exact for any int32 values and any
 * a, b. _ab codes with the given limits; terrad_rect_compress_slope picks them
 * (the most common neighbour differences); _smaller codes both encodings 2
 * and 3 and keeps the shorter, saying which in *encoding_out. Errors as for
 * encoding 2; a slope payload shorter than 13 bytes, or decoding a value out
 * of int32, is bad_compression. */
size_t terrad_rect_compress_slope_bound(size_t cells);
int terrad_rect_compress_slope_ab(const int32_t *diff, uint32_t w, uint32_t h, uint32_t a,
                                  uint32_t b, uint8_t *out, size_t cap, size_t *len_out);
int terrad_rect_compress_slope(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out,
                               size_t cap, size_t *len_out);
int terrad_rect_compress_base_smaller(const int32_t *diff, uint32_t w, uint32_t h, uint8_t *out,
                                      size_t cap, size_t *len_out, uint8_t *encoding_out);
int terrad_rect_decompress_slope(const uint8_t *data, size_t len, uint32_t w, uint32_t h,
                                 int32_t *out, size_t out_cap);
/* A base rectangle's decoded differences onto heights covering the region
 * (hx, hy, hw, hh), clipped: heights = base + diff, base over the region.
 * Returns the number of cells set. */
size_t terrad_rect_apply_base(const terrad_rect *r, const int32_t *diff, const int32_t *base,
                              int32_t *heights, int32_t hx, int32_t hy, uint32_t hw, uint32_t hh);

/* Apply decoded rectangle values to a heights array covering the region
 * (hx, hy, hw, hh), clipped to it: snapshot values replace heights, delta
 * values are added (wrapping). Returns the number of cells touched. */
size_t terrad_rect_apply_values(const terrad_rect *r, const int32_t *values, int32_t *heights,
                                int32_t hx, int32_t hy, uint32_t hw, uint32_t hh);

/* ---- client-side mirror -------------------------------------------------- */

/* A client's copy of one region with a version per tile (PROTOCOL.md,
 * "Versions"). Version 0 means "not held yet": deltas for that tile are
 * skipped until a snapshot of the tile's whole part of the region arrives. */
typedef struct terrad_mirror {
    int32_t x, y; /* region, world cells */
    uint32_t w, h;
    uint32_t tile_size; /* from the world message */
    int32_t *heights;   /* w * h, row-major, caller's memory */
    uint32_t *versions; /* terrad_mirror_tile_count(), caller's memory */
    int64_t tx0, ty0;   /* first tile column and row (computed) */
    uint32_t tiles_x, tiles_y;
    /* The scene's base terrain over the region (w * h, caller's memory), for
     * base and slope snapshot rectangles (TERRAD_ENC_BASE, _BASE_SLOPE); NULL (terrad_mirror_init):
     * such a rectangle is refused with bad_value. */
    const int32_t *base;
} terrad_mirror;

/* Tiles touching the region, or 0 for an empty region or tile_size 0. */
size_t terrad_mirror_tile_count(int32_t x, int32_t y, uint32_t w, uint32_t h, uint32_t tile_size);
/* Set up m over caller arrays; versions are zeroed, heights left alone. */
int terrad_mirror_init(terrad_mirror *m, int32_t x, int32_t y, uint32_t w, uint32_t h,
                       uint32_t tile_size, int32_t *heights, uint32_t *versions);
/* Apply the rectangles of one DELTA frame (as terrad_delta_decode gives
 * them). First every rectangle is checked: each must lie within one tile
 * (bad_value); a delta rectangle for a held tile whose base_version differs
 * from the held version fails the whole frame with stale_base and changes
 * nothing (the client should resync). Then the rectangles are applied:
 * snapshot rectangles covering the tile's whole part of the region set the
 * tile's version (partial ones are ignored), delta rectangles for held tiles
 * are added. scratch holds scratch_cells int32 (at least the largest
 * rectangle). If decompression fails part way, every version is reset to 0
 * and the error returned: resync. */
int terrad_mirror_apply(terrad_mirror *m, terrad_codec *c, const terrad_rect *rects, size_t count,
                        int32_t *scratch, size_t scratch_cells);
/* One CHECKSUM entry against the mirror: 1 when the mirror holds the tile
 * (version != 0) and its version or the hash of its part of the region
 * differs (a desync: ask for the tile), 0 when it agrees or the tile is not
 * held (its snapshot is on its way), -1 when the region does not touch it. */
int terrad_mirror_tile_differs(const terrad_mirror *m, const terrad_tile_sum *sum);

#ifdef __cplusplus
}
#endif

#endif /* TERRAD_PROTO_H */
