/*
 * metrics_cluster.c: what the cluster's log takes count
 * (server/cluster/cluster_wal.c): terrad_cluster_takes_redone_total, takes
 * of a world's log whose confirming read found another writer's message
 * after the point they recovered to — nats-server 2.9 stored an old owner's
 * append in flight beside the new owner's marker (docs/cluster.md, "The
 * fencing race of nats-server 2.9") — and were read on and made again. A
 * take runs before its world ticks, never in a tick. Rendered by
 * metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static atomic_uint_fast64_t takes_redone;

void metrics_count_cluster_take_redone(void)
{
    atomic_fetch_add_explicit(&takes_redone, 1, memory_order_relaxed);
}

void metrics_cluster_reset(void)
{
    atomic_store_explicit(&takes_redone, 0, memory_order_relaxed);
}

int metrics_cluster_text(char *out, size_t cap)
{
    size_t n = 0;
    int rc = metrics_put_counter(out, cap, &n, "terrad_cluster_takes_redone_total",
                                 "Takes of a world's log that found another writer's message "
                                 "after the point they recovered to, and were made again.",
                                 &takes_redone);
    return rc == 0 ? (int)n : -1;
}
