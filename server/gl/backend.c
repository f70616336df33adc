/*
 * backend.c: the GL backend of the deformation pipeline (sim.h). It runs all
 * windows of a tick as one batch, with one draw per collider and one compute
 * dispatch per stage (per step or iteration) for the whole batch:
 *
 *   upload      heights (and uploaded bottoms) into flat per-cell buffers
 *   depth       colliders rasterised into a depth atlas, then depth → bottom
 *   classify    classify.comp (also heights -= raw, jump-flood init)
 *   jump_flood  jump_flood.comp, once per step size, ping-pong
 *   displace    displace_ssbo/multi.comp + displace_land.comp, or
 *               displace_iterative_init/pass.../finish.comp
 *   even_slopes even_slopes.comp per iteration, ping-pong
 *   readback    window status flags, then the heights of accepted windows
 *
 * Layout: window i of the batch owns cells [offset_i, offset_i + w_i*h_i)
 * of every per-cell buffer, row-major. A batch table lists the windows
 * (offset, corner, size, atlas slot, depth range) and then every 8x8 tile of
 * every window; a dispatch runs one workgroup per tile, so an invocation
 * finds its window and cell from one fetch (common.glsl). Passes read
 * through buffer textures and write through storage buffers, with a
 * glMemoryBarrier after every pass. Buffers grow by doubling to the largest
 * batch seen, so scratch memory follows active cells, never the world's
 * size; a batch larger than one storage block allows runs in chunks.
 *
 * The depth atlas is one GL_DEPTH_COMPONENT32F texture; windows are packed
 * into it by shelves (tallest first). If a batch does not fit the largest
 * texture, it is rasterised in several rounds, each converted to bottoms
 * before the next clears the atlas.
 *
 * Stage times: with stage timing on, glFinish ends every stage, so each
 * time is the GPU's. Off, a stage's time is only what it took to submit,
 * and the wait for the GPU lands in "transfer" with the readback.
 *
 * Everything after depth is integer-only and mirrors sim_stages.c exactly
 * (tests/unit/test_gl.c checks bit-equality with the CPU twin).
 *
 * GPU tile cache (after the large-terrain paper's block cache: blocks in an
 * array texture, a pointer table, an upload budget per frame): world tiles
 * live in one R32I GL_TEXTURE_2D_ARRAY, a layer per tile, keyed by tile
 * coordinates and the world's tile generation, LRU-evicted. At upload a
 * window whose tiles are all resident and current (uploading stale or
 * missing ones while the tick's byte budget lasts) is copied out of them by
 * tile_gather.comp through a per-window table of layers; after readback every
 * accepted window is written by tile_scatter.comp into those of its tiles
 * that were current when the tick began, and when the engine
 * scatters the same ints into the CPU world (window_scattered) the tiles'
 * generations are brought up to date. Everything else is uploaded from the
 * CPU copy as before, so a full, tiny or missing cache changes speed only.
 */
#include "gl/gl_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
    PROG_ITER_FINISH,
    PROG_EVEN_SLOPES,
    PROG_DEPTH_TO_BOTTOM,
    PROG_COMPUTE_COUNT,
    PROG_RASTER = PROG_COMPUTE_COUNT,
    PROG_COUNT
};

static const char *const compute_names[PROG_COMPUTE_COUNT] = {
    "shaders/classify.comp",
    "shaders/jump_flood.comp",
    "shaders/displace_ssbo.comp",
    "shaders/displace_multi.comp",
    "shaders/displace_land.comp",
    "shaders/displace_iterative_init.comp",
    "shaders/displace_iterative_pass.comp",
    "shaders/displace_iterative_finish.comp",
    "shaders/even_slopes.comp",
    "shaders/depth_to_bottom.comp",
};

/* Uniforms, looked up once per program (-1 where a program has none). */
enum {
    U_TILE_COUNT,
    U_WINDOW_COUNT,
    U_METRIC,
    U_COMPRESSION,
    U_ROUGHNESS,
    U_THRESHOLD_AXIAL,
    U_THRESHOLD_DIAGONAL,
    U_OBSTACLE_GAP,
    U_MULTI_STEP,
    U_MULTI_MAX,
    U_FLOOR,
    U_STEP,
    U_ROUND,
    U_MVP,
    U_MATERIALS_ON,
    U_MATERIAL_COUNT,
    U_MATERIAL_ROWS,
    U_MATERIAL_MAX,
    U_COUNT
};

static const char *const uniform_names[U_COUNT] = {
    "u_tile_count",
    "u_window_count",
    "u_metric",
    "u_compression_q16",
    "u_roughness_q16",
    "u_slope_threshold_axial",
    "u_slope_threshold_diagonal",
    "u_obstacle_gap",
    "u_multi_target_step",
    "u_multi_target_max",
    "u_floor",
    "u_step",
    "u_round",
    "u_mvp",
    "u_materials_on",
    "u_material_count",
    "u_material_rows",
    "u_material_max_compaction",
};

/* One window of the batch table (WINDOW_INTS ints in common.glsl); the
 * table continues with TILE_INTS ints per 8x8 tile: window index, corner
 * x | y << 16, the window's offset, w | h << 16. */
#define TILE_INTS 4
typedef struct window_entry {
    int32_t offset;
    int32_t x, y;
    int32_t w, h;
    int32_t slot_x, slot_y;
    int32_t raster_round; /* atlas round + 1, or 0: bottom uploaded */
    int32_t depth_low, depth_high;
    int32_t pad0, pad1;
} window_entry;

/* A collider geometry's triangles, uploaded once and cached by pointer. */
typedef struct geometry_entry {
    const collider_geometry *geometry;
    GLuint vao, vbo, ebo;
    GLsizei index_count;
} geometry_entry;

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
    int window_capacity;
    window_entry *entries;
    uint32_t *status_host;
    int *order;
    int host_capacity;
    int32_t *tiles;
    int64_t tile_capacity;
    /* the chunk being run */
    int64_t tile_count;
    int window_count;

    /* depth atlas */
    GLuint atlas, fbo;
    int atlas_w, atlas_h;

    geometry_entry *geometries;
    int geometry_count, geometry_capacity;

    /* Per-cell material words (id | compaction << 8), only created and grown
     * when a batch carries materials: uniform scenes never allocate them. */
    GLuint material_buffer, material_texture;
    int64_t material_capacity;
    int32_t *material_host;
    struct tile_cache *cache;
} gl_backend;

/* ---- GPU tile cache: state ---- */

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
    int from_cache_capacity;
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

static const char *const cache_uniform_names[7] = {
    "u_origin", "u_size", "u_offset", "u_shift", "u_first_tile", "u_tiles_x", "u_layer_base",
};

/* ---- small helpers ---- */

static void barrier(void)
{
    /* Every pass reads what the previous one wrote through SSBOs, and buffer
     * clears and readbacks follow shader writes: the GL requires an explicit
     * barrier for both (the original implementation omitted it). */
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT |
                    GL_TEXTURE_FETCH_BARRIER_BIT);
}

static int check_gl(const char *what, error_text *err)
{
    GLenum e = glGetError();
    if (e == GL_NO_ERROR)
        return 0;
    if (e == GL_OUT_OF_MEMORY)
        error_set(err, "gl backend: out of GPU memory (%s)", what);
    else
        error_set(err, "gl backend: GL error 0x%04x (%s)", (unsigned)e, what);
    return -1;
}

/* A per-cell buffer as a shader storage block (what a pass writes). */
static void bind(gl_backend *b, int binding, int buffer)
{
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, (GLuint)binding, b->buffers[buffer]);
}

/* A per-cell buffer as a buffer texture on a sampler unit (what a pass only
 * reads: see common.glsl for why reads and writes take different paths). */
static void sample(gl_backend *b, int unit, int buffer)
{
    glActiveTexture(GL_TEXTURE0 + (GLenum)unit);
    glBindTexture(GL_TEXTURE_BUFFER, b->textures[buffer]);
}

/* One 8x8 workgroup per tile of the chunk, in a 2D grid so that more than
 * 65535 tiles fit; the shader maps its group to a tile (common.glsl). */
static void dispatch(gl_backend *b, int prog)
{
    glUseProgram(b->programs[prog]);
    glUniform1i(b->uniforms[prog][U_TILE_COUNT], (GLint)b->tile_count);
    glUniform1i(b->uniforms[prog][U_WINDOW_COUNT], b->window_count);
    int64_t groups = b->tile_count;
    int64_t gx = groups < b->max_groups_x ? groups : b->max_groups_x;
    int64_t gy = (groups + gx - 1) / gx;
    glDispatchCompute((GLuint)gx, (GLuint)gy, 1);
    barrier();
}

/* Ends a stage: with stage timing on, waits for the GPU so the time is real. */
static double stage_end(gl_backend *b, double *acc, double since)
{
    if (b->stage_timing)
        glFinish();
    double now = time_now_ms();
    *acc += now - since;
    return now;
}

/* ---- buffers ---- */

static uint64_t texture_bytes(const gl_backend *b)
{
    return (uint64_t)b->atlas_w * (uint64_t)b->atlas_h * 4u;
}

static uint64_t gl_scratch_bytes(const sim_backend *base)
{
    const gl_backend *b = (const gl_backend *)base;
    uint64_t bytes = (uint64_t)b->cell_capacity * BUF_COUNT * sizeof(int32_t);
    bytes += (uint64_t)b->material_capacity * 2 * sizeof(int32_t); /* GPU and host copies */
    bytes += (uint64_t)b->table_capacity + (uint64_t)b->window_capacity * sizeof(uint32_t);
    return bytes + texture_bytes(b);
}

static int ensure_cells(gl_backend *b, int64_t cells, error_text *err)
{
    if (cells <= b->cell_capacity)
        return 0;
    int64_t cap = b->cell_capacity ? b->cell_capacity : 4096;
    while (cap < cells)
        cap *= 2;
    if (cap > b->max_chunk_cells)
        cap = b->max_chunk_cells;
    /* Contents never live from one batch to the next: replace, don't copy. */
    for (int i = 0; i < BUF_COUNT; i++) {
        glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[i]);
        glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(cap * 4), NULL, GL_DYNAMIC_COPY);
        glBindTexture(GL_TEXTURE_BUFFER, b->textures[i]);
        glTexBuffer(GL_TEXTURE_BUFFER, GL_R32I, b->buffers[i]);
    }
    glBindTexture(GL_TEXTURE_BUFFER, 0);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    if (check_gl("growing the cell buffers", err) != 0) {
        b->cell_capacity = 0;
        return -1;
    }
    b->cell_capacity = cap;
    return 0;
}

static int ensure_materials(gl_backend *b, int64_t cells, error_text *err)
{
    if (cells <= b->material_capacity)
        return 0;
    int64_t cap = b->material_capacity ? b->material_capacity : 4096;
    while (cap < cells)
        cap *= 2;
    int32_t *host = realloc(b->material_host, (size_t)cap * sizeof *host);
    if (!host) {
        error_set(err, "gl backend: out of memory for %lld material words", (long long)cap);
        return -1;
    }
    b->material_host = host;
    if (!b->material_buffer) {
        glGenBuffers(1, &b->material_buffer);
        glGenTextures(1, &b->material_texture);
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->material_buffer);
    glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(cap * 4), NULL, GL_DYNAMIC_COPY);
    glBindTexture(GL_TEXTURE_BUFFER, b->material_texture);
    glTexBuffer(GL_TEXTURE_BUFFER, GL_R32I, b->material_buffer);
    glBindTexture(GL_TEXTURE_BUFFER, 0);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    if (check_gl("growing the material buffer", err) != 0) {
        b->material_capacity = 0;
        return -1;
    }
    b->material_capacity = cap;
    return 0;
}

static int ensure_windows(gl_backend *b, int count, error_text *err)
{
    if (count > b->host_capacity) {
        int cap = b->host_capacity ? b->host_capacity : 16;
        while (cap < count)
            cap *= 2;
        window_entry *e = realloc(b->entries, (size_t)cap * sizeof *e);
        if (e)
            b->entries = e;
        uint32_t *s = realloc(b->status_host, (size_t)cap * sizeof *s);
        if (s)
            b->status_host = s;
        int *o = realloc(b->order, (size_t)cap * sizeof *o);
        if (o)
            b->order = o;
        if (!e || !s || !o) {
            error_set(err, "gl backend: out of memory for %d windows", count);
            return -1;
        }
        b->host_capacity = cap;
    }
    if (count <= b->window_capacity)
        return 0;
    int cap = b->window_capacity ? b->window_capacity : 16;
    while (cap < count)
        cap *= 2;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)((size_t)cap * sizeof(uint32_t)), NULL,
                 GL_DYNAMIC_READ);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    if (check_gl("growing the window status buffer", err) != 0)
        return -1;
    b->window_capacity = cap;
    return 0;
}

/* The batch table: windows then tiles, host copy and GPU buffer. */
static int ensure_table(gl_backend *b, int window_count, int64_t tiles, error_text *err)
{
    int64_t ints = (int64_t)window_count * (int64_t)(sizeof(window_entry) / 4) + TILE_INTS * tiles;
    if (TILE_INTS * tiles > b->tile_capacity) {
        int64_t cap = b->tile_capacity ? b->tile_capacity : 1024;
        while (cap < TILE_INTS * tiles)
            cap *= 2;
        int32_t *t = realloc(b->tiles, (size_t)cap * sizeof *t);
        if (!t) {
            error_set(err, "gl backend: out of memory for %lld tiles", (long long)tiles);
            return -1;
        }
        b->tiles = t;
        b->tile_capacity = cap;
    }
    if (ints * 4 <= b->table_capacity)
        return 0;
    int64_t cap = b->table_capacity ? b->table_capacity : 16384;
    while (cap < ints * 4)
        cap *= 2;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->table_buffer);
    glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)cap, NULL, GL_DYNAMIC_DRAW);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    glBindTexture(GL_TEXTURE_BUFFER, b->table_texture);
    glTexBuffer(GL_TEXTURE_BUFFER, GL_RGBA32I, b->table_buffer);
    glBindTexture(GL_TEXTURE_BUFFER, 0);
    if (check_gl("growing the batch table", err) != 0)
        return -1;
    b->table_capacity = cap;
    return 0;
}

static int ensure_atlas(gl_backend *b, int w, int h, error_text *err)
{
    if (w <= b->atlas_w && h <= b->atlas_h)
        return 0;
    int nw = b->atlas_w ? b->atlas_w : 256, nh = b->atlas_h ? b->atlas_h : 256;
    while (nw < w)
        nw *= 2;
    while (nh < h)
        nh *= 2;
    if (nw > b->max_texture_size)
        nw = b->max_texture_size;
    if (nh > b->max_texture_size)
        nh = b->max_texture_size;
    if (b->atlas)
        glDeleteTextures(1, &b->atlas);
    glGenTextures(1, &b->atlas);
    glBindTexture(GL_TEXTURE_2D, b->atlas);
    glTexStorage2D(GL_TEXTURE_2D, 1, GL_DEPTH_COMPONENT32F, nw, nh);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
    glTexParameteri(GL_TEXTURE_2D, GL_TEXTURE_COMPARE_MODE, GL_NONE);
    glBindFramebuffer(GL_FRAMEBUFFER, b->fbo);
    glFramebufferTexture2D(GL_FRAMEBUFFER, GL_DEPTH_ATTACHMENT, GL_TEXTURE_2D, b->atlas, 0);
    glDrawBuffer(GL_NONE);
    glReadBuffer(GL_NONE);
    GLenum fb = glCheckFramebufferStatus(GL_FRAMEBUFFER);
    b->atlas_w = nw;
    b->atlas_h = nh;
    if (fb != GL_FRAMEBUFFER_COMPLETE) {
        error_set(err, "gl backend: depth atlas %dx%d is not a complete framebuffer (0x%04x)", nw,
                  nh, (unsigned)fb);
        return -1;
    }
    return check_gl("allocating the depth atlas", err);
}

/* ---- geometry cache ---- */

static geometry_entry *geometry_find(gl_backend *b, const collider_geometry *g, error_text *err)
{
    for (int i = 0; i < b->geometry_count; i++)
        if (b->geometries[i].geometry == g)
            return &b->geometries[i];
    float *vertices = NULL;
    uint32_t *indices = NULL;
    int vertex_count = 0, index_count = 0;
    if (collider_tessellate(g, &vertices, &vertex_count, &indices, &index_count) != 0) {
        error_set(err, "gl backend: cannot tessellate a collider (shape %d)", (int)g->shape);
        return NULL;
    }
    if (b->geometry_count == b->geometry_capacity) {
        int cap = b->geometry_capacity ? b->geometry_capacity * 2 : 16;
        geometry_entry *grown = realloc(b->geometries, (size_t)cap * sizeof *grown);
        if (!grown) {
            free(vertices);
            free(indices);
            error_set(err, "gl backend: out of memory caching colliders");
            return NULL;
        }
        b->geometries = grown;
        b->geometry_capacity = cap;
    }
    geometry_entry *e = &b->geometries[b->geometry_count];
    memset(e, 0, sizeof *e);
    e->geometry = g;
    e->index_count = index_count;
    glGenVertexArrays(1, &e->vao);
    glGenBuffers(1, &e->vbo);
    glGenBuffers(1, &e->ebo);
    glBindVertexArray(e->vao);
    glBindBuffer(GL_ARRAY_BUFFER, e->vbo);
    glBufferData(GL_ARRAY_BUFFER, (GLsizeiptr)((size_t)vertex_count * 3 * sizeof(float)), vertices,
                 GL_STATIC_DRAW);
    glBindBuffer(GL_ELEMENT_ARRAY_BUFFER, e->ebo);
    glBufferData(GL_ELEMENT_ARRAY_BUFFER, (GLsizeiptr)((size_t)index_count * sizeof(uint32_t)),
                 indices, GL_STATIC_DRAW);
    glEnableVertexAttribArray(0);
    glVertexAttribPointer(0, 3, GL_FLOAT, GL_FALSE, 3 * sizeof(float), NULL);
    glBindVertexArray(0);
    glBindBuffer(GL_ARRAY_BUFFER, 0);
    free(vertices);
    free(indices);
    if (check_gl("uploading collider triangles", err) != 0) {
        glDeleteVertexArrays(1, &e->vao);
        glDeleteBuffers(1, &e->vbo);
        glDeleteBuffers(1, &e->ebo);
        return NULL;
    }
    b->geometry_count++;
    return e;
}

static void gl_forget_geometry(sim_backend *base, const collider_geometry *g)
{
    gl_backend *b = (gl_backend *)base;
    for (int i = 0; i < b->geometry_count; i++) {
        if (b->geometries[i].geometry != g)
            continue;
        if (gl_context_make_current(b->context, NULL) == 0) {
            glDeleteVertexArrays(1, &b->geometries[i].vao);
            glDeleteBuffers(1, &b->geometries[i].vbo);
            glDeleteBuffers(1, &b->geometries[i].ebo);
        }
        b->geometries[i] = b->geometries[--b->geometry_count];
        return;
    }
}

/* ---- depth stage ---- */

/*
 * The collider's pose followed by the window's orthographic projection, in
 * double precision, as a column-major float matrix. NDC x, y span the
 * window's world rectangle, so pixel centres fall on cell centres; NDC z
 * spans [depth_low, depth_high] (units → metres), lower is nearer.
 */
static void window_mvp(const sim_window_job *job, collider_pose pose, float out[16])
{
    quatd q = quat_normalize(pose.orientation);
    double r[3][3] = {
        {1 - 2 * (q.y * q.y + q.z * q.z), 2 * (q.x * q.y - q.w * q.z), 2 * (q.x * q.z + q.w * q.y)},
        {2 * (q.x * q.y + q.w * q.z), 1 - 2 * (q.x * q.x + q.z * q.z), 2 * (q.y * q.z - q.w * q.x)},
        {2 * (q.x * q.z - q.w * q.y), 2 * (q.y * q.z + q.w * q.x), 1 - 2 * (q.x * q.x + q.y * q.y)},
    };
    double cs = job->cell_size_m, upm = job->units_per_m > 0 ? job->units_per_m : 1;
    double x0 = job->rect.x * cs, y0 = job->rect.y * cs;
    double sx = 2.0 / (job->rect.w * cs), sy = 2.0 / (job->rect.h * cs);
    double zl = job->depth_low / upm;
    double zh =
        job->depth_high > job->depth_low ? job->depth_high / upm : (job->depth_low + 1) / upm;
    double sz = 2.0 / (zh - zl);
    double scale[3] = {sx, sy, sz};
    double shift[3] = {sx * (pose.position.x - x0) - 1.0, sy * (pose.position.y - y0) - 1.0,
                       sz * (pose.position.z - zl) - 1.0};
    memset(out, 0, 16 * sizeof *out);
    for (int row = 0; row < 3; row++) {
        for (int col = 0; col < 3; col++)
            out[col * 4 + row] = (float)(scale[row] * r[row][col]);
        out[12 + row] = (float)shift[row];
    }
    out[15] = 1.0f;
}

/* Tallest first, then batch order: insertion sort (a tick has few windows,
 * and this keeps the order stable without qsort_r). */
static void sort_taller_first(int *order, int n, const window_entry *e)
{
    for (int i = 1; i < n; i++) {
        int v = order[i], j = i;
        while (j > 0 && e[order[j - 1]].h < e[v].h) {
            order[j] = order[j - 1];
            j--;
        }
        order[j] = v;
    }
}

/*
 * Shelf packing of the windows to rasterise, tallest first; a window that
 * does not fit under the atlas's largest size starts a new round. Returns
 * the number of rounds; slot and round go into the entries.
 */
static int pack_atlas(gl_backend *b, const sim_window_job *jobs, int count, int *atlas_w,
                      int *atlas_h)
{
    int n = 0, max_w = 1;
    int64_t area = 0;
    for (int i = 0; i < count; i++) {
        if (jobs[i].bottom_override)
            continue;
        b->order[n++] = i;
        if (b->entries[i].w > max_w)
            max_w = b->entries[i].w;
        area += (int64_t)b->entries[i].w * b->entries[i].h;
    }
    if (n == 0)
        return 0;
    sort_taller_first(b->order, n, b->entries);
    /* Width: the widest window, or the side of a square of the batch's area,
     * and never narrower than the texture we already hold. */
    int width = max_w;
    int side = (int)ceil(sqrt((double)area));
    if (side > width)
        width = side;
    if (b->atlas_w > width)
        width = b->atlas_w;
    if (width > b->max_texture_size)
        width = b->max_texture_size;
    int limit_h = b->max_texture_size;
    int rounds = 1, x = 0, y = 0, shelf_h = 0, used_h = 0;
    for (int k = 0; k < n; k++) {
        window_entry *e = &b->entries[b->order[k]];
        if (x + e->w > width) {
            y += shelf_h;
            x = 0;
            shelf_h = 0;
        }
        if (y + e->h > limit_h) {
            rounds++;
            x = y = shelf_h = 0;
        }
        e->slot_x = x;
        e->slot_y = y;
        e->raster_round = rounds;
        x += e->w;
        if (e->h > shelf_h)
            shelf_h = e->h;
        if (y + shelf_h > used_h)
            used_h = y + shelf_h;
    }
    *atlas_w = width;
    *atlas_h = used_h;
    return rounds;
}

static int run_depth(gl_backend *b, sim_window_job *jobs, int count, int rounds, error_text *err)
{
    glBindFramebuffer(GL_FRAMEBUFFER, b->fbo);
    glEnable(GL_DEPTH_TEST);
    glDepthFunc(GL_LESS);
    glDepthMask(GL_TRUE);
    /* Geometry below depth_low must clamp to depth 0 (the collider is below
     * the whole range), not be clipped away by the near plane. */
    glEnable(GL_DEPTH_CLAMP);
    glDisable(GL_CULL_FACE);
    glDisable(GL_BLEND);
    glEnable(GL_SCISSOR_TEST);
    glUseProgram(b->programs[PROG_RASTER]);
    for (int round = 0; round < rounds; round++) {
        glDisable(GL_SCISSOR_TEST);
        glClearDepth(1.0);
        glClear(GL_DEPTH_BUFFER_BIT);
        glEnable(GL_SCISSOR_TEST);
        glUseProgram(b->programs[PROG_RASTER]);
        for (int i = 0; i < count; i++) {
            const window_entry *e = &b->entries[i];
            if (e->raster_round != round + 1)
                continue;
            glViewport(e->slot_x, e->slot_y, e->w, e->h);
            glScissor(e->slot_x, e->slot_y, e->w, e->h);
            for (int c = 0; c < jobs[i].collider_count; c++) {
                const sim_collider *col = &jobs[i].colliders[c];
                geometry_entry *g = geometry_find(b, col->geometry, err);
                if (!g)
                    return -1;
                float mvp[16];
                window_mvp(&jobs[i], col->pose, mvp);
                glUniformMatrix4fv(b->uniforms[PROG_RASTER][U_MVP], 1, GL_FALSE, mvp);
                glBindVertexArray(g->vao);
                glDrawElements(GL_TRIANGLES, g->index_count, GL_UNSIGNED_INT, NULL);
            }
        }
        glBindVertexArray(0);
        glMemoryBarrier(GL_FRAMEBUFFER_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT);
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, b->atlas);
        glUseProgram(b->programs[PROG_DEPTH_TO_BOTTOM]);
        glUniform1i(b->uniforms[PROG_DEPTH_TO_BOTTOM][U_ROUND], round);
        bind(b, 2, BUF_BOTTOM);
        dispatch(b, PROG_DEPTH_TO_BOTTOM);
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, 0);
    }
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_DEPTH_CLAMP);
    glDisable(GL_DEPTH_TEST);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    return check_gl("depth stage", err);
}

/* ---- the integer stages ---- */

static void set_params(gl_backend *b, const sim_params *p, const ground_material_table *t)
{
    GLint rows[GROUND_MATERIALS_MAX * 4], max_compaction[GROUND_MATERIALS_MAX];
    memset(rows, 0, sizeof rows);
    memset(max_compaction, 0, sizeof max_compaction);
    for (int i = 0; t && i < t->count; i++) {
        rows[4 * i] = t->rows[i].compression_q16;
        rows[4 * i + 1] = t->rows[i].roughness_q16;
        rows[4 * i + 2] = t->rows[i].slope_threshold_axial;
        rows[4 * i + 3] = t->rows[i].slope_threshold_diagonal;
        max_compaction[i] = t->rows[i].max_compaction;
    }
    for (int prog = 0; prog < PROG_COMPUTE_COUNT; prog++) {
        GLuint pr = b->programs[prog];
        const GLint *u = b->uniforms[prog];
        glProgramUniform1i(pr, u[U_METRIC], (GLint)p->metric);
        glProgramUniform1i(pr, u[U_COMPRESSION], p->compression_q16);
        glProgramUniform1i(pr, u[U_ROUGHNESS], p->roughness_q16);
        glProgramUniform1i(pr, u[U_THRESHOLD_AXIAL], p->slope_threshold_axial);
        glProgramUniform1i(pr, u[U_THRESHOLD_DIAGONAL], p->slope_threshold_diagonal);
        glProgramUniform1i(pr, u[U_OBSTACLE_GAP], p->obstacle_gap);
        glProgramUniform1i(pr, u[U_MULTI_STEP], p->multi_target_step);
        glProgramUniform1i(pr, u[U_MULTI_MAX], p->multi_target_max);
        glProgramUniform1i(pr, u[U_FLOOR], p->floor);
        glProgramUniform1i(pr, u[U_MATERIALS_ON], t != NULL);
        glProgramUniform1i(pr, u[U_MATERIAL_COUNT], t ? t->count : 1);
        glProgramUniform4iv(pr, u[U_MATERIAL_ROWS], GROUND_MATERIALS_MAX, rows);
        glProgramUniform1iv(pr, u[U_MATERIAL_MAX], GROUND_MATERIALS_MAX, max_compaction);
    }
}

/* jump_flood_first_step of sim_stages.c, for the largest side of the batch:
 * steps at or beyond a smaller window's side only look outside it. */
static int first_step(int side)
{
    int k = 1;
    while (k * 2 < side)
        k *= 2;
    return k;
}

/* Returns the buffer (BUF_*) that holds the final seeds. */
static int run_jump_flood(gl_backend *b, int max_side)
{
    int in = BUF_SEED_A, out = BUF_SEED_B;
    for (int k = first_step(max_side); k >= 1; k /= 2) {
        glProgramUniform1i(b->programs[PROG_JUMP_FLOOD], b->uniforms[PROG_JUMP_FLOOD][U_STEP], k);
        sample(b, 1, in);
        bind(b, 2, out);
        dispatch(b, PROG_JUMP_FLOOD);
        int t = in;
        in = out;
        out = t;
    }
    return in;
}

static void run_displace(gl_backend *b, const sim_params *p, int64_t cells, int seed)
{
    if (p->method == SIM_METHOD_ITERATIVE) {
        /* mask words (with the split's remainder) and shares, ping-pong;
         * see displace_iterative_init.comp */
        int mask = BUF_S0, share = BUF_S1, mask_next = BUF_S2, share_next = BUF_S3;
        sample(b, 1, BUF_CLS);
        sample(b, 2, seed);
        sample(b, 3, BUF_MOVED);
        bind(b, 2, mask);
        bind(b, 3, share);
        dispatch(b, PROG_ITER_INIT);
        for (int32_t pass = 0; pass < p->displace_iterations; pass++) {
            sample(b, 1, BUF_CLS);
            sample(b, 2, mask);
            sample(b, 3, share);
            bind(b, 2, mask_next);
            bind(b, 3, share_next);
            dispatch(b, PROG_ITER_PASS);
            int t = mask;
            mask = mask_next;
            mask_next = t;
            t = share;
            share = share_next;
            share_next = t;
        }
        sample(b, 1, mask);
        sample(b, 2, share);
        bind(b, 2, BUF_HEIGHTS);
        dispatch(b, PROG_ITER_FINISH);
        return;
    }
    /* Exact 64-bit received sums start at zero. */
    const GLuint zero = 0;
    for (int i = BUF_S0; i <= BUF_S1; i++) {
        glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[i]);
        glClearBufferSubData(GL_SHADER_STORAGE_BUFFER, GL_R32UI, 0, (GLsizeiptr)(cells * 4),
                             GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    barrier();
    sample(b, 1, BUF_CLS);
    sample(b, 2, seed);
    sample(b, 3, BUF_MOVED);
    bind(b, 2, BUF_S0);
    bind(b, 3, BUF_S1);
    dispatch(b, p->method == SIM_METHOD_MULTI ? PROG_DISPLACE_MULTI : PROG_DISPLACE_SSBO);
    sample(b, 1, BUF_S0);
    sample(b, 2, BUF_S1);
    bind(b, 2, BUF_HEIGHTS);
    dispatch(b, PROG_DISPLACE_LAND);
}

/* Returns the buffer (BUF_*) that holds the final heights. */
static int run_even_slopes(gl_backend *b, const sim_params *p, int materials)
{
    int in = BUF_HEIGHTS, out = BUF_S0;
    for (int32_t iter = 0; iter < p->slope_iterations; iter++) {
        if (materials) {
            glActiveTexture(GL_TEXTURE3);
            glBindTexture(GL_TEXTURE_BUFFER, b->material_texture);
        }
        sample(b, 1, BUF_CLS);
        sample(b, 2, in);
        bind(b, 2, out);
        dispatch(b, PROG_EVEN_SLOPES);
        int t = in;
        in = out;
        out = t;
    }
    return in;
}

/* ---- a batch ---- */

/* ---- GPU tile cache ---- */

static void cache_free(tile_cache *c)
{
    if (!c)
        return;
    free(c->layer);
    free(c->from_cache);
    free(c->table);
    free(c->table_base);
    free(c->staging);
    free(c);
}

/* GL objects; only with the context current. */
static void cache_delete_gl(tile_cache *c)
{
    if (c->texture)
        glDeleteTextures(1, &c->texture);
    if (c->table_buffer)
        glDeleteBuffers(1, &c->table_buffer);
    if (c->gather)
        glDeleteProgram(c->gather);
    if (c->scatter)
        glDeleteProgram(c->scatter);
    c->texture = c->table_buffer = c->gather = c->scatter = 0;
}

static int grow_bytes(void **p, int64_t *cap, int64_t need, size_t size)
{
    if (need <= *cap)
        return 0;
    int64_t n = *cap ? *cap : 64;
    while (n < need)
        n *= 2;
    void *q = realloc(*p, (size_t)n * size);
    if (!q)
        return -1;
    *p = q;
    *cap = n;
    return 0;
}

/* Start a tick: decide whether the cache serves it, (re)make the texture for
 * the world's tile size, and drop everything if the world's base changed. */
static int cache_begin_tick(gl_backend *b, const sim_window_job *jobs, int count, error_text *err)
{
    tile_cache *c = b->cache;
    c->active = 0;
    if (c->from_cache_capacity < count) {
        unsigned char *f = realloc(c->from_cache, (size_t)count);
        if (!f) {
            error_set(err, "gl backend: out of memory for the tile cache");
            return -1;
        }
        c->from_cache = f;
        c->from_cache_capacity = count;
    }
    memset(c->from_cache, 0, (size_t)count);
    if (grow_bytes((void **)&c->table_base, &c->table_base_capacity, count,
                   sizeof *c->table_base) != 0) {
        error_set(err, "gl backend: out of memory for the tile cache");
        return -1;
    }
    for (int i = 0; i < count; i++)
        c->table_base[i] = -1;
    c->table_used = 0;
    const world *w = count > 0 ? jobs[0].world : NULL;
    if (c->layers_max <= 0 || !w || w->tile_cells > TILE_CACHE_SIDE_MAX ||
        w->tile_cells > b->max_texture_size)
        return 0;
    c->tick++;
    c->budget_left = c->budget_bytes;
    if (c->serial != world_base_serial(w) || c->side != w->tile_cells ||
        c->layers != c->layers_max) {
        if (c->texture && (c->side != w->tile_cells || c->layers != c->layers_max)) {
            glDeleteTextures(1, &c->texture);
            c->texture = 0;
        }
        cache_layer *l = realloc(c->layer, (size_t)c->layers_max * sizeof *l);
        int32_t *st = realloc(c->staging, (size_t)w->tile_cells * w->tile_cells * sizeof *st);
        if (l)
            c->layer = l;
        if (st)
            c->staging = st;
        if (!l || !st) {
            error_set(err, "gl backend: out of memory for the tile cache");
            return -1;
        }
        memset(c->layer, 0, (size_t)c->layers_max * sizeof *c->layer);
        c->layers = c->layers_max;
        c->side = w->tile_cells;
        c->shift = 0;
        while ((1 << c->shift) < c->side)
            c->shift++;
        c->serial = world_base_serial(w);
        c->stats.tile_cells = c->side;
        c->stats.resident_tiles = 0;
    }
    if (!c->texture) {
        glGenTextures(1, &c->texture);
        glBindTexture(GL_TEXTURE_2D_ARRAY, c->texture);
        glTexStorage3D(GL_TEXTURE_2D_ARRAY, 1, GL_R32I, c->side, c->side, c->layers);
        /* an integer texture is incomplete (reads 0) with a filtering
         * minification mode, and the default one filters */
        glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MIN_FILTER, GL_NEAREST);
        glTexParameteri(GL_TEXTURE_2D_ARRAY, GL_TEXTURE_MAG_FILTER, GL_NEAREST);
        glBindTexture(GL_TEXTURE_2D_ARRAY, 0);
        if (check_gl("allocating the tile cache", err) != 0) {
            glDeleteTextures(1, &c->texture);
            c->texture = 0;
            return -1;
        }
        memset(c->layer, 0, (size_t)c->layers * sizeof *c->layer);
        c->stats.resident_tiles = 0;
        c->stats.texture_bytes = (uint64_t)c->side * c->side * 4u * (uint64_t)c->layers;
    }
    c->active = 1;
    return 0;
}

/* The layer holding tile (tx, ty) as it is in w now, uploading it if the
 * budget allows; -1 if it cannot be had this tick. */
static int cache_acquire(tile_cache *c, const world *w, int tx, int ty)
{
    uint64_t generation = world_tile_generation(w, tx, ty);
    int found = -1, victim = -1;
    for (int i = 0; i < c->layers; i++) {
        cache_layer *l = &c->layer[i];
        if (l->used && l->tx == tx && l->ty == ty) {
            found = i;
            break;
        }
        if (!l->used) {
            if (victim < 0 || c->layer[victim].used)
                victim = i;
        } else if (l->last_use != c->tick &&
                   (victim < 0 ||
                    (c->layer[victim].used && l->last_use < c->layer[victim].last_use))) {
            victim = i;
        }
    }
    if (found >= 0 && c->layer[found].generation == generation) {
        c->layer[found].last_use = c->tick;
        return found;
    }
    int slot = found >= 0 ? found : victim;
    world_rect tr = world_tile_rect(w, tx, ty);
    int64_t bytes = (int64_t)tr.w * tr.h * 4;
    if (slot < 0 || bytes > c->budget_left)
        return -1;
    if (found < 0 && c->layer[slot].used)
        c->stats.evictions++;
    if (found < 0 && !c->layer[slot].used)
        c->stats.resident_tiles++;
    world_gather_window(w, tr, c->staging);
    glBindTexture(GL_TEXTURE_2D_ARRAY, c->texture);
    glTexSubImage3D(GL_TEXTURE_2D_ARRAY, 0, 0, 0, slot, tr.w, tr.h, 1, GL_RED_INTEGER, GL_INT,
                    c->staging);
    glBindTexture(GL_TEXTURE_2D_ARRAY, 0);
    c->budget_left -= bytes;
    c->stats.uploads++;
    c->stats.upload_bytes += (uint64_t)bytes;
    c->layer[slot] = (cache_layer){1, tx, ty, generation, c->tick, 0};
    return slot;
}

/* The layer holding tile (tx, ty) as it is in w now, without uploading; -1
 * if there is none. Pins it for this tick. */
static int cache_current(tile_cache *c, const world *w, int tx, int ty)
{
    uint64_t generation = world_tile_generation(w, tx, ty);
    for (int i = 0; i < c->layers; i++) {
        cache_layer *l = &c->layer[i];
        if (l->used && l->tx == tx && l->ty == ty) {
            if (l->generation != generation)
                return -1;
            l->last_use = c->tick;
            return i;
        }
    }
    return -1;
}

/* Plan the chunk (windows first .. first + count - 1 of the tick): each
 * window's table of layers, one per tile it covers. A window whose tiles
 * are all there (after uploads within the budget) is gathered from the
 * cache; any other keeps -1 for the tiles that are missing or stale, and
 * its result still goes into the ones that are current. */
static int cache_plan_chunk(gl_backend *b, const sim_window_job *jobs, int count, int first,
                            error_text *err)
{
    tile_cache *c = b->cache;
    if (!c->active)
        return 0;
    for (int i = 0; i < count; i++) {
        const world_rect r = jobs[i].rect;
        int tx0 = r.x >> c->shift, ty0 = r.y >> c->shift;
        int tx1 = (r.x + r.w - 1) >> c->shift, ty1 = (r.y + r.h - 1) >> c->shift;
        int64_t n = (int64_t)(tx1 - tx0 + 1) * (ty1 - ty0 + 1);
        if (n > c->layers || grow_bytes((void **)&c->table, &c->table_capacity, c->table_used + n,
                                        sizeof *c->table) != 0)
            continue; /* too many tiles for the cache: uploaded directly */
        int ok = 1;
        for (int ty = ty0; ty <= ty1; ty++)
            for (int tx = tx0; tx <= tx1; tx++) {
                int layer = ok ? cache_acquire(c, jobs[i].world, tx, ty)
                               : cache_current(c, jobs[i].world, tx, ty);
                ok &= layer >= 0;
                c->table[c->table_used + (int64_t)(ty - ty0) * (tx1 - tx0 + 1) + (tx - tx0)] =
                    layer;
            }
        c->table_base[first + i] = c->table_used;
        c->from_cache[first + i] = (unsigned char)ok;
        c->table_used += n;
    }
    if (c->table_used == 0)
        return 0;
    if (!c->table_buffer)
        glGenBuffers(1, &c->table_buffer);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, c->table_buffer);
    if (c->table_used > c->table_buffer_capacity) {
        int64_t cap = c->table_buffer_capacity ? c->table_buffer_capacity : 256;
        while (cap < c->table_used)
            cap *= 2;
        glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(cap * 4), NULL, GL_DYNAMIC_DRAW);
        c->table_buffer_capacity = cap;
    }
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)(c->table_used * 4), c->table);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    return check_gl("planning the tile cache", err);
}

/* Uniforms of one window for tile_gather / tile_scatter. */
static void cache_window_uniforms(const tile_cache *c, const GLint *u, const sim_window_job *job,
                                  int32_t offset, int64_t table_base)
{
    const world_rect r = job->rect;
    glUniform2i(u[0], r.x, r.y);
    glUniform2i(u[1], r.w, r.h);
    glUniform1i(u[2], offset);
    glUniform1i(u[3], c->shift);
    glUniform2i(u[4], r.x >> c->shift, r.y >> c->shift);
    glUniform1i(u[5], ((r.x + r.w - 1) >> c->shift) - (r.x >> c->shift) + 1);
    glUniform1i(u[6], (GLint)table_base);
    glDispatchCompute((GLuint)((r.w + 7) / 8), (GLuint)((r.h + 7) / 8), 1);
}

static void cache_gather(gl_backend *b, const sim_window_job *job, int32_t offset,
                         int64_t table_base)
{
    tile_cache *c = b->cache;
    glUseProgram(c->gather);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, b->buffers[BUF_HEIGHTS]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, c->table_buffer);
    glActiveTexture(GL_TEXTURE7);
    glBindTexture(GL_TEXTURE_2D_ARRAY, c->texture);
    glActiveTexture(GL_TEXTURE0);
    cache_window_uniforms(c, c->gather_u, job, offset, table_base);
}

static void cache_scatter(gl_backend *b, const sim_window_job *job, int32_t offset,
                          int64_t table_base, int heights)
{
    tile_cache *c = b->cache;
    glUseProgram(c->scatter);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 2, b->buffers[heights]);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, c->table_buffer);
    glBindImageTexture(0, c->texture, 0, GL_TRUE, 0, GL_WRITE_ONLY, GL_R32I);
    cache_window_uniforms(c, c->scatter_u, job, offset, table_base);
}

/* The engine wrote window `window` into w: a tile the GPU wrote the same
 * ints into (it is in the window's table: it was current when the tick
 * began) is current again; any other cached tile the window covers is stale
 * for the rest of the tick, whatever a later window does. */
static void gl_window_scattered(sim_backend *base, int window, const world *w, world_rect r)
{
    gl_backend *b = (gl_backend *)base;
    tile_cache *c = b->cache;
    if (!c || !c->active || c->serial != world_base_serial(w) || w->tile_cells != c->side ||
        window < 0 || window >= c->from_cache_capacity)
        return;
    int64_t table = c->table_base[window];
    int tx0 = r.x >> c->shift, ty0 = r.y >> c->shift;
    int tx1 = (r.x + r.w - 1) >> c->shift, ty1 = (r.y + r.h - 1) >> c->shift;
    for (int i = 0; i < c->layers; i++) {
        cache_layer *l = &c->layer[i];
        if (!l->used || l->tx < tx0 || l->tx > tx1 || l->ty < ty0 || l->ty > ty1)
            continue;
        int written =
            table >= 0 &&
            c->table[table + (int64_t)(l->ty - ty0) * (tx1 - tx0 + 1) + (l->tx - tx0)] == i;
        if (written && l->stale_tick != c->tick) {
            l->generation = world_tile_generation(w, l->tx, l->ty);
        } else {
            l->generation = UINT64_MAX; /* never a real generation */
            l->stale_tick = c->tick;
        }
    }
}

void sim_backend_gl_set_tile_cache(sim_backend *base, int layers, int64_t budget_bytes)
{
    if (!base || !base->name || strcmp(base->name, "gl") != 0)
        return;
    tile_cache *c = ((gl_backend *)base)->cache;
    c->layers_max = layers > 0 ? layers : 0;
    c->budget_bytes = budget_bytes > 0 ? budget_bytes : 0;
}

/* The backend table's optional tile_cache_stats entry. */
static void gl_tile_cache_stats(const sim_backend *base, sim_tile_cache_stats *out)
{
    *out = ((const gl_backend *)base)->cache->stats;
}

static int run_chunk(gl_backend *b, const sim_params *p, sim_window_job *jobs, int count, int first,
                     int *status, sim_stage_times *times, error_text *err)
{
    int64_t cells = 0, tiles = 0;
    int max_side = 1;
    if (ensure_windows(b, count, err) != 0)
        return -1;
    for (int i = 0; i < count; i++) {
        const sim_window_job *job = &jobs[i];
        window_entry *e = &b->entries[i];
        memset(e, 0, sizeof *e);
        e->offset = (int32_t)cells;
        e->x = job->rect.x;
        e->y = job->rect.y;
        e->w = job->rect.w;
        e->h = job->rect.h;
        e->depth_low = job->depth_low;
        e->depth_high = job->depth_high;
        if (e->w > max_side)
            max_side = e->w;
        if (e->h > max_side)
            max_side = e->h;
        cells += (int64_t)job->rect.w * job->rect.h;
        tiles += (int64_t)((job->rect.w + 7) / 8) * ((job->rect.h + 7) / 8);
    }
    const ground_material_table *materials = jobs[0].materials;
    if (ensure_cells(b, cells, err) != 0 || ensure_table(b, count, tiles, err) != 0 ||
        (materials && ensure_materials(b, cells, err) != 0))
        return -1;
    int64_t t_index = 0;
    for (int i = 0; i < count; i++)
        for (int ty = 0; ty < b->entries[i].h; ty += 8)
            for (int tx = 0; tx < b->entries[i].w; tx += 8) {
                b->tiles[t_index++] = i;
                b->tiles[t_index++] = tx | ty << 16;
                b->tiles[t_index++] = b->entries[i].offset;
                b->tiles[t_index++] = b->entries[i].w | b->entries[i].h << 16;
            }
    b->tile_count = tiles;
    b->window_count = count;
    int atlas_w = 0, atlas_h = 0;
    int rounds = pack_atlas(b, jobs, count, &atlas_w, &atlas_h);
    if (rounds > 0 && ensure_atlas(b, atlas_w, atlas_h, err) != 0)
        return -1;

    /* upload */
    double t = time_now_ms();
    GLsizeiptr entry_bytes = (GLsizeiptr)((size_t)count * sizeof(window_entry));
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->table_buffer);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, entry_bytes, b->entries);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, entry_bytes, (GLsizeiptr)(tiles * TILE_INTS * 4),
                    b->tiles);
    memset(b->status_host, 0, (size_t)count * sizeof *b->status_host);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)((size_t)count * sizeof(uint32_t)),
                    b->status_host);
    if (cache_plan_chunk(b, jobs, count, first, err) != 0)
        return -1;
    for (int i = 0; i < count; i++) {
        GLintptr off = (GLintptr)b->entries[i].offset * 4;
        GLsizeiptr size = (GLsizeiptr)jobs[i].rect.w * jobs[i].rect.h * 4;
        if (b->cache->from_cache[first + i]) {
            cache_gather(b, &jobs[i], b->entries[i].offset, b->cache->table_base[first + i]);
            b->cache->stats.windows_cached++;
        } else {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[BUF_HEIGHTS]);
            glBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, jobs[i].heights);
            b->cache->stats.windows_direct++;
        }
        if (jobs[i].bottom_override) {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[BUF_BOTTOM]);
            glBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, jobs[i].bottom_override);
        }
        if (materials) {
            int32_t *words = b->material_host + b->entries[i].offset;
            int64_t n = (int64_t)jobs[i].rect.w * jobs[i].rect.h;
            for (int64_t k = 0; k < n; k++)
                words[k] = (jobs[i].material_ids ? jobs[i].material_ids[k] : 0) |
                           (jobs[i].compaction ? (int32_t)jobs[i].compaction[k] << 8 : 0);
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->material_buffer);
            glBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, words);
        }
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    barrier(); /* the gathered heights are read by the stages below */
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_BUFFER, b->table_texture);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, b->status_buffer);
    set_params(b, p, materials);
    if (check_gl("upload", err) != 0)
        return -1;
    t = stage_end(b, &times->transfer, t);

    /* depth */
    if (rounds > 0 && run_depth(b, jobs, count, rounds, err) != 0)
        return -1;
    t = stage_end(b, &times->depth, t);

    /* classify (+ heights -= raw, + jump-flood seeds) */
    sample(b, 1, BUF_BOTTOM);
    bind(b, 2, BUF_HEIGHTS);
    bind(b, 3, BUF_MOVED);
    bind(b, 4, BUF_CLS);
    bind(b, 5, BUF_SEED_A);
    if (materials)
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, b->material_buffer);
    dispatch(b, PROG_CLASSIFY);
    t = stage_end(b, &times->classify, t);

    int seed = run_jump_flood(b, max_side);
    t = stage_end(b, &times->jump_flood, t);

    run_displace(b, p, cells, seed);
    t = stage_end(b, &times->displace, t);

    int heights = run_even_slopes(b, p, materials != NULL);
    t = stage_end(b, &times->even_slopes, t);

    /* readback: status first, then only the windows that were accepted (a
     * refused window keeps the heights it came with) */
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)((size_t)count * sizeof(uint32_t)),
                       b->status_host);
    for (int i = 0; i < count; i++) {
        GLintptr off = (GLintptr)b->entries[i].offset * 4;
        GLsizeiptr size = (GLsizeiptr)jobs[i].rect.w * jobs[i].rect.h * 4;
        status[i] = (b->status_host[i] & 1u) ? SIM_WINDOW_HEIGHT_LIMIT : SIM_WINDOW_OK;
        if (status[i] == SIM_WINDOW_OK) {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[heights]);
            glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, jobs[i].heights);
        }
        if (status[i] == SIM_WINDOW_OK && materials && jobs[i].compaction) {
            int32_t *words = b->material_host + b->entries[i].offset;
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->material_buffer);
            glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, words);
            int64_t n = (int64_t)jobs[i].rect.w * jobs[i].rect.h;
            for (int64_t k = 0; k < n; k++)
                jobs[i].compaction[k] = (uint16_t)((uint32_t)words[k] >> 8);
        }
        if (jobs[i].bottom_out) {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[BUF_BOTTOM]);
            glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, jobs[i].bottom_out);
        }
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    /* accepted windows go back into those of their tiles that were current
     * (all of them for a window gathered from the cache); a refused one
     * leaves them as they were (and is not scattered by the engine) */
    int scattered = 0;
    for (int i = 0; i < count; i++) {
        if (b->cache->table_base[first + i] < 0)
            continue;
        if (status[i] != SIM_WINDOW_OK) {
            b->cache->from_cache[first + i] = 0;
            b->cache->table_base[first + i] = -1;
            continue;
        }
        cache_scatter(b, &jobs[i], b->entries[i].offset, b->cache->table_base[first + i], heights);
        scattered = 1;
    }
    if (scattered)
        glMemoryBarrier(GL_SHADER_IMAGE_ACCESS_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT |
                        GL_TEXTURE_UPDATE_BARRIER_BIT);
    if (check_gl("readback", err) != 0)
        return -1;
    stage_end(b, &times->transfer, t);
    return 0;
}

static int gl_run_windows(sim_backend *base, const sim_params *p, sim_window_job *jobs,
                          int job_count, int *status, sim_stage_times *times, error_text *err)
{
    gl_backend *b = (gl_backend *)base;
    if (job_count <= 0)
        return 0;
    if (gl_context_make_current(b->context, err) != 0)
        return -1;
    for (int i = 0; i < job_count; i++) {
        const world_rect r = jobs[i].rect;
        /* One batch is one set of uniforms: all its windows share the
         * engine's material table or none has one. */
        if (jobs[i].materials != jobs[0].materials) {
            error_set(err, "gl backend: window %d has a different material table from window 0", i);
            return -1;
        }
        if (r.w < 1 || r.h < 1 || r.w > SIM_WINDOW_SIDE_MAX || r.h > SIM_WINDOW_SIDE_MAX) {
            error_set(err, "gl backend: window %d is %dx%d cells (sides must be 1..%d)", i, r.w,
                      r.h, SIM_WINDOW_SIDE_MAX);
            return -1;
        }
        if (!jobs[i].bottom_override && (r.w > b->max_texture_size || r.h > b->max_texture_size)) {
            error_set(err, "gl backend: window %d (%dx%d) exceeds the largest depth texture (%d)",
                      i, r.w, r.h, b->max_texture_size);
            return -1;
        }
        if ((int64_t)r.w * r.h > b->max_chunk_cells) {
            error_set(err,
                      "gl backend: window %d has %lld cells, more than one storage block "
                      "holds here (%lld)",
                      i, (long long)r.w * r.h, (long long)b->max_chunk_cells);
            return -1;
        }
    }
    if (cache_begin_tick(b, jobs, job_count, err) != 0)
        return -1;
    /* Normally the whole tick is one chunk; chunks only split batches that a
     * single shader storage block cannot address. */
    for (int start = 0; start < job_count;) {
        int end = start;
        int64_t cells = 0;
        while (end < job_count) {
            int64_t n = (int64_t)jobs[end].rect.w * jobs[end].rect.h;
            if (end > start && cells + n > b->max_chunk_cells)
                break;
            cells += n;
            end++;
        }
        if (run_chunk(b, p, jobs + start, end - start, start, status + start, times, err) != 0)
            return -1;
        start = end;
    }
    return 0;
}

/* The backend table's optional set_stage_timing entry. */
static void gl_set_stage_timing(sim_backend *base, int on)
{
    ((gl_backend *)base)->stage_timing = on != 0;
}

void sim_backend_gl_set_limits(sim_backend *base, int atlas_side, int64_t chunk_cells)
{
    if (!base || !base->name || strcmp(base->name, "gl") != 0)
        return;
    gl_backend *b = (gl_backend *)base;
    if (atlas_side > 0 && atlas_side < b->max_texture_size)
        b->max_texture_size = atlas_side;
    if (chunk_cells > 0 && chunk_cells < b->max_chunk_cells)
        b->max_chunk_cells = chunk_cells;
}

static void gl_destroy(sim_backend *base)
{
    gl_backend *b = (gl_backend *)base;
    if (!b)
        return;
    if (b->context && gl_context_make_current(b->context, NULL) == 0) {
        for (int i = 0; i < b->geometry_count; i++) {
            glDeleteVertexArrays(1, &b->geometries[i].vao);
            glDeleteBuffers(1, &b->geometries[i].vbo);
            glDeleteBuffers(1, &b->geometries[i].ebo);
        }
        for (int i = 0; i < PROG_COUNT; i++)
            if (b->programs[i])
                glDeleteProgram(b->programs[i]);
        glDeleteTextures(BUF_COUNT, b->textures);
        glDeleteTextures(1, &b->table_texture);
        glDeleteBuffers(BUF_COUNT, b->buffers);
        glDeleteBuffers(1, &b->table_buffer);
        glDeleteBuffers(1, &b->status_buffer);
        if (b->atlas)
            glDeleteTextures(1, &b->atlas);
        if (b->fbo)
            glDeleteFramebuffers(1, &b->fbo);
        if (b->material_buffer) {
            glDeleteBuffers(1, &b->material_buffer);
            glDeleteTextures(1, &b->material_texture);
        }
        if (b->cache)
            cache_delete_gl(b->cache);
    }
    cache_free(b->cache);
    gl_context_destroy(b->context);
    free(b->geometries);
    free(b->entries);
    free(b->status_host);
    free(b->order);
    free(b->tiles);
    free(b->material_host);
    free(b);
}

sim_backend *sim_backend_gl_create(error_text *err)
{
    gl_backend *b = calloc(1, sizeof *b);
    if (!b) {
        error_set(err, "gl backend: out of memory");
        return NULL;
    }
    b->base.name = "gl";
    b->base.run_windows = gl_run_windows;
    b->base.forget_geometry = gl_forget_geometry;
    b->base.scratch_bytes = gl_scratch_bytes;
    b->base.window_scattered = gl_window_scattered;
    b->base.tile_cache_stats = gl_tile_cache_stats;
    b->base.set_stage_timing = gl_set_stage_timing;
    b->base.destroy = gl_destroy;
    b->base.impl = b;
    b->cache = calloc(1, sizeof *b->cache);
    if (!b->cache) {
        free(b);
        error_set(err, "gl backend: out of memory");
        return NULL;
    }
    b->cache->layers_max = TILE_CACHE_LAYERS_DEFAULT;
    b->cache->budget_bytes = TILE_CACHE_BUDGET_DEFAULT;
    const char *env = getenv("TERRAD_GL_TILE_CACHE");
    if (env && *env) {
        int layers = 0;
        long long budget = 0;
        if (sscanf(env, "%d,%lld", &layers, &budget) != 2 || layers < 0 || layers > 4096 ||
            budget < 0) {
            error_set(err,
                      "TERRAD_GL_TILE_CACHE: must be LAYERS,BUDGET_BYTES with LAYERS in "
                      "[0, 4096] (got \"%s\")",
                      env);
            free(b->cache);
            free(b);
            return NULL;
        }
        b->cache->layers_max = layers;
        b->cache->budget_bytes = budget;
    }
    b->context = gl_context_create(err);
    if (!b->context) {
        cache_free(b->cache);
        free(b);
        return NULL;
    }
    snprintf(b->base.renderer, sizeof b->base.renderer, "%s", gl_context_renderer(b->context));
    snprintf(b->base.version, sizeof b->base.version, "%s", gl_context_version(b->context));

    for (int i = 0; i < PROG_COMPUTE_COUNT; i++) {
        b->programs[i] = gl_program_compute(compute_names[i], err);
        if (!b->programs[i])
            goto fail;
    }
    b->programs[PROG_RASTER] = gl_program_raster("shaders/depth.vert", "shaders/depth.frag", err);
    if (!b->programs[PROG_RASTER])
        goto fail;
    b->cache->gather = gl_program_compute("shaders/tile_gather.comp", err);
    if (!b->cache->gather)
        goto fail;
    b->cache->scatter = gl_program_compute("shaders/tile_scatter.comp", err);
    if (!b->cache->scatter)
        goto fail;
    for (int u = 0; u < 7; u++) {
        b->cache->gather_u[u] = glGetUniformLocation(b->cache->gather, cache_uniform_names[u]);
        b->cache->scatter_u[u] = glGetUniformLocation(b->cache->scatter, cache_uniform_names[u]);
    }
    for (int i = 0; i < PROG_COUNT; i++)
        for (int u = 0; u < U_COUNT; u++)
            b->uniforms[i][u] = glGetUniformLocation(b->programs[i], uniform_names[u]);

    GLint64 block = 0;
    GLint groups_x = 0, texture_buffer = 0;
    glGetIntegerv(GL_MAX_TEXTURE_BUFFER_SIZE, &texture_buffer);
    glGetIntegerv(GL_MAX_TEXTURE_SIZE, &b->max_texture_size);
    glGetInteger64v(GL_MAX_SHADER_STORAGE_BLOCK_SIZE, &block);
    glGetIntegeri_v(GL_MAX_COMPUTE_WORK_GROUP_COUNT, 0, &groups_x);
    if (b->max_texture_size > 16384)
        b->max_texture_size = 16384;
    b->max_groups_x = groups_x > 0 ? groups_x : 65535;
    /* int32 indices everywhere; a block bounds one buffer binding. */
    b->max_chunk_cells = block > 0 ? (int64_t)block / 4 : (int64_t)1 << 22;
    /* the batch table holds at most 4 texels per cell (1x1 windows) */
    if (texture_buffer > 0 && (int64_t)texture_buffer / 4 < b->max_chunk_cells)
        b->max_chunk_cells = (int64_t)texture_buffer / 4;
    if (b->max_chunk_cells > ((int64_t)1 << 30))
        b->max_chunk_cells = (int64_t)1 << 30;

    glGenBuffers(BUF_COUNT, b->buffers);
    glGenTextures(BUF_COUNT, b->textures);
    glGenTextures(1, &b->table_texture);
    glGenBuffers(1, &b->table_buffer);
    glGenBuffers(1, &b->status_buffer);
    glGenFramebuffers(1, &b->fbo);
    if (check_gl("creating the backend", err) != 0)
        goto fail;
    /* Whichever thread runs the first batch makes the context current there
     * (a context can be current on one thread only): the backend may be
     * created on one thread and driven by the sim thread. */
    gl_context_release(b->context);
    return &b->base;
fail:
    gl_destroy(&b->base);
    return NULL;
}
