/*
 * gl_internal.h: what the files of server/gl/ share and nobody else sees —
 * the GL and EGL entry points (libepoxy), the shader loader, and the GL
 * backend's state and parts, one file per concern (backend.c has the map):
 *
 *   backend.c     the backend table, a batch in chunks, each chunk's upload
 *                 and readback
 *   buffers.c     per-cell buffers, batch table, status flags; small helpers
 *   depth.c       the depth stage: fixed-point instances, depth_exact.comp
 *   stages.c      the integer stages' dispatches (classify .. even_slopes)
 *   tile_cache.c  the GPU tile cache
 */
#ifndef TERRAD_GL_INTERNAL_H
#define TERRAD_GL_INTERNAL_H

#include <epoxy/egl.h>
#include <epoxy/gl.h>

#include "gl/gl.h"

/* Make c current on the calling thread if it is not already. */
int gl_context_make_current(gl_context *c, error_text *err);
/* Let go of c on this thread, so that another thread can make it current. */
void gl_context_release(gl_context *c);

/*
 * Programs from the embedded shaders/ files ("shaders/classify.comp"). A
 * line `#include "NAME"` is replaced by the embedded file "shaders/NAME".
 * On failure the file name and the driver's info log are logged, err names
 * the file, and 0 is returned.
 */
GLuint gl_program_compute(const char *name, error_text *err);

/* ---- The GL backend's state ---- */

/* Per-cell buffers. The stage scratch S0..S3 is reused across stages:
 * single/multi: S0 = received low words, S1 = high words;
 * iterative: S0/S2 = mask words, S1/S3 = shares (ping-pong pairs);
 * slope evening: S0 is the other half of the heights ping-pong. */
enum {
    BUF_HEIGHTS,
    BUF_BOTTOM,
    BUF_MOVED,
    BUF_CLS,
    BUF_SEED_A,
    BUF_SEED_B,
    BUF_S0,
    BUF_S1,
    BUF_S2,
    BUF_S3,
    /* the uploaded heights, kept for dirty_rect.comp; then the staging of
     * the dirty rows read back (chunk_readback) */
    BUF_ORIGINAL,
    BUF_COUNT
};

enum {
    PROG_CLASSIFY,
    PROG_JUMP_FLOOD,
    PROG_DISPLACE_SSBO,
    PROG_DISPLACE_MULTI,
    PROG_DISPLACE_LAND,
    PROG_ITER_INIT,
    PROG_ITER_PASS,
    PROG_ITER_DEAD_END,
    PROG_ITER_FINISH,
    PROG_EVEN_SLOPES,
    PROG_DEPTH_CLEAR,
    PROG_DEPTH_EXACT,
    PROG_TILE_LIST,
    PROG_DIRTY_RECT,
    PROG_COUNT
};

/* Uniforms, looked up once per program (-1 where a program has none). */
enum {
    U_TILE_COUNT,
    U_WINDOW_COUNT,
    U_METRIC,
    U_OBSTACLE_GAP,
    U_MULTI_STEP,
    U_MULTI_MAX,
    U_FLOOR,
    U_STEP,
    U_MATERIALS_ON,
    U_MATERIAL_COUNT,
    U_MATERIAL_ROWS,
    U_MATERIAL_MAX,
    U_LIST_ROW,
    U_SPARSE,
    U_STAMP,
    U_LIST_KIND,
    U_COUNT
};

/* One window of the batch table (WINDOW_INTS ints in common.glsl); the
 * table continues with TILE_INTS ints per 8x8 tile: window index, corner
 * x | y << 16, the window's offset, w | h << 16. */
#define TILE_INTS 4
/* A compacted tile list is dispatched indirectly as rows of this many
 * groups: whoever appends slot s raises the row count to s / 64 + 1
 * (atomicMax), so no pass is needed to turn a count into groups, and a row
 * overhangs the list by at most 63 groups, which return at once. */
#define TILE_LIST_ROW 64
/* Words per window in the status buffer: the status flags at [i], then from
 * [count + 4 i] the window's dirty rectangle (min x, min y, max x, max y of
 * the cells whose heights differ from the uploaded ones; min > max: none). */
#define STATUS_WORDS 5
typedef struct window_entry {
    int32_t offset;
    int32_t x, y;
    int32_t w, h;
    int32_t cast_depth; /* 1: the depth stage computes its bottoms, 0: uploaded */
    int32_t pad0, pad1;
} window_entry;

typedef struct gl_backend {
    sim_backend base;
    gl_context *context;
    GLuint programs[PROG_COUNT];
    GLint uniforms[PROG_COUNT][U_COUNT];
    int stage_timing;

    /* limits of this driver */
    GLint max_texture_size;
    GLint max_groups_x;
    int64_t max_chunk_cells;

    /* per-cell buffers, capacity in cells, and a buffer texture on each */
    GLuint buffers[BUF_COUNT];
    GLuint textures[BUF_COUNT];
    int64_t cell_capacity;
    /* batch table (windows, then tiles; capacity in bytes) and status flags
     * (capacity in windows) */
    GLuint table_buffer, table_texture, status_buffer;
    int64_t table_capacity;
    /* jump flooding's compacted tile list (tile_list.comp): a count, the
     * indirect dispatch's 3 group counts, then tile indices; capacity in tiles */
    GLuint tile_list_buffer;
    int64_t tile_list_capacity;
    /* slope evening's next tile list (the same layout; the first list is
     * tile_list_buffer, free by then) and a mark per tile (gl_stage_even_slopes) */
    GLuint tile_next_buffer, tile_mark_buffer;
    int window_capacity;
    window_entry *entries;
    uint32_t *status_host; /* STATUS_WORDS per window */
    int64_t status_host_capacity;
    int64_t host_capacity;
    int32_t *tiles;
    int64_t tile_capacity;
    /* the chunk being run */
    int64_t tile_count;
    int window_count;

    /* fixed-point depth instances (depth_exact.comp), built on the CPU */
    GLuint exact_buffer;
    int64_t exact_buffer_bytes;
    collider_fixed *exact_host;
    int64_t exact_host_capacity;

    /* Per-cell material words (id | compaction << 8), only created and grown
     * when a batch carries materials: uniform scenes never allocate them. */
    GLuint material_buffer, material_texture;
    int64_t material_capacity;
    int32_t *material_host;
    struct tile_cache *cache;
    thread_owner owner; /* the thread that runs the batches (the sim thread) */
} gl_backend;

/* ---- GPU tile cache: state (tile_cache.c) ---- */

#define TILE_CACHE_LAYERS_DEFAULT 64
#define TILE_CACHE_BUDGET_DEFAULT ((int64_t)4 << 20)
/* Larger tiles (a whole world as one tile) are not cached: one layer each
 * would be too big to upload within any budget. */
#define TILE_CACHE_SIDE_MAX 1024

typedef struct cache_layer {
    int used, tx, ty;
    uint64_t generation; /* world_tile_generation of the copy held */
    uint64_t last_use;   /* tick that last needed it: not evicted within that tick */
    uint64_t stale_tick; /* tick in which a CPU-only write made it stale */
} cache_layer;

typedef struct tile_cache {
    int layers_max;       /* configured capacity, 0 = off */
    int64_t budget_bytes; /* per tick */
    GLuint texture;
    int layers, side, shift; /* the texture: layers of side x side */
    uint64_t serial;         /* world_base_serial of the tiles held */
    int active;              /* on for the tick being run */
    cache_layer *layer;
    uint64_t tick;
    int64_t budget_left;
    unsigned char *from_cache; /* per window of the tick: gathered from the cache */
    int64_t from_cache_capacity;
    int64_t table_used; /* entries of table filled this tick */
    int32_t *table;     /* layers per tile of each window of the chunk */
    int64_t table_capacity;
    int64_t *table_base; /* per window of the tick: its layers in table, or -1 */
    int64_t table_base_capacity;
    GLuint table_buffer;
    int64_t table_buffer_capacity;
    int32_t *staging; /* one tile */
    GLuint gather, scatter;
    GLint gather_u[7], scatter_u[7];
    sim_tile_cache_stats stats;
} tile_cache;

/* ---- buffers.c ---- */

/* A barrier after every pass: SSBO writes, buffer updates, texture fetches. */
void gl_barrier(void);
/* The process's GL synchronisation counters (sim.h sim_gpu_sync_stats): the
 * GL context lives on one thread, so plain counters; every glDispatchCompute,
 * glDraw*, glMemoryBarrier, glGetBufferSubData and glFinish of gl/ adds to
 * them. */
extern sim_gpu_sync_stats gl_sync;
void gl_gpu_sync_stats(const sim_backend *b, sim_gpu_sync_stats *out);
/* 0, or -1 with err naming what failed (out of GPU memory, a GL error). */
int gl_check(const char *what, error_text *err);
/* A per-cell buffer as a storage block (written) or a buffer texture (read). */
void gl_bind(gl_backend *b, int binding, int buffer);
void gl_sample(gl_backend *b, int unit, int buffer);
/* One 8x8 workgroup per tile of the chunk, then a barrier. */
void gl_dispatch(gl_backend *b, int prog);
/* The same over the groups an earlier pass wrote into `buffer` at byte
 * `offset` (glDispatchComputeIndirect), then a barrier. */
void gl_dispatch_indirect(gl_backend *b, int prog, GLuint buffer, GLintptr offset);
/* Ends a stage: adds the time since `since` to *acc (after glFinish with
 * stage timing on); returns now. */
double gl_stage_end(gl_backend *b, double *acc, double since);
uint64_t gl_scratch_bytes(const sim_backend *base);
int gl_ensure_cells(gl_backend *b, int64_t cells, error_text *err);
int gl_ensure_materials(gl_backend *b, int64_t cells, error_text *err);
int gl_ensure_windows(gl_backend *b, int count, error_text *err);
int gl_ensure_table(gl_backend *b, int window_count, int64_t tiles, error_text *err);

/* ---- depth.c ---- */

/* The bottoms of the windows with cast_depth, from their colliders. */
int gl_depth_run(gl_backend *b, sim_window_job *jobs, int count, error_text *err);
void gl_forget_geometry(sim_backend *base, const collider_geometry *g);
/* The depth stage's GL objects and host copies (context current). */
void gl_depth_delete(gl_backend *b);

/* ---- stages.c ---- */

void gl_stages_set_params(gl_backend *b, const sim_params *p, const ground_material_table *t);
void gl_stage_classify(gl_backend *b, int materials);
/* These return the buffer (BUF_*) holding their result. */
int gl_stage_jump_flood(gl_backend *b, int max_side, int64_t cells);
/* Each window's dirty rectangle into the status buffer (dirty_rect.comp). */
void gl_stage_dirty_rects(gl_backend *b, int heights);
void gl_stage_displace(gl_backend *b, const sim_params *p, int64_t cells, int seed);
int gl_stage_even_slopes(gl_backend *b, const sim_params *p, int materials, int64_t cells);

/* ---- tile_cache.c ---- */

/* The cache with its defaults (or TERRAD_GL_TILE_CACHE); NULL with err set. */
tile_cache *gl_cache_create(error_text *err);
/* Its programs and uniforms, once the context is current. */
int gl_cache_load_programs(tile_cache *c, error_text *err);
void gl_cache_free(tile_cache *c);
void gl_cache_delete_gl(tile_cache *c);
int gl_cache_begin_tick(gl_backend *b, const sim_window_job *jobs, int count, error_text *err);
int gl_cache_plan_chunk(gl_backend *b, const sim_window_job *jobs, int count, int first,
                        error_text *err);
void gl_cache_gather(gl_backend *b, const sim_window_job *job, int32_t offset, int64_t table_base);
void gl_cache_scatter(gl_backend *b, const sim_window_job *job, int32_t offset, int64_t table_base,
                      int heights);
void gl_window_scattered(sim_backend *base, int window, const world *w, world_rect r);
void gl_tile_cache_stats(const sim_backend *base, sim_tile_cache_stats *out);

#endif
