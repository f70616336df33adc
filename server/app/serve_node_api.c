/*
 * serve_node_api.c: the world lifecycle API on a cluster node (issue 22;
 * docs/cluster.md "Worlds by HTTP"): POST /v1/worlds, GET /v1/worlds and
 * DELETE /v1/worlds/{name} on any node go through the cluster's registry
 * and leases, as `terrad world add|list|remove` do. A create checks its body
 * exactly as a single daemon does (worlds_body_check, serve_worlds_body.c),
 * registers the scene's text (cluster_world_add) and waits — up to
 * NODE_API_WAIT_MS — until a node holds the world's lease: whichever node
 * has room takes it (node_loop's take_world), this one or another. A list
 * names every registered world and the node ticking it; a delete removes the
 * world from the registry (its log, snapshots and lease with it) and the
 * owner, seeing it gone from its next listing, stops the world and closes its
 * clients with 4020 "world deleted" (serve_node.c, stop_deleted).
 *
 * Everything here runs on an HTTP thread and talks to NATS only: no tick
 * waits on it.
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "app/app.h"
#include "app/serve_internal.h"
#include "metrics/metrics.h"

#define NODE_API_WAIT_MS 30000.0 /* a create waits this long for a node to take the world */
#define NODE_API_POLL_MS 100.0

struct serve_node_api {
    cluster *cl;
    const char *scene_dir;
    char node[CLUSTER_NODE_NAME_MAX + 1];
};

/* One world's entry: its name, whether a node ticks it, and which. */
static cJSON *node_entry(const char *name, const char *holder)
{
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", name);
    cJSON_AddStringToObject(o, "state", holder[0] ? "running" : "starting");
    cJSON_AddBoolToObject(o, "default", 0);
    if (holder[0])
        cJSON_AddStringToObject(o, "node", holder);
    else
        cJSON_AddNullToObject(o, "node");
    return o;
}

static unsigned answer(cJSON *o, unsigned code, char **json)
{
    *json = json_print_delete(o);
    return code;
}

static unsigned unreachable(const char *op, const char *message, char **json)
{
    char why[400];
    snprintf(why, sizeof why, "cluster: %.380s", message);
    return worlds_refuse(op, 503, "cluster", why, json);
}

static unsigned node_create(void *ctx, const char *body, size_t len, char **json)
{
    serve_node_api *a = ctx;
    char name[CLUSTER_WORLD_NAME_MAX + 1] = "", why[640], field[64];
    char *text = NULL;
    unsigned code = worlds_body_check(body, len, a->scene_dir, NULL, name, &text, field,
                                      sizeof field, why, sizeof why);
    if (code)
        return worlds_refuse("create", code, field, why, json);
    error_text err = {{0}};
    cluster_status r = cluster_world_add(a->cl, name, text, &err);
    free(text);
    if (r == CLUSTER_FENCED) {
        snprintf(why, sizeof why, "name: a world \"%s\" exists already (DELETE it first)", name);
        return worlds_refuse("create", 409, "name", why, json);
    }
    if (r != CLUSTER_OK)
        return unreachable("create", err.message, json);
    metrics_count_world_request("create", 1);
    log_info("worlds: world %s registered in the cluster (POST /v1/worlds on node %s)", name,
             a->node);
    char holder[CLUSTER_NODE_NAME_MAX + 1] = "";
    double until = time_now_ms() + NODE_API_WAIT_MS;
    while (cluster_lease_holder(a->cl, name, holder, sizeof holder, &err) <= 0 &&
           time_now_ms() < until)
        host_sleep_ms(NODE_API_POLL_MS);
    return answer(node_entry(name, holder), 201, json);
}

static unsigned node_list(void *ctx, char **json)
{
    serve_node_api *a = ctx;
    error_text err = {{0}};
    char **names = NULL;
    int count = 0;
    if (cluster_world_list(a->cl, &names, &count, &err) != 0)
        return unreachable("list", err.message, json);
    cJSON *doc = cJSON_CreateObject(), *arr = cJSON_AddArrayToObject(doc, "worlds");
    for (int i = 0; i < count; i++) {
        char holder[CLUSTER_NODE_NAME_MAX + 1] = "";
        if (cluster_lease_holder(a->cl, names[i], holder, sizeof holder, &err) < 0)
            holder[0] = 0; /* unknown now: listed as waiting for a node */
        cJSON_AddItemToArray(arr, node_entry(names[i], holder));
        free(names[i]);
    }
    free(names);
    cJSON_AddStringToObject(doc, "node", a->node);
    return answer(doc, 200, json);
}

static unsigned node_remove(void *ctx, const char *name, int keep, char **json)
{
    serve_node_api *a = ctx;
    char why[400];
    error_text err = {{0}};
    if (keep)
        return worlds_refuse("delete", 400, "keep",
                             "keep: a cluster keeps no storage of a deleted world (its log and "
                             "snapshots are removed with it)",
                             json);
    if (!cluster_name_valid(name, "world", &err)) {
        snprintf(why, sizeof why, "name: %.380s", err.message);
        return worlds_refuse("delete", 400, "name", why, json);
    }
    int r = cluster_world_remove(a->cl, name, &err);
    if (r < 0)
        return unreachable("delete", err.message, json);
    if (r == 0) {
        snprintf(why, sizeof why, "name: no such world (GET /v1/worlds lists them)");
        return worlds_refuse("delete", 404, "name", why, json);
    }
    metrics_count_world_request("delete", 1);
    log_info("worlds: world %s removed from the cluster (DELETE on node %s)", name, a->node);
    cJSON *o = cJSON_CreateObject();
    cJSON_AddStringToObject(o, "name", name);
    cJSON_AddBoolToObject(o, "deleted", 1);
    cJSON_AddNullToObject(o, "kept");
    return answer(o, 200, json);
}

serve_node_api *serve_node_api_start(cluster *cl, const serve_options *o, const char *node,
                                     http_server *http)
{
    serve_node_api *a = calloc(1, sizeof *a);
    if (!a)
        return NULL;
    a->cl = cl;
    a->scene_dir = o->scene_dir;
    snprintf(a->node, sizeof a->node, "%s", node);
    http_world_api api = {node_create, node_list, node_remove, a};
    http_server_set_world_api(http, &api);
    return a;
}

void serve_node_api_free(serve_node_api *a)
{
    free(a);
}
