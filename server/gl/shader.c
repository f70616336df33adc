/*
 * shader.c: compiles and links the GL backend's programs from the shaders/
 * files embedded in the binary (embedded_file_find, base/base.h), so the daemon needs no
 * files at run time. Compute shaders share shaders/common.glsl through a
 * one-level `#include "common.glsl"` line that is spliced in here, with
 * #line directives so the driver's messages still point at the right file
 * and line (source string 0 is the shader, 1 the included file).
 */
#include "gl/gl_internal.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define INCLUDE_DIRECTIVE "#include \""

static void log_info_log(const char *what, const char *name, const char *text)
{
    log_error("gl: %s %s failed:", name, what);
    /* one log line per line of the driver's message */
    const char *p = text;
    while (p && *p) {
        size_t len = strcspn(p, "\n");
        if (len > 0)
            log_error("gl:   %.*s", (int)len, p);
        p += len;
        if (*p == '\n')
            p++;
    }
}

/* The first line of a driver message, for the one-line error text. */
static void first_line(const char *text, char *out, size_t size)
{
    size_t len = text ? strcspn(text, "\n") : 0;
    if (len >= size)
        len = size - 1;
    if (len)
        memcpy(out, text, len);
    out[len] = '\0';
}

/* A shader or program as the driver left it: obj when its status says so,
 * else 0 after logging the driver's message and deleting obj (what is
 * "compile" or "link"; the getters are the shader's or the program's). */
static GLuint checked(GLuint obj, GLenum status, void (*get_iv)(GLuint, GLenum, GLint *),
                      void (*get_log)(GLuint, GLsizei, GLsizei *, GLchar *),
                      void (*destroy)(GLuint), const char *what, const char *name, error_text *err)
{
    GLint ok = 0;
    get_iv(obj, status, &ok);
    if (ok)
        return obj;
    char log[4096] = "";
    get_log(obj, sizeof log, NULL, log);
    log_info_log(what, name, log);
    char line[160];
    first_line(log, line, sizeof line);
    error_set(err, "gl: %s does not %s: %s", name, what, line);
    destroy(obj);
    return 0;
}

static GLuint compile_stage(GLenum type, const char *name, error_text *err)
{
    size_t size = 0;
    const char *src = embedded_file_find(name, &size);
    if (!src) {
        error_set(err, "gl: shader %s is not embedded in this binary", name);
        log_error("gl: shader %s is not embedded in this binary", name);
        return 0;
    }
    /* Split around an include line, if any: before, included file, after. */
    const char *strings[5];
    GLint lengths[5];
    int count = 0;
    char line_inc[32], line_back[48];
    const char *inc = NULL;
    for (const char *p = src; p < src + size;) {
        const char *eol = memchr(p, '\n', (size_t)(src + size - p));
        size_t len = eol ? (size_t)(eol - p) : (size_t)(src + size - p);
        if (len > strlen(INCLUDE_DIRECTIVE) &&
            memcmp(p, INCLUDE_DIRECTIVE, strlen(INCLUDE_DIRECTIVE)) == 0) {
            inc = p;
            break;
        }
        p += len + 1;
    }
    if (!inc) {
        strings[count] = src;
        lengths[count++] = (GLint)size;
    } else {
        const char *name_start = inc + strlen(INCLUDE_DIRECTIVE);
        const char *name_end = memchr(name_start, '"', (size_t)(src + size - name_start));
        const char *eol = memchr(inc, '\n', (size_t)(src + size - inc));
        if (!name_end || (eol && name_end > eol) || name_end - name_start > 200) {
            error_set(err, "gl: %s: malformed #include line", name);
            log_error("gl: %s: malformed #include line", name);
            return 0;
        }
        char inc_name[256];
        snprintf(inc_name, sizeof inc_name, "shaders/%.*s", (int)(name_end - name_start),
                 name_start);
        size_t inc_size = 0;
        const char *inc_src = embedded_file_find(inc_name, &inc_size);
        if (!inc_src) {
            error_set(err, "gl: %s includes %s, which is not embedded", name, inc_name);
            log_error("gl: %s includes %s, which is not embedded", name, inc_name);
            return 0;
        }
        int inc_line = 1;
        for (const char *p = src; p < inc; p++)
            inc_line += *p == '\n';
        snprintf(line_inc, sizeof line_inc, "#line 1 1\n");
        snprintf(line_back, sizeof line_back, "\n#line %d 0\n", inc_line + 1);
        strings[count] = src;
        lengths[count++] = (GLint)(inc - src);
        strings[count] = line_inc;
        lengths[count++] = (GLint)strlen(line_inc);
        strings[count] = inc_src;
        lengths[count++] = (GLint)inc_size;
        strings[count] = line_back;
        lengths[count++] = (GLint)strlen(line_back);
        const char *after = eol ? eol + 1 : src + size;
        strings[count] = after;
        lengths[count++] = (GLint)(src + size - after);
    }
    GLuint shader = glCreateShader(type);
    glShaderSource(shader, count, strings, lengths);
    glCompileShader(shader);
    return checked(shader, GL_COMPILE_STATUS, glGetShaderiv, glGetShaderInfoLog, glDeleteShader,
                   "compile", name, err);
}

static GLuint link_program(const GLuint *shaders, int count, const char *name, error_text *err)
{
    GLuint program = glCreateProgram();
    for (int i = 0; i < count; i++)
        glAttachShader(program, shaders[i]);
    glLinkProgram(program);
    for (int i = 0; i < count; i++) {
        glDetachShader(program, shaders[i]);
        glDeleteShader(shaders[i]);
    }
    return checked(program, GL_LINK_STATUS, glGetProgramiv, glGetProgramInfoLog, glDeleteProgram,
                   "link", name, err);
}

GLuint gl_program_compute(const char *name, error_text *err)
{
    GLuint cs = compile_stage(GL_COMPUTE_SHADER, name, err);
    if (!cs)
        return 0;
    return link_program(&cs, 1, name, err);
}
