/*
 * depth.c: the GL backend's depth stage (gl_internal.h). Collider geometries
 * are tessellated (collider_tessellate) and uploaded once, cached by
 * pointer. The windows that need a depth are packed into one
 * GL_DEPTH_COMPONENT32F atlas by shelves (tallest first); each collider is
 * drawn once per window it meets with an orthographic camera under the
 * window, and depth_to_bottom.comp turns the atlas into the int32 bottoms
 * the integer stages read. Every shape is now computed exactly instead
 * (depth_exact, collider/depth_fixed.c's GLSL twin), after the raster: the
 * same bottoms as the CPU twin's sim_window_depth, bit for bit. The raster
 * path remains for shapes collider_fixed_supported refuses (none today). A batch too large for the
 * largest texture is rasterised in rounds, each converted before the next clears the atlas.
 */
#include "gl/gl_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

int gl_depth_ensure_atlas(gl_backend *b, int w, int h, error_text *err)
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
    return gl_check("allocating the depth atlas", err);
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
    if (array_grow((void **)&b->geometries, &b->geometry_capacity, b->geometry_count + 1,
                   sizeof *b->geometries) != 0) {
        free(vertices);
        free(indices);
        error_set(err, "gl backend: out of memory caching colliders");
        return NULL;
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
    if (gl_check("uploading collider triangles", err) != 0) {
        glDeleteVertexArrays(1, &e->vao);
        glDeleteBuffers(1, &e->vbo);
        glDeleteBuffers(1, &e->ebo);
        return NULL;
    }
    b->geometry_count++;
    return e;
}

void gl_forget_geometry(sim_backend *base, const collider_geometry *g)
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
int gl_depth_pack_atlas(gl_backend *b, const sim_window_job *jobs, int count, int *atlas_w,
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

/*
 * The fixed-point shapes (collider/depth_fixed.c): one instance per shape,
 * sub-step pose and rasterised window, prepared on the CPU exactly as the
 * CPU twin prepares them, uploaded, and lowered into the bottoms by
 * depth_exact.comp (one workgroup row per instance) after the raster's
 * bottoms are written.
 */
static int depth_exact(gl_backend *b, const sim_window_job *jobs, int count, error_text *err)
{
    int64_t n = 0, max_cells = 1;
    for (int i = 0; i < count; i++) {
        if (b->entries[i].raster_round == 0)
            continue; /* its bottom was uploaded */
        for (int c = 0; c < jobs[i].collider_count; c++) {
            const sim_collider *col = &jobs[i].colliders[c];
            if (!collider_fixed_supported(col->geometry))
                continue;
            int steps = sim_collider_sweep_steps(col, jobs[i].cell_size_m);
            for (int k = 1; k <= steps; k++) {
                if (col->geometry->shape == COLLIDER_MESH) {
                    int64_t first = n;
                    if (collider_fixed_mesh_prepare(
                            col->geometry, sim_collider_sweep_pose(col, k, steps), jobs[i].rect,
                            jobs[i].cell_size_m, jobs[i].units_per_m, &b->exact_host, &n,
                            &b->exact_host_capacity) < 0) {
                        error_set(err, "gl backend: out of memory for depth instances");
                        return -1;
                    }
                    for (int64_t t = first; t < n; t++) {
                        b->exact_host[t].v[CF_WINDOW] = i;
                        if (b->exact_host[t].v[CF_W] * b->exact_host[t].v[CF_H] > max_cells)
                            max_cells = b->exact_host[t].v[CF_W] * b->exact_host[t].v[CF_H];
                    }
                    continue;
                }
                if (array_grow((void **)&b->exact_host, &b->exact_host_capacity, n + 1,
                               sizeof *b->exact_host) != 0) {
                    error_set(err, "gl backend: out of memory for depth instances");
                    return -1;
                }
                collider_fixed *f = &b->exact_host[n];
                if (!collider_fixed_prepare(col->geometry, sim_collider_sweep_pose(col, k, steps),
                                            jobs[i].rect, jobs[i].cell_size_m, jobs[i].units_per_m,
                                            f))
                    continue;
                f->v[CF_WINDOW] = i;
                if (f->v[CF_W] * f->v[CF_H] > max_cells)
                    max_cells = f->v[CF_W] * f->v[CF_H];
                n++;
            }
        }
    }
    if (n == 0)
        return 0;
    int64_t bytes = n * (int64_t)sizeof *b->exact_host;
    if (!b->exact_buffer)
        glGenBuffers(1, &b->exact_buffer);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, b->exact_buffer);
    if (bytes > b->exact_buffer_bytes) {
        glBufferData(GL_SHADER_STORAGE_BUFFER, (GLsizeiptr)bytes, NULL, GL_DYNAMIC_DRAW);
        b->exact_buffer_bytes = bytes;
    }
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, (GLsizeiptr)bytes, b->exact_host);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    glUseProgram(b->programs[PROG_DEPTH_EXACT]);
    glActiveTexture(GL_TEXTURE0);
    glBindTexture(GL_TEXTURE_BUFFER, b->table_texture);
    gl_bind(b, 2, BUF_BOTTOM);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, b->exact_buffer);
    int64_t gx = (max_cells + 63) / 64;
    if (gx > 64)
        gx = 64; /* the shader strides over the rest */
    for (int64_t first = 0; first < n; first += 65535) {
        int64_t rows = n - first < 65535 ? n - first : 65535;
        glUniform1i(b->uniforms[PROG_DEPTH_EXACT][U_STEP], (GLint)first);
        glDispatchCompute((GLuint)gx, (GLuint)rows, 1);
    }
    gl_barrier();
    return gl_check("exact depth", err);
}

int gl_depth_run(gl_backend *b, sim_window_job *jobs, int count, int rounds, error_text *err)
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
                if (collider_fixed_supported(col->geometry))
                    continue; /* computed exactly by depth_exact.comp below */
                geometry_entry *g = geometry_find(b, col->geometry, err);
                if (!g)
                    return -1;
                glBindVertexArray(g->vao);
                /* the swept collider: the CPU's sub-step poses, drawn one by one */
                int steps = sim_collider_sweep_steps(col, jobs[i].cell_size_m);
                for (int k = 1; k <= steps; k++) {
                    float mvp[16];
                    window_mvp(&jobs[i], sim_collider_sweep_pose(col, k, steps), mvp);
                    glUniformMatrix4fv(b->uniforms[PROG_RASTER][U_MVP], 1, GL_FALSE, mvp);
                    glDrawElements(GL_TRIANGLES, g->index_count, GL_UNSIGNED_INT, NULL);
                    gl_sync.draws++;
                }
            }
        }
        glBindVertexArray(0);
        glMemoryBarrier(GL_FRAMEBUFFER_BARRIER_BIT | GL_TEXTURE_FETCH_BARRIER_BIT);
        gl_sync.barriers++;
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, b->atlas);
        glUseProgram(b->programs[PROG_DEPTH_TO_BOTTOM]);
        glUniform1i(b->uniforms[PROG_DEPTH_TO_BOTTOM][U_ROUND], round);
        gl_bind(b, 2, BUF_BOTTOM);
        gl_dispatch(b, PROG_DEPTH_TO_BOTTOM);
        glActiveTexture(GL_TEXTURE1);
        glBindTexture(GL_TEXTURE_2D, 0);
    }
    glDisable(GL_SCISSOR_TEST);
    glDisable(GL_DEPTH_CLAMP);
    glDisable(GL_DEPTH_TEST);
    glBindFramebuffer(GL_FRAMEBUFFER, 0);
    if (depth_exact(b, jobs, count, err) != 0)
        return -1;
    return gl_check("depth stage", err);
}

void gl_depth_delete_geometries(gl_backend *b)
{
    if (b->exact_buffer)
        glDeleteBuffers(1, &b->exact_buffer);
    b->exact_buffer = 0;
    b->exact_buffer_bytes = 0;
    free(b->exact_host);
    b->exact_host = NULL;
    b->exact_host_capacity = 0;
    for (int i = 0; i < b->geometry_count; i++) {
        glDeleteVertexArrays(1, &b->geometries[i].vao);
        glDeleteBuffers(1, &b->geometries[i].vbo);
        glDeleteBuffers(1, &b->geometries[i].ebo);
    }
}
