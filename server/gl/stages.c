/*
 * stages.c: the integer stages of the GL backend (gl_internal.h) — classify,
 * jump flooding, displacement (iterative, SSBO single or multiple target)
 * and slope evening — as one dispatch per pass for the whole chunk. The
 * compute shaders in shaders/ mirror sim_stages.c line for line, so the
 * heights equal the CPU twin's bit for bit (tests/unit/test_gl.c).
 */
#include "gl/gl_internal.h"

#include <string.h>

/* ---- the integer stages ---- */

void gl_stages_set_params(gl_backend *b, const sim_params *p, const ground_material_table *t)
{
    /* the uniform path is a one-row table of the params, as in sim_stages.c */
    ground_material_table uniform = {.count = 1};
    uniform.rows[0] = sim_material_row_from_params(p, 0);
    int per_cell = t != NULL;
    if (!t)
        t = &uniform;
    GLint rows[GROUND_MATERIALS_MAX * 4], max_compaction[GROUND_MATERIALS_MAX];
    memset(rows, 0, sizeof rows);
    memset(max_compaction, 0, sizeof max_compaction);
    for (int i = 0; i < t->count; i++) {
        rows[4 * i] = t->rows[i].compression_q16;
        rows[4 * i + 1] = t->rows[i].roughness_q16;
        rows[4 * i + 2] = t->rows[i].slope_threshold_axial;
        rows[4 * i + 3] = t->rows[i].slope_threshold_diagonal;
        max_compaction[i] = t->rows[i].max_compaction;
    }
    for (int prog = 0; prog < PROG_COUNT; prog++) {
        GLuint pr = b->programs[prog];
        const GLint *u = b->uniforms[prog];
        glProgramUniform1i(pr, u[U_METRIC], (GLint)p->metric);
        glProgramUniform1i(pr, u[U_OBSTACLE_GAP], p->obstacle_gap);
        glProgramUniform1i(pr, u[U_MULTI_STEP], p->multi_target_step);
        glProgramUniform1i(pr, u[U_MULTI_MAX], p->multi_target_max);
        glProgramUniform1i(pr, u[U_FLOOR], p->floor);
        glProgramUniform1i(pr, u[U_MATERIALS_ON], per_cell);
        glProgramUniform1i(pr, u[U_MATERIAL_COUNT], t->count);
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

/* Zero `words` 32-bit words of buffer at its start (a list's count, marks). */
static void clear_words(GLuint buffer, int64_t words)
{
    const GLuint zero = 0;
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, buffer);
    glClearBufferSubData(GL_SHADER_STORAGE_BUFFER, GL_R32UI, 0, (GLsizeiptr)(words * 4),
                         GL_RED_INTEGER, GL_UNSIGNED_INT, &zero);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
}

/* An empty tile list: count 0, and indirect groups of 0 rows of
 * TILE_LIST_ROW (the appending passes raise the rows). Also sets the row
 * length the appending programs use. */
static void list_reset(gl_backend *b, GLuint list)
{
    const GLuint header[4] = {0, TILE_LIST_ROW, 0, 1};
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, list);
    glBufferSubData(GL_SHADER_STORAGE_BUFFER, 0, sizeof header, header);
    glBindBuffer(GL_SHADER_STORAGE_BUFFER, 0);
    glProgramUniform1i(b->programs[PROG_TILE_LIST], b->uniforms[PROG_TILE_LIST][U_LIST_ROW],
                       TILE_LIST_ROW);
    glProgramUniform1i(b->programs[PROG_EVEN_SLOPES], b->uniforms[PROG_EVEN_SLOPES][U_LIST_ROW],
                       TILE_LIST_ROW);
}

/*
 * Sparse jump flooding, as sim_jump_flood on the CPU: tile_list.comp lists
 * the 8x8 tiles holding a cell that is not free (and the groups of an
 * indirect dispatch over them), and each step runs over the listed tiles only.
 * The other tiles hold free cells, which are their own seeds in both
 * ping-pong buffers (SEED_A copied to SEED_B once), so whichever buffer
 * ends the steps holds every cell's seed. Returns that buffer (BUF_*).
 */
int gl_stage_jump_flood(gl_backend *b, int max_side, int64_t cells)
{
    list_reset(b, b->tile_list_buffer);
    glProgramUniform1i(b->programs[PROG_TILE_LIST], b->uniforms[PROG_TILE_LIST][U_LIST_KIND], 0);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, b->tile_list_buffer);
    gl_sample(b, 1, BUF_CLS);
    gl_dispatch(b, PROG_TILE_LIST); /* its barrier lets the steps' dispatches read the groups */
    glBindBuffer(GL_COPY_READ_BUFFER, b->buffers[BUF_SEED_A]);
    glBindBuffer(GL_COPY_WRITE_BUFFER, b->buffers[BUF_SEED_B]);
    glCopyBufferSubData(GL_COPY_READ_BUFFER, GL_COPY_WRITE_BUFFER, 0, 0, (GLsizeiptr)(cells * 4));
    glBindBuffer(GL_COPY_READ_BUFFER, 0);
    glBindBuffer(GL_COPY_WRITE_BUFFER, 0);
    int in = BUF_SEED_A, out = BUF_SEED_B;
    for (int k = first_step(max_side); k >= 1; k /= 2) {
        glProgramUniform1i(b->programs[PROG_JUMP_FLOOD], b->uniforms[PROG_JUMP_FLOOD][U_STEP], k);
        gl_sample(b, 1, in);
        gl_bind(b, 2, out);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, b->tile_list_buffer);
        gl_dispatch_indirect(b, PROG_JUMP_FLOOD, b->tile_list_buffer, 4);
        int t = in;
        in = out;
        out = t;
    }
    return in;
}

/* One displacement dispatch of the three-in, two-out layout (displace_iterative_init,
 * displace_iterative_pass, displace_ssbo, displace_multi): prog reads units 1-3 (in1, in2,
 * in3) and writes bindings 2-3 (out2, out3). */
static void displace_pass(gl_backend *b, int prog, int in1, int in2, int in3, int out2, int out3)
{
    gl_sample(b, 1, in1);
    gl_sample(b, 2, in2);
    gl_sample(b, 3, in3);
    gl_bind(b, 2, out2);
    gl_bind(b, 3, out3);
    gl_dispatch(b, prog);
}

void gl_stage_displace(gl_backend *b, const sim_params *p, int64_t cells, int seed)
{
    if (p->method == SIM_METHOD_ITERATIVE) {
        /* mask words (with the split's remainder) and shares, ping-pong;
         * see displace_iterative_init.comp */
        int mask = BUF_S0, share = BUF_S1, mask_next = BUF_S2, share_next = BUF_S3;
        displace_pass(b, PROG_ITER_INIT, BUF_CLS, seed, BUF_MOVED, mask, share);
        for (int32_t pass = 0; pass < p->displace_iterations; pass++) {
            displace_pass(b, PROG_ITER_PASS, BUF_CLS, mask, share, mask_next, share_next);
            int t = mask;
            mask = mask_next;
            mask_next = t;
            t = share;
            share = share_next;
            share_next = t;
        }
        /* dead ends hand their transit to their seed (sim_stages.c) */
        gl_sample(b, 1, BUF_CLS);
        gl_sample(b, 2, seed);
        gl_sample(b, 3, mask);
        gl_bind(b, 2, share);
        gl_dispatch(b, PROG_ITER_DEAD_END);
        gl_sample(b, 1, mask);
        gl_sample(b, 2, share);
        gl_bind(b, 2, BUF_HEIGHTS);
        gl_dispatch(b, PROG_ITER_FINISH);
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
    gl_barrier();
    displace_pass(b, p->method == SIM_METHOD_MULTI ? PROG_DISPLACE_MULTI : PROG_DISPLACE_SSBO,
                  BUF_CLS, seed, BUF_MOVED, BUF_S0, BUF_S1);
    gl_sample(b, 1, BUF_S0);
    gl_sample(b, 2, BUF_S1);
    gl_bind(b, 2, BUF_HEIGHTS);
    gl_dispatch(b, PROG_DISPLACE_LAND);
}

/*
 * Sparse slope evening, as the CPU's work list at tile granularity: the
 * first list is the tiles where some cell differs from a neighbour by more
 * than the smallest threshold (tile_list.comp, kind 1; the heights are
 * copied into the other ping-pong buffer once); a tile where some cell
 * changed appends itself and its 8
 * neighbouring tiles of the same window to the next list (each once: a mark
 * per tile holds the iteration that listed it), and the next iteration is
 * an indirect dispatch over that list. A tile left out had no change within
 * one tile of it, so none of its cells can change, and its heights are
 * equal in both buffers (it was last written when it did not change).
 * Returns the buffer (BUF_*) that holds the final heights.
 */
int gl_stage_even_slopes(gl_backend *b, const sim_params *p, int materials, int64_t cells)
{
    int in = BUF_HEIGHTS, out = BUF_S0;
    GLuint cur = b->tile_list_buffer, next = b->tile_next_buffer;
    const GLuint prog = b->programs[PROG_EVEN_SLOPES];
    const GLint *u = b->uniforms[PROG_EVEN_SLOPES];
    if (p->slope_iterations <= 0)
        return in;
    clear_words(b->tile_mark_buffer, b->tile_count);
    /* the first list: tiles where some flux may have a positive excess */
    list_reset(b, cur);
    glProgramUniform1i(b->programs[PROG_TILE_LIST], b->uniforms[PROG_TILE_LIST][U_LIST_KIND], 1);
    glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, cur);
    gl_sample(b, 1, BUF_HEIGHTS);
    gl_dispatch(b, PROG_TILE_LIST);
    /* an unlisted tile holds its heights in both ping-pong buffers */
    glBindBuffer(GL_COPY_READ_BUFFER, b->buffers[BUF_HEIGHTS]);
    glBindBuffer(GL_COPY_WRITE_BUFFER, b->buffers[BUF_S0]);
    glCopyBufferSubData(GL_COPY_READ_BUFFER, GL_COPY_WRITE_BUFFER, 0, 0, (GLsizeiptr)(cells * 4));
    glBindBuffer(GL_COPY_READ_BUFFER, 0);
    glBindBuffer(GL_COPY_WRITE_BUFFER, 0);
    for (int32_t iter = 0; iter < p->slope_iterations; iter++) {
        if (materials) {
            glActiveTexture(GL_TEXTURE3);
            glBindTexture(GL_TEXTURE_BUFFER, b->material_texture);
        }
        list_reset(b, next);
        glProgramUniform1i(prog, u[U_SPARSE], 1);
        glProgramUniform1i(prog, u[U_STAMP], iter + 1);
        gl_sample(b, 1, BUF_CLS);
        gl_sample(b, 2, in);
        gl_bind(b, 2, out);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 3, cur);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 4, next);
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 5, b->tile_mark_buffer);
        gl_dispatch_indirect(b, PROG_EVEN_SLOPES, cur, 4);
        GLuint tl = cur;
        cur = next;
        next = tl;
        int t = in;
        in = out;
        out = t;
    }
    return in;
}

void gl_stage_dirty_rects(gl_backend *b, int heights)
{
    gl_sample(b, 1, heights);
    gl_sample(b, 2, BUF_ORIGINAL);
    gl_dispatch(b, PROG_DIRTY_RECT);
}

/* classify (+ heights -= raw, + jump-flood seeds) */
void gl_stage_classify(gl_backend *b, int materials)
{
    gl_sample(b, 1, BUF_BOTTOM);
    gl_bind(b, 2, BUF_HEIGHTS);
    gl_bind(b, 3, BUF_MOVED);
    gl_bind(b, 4, BUF_CLS);
    gl_bind(b, 5, BUF_SEED_A);
    if (materials)
        glBindBufferBase(GL_SHADER_STORAGE_BUFFER, 6, b->material_buffer);
    gl_dispatch(b, PROG_CLASSIFY);
}
