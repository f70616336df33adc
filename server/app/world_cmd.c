/*
 * world_cmd.c: `terrad world add NAME --scene FILE | list | remove NAME` —
 * the cluster's world registry (docs/cluster.md), a JetStream key-value
 * bucket that nodes started with --cluster read to know which worlds exist.
 * A scene is checked with the daemon's own parser before it is registered,
 * so a node never meets a scene it refuses. With --http URL (or
 * $TERRAD_HTTP) the same command line is a client of a node's (or a single
 * daemon's) world lifecycle API instead — POST/GET /v1/worlds, DELETE
 * /v1/worlds/NAME (app/serve_node_api.c) — which checks the body itself and
 * answers with the node that took the world. Offline from any tick.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cjson/cJSON.h>

#include "app/app.h"
#include "app/http_client_internal.h"
#include "cluster/cluster.h"
#include "scene/scene.h"

#define WORLD_USAGE                                                                                \
    "add NAME --scene FILE | list | remove NAME  [--cluster URLS | --http URL [--token TOKEN]]"

typedef struct world_cmd {
    const char *cluster_urls, *scene_path, *http_url, *token;
} world_cmd;

static const cli_option world_options[] = {
    {"cluster", "URLS",
     "comma-separated NATS URLs (default: $TERRAD_CLUSTER, else\nnats://127.0.0.1:4222)",
     CLI_AT_STRING(world_cmd, cluster_urls)},
    {"scene", "FILE", "add: the world's scene JSON (checked before it is registered)",
     CLI_AT_STRING(world_cmd, scene_path)},
    {"http", "URL",
     "http://HOST:PORT of a node (or daemon): go through its world API\n(POST/GET/DELETE "
     "/v1/worlds) instead of NATS (default: $TERRAD_HTTP)",
     CLI_AT_STRING(world_cmd, http_url)},
    {"token", "TOKEN", "--http: an admin token where it has tokens (default: $TERRAD_TOKEN)",
     CLI_AT_STRING(world_cmd, token)},
    {0},
};

/* The scene file's text, refused unless the daemon's parser accepts it. */
static char *scene_text_checked(const char *path, error_text *err)
{
    uint8_t *text = NULL;
    size_t len = 0;
    if (file_read_all(path, 1 << 20, &text, &len, err) != 0)
        return NULL;
    scene sc;
    if (scene_load_file(path, &sc, err) != 0) {
        free(text);
        return NULL;
    }
    scene_free(&sc);
    return (char *)text;
}

static int world_add(cluster *cl, const char *name, const char *scene_path)
{
    error_text err = {{0}};
    if (!scene_path) {
        fprintf(stderr, "terrad world add: --scene FILE is required\n");
        return 2;
    }
    char *text = scene_text_checked(scene_path, &err);
    if (!text) {
        fprintf(stderr, "terrad world add: scene refused: %s\n", err.message);
        return 1;
    }
    cluster_status r = cluster_world_add(cl, name, text, &err);
    free(text);
    if (r != CLUSTER_OK) {
        fprintf(stderr, "terrad world add: %s\n", err.message);
        return 1;
    }
    printf("world %s added\n", name);
    return 0;
}

/* One line per world: its name and the node ticking it ("-": none now). */
static int world_list(cluster *cl)
{
    error_text err = {{0}};
    char **names = NULL;
    int count = 0;
    if (cluster_world_list(cl, &names, &count, &err) != 0) {
        fprintf(stderr, "terrad world list: %s\n", err.message);
        return 1;
    }
    int rc = 0;
    for (int i = 0; i < count; i++) {
        char holder[CLUSTER_NODE_NAME_MAX + 1] = "";
        if (cluster_lease_holder(cl, names[i], holder, sizeof holder, &err) < 0) {
            fprintf(stderr, "terrad world list: %s\n", err.message);
            rc = 1;
        }
        printf("%s %s\n", names[i], holder[0] ? holder : "-");
        free(names[i]);
    }
    free(names);
    return rc;
}

static int world_remove(cluster *cl, const char *name)
{
    error_text err = {{0}};
    int r = cluster_world_remove(cl, name, &err);
    if (r < 0)
        fprintf(stderr, "terrad world remove: %s\n", err.message);
    else if (r == 0)
        fprintf(stderr, "terrad world remove: no world named \"%s\"\n", name);
    else
        printf("world %s removed\n", name);
    return r == 1 ? 0 : 1;
}

/* ---- --http: a client of the world lifecycle API ---- */

/* The answer's "error" (the server's words, naming the field), or the status. */
static void http_refused(const char *verb, int status, const char *answer)
{
    cJSON *doc = answer ? cJSON_Parse(answer) : NULL;
    const cJSON *e = cJSON_GetObjectItemCaseSensitive(doc, "error");
    if (status < 0)
        fprintf(stderr, "terrad world %s: no answer from the HTTP server\n", verb);
    else
        fprintf(stderr, "terrad world %s: %d: %s\n", verb, status,
                cJSON_IsString(e) ? e->valuestring : "(no error message)");
    cJSON_Delete(doc);
}

/* The body of POST /v1/worlds: {"name": name, "scene": the file's JSON}. */
static char *create_body(const char *name, const char *scene_path)
{
    uint8_t *text = NULL;
    size_t len = 0;
    error_text err = {{0}};
    if (file_read_all(scene_path, 1 << 20, &text, &len, &err) != 0) {
        fprintf(stderr, "terrad world add: %s\n", err.message);
        return NULL;
    }
    cJSON *scene_doc = cJSON_ParseWithLength((const char *)text, len);
    free(text);
    if (!scene_doc) {
        fprintf(stderr, "terrad world add: scene refused: %s is not JSON\n", scene_path);
        return NULL;
    }
    cJSON *body = cJSON_CreateObject();
    cJSON_AddStringToObject(body, "name", name);
    cJSON_AddItemToObject(body, "scene", scene_doc);
    return json_print_delete(body);
}

/* One line per world, as over NATS: its name and its node ("-": none). */
static void print_list(const char *answer)
{
    cJSON *doc = cJSON_Parse(answer);
    const cJSON *w;
    cJSON_ArrayForEach(w, cJSON_GetObjectItemCaseSensitive(doc, "worlds"))
    {
        const cJSON *name = cJSON_GetObjectItemCaseSensitive(w, "name");
        const cJSON *node = cJSON_GetObjectItemCaseSensitive(w, "node");
        if (cJSON_IsString(name))
            printf("%s %s\n", name->valuestring, cJSON_IsString(node) ? node->valuestring : "-");
    }
    cJSON_Delete(doc);
}

static int world_http(const world_cmd *c, const char *verb, const char *name)
{
    char host[256], path[128];
    int port = 0;
    if (app_http_url(c->http_url, host, sizeof host, &port) != 0) {
        fprintf(stderr, "terrad world %s: --http: \"%s\" is not http://HOST:PORT\n", verb,
                c->http_url);
        return 2;
    }
    char *body = NULL, *answer = NULL;
    size_t len = 0;
    int add = strcmp(verb, "add") == 0, list = strcmp(verb, "list") == 0;
    if (add && !(body = create_body(name, c->scene_path)))
        return 1;
    snprintf(path, sizeof path, "/v1/worlds%s%s", list || add ? "" : "/", list || add ? "" : name);
    int status = app_http_request(host, port,
                                  add    ? "POST"
                                  : list ? "GET"
                                         : "DELETE",
                                  path, c->token, body, body ? strlen(body) : 0, &answer, &len);
    free(body);
    int ok = status == (add ? 201 : 200);
    if (!ok) {
        http_refused(verb, status, answer);
    } else if (list) {
        print_list(answer);
    } else if (add) {
        cJSON *doc = cJSON_Parse(answer);
        const cJSON *node = cJSON_GetObjectItemCaseSensitive(doc, "node");
        printf("world %s added%s%s\n", name, cJSON_IsString(node) ? " on node " : "",
               cJSON_IsString(node) ? node->valuestring : "");
        cJSON_Delete(doc);
    } else {
        printf("world %s removed\n", name);
    }
    free(answer);
    return ok ? 0 : 1;
}

void app_world_usage(FILE *out)
{
    cli_print_help(out, "world", WORLD_USAGE, world_options);
}

/* argv[0] is "world", argv[1] the verb. */
int app_world(int argc, char **argv)
{
    argc--, argv++; /* from the verb on */
    const char *verb = argc > 0 ? argv[0] : "";
    int named = strcmp(verb, "add") == 0 || strcmp(verb, "remove") == 0;
    if (strcmp(verb, "--help") == 0 || strcmp(verb, "-h") == 0) {
        app_world_usage(stdout);
        return 0;
    }
    if (!named && strcmp(verb, "list") != 0) {
        fprintf(stderr, "terrad world: expected add, list or remove (usage: terrad world %s)\n",
                WORLD_USAGE);
        return 2;
    }
    if (named && (argc < 2 || argv[1][0] == '-')) {
        fprintf(stderr, "terrad world %s: NAME is missing\n", verb);
        return 2;
    }
    world_cmd c = {getenv("TERRAD_CLUSTER"), NULL, getenv("TERRAD_HTTP"), getenv("TERRAD_TOKEN")};
    /* options follow the verb (list) or the name (add, remove): that word is
     * cli_parse's argv[0] */
    int skip = named ? 1 : 0;
    cli_result parsed =
        cli_parse("world", WORLD_USAGE, world_options, argc - skip, argv + skip, &c, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    const char *name = named ? argv[1] : NULL;
    error_text err = {{0}};
    if (name && !cluster_name_valid(name, "world", &err)) {
        fprintf(stderr, "terrad world %s: %s\n", verb, err.message);
        return 2;
    }
    if (strcmp(verb, "add") == 0 && !c.scene_path) {
        fprintf(stderr, "terrad world add: --scene FILE is required\n");
        return 2;
    }
    if (c.http_url && c.http_url[0])
        return world_http(&c, verb, name);
    char node[CLUSTER_NODE_NAME_MAX + 1];
    snprintf(node, sizeof node, "cli-%d", (int)getpid());
    cluster_config cc = {.urls = c.cluster_urls && c.cluster_urls[0] ? c.cluster_urls
                                                                     : "nats://127.0.0.1:4222",
                         .node = node};
    cluster *cl = cluster_connect(&cc, &err);
    if (!cl) {
        fprintf(stderr, "terrad world %s: %s\n", verb, err.message);
        return 1;
    }
    int rc = strcmp(verb, "add") == 0      ? world_add(cl, name, c.scene_path)
             : strcmp(verb, "remove") == 0 ? world_remove(cl, name)
                                           : world_list(cl);
    cluster_close(cl);
    return rc;
}
