/*
 * thread_owner.c: thread-ownership checks (base.h). docs/design.md names the
 * daemon's threads and what each one owns; the owner claims itself when its
 * thread starts and every thread-owned entry point asserts it runs there
 * (THREAD_OWNED), so a call from the wrong thread is caught in debug and
 * sanitizer builds instead of racing silently.
 */
#include "base/base.h"

#include <stdlib.h>
#ifdef TERRAD_TWIN_LIB
/* The twin library's WebAssembly build has one thread and no pthreads. */
static unsigned long this_thread(void)
{
    return 1;
}
#else
#include <pthread.h>
static unsigned long this_thread(void)
{
    return (unsigned long)pthread_self();
}
#endif

void thread_owner_claim(thread_owner *o, const char *name)
{
    o->name = name;
    o->tid = this_thread();
}

void thread_owner_release(thread_owner *o)
{
    o->tid = 0;
}

void thread_owner_check(const thread_owner *o, const char *function)
{
    /* Unclaimed: the owner's thread has not started (set-up, tests that call
     * a subsystem directly). Nothing to compare against. */
    if (!o->tid)
        return;
    if (o->tid != this_thread()) {
        log_error("%s: must run on the %s thread; called from another thread", function,
                  o->name ? o->name : "owning");
        abort();
    }
}
