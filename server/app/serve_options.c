/*
 * serve_options.c: `terrad serve`'s options — one table (what --help
 * prints), read from the command line by base.h's cli_parse and from
 * --config FILE (its numbers through the same rows, cli_store_value; its
 * strings and "limits" by base.h's JSON field readers). Read once, before the daemon
 * starts its threads and its first tick.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "app/app.h"
#include "app/serve_internal.h"

/* --public-ws-url: ws:// or wss://, a host, printable without spaces or
 * quotes (it goes into JSON and a browser's WebSocket constructor as is). */
static int public_ws_url_check(const char *v, error_text *err)
{
    size_t scheme = strncmp(v, "ws://", 5) == 0 ? 5 : strncmp(v, "wss://", 6) == 0 ? 6 : 0;
    if (!scheme || !v[scheme] || v[scheme] == '/' || v[scheme] == ':') {
        error_set(err, "\"%.80s\" is not a ws:// or wss:// URL with a host", v);
        return -1;
    }
    if (strlen(v) >= HTTP_PUBLIC_URL_MAX) {
        error_set(err, "longer than %d bytes", HTTP_PUBLIC_URL_MAX - 1);
        return -1;
    }
    for (const char *p = v; *p; p++)
        if ((unsigned char)*p <= ' ' || (unsigned char)*p >= 0x7f || strchr("\"\\<>`{}|^", *p)) {
            error_set(err, "\"%.80s\": character %d is not allowed in a URL here", v,
                      (int)(p - v) + 1);
            return -1;
        }
    return 0;
}

/* A string key of the config: copied into buf, *out pointed at it. */
static int config_string(const cJSON *doc, const char *key, char *buf, size_t size,
                         const char **out, error_text *err)
{
    int r = json_get_string(doc, "", key, buf, size, err);
    if (r > 0)
        *out = buf;
    return r < 0 ? -1 : 0;
}

static int config_public_ws_url(const cJSON *doc, serve_options *o, error_text *err)
{
    int r = json_get_string(doc, "", "public_ws_url", o->config_public_ws_url,
                            sizeof o->config_public_ws_url, err);
    if (r > 0 && public_ws_url_check(o->config_public_ws_url, err) != 0) {
        error_prefix(err, "public_ws_url", ": ");
        return -1;
    }
    if (r > 0)
        o->public_ws_url = o->config_public_ws_url;
    return r < 0 ? -1 : 0;
}

/* "limits": PROTOCOL.md's names, each a positive number, at least its row's
 * min, or 0 where the row says 0 means none or its default (NET_LIMITS,
 * net/net.h, says which and where each goes). */
static int config_limits(const cJSON *doc, serve_options *o, error_text *err)
{
    const char *keys[64];
    int n = 0;
    for (const net_limit_spec *t = net_limit_table; t->name && n < 63; t++)
        if (t->flags & NET_LIMIT_CONFIG)
            keys[n++] = t->name;
    keys[n] = NULL;
    const cJSON *l = cJSON_GetObjectItemCaseSensitive(doc, "limits");
    if (!l)
        return 0;
    if (json_expect_object(l, "limits", "limits", err) ||
        json_check_keys(l, "limits", keys, NULL, err))
        return -1;
    for (const net_limit_spec *t = net_limit_table; t->name; t++) {
        double v = 0;
        int r = 0;
        if (t->flags & NET_LIMIT_ZERO) /* 0 means none or the default its help names */
            r = json_get_number(l, "limits", t->name, 0, 1e12, &v, err);
        else if (t->flags & NET_LIMIT_CONFIG)
            r = json_get_positive(l, "limits", t->name, 1e12, 0, &v, err);
        if (r < 0)
            return -1;
        if (r > 0 && v != 0 && v < t->min) { /* a budget under hello's smallest (NET_LIMITS) */
            error_set(err, "limits.%s: must be 0 or at least %g (got %g)", t->name, t->min, v);
            return -1;
        }
        if (r > 0)
            net_limit_set(&o->limits, t, v);
    }
    return 0;
}

static const cli_option *serve_rows(void);

/* The config's numbers go through their options' rows (serve_rows): the same
 * kind, range, store and refusal as on the command line ("tick_hz": 59.5 is
 * refused as --tick-hz 59.5 is), so a range is written once, in its row. */
static int config_numbers(const cJSON *doc, serve_options *o, error_text *err)
{
    static const char *const keys[] = {
        "http_port",  "ws_port",           "demo_actors",         "tick_hz",
        "max_worlds", "wal_segment_bytes", "replay_retain_bytes", NULL};
    for (const char *const *k = keys; *k; k++) {
        const cJSON *v = cJSON_GetObjectItemCaseSensitive(doc, *k);
        if (!v)
            continue;
        char name[64], text[40];
        snprintf(name, sizeof name, "%s", *k);
        for (char *c = name; *c; c++)
            *c = *c == '_' ? '-' : *c;
        const cli_option *row = cli_find(serve_rows(), name);
        if (!row) { /* a key of this list with no option of that name: a bug here */
            error_set(err, "%s: no option --%s", *k, name);
            return -1;
        }
        if (!cJSON_IsNumber(v) || !isfinite(v->valuedouble)) {
            error_set(err, "%s: expected a number", *k);
            return -1;
        }
        snprintf(text, sizeof text, "%.17g", v->valuedouble);
        if (cli_store_value(row, o, text, err) != 0) {
            error_prefix(err, *k, ": ");
            return -1;
        }
    }
    int r, flag;
    if ((r = json_get_bool(doc, "", "bind_any", &flag, err)) < 0)
        return -1;
    if (r)
        o->bind_any = flag;
    if ((r = json_get_bool(doc, "", "no_data", &flag, err)) < 0)
        return -1;
    if (r && flag)
        o->data_dir = NULL;
    return 0;
}

/* --config FILE: a JSON object whose keys are the long options without the
 * dashes (dashes as underscores) plus "limits" with PROTOCOL.md's names.
 * Flags given on the command line after --config override it; within the
 * file, "no_data": true wins over "data". */
#define TOKEN_REMOVED                                                                              \
    "removed: a token is no longer given in clear; write its hash to an auth file "                \
    "(terrad token add --auth-file FILE --role admin --name NAME) and give --auth-file FILE "      \
    "(config \"auth_file\")"

/* The single admin token ("token", like --token) went away: a config that
 * still has it is refused, named, rather than started with auth off. */
static int config_no_token(const cJSON *doc, error_text *err)
{
    if (!cJSON_GetObjectItemCaseSensitive(doc, "token"))
        return 0;
    error_set(err, "token: " TOKEN_REMOVED);
    return -1;
}

static int config_load(const char *path, serve_options *o, error_text *err)
{
    static const char *const keys[] = {"scene",
                                       "backend",
                                       "token",
                                       "data",
                                       "no_data",
                                       "durability",
                                       "store_fault",
                                       "wal_segment_bytes",
                                       "http_port",
                                       "ws_port",
                                       "bind_any",
                                       "demo_actors",
                                       "tick_hz",
                                       "limits",
                                       "auth_file",
                                       "tls_cert",
                                       "tls_key",
                                       "scene_dir",
                                       "max_worlds",
                                       "public_ws_url",
                                       "replay_retain_bytes",
                                       NULL};
    uint8_t *text = NULL;
    size_t len = 0;
    if (file_read_all(path, (size_t)1 << 20, &text, &len, err) != 0)
        return -1;
    cJSON *doc = cJSON_Parse((const char *)text);
    free(text);
    int rc = -1;
    if (!cJSON_IsObject(doc)) {
        error_set(err, "%s: not a JSON object (syntax error?)", path);
        goto done;
    }
    if (json_check_keys(doc, "", keys, NULL, err) ||
        config_string(doc, "scene", o->config_scene, sizeof o->config_scene, &o->scene_path, err) ||
        config_string(doc, "backend", o->config_backend, sizeof o->config_backend, &o->backend,
                      err) ||
        config_no_token(doc, err) ||
        config_string(doc, "data", o->config_data, sizeof o->config_data, &o->data_dir, err) ||
        config_string(doc, "durability", o->config_durability, sizeof o->config_durability,
                      &o->durability, err) ||
        config_string(doc, "store_fault", o->config_store_fault, sizeof o->config_store_fault,
                      &o->store_fault, err) ||
        config_string(doc, "scene_dir", o->config_scene_dir, sizeof o->config_scene_dir,
                      &o->scene_dir, err) ||
        config_public_ws_url(doc, o, err) || serve_security_config(doc, o, err) ||
        config_numbers(doc, o, err) || config_limits(doc, o, err)) {
        error_prefix(err, path, ": ");
        goto done;
    }
    rc = 0;
done:
    cJSON_Delete(doc);
    return rc;
}

/* The options that need code; the rest are stored by cli_parse (serve_table). */
static int config_option(void *ctx, const char *value, error_text *err)
{
    serve_options *o = ctx;
    if (o->config_loaded) {
        error_set(err, "given twice");
        return -1;
    }
    o->config_loaded = 1;
    return config_load(value, o, err);
}

static int public_ws_url_option(void *ctx, const char *value, error_text *err)
{
    ((serve_options *)ctx)->public_ws_url = value;
    return public_ws_url_check(value, err);
}

static int token_option(void *ctx, const char *value, error_text *err)
{
    (void)ctx;
    (void)value;
    error_set(err, TOKEN_REMOVED);
    return -1;
}

static int data_option(void *ctx, const char *value, error_text *err)
{
    serve_options *o = ctx;
    (void)err;
    o->data_dir = value;
    o->data_given = 1;
    return 0;
}

static int no_data_option(void *ctx, const char *value, error_text *err)
{
    (void)value;
    (void)err;
    ((serve_options *)ctx)->data_dir = NULL;
    return 0;
}

static int no_demo_option(void *ctx, const char *value, error_text *err)
{
    (void)value;
    (void)err;
    ((serve_options *)ctx)->demo_actors = 0;
    return 0;
}

/* a whole number of ticks a second (its row's range checked), kept as the
 * double the ticker takes */
static int tick_hz_option(void *ctx, const char *value, error_text *err)
{
    (void)err;
    ((serve_options *)ctx)->tick_hz = (double)strtol(value, NULL, 10);
    return 0;
}

static int threads_option(void *ctx, const char *value, error_text *err)
{
    (void)ctx;
    (void)err;
    /* in its row's range; process-wide: the sim reads it each tick */
    sim_set_threads((int)strtol(value, NULL, 10));
    return 0;
}

static const cli_option serve_table[] = {
    {"config", "FILE",
     "JSON file with any of the options below (keys without the\n"
     "dashes, '_' for '-') and \"limits\": {...} with the names of\n"
     "proto/PROTOCOL.md's limits; later flags override it",
     CLI_CALLS(config_option)},
    {"scene", "FILE", "scene JSON (default: the embedded default scene)",
     CLI_AT_STRING(serve_options, scene_path)},
    {"backend", "auto|gl|cpu",
     "deformation backend (default auto: gl, EGL with no window, where\n"
     "the renderer is a hardware GPU; cpu, the integer twin, where GL\n"
     "is software (llvmpipe, softpipe, SwiftShader) or missing)",
     CLI_AT_STRING(serve_options, backend)},
    {"http-port", "N",
     "HTTP port: /healthz /readyz /metrics /v1/world /v1/stats\n"
     "/v1/heights /v1/twin, POST /v1/worlds/NAME/edits (terrain edits) and the\n"
     "viewer at / (default 8080; 0: any free)",
     CLI_AT_INT(serve_options, http_port, 0, 65535)},
    {"ws-port", "N", "websocket port, subprotocol terrad.v1 (default 8081; 0: any)",
     CLI_AT_INT(serve_options, ws_port, 0, 65535)},
    {"bind-any", NULL, "listen on all interfaces (default: 127.0.0.1 only)",
     CLI_AT_FLAG(serve_options, bind_any)},
    {"token", "T",
     "removed (every local user can read the command line): refused\n"
     "with a pointer to --auth-file",
     CLI_CALLS(token_option)},
    {"tick-hz", "N", "tick rate (default: the scene's, normally 60)",
     CLI_CALLS_LONG(tick_hz_option, 1, 1000)},
    {"demo-actors", "N", "built-in spheres running laps over the terrain (default 6)",
     CLI_AT_INT(serve_options, demo_actors, 0, 256)},
    {"no-demo", NULL, "no demo actors", CLI_CALLS(no_demo_option)},
    {"ticks", "N", "stop after N ticks (default: run until SIGINT/SIGTERM)",
     CLI_AT_LONG(serve_options, max_ticks, 0, 1000000000)},
    {"data", "DIR",
     "data directory: tile snapshots + write-ahead log, recovered\n"
     "at start (default ./data; with demo actors and no --data the\n"
     "world is in memory only, so the demo never wears out a world)",
     CLI_CALLS(data_option)},
    {"no-data", NULL, "keep the terrain in memory only", CLI_CALLS(no_data_option)},
    {"durability", "P",
     "every-tick (default: fdatasync before a tick is published),\n"
     "group:MS (one fdatasync per MS ms; ticks held until it) or\n"
     "none (written before publish, never synced)",
     CLI_AT_STRING(serve_options, durability)},
    {"wal-segment-bytes", "N", "compact the log into tile snapshots past N bytes (default 16 MiB)",
     CLI_AT_LONG(serve_options, wal_segment_bytes, 4096, 1L << 40)},
    {"replay-retain-bytes", "N",
     "keep the whole log (compacted segments too) while it is\n"
     "under N bytes, so /v1/heights?tick= can rebuild every tick\n"
     "since the first (default 0: compacted segments are deleted)",
     CLI_AT_LONG(serve_options, replay_retain_bytes, 0, 1L << 40)},
    {"store-fault", "FILE",
     "test hook: storage writes fail ENOSPC while FILE exists\n"
     "(also TERRAD_STORE_FAULT)",
     CLI_AT_STRING(serve_options, store_fault)},
    {"fresh", NULL,
     "start the data directory over: delete its terrain files (and\n"
     "refuse a directory holding anything else) before starting",
     CLI_AT_FLAG(serve_options, fresh)},
    {"threads", "N", "threads of the CPU twin (default: the machine's cores)",
     CLI_CALLS_LONG(threads_option, 1, SIM_THREADS_MAX)},
    {"insecure-open", NULL,
     "allow --bind-any without a token: anyone who can reach the\n"
     "ports may deform the world",
     CLI_AT_FLAG(serve_options, insecure_open)},
    {"recover-truncate", NULL,
     "start on a damaged data directory anyway: cut the damage\n"
     "and log exactly which ticks are lost (default: refuse)",
     CLI_AT_FLAG(serve_options, recover_truncate)},
    {"cluster", "URLS",
     "join a NATS JetStream cluster (comma-separated nats:// URLs):\n"
     "the world, its log and snapshots live there instead of\n"
     "--data (docs/cluster.md)",
     CLI_AT_STRING(serve_options, cluster_urls)},
    {"node", "NAME", "--cluster: this node's name (default: the host name)",
     CLI_AT_STRING(serve_options, node)},
    {"world", "NAME", "--cluster: the same as --worlds NAME", CLI_AT_STRING(serve_options, worlds)},
    {"worlds", "A,B,...",
     "--cluster: the worlds this node may tick (registered with\n"
     "terrad world add; default: any registered world, in name order).\n"
     "A node waits (a standby) until it can take one",
     CLI_AT_STRING(serve_options, worlds)},
    {"max-worlds", "K",
     "--cluster: worlds this node ticks at once, all on one pool of\n"
     "sim workers (default 1; with --worlds, as many as named).\n"
     "A single daemon: worlds POST /v1/worlds may create beside the\n"
     "default one (default 16)",
     CLI_AT_INT(serve_options, max_worlds, 1, SERVE_WORLDS_MAX)},
    {"compact-records", "N",
     "--cluster: log records (one a tick) between compactions of a\n"
     "world's log into tile snapshots (default 600). The log before the\n"
     "last compaction is purged: spectators and /v1/heights?tick=\n"
     "reach back to it, recovery replays up to N records",
     CLI_AT_INT(serve_options, compact_records, 1, 1 << 24)},
    {"auth-file", "FILE",
     "tokens with roles (viewer, driver, admin), one \"ROLE NAME\n"
     "SHA256HEX\" a line (terrad token add); SIGHUP reads it again\n"
     "and closes connections of revoked tokens",
     CLI_AT_STRING(serve_options, auth_file)},
    {"tls-cert", "FILE", "PEM certificate (chain): both ports TLS only",
     CLI_AT_STRING(serve_options, tls_cert)},
    {"tls-key", "FILE", "PEM private key of --tls-cert", CLI_AT_STRING(serve_options, tls_key)},
    {"probe-port", "N",
     "also serve /healthz /readyz /metrics on 127.0.0.1:N with its own\n"
     "connection budget (0: any free port; default: none)",
     CLI_AT_INT(serve_options, probe_port, 0, 65535)},
    {"drain-grace-ms", "MS",
     "SIGTERM (or POST /v1/drain) drains: /readyz fails, new clients\n"
     "and worlds are refused, connected clients are told; the daemon\n"
     "stops once they have all left, or MS after (default 0: at once;\n"
     "set it below the orchestrator's grace, docs/fleet.md)",
     CLI_AT_INT(serve_options, drain_grace_ms, 0, 86400000L)},
    {"scene-dir", "DIR",
     "scenes POST /v1/worlds may name (\"scene_name\": NAME reads\n"
     "DIR/NAME.json; default: none, only scenes in the body)",
     CLI_AT_STRING(serve_options, scene_dir)},
    {"public-ws-url", "URL",
     "the websocket's address as clients reach it (ws://HOST:PORT/PATH\n"
     "or wss://…), for a proxy that maps ports or paths: what GET\n"
     "/v1/websocket tells the viewer (default: the Host the browser\n"
     "used, with the websocket port)",
     CLI_CALLS(public_ws_url_option)},
    {0},
};

static const cli_option *serve_rows(void)
{
    return serve_table;
}

static const char serve_usage[] = "[options]";

void app_serve_usage(FILE *out)
{
    cli_print_help(out, "serve", serve_usage, serve_table);
    net_limits_usage(out);
}

cli_result serve_options_parse(int argc, char **argv, serve_options *o)
{
    memset(o, 0, sizeof *o);
    o->backend = "auto";
    o->http_port = 8080;
    o->ws_port = 8081;
    o->probe_port = -1;
    o->demo_actors = 6;
    o->max_ticks = -1;
    o->limits = net_limits_default();
    o->data_dir = "./data";
    o->durability = "every-tick";
    o->store_fault = getenv("TERRAD_STORE_FAULT");
    cli_result r = cli_parse("serve", serve_usage, serve_table, argc, argv, o, NULL);
    if (r == CLI_HELP)
        net_limits_usage(stdout); /* after the options cli_parse printed */
    if (o->data_dir && o->data_dir == o->config_data)
        o->data_given = 1; /* "data" in --config */
    /* the demo's pits would pile up in ./data run after run: a demo world is
     * kept only where asked for */
    if (r == CLI_OK && o->demo_actors > 0 && o->data_dir && !o->data_given) {
        o->data_dir = NULL;
        o->demo_in_memory = 1;
    }
    if (r == CLI_OK && o->bind_any && !(o->auth_file && o->auth_file[0]) && !o->insecure_open) {
        log_error("serve: --bind-any without a token would let anyone who can reach the ports "
                  "deform the world: give --auth-file (terrad token add), or pass "
                  "--insecure-open");
        return CLI_ERROR;
    }
    return r;
}

host_sim_config serve_host_config(const serve_options *o)
{
    return (host_sim_config){.backend = o->backend,
                             .max_tick_cells = o->limits.max_tick_cells,
                             .max_sweep_cells = o->limits.max_sweep_cells,
                             .checksum_interval_ticks = o->limits.checksum_interval_ticks,
                             .demo_actors = o->demo_actors};
}
