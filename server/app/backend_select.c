/*
 * backend_select.c: picks a deformation backend by name for the commands,
 * once before the first tick; every tick's deformation then runs on it.
 */
#include <string.h>

#include "app/app.h"
#include "gl/gl.h"

sim_backend *app_backend_create(const char *name, error_text *err)
{
    if (strcmp(name, "cpu") == 0)
        return sim_backend_cpu_create(err);
    if (strcmp(name, "gl") == 0)
        return sim_backend_gl_create(err);
    error_set(err, "--backend: must be gl or cpu (got \"%s\")", name);
    return NULL;
}
