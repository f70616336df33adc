/*
 * test_hub_worlds.c: the one table of worlds both ports read (hub.h,
 * hub_worlds; issue 29). Lookups by name (NULL: the first), the names a 404
 * lists, a full table refused with a reason, and the removal's two waits:
 * an entry leaves the table at once (no new lookup finds it) but removal
 * returns only once the readers using it released it and its holder (the
 * net thread's part, played here by the test) let go after seeing it gone,
 * with the deleted flag it was removed with; with a holder, an add returns
 * only once it holds the entry (so a hello right after finds the world). The
 * watcher (the net thread's waker) is told of every add and remove. A reader
 * that outlives the readers' deadline is counted
 * (terrad_world_readers_overdue_total) while the removal waits on, its entry
 * still whole (in an ASan build a freed one would be caught), and the
 * removal returns once it lets go; one that lets go in time counts nothing.
 */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "check.h"
#include "hub/hub.h"
#include "metrics/metrics.h"

static atomic_int told;

static void watcher(void *ctx)
{
    (void)ctx;
    atomic_fetch_add(&told, 1);
}

static hub_world *add(hub_worlds *t, const char *name);

/* An add or a removal on a thread of its own (each may wait): w, rc once done. */
typedef struct removal {
    hub_worlds *t;
    hub_world *w; /* removed, or added (name) */
    const char *name;
    int deleted, rc;
    atomic_int done;
} removal;

static void *remove_main(void *arg)
{
    removal *r = arg;
    r->rc = hub_worlds_remove(r->t, r->w, r->deleted);
    atomic_store(&r->done, 1);
    return NULL;
}

static void *add_main(void *arg)
{
    removal *r = arg;
    r->w = add(r->t, r->name);
    atomic_store(&r->done, 1);
    return NULL;
}

static hub_world *add(hub_worlds *t, const char *name)
{
    hub_world e = {0};
    snprintf(e.name, sizeof e.name, "%s", name);
    error_text err = {{0}};
    hub_world *w = hub_worlds_add(t, &e, &err);
    CHECK(w != NULL, "add %s: %s", name, err.message);
    return w;
}

/* 1 once changed() holds (60 s at most: a loaded machine may start a thread
 * late, so a step of another thread is waited for, never given a fixed window). */
static int eventually(int (*changed)(hub_worlds *t, unsigned since), hub_worlds *t, unsigned since)
{
    for (int i = 0; i < 30000 && !changed(t, since); i++) {
        struct timespec ts = {0, 2 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    return changed(t, since);
}

/* The watcher was told since it was told `since` times. */
static int told_since(hub_worlds *t, unsigned since)
{
    (void)t;
    return (unsigned)atomic_load(&told) > since;
}

/* The table changed (an add or a removal took its lock) since generation `since`. */
static int moved_since(hub_worlds *t, unsigned since)
{
    return hub_worlds_generation(t) != since;
}

/* 1 when r is still waiting after ms (it should be). */
static int still_waiting(removal *r, int ms)
{
    for (int i = 0; i < ms / 10; i++) {
        if (atomic_load(&r->done))
            return 0;
        struct timespec ts = {0, 10 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    return !atomic_load(&r->done);
}

static void test_lookups(void)
{
    hub_worlds *t = hub_worlds_create();
    CHECK(hub_worlds_acquire(t, NULL) == NULL, "an empty table has no first world");
    hub_world *a = add(t, "alpha"), *b = add(t, "beta");
    hub_world *got = hub_worlds_acquire(t, "beta");
    CHECK(got == b, "beta by name");
    hub_worlds_release(t, got);
    got = hub_worlds_acquire(t, NULL);
    CHECK(got == a, "no name: the first added");
    hub_worlds_release(t, got);
    CHECK(hub_worlds_acquire(t, "gamma") == NULL, "an unknown name finds nothing");
    char def[HUB_WORLD_NAME_MAX + 1];
    CHECK(!hub_worlds_default(t, def, sizeof def) && !def[0], "no default name yet");
    hub_worlds_set_default(t, "beta"); /* a single daemon's default scene */
    got = hub_worlds_acquire(t, NULL);
    CHECK(got == b && hub_worlds_default(t, def, sizeof def) && strcmp(def, "beta") == 0,
          "no name: the entry the default name names");
    hub_worlds_release(t, got);
    hub_worlds_set_default(t, "gamma");
    CHECK(hub_worlds_acquire(t, NULL) == NULL, "a default name no entry has: no default world");
    hub_worlds_set_default(t, NULL);
    char names[64];
    int n = hub_worlds_names(t, names, sizeof names);
    CHECK(n == 2 && strcmp(names, "\"alpha\", \"beta\"") == 0, "names: %d %s", n, names);
    CHECK(hub_worlds_remove(t, a, 0) == 0 && hub_worlds_remove(t, b, 0) == 0, "removed");
    n = hub_worlds_names(t, names, sizeof names);
    CHECK(n == 0 && names[0] == 0, "no names left: %d %s", n, names);
    hub_worlds_destroy(t);
}

/* The entry the holder sees gone once a removal started, waited for together with the
 * watcher told at least told_min times; NULL after 60 s (generous, never a fixed window:
 * a loaded machine may run the removal's thread late). */
static hub_world *wait_gone(hub_worlds *t, int told_min)
{
    hub_world *gone = NULL;
    for (int i = 0; i < 30000 && (!gone || atomic_load(&told) < told_min); i++) {
        if (!gone)
            gone = hub_worlds_gone_next(t);
        struct timespec ts = {0, 2 * 1000 * 1000};
        nanosleep(&ts, NULL);
    }
    return gone;
}

static void test_full(void)
{
    hub_worlds *t = hub_worlds_create();
    hub_world *in[HUB_WORLDS_MAX];
    for (int i = 0; i < HUB_WORLDS_MAX; i++) {
        char name[16];
        snprintf(name, sizeof name, "w%d", i);
        in[i] = add(t, name);
    }
    hub_world e = {.name = "one-more"};
    error_text err = {{0}};
    CHECK(hub_worlds_add(t, &e, &err) == NULL && strstr(err.message, "already serves"),
          "a full table refuses with a reason: %s", err.message);
    /* an entry removed while the net thread holds it is still leaving: it
     * keeps its place until let go, so the leaving entries always fit and
     * each is detached (once an add took its place, a table full of such
     * removals left one out of leaving[], never let go of: a leak) */
    hub_world *held = hub_worlds_hold_next(t);
    removal r = {.t = t, .w = held};
    pthread_t th;
    pthread_create(&th, NULL, remove_main, &r);
    hub_world *gone = wait_gone(t, 0);
    CHECK(gone == in[0] && still_waiting(&r, 100), "the held entry is leaving");
    CHECK(hub_worlds_add(t, &e, &err) == NULL && strstr(err.message, "1 of them still leaving"),
          "while it leaves it keeps its place: %s", err.message);
    hub_worlds_let_go(t, held);
    pthread_join(th, NULL);
    hub_world *more = add(t, "one-more");
    CHECK(r.rc == 0 && more != NULL, "once let go, its place is free again");
    hub_worlds_remove(t, more, 0);
    for (int i = 1; i < HUB_WORLDS_MAX; i++)
        hub_worlds_remove(t, in[i], 0);
    hub_worlds_destroy(t);
}

/* terrad_world_readers_overdue_total as /metrics shows it (-1: not shown). */
static long long readers_overdue(void)
{
    size_t len = 0;
    char *text = metrics_render(&len);
    const char *at = text ? strstr(text, "\nterrad_world_readers_overdue_total ") : NULL;
    long long n = at ? strtoll(at + strlen("\nterrad_world_readers_overdue_total "), NULL, 10) : -1;
    free(text);
    return n;
}

static void test_remove_waits_for_readers(void)
{
    long long overdue = readers_overdue();
    hub_worlds *t = hub_worlds_create();
    hub_world *a = add(t, "alpha");
    hub_world *reader = hub_worlds_acquire(t, "alpha");
    removal r = {.t = t, .w = a};
    pthread_t th;
    unsigned g = hub_worlds_generation(t);
    pthread_create(&th, NULL, remove_main, &r);
    /* the removal took alpha out of the table (before that, a lookup still finds it) */
    CHECK(eventually(moved_since, t, g), "the removal starts");
    CHECK(still_waiting(&r, 200), "removal waits while a request uses the world");
    CHECK(hub_worlds_acquire(t, "alpha") == NULL, "but nothing new finds it meanwhile");
    hub_worlds_release(t, reader);
    pthread_join(th, NULL);
    CHECK(r.rc == 0, "removal returns once the request released it");
    CHECK(readers_overdue() == overdue && overdue >= 0,
          "a reader that let go in time is not counted overdue (%lld)", overdue);
    hub_worlds_destroy(t);
}

/* The counter moved past `since` (hub_worlds_remove counts at the readers' deadline). */
static int overdue_since(hub_worlds *t, unsigned since)
{
    (void)t;
    return readers_overdue() > (long long)since;
}

/* A reader that outlives the readers' deadline (a spectator's replay that does not
 * stop, an HTTP rebuild on a stalled disk): counted, and waited for all the same,
 * since what it reads goes with the world once the removal returns. */
static void test_overdue_reader(void)
{
    hub_worlds *t = hub_worlds_create();
    hub_world *a = add(t, "alpha");
    hub_world *reader = hub_worlds_acquire(t, "alpha");
    hub_world *other = hub_worlds_acquire(t, "alpha");
    long long before = readers_overdue();
    removal r = {.t = t, .w = a};
    pthread_t th;
    pthread_create(&th, NULL, remove_main, &r);
    /* 60 s at most (the deadline is 10 s; a loaded machine may run the removal late) */
    int counted = eventually(overdue_since, t, (unsigned)before);
    CHECK(counted && readers_overdue() == before + 2,
          "both readers still using it at the deadline are counted (%lld -> %lld)", before,
          readers_overdue());
    CHECK(still_waiting(&r, 200), "the removal waits on for them");
    CHECK(hub_worlds_leaving(reader) && strcmp(reader->name, "alpha") == 0,
          "the entry they hold is still whole, and says it is leaving");
    hub_worlds_release(t, reader);
    CHECK(still_waiting(&r, 200), "and for the last of them");
    hub_worlds_release(t, other);
    pthread_join(th, NULL);
    CHECK(r.rc == 0 && readers_overdue() == before + 2,
          "once both let go the removal returns, counted once (%lld)", readers_overdue());
    hub_worlds_destroy(t);
}

/* With a holder (a watcher set), an add returns once the holder holds it. */
static hub_world *add_held(hub_worlds *t, const char *name)
{
    removal r = {.t = t, .name = name};
    pthread_t th;
    int before = atomic_load(&told);
    pthread_create(&th, NULL, add_main, &r);
    /* told under the table's lock once the entry is in: the holder finds it from then on */
    CHECK(eventually(told_since, t, (unsigned)before), "the watcher is told of adding %s", name);
    CHECK(still_waiting(&r, 200), "adding %s waits for the holder", name);
    hub_world *held = hub_worlds_hold_next(t);
    pthread_join(th, NULL);
    CHECK(held && held == r.w, "the holder takes %s, and its add returns", name);
    return r.w;
}

static void test_holder(void)
{
    hub_worlds *t = hub_worlds_create();
    hub_worlds_watch(t, watcher, NULL);
    unsigned g0 = hub_worlds_generation(t);
    hub_world *a = add_held(t, "alpha"), *b = add_held(t, "beta");
    CHECK(hub_worlds_generation(t) != g0, "the generation moved");
    CHECK(hub_worlds_hold_next(t) == NULL, "the holder takes each entry once");
    CHECK(hub_worlds_gone_next(t) == NULL, "nothing gone yet");
    removal r = {.t = t, .w = a, .deleted = 1};
    pthread_t th;
    pthread_create(&th, NULL, remove_main, &r);
    /* Two adds and the removal told the watcher 3 times; a 4th is a re-wake while the
     * removal waits: the removal must keep waiting meanwhile, since the holder has not
     * let go. */
    hub_world *gone = wait_gone(t, 4);
    CHECK(gone == a && gone->deleted, "the holder sees the removed entry, deleted");
    CHECK(atomic_load(&told) >= 4, "the watcher is told again while it waits: %d",
          atomic_load(&told));
    CHECK(still_waiting(&r, 200), "removal waits for the holder");
    hub_worlds_let_go(t, a);
    pthread_join(th, NULL);
    CHECK(r.rc == 0 && hub_worlds_gone_next(t) == NULL, "removal returns once let go");
    hub_worlds_watch(t, NULL, NULL);
    int before = atomic_load(&told);
    hub_worlds_let_go(t, b); /* a holder that stops lets go of what it still holds */
    CHECK(hub_worlds_remove(t, b, 0) == 0, "removal after the holder let go");
    CHECK(atomic_load(&told) == before, "an unwatched table tells nobody");
    hub_worlds_destroy(t);
}

int main(void)
{
    test_lookups();
    test_full();
    test_remove_waits_for_readers();
    test_overdue_reader();
    test_holder();
    return check_report();
}
