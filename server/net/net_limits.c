/*
 * net_limits.c: every limit of the daemon's "limits" once (issue 29 item 4) —
 * its name (PROTOCOL.md's Limits table, --config's "limits" key, the world
 * message's), its field of net_limits, its default, whether a config may set
 * it and whether clients are told it, and what it bounds. net_limits_default,
 * the world message's "limits" (net_requests.c), the config's "limits"
 * (serve_options.c: a number in (0, 1e12], at least the row's min) and serve
 * --help's limits section are all made from this table, so a new limit is
 * one row here. The limits themselves are enforced where each is used (net/,
 * service/, http/); none of this runs in a tick.
 */
#include <limits.h>
#include <stddef.h>

#include "net/net.h"
#include "world/world.h"

/* A row's kind is its field's type in net_limits (net.h), so the table
 * cannot read or write a field as what it is not; a field of another type
 * does not compile. */
/* clang-format off */
#define KIND_OF(name)                                                                              \
    _Generic(((net_limits *)0)->name,                                                              \
             int: NET_LIMIT_INT,                                                                   \
             int64_t: NET_LIMIT_INT64,                                                             \
             size_t: NET_LIMIT_SIZE,                                                               \
             double: NET_LIMIT_DOUBLE)
/* clang-format on */
/* A row whose config value may not be under min (the budgets: hello's
 * NET_BUDGET_MIN); ROW: any value > 0. */
#define ROW_MIN(name, def, min, flags, help)                                                       \
    {                                                                                              \
#name, offsetof(net_limits, name), KIND_OF(name), def, flags, help, min                    \
    }
#define ROW(name, def, flags, help) ROW_MIN(name, def, 0, flags, help)

const net_limit_spec net_limit_table[] = {
    /* told to clients, in the world message's order */
    ROW(max_message_bytes, 1048576, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "largest websocket frame, text or binary"),
    ROW(max_colliders, 64, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "colliders per client"),
    ROW(max_poses_per_batch, 64, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "poses in one POSE_BATCH"),
    ROW(max_subscriptions, 16, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "subscriptions per client"),
    ROW(max_subscribed_cells, 4194304, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "cells over a client's subscriptions"),
    ROW(max_messages_per_s, 240, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "a client's sustained messages per second (token bucket)"),
    ROW(messages_burst, 480, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "the token bucket's depth"),
    ROW(max_mesh_vertices, 16384, NET_LIMIT_TOLD, "vertices per mesh collider"),
    ROW(max_mesh_triangles, 32768, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "triangles over a client's mesh colliders"),
    ROW(max_active_cells, 8192, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "a client's colliders' cost in cells (docs/service.md: a quarter of a 60 Hz tick)"),
    ROW(max_collider_extent_m, 50, NET_LIMIT_TOLD, "largest length of any collider dimension"),
    ROW(max_pending_bytes, 8388608, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "bytes queued for a client before it is treated as slow"),
    ROW(hello_timeout_s, 5, NET_LIMIT_CONFIG | NET_LIMIT_TOLD, "seconds allowed for hello"),
    ROW(max_client_lag_ticks, 0, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "ticks a client's oldest queued frame may lag before it is slow (0: 2 s of ticks)"),
    ROW(max_tick_cells, 32768, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "the tick's cost budget over every client (four clients' max_active_cells)"),
    ROW(max_sweep_cells, 32768, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "one client's cost this tick, its sweeps included (a whole tick's budget)"),
    ROW(max_edit_cells, WORLD_EDIT_MAX_CELLS_DEFAULT, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "cells one terrain edit may change"),
    ROW(max_step_ticks, 600, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "ticks one STEP of a client-clocked world may ask for (10 s of 60 Hz ticks)"),
    ROW(checksum_interval_ticks, 30, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "ticks between a subscription's CHECKSUM frames (0.5 s at 60 Hz)"),
    ROW(max_resync_tiles, 64, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
        "tiles one resync request may name (a 512 x 512 window's)"),
    ROW_MIN(default_budget_bytes_per_s, 0, NET_BUDGET_MIN, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
            "a client's bandwidth budget when its hello states none (0: none; else >= 1024)"),
    ROW_MIN(max_budget_bytes_per_s, 0, NET_BUDGET_MIN, NET_LIMIT_CONFIG | NET_LIMIT_TOLD,
            "the largest budget a hello may state (0: any, and none; else >= 1024)"),
    /* the server's own */
    ROW(max_connections, 0, NET_LIMIT_CONFIG,
        "websocket connections in all (0: from RLIMIT_NOFILE)"),
    ROW(max_connections_per_address, 256, NET_LIMIT_CONFIG,
        "websocket connections from one address"),
    ROW(max_heights_bytes_per_address, 0, NET_LIMIT_CONFIG,
        "HTTP: /v1/heights bytes one address may hold at once (0: 64 MiB)"),
    ROW(max_heights_bytes_in_flight, 0, NET_LIMIT_CONFIG,
        "HTTP: the same over every address (0: 256 MiB)"),
    ROW(fd_reserve, 64, 0, "descriptors left free under RLIMIT_NOFILE"),
    {0},
};

double net_limit_get(const net_limits *l, const net_limit_spec *s)
{
    const char *p = (const char *)l + s->offset;
    switch (s->kind) {
    case NET_LIMIT_INT:
        return *(const int *)(const void *)p;
    case NET_LIMIT_INT64:
        return (double)*(const int64_t *)(const void *)p;
    case NET_LIMIT_SIZE:
        return (double)*(const size_t *)(const void *)p;
    default:
        return *(const double *)(const void *)p;
    }
}

void net_limit_set(net_limits *l, const net_limit_spec *s, double v)
{
    char *p = (char *)l + s->offset;
    switch (s->kind) {
    case NET_LIMIT_INT:
        *(int *)(void *)p = v > INT_MAX ? INT_MAX : (int)v;
        break;
    case NET_LIMIT_INT64:
        *(int64_t *)(void *)p = (int64_t)v;
        break;
    case NET_LIMIT_SIZE:
        *(size_t *)(void *)p = (size_t)v;
        break;
    default:
        *(double *)(void *)p = v;
        break;
    }
}

net_limits net_limits_default(void)
{
    net_limits l = {0};
    for (const net_limit_spec *s = net_limit_table; s->name; s++)
        net_limit_set(&l, s, s->def);
    return l;
}

void net_limits_usage(FILE *out)
{
    fprintf(out,
            "limits (--config's \"limits\": each a number > 0, a budget >= %d; PROTOCOL.md "
            "\"Limits\"):\n",
            NET_BUDGET_MIN);
    for (const net_limit_spec *s = net_limit_table; s->name; s++)
        if (s->flags & NET_LIMIT_CONFIG)
            fprintf(out, "  %-30s %-10.15g %s\n", s->name, s->def, s->help);
}
