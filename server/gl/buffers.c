/*
 * buffers.c: the GL backend's storage (gl_internal.h) — per-cell buffers
 * with a buffer texture on each, the per-cell material words, the batch
 * table and the window status flags, all grown by doubling to the largest
 * batch seen (scratch follows active cells, never the world) — and the small
 * helpers every pass uses to bind, dispatch and time itself.
 */
#include "gl/gl_internal.h"

#include <stdlib.h>

/* ---- helpers of every pass ---- */

/* ---- small helpers ---- */

sim_gpu_sync_stats gl_sync;

void gl_gpu_sync_stats(const sim_backend *b, sim_gpu_sync_stats *out)
{
    (void)b;
    *out = gl_sync;
}

void gl_barrier(void)
{
    gl_sync.barriers++;
    /* Every pass reads what the previous one wrote through SSBOs, and buffer
     * clears and readbacks follow shader writes: the GL requires an explicit
     * barrier for both (the original implementation omitted it). Tile lists
     * written by a pass are read by the next as indirect dispatch groups. */
    glMemoryBarrier(GL_SHADER_STORAGE_BARRIER_BIT | GL_BUFFER_UPDATE_BARRIER_BIT |
                    GL_TEXTURE_FETCH_BARRIER_BIT | GL_COMMAND_BARRIER_BIT);
}

int gl_check(const char *what, error_text *err)
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
void gl_bind(gl_backend *b, int binding, int buffer)
{
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, (GLuint)binding, b->buffers[buffer]);
}

/* A per-cell buffer as a buffer texture on a sampler unit (what a pass only
 * reads: see common.glsl for why reads and writes take different paths). */
void gl_sample(gl_backend *b, int unit, int buffer)
{
    glActiveTexture(GL_TEXTURE0 + (GLenum)unit);
    glBindTexture(GL_TEXTURE_BUFFER, b->textures[buffer]);
}

/* One 8x8 workgroup per tile of the chunk, in a 2D grid so that more than
 * 65535 tiles fit; the shader maps its group to a tile (common.glsl). */
void gl_dispatch(gl_backend *b, int prog)
{
    glUseProgram(b->programs[prog]);
    glUniform1i(b->uniforms[prog][U_TILE_COUNT], (GLint)b->tile_count);
    glUniform1i(b->uniforms[prog][U_WINDOW_COUNT], b->window_count);
    int64_t groups = b->tile_count;
    int64_t gx = groups < b->max_groups_x ? groups : b->max_groups_x;
    int64_t gy = (groups + gx - 1) / gx;
    glDispatchCompute((GLuint)gx, (GLuint)gy, 1);
    gl_sync.dispatches++;
    gl_barrier();
}

void gl_dispatch_indirect(gl_backend *b, int prog, GLuint buffer, GLintptr offset)
{
    glUseProgram(b->programs[prog]);
    glUniform1i(b->uniforms[prog][U_TILE_COUNT], (GLint)b->tile_count);
    glUniform1i(b->uniforms[prog][U_WINDOW_COUNT], b->window_count);
    glBindBuffer(GL_DISPATCH_INDIRECT_BUFFER, buffer);
    glDispatchComputeIndirect(offset);
    glBindBuffer(GL_DISPATCH_INDIRECT_BUFFER, 0);
    gl_sync.dispatches++;
    gl_sync.indirect++;
    gl_barrier();
}

/* Ends a stage: with stage timing on, waits for the GPU so the time is real. */
double gl_stage_end(gl_backend *b, double *acc, double since)
{
    if (b->stage_timing) {
        glFinish();
        gl_sync.finishes++;
    }
    double now = time_now_ms();
    *acc += now - since;
    return now;
}

/* ---- buffers ---- */

uint64_t gl_scratch_bytes(const sim_backend *base)
{
    const gl_backend *b = (const gl_backend *)base;
    uint64_t bytes = (uint64_t)b->cell_capacity * BUF_COUNT * sizeof(int32_t);
    bytes += (uint64_t)b->material_capacity * 2 * sizeof(int32_t); /* GPU and host copies */
    bytes += (uint64_t)b->table_capacity +
             (uint64_t)b->window_capacity * STATUS_WORDS * sizeof(uint32_t);
    bytes += b->tile_list_capacity > 0 ? 3 * (16u + 4u * (uint64_t)b->tile_list_capacity) : 0u;
    /* the depth stage's instances, GPU and host copies */
    return bytes + (uint64_t)b->exact_buffer_bytes +
           (uint64_t)b->exact_host_capacity * sizeof(collider_fixed);
}

int gl_ensure_cells(gl_backend *b, int64_t cells, error_text *err)
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
    if (gl_check("growing the cell buffers", err) != 0) {
        b->cell_capacity = 0;
        return -1;
    }
    b->cell_capacity = cap;
    return 0;
}

int gl_ensure_materials(gl_backend *b, int64_t cells, error_text *err)
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
    if (gl_check("growing the material buffer", err) != 0) {
        b->material_capacity = 0;
        return -1;
    }
    b->material_capacity = cap;
    return 0;
}

int gl_ensure_windows(gl_backend *b, int count, error_text *err)
{
    /* the host arrays grow together, to one capacity */
    int64_t cap = b->host_capacity;
#define HOST_GROW(array)                                                                           \
    (cap = b->host_capacity, array_grow((void **)&b->array, &cap, count, sizeof *b->array))
    if (HOST_GROW(entries) != 0 ||
        array_grow((void **)&b->status_host, &b->status_host_capacity,
                   (int64_t)count * STATUS_WORDS, sizeof *b->status_host) != 0) {
        error_set(err, "gl backend: out of memory for %d windows", count);
        return -1;
    }
#undef HOST_GROW
    b->host_capacity = cap;
    if (count <= b->window_capacity)
        return 0;
    int status_cap = b->window_capacity ? b->window_capacity : 16;
    while (status_cap < count)
        status_cap *= 2;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    glBufferData(GL_SHADER_STORAGE_BUFFER,
                 (GLsizeiptr)((size_t)status_cap * STATUS_WORDS * sizeof(uint32_t)), NULL,
                 GL_DYNAMIC_READ);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    if (gl_check("growing the window status buffer", err) != 0)
        return -1;
    b->window_capacity = status_cap;
    return 0;
}

/* The batch table: windows then tiles, host copy and GPU buffer. */
int gl_ensure_table(gl_backend *b, int window_count, int64_t tiles, error_text *err)
{
    int64_t ints = (int64_t)window_count * (int64_t)(sizeof(window_entry) / 4) + TILE_INTS * tiles;
    if (array_grow((void **)&b->tiles, &b->tile_capacity, TILE_INTS * tiles, sizeof *b->tiles) !=
        0) {
        error_set(err, "gl backend: out of memory for %lld tiles", (long long)tiles);
        return -1;
    }
    if (tiles > b->tile_list_capacity) {
        int64_t list_cap = b->tile_list_capacity ? b->tile_list_capacity : 1024;
        while (list_cap < tiles)
            list_cap *= 2;
        const GLuint lists[3] = {b->tile_list_buffer, b->tile_next_buffer, b->tile_mark_buffer};
        for (int i = 0; i < 3; i++) {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, lists[i]);
            glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)(16 + 4 * list_cap), NULL,
                         GL_DYNAMIC_COPY);
        }
        glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
        if (gl_check("growing the tile list", err) != 0)
            return -1;
        b->tile_list_capacity = list_cap;
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
    if (gl_check("growing the batch table", err) != 0)
        return -1;
    b->table_capacity = cap;
    return 0;
}
