/*
 * http_worlds.c: the worlds a request may name (?world=NAME), read from the
 * one table of worlds the daemon keeps (hub.h, hub_worlds; the HTTP threads
 * and the net thread read it, each world's host adds and removes it). A
 * request takes the world it names for as long as it runs (a height read
 * waits on the world's sim thread through the hub), so the world's removal
 * waits for the requests in flight — hub_close_reads first makes those fail
 * fast.
 */
#include <stdio.h>
#include <string.h>

#include "http/http_internal.h"

void http_server_host_worlds(http_server *s)
{
    pthread_mutex_lock(&s->worlds_lock);
    s->hosts_worlds = 1;
    pthread_mutex_unlock(&s->worlds_lock);
}

hub_world *http_world_acquire(http_server *s, const char *name, unsigned *code, char *why,
                              size_t cap)
{
    hub_world *found = s->worlds ? hub_worlds_acquire(s->worlds, name) : NULL;
    if (found)
        return found;
    if (!name) {
        *code = MHD_HTTP_SERVICE_UNAVAILABLE;
        snprintf(why, cap, "%s",
                 s->hosts_worlds ? "this node serves no world now (a standby)"
                                 : "the default world is not served (it is "
                                   "starting, or the daemon stops)");
        return NULL;
    }
    char names[400];
    int n = s->worlds ? hub_worlds_names(s->worlds, names, sizeof names) : 0;
    *code = MHD_HTTP_NOT_FOUND;
    snprintf(why, cap,
             "this node does not serve world \"%.64s\"%s%s%s; terrad world list names "
             "each world's node",
             name, n ? " (it serves " : "", n ? names : "", n ? ")" : "");
    return NULL;
}

void http_world_release(http_server *s, hub_world *w)
{
    hub_worlds_release(s->worlds, w);
}
