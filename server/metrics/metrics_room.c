/*
 * metrics_room.c: the clients told to come back or to catch up, for want of
 * room (issue 28, item 5): terrad_http_refused_total{reason}, HTTP requests
 * answered 503 with Retry-After because they came past a connection limit
 * while every other connection was in a request (http_guard.c, counted by
 * the HTTP threads), and terrad_clients_behind_total, websocket clients
 * whose own report of the tick they have handled (PROTOCOL.md "seen") fell
 * more than max_client_lag_ticks behind what was written to them (counted
 * by the net thread); and terrad_http_bad_requests_total, HTTP requests
 * answered 400 (a parameter missing or wrong, named in the answer: the
 * sender must fix it, not retry). Rendered by metrics_render.
 */
#include <stdatomic.h>
#include <stdint.h>

#include "metrics/metrics.h"
#include "metrics/metrics_internal.h"

static const char *const reasons[] = {"connections_per_address", "connections"};
static atomic_uint_fast64_t http_refused[2], behind, bad_requests;

void metrics_count_http_refused(int overall)
{
    atomic_fetch_add_explicit(&http_refused[overall ? 1 : 0], 1, memory_order_relaxed);
}

void metrics_count_http_bad_request(void)
{
    atomic_fetch_add_explicit(&bad_requests, 1, memory_order_relaxed);
}

void metrics_count_client_behind(void)
{
    atomic_fetch_add_explicit(&behind, 1, memory_order_relaxed);
}

void metrics_room_reset(void)
{
    atomic_store_explicit(&http_refused[0], 0, memory_order_relaxed);
    atomic_store_explicit(&http_refused[1], 0, memory_order_relaxed);
    atomic_store_explicit(&behind, 0, memory_order_relaxed);
    atomic_store_explicit(&bad_requests, 0, memory_order_relaxed);
}

int metrics_room_text(char *out, size_t cap)
{
    size_t n = 0;
    int rc = metrics_put_labelled(
        out, cap, &n, "terrad_http_refused_total",
        "HTTP requests answered 503 with Retry-After, nothing done: they came past a connection "
        "limit while every other connection was in a request or waiting its turn.",
        "reason", reasons, 2, http_refused);
    if (rc == 0)
        rc = metrics_put_counter(
            out, cap, &n, "terrad_clients_behind_total",
            "Clients switched to snapshots because the tick they said they had handled (seen) was "
            "more than max_client_lag_ticks behind what was written to them.",
            &behind);
    if (rc == 0)
        rc = metrics_put_counter(out, cap, &n, "terrad_http_bad_requests_total",
                                 "HTTP requests answered 400: a parameter missing or wrong "
                                 "(named in the answer).",
                                 &bad_requests);
    return rc == 0 ? (int)n : -1;
}
