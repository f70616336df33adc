/*
 * context.c: a headless OpenGL >= 4.3 core context through EGL, with no
 * window and no X server. The sim thread creates it once (through the GL
 * backend) and owns it for the life of the daemon.
 *
 * Display candidates, in order:
 *   1. EGL_EXT_platform_device, hardware devices (a GPU: NVIDIA's driver
 *      exposes its devices this way, Mesa exposes DRM render nodes);
 *   2. EGL_MESA_platform_surfaceless (Mesa; llvmpipe when there is no GPU);
 *   3. EGL_EXT_platform_device, software devices (Mesa's own llvmpipe device).
 * A candidate is kept only if the whole chain works on it: eglInitialize, a
 * config that can render OpenGL, a 4.6..4.3 core context, surfaceless
 * make-current and GL >= 4.3. TERRAD_EGL_PLATFORM=device|surfaceless limits
 * the search to one platform. When everything fails, the error names the
 * first thing that was missing, since that is what an operator must install.
 */
#include "gl/gl_internal.h"

#include <ctype.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct gl_context {
    EGLDisplay display;
    EGLContext context;
    char renderer[256];
    char version[256];
};

#define MAX_DEVICES 16

/* Whole-word search in a space-separated extension string. */
static int has_word(const char *list, const char *word)
{
    if (!list)
        return 0;
    size_t n = strlen(word);
    for (const char *p = list; (p = strstr(p, word)) != NULL; p += n) {
        int starts = p == list || p[-1] == ' ';
        int ends = p[n] == '\0' || p[n] == ' ';
        if (starts && ends)
            return 1;
    }
    return 0;
}

static const char *egl_error_name(EGLint e)
{
    switch (e) {
    case EGL_SUCCESS:
        return "EGL_SUCCESS";
    case EGL_NOT_INITIALIZED:
        return "EGL_NOT_INITIALIZED";
    case EGL_BAD_ACCESS:
        return "EGL_BAD_ACCESS";
    case EGL_BAD_ALLOC:
        return "EGL_BAD_ALLOC";
    case EGL_BAD_ATTRIBUTE:
        return "EGL_BAD_ATTRIBUTE";
    case EGL_BAD_CONFIG:
        return "EGL_BAD_CONFIG";
    case EGL_BAD_CONTEXT:
        return "EGL_BAD_CONTEXT";
    case EGL_BAD_DISPLAY:
        return "EGL_BAD_DISPLAY";
    case EGL_BAD_MATCH:
        return "EGL_BAD_MATCH";
    case EGL_BAD_PARAMETER:
        return "EGL_BAD_PARAMETER";
    default:
        return "EGL error";
    }
}

/*
 * Try one display: the whole chain up to a current context with GL >= 4.3.
 * On failure the display is terminated, *why describes the first missing
 * piece, and NULL is returned.
 */
static gl_context *try_display(EGLDisplay dpy, const char *label, error_text *why)
{
    EGLint major = 0, minor = 0;
    if (dpy == EGL_NO_DISPLAY) {
        error_set(why, "gl: %s: no EGL display (%s)", label, egl_error_name(eglGetError()));
        return NULL;
    }
    if (!eglInitialize(dpy, &major, &minor)) {
        error_set(why,
                  "gl: %s: eglInitialize failed (%s): no usable driver (install "
                  "libgl1-mesa-dri, or the GPU's driver)",
                  label, egl_error_name(eglGetError()));
        return NULL;
    }
    EGLContext ctx = EGL_NO_CONTEXT;
    if (!epoxy_has_egl_extension(dpy, "EGL_KHR_surfaceless_context")) {
        error_set(why, "gl: %s: EGL_KHR_surfaceless_context is missing", label);
        goto fail;
    }
    if (!eglBindAPI(EGL_OPENGL_API)) {
        error_set(why, "gl: %s: desktop OpenGL is not available through EGL (eglBindAPI)", label);
        goto fail;
    }
    /* EGL_SURFACE_TYPE 0: no surface of any kind is needed (the default
     * would be EGL_WINDOW_BIT, which a surfaceless display never offers). */
    /* clang-format off */
    const EGLint config_attribs[] = {
        EGL_RENDERABLE_TYPE, EGL_OPENGL_BIT,
        EGL_SURFACE_TYPE, 0,
        EGL_NONE,
    };
    /* clang-format on */
    EGLConfig config = NULL;
    EGLint config_count = 0;
    if (!eglChooseConfig(dpy, config_attribs, &config, 1, &config_count) || config_count < 1) {
        if (epoxy_has_egl_extension(dpy, "EGL_KHR_no_config_context")) {
            config = EGL_NO_CONFIG_KHR;
        } else {
            error_set(why, "gl: %s: no EGL config can render desktop OpenGL", label);
            goto fail;
        }
    }
    /* The newest core version first; compute shaders need 4.3. */
    for (int v = 6; v >= 3 && ctx == EGL_NO_CONTEXT; v--) {
        /* clang-format off */
        const EGLint ctx_attribs[] = {
            EGL_CONTEXT_MAJOR_VERSION, 4,
            EGL_CONTEXT_MINOR_VERSION, v,
            EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT,
            EGL_NONE,
        };
        /* clang-format on */
        ctx = eglCreateContext(dpy, config, EGL_NO_CONTEXT, ctx_attribs);
    }
    if (ctx == EGL_NO_CONTEXT) {
        error_set(why,
                  "gl: %s: no OpenGL 4.3+ core context (the driver offers less; "
                  "compute shaders need 4.3)",
                  label);
        goto fail;
    }
    if (!eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, ctx)) {
        error_set(why, "gl: %s: eglMakeCurrent without a surface failed (%s)", label,
                  egl_error_name(eglGetError()));
        goto fail;
    }
    int gl_version = epoxy_gl_version();
    if (gl_version < 43) {
        error_set(why, "gl: %s: OpenGL %d.%d is too old (compute shaders need 4.3)", label,
                  gl_version / 10, gl_version % 10);
        goto fail;
    }
    gl_context *c = calloc(1, sizeof *c);
    if (!c) {
        error_set(why, "gl: out of memory");
        goto fail;
    }
    c->display = dpy;
    c->context = ctx;
    const char *renderer = (const char *)glGetString(GL_RENDERER);
    const char *version = (const char *)glGetString(GL_VERSION);
    snprintf(c->renderer, sizeof c->renderer, "%s", renderer ? renderer : "unknown");
    snprintf(c->version, sizeof c->version, "%s", version ? version : "unknown");
    return c;
fail:
    eglMakeCurrent(dpy, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    if (ctx != EGL_NO_CONTEXT)
        eglDestroyContext(dpy, ctx);
    eglTerminate(dpy);
    return NULL;
}

/* Remember the first failure: it names what is missing on this machine. */
static void keep_first(error_text *first, int *have_first, const error_text *why)
{
    if (!*have_first) {
        *first = *why;
        *have_first = 1;
    }
}

/* Devices of EGL_EXT_platform_device: hardware ones (software == 0) or Mesa's
 * software device (software == 1). */
static gl_context *try_devices(int software, error_text *first, int *have_first)
{
    EGLDeviceEXT devices[MAX_DEVICES];
    EGLint count = 0;
    if (!eglQueryDevicesEXT(MAX_DEVICES, devices, &count))
        return NULL;
    for (EGLint i = 0; i < count; i++) {
        const char *ext = eglQueryDeviceStringEXT(devices[i], EGL_EXTENSIONS);
        int is_software = has_word(ext, "EGL_MESA_device_software");
        if (is_software != software)
            continue;
        char label[64];
        snprintf(label, sizeof label, "EGL device %d%s", (int)i,
                 has_word(ext, "EGL_EXT_device_drm") ? " (DRM)" : "");
        EGLDisplay dpy = eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], NULL);
        error_text why;
        gl_context *c = try_display(dpy, label, &why);
        if (c)
            return c;
        keep_first(first, have_first, &why);
    }
    return NULL;
}

gl_context *gl_context_create(error_text *err)
{
    const char *client = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    const char *force = getenv("TERRAD_EGL_PLATFORM");
    int want_device = 1, want_surfaceless = 1;
    if (force && *force) {
        if (strcmp(force, "device") == 0) {
            want_surfaceless = 0;
        } else if (strcmp(force, "surfaceless") == 0) {
            want_device = 0;
        } else {
            error_set(err, "gl: TERRAD_EGL_PLATFORM must be device or surfaceless (got \"%s\")",
                      force);
            return NULL;
        }
    }
    if (!client) {
        error_set(err, "gl: no EGL client extensions: libEGL is missing or too old "
                       "(install libegl1 and libegl-mesa0)");
        return NULL;
    }
    int has_base = has_word(client, "EGL_EXT_platform_base");
    int has_enum =
        has_word(client, "EGL_EXT_device_enumeration") || has_word(client, "EGL_EXT_device_base");
    int has_device = has_base && has_enum && has_word(client, "EGL_EXT_platform_device");
    int has_surfaceless = has_base && has_word(client, "EGL_MESA_platform_surfaceless");
    if ((!want_device || !has_device) && (!want_surfaceless || !has_surfaceless)) {
        if (!want_surfaceless)
            error_set(err, "gl: no EGL display: EGL_EXT_platform_device is not available "
                           "(TERRAD_EGL_PLATFORM=device; install the GPU's EGL driver)");
        else if (!want_device)
            error_set(err, "gl: no EGL display: EGL_MESA_platform_surfaceless is not available "
                           "(TERRAD_EGL_PLATFORM=surfaceless; install libegl-mesa0)");
        else
            error_set(err, "gl: no EGL display: neither EGL_EXT_platform_device nor "
                           "EGL_MESA_platform_surfaceless is available (install libegl-mesa0)");
        return NULL;
    }

    error_text first;
    int have_first = 0;
    gl_context *c = NULL;
    if (want_device && has_device)
        c = try_devices(0, &first, &have_first);
    if (!c && want_surfaceless && has_surfaceless) {
        EGLDisplay dpy =
            eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, NULL);
        error_text why;
        c = try_display(dpy, "EGL surfaceless platform", &why);
        if (!c)
            keep_first(&first, &have_first, &why);
    }
    if (!c && want_device && has_device)
        c = try_devices(1, &first, &have_first);
    if (!c) {
        if (have_first)
            *err = first;
        else
            error_set(err, "gl: no EGL device offers OpenGL (install libegl-mesa0 and "
                           "libgl1-mesa-dri, or the GPU's EGL driver)");
        return NULL;
    }
    log_info("gl: renderer %s, version %s", c->renderer, c->version);
    return c;
}

const char *gl_context_renderer(const gl_context *c)
{
    return c->renderer;
}

const char *gl_context_version(const gl_context *c)
{
    return c->version;
}

int gl_renderer_is_software(const char *renderer)
{
    static const char *const software[] = {"llvmpipe", "softpipe", "swiftshader", "lavapipe",
                                           "software rasterizer"};
    char lower[256];
    size_t n = 0;
    for (; renderer && renderer[n] && n + 1 < sizeof lower; n++)
        lower[n] = (char)tolower((unsigned char)renderer[n]);
    lower[n] = 0;
    for (size_t i = 0; i < sizeof software / sizeof software[0]; i++)
        if (strstr(lower, software[i]))
            return 1;
    return 0;
}

int gl_probe_renderer(char *renderer, size_t cap, error_text *err)
{
    gl_context *c = gl_context_create(err);
    if (!c)
        return -1;
    snprintf(renderer, cap, "%s", c->renderer);
    gl_context_destroy(c);
    return 0;
}

/*
 * The display stays initialised: an EGL display is one per process and
 * platform, shared by every context on it, so eglTerminate here would pull
 * it from under any other context (a test's probe context and a backend's,
 * say). It also makes Mesa unload its driver with a few allocations never
 * freed, which leak checkers then report against us.
 */
void gl_context_destroy(gl_context *c)
{
    if (!c)
        return;
    if (eglGetCurrentContext() == c->context)
        eglMakeCurrent(c->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    eglDestroyContext(c->display, c->context);
    eglReleaseThread();
    free(c);
}

int gl_context_make_current(gl_context *c, error_text *err)
{
    if (eglGetCurrentContext() == c->context)
        return 0;
    if (!eglMakeCurrent(c->display, EGL_NO_SURFACE, EGL_NO_SURFACE, c->context)) {
        error_set(err, "gl: eglMakeCurrent failed (%s)", egl_error_name(eglGetError()));
        return -1;
    }
    return 0;
}

void gl_context_release(gl_context *c)
{
    if (eglGetCurrentContext() == c->context)
        eglMakeCurrent(c->display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
}
