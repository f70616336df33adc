/*
 * tile_cache.c: the GL backend's GPU tile cache (gl.h describes it; after
 * the large-terrain paper's block cache: blocks in an array texture, a
 * pointer table, an upload budget per frame). World tiles live in one R32I
 * GL_TEXTURE_2D_ARRAY, a layer per tile, keyed by tile coordinates and the
 * world's tile generation, LRU-evicted. At upload a window whose tiles are
 * all resident and current (uploading stale or missing ones while the
 * tick's byte budget lasts) is copied out of them by tile_gather.comp
 * through a per-window table of layers; after readback every accepted
 * window is written by tile_scatter.comp into those of its tiles that were
 * current when the tick began, and when the engine scatters the same ints
 * into the CPU world (window_scattered) the tiles' generations are brought
 * up to date. Everything else is uploaded from the CPU copy, so a full, tiny
 * or missing cache changes speed only.
 */
#include "gl/gl_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

tile_cache *gl_cache_create(error_text *err)
{
    tile_cache *c = calloc(1, sizeof *c);
    if (!c) {
        error_set(err, "gl backend: out of memory");
        return NULL;
    }
    c->layers_max = TILE_CACHE_LAYERS_DEFAULT;
    c->budget_bytes = TILE_CACHE_BUDGET_DEFAULT;
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
            free(c);
            return NULL;
        }
        c->layers_max = layers;
        c->budget_bytes = budget;
    }
    return c;
}

static const char *const cache_uniform_names[7] = {
    "u_origin", "u_size", "u_offset", "u_shift", "u_first_tile", "u_tiles_x", "u_layer_base",
};

int gl_cache_load_programs(tile_cache *c, error_text *err)
{
    c->gather = gl_program_compute("shaders/tile_gather.comp", err);
    if (!c->gather)
        return -1;
    c->scatter = gl_program_compute("shaders/tile_scatter.comp", err);
    if (!c->scatter)
        return -1;
    for (int u = 0; u < 7; u++) {
        c->gather_u[u] = glGetUniformLocation(c->gather, cache_uniform_names[u]);
        c->scatter_u[u] = glGetUniformLocation(c->scatter, cache_uniform_names[u]);
    }
    return 0;
}

void gl_cache_free(tile_cache *c)
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
void gl_cache_delete_gl(tile_cache *c)
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

/* Start a tick: decide whether the cache serves it, (re)make the texture for
 * the world's tile size, and drop everything if the world's base changed. */
int gl_cache_begin_tick(gl_backend *b, const sim_window_job *jobs, int count, error_text *err)
{
    tile_cache *c = b->cache;
    c->active = 0;
    if (array_grow((void **)&c->from_cache, &c->from_cache_capacity, count,
                   sizeof *c->from_cache) != 0 ||
        array_grow((void **)&c->table_base, &c->table_base_capacity, count,
                   sizeof *c->table_base) != 0) {
        error_set(err, "gl backend: out of memory for the tile cache");
        return -1;
    }
    memset(c->from_cache, 0, (size_t)count);
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
        if (gl_check("allocating the tile cache", err) != 0) {
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
int gl_cache_plan_chunk(gl_backend *b, const sim_window_job *jobs, int count, int first,
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
        if (n > c->layers || array_grow((void **)&c->table, &c->table_capacity, c->table_used + n,
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
    return gl_check("planning the tile cache", err);
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
    gl_sync.dispatches++;
}

void gl_cache_gather(gl_backend *b, const sim_window_job *job, int32_t offset, int64_t table_base)
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

void gl_cache_scatter(gl_backend *b, const sim_window_job *job, int32_t offset, int64_t table_base,
                      int heights)
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
void gl_window_scattered(sim_backend *base, int window, const world *w, world_rect r)
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

/* ---- configuration and statistics ---- */

void sim_backend_gl_set_tile_cache(sim_backend *base, int layers, int64_t budget_bytes)
{
    if (!base || !base->name || strcmp(base->name, "gl") != 0)
        return;
    tile_cache *c = ((gl_backend *)base)->cache;
    c->layers_max = layers > 0 ? layers : 0;
    c->budget_bytes = budget_bytes > 0 ? budget_bytes : 0;
}

/* The backend table's optional tile_cache_stats entry. */
void gl_tile_cache_stats(const sim_backend *base, sim_tile_cache_stats *out)
{
    *out = ((const gl_backend *)base)->cache->stats;
}
