/*
 * cluster_wal.c: a world's fenced write-ahead log (cluster.h) on the stream
 * TERRAD_WAL, subject terrad.wal.<world>. Every publish carries the header
 * Nats-Expected-Last-Subject-Sequence with the last sequence this writer
 * saw, so JetStream refuses it once anyone else appended — the fencing that
 * makes a deposed owner's commit fail. In the tick, the store's commit is
 * cluster_wal_append, which returns only once the stream's replicas have
 * acknowledged the record.
 *
 * A record larger than max_payload goes out as parts (header Terrad-Part:
 * "i/n"), each expecting the previous part's sequence; a reader keeps a
 * record only when all its parts follow each other. Owner markers and
 * confirm records (header Terrad-Kind: owner / confirm, the node's name as
 * data) carry no terrain; they only move the expected sequence.
 *
 * A take is confirmed before the new owner serves anything: nats-server 2.9
 * checks the expected sequence of a clustered stream only before proposing,
 * against what the leader has applied, so an old owner's append in flight
 * when the marker is proposed is stored too (cluster_wal_take says how it is
 * found). One writer per cluster_wal, one append in flight at a time
 * (js_PublishMsg waits for the PubAck): not for concurrent use.
 */
#include "cluster/cluster_internal.h"

#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <cjson/cJSON.h>

#include "metrics/metrics.h"

#define HDR_EXPECT "Nats-Expected-Last-Subject-Sequence"
#define HDR_KIND "Terrad-Kind"
#define HDR_PART "Terrad-Part"
#define PART_ROOM 512 /* headers and protocol overhead within max_payload */
#define KIND_OWNER "owner"
#define KIND_CONFIRM "confirm"

struct cluster_wal {
    cluster *cl;
    char world[CLUSTER_WORLD_NAME_MAX + 1];
    char subject[128];
    uint64_t last_seq;
    int uncertain;       /* an append failed without an answer: it may have landed */
    uint64_t must_start; /* the next read's first message must be at this sequence (0: any) */
    /* a confirming read (wal_confirm): what it found after the point recovered to */
    int checking;            /* classify each message read */
    uint64_t confirm_seq;    /* this writer's confirm record, which the read must reach (0: none) */
    int saw_confirm;         /* the read delivered confirm_seq */
    int64_t foreign;         /* messages read that are not this node's markers */
    char first_foreign[160]; /* the first of them, in words */
    int64_t takes_redone;    /* by the last cluster_wal_take */
    /* a record being put together from its parts while reading */
    uint8_t *part_data;
    int64_t part_len, part_capacity;
    int part_next, part_total;
};

void cluster_wal_subject(const char *world, char *out, size_t cap)
{
    snprintf(out, cap, "%s%s", CLUSTER_SUBJECT_PREFIX, world);
}

cluster_wal *cluster_wal_open(cluster *cl, const char *world, error_text *err)
{
    if (!cluster_name_valid(world, "world", err))
        return NULL;
    cluster_wal *w = calloc(1, sizeof *w);
    if (!w) {
        error_set(err, "out of memory");
        return NULL;
    }
    w->cl = cl;
    snprintf(w->world, sizeof w->world, "%s", world);
    cluster_wal_subject(world, w->subject, sizeof w->subject);
    return w;
}

void cluster_wal_close(cluster_wal *w)
{
    if (!w)
        return;
    free(w->part_data);
    free(w);
}

uint64_t cluster_wal_last_seq(const cluster_wal *w)
{
    return w->last_seq;
}

/* The subject's last sequence in the stream (0: none). */
static cluster_status wal_end(cluster_wal *w, uint64_t *end, error_text *err)
{
    natsMsg *msg = NULL;
    jsErrCode code = 0;
    natsStatus s = js_GetLastMsg(&msg, w->cl->js, CLUSTER_STREAM, w->subject, NULL, &code);
    if (s == NATS_NOT_FOUND || code == JSNoMessageFoundErr) {
        *end = 0;
        return CLUSTER_OK;
    }
    if (s != NATS_OK) {
        cluster_error(err, s, "log of world %s", w->world);
        return CLUSTER_ERROR;
    }
    *end = natsMsg_GetSequence(msg);
    natsMsg_Destroy(msg);
    return CLUSTER_OK;
}

/* During a confirming read: is this message this node's own marker? Anything
 * else after the point recovered to is foreign; the first is described for
 * the log line. */
static void wal_classify(cluster_wal *w, uint64_t seq, const char *kind, int marker,
                         const uint8_t *data, size_t len)
{
    const char *node = cluster_node(w->cl);
    if (marker && len == strlen(node) && memcmp(data, node, len) == 0) {
        if (seq == w->confirm_seq)
            w->saw_confirm = 1;
        return;
    }
    if (w->foreign++ > 0)
        return;
    if (marker)
        snprintf(w->first_foreign, sizeof w->first_foreign,
                 "sequence %" PRIu64 ", %s %s of node %.*s", seq,
                 strcmp(kind, KIND_OWNER) == 0 ? "an" : "a",
                 strcmp(kind, KIND_OWNER) == 0 ? "owner marker" : "confirm record",
                 (int)(len < 64 ? len : 64), (const char *)data);
    else
        snprintf(w->first_foreign, sizeof w->first_foreign,
                 "sequence %" PRIu64 ", a record of %zu bytes", seq, len);
}

/* One message of the log: a part of a record, a whole record or a marker. */
static int wal_deliver(cluster_wal *w, natsMsg *msg, uint64_t seq, cluster_record_fn on_record,
                       void *ctx)
{
    const char *kind = NULL, *part = NULL;
    natsMsgHeader_Get(msg, HDR_KIND, &kind);
    const uint8_t *data = (const uint8_t *)natsMsg_GetData(msg);
    size_t len = (size_t)natsMsg_GetDataLength(msg);
    int marker = kind && (strcmp(kind, KIND_OWNER) == 0 || strcmp(kind, KIND_CONFIRM) == 0);
    if (w->checking)
        wal_classify(w, seq, kind, marker, data, len);
    /* A marker does not cut off a record whose parts it sits between: a later
     * part expected the part before it, so past a marker it can only have
     * landed by the race cluster_wal_take confirms against — its writer had
     * it acknowledged, and it is part of the log. A record whose last parts
     * never came is dropped at the next record's first part. */
    if (marker)
        return 0;
    int i = 0, n = 0;
    if (natsMsgHeader_Get(msg, HDR_PART, &part) != NATS_OK || sscanf(part, "%d/%d", &i, &n) != 2 ||
        n <= 1) {
        w->part_next = 0;
        return on_record ? on_record(ctx, seq, data, len) : 0;
    }
    if (i == 1) {
        w->part_len = 0;
        w->part_total = n;
    } else if (i != w->part_next || n != w->part_total) {
        w->part_next = 0; /* not the part expected: an incomplete record, dropped */
        return 0;
    }
    if (array_grow((void **)&w->part_data, &w->part_capacity, w->part_len + (int64_t)len, 1) != 0)
        return -1;
    memcpy(w->part_data + w->part_len, data, len);
    w->part_len += (int64_t)len;
    w->part_next = i + 1;
    if (i < n)
        return 0;
    w->part_next = 0;
    return on_record ? on_record(ctx, seq, w->part_data, (size_t)w->part_len) : 0;
}

/* The API's message as a natsMsg with its headers ("NATS/1.0\r\nK: V\r\n..."). */
static natsMsg *wal_message_from_json(const cJSON *m, const char *subject)
{
    const cJSON *data = cJSON_GetObjectItemCaseSensitive(m, "data");
    const cJSON *hdrs = cJSON_GetObjectItemCaseSensitive(m, "hdrs");
    const char *d = cJSON_IsString(data) ? data->valuestring : "";
    uint8_t *bytes = malloc(strlen(d) * 3 / 4 + 4);
    int64_t len = bytes ? base64_decode(d, bytes) : -1;
    natsMsg *msg = NULL;
    if (len < 0 || natsMsg_Create(&msg, subject, NULL, (const char *)bytes, (int)len) != NATS_OK) {
        free(bytes);
        return NULL;
    }
    free(bytes);
    if (cJSON_IsString(hdrs)) {
        char *text = malloc(strlen(hdrs->valuestring) * 3 / 4 + 4);
        int64_t n = text ? base64_decode(hdrs->valuestring, (uint8_t *)text) : -1;
        if (n < 0) {
            free(text);
            natsMsg_Destroy(msg);
            return NULL;
        }
        text[n] = '\0';
        char *save = NULL;
        for (char *line = strtok_r(text, "\r\n", &save); line;
             line = strtok_r(NULL, "\r\n", &save)) {
            char *colon = strchr(line, ':');
            if (!colon || strncmp(line, "NATS/", 5) == 0)
                continue;
            *colon = '\0';
            const char *value = colon + 1;
            while (*value == ' ')
                value++;
            natsMsgHeader_Add(msg, line, value);
        }
        free(text);
    }
    return msg;
}

/* "The subject's next message from *from", asked of the stream's leader
 * ($JS.API.STREAM.MSG.GET with next_by_subj: a replica's direct get could
 * answer from a store that lost its last writes to a kill -9 and skip
 * records). NATS_NOT_FOUND: none at or after *from. */
static natsStatus log_get_next(cluster *cl, const char *subject, uint64_t from, natsMsg **out,
                               uint64_t *seq)
{
    char api[128], req[256];
    snprintf(api, sizeof api, "$JS.API.STREAM.MSG.GET.%s", CLUSTER_STREAM);
    snprintf(req, sizeof req, "{\"seq\":%" PRIu64 ",\"next_by_subj\":\"%s\"}", from, subject);
    natsMsg *reply = NULL;
    natsStatus s = natsConnection_RequestString(&reply, cl->nc, api, req, cl->timeout_ms);
    if (s != NATS_OK)
        return s;
    cJSON *doc =
        cJSON_ParseWithLength(natsMsg_GetData(reply), (size_t)natsMsg_GetDataLength(reply));
    natsMsg_Destroy(reply);
    const cJSON *m = cJSON_GetObjectItemCaseSensitive(doc, "message");
    const cJSON *error = cJSON_GetObjectItemCaseSensitive(doc, "error");
    const cJSON *q = cJSON_GetObjectItemCaseSensitive(m, "seq");
    s = NATS_ERR;
    if (error) {
        const cJSON *code = cJSON_GetObjectItemCaseSensitive(error, "err_code");
        s = cJSON_IsNumber(code) && code->valueint == JSNoMessageFoundErr ? NATS_NOT_FOUND
                                                                          : NATS_ERR;
    } else if (cJSON_IsNumber(q) && q->valuedouble >= (double)from) {
        *seq = (uint64_t)q->valuedouble;
        *out = wal_message_from_json(m, subject);
        s = *out ? NATS_OK : NATS_ERR;
    }
    cJSON_Delete(doc);
    return s;
}

/* Delivers the messages from *from until the leader says there is none
 * after (NATS_NOT_FOUND ends the pass: *done), one request each; *from moves
 * past each one, so a retry resumes there. Reading needs no consumer, so it
 * works while the cluster is still electing a meta leader after losing a
 * server. *stopped: on_record refused, or the first message is not at
 * w->must_start. */
static natsStatus wal_read_pass(cluster_wal *w, uint64_t *from, cluster_record_fn on_record,
                                void *ctx, int *stopped, int *done)
{
    natsStatus s = NATS_OK;
    while (s == NATS_OK && !*stopped) {
        natsMsg *msg = NULL;
        uint64_t seq = 0;
        s = log_get_next(w->cl, w->subject, *from, &msg, &seq);
        if (s == NATS_NOT_FOUND) {
            *done = 1;
            return NATS_OK;
        }
        if (s != NATS_OK)
            break;
        if (w->must_start && seq != w->must_start) {
            *stopped = 1;
        } else {
            w->must_start = 0;
            *stopped = wal_deliver(w, msg, seq, on_record, ctx) != 0;
            *from = seq + 1;
        }
        natsMsg_Destroy(msg);
    }
    return s;
}

/* What cluster_wal_next hands over: the record wal_deliver put together. */
typedef struct wal_grab {
    uint8_t **buf;
    int64_t *cap;
    size_t len;
    int got;
} wal_grab;

static int wal_grab_record(void *ctx, uint64_t seq, const uint8_t *data, size_t len)
{
    (void)seq;
    wal_grab *g = ctx;
    if (array_grow((void **)g->buf, g->cap, (int64_t)len + 1, 1) != 0)
        return -1;
    memcpy(*g->buf, data, len);
    g->len = len;
    g->got = 1;
    return 0;
}

int cluster_wal_next(cluster_wal *w, uint64_t *from, uint64_t *first, uint8_t **buf, int64_t *cap,
                     size_t *len, uint64_t *seq, error_text *err)
{
    *first = 0;
    for (int tries = 0;;) {
        natsMsg *msg = NULL;
        uint64_t at = 0;
        natsStatus s = log_get_next(w->cl, w->subject, *from, &msg, &at);
        if (s == NATS_NOT_FOUND)
            return 0;
        if (s != NATS_OK) { /* a leader being elected: a few tries, as wal_read's passes */
            if (++tries < 4) {
                nats_Sleep(100);
                continue;
            }
            cluster_error(err, s, "reading the log of world %s from sequence %" PRIu64, w->world,
                          *from);
            return -1;
        }
        if (!*first)
            *first = at;
        wal_grab g = {.buf = buf, .cap = cap};
        int rc = wal_deliver(w, msg, at, wal_grab_record, &g);
        natsMsg_Destroy(msg);
        *from = at + 1;
        if (rc != 0) {
            error_set(err, "log of world %s: out of memory for a record", w->world);
            return -1;
        }
        if (g.got) {
            *len = g.len;
            *seq = at;
            return 1;
        }
    }
}

/* The log is read to where the leader has no next message, not only to the
 * end its last_by_subj answer named: the two answers come from different
 * lookups of the leader's store, and the chaos runs (docs/cluster.md,
 * "Chaos") met a leader, right after NATS servers were killed and started
 * again, that answered "no message" to last_by_subj for a world whose log
 * held thousands: a recovery that trusted it replayed nothing, restarted the
 * world at tick 0, and its owner marker, expecting that empty end, was
 * accepted — every acknowledged tick of the world lost. So both answers must
 * agree before the log counts as read, and an end short of what was read is
 * not believed. */
static cluster_status wal_read(cluster_wal *w, uint64_t from_seq, int keep_parts,
                               cluster_record_fn on_record, void *ctx, error_text *err)
{
    uint64_t end = 0;
    if (wal_end(w, &end, err) != CLUSTER_OK)
        return CLUSTER_ERROR;
    /* A continuation (cluster_wal_take reading on) keeps a record's first parts. */
    if (!keep_parts)
        w->part_next = 0;
    if (from_seq == 0)
        from_seq = 1;
    uint64_t from = from_seq;
    int stopped = 0, done = 0;
    natsStatus s = NATS_OK;
    /* Right after a server is lost, a replica may be behind or the stream's
     * leader being elected: a few passes, each resuming where it stopped. */
    for (double deadline = time_now_ms() + 4.0 * w->cl->timeout_ms; !done && !stopped;) {
        s = wal_read_pass(w, &from, on_record, ctx, &stopped, &done);
        if (s == NATS_OK || time_now_ms() > deadline)
            break;
        nats_Sleep(100);
    }
    if (stopped && w->must_start) {
        error_set(err,
                  "log of world %s: the record at sequence %" PRIu64 " that the snapshot index "
                  "covers is not there (the stream's answer is behind): not read now",
                  w->world, w->must_start);
        w->must_start = 0;
        return CLUSTER_ERROR;
    }
    if (stopped) {
        error_set(err, "log of world %s: reading stopped at sequence %" PRIu64, w->world, from - 1);
        return CLUSTER_ERROR;
    }
    if (s != NATS_OK || !done) {
        cluster_error(err, s, "reading the log of world %s from sequence %" PRIu64, w->world, from);
        return CLUSTER_ERROR;
    }
    if (end >= from) {
        error_set(err,
                  "log of world %s: its last message is at sequence %" PRIu64 " but reading "
                  "it ends before %" PRIu64 " (the stream's answers disagree): not read now",
                  w->world, end, from);
        return CLUSTER_ERROR;
    }
    w->last_seq = from - 1 > end ? from - 1 : end;
    w->uncertain = 0;
    return CLUSTER_OK;
}

cluster_status cluster_wal_read(cluster_wal *w, uint64_t from_seq, cluster_record_fn on_record,
                                void *ctx, error_text *err)
{
    return wal_read(w, from_seq, from_seq == w->last_seq + 1, on_record, ctx, err);
}

/* One publish expecting w->last_seq; on success w->last_seq is its sequence. */
static cluster_status wal_publish(cluster_wal *w, const void *data, size_t len, const char *kind,
                                  const char *part, error_text *err)
{
    natsMsg *msg = NULL;
    char expect[32];
    snprintf(expect, sizeof expect, "%" PRIu64, w->last_seq);
    natsStatus s = natsMsg_Create(&msg, w->subject, NULL, data, (int)len);
    if (s == NATS_OK)
        s = natsMsgHeader_Set(msg, HDR_EXPECT, expect);
    if (s == NATS_OK && kind)
        s = natsMsgHeader_Set(msg, HDR_KIND, kind);
    if (s == NATS_OK && part)
        s = natsMsgHeader_Set(msg, HDR_PART, part);
    jsPubAck *ack = NULL;
    jsErrCode code = 0;
    /* Not sent at all while disconnected (it could land after the reconnect). */
    if (s == NATS_OK && natsConnection_Status(w->cl->nc) != NATS_CONN_STATUS_CONNECTED) {
        natsMsg_Destroy(msg);
        error_set(err, "appending to the log of world %s: not connected to NATS", w->world);
        return CLUSTER_ERROR;
    }
    if (s == NATS_OK) {
        jsPubOptions po;
        jsPubOptions_Init(&po);
        po.MaxWait = w->cl->timeout_ms;
        s = js_PublishMsg(&ack, w->cl->js, msg, &po, &code);
    }
    natsMsg_Destroy(msg);
    if (s == NATS_OK) {
        w->last_seq = ack->Sequence;
        jsPubAck_Destroy(ack);
        return CLUSTER_OK;
    }
    if (code == JSStreamWrongLastSequenceErr) {
        error_set(err,
                  "log of world %s: another owner appended after sequence %" PRIu64
                  " (this node is fenced off)",
                  w->world, w->last_seq);
        return CLUSTER_FENCED;
    }
    cluster_error(err, s, "appending to the log of world %s", w->world);
    return CLUSTER_ERROR;
}

/* Appends a confirm record expecting w->last_seq, then reads the subject from
 * recovered + 1 to where the leader has no next message, handing every record
 * it finds to on_record. *clean: the confirm record was accepted, the read
 * reached it, and nothing but this node's own markers lies after recovered.
 * Why this proves a take (or an append whose answer was lost): whatever
 * another writer had proposed before the confirm record is before it in the
 * stream's raft log, and the PubAck of the confirm record comes from the
 * leader once it applied it, so the leader's read after that answer holds
 * every such append; anything proposed later expects a sequence below ours
 * and is refused by the leader's check. */
static cluster_status wal_confirm(cluster_wal *w, uint64_t recovered, cluster_record_fn on_record,
                                  void *ctx, int *clean, error_text *err)
{
    const char *node = cluster_node(w->cl);
    uint64_t expected = w->last_seq;
    cluster_status r = wal_publish(w, node, strlen(node), KIND_CONFIRM, NULL, err);
    if (r == CLUSTER_ERROR)
        return CLUSTER_ERROR;
    w->checking = 1;
    w->confirm_seq = r == CLUSTER_OK ? w->last_seq : 0;
    w->saw_confirm = 0;
    w->foreign = 0;
    w->first_foreign[0] = '\0';
    cluster_status got = wal_read(w, recovered + 1, 1, on_record, ctx, err);
    w->checking = 0;
    if (got != CLUSTER_OK)
        return CLUSTER_ERROR;
    *clean = r == CLUSTER_OK && w->foreign == 0 && w->saw_confirm;
    if (!*clean && w->foreign == 0)
        snprintf(w->first_foreign, sizeof w->first_foreign,
                 r == CLUSTER_OK ? "the leader's answer does not yet hold the confirm record "
                                   "(it expected sequence %" PRIu64 ")"
                                 : "the confirm record expecting sequence %" PRIu64 " was refused",
                 expected);
    return CLUSTER_OK;
}

/* After an append that got no answer: did it land? It may still be in
 * flight (a paused server holds it), so the log's end now proves nothing; a
 * confirm record does. If anything but the confirm lies after what this
 * writer last saw, its view is not the log's any more: it must stop and be
 * reloaded. */
static cluster_status wal_resolve(cluster_wal *w, error_text *err)
{
    uint64_t before = w->last_seq;
    int clean = 0;
    if (wal_confirm(w, before, NULL, NULL, &clean, err) != CLUSTER_OK)
        return CLUSTER_ERROR;
    if (!clean) {
        error_set(err,
                  "log of world %s: after an append whose answer was lost, %s after sequence "
                  "%" PRIu64 " (this writer expected nothing else there); reload from the log",
                  w->world, w->first_foreign, before);
        return CLUSTER_FENCED;
    }
    w->uncertain = 0;
    return CLUSTER_OK;
}

cluster_status cluster_wal_append(cluster_wal *w, const void *data, size_t len, uint64_t *seq,
                                  error_text *err)
{
    if (w->uncertain) {
        cluster_status r = wal_resolve(w, err);
        if (r != CLUSTER_OK)
            return r;
    }
    size_t room =
        (size_t)(w->cl->max_payload > 2 * PART_ROOM ? w->cl->max_payload - PART_ROOM : PART_ROOM);
    size_t parts = len <= room ? 1 : (len + room - 1) / room;
    if (parts > 1000000) {
        error_set(err, "log of world %s: a record of %zu bytes is too large", w->world, len);
        return CLUSTER_ERROR;
    }
    const uint8_t *bytes = data;
    for (size_t i = 0; i < parts; i++) {
        char part[48];
        size_t at = i * room, n = len - at < room ? len - at : room;
        snprintf(part, sizeof part, "%zu/%zu", i + 1, parts);
        cluster_status r = wal_publish(w, bytes + at, n, NULL, parts > 1 ? part : NULL, err);
        if (r == CLUSTER_ERROR)
            w->uncertain = 1;
        if (r != CLUSTER_OK)
            return r;
    }
    if (seq)
        *seq = w->last_seq;
    return CLUSTER_OK;
}

cluster_status cluster_wal_take(cluster_wal *w, uint64_t from_seq, cluster_record_fn on_record,
                                void *ctx, error_text *err)
{
    /* from_seq > 1 is a snapshot index's: the record there is never purged */
    w->must_start = from_seq > 1 ? from_seq : 0;
    w->takes_redone = 0;
    if (cluster_wal_read(w, from_seq, on_record, ctx, err) != CLUSTER_OK)
        return CLUSTER_ERROR;
    const char *node = cluster_node(w->cl);
    for (int attempt = 0; attempt < 100; attempt++) {
        uint64_t recovered = w->last_seq;
        cluster_status r = wal_publish(w, node, strlen(node), KIND_OWNER, NULL, err);
        if (r == CLUSTER_ERROR)
            return r;
        if (r == CLUSTER_FENCED) {
            /* the previous owner committed meanwhile: its records are ours to replay */
            if (cluster_wal_read(w, w->last_seq + 1, on_record, ctx, err) != CLUSTER_OK)
                return CLUSTER_ERROR;
            continue;
        }
        /* The marker was accepted, but on nats-server 2.9 an old owner's
         * append proposed before it was applied is stored too, before or
         * after it (docs/cluster.md, "The fencing race"): confirm the take
         * before anything is served. A foreign record found is applied (its
         * writer may have acknowledged it) and the take is made again,
         * expecting the log's true end. */
        int clean = 0;
        if (wal_confirm(w, recovered, on_record, ctx, &clean, err) != CLUSTER_OK)
            return CLUSTER_ERROR;
        if (clean)
            return CLUSTER_OK;
        w->takes_redone++;
        metrics_count_cluster_take_redone();
        log_info("cluster: world %s: take after sequence %" PRIu64 " not clean: %s; read on to "
                 "sequence %" PRIu64 ", taking again",
                 w->world, recovered, w->first_foreign, w->last_seq);
    }
    error_set(err, "log of world %s: another writer keeps appending; not taken", w->world);
    return CLUSTER_FENCED;
}

int64_t cluster_wal_takes_redone(const cluster_wal *w)
{
    return w->takes_redone;
}

/* Removes the world's messages below seq one by one ($JS.API.STREAM.MSG.DELETE),
 * never with a purge filtered by subject: nats-server before 2.9.18 (Debian 12
 * ships 2.9.10) replays a purge, when a restarted server recovers its stream,
 * as a purge of the whole stream up to the purge's last sequence — every
 * other world's messages below it went with it on that server (nats-server
 * issue #4196, fixed by #4212). make chaos met it: after a NATS server was
 * killed and started again and led the stream, worlds recovered at tick 0 or
 * could not be recovered (docs/cluster.md, "Chaos"). A delete is replayed as
 * that one delete. */
cluster_status cluster_log_purge_below(cluster *cl, const char *world, uint64_t seq,
                                       error_text *err)
{
    char subject[128];
    cluster_wal_subject(world, subject, sizeof subject);
    jsOptions jo;
    jsOptions_Init(&jo);
    jo.Wait = cl->timeout_ms;
    uint64_t from = 1;
    for (;;) {
        natsMsg *msg = NULL;
        uint64_t at = 0;
        natsStatus s = log_get_next(cl, subject, from, &msg, &at);
        if (s == NATS_NOT_FOUND)
            return CLUSTER_OK;
        natsMsg_Destroy(msg);
        if (s == NATS_OK && at >= seq)
            return CLUSTER_OK;
        jsErrCode code = 0;
        if (s == NATS_OK)
            s = js_DeleteMsg(cl->js, CLUSTER_STREAM, at, &jo, &code);
        if (s != NATS_OK && code != JSNoMessageFoundErr) {
            cluster_error(err, s, "removing the log of world %s below %" PRIu64, world, seq);
            return CLUSTER_ERROR;
        }
        from = at + 1;
    }
}

cluster_status cluster_wal_purge_below(cluster_wal *w, uint64_t seq, error_text *err)
{
    /* The subject's last message always stays: it is what the next append expects. */
    return cluster_log_purge_below(w->cl, w->world, seq < w->last_seq ? seq : w->last_seq, err);
}
