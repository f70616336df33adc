/*
 * serve_worlds_body.c: the one check of a POST /v1/worlds body and the one
 * shape of a refusal, shared by a single daemon's created worlds
 * (serve_worlds.c) and a cluster node's registry (serve_node_api.c), so both
 * refuse the same input with the same status, field and words (issue 22).
 * Runs on an HTTP thread, off every tick: it parses the scene with the
 * daemon's own parser and makes nothing of it.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "app/serve_internal.h"
#include "metrics/metrics.h"

#define SCENE_MAX_BYTES (1 << 20)
#define PATH_CAP 1200

char *worlds_error_json(const char *field, const char *why)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "error", why);
    cJSON_AddStringToObject(o, "field", field);
    return json_print_delete(o);
}

unsigned worlds_refuse(const char *op, unsigned code, const char *field, const char *why,
                       char **json)
{
    metrics_count_world_request(op, 0);
    log_info("worlds: %s refused (%u): %s", op, code, why);
    *json = worlds_error_json(field, why);
    return code;
}

/* Where cJSON stopped in a body that is not JSON, named by the key before it
 * (a NaN or Infinity, which JSON has no literal for, stops it right there):
 * that key is the field, else "body". */
static void parse_failure(const char *body, size_t len, char *field, size_t fcap, char *why,
                          size_t cap)
{
    const char *at = cJSON_GetErrorPtr();
    size_t off = at && at >= body && at <= body + len ? (size_t)(at - body) : len;
    char key[64] = "";
    for (size_t i = off; i > 0 && !key[0]; i--) {
        if (body[i - 1] != ':')
            continue;
        size_t e = i - 1;
        while (e > 0 && body[e - 1] == ' ')
            e--;
        if (e == 0 || body[e - 1] != '"')
            break;
        size_t b = e - 1;
        while (b > 0 && body[b - 1] != '"')
            b--;
        snprintf(key, sizeof key, "%.*s", (int)(e - 1 - b < 63 ? e - 1 - b : 63), body + b);
    }
    snprintf(field, fcap, "%s", key[0] ? key : "body");
    snprintf(why, cap,
             "%s: not JSON at byte %zu%s%s%s (NaN and Infinity are not JSON numbers; one "
             "object: {\"name\": ..., \"scene\": {...}} or {\"name\": ..., \"scene_name\": ...})",
             field, off, key[0] ? ", in the value of \"" : "", key, key[0] ? "\"" : "");
}

/* The scene's text from the body: its "scene" object, or scene_dir's
 * "scene_name".json. NULL with *code, field and why. */
static char *scene_of(const char *scene_dir, const cJSON *doc, unsigned *code, char *field,
                      size_t fcap, char *why, size_t cap)
{
    const cJSON *obj = cJSON_GetObjectItemCaseSensitive(doc, "scene");
    const cJSON *named = cJSON_GetObjectItemCaseSensitive(doc, "scene_name");
    *code = 400;
    snprintf(field, fcap, "%s", obj ? "scene" : "scene_name");
    if (!obj == !named) {
        snprintf(why, cap,
                 "scene: give exactly one of \"scene\" (a scene object, as in a scene "
                 "file) and \"scene_name\" (a scene of --scene-dir)");
        return NULL;
    }
    if (obj) {
        if (!cJSON_IsObject(obj)) {
            snprintf(why, cap, "scene: must be a JSON object (a scene, as in a scene file)");
            return NULL;
        }
        char *text = cJSON_PrintUnformatted(obj);
        if (!text)
            snprintf(why, cap, "scene: out of memory");
        return text;
    }
    error_text err = {{0}};
    if (!cJSON_IsString(named) || !cluster_name_valid(named->valuestring, "scene_name", &err)) {
        snprintf(why, cap, "scene_name: %s",
                 err.message[0] ? err.message : "must be a string, a scene's file name");
        return NULL;
    }
    if (!scene_dir) {
        snprintf(why, cap, "scene_name: this daemon has no --scene-dir: send the scene itself");
        return NULL;
    }
    char path[PATH_CAP];
    snprintf(path, sizeof path, "%.1000s/%s.json", scene_dir, named->valuestring);
    uint8_t *text = NULL;
    size_t len = 0;
    if (file_read_all(path, SCENE_MAX_BYTES, &text, &len, &err) != 0) {
        *code = 404;
        snprintf(why, cap, "scene_name: no scene \"%s\" in the scene directory (%.120s)",
                 named->valuestring, err.message);
        return NULL;
    }
    return (char *)text;
}

/* The body's "clock" ("wall" or "client"), beside name and scene, is the
 * scene's "clock" (PROTOCOL.md "STEP"): written into the scene text, so the
 * world's NAME.json (or registry entry) keeps it. 0, or -1 with field and why. */
static int body_clock(const cJSON *doc, char **scene_text, char *field, size_t fcap, char *why,
                      size_t cap)
{
    const cJSON *c = cJSON_GetObjectItemCaseSensitive(doc, "clock");
    if (!c)
        return 0;
    snprintf(field, fcap, "clock");
    if (!cJSON_IsString(c) ||
        (strcmp(c->valuestring, "wall") != 0 && strcmp(c->valuestring, "client") != 0)) {
        snprintf(why, cap, "clock: must be \"wall\" or \"client\"");
        return -1;
    }
    cJSON *scene = cJSON_Parse(*scene_text);
    char *text = NULL;
    if (cJSON_IsObject(scene)) {
        cJSON_DeleteItemFromObjectCaseSensitive(scene, "clock");
        cJSON_AddStringToObject(scene, "clock", c->valuestring);
        text = json_print_delete(scene);
    } else {
        cJSON_Delete(scene);
    }
    if (!text) { /* not an object: scene_load_json names it */
        snprintf(field, fcap, "scene");
        return 0;
    }
    free(*scene_text);
    *scene_text = text;
    return 0;
}

unsigned worlds_body_check(const char *body, size_t len, const char *scene_dir,
                           const char *default_name, char *name, char **scene_text, char *field,
                           size_t fcap, char *why, size_t cap)
{
    cJSON *doc = cJSON_ParseWithLength(body, len);
    snprintf(field, fcap, "body");
    if (!cJSON_IsObject(doc)) {
        if (doc)
            snprintf(why, cap, "body: must be a JSON object: {\"name\": ..., \"scene\": {...}}");
        else
            parse_failure(body, len, field, fcap, why, cap);
        cJSON_Delete(doc);
        return 400;
    }
    const cJSON *n = cJSON_GetObjectItemCaseSensitive(doc, "name");
    error_text err = {{0}};
    unsigned code = 400;
    snprintf(field, fcap, "name");
    if (!cJSON_IsString(n) || !cluster_name_valid(n->valuestring, "world", &err)) {
        snprintf(why, cap, "name: %s",
                 err.message[0] ? err.message : "required: a string of letters, digits, _ and -");
    } else if (default_name && strcmp(n->valuestring, default_name) == 0) {
        code = 409;
        snprintf(why, cap, "name: \"%s\" is the default world's (its scene's name)",
                 n->valuestring);
    } else if ((*scene_text = scene_of(scene_dir, doc, &code, field, fcap, why, cap))) {
        snprintf(name, CLUSTER_WORLD_NAME_MAX + 1, "%s", n->valuestring);
        scene sc;
        code = 0;
        if (body_clock(doc, scene_text, field, fcap, why, cap) != 0) {
            code = 400;
            free(*scene_text);
            *scene_text = NULL;
        } else if (scene_load_json(*scene_text, scene_dir ? scene_dir : ".", &sc, &err) != 0) {
            code = 422;
            snprintf(field, fcap, "scene");
            snprintf(why, cap, "scene: %s", err.message);
            free(*scene_text);
            *scene_text = NULL;
        } else {
            scene_free(&sc);
        }
    }
    cJSON_Delete(doc);
    return code;
}
