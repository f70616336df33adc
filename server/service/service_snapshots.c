/*
 * service_snapshots.c: snapshots off the tick (issue 15, item 2: one client
 * asking for whole-world resyncs took the tick from 59.8 to 0.6 per second,
 * because every snapshot was compressed inside the tick).
 *
 * The sim thread only copies: when service_publish_snapshots answers a
 * request in tick t, each tile piece of the request's rectangle is copied
 * (world_gather_window) with its tile version, and the tick's requests are
 * handed to one worker thread at the end of the tick. The worker compresses
 * and frames them (the same frames, byte for byte, as tick t would have
 * built: tick t, tick t's versions, packed under SERVICE_FRAME_MAX, the last
 * frame of a request marked snapshot_done, one empty marked frame per
 * coalesced request) while the sim thread sleeps until tick t + 1. At the
 * start of tick t + 1, before anything of that tick is queued, the sim thread
 * takes the finished frames (waiting for the rest of the work if need be) and
 * queues them: right behind tick t's frames, ahead of tick t + 1's deltas,
 * whose base versions are the snapshot's. A client that has left by then has
 * its frames dropped (terrad_snapshot_requests_dropped_total); the frames
 * are replies in the client's queue, charged against its max_pending_bytes
 * and hard bound like any other output.
 *
 * The worker thread, its codec and its buffer are made at the first
 * snapshot a world serves (start_worker), not with the service: a process
 * may hold hundreds of worlds (issue 22), and one nobody has subscribed to
 * costs no thread. Should the thread not start, the sim thread frames the
 * requests itself (the same frames, inside the tick).
 *
 * A client whose hello asked for base snapshots (PROTOCOL.md "Base
 * snapshots", issue 32 item 2) gets each piece as its heights less the
 * scene's base (subtracted here, on the sim thread, which owns the world's
 * base cache) and the worker codes it with terrad_rect_compress_base, or,
 * for a client that also decodes slope snapshots (encoding 3), with
 * terrad_rect_compress_base_smaller: both codings, the shorter kept.
 */
#include "service/service_internal.h"

#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "metrics/metrics.h"

typedef struct snap_piece {
    terrad_rect rect; /* data: the compressed piece, filled by the worker */
    int32_t *values;  /* the copied cells, freed by the worker */
} snap_piece;

typedef struct snap_frame {
    hub_frame *f; /* NULL: it could not be built (counted when queued) */
    int done;     /* carries snapshot_done */
} snap_frame;

typedef struct snap_request {
    snapshot_job job;
    uint64_t tick;
    snap_piece *pieces;
    int npieces;
    int failed; /* pieces that could not be copied or compressed */
    snap_frame *frames;
    int nframes, frames_cap;
    int mark_only; /* no memory for the pieces: only the marks go out */
} snap_request;

struct snap_worker {
    pthread_t thread;
    int started; /* the thread runs (start_worker) */
    pthread_mutex_t lock;
    pthread_cond_t cond;
    int stop, busy;
    snap_request *job; /* handed over, being framed */
    int njob;
    snap_request *staged; /* this tick's, not yet handed over (sim thread) */
    int nstaged;
    int64_t staged_cap;
    terrad_codec *codec;
    uint8_t *packed;
    size_t packed_cap;
};

static void free_requests(snap_request *r, int n)
{
    for (int i = 0; r && i < n; i++) {
        for (int k = 0; k < r[i].npieces; k++) {
            free(r[i].pieces[k].values);
            free((void *)r[i].pieces[k].rect.data);
        }
        for (int k = 0; k < r[i].nframes; k++)
            if (r[i].frames[k].f)
                hub_frame_unref(r[i].frames[k].f);
        free(r[i].pieces);
        free(r[i].frames);
    }
    free(r);
}

/* ---- the worker: compress and frame ---- */

static void add_frame(snap_request *r, const terrad_rect *rects, int count, int done)
{
    if (r->nframes == r->frames_cap) {
        int cap = r->frames_cap ? 2 * r->frames_cap : 4;
        snap_frame *grown = realloc(r->frames, (size_t)cap * sizeof *grown);
        if (!grown) {
            r->failed++;
            return;
        }
        r->frames = grown;
        r->frames_cap = cap;
    }
    size_t size = terrad_delta_size(rects, (size_t)count);
    hub_frame *f = hub_frame_new(1, size);
    if (f && terrad_delta_encode(f->data, size, &f->len, r->tick, rects, (size_t)count) != 0) {
        hub_frame_unref(f);
        f = NULL;
    }
    r->frames[r->nframes++] = (snap_frame){f, done};
}

static void frame_request(snap_worker *w, snap_request *r)
{
    terrad_rect *rects = calloc((size_t)r->npieces + 1, sizeof *rects);
    int count = 0;
    for (int k = 0; rects && k < r->npieces; k++) {
        snap_piece *p = &r->pieces[k];
        size_t len = 0;
        uint8_t *data = NULL;
        int coded =
            !p->values ? -1
            : p->rect.encoding == TERRAD_ENC_BASE
                ? terrad_rect_compress_base(p->values, p->rect.w, p->rect.h, w->packed,
                                            w->packed_cap, &len)
            : p->rect.encoding == TERRAD_ENC_BASE_SLOPE /* 2 or 3: the shorter */
                ? terrad_rect_compress_base_smaller(p->values, p->rect.w, p->rect.h, w->packed,
                                                    w->packed_cap, &len, &p->rect.encoding)
                : terrad_rect_compress(w->codec, p->values, (size_t)p->rect.w * p->rect.h,
                                       w->packed, w->packed_cap, &len);
        if (coded != 0 || !(data = malloc(len ? len : 1))) {
            r->failed++;
        } else {
            memcpy(data, w->packed, len);
            p->rect.data = data;
            p->rect.data_len = (uint32_t)len;
            rects[count++] = p->rect;
        }
        free(p->values);
        p->values = NULL;
    }
    if (!rects) {
        r->mark_only = 1;
        return;
    }
    int first = 0;
    size_t size = TERRAD_DELTA_FIXED;
    for (int i = 0; i < count; i++) {
        size_t add = TERRAD_RECT_FIXED + rects[i].data_len;
        if (i > first && (size + add > SERVICE_FRAME_MAX || i - first == TERRAD_MAX_COUNT)) {
            add_frame(r, rects + first, i - first, 0);
            first = i;
            size = TERRAD_DELTA_FIXED;
        }
        size += add;
    }
    int mark = r->job.last && !r->job.quiet; /* a tile's resync has no snapshot_done */
    if (count > first || mark)
        add_frame(r, rects + first, count - first, mark);
    terrad_rect none[1] = {{0}};
    for (int m = 0; m < r->job.marks; m++) /* coalesced requests' marks */
        add_frame(r, none, 0, 1);
    free(rects);
}

static void *snap_main(void *arg)
{
    snap_worker *w = arg;
    pthread_mutex_lock(&w->lock);
    for (;;) {
        while (!w->stop && !(w->busy && w->job))
            pthread_cond_wait(&w->cond, &w->lock);
        if (w->stop)
            break;
        snap_request *job = w->job;
        int n = w->njob;
        pthread_mutex_unlock(&w->lock);
        for (int i = 0; i < n; i++)
            if (!job[i].mark_only)
                frame_request(w, &job[i]);
        pthread_mutex_lock(&w->lock);
        w->busy = 0;
        pthread_cond_broadcast(&w->cond);
    }
    pthread_mutex_unlock(&w->lock);
    return NULL;
}

/* ---- the sim thread's side ---- */

int service_snapshots_start(service *s)
{
    snap_worker *w = calloc(1, sizeof *w);
    if (!w)
        return -1;
    pthread_mutex_init(&w->lock, NULL);
    pthread_cond_init(&w->cond, NULL);
    s->snapper = w;
    return 0;
}

/* The codec and buffer, then the thread (sim thread, at the first hand-over):
 * 0 when the codec is there (the thread may not be: w->started says). */
static int start_worker(snap_worker *w)
{
    if (!w->codec) {
        size_t cells = SERVICE_TILE_SIZE * SERVICE_TILE_SIZE;    /* the larger of the two codings */
        w->packed_cap = terrad_rect_compress_slope_bound(cells); /* > encoding 2's */
        if (w->packed_cap < terrad_rect_compress_bound(cells))
            w->packed_cap = terrad_rect_compress_bound(cells);
        w->packed = malloc(w->packed_cap);
        w->codec = terrad_codec_new(3); /* the level snapshots always used (deltas: 1) */
        if (!w->packed || !w->codec) {
            terrad_codec_free(w->codec);
            free(w->packed);
            w->codec = NULL;
            w->packed = NULL;
            return -1;
        }
    }
    if (!w->started)
        w->started = pthread_create(&w->thread, NULL, snap_main, w) == 0;
    return 0;
}

void service_snapshots_stop(service *s)
{
    snap_worker *w = s->snapper;
    if (!w)
        return;
    pthread_mutex_lock(&w->lock);
    w->stop = 1;
    pthread_cond_broadcast(&w->cond);
    pthread_mutex_unlock(&w->lock);
    if (w->started)
        pthread_join(w->thread, NULL);
    free_requests(w->job, w->njob); /* never delivered: the daemon is stopping */
    free_requests(w->staged, w->nstaged);
    terrad_codec_free(w->codec);
    free(w->packed);
    pthread_cond_destroy(&w->cond);
    pthread_mutex_destroy(&w->lock);
    free(w);
    s->snapper = NULL;
}

/* The piece's heights less the scene's base terrain, wrapping (a base
 * snapshot's d = h - base): -1 without memory for the base. */
static int less_base(service *s, world_rect piece, int32_t *values)
{
    size_t n = (size_t)piece.w * piece.h;
    int32_t *base = malloc(n * sizeof *base);
    if (!base)
        return -1;
    world_base_fill_rect(s->world, piece, base);
    for (size_t i = 0; i < n; i++)
        values[i] = (int32_t)((uint32_t)values[i] - (uint32_t)base[i]);
    free(base);
    return 0;
}

/* Copy one job's tile pieces (the cells and their tile versions) for the worker. */
void service_snapshot_stage(service *s, const snapshot_job *job)
{
    THREAD_OWNED(&s->owner);
    snap_worker *w = s->snapper;
    if (array_grow((void **)&w->staged, &w->staged_cap, (int64_t)w->nstaged + 1,
                   sizeof *w->staged) != 0) {
        service_note_drop(s, "snapshot", "no memory to stage a snapshot for client %u",
                          job->client);
        if (job->last && !job->quiet) /* the client still gets its mark, without a frame */
            service_queue_client(s, job->client, NULL, TERRAD_MSG_DELTA, 1);
        return;
    }
    snap_request *r = &w->staged[w->nstaged++];
    memset(r, 0, sizeof *r);
    r->job = *job;
    r->tick = s->tick;
    world_rect q = job->rect;
    svc_client *cl = service_find_client(s, job->client);
    int against_base = cl ? cl->snapshot_base : 0; /* PROTOCOL.md "Base snapshots": 0, 1, 2 */
    int tiles = 0;
    if (q.w > 0 && q.h > 0)
        tiles = ((q.x + q.w - 1) / SERVICE_TILE_SIZE - q.x / SERVICE_TILE_SIZE + 1) *
                ((q.y + q.h - 1) / SERVICE_TILE_SIZE - q.y / SERVICE_TILE_SIZE + 1);
    r->pieces = calloc((size_t)tiles + 1, sizeof *r->pieces);
    if (!r->pieces) {
        r->mark_only = 1;
        service_note_drop(s, "snapshot", "no memory for a snapshot of %d tiles for client %u",
                          tiles, job->client);
        return;
    }
    for (int ty = q.y / SERVICE_TILE_SIZE; tiles && ty <= (q.y + q.h - 1) / SERVICE_TILE_SIZE;
         ty++) {
        for (int tx = q.x / SERVICE_TILE_SIZE; tx <= (q.x + q.w - 1) / SERVICE_TILE_SIZE; tx++) {
            world_rect piece =
                world_rect_meet(q, (world_rect){tx * SERVICE_TILE_SIZE, ty * SERVICE_TILE_SIZE,
                                                SERVICE_TILE_SIZE, SERVICE_TILE_SIZE});
            snap_piece *p = &r->pieces[r->npieces++];
            p->rect = (terrad_rect){.x = piece.x,
                                    .y = piece.y,
                                    .w = (uint16_t)piece.w,
                                    .h = (uint16_t)piece.h,
                                    .base_version = 0,
                                    .new_version = s->tile_versions[ty * s->tiles_x + tx],
                                    .encoding = against_base == 2 ? TERRAD_ENC_BASE_SLOPE
                                                : against_base    ? TERRAD_ENC_BASE
                                                                  : TERRAD_ENC_SNAPSHOT};
            p->values = malloc((size_t)piece.w * piece.h * sizeof *p->values);
            if (p->values) /* NULL: the worker counts the piece as failed */
                world_gather_window(s->world, piece, p->values);
            if (p->values && against_base && less_base(s, piece, p->values) != 0) {
                free(p->values); /* no memory for the base: counted as failed */
                p->values = NULL;
            }
        }
    }
}

/* End of tick t: hand the staged requests to the worker (idle: collected at
 * the start of this tick). */
void service_snapshots_hand_over(service *s)
{
    THREAD_OWNED(&s->owner);
    snap_worker *w = s->snapper;
    if (!w->nstaged)
        return;
    if (start_worker(w) != 0)
        for (int i = 0; i < w->nstaged; i++) /* no codec: the clients get their marks */
            w->staged[i].mark_only = 1;
    pthread_mutex_lock(&w->lock);
    w->job = w->staged;
    w->njob = w->nstaged;
    w->busy = w->started;
    pthread_cond_broadcast(&w->cond);
    pthread_mutex_unlock(&w->lock);
    if (!w->started) /* no thread: framed here, inside the tick */
        for (int i = 0; i < w->njob; i++)
            if (!w->job[i].mark_only)
                frame_request(w, &w->job[i]);
    w->staged = NULL;
    w->nstaged = 0;
    w->staged_cap = 0;
}

/* Start of tick t + 1: queue the frames the worker made of tick t's requests. */
void service_snapshots_collect(service *s)
{
    THREAD_OWNED(&s->owner);
    snap_worker *w = s->snapper;
    pthread_mutex_lock(&w->lock);
    while (w->busy)
        pthread_cond_wait(&w->cond, &w->lock);
    snap_request *job = w->job;
    int n = w->njob;
    w->job = NULL;
    w->njob = 0;
    pthread_mutex_unlock(&w->lock);
    uint64_t gone = 0;
    for (int i = 0; i < n; i++) {
        snap_request *r = &job[i];
        if (!service_find_client(s, r->job.client)) { /* left before its snapshot went out */
            gone += r->job.last;
            continue;
        }
        if (r->failed)
            service_note_drop(s, "snapshot", "%d piece(s) of a snapshot for client %u", r->failed,
                              r->job.client);
        if (r->mark_only) {
            for (int m = 0; m < (r->job.quiet ? 0 : r->job.last) + r->job.marks; m++)
                service_queue_client(s, r->job.client, NULL, TERRAD_MSG_DELTA, 1);
            continue;
        }
        for (int k = 0; k < r->nframes; k++) {
            service_queue_client(s, r->job.client, r->frames[k].f, TERRAD_MSG_DELTA,
                                 r->frames[k].done);
            r->frames[k].f = NULL; /* the out queue holds it now */
        }
    }
    free_requests(job, n);
    if (gone)
        metrics_count_snapshots_dropped(gone);
}
