/*
 * world_cmd.c: `terrad world add NAME --scene FILE | list | remove NAME` —
 * the cluster's world registry (docs/cluster.md), a JetStream key-value
 * bucket that nodes started with --cluster read to know which worlds exist.
 * A scene is checked with the daemon's own parser before it is registered,
 * so a node never meets a scene it refuses. Offline from any tick: it talks
 * to NATS only.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "app/app.h"
#include "cluster/cluster.h"
#include "scene/scene.h"

#define WORLD_USAGE "add NAME --scene FILE | list | remove NAME  [--cluster URLS]"

typedef struct world_cmd {
    const char *cluster_urls, *scene_path;
} world_cmd;

static const cli_option world_options[] = {
    {"cluster", "URLS",
     "comma-separated NATS URLs (default: $TERRAD_CLUSTER, else\nnats://127.0.0.1:4222)"},
    {"scene", "FILE", "add: the world's scene JSON (checked before it is registered)"},
    {0},
};

static int world_on_option(void *ctx, int index, const char *value, error_text *err)
{
    world_cmd *c = ctx;
    (void)err;
    if (index == 0)
        c->cluster_urls = value;
    else
        c->scene_path = value;
    return 0;
}

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
    world_cmd c = {getenv("TERRAD_CLUSTER"), NULL};
    /* options follow the verb (list) or the name (add, remove): that word is
     * cli_parse's argv[0] */
    int skip = named ? 1 : 0;
    cli_result parsed = cli_parse("world", WORLD_USAGE, world_options, argc - skip, argv + skip,
                                  world_on_option, &c, NULL);
    if (parsed != CLI_OK)
        return parsed == CLI_HELP ? 0 : 2;
    const char *name = named ? argv[1] : NULL;
    error_text err = {{0}};
    if (name && !cluster_name_valid(name, "world", &err)) {
        fprintf(stderr, "terrad world %s: %s\n", verb, err.message);
        return 2;
    }
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
