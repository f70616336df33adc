/*
 * gl_internal.h: what the files of server/gl/ share and nobody else sees —
 * the GL and EGL entry points (libepoxy) and the shader loader.
 */
#ifndef TERRAD_GL_INTERNAL_H
#define TERRAD_GL_INTERNAL_H

#include <epoxy/egl.h>
#include <epoxy/gl.h>

#include "gl/gl.h"

/* Make c current on the calling thread if it is not already. */
int gl_context_make_current(gl_context *c, error_text *err);
/* Let go of c on this thread, so that another thread can make it current. */
void gl_context_release(gl_context *c);

/*
 * Programs from the embedded shaders/ files ("shaders/classify.comp"). A
 * line `#include "NAME"` is replaced by the embedded file "shaders/NAME".
 * On failure the file name and the driver's info log are logged, err names
 * the file, and 0 is returned.
 */
GLuint gl_program_compute(const char *name, error_text *err);
GLuint gl_program_raster(const char *vertex_name, const char *fragment_name, error_text *err);

#endif
