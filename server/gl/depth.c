/*
 * depth.c: the GL backend's depth stage (gl_internal.h), row 4d.1 of the
 * tick table in docs/design.md, on the GPU. Every shape is computed exactly
 * by depth_exact.comp, the GLSL twin of collider/depth_fixed.c: the same
 * bottoms as the CPU twin's sim_window_depth, bit for bit. depth_clear.comp
 * first sets the bottoms of the windows that need a depth to
 * COLLIDER_BOTTOM_NONE (windows whose bottom was uploaded keep it), then the
 * instances — one per shape, sub-step pose of the swept collider and window,
 * a mesh one per triangle, a lugged wheel one per lug beside its rim — lower them with atomicMin.
 * (Until issue 12 the colliders were rasterised into a depth atlas in float; that path and its
 * atlas, geometry cache and vertex/fragment programs are gone.)
 */
#include "gl/gl_internal.h"

#include <stdlib.h>

/*
 * The fixed-point shapes (collider/depth_fixed.c): one instance per shape,
 * sub-step pose and window that needs a depth, prepared on the CPU exactly as the
 * CPU twin prepares them, uploaded, and lowered into the bottoms by
 * depth_exact.comp (one workgroup row per instance) after depth_clear.comp
 * has set them to COLLIDER_BOTTOM_NONE.
 */
static int depth_exact(gl_backend *b, const sim_window_job *jobs, int count, error_text *err)
{
    int64_t n = 0, max_cells = 1;
    for (int i = 0; i < count; i++) {
        if (!b->entries[i].cast_depth)
            continue; /* its bottom was uploaded */
        for (int c = 0; c < jobs[i].collider_count; c++) {
            const sim_collider *col = &jobs[i].colliders[c];
            if (!collider_fixed_supported(col->geometry))
                continue; /* a mesh without triangles: nothing to press */
            int steps = sim_collider_sweep_steps(col, jobs[i].cell_size_m);
            for (int k = 1; k <= steps; k++) {
                /* a primitive's one instance, a mesh's triangles, a lugged wheel's lugs */
                int64_t first = n;
                if (collider_fixed_instances(col->geometry, sim_collider_sweep_pose(col, k, steps),
                                             jobs[i].rect, jobs[i].cell_size_m, jobs[i].units_per_m,
                                             &b->exact_host, &n, &b->exact_host_capacity) < 0) {
                    error_set(err, "gl backend: out of memory for depth instances");
                    return -1;
                }
                for (int64_t t = first; t < n; t++) {
                    b->exact_host[t].v[CF_WINDOW] = i;
                    if (b->exact_host[t].v[CF_W] * b->exact_host[t].v[CF_H] > max_cells)
                        max_cells = b->exact_host[t].v[CF_W] * b->exact_host[t].v[CF_H];
                }
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

int gl_depth_run(gl_backend *b, sim_window_job *jobs, int count, error_text *err)
{
    int any = 0;
    for (int i = 0; i < count && !any; i++)
        any = b->entries[i].cast_depth;
    if (!any)
        return 0; /* every window came with its bottom */
    glUseProgram(b->programs[PROG_DEPTH_CLEAR]);
    gl_bind(b, 2, BUF_BOTTOM);
    gl_dispatch(b, PROG_DEPTH_CLEAR);
    if (depth_exact(b, jobs, count, err) != 0)
        return -1;
    return gl_check("depth stage", err);
}

void gl_forget_geometry(sim_backend *base, const collider_geometry *g)
{
    (void)base; /* instances are prepared per tick: nothing is cached per geometry */
    (void)g;
}

void gl_depth_delete(gl_backend *b)
{
    if (b->exact_buffer)
        glDeleteBuffers(1, &b->exact_buffer);
    b->exact_buffer = 0;
    b->exact_buffer_bytes = 0;
    free(b->exact_host);
    b->exact_host = NULL;
    b->exact_host_capacity = 0;
}
