/*
 * metrics_auth.c: terrad_auth_refused_total{reason}, the requests refused for
 * who sent them (base.h "Authentication"): counted by the net thread at
 * hello, on a forbidden request and when a reload revokes an open
 * connection's token, and by the HTTP threads; rendered by metrics_render.
 */
#include <stdatomic.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const reasons[] = {METRICS_AUTH_REASONS};
#define REASONS (sizeof reasons / sizeof reasons[0])
static atomic_uint_fast64_t refused[REASONS];

void metrics_count_auth_refused(const char *reason)
{
    int i = metrics_label_index(reasons, (int)REASONS, reason);
    if (i >= 0)
        atomic_fetch_add_explicit(&refused[i], 1, memory_order_relaxed);
}

void metrics_auth_reset(void)
{
    for (size_t i = 0; i < REASONS; i++)
        atomic_store_explicit(&refused[i], 0, memory_order_relaxed);
}

int metrics_auth_text(char *out, size_t cap)
{
    size_t n = 0;
    int rc = metrics_put_labelled(out, cap, &n, "terrad_auth_refused_total",
                                  "Requests refused for their sender's token or role, by reason.",
                                  "reason", reasons, (int)REASONS, refused);
    return rc == 0 ? (int)n : -1;
}
