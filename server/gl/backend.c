/*
 * backend.c: the GL backend of the deformation pipeline (sim.h): its function
 * table, a batch in chunks, and each chunk's upload and readback; the parts
 * are depth.c, stages.c, tile_cache.c and buffers.c (gl_internal.h). It runs all
 * windows of a tick as one batch, with one draw per collider and one compute
 * dispatch per stage (per step or iteration) for the whole batch:
 *
 *   upload      heights (and uploaded bottoms) into flat per-cell buffers
 *   depth       depth_clear.comp, then depth_exact.comp: the fixed-point
 *               depth of every collider (collider/depth_fixed.c's twin)
 *   classify    classify.comp (also heights -= raw, jump-flood init)
 *   jump_flood  tile_list.comp (the tiles that are not all free), then
 *               jump_flood.comp once per step size over that list
 *               (indirect dispatch), ping-pong
 *   displace    displace_ssbo/multi.comp + displace_land.comp, or
 *               displace_iterative_init/pass.../dead_end/finish.comp
 *   even_slopes even_slopes.comp per iteration, ping-pong: every tile first,
 *               then the tiles around the last iteration's changes
 *               (indirect dispatch over the list it appended)
 *   readback    window status flags, then the heights of accepted windows
 *
 * Layout: window i of the batch owns cells [offset_i, offset_i + w_i*h_i)
 * of every per-cell buffer, row-major. A batch table lists the windows
 * (offset, corner, size, whether the depth stage computes its bottoms) and then every 8x8 tile of
 * every window; a dispatch runs one workgroup per tile, so an invocation
 * finds its window and cell from one fetch (common.glsl). Passes read
 * through buffer textures and write through storage buffers, with a
 * glMemoryBarrier after every pass. Buffers grow by doubling to the largest
 * batch seen, so scratch memory follows active cells, never the world's
 * size; a batch larger than one storage block allows runs in chunks.
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

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const compute_names[PROG_COUNT] = {
    "shaders/classify.comp",
    "shaders/jump_flood.comp",
    "shaders/displace_ssbo.comp",
    "shaders/displace_multi.comp",
    "shaders/displace_land.comp",
    "shaders/displace_iterative_init.comp",
    "shaders/displace_iterative_pass.comp",
    "shaders/displace_iterative_dead_end.comp",
    "shaders/displace_iterative_finish.comp",
    "shaders/even_slopes.comp",
    "shaders/depth_clear.comp",
    "shaders/depth_exact.comp",
    "shaders/tile_list.comp",
    "shaders/dirty_rect.comp",
};

static const char *const uniform_names[U_COUNT] = {
    "u_tile_count",        "u_window_count",     "u_metric",        "u_obstacle_gap",
    "u_multi_target_step", "u_multi_target_max", "u_floor",         "u_step",
    "u_materials_on",      "u_material_count",   "u_material_rows", "u_material_max_compaction",
    "u_list_row",          "u_sparse",           "u_stamp",         "u_list_kind",
};

/* ---- a batch ---- */

/* The chunk's layout: a batch-table entry per window, the table's tiles and
 * the per-cell buffers sized for it. Returns 0, or -1. */
static int chunk_layout(gl_backend *b, const sim_window_job *jobs, int count, int64_t *cells_out,
                        int *max_side_out, error_text *err)
{
    int64_t cells = 0, tiles = 0;
    int max_side = 1;
    if (gl_ensure_windows(b, count, err) != 0)
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
        e->cast_depth = job->bottom_override == NULL;
        if (e->w > max_side)
            max_side = e->w;
        if (e->h > max_side)
            max_side = e->h;
        cells += (int64_t)job->rect.w * job->rect.h;
        tiles += (int64_t)((job->rect.w + 7) / 8) * ((job->rect.h + 7) / 8);
    }
    if (gl_ensure_cells(b, cells, err) != 0 || gl_ensure_table(b, count, tiles, err) != 0 ||
        (jobs[0].materials && gl_ensure_materials(b, cells, err) != 0))
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
    *cells_out = cells;
    *max_side_out = max_side;
    return 0;
}

/* The material words of one window: id | compaction << 8. */
static void upload_materials(gl_backend *b, const sim_window_job *job, int32_t offset)
{
    int32_t *words = b->material_host + offset;
    int64_t n = (int64_t)job->rect.w * job->rect.h;
    for (int64_t k = 0; k < n; k++)
        words[k] = (job->material_ids ? job->material_ids[k] : 0) |
                   (job->compaction ? (int32_t)job->compaction[k] << 8 : 0);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->material_buffer);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, (GLintptr)offset * 4, (GLsizeiptr)(n * 4), words);
}

/* upload: the batch table, cleared status flags, each window's heights
 * (from the tile cache or the CPU copy), uploaded bottoms and materials, and
 * the params as uniforms. */
static int chunk_upload(gl_backend *b, const sim_params *p, const sim_window_job *jobs, int count,
                        int first, error_text *err)
{
    const ground_material_table *materials = jobs[0].materials;
    GLsizeiptr entry_bytes = (GLsizeiptr)((size_t)count * sizeof(window_entry));
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->table_buffer);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, entry_bytes, b->entries);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, entry_bytes,
                    (GLsizeiptr)(b->tile_count * TILE_INTS * 4), b->tiles);
    /* status flags clear, dirty rectangles empty (min > max) */
    memset(b->status_host, 0, (size_t)count * sizeof *b->status_host);
    for (int i = 0; i < count; i++) {
        uint32_t *r = b->status_host + count + 4 * i;
        r[0] = r[1] = UINT32_MAX;
        r[2] = r[3] = 0;
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0,
                    (GLsizeiptr)((size_t)count * STATUS_WORDS * sizeof(uint32_t)), b->status_host);
    if (gl_cache_plan_chunk(b, jobs, count, first, err) != 0)
        return -1;
    for (int i = 0; i < count; i++) {
        GLintptr off = (GLintptr)b->entries[i].offset * 4;
        GLsizeiptr size = (GLsizeiptr)jobs[i].rect.w * jobs[i].rect.h * 4;
        if (b->cache->from_cache[first + i]) {
            gl_cache_gather(b, &jobs[i], b->entries[i].offset, b->cache->table_base[first + i]);
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
        if (materials)
            upload_materials(b, &jobs[i], b->entries[i].offset);
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    gl_barrier(); /* the gathered heights are read by the stages below */
    /* the uploaded heights, for dirty_rect.comp at the end of the tick */
    int64_t cells =
        b->entries[count - 1].offset + (int64_t)jobs[count - 1].rect.w * jobs[count - 1].rect.h;
    glBindBuffer(GL_COPY_READ_BUFFER, b->buffers[BUF_HEIGHTS]);
    glBindBuffer(GL_COPY_WRITE_BUFFER, b->buffers[BUF_ORIGINAL]);
    glCopyBufferSubData(GL_COPY_READ_BUFFER, GL_COPY_WRITE_BUFFER, 0, 0, (GLsizeiptr)(cells * 4));
    glBindBuffer(GL_COPY_READ_BUFFER, 0);
    glBindBuffer(GL_COPY_WRITE_BUFFER, 0);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_BUFFER, b->table_texture);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 1, b->status_buffer);
    gl_stages_set_params(b, p, materials);
    return gl_check("upload", err);
}

/* One GPU→CPU copy from the bound storage buffer, counted (gl_sync). */
static void read_back(GLintptr off, GLsizeiptr size, void *out)
{
    glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, off, size, out);
    gl_sync.readbacks++;
    gl_sync.readback_bytes += (uint64_t)size;
}

/* The rows of each accepted window's dirty rectangle, in one GPU→CPU
 * transfer: the GPU copies each window's rows y0..y1 (whole rows, one range
 * per window) one after another into BUF_ORIGINAL, free by now, and one read
 * brings them all; each band lands in the window's host heights at row y0.
 * Every other cell kept its uploaded height, which the host copy already
 * holds, so the heights are those of reading the whole window. A tick that
 * changed nothing reads no heights at all. */
static void read_heights(gl_backend *b, sim_window_job *jobs, int count, int heights,
                         const int *status)
{
    GLintptr packed = 0;
    for (int i = 0; i < count; i++) {
        const uint32_t *r = b->status_host + count + 4 * i;
        if (status[i] != SIM_WINDOW_OK || r[1] > r[3])
            continue;
        GLintptr off = ((GLintptr)b->entries[i].offset + (GLintptr)r[1] * jobs[i].rect.w) * 4;
        GLsizeiptr size = (GLsizeiptr)(r[3] - r[1] + 1) * jobs[i].rect.w * 4;
        glBindBuffer(GL_COPY_READ_BUFFER, b->buffers[heights]);
        glBindBuffer(GL_COPY_WRITE_BUFFER, b->buffers[BUF_ORIGINAL]);
        glCopyBufferSubData(GL_COPY_READ_BUFFER, GL_COPY_WRITE_BUFFER, off, packed, size);
        packed += size;
    }
    glBindBuffer(GL_COPY_READ_BUFFER, 0);
    glBindBuffer(GL_COPY_WRITE_BUFFER, 0);
    if (packed == 0)
        return;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[BUF_ORIGINAL]);
    const uint8_t *span = glMapBufferRange(GL_SHADER_STORAGE_BUFFER, 0, packed, GL_MAP_READ_BIT);
    gl_sync.readbacks++;
    gl_sync.readback_bytes += (uint64_t)packed;
    packed = 0;
    for (int i = 0; i < count; i++) {
        const uint32_t *r = b->status_host + count + 4 * i;
        if (status[i] != SIM_WINDOW_OK || r[1] > r[3])
            continue;
        GLsizeiptr size = (GLsizeiptr)(r[3] - r[1] + 1) * jobs[i].rect.w * 4;
        int32_t *dst = jobs[i].heights + (int64_t)r[1] * jobs[i].rect.w;
        if (span)
            memcpy(dst, span + packed, (size_t)size);
        else /* the mapping failed: read the band on its own */
            glGetBufferSubData(GL_SHADER_STORAGE_BUFFER, packed, size, dst);
        packed += size;
    }
    if (span)
        glUnmapBuffer(GL_SHADER_STORAGE_BUFFER);
}

/* readback: status first, then only the windows that were accepted (a
 * refused window keeps the heights it came with), their compaction and any
 * bottoms asked for. */
static void chunk_readback(gl_backend *b, sim_window_job *jobs, int count, int heights, int *status)
{
    int materials = jobs[0].materials != NULL;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->status_buffer);
    read_back(0, (GLsizeiptr)((size_t)count * STATUS_WORDS * sizeof(uint32_t)), b->status_host);
    for (int i = 0; i < count; i++)
        status[i] = (b->status_host[i] & 1u) ? SIM_WINDOW_HEIGHT_LIMIT : SIM_WINDOW_OK;
    read_heights(b, jobs, count, heights, status);
    for (int i = 0; i < count; i++) {
        GLintptr off = (GLintptr)b->entries[i].offset * 4;
        GLsizeiptr size = (GLsizeiptr)jobs[i].rect.w * jobs[i].rect.h * 4;
        if (status[i] == SIM_WINDOW_OK && materials && jobs[i].compaction) {
            int32_t *words = b->material_host + b->entries[i].offset;
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->material_buffer);
            read_back(off, size, words);
            int64_t n = (int64_t)jobs[i].rect.w * jobs[i].rect.h;
            for (int64_t k = 0; k < n; k++)
                jobs[i].compaction[k] = (uint16_t)((uint32_t)words[k] >> 8);
        }
        if (jobs[i].bottom_out) {
            glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->buffers[BUF_BOTTOM]);
            read_back(off, size, jobs[i].bottom_out);
        }
    }
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
}

/* Accepted windows go back into those of their tiles that were current (all
 * of them for a window gathered from the cache); a refused one leaves them
 * as they were (and is not scattered by the engine). */
static void chunk_cache_scatter(gl_backend *b, const sim_window_job *jobs, int count, int first,
                                const int *status, int heights)
{
    int scattered = 0;
    for (int i = 0; i < count; i++) {
        if (b->cache->table_base[first + i] < 0)
            continue;
        if (status[i] != SIM_WINDOW_OK) {
            b->cache->from_cache[first + i] = 0;
            b->cache->table_base[first + i] = -1;
            continue;
        }
        gl_cache_scatter(b, &jobs[i], b->entries[i].offset, b->cache->table_base[first + i],
                         heights);
        scattered = 1;
    }
    if (scattered) {
        glMemoryBarrier(GL_SHADER_IMAGE_ACCESS_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT |
                        GL_TEXTURE_UPDATE_BARRIER_BIT);
        gl_sync.barriers++;
    }
}

/* One chunk of the batch through every stage, in the order of the banner. */
static int run_chunk(gl_backend *b, const sim_params *p, sim_window_job *jobs, int count, int first,
                     int *status, sim_stage_times *times, error_text *err)
{
    int64_t cells = 0;
    int max_side = 1;
    if (chunk_layout(b, jobs, count, &cells, &max_side, err) != 0)
        return -1;
    double t = time_now_ms();
    if (chunk_upload(b, p, jobs, count, first, err) != 0)
        return -1;
    t = gl_stage_end(b, &times->transfer, t);

    if (gl_depth_run(b, jobs, count, err) != 0)
        return -1;
    t = gl_stage_end(b, &times->depth, t);

    gl_stage_classify(b, jobs[0].materials != NULL);
    t = gl_stage_end(b, &times->classify, t);

    int seed = gl_stage_jump_flood(b, max_side, cells);
    t = gl_stage_end(b, &times->jump_flood, t);

    gl_stage_displace(b, p, cells, seed);
    t = gl_stage_end(b, &times->displace, t);

    int heights = gl_stage_even_slopes(b, p, jobs[0].materials != NULL, cells);
    gl_stage_dirty_rects(b, heights);
    t = gl_stage_end(b, &times->even_slopes, t);

    chunk_readback(b, jobs, count, heights, status);
    chunk_cache_scatter(b, jobs, count, first, status, heights);
    if (gl_check("readback", err) != 0)
        return -1;
    gl_stage_end(b, &times->transfer, t);
    return 0;
}

/* Every window must fit the batch's limits; err names the first that does not. */
static int check_windows(const gl_backend *b, const sim_window_job *jobs, int job_count,
                         error_text *err)
{
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
        if ((int64_t)r.w * r.h > b->max_chunk_cells) {
            error_set(err,
                      "gl backend: window %d has %lld cells, more than one storage block "
                      "holds here (%lld)",
                      i, (long long)r.w * r.h, (long long)b->max_chunk_cells);
            return -1;
        }
    }
    return 0;
}

static int gl_run_windows(sim_backend *base, const sim_params *p, sim_window_job *jobs,
                          int job_count, int *status, sim_stage_times *times, error_text *err)
{
    gl_backend *b = (gl_backend *)base;
    /* the context is current on one thread: the first to run a batch keeps it */
    if (!b->owner.tid)
        thread_owner_claim(&b->owner, "sim");
    THREAD_OWNED(&b->owner);
    if (job_count <= 0)
        return 0;
    if (gl_context_make_current(b->context, err) != 0)
        return -1;
    if (check_windows(b, jobs, job_count, err) != 0)
        return -1;
    if (gl_cache_begin_tick(b, jobs, job_count, err) != 0)
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

void sim_backend_gl_set_limits(sim_backend *base, int64_t chunk_cells)
{
    if (!base || !base->name || strcmp(base->name, "gl") != 0)
        return;
    gl_backend *b = (gl_backend *)base;
    if (chunk_cells > 0 && chunk_cells < b->max_chunk_cells)
        b->max_chunk_cells = chunk_cells;
}

static void gl_destroy(sim_backend *base)
{
    gl_backend *b = (gl_backend *)base;
    if (!b)
        return;
    if (b->context && gl_context_make_current(b->context, NULL) == 0) {
        gl_depth_delete(b);
        for (int i = 0; i < PROG_COUNT; i++)
            if (b->programs[i])
                glDeleteProgram(b->programs[i]);
        glDeleteTextures(BUF_COUNT, b->textures);
        glDeleteTextures(1, &b->table_texture);
        glDeleteBuffers(BUF_COUNT, b->buffers);
        glDeleteBuffers(1, &b->table_buffer);
        glDeleteBuffers(1, &b->status_buffer);
        glDeleteBuffers(1, &b->tile_list_buffer);
        glDeleteBuffers(1, &b->tile_next_buffer);
        glDeleteBuffers(1, &b->tile_mark_buffer);
        if (b->material_buffer) {
            glDeleteBuffers(1, &b->material_buffer);
            glDeleteTextures(1, &b->material_texture);
        }
        if (b->cache)
            gl_cache_delete_gl(b->cache);
    }
    gl_cache_free(b->cache);
    gl_context_destroy(b->context);
    free(b->entries);
    free(b->status_host);
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
    b->base.gpu_sync_stats = gl_gpu_sync_stats;
    b->base.set_stage_timing = gl_set_stage_timing;
    b->base.destroy = gl_destroy;
    b->cache = gl_cache_create(err);
    if (!b->cache) {
        free(b);
        return NULL;
    }
    b->context = gl_context_create(err);
    if (!b->context) {
        gl_cache_free(b->cache);
        free(b);
        return NULL;
    }
    snprintf(b->base.renderer, sizeof b->base.renderer, "%s", gl_context_renderer(b->context));
    snprintf(b->base.version, sizeof b->base.version, "%s", gl_context_version(b->context));

    for (int i = 0; i < PROG_COUNT; i++) {
        b->programs[i] = gl_program_compute(compute_names[i], err);
        if (!b->programs[i])
            goto fail;
    }
    if (gl_cache_load_programs(b->cache, err) != 0)
        goto fail;
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
    glGenBuffers(1, &b->tile_list_buffer);
    glGenBuffers(1, &b->tile_next_buffer);
    glGenBuffers(1, &b->tile_mark_buffer);
    if (gl_check("creating the backend", err) != 0)
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
