/*
 * host_backend.c: picks a deformation backend by name for the commands,
 * once before the first tick; every tick's deformation then runs on it.
 *
 * `auto` (the default) chooses the faster one for this machine: GL where
 * the renderer is a hardware GPU, the CPU twin where GL is a software
 * rasteriser (llvmpipe on a CPU cloud machine runs the compute shaders on
 * the same cores, slower than the twin: issue 22 measured 28 against 60
 * ticks/s for 64 wheels) or cannot be made at all. The renderer is probed
 * once per process (a context made and destroyed) and the answer kept, so a
 * cluster node's worlds decide alike and cheaply. Heights do not depend on
 * the choice (GL ≡ CPU).
 */
#include <pthread.h>
#include <string.h>

#include "host/host.h"
#include "gl/gl.h"

static pthread_mutex_t auto_lock = PTHREAD_MUTEX_INITIALIZER;
static int auto_decided, auto_gl;
static char auto_reason[HOST_BACKEND_REASON_MAX];

/* The auto choice, probed on the first call. */
static int auto_choose(char *why, size_t cap)
{
    pthread_mutex_lock(&auto_lock);
    if (!auto_decided) {
        char renderer[256] = "";
        error_text err = {{0}};
        if (gl_probe_renderer(renderer, sizeof renderer, &err) != 0) {
            snprintf(auto_reason, sizeof auto_reason,
                     "auto: no GL context here (%.200s), so the CPU twin", err.message);
        } else if (gl_renderer_is_software(renderer)) {
            snprintf(auto_reason, sizeof auto_reason,
                     "auto: GL renderer \"%.200s\" is software, so the CPU twin (faster there)",
                     renderer);
        } else {
            auto_gl = 1;
            snprintf(auto_reason, sizeof auto_reason,
                     "auto: GL renderer \"%.200s\" is a hardware GPU", renderer);
        }
        auto_decided = 1;
    }
    int gl = auto_gl;
    snprintf(why, cap, "%s", auto_reason);
    pthread_mutex_unlock(&auto_lock);
    return gl;
}

sim_backend *host_backend_create(const char *name, char *why, size_t why_cap, error_text *err)
{
    char scratch[HOST_BACKEND_REASON_MAX];
    if (!why) {
        why = scratch;
        why_cap = sizeof scratch;
    }
    int gl;
    if (strcmp(name, "auto") == 0) {
        gl = auto_choose(why, why_cap);
    } else if (strcmp(name, "cpu") == 0 || strcmp(name, "gl") == 0) {
        gl = name[0] == 'g';
        snprintf(why, why_cap, "forced by --backend %s", name);
    } else {
        error_set(err, "--backend: must be auto, gl or cpu (got \"%s\")", name);
        return NULL;
    }
    sim_backend *b = gl ? sim_backend_gl_create(err) : sim_backend_cpu_create(err);
    if (b)
        log_info("backend: %s (%s)", b->name, why);
    return b;
}

int host_ground_attach(const scene *sc, const world *w, sim_engine *engine, ground *g,
                       error_text *err)
{
    if (scene_create_ground(sc, w, g, err) != 0)
        return -1;
    sim_engine_set_ground(engine, g);
    return 0;
}
