/*
 * gl: the headless OpenGL side of terrad — an EGL context with no window and
 * no X server (Mesa's surfaceless platform where there is no GPU,
 * EGL_EXT_platform_device on NVIDIA), shaders embedded from shaders/, and the
 * GL backend of the deformation pipeline (sim.h), whose compute shaders
 * mirror the CPU twin's integer stages exactly.
 *
 * Only the sim thread may call into this subsystem: it owns the context. (A
 * backend may be created on another thread; the first batch makes the
 * context current on the thread that runs it, which keeps it.)
 */
#ifndef TERRAD_GL_H
#define TERRAD_GL_H

#include "base/base.h"
#include "sim/sim.h"

typedef struct gl_context gl_context;

/*
 * Make an OpenGL >= 4.3 core context current on this thread. On failure,
 * err names what is missing in one line (no EGL display, no surfaceless
 * platform, GL too old, no compute shaders ...). Logs GL_RENDERER and
 * GL_VERSION on success.
 */
gl_context *gl_context_create(error_text *err);
const char *gl_context_renderer(const gl_context *c);
const char *gl_context_version(const gl_context *c);
void gl_context_destroy(gl_context *c);

/*
 * Whether a GL_RENDERER string names a software rasteriser (Mesa's llvmpipe
 * and softpipe, SwiftShader, lavapipe, "Software Rasterizer"): GL there runs
 * the compute shaders on the CPU, slower than the CPU twin.
 */
int gl_renderer_is_software(const char *renderer);
/* Make a context, copy its GL_RENDERER into renderer and destroy it again:
 * what `--backend auto` asks before choosing. 0, or -1 with err set as by
 * gl_context_create. */
int gl_probe_renderer(char *renderer, size_t cap, error_text *err);

/* The GL backend: creates its own context. */
sim_backend *sim_backend_gl_create(error_text *err);

/* Stage timing (sim_backend_set_stage_timing, an optional entry of the
 * backend table): on, the backend waits for the GPU after every stage
 * (glFinish) so per-stage times are real; off (the default), it waits once
 * per batch, stage times are submission times and the wait is counted as
 * transfer. */

/*
 * Tests only: pretend the driver's limits are smaller, so that small batches
 * take the paths big ones need — at most chunk_cells cells per chunk
 * (several chunks per batch). 0 keeps the driver's value.
 */
void sim_backend_gl_set_limits(sim_backend *b, int64_t chunk_cells);

/*
 * The GPU tile cache: world tiles resident in one GL_TEXTURE_2D_ARRAY (R32I,
 * a layer per tile), LRU-evicted, at most budget_bytes uploaded per tick. A
 * window whose tiles are all resident and current is gathered on the GPU
 * from them and its result written back into them; any other window is
 * uploaded from the CPU copy as before, so correctness never depends on the
 * cache. layers 0 turns it off. Defaults: 64 layers, 4 MiB per tick; the
 * environment variable TERRAD_GL_TILE_CACHE="LAYERS,BUDGET_BYTES" overrides
 * them when the backend is created (tests use a tiny cache). Its statistics
 * are the backend table's optional tile_cache_stats entry
 * (sim_backend_tile_cache_stats).
 */
void sim_backend_gl_set_tile_cache(sim_backend *b, int layers, int64_t budget_bytes);

#endif
