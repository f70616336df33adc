/*
 * net_limits.c: the daemon's "limits" as data. net_limit_table has a row for
 * each limit of NET_LIMITS (net.h, where each is written once: its C type,
 * name, default, min, where it may be set or is told, and what it bounds).
 * net_limits_default, the world message's "limits" (net_requests.c), the
 * config's "limits" (serve_options.c: a number in (0, 1e12], at least the
 * row's min) and serve --help's limits section are all made from this
 * table. The limits themselves are enforced where each is used (net/,
 * service/, http/); none of this runs in a tick.
 */
#include <limits.h>
#include <stddef.h>

#include "net/net.h"
#include "world/world.h"

/* A row's kind is its field's type in net_limits (the type column of
 * NET_LIMITS), so the table cannot read or write a field as what it is not;
 * a field of another type does not compile. */
/* clang-format off */
#define KIND_OF(name)                                                                              \
    _Generic(((net_limits *)0)->name,                                                              \
             int: NET_LIMIT_INT,                                                                   \
             int64_t: NET_LIMIT_INT64,                                                             \
             size_t: NET_LIMIT_SIZE,                                                               \
             double: NET_LIMIT_DOUBLE)
/* clang-format on */
#define ROW(type, name, def, min, flags, help)                                                     \
    {#name, offsetof(net_limits, name), KIND_OF(name), def, flags, help, min},

const net_limit_spec net_limit_table[] = {
    NET_LIMITS(ROW) /* each ROW ends with its comma */
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
