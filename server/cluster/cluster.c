/*
 * cluster.c: the connection to the NATS servers and the JetStream objects
 * every node shares (cluster.h): the stream TERRAD_WAL and the buckets
 * TERRAD_LEASES, TERRAD_TILES and TERRAD_WORLDS, created by whichever node
 * comes first. Runs at start; the tick only uses what it set up.
 */
#include "cluster/cluster_internal.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void cluster_error(error_text *err, natsStatus s, const char *fmt, ...)
{
    char what[160];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(what, sizeof what, fmt, ap);
    va_end(ap);
    natsStatus last_status = NATS_OK;
    const char *last = nats_GetLastError(&last_status);
    if (last && last[0] == '(') { /* "(conn.c:2088): text": the text only */
        const char *end = strstr(last, "): ");
        last = end ? end + 3 : last;
    }
    /* "NATS:" whatever failed, unless what says so already: an operator
     * reading /readyz or a log line learns that NATS, not this node, failed */
    const char *from = strstr(what, "NATS") ? "" : "NATS: ";
    if (last && last[0] && strcmp(last, natsStatus_GetText(s)) != 0)
        error_set(err, "%s: %s%s (%s)", what, from, natsStatus_GetText(s), last);
    else
        error_set(err, "%s: %s%s", what, from, natsStatus_GetText(s));
}

int cluster_name_valid(const char *name, const char *what, error_text *err)
{
    size_t n = name ? strlen(name) : 0;
    if (n == 0 || n > CLUSTER_WORLD_NAME_MAX) {
        error_set(err, "%s name must be 1 to %d characters", what, CLUSTER_WORLD_NAME_MAX);
        return 0;
    }
    for (size_t i = 0; i < n; i++) {
        char c = name[i];
        int ok = (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || (c >= '0' && c <= '9') ||
                 c == '_' || c == '-';
        if (!ok) {
            error_set(err, "%s name \"%s\": only letters, digits, '_' and '-' are allowed", what,
                      name);
            return 0;
        }
    }
    return 1;
}

/* The comma-separated URLs as an array of pointers into buf. */
static int split_urls(char *buf, const char **urls, int cap)
{
    int n = 0;
    for (char *save = NULL, *tok = strtok_r(buf, ",", &save); tok && n < cap;
         tok = strtok_r(NULL, ",", &save)) {
        while (*tok == ' ')
            tok++;
        if (*tok)
            urls[n++] = tok;
    }
    return n;
}

static int connect_servers(cluster *cl, const cluster_config *c, int *url_count, error_text *err)
{
    char buf[sizeof cl->urls];
    const char *urls[32];
    snprintf(buf, sizeof buf, "%s", c->urls);
    int n = split_urls(buf, urls, 32);
    if (n == 0) {
        error_set(err, "no NATS URL given");
        return -1;
    }
    *url_count = n;
    natsOptions *opts = NULL;
    natsStatus s = natsOptions_Create(&opts);
    if (s == NATS_OK)
        s = natsOptions_SetServers(opts, urls, n);
    if (s == NATS_OK)
        s = natsOptions_SetTimeout(opts, cl->timeout_ms);
    if (s == NATS_OK)
        s = natsOptions_SetName(opts, cl->node);
    if (s == NATS_OK)
        s = natsOptions_SetMaxReconnect(opts, -1); /* a node waits for NATS to come back */
    if (s == NATS_OK)
        s = natsOptions_SetReconnectWait(opts, 250);
    /* No buffering while disconnected: a commit fails at once instead of
     * landing later, after its tick was already undone. */
    if (s == NATS_OK)
        s = natsOptions_SetReconnectBufSize(opts, 1);
    if (s != NATS_OK) {
        natsOptions_Destroy(opts);
        cluster_error(err, s, "NATS options for %s", c->urls);
        return -1;
    }
    s = natsConnection_Connect(&cl->nc, opts);
    natsOptions_Destroy(opts);
    if (s != NATS_OK) {
        cl->nc = NULL;
        cluster_error(err, s, "cannot reach NATS at %s", c->urls);
        return -1;
    }
    cl->max_payload = natsConnection_GetMaxPayload(cl->nc);
    return 0;
}

/* Distinct servers known: those given and those the cluster told about. */
static int known_servers(cluster *cl, int given)
{
    char **servers = NULL;
    int count = 0;
    if (natsConnection_GetServers(cl->nc, &servers, &count) != NATS_OK)
        return given;
    for (int i = 0; i < count; i++)
        free(servers[i]);
    free(servers);
    return count > given ? count : given;
}

/* A stream or bucket request may fail while the JetStream cluster elects
 * its meta leader right after the servers start: retried for a while. */
static int retryable(natsStatus s, jsErrCode code)
{
    return s == NATS_TIMEOUT || s == NATS_NO_RESPONDERS || code == JSClusterNotAvailErr ||
           code == JSClusterNoPeersErr /* servers still joining */ || code == JSNotEnabledErr ||
           code == JSNotEnabledForAccountErr;
}

static int ensure_stream(cluster *cl, error_text *err)
{
    char subjects[64];
    snprintf(subjects, sizeof subjects, "%s>", CLUSTER_SUBJECT_PREFIX);
    const char *list[1] = {subjects};
    jsStreamConfig cfg;
    jsStreamConfig_Init(&cfg);
    cfg.Name = CLUSTER_STREAM;
    cfg.Subjects = list;
    cfg.SubjectsLen = 1;
    cfg.Storage = js_FileStorage;
    cfg.Replicas = cl->replicas;
    cfg.AllowDirect = true;
    natsStatus s = NATS_OK;
    jsErrCode code = 0;
    for (double deadline = time_now_ms() + 15000.0;;) {
        jsStreamInfo *si = NULL;
        code = 0;
        s = js_GetStreamInfo(&si, cl->js, CLUSTER_STREAM, NULL, &code);
        if (s == NATS_OK) {
            jsStreamInfo_Destroy(si);
            return 0;
        }
        if (s == NATS_NOT_FOUND) {
            code = 0;
            s = js_AddStream(&si, cl->js, &cfg, NULL, &code);
            jsStreamInfo_Destroy(si);
            if (s == NATS_OK || code == JSStreamNameExistErr)
                return 0;
        }
        if (!retryable(s, code) || time_now_ms() > deadline)
            break;
        nats_Sleep(200);
    }
    cluster_error(err, s, "JetStream stream %s (error code %d)", CLUSTER_STREAM, (int)code);
    return -1;
}

static int ensure_bucket(cluster *cl, const char *bucket, kvStore **kv, error_text *err)
{
    kvConfig cfg;
    kvConfig_Init(&cfg);
    cfg.Bucket = bucket;
    cfg.History = 1;
    cfg.Replicas = cl->replicas;
    cfg.StorageType = js_FileStorage;
    natsStatus s = NATS_OK;
    for (double deadline = time_now_ms() + 15000.0;;) {
        s = js_KeyValue(kv, cl->js, bucket);
        if (s == NATS_OK)
            return 0;
        if (s == NATS_NOT_FOUND) {
            s = js_CreateKeyValue(kv, cl->js, &cfg);
            if (s == NATS_OK)
                return 0;
        }
        if (time_now_ms() > deadline)
            break;
        nats_Sleep(200);
    }
    *kv = NULL;
    cluster_error(err, s, "JetStream key-value bucket %s", bucket);
    return -1;
}

int cluster_kv_read(cluster *cl, const char *bucket, const char *key, uint8_t **data, size_t *len,
                    uint64_t *revision, error_text *err)
{
    char stream[96], subject[384];
    snprintf(stream, sizeof stream, "KV_%s", bucket);
    snprintf(subject, sizeof subject, "$KV.%s.%s", bucket, key);
    natsMsg *msg = NULL;
    jsErrCode code = 0;
    natsStatus s = js_GetLastMsg(&msg, cl->js, stream, subject, NULL, &code);
    if (s == NATS_NOT_FOUND || code == JSNoMessageFoundErr)
        return 0;
    if (s != NATS_OK) {
        cluster_error(err, s, "%s key %s", bucket, key);
        return -1;
    }
    const char *op = NULL;
    if (natsMsgHeader_Get(msg, "KV-Operation", &op) == NATS_OK && op &&
        (strcmp(op, "DEL") == 0 || strcmp(op, "PURGE") == 0)) {
        natsMsg_Destroy(msg);
        return 0;
    }
    int n = natsMsg_GetDataLength(msg);
    uint8_t *out = malloc((size_t)n + 1);
    if (!out) {
        natsMsg_Destroy(msg);
        error_set(err, "out of memory");
        return -1;
    }
    if (n > 0)
        memcpy(out, natsMsg_GetData(msg), (size_t)n);
    out[n] = '\0';
    *data = out;
    *len = (size_t)n;
    *revision = natsMsg_GetSequence(msg);
    natsMsg_Destroy(msg);
    return 1;
}

cluster *cluster_connect(const cluster_config *c, error_text *err)
{
    if (!cluster_name_valid(c->node, "node", err))
        return NULL;
    if (!c->urls || strlen(c->urls) >= sizeof(((cluster *)0)->urls)) {
        error_set(err, "NATS URLs missing or too long");
        return NULL;
    }
    cluster *cl = calloc(1, sizeof *cl);
    if (!cl) {
        error_set(err, "out of memory");
        return NULL;
    }
    snprintf(cl->node, sizeof cl->node, "%s", c->node);
    snprintf(cl->urls, sizeof cl->urls, "%s", c->urls);
    cl->lease_ms = c->lease_ms > 0 ? c->lease_ms : 3000;
    cl->timeout_ms = c->timeout_ms > 0 ? c->timeout_ms : 2000;
    cl->renew_ms = c->renew_ms < 0 ? 0 : c->renew_ms > 0 ? c->renew_ms : 1000;
    pthread_mutex_init(&cl->lock, NULL);
    pthread_cond_init(&cl->renewer_wake, NULL);
    int given = 0;
    if (connect_servers(cl, c, &given, err) != 0) {
        cluster_close(cl);
        return NULL;
    }
    cl->replicas = c->replicas > 0 ? c->replicas : (known_servers(cl, given) >= 3 ? 3 : 1);
    jsOptions jo;
    jsOptions_Init(&jo);
    jo.Wait = cl->timeout_ms;
    natsStatus s = natsConnection_JetStream(&cl->js, cl->nc, &jo);
    if (s != NATS_OK) {
        cluster_error(err, s, "JetStream at %s", cl->urls);
        cluster_close(cl);
        return NULL;
    }
    if (ensure_stream(cl, err) != 0 || ensure_bucket(cl, CLUSTER_BUCKET_LEASES, &cl->leases, err) ||
        ensure_bucket(cl, CLUSTER_BUCKET_TILES, &cl->tiles, err) ||
        ensure_bucket(cl, CLUSTER_BUCKET_WORLDS, &cl->worlds, err)) {
        error_prefix(err, cl->urls, ": ");
        cluster_close(cl);
        return NULL;
    }
    if (cl->renew_ms > 0 && cluster_renewer_start(cl) != 0) {
        error_set(err, "cannot start the lease renewal thread");
        cluster_close(cl);
        return NULL;
    }
    return cl;
}

void cluster_close(cluster *cl)
{
    if (!cl)
        return;
    cluster_renewer_stop(cl);
    if (cl->leases && cl->nc) {
        for (int64_t i = 0; i < cl->lease_count; i++)
            if (cl->lease_list[i].held)
                cluster_lease_release(cl, cl->lease_list[i].world);
    }
    kvStore_Destroy(cl->leases);
    kvStore_Destroy(cl->tiles);
    kvStore_Destroy(cl->worlds);
    jsCtx_Destroy(cl->js);
    if (cl->nc) {
        natsConnection_Close(cl->nc);
        natsConnection_Destroy(cl->nc);
    }
    free(cl->lease_list);
    pthread_cond_destroy(&cl->renewer_wake);
    pthread_mutex_destroy(&cl->lock);
    free(cl);
}

int cluster_connected(cluster *cl)
{
    return cl && cl->nc && natsConnection_Status(cl->nc) == NATS_CONN_STATUS_CONNECTED;
}

const char *cluster_node(const cluster *cl)
{
    return cl->node;
}

int64_t cluster_max_payload(const cluster *cl)
{
    return cl->max_payload;
}

int cluster_replicas(const cluster *cl)
{
    return cl->replicas;
}

/* ---- messages between nodes ---- */

struct cluster_sub {
    natsSubscription *sub;
    cluster_msg_fn fn;
    cluster_answer_fn answer_fn; /* cluster_serve_requests */
    natsConnection *nc;
    void *ctx;
};

static void on_message(natsConnection *nc, natsSubscription *sub, natsMsg *msg, void *closure)
{
    (void)nc;
    (void)sub;
    cluster_sub *s = closure;
    s->fn(s->ctx, natsMsg_GetSubject(msg), natsMsg_GetData(msg),
          (size_t)natsMsg_GetDataLength(msg));
    natsMsg_Destroy(msg);
}

static void on_request(natsConnection *nc, natsSubscription *sub, natsMsg *msg, void *closure)
{
    (void)sub;
    cluster_sub *s = closure;
    void *answer = NULL;
    size_t len = 0;
    s->answer_fn(s->ctx, natsMsg_GetData(msg), (size_t)natsMsg_GetDataLength(msg), &answer, &len);
    const char *reply = natsMsg_GetReply(msg);
    if (answer && reply && reply[0]) /* the asker times out when it cannot be sent */
        natsConnection_Publish(nc, reply, answer, (int)len);
    free(answer);
    natsMsg_Destroy(msg);
}

cluster_status cluster_publish(cluster *cl, const char *subject, const void *data, size_t len)
{
    return natsConnection_Publish(cl->nc, subject, data, (int)len) == NATS_OK ? CLUSTER_OK
                                                                              : CLUSTER_ERROR;
}

static cluster_sub *subscribe(cluster *cl, const char *subject, cluster_msg_fn fn,
                              cluster_answer_fn answer_fn, void *ctx, error_text *err)
{
    cluster_sub *s = calloc(1, sizeof *s);
    if (!s) {
        error_set(err, "cluster: out of memory");
        return NULL;
    }
    s->fn = fn;
    s->answer_fn = answer_fn;
    s->nc = cl->nc;
    s->ctx = ctx;
    natsStatus st =
        natsConnection_Subscribe(&s->sub, cl->nc, subject, answer_fn ? on_request : on_message, s);
    if (st == NATS_OK) /* a relay holds what it cannot take yet rather than lose it */
        st = natsSubscription_SetPendingLimits(s->sub, 1 << 20, 1 << 30);
    if (st != NATS_OK) {
        error_set(err, "cluster: cannot subscribe to %s: %s", subject, natsStatus_GetText(st));
        natsSubscription_Destroy(s->sub);
        free(s);
        return NULL;
    }
    return s;
}

cluster_sub *cluster_subscribe(cluster *cl, const char *subject, cluster_msg_fn fn, void *ctx,
                               error_text *err)
{
    return subscribe(cl, subject, fn, NULL, ctx, err);
}

cluster_sub *cluster_serve_requests(cluster *cl, const char *subject, cluster_answer_fn fn,
                                    void *ctx, error_text *err)
{
    return subscribe(cl, subject, NULL, fn, ctx, err);
}

int cluster_request(cluster *cl, const char *subject, const void *data, size_t len, int timeout_ms,
                    void **answer, size_t *answer_len, error_text *err)
{
    *answer = NULL;
    *answer_len = 0;
    natsMsg *reply = NULL;
    natsStatus s = natsConnection_Request(&reply, cl->nc, subject, data, (int)len, timeout_ms);
    if (s == NATS_NO_RESPONDERS)
        return 0;
    if (s != NATS_OK) {
        cluster_error(err, s, "request on %s", subject);
        return -1;
    }
    size_t n = (size_t)natsMsg_GetDataLength(reply);
    *answer = malloc(n ? n : 1);
    if (!*answer) {
        natsMsg_Destroy(reply);
        error_set(err, "cluster: out of memory");
        return -1;
    }
    if (n)
        memcpy(*answer, natsMsg_GetData(reply), n);
    *answer_len = n;
    natsMsg_Destroy(reply);
    return 1;
}

int64_t cluster_sub_dropped(cluster_sub *s)
{
    int64_t dropped = 0;
    natsSubscription_GetDropped(s->sub, &dropped);
    return dropped;
}

void cluster_unsubscribe(cluster_sub *s)
{
    if (!s)
        return;
    if (natsSubscription_Drain(s->sub) == NATS_OK)
        natsSubscription_WaitForDrainCompletion(s->sub, 2000);
    else
        natsSubscription_Unsubscribe(s->sub);
    natsSubscription_Destroy(s->sub);
    free(s);
}
