/*
 * test_ticker.c: the shared pool of sim workers (host/host_ticker.c, issue
 * 22) ticks several worlds at once, and each world's heights after T ticks
 * are bit-identical to the same world ticked alone on one thread. The worlds
 * are the daemon's default scene with demo actors, whose poses are a
 * function of the tick number only (host_demo.c), so the comparison needs
 * no clock. Also: a job asked to end mid-run ends (its end runs once, on a
 * worker), a stopped ticker ends every job it still holds, and the clock seam
 * (host.h, host_clock): a world whose clock says HOST_CLOCK_NEVER is taken by
 * no worker while others tick, and after host_ticker_wake runs exactly the
 * ticks its clock then allows (a client-driven clock's steps). And a tick
 * that stalls (an fsync, a commit: here a check that blocks) holds no other
 * world back: another worker wakes for the next due world while one ticks
 * (host_ticker.c: "Why more workers than cores"). A ticker that lets one
 * worker tick alone while the others sleep untimed fails it: the witness
 * never ticks while the stalled world waits for it.
 *
 * And a world's tick is published before anything names it (host_sim.c
 * publish_tick): when the tick's frames reach the network (the hub's waker,
 * called on the sim thread as they are handed over) and when a height read
 * is answered as of tick T, the status block (/v1/stats, and the ?tick=
 * check, http_views.c past_tick), the metrics and the hub's published tick
 * (spectate's from_tick check, net_spectate.c) already say T, and the read
 * is still waiting then. The window between "named" and "published" cannot
 * be forced from outside; the waker sees it from inside, every tick. An HTTP
 * edit's sender (POST /v1/worlds/{name}/edits answers with the edit's tick)
 * is told only once the status names the tick: each tick runs while the test
 * holds the status lock, and where the tick stops for it, the edit is not
 * answered yet.
 */
#include <cjson/cJSON.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "app/app.h"
#include "app/serve_internal.h"
#include "check.h"
#include "metrics/metrics.h"

#define POOL_WORLDS 5
#define TICKS 24
#define STALL_TICK 5 /* the stalling world's tick that waits for the witness */

typedef struct pooled {
    host_sim m;
    host_job job;
    int32_t *heights; /* copied by its end */
    int64_t volume;
    long ticks; /* service ticks when it ended */
    int ended, rc;
    atomic_long ticked; /* counted by count_tick */
    atomic_long owed;   /* owed_due's: the ticks its clock allows */
} pooled;

static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static pthread_cond_t cond = PTHREAD_COND_INITIALIZER;

static int32_t *all_heights(const world *w)
{
    int32_t *h = malloc((size_t)w->width * (size_t)w->height * sizeof *h);
    if (h)
        world_gather_window(w, (world_rect){0, 0, w->width, w->height}, h);
    return h;
}

static void pooled_end(host_job *j, int rc)
{
    pooled *p = j->ctx;
    p->heights = all_heights(&p->m.w);
    p->volume = world_volume(&p->m.w);
    p->ticks = (long)service_current_tick(p->m.svc);
    host_sim_free(&p->m); /* on the worker, as the daemon's ends do */
    pthread_mutex_lock(&lock);
    p->ended++;
    p->rc = rc;
    pthread_cond_broadcast(&cond);
    pthread_mutex_unlock(&lock);
}

/* The default scene's world with o's demo actors, ready to tick. */
static int open_world(host_sim *m, const serve_options *o, error_text *err)
{
    memset(m, 0, sizeof *m);
    m->metrics_slot = -1;
    pthread_mutex_init(&m->status.lock, NULL);
    if (app_open_scene_world(NULL, &m->sc, &m->w, err) != 0)
        return -1;
    m->sc.tick_hz = 1000; /* as fast as the workers go: overruns are fine here */
    host_sim_status_init(m);
    if (!(m->h = hub_create())) {
        error_set(err, "out of memory");
        return -1;
    }
    host_sim_config c = serve_host_config(o);
    return host_sim_start(m, &c, err);
}

/* A job's check: counts its ticks. */
static int count_tick(void *ctx, host_sim *m, long tick, char *why, size_t cap)
{
    (void)m, (void)tick, (void)why, (void)cap;
    atomic_fetch_add(&((pooled *)ctx)->ticked, 1);
    return 0;
}

/* A clock of the seam's kind a client-driven world has: due at once while
 * ticks are owed, never otherwise. */
static double owed_due(void *ctx, long tick, double period_ms, double last_due_ms, double now_ms)
{
    (void)period_ms, (void)last_due_ms;
    return tick < atomic_load(&((pooled *)ctx)->owed) ? now_ms : HOST_CLOCK_NEVER;
}

/* Until p has ticked at least n times (a generous deadline: a busy machine). */
static int wait_ticked(pooled *p, long n)
{
    for (int i = 0; i < 120000 && atomic_load(&p->ticked) < n; i++)
        host_sleep_ms(1);
    return atomic_load(&p->ticked) >= n;
}

static pooled *stall_witness;
static atomic_int stall_ok; /* 1: the witness ticked while the world stalled; -1: it did not */

/* A job's check that stalls once, at STALL_TICK, until the witness ticked 20
 * more times (the deadline: wait_ticked's). */
static int stall_tick(void *ctx, host_sim *m, long tick, char *why, size_t cap)
{
    count_tick(ctx, m, tick, why, cap);
    if (tick == STALL_TICK) {
        long seen = atomic_load(&stall_witness->ticked);
        atomic_store(&stall_ok, wait_ticked(stall_witness, seen + 20) ? 1 : -1);
    }
    return 0;
}

/* ---- a tick is published before anything names it ---- */

typedef struct published_view {
    host_sim *m;
    int wakes, late_status, late_metrics, late_hub, answered_first;
} published_view;

static uint64_t status_tick(host_sim *m)
{
    pthread_mutex_lock(&m->status.lock);
    uint64_t t = m->status.tick;
    pthread_mutex_unlock(&m->status.lock);
    return t;
}

/* terrad_tick as a scrape reads it (the default world's gauge). */
static uint64_t metrics_tick(void)
{
    size_t len = 0;
    char *text = metrics_render(&len);
    const char *line = text ? strstr(text, "\nterrad_tick ") : NULL;
    unsigned long long t = 0;
    if (line)
        sscanf(line, "\nterrad_tick %llu", &t);
    free(text);
    return t;
}

/* The hub's waker: on the sim thread, as the tick's frames are handed to the
 * network. The status and the metrics must name the tick already, and the
 * read waiting for this tick must not be answered yet. */
static void frames_out(void *arg)
{
    published_view *v = arg;
    uint64_t tick = service_current_tick(v->m->svc);
    v->wakes++;
    v->late_status += status_tick(v->m) != tick;
    v->late_metrics += metrics_tick() != tick;
    v->late_hub += hub_published_tick(v->m->h) != tick;
    v->answered_first += hub_reads_pending(v->m->h) == 0;
}

typedef struct tick_reader {
    host_sim *m;
    int32_t cells[16 * 16];
    uint64_t tick, status_after;
    int rc;
} tick_reader;

/* GET /v1/heights's wait (http_views.c read_rect), then what /v1/stats and
 * ?tick= would read at once. */
static void *read_then_status(void *arg)
{
    tick_reader *r = arg;
    r->rc = hub_read_heights(r->m->h, (world_rect){32, 32, 16, 16}, r->cells, &r->tick, 30000);
    r->status_after = status_tick(r->m);
    return NULL;
}

static void test_published_before_named(const serve_options *o)
{
    error_text err = {{0}};
    host_sim m;
    CHECK(open_world(&m, o, &err) == 0, "published: %s", err.message);
    published_view v = {.m = &m};
    hub_set_waker(m.h, frames_out, &v);
    for (long t = 0; t < 6; t++) {
        tick_reader r = {.m = &m};
        pthread_t th;
        CHECK(pthread_create(&th, NULL, read_then_status, &r) == 0, "reader thread");
        for (int i = 0; i < 30000 && hub_reads_pending(m.h) == 0; i++)
            host_sleep_ms(1); /* queued before the tick runs: this tick answers it */
        CHECK(hub_reads_pending(m.h) == 1, "tick %ld: the read waits for the tick", t);
        CHECK(host_sim_step(&m, t, 0, &err) == 0, "tick %ld: %s", t, err.message);
        pthread_join(th, NULL);
        CHECK(r.rc == 0 && r.tick == (uint64_t)t + 1,
              "tick %ld: the read is answered as of it (%d, %llu)", t, r.rc,
              (unsigned long long)r.tick);
        CHECK(r.status_after >= r.tick,
              "tick %ld: answered as of tick %llu, the status then says %llu (?tick= takes it)", t,
              (unsigned long long)r.tick, (unsigned long long)r.status_after);
    }
    CHECK(v.wakes == 6, "the frames of each tick went out once (%d)", v.wakes);
    CHECK(v.late_status == 0,
          "the status named each tick before its frames went out (%d of %d ticks late)",
          v.late_status, v.wakes);
    CHECK(v.late_metrics == 0, "so did the metrics (%d of %d ticks late)", v.late_metrics, v.wakes);
    CHECK(v.late_hub == 0, "so did the hub's published tick, spectate's (%d of %d ticks late)",
          v.late_hub, v.wakes);
    CHECK(v.answered_first == 0, "no read was answered before its tick's status (%d)",
          v.answered_first);
    hub_set_waker(m.h, NULL, NULL);
    host_sim_free(&m);
    pthread_mutex_destroy(&m.status.lock);
}

/* An HTTP edit (POST /v1/worlds/{name}/edits' wait, http_edits.c), then
 * what /v1/stats and ?tick= would read at once. */
typedef struct edit_sender {
    host_sim *m;
    hub_edit_result res;
    uint64_t status_after;
    atomic_int rc; /* 2 until hub_edit_submit returned */
} edit_sender;

static void *send_edit(void *arg)
{
    edit_sender *e = arg;
    cJSON *msg = cJSON_Parse("{\"op\":\"crater\",\"x\":40,\"y\":40,\"radius\":4,\"depth\":300}");
    world_edit *we = malloc(sizeof *we);
    hub_edit_error why = {0};
    int rc = we && hub_edit_parse(msg, e->m->w.width, e->m->w.height, 1 << 20, we, &why) == 0
                 ? hub_edit_submit(e->m->h, we, &e->res, 30000)
                 : -1;
    cJSON_Delete(msg);
    e->status_after = status_tick(e->m);
    atomic_store(&e->rc, rc);
    return NULL;
}

/* terrad_edits_total{op="crater",result="applied"}: counted on the sim
 * thread as the edit's sender is told (service_edits.c tell). */
static long long craters_applied(void)
{
    size_t len = 0;
    char *text = metrics_render(&len);
    const char *key = "terrad_edits_total{op=\"crater\",result=\"applied\"} ";
    const char *at = text ? strstr(text, key) : NULL;
    long long n = at ? strtoll(at + strlen(key), NULL, 10) : -1;
    free(text);
    return n;
}

typedef struct stepper {
    host_sim *m;
    long tick;
    int rc;
    error_text err;
} stepper;

static void *step_once(void *arg)
{
    stepper *st = arg;
    service_claim(st->m->svc); /* this thread is the world's sim thread for the tick */
    st->rc = host_sim_step(st->m, st->tick, 0, &st->err);
    return NULL;
}

/* An HTTP edit's sender hears of its tick only once the status names it.
 * Each tick runs on a thread of its own while this one holds the status
 * lock, so the tick stops where its host publishes the status; once the
 * hub's published tick (set just before) says the tick got there, the
 * edit must not have been answered yet. */
static void test_edit_answered_once_published(const serve_options *o)
{
    error_text err = {{0}};
    host_sim m;
    CHECK(open_world(&m, o, &err) == 0, "edited: %s", err.message);
    edit_sender e = {.m = &m, .rc = 2};
    long long before = craters_applied();
    pthread_t sender;
    CHECK(pthread_create(&sender, NULL, send_edit, &e) == 0, "sender thread");
    int early = 0, answered_at = -1;
    for (long t = 0; t < 3000 && answered_at < 0; t++) {
        stepper st = {.m = &m, .tick = t};
        uint64_t tick = service_current_tick(m.svc) + 1;
        pthread_mutex_lock(&m.status.lock);
        pthread_t th;
        CHECK(pthread_create(&th, NULL, step_once, &st) == 0, "tick thread");
        for (int i = 0; i < 30000 && hub_published_tick(m.h) < tick; i++)
            host_sleep_ms(1);
        int at_status = hub_published_tick(m.h) == tick;
        early += at_status && craters_applied() != before;
        pthread_mutex_unlock(&m.status.lock);
        pthread_join(th, NULL);
        CHECK(at_status && st.rc == 0, "tick %ld reached its status and ran (%s)", t,
              st.err.message);
        if (craters_applied() != before)
            answered_at = (int)tick;
        if (!at_status || st.rc != 0)
            break;
        host_sleep_ms(1); /* the edit is queued by another thread: a tick later takes it */
    }
    pthread_join(sender, NULL);
    CHECK(answered_at > 0 && atomic_load(&e.rc) == 0 && e.res.code == 0 &&
              e.res.tick == (uint64_t)answered_at,
          "the edit was applied at tick %d (rc %d, code %d, tick %llu)", answered_at,
          atomic_load(&e.rc), e.res.code, (unsigned long long)e.res.tick);
    CHECK(early == 0, "its sender was not told before the status named the tick");
    CHECK(e.status_after >= e.res.tick,
          "told tick %llu, the status then says %llu (?tick= takes it)",
          (unsigned long long)e.res.tick, (unsigned long long)e.status_after);
    service_claim(m.svc); /* back to this thread, which frees it */
    host_sim_free(&m);
    pthread_mutex_destroy(&m.status.lock);
}

static void wait_ended(pooled *p, int n)
{
    pthread_mutex_lock(&lock);
    for (int i = 0; i < n; i++)
        while (!p[i].ended)
            pthread_cond_wait(&cond, &lock);
    pthread_mutex_unlock(&lock);
}

int main(void)
{
    char *argv[] = {"serve", "--backend", "cpu", "--demo-actors", "4", "--no-data", NULL};
    serve_options o;
    CHECK(serve_options_parse(6, argv, &o) == CLI_OK, "options");
    error_text err = {{0}};
    test_published_before_named(&o);
    test_edit_answered_once_published(&o);

    /* the world alone, ticked on this thread */
    host_sim alone;
    CHECK(open_world(&alone, &o, &err) == 0, "alone: %s", err.message);
    for (long t = 0; t < TICKS; t++)
        CHECK(host_sim_step(&alone, t, 0, &err) == 0, "alone tick %ld: %s", t, err.message);
    int32_t *want = all_heights(&alone.w);
    int64_t want_volume = world_volume(&alone.w);
    {
        host_sim fresh;
        CHECK(open_world(&fresh, &o, &err) == 0, "fresh: %s", err.message);
        int32_t *base = all_heights(&fresh.w);
        CHECK(want && base &&
                  memcmp(want, base, (size_t)alone.w.width * alone.w.height * sizeof *want) != 0,
              "the demo actors deformed the world alone");
        free(base);
        host_sim_free(&fresh);
        pthread_mutex_destroy(&fresh.status.lock);
    }

    /* the same world POOL_WORLDS times on a pool of 3 workers, side by side */
    host_ticker *t = host_ticker_start(3, &err);
    CHECK(t != NULL, "ticker: %s", err.message);
    pooled *p = calloc(POOL_WORLDS + 6, sizeof *p);
    for (int i = 0; i < POOL_WORLDS; i++) { /* all made first: they tick side by side */
        CHECK(open_world(&p[i].m, &o, &err) == 0, "world %d: %s", i, err.message);
        p[i].job = (host_job){.m = &p[i].m, .max_ticks = TICKS, .end = pooled_end, .ctx = &p[i]};
    }
    for (int i = 0; t && i < POOL_WORLDS; i++)
        CHECK(host_ticker_add(t, &p[i].job, &err) == 0, "add %d: %s", i, err.message);
    wait_ended(p, POOL_WORLDS);
    size_t cells = (size_t)alone.w.width * alone.w.height;
    for (int i = 0; i < POOL_WORLDS; i++) {
        CHECK(p[i].ended == 1 && p[i].rc == 0, "world %d ended once, rc 0 (%d, %d)", i, p[i].ended,
              p[i].rc);
        CHECK(p[i].ticks == TICKS, "world %d ticked %d times (%ld)", i, TICKS, p[i].ticks);
        CHECK(p[i].heights && want && memcmp(p[i].heights, want, cells * sizeof *want) == 0,
              "world %d on the pool: heights identical to the world alone", i);
        CHECK(p[i].volume == want_volume, "world %d: volume %lld, alone %lld", i,
              (long long)p[i].volume, (long long)want_volume);
    }

    /* one asked to end mid-run, one left to the ticker's stop */
    pooled *a = &p[POOL_WORLDS], *b = &p[POOL_WORLDS + 1];
    for (int i = 0; t && i < 2; i++) {
        CHECK(open_world(&a[i].m, &o, &err) == 0, "endless %d: %s", i, err.message);
        a[i].job = (host_job){.m = &a[i].m, .max_ticks = -1, .end = pooled_end, .ctx = &a[i]};
        CHECK(host_ticker_add(t, &a[i].job, &err) == 0, "add endless %d: %s", i, err.message);
    }
    host_ticker_end(t, &a->job);
    wait_ended(a, 1);
    CHECK(a->ended == 1 && a->rc == 0, "ended when asked (%d, rc %d)", a->ended, a->rc);

    /* the clock seam: a parked world beside a witness that ticks on the wall clock */
    pooled *parked = &p[POOL_WORLDS + 2], *witness = &p[POOL_WORLDS + 3];
    pooled *both[] = {parked, witness};
    for (int i = 0; t && i < 2; i++) {
        CHECK(open_world(&both[i]->m, &o, &err) == 0, "clocked %d: %s", i, err.message);
        both[i]->job = (host_job){.m = &both[i]->m,
                                  .max_ticks = -1,
                                  .check = count_tick,
                                  .end = pooled_end,
                                  .ctx = both[i]};
    }
    parked->job.clock = (host_clock){.name = "owed", .due_ms = owed_due, .ctx = parked};
    for (int i = 0; t && i < 2; i++)
        CHECK(host_ticker_add(t, &both[i]->job, &err) == 0, "add clocked %d: %s", i, err.message);
    CHECK(wait_ticked(witness, 20), "the witness ticks on the wall clock");
    CHECK(atomic_load(&parked->ticked) == 0, "a world whose clock says never is not ticked (%ld)",
          atomic_load(&parked->ticked));
    atomic_store(&parked->owed, 3);
    host_ticker_wake(t, &parked->job);
    CHECK(wait_ticked(parked, 3), "woken, it runs the ticks its clock allows");
    long seen = atomic_load(&witness->ticked);
    CHECK(wait_ticked(witness, seen + 20), "the witness goes on");
    CHECK(atomic_load(&parked->ticked) == 3, "then it waits again: exactly 3 ticks (%ld)",
          atomic_load(&parked->ticked));
    host_ticker_end(t, &parked->job);
    wait_ended(parked, 1);
    CHECK(parked->ended == 1 && parked->ticks == 3,
          "a parked world ends when asked, after its 3 "
          "ticks (%d, %ld)",
          parked->ended, parked->ticks);
    host_ticker_stop(t);
    CHECK(b->ended == 1 && b->rc == 0, "the ticker's stop ended the last (%d, rc %d)", b->ended,
          b->rc);

    /* a stalled tick beside a witness, both at 60 Hz on a pool of their own
     * (so its workers sleep between ticks): the witness goes on meanwhile */
    pooled *stalled = &p[POOL_WORLDS + 4], *witness2 = &p[POOL_WORLDS + 5];
    host_ticker *t2 = host_ticker_start(3, &err);
    CHECK(t2 != NULL, "ticker: %s", err.message);
    pooled *pair[] = {stalled, witness2};
    /* no demo actors: a tick far shorter than the gap to the other world's,
     * so nothing but the stall keeps the witness waiting */
    char *argv0[] = {"serve", "--backend", "cpu", "--demo-actors", "0", "--no-data", NULL};
    serve_options o0;
    CHECK(serve_options_parse(6, argv0, &o0) == CLI_OK, "options");
    for (int i = 0; t2 && i < 2; i++) {
        CHECK(open_world(&pair[i]->m, &o0, &err) == 0, "stall pair %d: %s", i, err.message);
        pair[i]->m.sc.tick_hz = 60;
        pair[i]->job = (host_job){.m = &pair[i]->m,
                                  .max_ticks = -1,
                                  .check = i == 0 ? stall_tick : count_tick,
                                  .end = pooled_end,
                                  .ctx = pair[i]};
    }
    stall_witness = witness2;
    /* the witness first, the stalling world a few ticks later: out of phase,
     * so the witness is not due when the stall begins */
    CHECK(t2 && host_ticker_add(t2, &witness2->job, &err) == 0, "add witness: %s", err.message);
    CHECK(wait_ticked(witness2, 3), "the witness ticks");
    host_sleep_ms(5);
    CHECK(t2 && host_ticker_add(t2, &stalled->job, &err) == 0, "add stalled: %s", err.message);
    CHECK(wait_ticked(stalled, STALL_TICK + 2), "the stalled world ticks on after its stall");
    CHECK(atomic_load(&stall_ok) == 1,
          "the witness ticked 20 times while a world's tick stalled (%d)", atomic_load(&stall_ok));
    host_ticker_stop(t2);
    CHECK(stalled->ended == 1 && witness2->ended == 1, "the stall pair ended (%d, %d)",
          stalled->ended, witness2->ended);

    for (int i = 0; i < POOL_WORLDS + 6; i++) {
        free(p[i].heights);
        pthread_mutex_destroy(&p[i].m.status.lock);
    }
    free(p);
    free(want);
    host_sim_free(&alone);
    pthread_mutex_destroy(&alone.status.lock);
    return check_report();
}
