/*
 * json_fields.c: strict readers of JSON fields (base.h), shared by the scene
 * parser, the ground's material map, the daemon's configuration file and the
 * websocket control messages. Strictness is the point: a value of the wrong
 * type, out of range or not finite is refused with the JSON path that names
 * it, never silently replaced by a default.
 */
#include "base/base.h"

#include <cjson/cJSON.h>
#include <math.h>
#include <stdarg.h>
#include <string.h>

/* JSON paths are short in practice; a pathological one is cut, never overrun. */
static void json_path_format(char *out, size_t size, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static void json_path_format(char *out, size_t size, const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(out, size, fmt, ap);
    va_end(ap);
}

/* "world" + "width" → "world.width"; "" + "name" → "name". */
void json_path_join(char *out, size_t size, const char *parent, const char *key)
{
    if (parent[0])
        json_path_format(out, size, "%s.%s", parent, key);
    else
        json_path_format(out, size, "%s", key);
}

void json_path_index(char *out, size_t size, const char *parent, int i)
{
    json_path_format(out, size, "%s[%d]", parent, i);
}

const char *json_type_name(const cJSON *v)
{
    if (cJSON_IsNumber(v))
        return "a number";
    if (cJSON_IsString(v))
        return "a string";
    if (cJSON_IsBool(v))
        return "a boolean";
    if (cJSON_IsNull(v))
        return "null";
    if (cJSON_IsArray(v))
        return "an array";
    if (cJSON_IsObject(v))
        return "an object";
    return "an unknown value";
}

int json_expect_object(const cJSON *v, const char *path, const char *root_name, error_text *err)
{
    if (!cJSON_IsObject(v)) {
        error_set(err, "%s: must be an object (got %s)", path[0] ? path : root_name,
                  json_type_name(v));
        return -1;
    }
    return 0;
}

/* Every key of obj must be in allowed (NULL-terminated), once. */
int json_check_keys(const cJSON *obj, const char *path, const char *const *allowed,
                    const char *context, error_text *err)
{
    for (const cJSON *c = obj->child; c; c = c->next) {
        char p[256];
        json_path_join(p, sizeof p, path, c->string ? c->string : "");
        int known = 0;
        for (const char *const *a = allowed; *a; a++)
            if (c->string && strcmp(c->string, *a) == 0)
                known = 1;
        if (!known) {
            if (context)
                error_set(err, "%s: unknown key for %s", p, context);
            else
                error_set(err, "%s: unknown key", p);
            return -1;
        }
        for (const cJSON *d = obj->child; d != c; d = d->next)
            if (d->string && strcmp(d->string, c->string) == 0) {
                error_set(err, "%s: duplicate key", p);
                return -1;
            }
    }
    return 0;
}

/* The field key of obj (NULL when absent) and its path for messages, into p. */
static const cJSON *field(const cJSON *obj, const char *path, const char *key, char p[256])
{
    json_path_join(p, 256, path, key);
    return cJSON_GetObjectItemCaseSensitive(obj, key);
}

/* "P: must be WHAT (got X)": X the number when a number field holds one (its
 * value was wrong), else v's type; -1. */
static int refuse(error_text *err, const char *p, const char *what, const cJSON *v)
{
    if (cJSON_IsNumber(v))
        error_set(err, "%s: must be %s (got %g)", p, what, v->valuedouble);
    else
        error_set(err, "%s: must be %s (got %s)", p, what, json_type_name(v));
    return -1;
}

/* v (at p) accepted when ok, named what in messages: 1 present, 0 absent (an
 * error when required), -1 refused. */
static int get_checked(int required, const char *what, int ok, const cJSON *v, const char *p,
                       double *out, error_text *err)
{
    if (!v) {
        if (!required)
            return 0;
        error_set(err, "%s: missing (%s)", p, what);
        return -1;
    }
    if (!ok)
        return refuse(err, p, what, v);
    *out = v->valuedouble;
    return 1;
}

/* A finite number in [lo, hi]. Returns 1 when present, 0 when absent, -1 on
 * error, which names the first test the value fails: a number, finite, in
 * range. */
int json_get_number(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                    double *out, error_text *err)
{
    char p[256], range[96] = "";
    const cJSON *v = field(obj, path, key, p);
    int number = cJSON_IsNumber(v), finite = number && isfinite(v->valuedouble);
    int ok = finite && v->valuedouble >= lo && v->valuedouble <= hi;
    if (finite && !ok)
        json_path_format(range, sizeof range, "in [%g, %g]", lo, hi);
    const char *what = !number ? "a number" : !finite ? "a finite number" : range;
    return get_checked(0, what, ok, v, p, out, err);
}

int json_require_number(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                        double *out, error_text *err)
{
    int r = json_get_number(obj, path, key, lo, hi, out, err);
    if (r == 0) {
        char p[256];
        json_path_join(p, sizeof p, path, key);
        error_set(err, "%s: missing (a number in [%g, %g])", p, lo, hi);
        return -1;
    }
    return r < 0 ? -1 : 0;
}

/* Present and positive: (0, hi]. */
int json_get_positive(const cJSON *obj, const char *path, const char *key, double hi, int required,
                      double *out, error_text *err)
{
    char p[256], what[96];
    const cJSON *v = field(obj, path, key, p);
    json_path_format(what, sizeof what, "a finite number > 0 and <= %g", hi);
    int ok = cJSON_IsNumber(v) && isfinite(v->valuedouble) && v->valuedouble > 0.0 &&
             v->valuedouble <= hi;
    return get_checked(required, what, ok, v, p, out, err);
}

/* An integer in [lo, hi]. Returns 1 when present, 0 when absent, -1 on error. */
int json_get_integer(const cJSON *obj, const char *path, const char *key, double lo, double hi,
                     int required, double *out, error_text *err)
{
    char p[256], what[96];
    const cJSON *v = field(obj, path, key, p);
    json_path_format(what, sizeof what, "an integer in [%.0f, %.0f]", lo, hi);
    int ok = cJSON_IsNumber(v) && isfinite(v->valuedouble) &&
             v->valuedouble == floor(v->valuedouble) && v->valuedouble >= lo &&
             v->valuedouble <= hi;
    return get_checked(required, what, ok, v, p, out, err);
}

/* A string shorter than size. Returns 1 when present, 0 when absent, -1 on error. */
int json_get_string(const cJSON *obj, const char *path, const char *key, char *out, size_t size,
                    error_text *err)
{
    char p[256];
    const cJSON *v = field(obj, path, key, p);
    if (!v)
        return 0;
    if (!cJSON_IsString(v) || !v->valuestring) {
        error_set(err, "%s: must be a string (got %s)", p, json_type_name(v));
        return -1;
    }
    if (strlen(v->valuestring) >= size) {
        error_set(err, "%s: must be shorter than %zu bytes", p, size);
        return -1;
    }
    snprintf(out, size, "%s", v->valuestring);
    return 1;
}

/* An array of n finite numbers, each with |x| <= limit. */
int json_get_vector(const cJSON *obj, const char *path, const char *key, int n, double limit,
                    double *out, error_text *err)
{
    char p[256], what[96];
    const cJSON *v = field(obj, path, key, p);
    if (!v)
        return 0;
    if (!cJSON_IsArray(v) || cJSON_GetArraySize(v) != n) {
        error_set(err, "%s: must be an array of %d numbers", p, n);
        return -1;
    }
    int i = 0;
    for (const cJSON *e = v->child; e; e = e->next, i++) {
        char q[280];
        json_path_format(q, sizeof q, "%s[%d]", p, i);
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble))
            return refuse(err, q, "a finite number", e);
        if (fabs(e->valuedouble) > limit) {
            json_path_format(what, sizeof what, "within [-%g, %g]", limit, limit);
            return refuse(err, q, what, e);
        }
        out[i] = e->valuedouble;
    }
    return 1;
}

int json_get_bool(const cJSON *obj, const char *path, const char *key, int *out, error_text *err)
{
    char p[256];
    const cJSON *v = field(obj, path, key, p);
    if (!v)
        return 0;
    if (!cJSON_IsBool(v)) {
        error_set(err, "%s: must be true or false (got %s)", p, json_type_name(v));
        return -1;
    }
    *out = cJSON_IsTrue(v) ? 1 : 0;
    return 1;
}

char *json_print_delete(cJSON *o)
{
    char *text = cJSON_PrintUnformatted(o);
    cJSON_Delete(o);
    return text;
}
