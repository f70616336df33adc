/*
 * obj.c: Wavefront OBJ meshes for mesh colliders (a boot, a track link, a
 * robot foot). Loaded once when a scene or a client registers the collider;
 * the tick then uses the triangles in the fixed-point depth rule
 * (depth_fixed.c on the CPU, shaders/depth_exact.comp on GL). Only `v` and
 * `f` lines matter: polygons are fanned into triangles, indices may be `i`, `i/t`, `i//n`, `i/t/n`
 * or negative (relative to the vertices read so far). Everything that would make a wrong depth
 * later — no triangles, an index out of range, a NaN coordinate, an absurd size — is refused here
 * with the file and line in the message.
 */
#include "collider/collider.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define OBJ_VERTICES_MAX 10000000
#define OBJ_TRIANGLES_MAX 20000000
#define OBJ_FILE_BYTES_MAX ((size_t)1 << 30)

typedef struct obj_reader {
    const char *path;
    float *v;
    int vn;
    int64_t vcap; /* floats */
    uint32_t *idx;
    int tn;       /* triangles */
    int64_t tcap; /* indices */
    error_text *err;
} obj_reader;

static int parse_vertex(obj_reader *r, char *s, int line)
{
    if (r->vn >= OBJ_VERTICES_MAX) {
        error_set(r->err, "%s:%d: more than %d vertices", r->path, line, OBJ_VERTICES_MAX);
        return -1;
    }
    double c[3];
    for (int k = 0; k < 3; k++) {
        char *end;
        errno = 0;
        c[k] = strtod(s, &end);
        if (end == s) {
            error_set(r->err, "%s:%d: vertex needs three numbers", r->path, line);
            return -1;
        }
        if (!isfinite(c[k]) || fabs(c[k]) > 1e6) {
            error_set(r->err, "%s:%d: vertex coordinate %d is not a finite number within 1e6",
                      r->path, line, k);
            return -1;
        }
        s = end;
    }
    if (array_grow((void **)&r->v, &r->vcap, 3 * ((int64_t)r->vn + 1), sizeof *r->v) != 0) {
        error_set(r->err, "%s:%d: out of memory", r->path, line);
        return -1;
    }
    for (int k = 0; k < 3; k++)
        r->v[3 * (size_t)r->vn + k] = (float)c[k];
    r->vn++;
    return 0;
}

static int parse_face(obj_reader *r, char *s, int line, int total_vertices)
{
    uint32_t first = 0, prev = 0;
    int count = 0;
    for (;;) {
        while (*s == ' ' || *s == '\t')
            s++;
        if (*s == '\0' || *s == '#')
            break;
        char *end;
        errno = 0;
        long i = strtol(s, &end, 10);
        if (end == s || errno == ERANGE) {
            error_set(r->err, "%s:%d: face index %d is not an integer", r->path, line, count + 1);
            return -1;
        }
        /* skip /t, //n, /t/n */
        while (*end && *end != ' ' && *end != '\t')
            end++;
        s = end;
        long resolved = i < 0 ? (long)r->vn + i : i - 1; /* negative: relative to vertices so far */
        if (i == 0 || resolved < 0 || resolved >= total_vertices) {
            error_set(r->err, "%s:%d: face index %ld out of range (%d vertices)", r->path, line, i,
                      i < 0 ? r->vn : total_vertices);
            return -1;
        }
        uint32_t v = (uint32_t)resolved;
        if (count == 0)
            first = v;
        else if (count >= 2) {
            if (r->tn >= OBJ_TRIANGLES_MAX) {
                error_set(r->err, "%s:%d: more than %d triangles", r->path, line,
                          OBJ_TRIANGLES_MAX);
                return -1;
            }
            if (array_grow((void **)&r->idx, &r->tcap, 3 * ((int64_t)r->tn + 1), sizeof *r->idx) !=
                0) {
                error_set(r->err, "%s:%d: out of memory", r->path, line);
                return -1;
            }
            uint32_t *t = r->idx + 3 * (size_t)r->tn++;
            t[0] = first;
            t[1] = prev;
            t[2] = v;
        }
        prev = v;
        count++;
    }
    if (count < 3) {
        error_set(r->err, "%s:%d: face needs at least 3 vertices (got %d)", r->path, line, count);
        return -1;
    }
    return 0;
}

/* "v"/"f" keyword at the start of a line (after blanks), else NULL. */
static char *keyword(char *line, const char *kw)
{
    while (*line == ' ' || *line == '\t')
        line++;
    size_t n = strlen(kw);
    if (strncmp(line, kw, n) == 0 && (line[n] == ' ' || line[n] == '\t'))
        return line + n;
    return NULL;
}

int collider_mesh_load_obj(const char *path, collider_mesh *mesh, error_text *err)
{
    memset(mesh, 0, sizeof *mesh);
    uint8_t *data = NULL;
    size_t size = 0;
    if (file_read_all(path, OBJ_FILE_BYTES_MAX, &data, &size, err) != 0)
        return -1;
    char *text = (char *)data; /* NUL-terminated by file_read_all */
    if (memchr(text, '\0', size)) {
        error_set(err, "%s: not a text file (contains NUL bytes)", path);
        free(text);
        return -1;
    }

    /* First pass counts vertices, so a face may name any vertex of the file. */
    int total = 0;
    for (char *p = text; p && *p;) {
        char *nl = strchr(p, '\n');
        if (nl)
            *nl = '\0';
        if (keyword(p, "v") && total <= OBJ_VERTICES_MAX)
            total++;
        if (nl)
            *nl = '\n';
        p = nl ? nl + 1 : NULL;
    }

    obj_reader r = {.path = path, .err = err};
    int line = 0, rc = 0;
    for (char *p = text; p && *p && rc == 0;) {
        char *nl = strchr(p, '\n');
        if (nl)
            *nl = '\0';
        line++;
        char *cr = strchr(p, '\r');
        if (cr)
            *cr = '\0';
        char *args;
        if ((args = keyword(p, "v")))
            rc = parse_vertex(&r, args, line);
        else if ((args = keyword(p, "f")))
            rc = parse_face(&r, args, line, total);
        p = nl ? nl + 1 : NULL;
    }
    free(text);
    if (rc == 0 && r.tn == 0) {
        error_set(err, "%s: no triangles (no f lines with 3 or more vertices)", path);
        rc = -1;
    }
    if (rc != 0) {
        free(r.v);
        free(r.idx);
        return -1;
    }
    double br = 0.0;
    for (int i = 0; i < r.vn; i++) {
        const float *v = r.v + 3 * (size_t)i;
        double d = sqrt((double)v[0] * v[0] + (double)v[1] * v[1] + (double)v[2] * v[2]);
        if (d > br)
            br = d;
    }
    mesh->vertex_count = r.vn;
    mesh->triangle_count = r.tn;
    mesh->vertices = r.v;
    mesh->indices = r.idx;
    mesh->bounding_radius = br;
    return 0;
}

void collider_mesh_free(collider_mesh *mesh)
{
    if (!mesh)
        return;
    free(mesh->vertices);
    free(mesh->indices);
    memset(mesh, 0, sizeof *mesh);
}
